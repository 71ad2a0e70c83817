"""PushT tasks and the Panda model on the CPU: kinematics, exactness, physics, bad input."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from conftest import pad_rows
from pachs_jax import envs
from pachs_jax.envs import coverage, panda, pusht

BATCH = 64  # test_mujoco_c.BATCH


@pytest.fixture(scope='module')
def env():
  return envs.make('pusht-fixed')


@pytest.fixture(scope='module')
def jitted(env):
  """Compiled once for the whole module: single transition, training step, batched evaluate."""
  return dict(transition=jax.jit(env.transition), step=jax.jit(env.step),
              evaluate=jax.jit(env.evaluate), tip=jax.jit(env.tip_position))


def _dh_flange(q):
  """Independent forward kinematics: product of modified-DH transforms (Craig)."""
  a = [0, 0, 0, 0.0825, -0.0825, 0, 0.088]
  d = [0.333, 0, 0.316, 0, 0.384, 0, 0.107]
  alpha = [0, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2]
  t = np.eye(4)
  for i in range(7):
    rx = np.array([[1, 0, 0, 0], [0, np.cos(alpha[i]), -np.sin(alpha[i]), 0],
                   [0, np.sin(alpha[i]), np.cos(alpha[i]), 0], [0, 0, 0, 1]])
    tx = np.eye(4)
    tx[0, 3] = a[i]
    rz = np.array([[np.cos(q[i]), -np.sin(q[i]), 0, 0], [np.sin(q[i]), np.cos(q[i]), 0, 0],
                   [0, 0, 1, 0], [0, 0, 0, 1]])
    tz = np.eye(4)
    tz[2, 3] = d[i]
    t = t @ rx @ tx @ rz @ tz
  return t


def test_unknown_task_lists_valid_names():
  with pytest.raises(ValueError, match='pusht-fixed.*pusht-rand.*pusht-obs.*shelf'):
    envs.make('pusht')


def test_a_pusht_task_takes_a_named_physics():
  free = envs.make('pusht-obs', layout='wall', physics='faithful')
  want = pusht.physics_preset('faithful', variant='obs', layout='wall')
  assert free.config == want and free.config.t_body == 'free' and free.mj_model.nq == 14
  assert envs.make('pusht-fixed').config == pusht.PushTConfig()  # no physics: the default
  with pytest.raises(ValueError, match="unknown physics preset 'stiff'; valid: "):
    envs.make('pusht-rand', physics='stiff')
  with pytest.raises(ValueError, match="task 'shelf' has no option physics"):
    envs.make('shelf', physics='faithful')


def test_free_t_cost_keeps_the_tip_at_the_t_half_height(env):
  """Over the T's centre, lifting the tip from the T's half height to 6 cm costs w_height per m
  of the free T (the 3D reach term is still inside its 5 cm), nothing for the planar T."""
  free, planar = env, envs.make('pusht-fixed', physics='planar')
  for e, want in ((free, free.config.w_height * 0.04), (planar, 0.0)):
    node = e.canonical_instances(1)
    node = jax.tree.map(lambda x: x[0], node)
    centre = np.asarray(pusht.t_pose(node.qpos))[:2]
    costs = [float(e._cost(node, jnp.asarray([*centre, z], jnp.float32)))
             for z in (pusht.T_HALF_HEIGHT, 0.06)]
    assert costs[1] - costs[0] == pytest.approx(want, abs=1e-5)
  assert free.config.w_height > 0


def test_end_effector_matches_dh_in_mujoco_c_and_mjx(env):
  rng = np.random.default_rng(0)
  qs = rng.uniform(panda.JOINT_LOWER, panda.JOINT_UPPER, size=(16, 7))
  m = env.mj_model
  data = mujoco.MjData(m)
  site = m.site('flange').id
  base = np.asarray(pusht.BASE_POS)

  t_qpos = np.asarray(env.node_from_pose(jnp.zeros(3), jnp.zeros(3)).qpos[7:])  # the T at 0

  @jax.jit
  def mjx_flange(q):
    d = mjx.kinematics(env.mjx_model, env.restore(env.node_from_pose(
        jnp.zeros(3), jnp.zeros(3))).replace(qpos=jnp.concatenate([q, jnp.asarray(t_qpos)])))
    return d.site_xpos[site]

  for q in qs:
    data.qpos[:] = np.concatenate([q, t_qpos])
    mujoco.mj_kinematics(m, data)
    want = _dh_flange(q)[:3, 3] + base
    np.testing.assert_allclose(data.site_xpos[site], want, atol=1e-4)
    np.testing.assert_allclose(np.asarray(mjx_flange(jnp.asarray(q, jnp.float32))), want,
                               atol=1e-4)


def test_tip_chain_kinematics_matches_mujoco(env, jitted):
  """The tip the observation and lattice read (the arm's chain alone) is MuJoCo's tip site, for
  any arm angles and T pose."""
  rng = np.random.default_rng(1)
  m = env.mj_model
  data = mujoco.MjData(m)
  for _ in range(8):
    t_pose = np.concatenate([rng.uniform(-0.3, 0.3, 2), rng.uniform(-np.pi, np.pi, 1)])
    node = env.node_from_pose(jnp.asarray(t_pose, jnp.float32), jnp.zeros(3))
    qpos = np.concatenate([rng.uniform(panda.JOINT_LOWER, panda.JOINT_UPPER),
                           np.asarray(node.qpos[7:])])
    data.qpos[:] = qpos
    mujoco.mj_kinematics(m, data)
    node = node.replace(qpos=jnp.asarray(qpos, jnp.float32))
    np.testing.assert_allclose(np.asarray(jitted['tip'](node)), data.site_xpos[m.site('tip').id],
                               atol=2e-6)


def test_model_uses_only_explicit_primitive_contacts(env):
  m = env.mj_model
  assert np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
  allowed = {mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_SPHERE,
             mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_PLANE}
  assert {int(t) for t in m.geom_type} <= {int(t) for t in allowed}
  assert m.npair == 5  # stick against bar, stem and table; the free T's bar and stem on the table
  obs = envs.make('pusht-obs')
  assert obs.mj_model.npair == 5 + 3 * len(obs.obstacles) and len(obs.obstacles) > 0
  assert envs.make('pusht-fixed', physics='planar').mj_model.npair == 3  # a T on joints


def test_observation_and_interface_sizes(env):
  state = jax.jit(env.reset)(jax.random.PRNGKey(3))
  assert env.action_size == 7
  assert state.obs.shape == (env.observation_size,)
  assert np.all(np.isfinite(np.asarray(state.obs)))
  assert float(state.reward) == 0.0 and float(state.done) == 0.0


def test_step_is_restore_and_evaluate_bit_for_bit(env, jitted):
  """The node state is all the simulation state: a training trajectory replays exactly."""
  state = jax.jit(env.reset)(jax.random.PRNGKey(0))
  actions = jax.random.uniform(jax.random.PRNGKey(1), (6, 7), minval=-1, maxval=1)
  nodes = [state.pipeline_state]
  for a in actions:
    state = jitted['step'](state, a)
    assert float(state.reward) <= 0.0
    nodes.append(state.pipeline_state)
  node = nodes[0]
  for i, a in enumerate(actions):
    node = jitted['transition'](node, a).next_node
    for got, want in zip(jax.tree.leaves(node), jax.tree.leaves(nodes[i + 1])):
      np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_restored_node_continues_a_carried_simulation_exactly(env):
  """Restoring from the compact node inside a rollout changes nothing against carrying the
  whole mjx.Data: qpos, qvel, ctrl and qacc_warmstart hold the complete state. (One program
  for both rollouts: whether to restore is an argument.)"""
  start = env.node_from_pose(jnp.array([-0.3, -0.28, 0.3]), jnp.asarray(pusht.FIXED_GOAL))
  actions = jax.random.uniform(jax.random.PRNGKey(2), (4, 7), minval=-1, maxval=1)

  def restored(d):
    return env.restore(env.node_from_pose(jnp.zeros(3), jnp.zeros(3)).replace(
        qpos=d.qpos, qvel=d.qvel, ctrl=d.ctrl, qacc_warmstart=d.qacc_warmstart))

  @jax.jit
  def rollout(restore_each_step, node, acts):
    def body(d, a):
      d = jax.lax.cond(restore_each_step, restored, lambda x: x, d)
      d = d.replace(ctrl=jnp.clip(d.qpos[:7] + 0.1 * a, env._arm_lower, env._arm_upper))
      d = jax.lax.fori_loop(0, env.config.substeps, lambda _, x: mjx.step(env.mjx_model, x), d)
      return d, (d.qpos, d.qvel, d.qacc_warmstart)
    return jax.lax.scan(body, env.restore(node), acts)[1]

  carried, restarted = rollout(False, start, actions), rollout(True, start, actions)
  assert np.abs(np.diff(np.asarray(carried[0]), axis=0)).max() > 1e-4  # the state moves
  for x, y in zip(carried, restarted):
    np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_stick_pushes_the_t(env, jitted):
  """A Jacobian controller drives the tip at 1.5 cm into the T and on along +y: the T slides
  ahead of the tip, upright, along the same line."""
  node = env.node_from_pose(jnp.array([-0.25, -0.15, 0.0]), jnp.asarray(pusht.FIXED_GOAL))
  data = mujoco.MjData(env.mj_model)
  waypoints = [np.array([-0.25, -0.32, 0.015])] * 10 + [np.array([-0.25, 0.05, 0.015])] * 20
  for goal in waypoints:
    action = pusht.jacobian_action(env.mj_model, data, goal, qpos=np.asarray(node.qpos))
    out = jitted['transition'](node, jnp.asarray(action, jnp.float32))
    assert bool(out.is_valid)
    node = out.next_node
  tip = np.asarray(jitted['tip'](node))
  t_pose = np.asarray(pusht.t_pose(node.qpos))
  assert tip[1] > -0.06 and abs(tip[2] - 0.015) < 0.01  # the tip moved on, along the table
  assert t_pose[1] > 0.0 and abs(t_pose[0] + 0.25) < 0.02  # the T was pushed along +y
  assert t_pose[1] - tip[1] > 0.03 and float(pusht.t_tilt(node.qpos)) < 0.1  # ahead, upright


def test_bad_actions_and_states(env, jitted):
  # a batch of BATCH rows, the batch test_mujoco_c.py's MJX evaluate compiles (one program)
  nodes = pad_rows(env.canonical_instances(2), BATCH)
  with pytest.raises(ValueError, match=r'actions must have shape \[B, 7\]'):
    env.evaluate(nodes, jnp.zeros((BATCH, 6)))
  with pytest.raises(ValueError, match=r'shape \[7\]'):
    env.step(jax.jit(env.reset)(jax.random.PRNGKey(0)), jnp.zeros(8))
  actions = jnp.zeros((BATCH, 7)).at[0, 3].set(jnp.nan)
  out = jitted['evaluate'](nodes, actions)
  assert not bool(out.is_valid[0]) and bool(out.is_valid[1:].all())
  assert np.all(np.isfinite(np.asarray(out.cost)))
  bad = nodes.replace(qvel=nodes.qvel.at[1, 2].set(jnp.inf))
  out = jitted['evaluate'](bad, jnp.zeros((BATCH, 7)))
  assert bool(out.is_valid[0]) and not bool(out.is_valid[1])
  assert np.all(np.isfinite(np.asarray(out.cost)))
  assert all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree.leaves(out.next_node))


def test_goal_and_lattice(env):
  goal = jnp.asarray(pusht.FIXED_GOAL, jnp.float32)
  at_goal = env.node_from_pose(goal, goal)
  away = env.node_from_pose(goal + jnp.array([0.1, 0.0, 0.0]), goal)
  both = jax.tree.map(lambda a, b: jnp.stack([a, b]), at_goal, away)
  np.testing.assert_array_equal(np.asarray(env.is_goal(both)), [True, False])
  keys = np.asarray(env.lattice_key(both))
  assert keys.shape == (2, 5) and keys.dtype == np.int32
  assert keys[1, 0] - keys[0, 0] == 10  # 0.1 m at 1 cm cells
  coarse = np.asarray(env.lattice_key(both, jnp.array([1.0, 1.0, 10.0, 1.0, 1.0])))
  assert np.all(coarse[0] == coarse[1])


@pytest.mark.parametrize('name', ['pusht-fixed', 'pusht-rand', 'pusht-obs'])
def test_canonical_instances(name):
  env = envs.make(name)
  first, again = env.canonical_instances(30), env.canonical_instances(30)
  np.testing.assert_array_equal(np.asarray(first.qpos), np.asarray(again.qpos))
  poses, goals = np.asarray(pusht.t_pose(first.qpos)), np.asarray(first.goal)
  assert poses.shape == (30, 3)
  assert np.all(np.asarray(coverage.coverage(poses, goals)) < 0.9)
  if env.layout is not None:  # pusht-obs: its layout's start region (tests/test_layouts.py)
    assert env.layout.in_start_region(poses).all()
  else:
    offsets = poses[:, :2] - goals[:, :2]
    assert np.all(offsets >= np.array(pusht.START_OFFSET_LOW) - 1e-6)
    assert np.all(offsets <= np.array(pusht.START_OFFSET_HIGH) + 1e-6)
  if name == 'pusht-rand':
    assert len({tuple(g) for g in goals.round(4)}) == 30
  else:
    np.testing.assert_allclose(goals, np.tile(pusht.FIXED_GOAL, (30, 1)), atol=1e-6)
  for box in env.obstacles:  # no T overlaps an obstacle's centre region
    centre = np.broadcast_to(box[:2], (30, 1, 2))
    assert not np.any(np.asarray(coverage.points_in_t(centre, poses)))
