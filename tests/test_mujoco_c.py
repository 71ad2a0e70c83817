"""MuJoCo C bridge: exact state conversion, C vs MJX physics, the CPU backend, the world."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from conftest import UniformActorCritic, pad_rows

from pachs_jax import envs
from pachs_jax.envs import panda, pusht
from pachs_jax.envs import backends, mujoco_c, world as world_lib

BATCH = 64


@pytest.fixture(scope='module')
def env():
  return envs.make('pusht-fixed')


@pytest.fixture(scope='module')
def cenv(env):
  c = mujoco_c.MujocoCEnv(env)
  yield c
  c.close()


@pytest.fixture(scope='module')
def mjx_evaluate(env):
  return jax.jit(env.evaluate)


@pytest.fixture(scope='module')
def c_evaluate(cenv):
  return jax.jit(cenv.evaluate)


def _random_node(env, seed):
  """A single node with random (finite) velocities and warm start, float32 leaves."""
  rng = np.random.default_rng(seed)
  node = env.sample_instance(jax.random.PRNGKey(seed))
  nv = env.mj_model.nv
  return node.replace(qvel=jnp.asarray(rng.normal(size=nv), jnp.float32),
                      qacc_warmstart=jnp.asarray(rng.normal(size=nv) * 10, jnp.float32),
                      ctrl=node.ctrl + jnp.float32(0.01), t=jnp.int32(7))


def _push(env, num_steps=30):
  """A Jacobian-controlled push in MuJoCo C: (nodes [num_steps] float32, actions [num_steps, 7]).

  The tip first goes below the T, then pushes it in +y.
  """
  m = env.mj_model
  d = mujoco.MjData(m)
  d.qpos[:7] = pusht.HOME_QPOS
  d.qpos[7:] = np.asarray(env.node_from_pose(jnp.float32([-0.25, -0.18, 0.3]),
                                             jnp.zeros(3)).qpos[7:])
  d.ctrl[:] = d.qpos[:7]
  nodes, actions = [], []
  for k in range(num_steps):
    mujoco.mj_forward(m, d)
    nodes.append(mujoco_c.mjdata_to_node(env, d, pusht.FIXED_GOAL, k))
    goal = np.array([-0.25, -0.32, 0.015]) if k < 8 else np.array([-0.22, 0.05, 0.015])
    a = pusht.jacobian_action(m, d, goal)
    actions.append(a.astype(np.float32))
    d.ctrl[:] = np.clip(d.qpos[:7] + 0.1 * a, panda.JOINT_LOWER, panda.JOINT_UPPER)
    mujoco.mj_step(m, d, nstep=env.config.substeps)
  return world_lib.stack_nodes(nodes), np.stack(actions)


@pytest.fixture(scope='module')
def push(env):
  return _push(env)


# ---- conversions ----

def test_single_node_round_trip_is_exact(env):
  node = _random_node(env, 0)
  data = mujoco.MjData(env.mj_model)
  mujoco_c.node_to_mjdata(env, node, data)
  back = mujoco_c.mjdata_to_node(env, data, node.goal, node.t)
  for a, b in zip(jax.tree.leaves(node), jax.tree.leaves(back)):
    np.testing.assert_array_equal(np.asarray(a), b)
    assert np.asarray(a).dtype == b.dtype
  with pytest.raises(ValueError, match='qpos'):
    mujoco_c.node_to_mjdata(env, node.replace(qpos=node.qpos[:5]), data)


def test_batched_round_trip_is_exact_and_matches_mj_get_state(env):
  nodes = world_lib.stack_nodes([_random_node(env, s) for s in range(3)])
  state, warm, ctrl = mujoco_c.batch_to_rollout(env, nodes)
  m = env.mj_model
  assert state.shape == (3, mujoco.mj_stateSize(m, mujoco_c.FULLPHYSICS))
  # The vectorised layout agrees with MuJoCo's own mj_getState.
  data = mujoco.MjData(m)
  for i in range(3):
    mujoco_c.node_to_mjdata(env, jax.tree.map(lambda x: x[i], nodes), data)
    want = np.zeros(state.shape[1])
    mujoco.mj_getState(m, data, want, mujoco_c.FULLPHYSICS)
    np.testing.assert_array_equal(state[i], want)
  back = mujoco_c.rollout_to_batch(env, state, warm, ctrl, nodes.goal, nodes.t)
  for a, b in zip(jax.tree.leaves(nodes), jax.tree.leaves(back)):
    np.testing.assert_array_equal(np.asarray(a), b)
  with pytest.raises(ValueError, match='qpos'):
    mujoco_c.batch_to_rollout(env, nodes.replace(qpos=nodes.qpos[:, :4]))


# ---- physics: MuJoCo C against MJX ----

def test_c_step_matches_mjx_step_along_a_push(env, push, mjx_evaluate, c_evaluate):
  nodes, actions = push
  num = len(actions)
  # The push moves the T (so contacts are exercised).
  assert np.linalg.norm(nodes.qpos[-1, 7:9] - nodes.qpos[0, 7:9]) > 0.02
  padded, padded_actions = pad_rows(nodes, BATCH), pad_rows(actions, BATCH)
  mjx_out = jax.tree.map(lambda x: np.asarray(x)[:num], mjx_evaluate(padded, padded_actions))
  c_out = jax.tree.map(lambda x: np.asarray(x)[:num], c_evaluate(padded, padded_actions))
  assert mjx_out.is_valid.all() and c_out.is_valid.all()
  dq = np.abs(mjx_out.next_node.qpos - c_out.next_node.qpos).max(0)
  dv = np.abs(mjx_out.next_node.qvel - c_out.next_node.qvel).max(0)
  print(f'\nC vs MJX, one control step: max |dqpos| arm {dq[:7].max():.2e} rad, '
        f'T {dq[7:].max():.2e}; max |dqvel| {dv.max():.2e}; '
        f'|dcost| {np.abs(mjx_out.cost - c_out.cost).max():.2e}')
  assert dq.max() < 1e-3
  # the arm's and the T's linear velocities agree to 0.1; the free T's rocking on its stiff
  # table contacts (angular x, y, z: the last three) to 0.5 rad/s
  assert dv[:10].max() < 0.1 and dv[10:].max() < 0.5
  np.testing.assert_allclose(c_out.cost, mjx_out.cost, atol=5e-3)
  np.testing.assert_array_equal(c_out.next_node.ctrl, mjx_out.next_node.ctrl)
  np.testing.assert_array_equal(c_out.next_node.t, nodes.t[:num] + 1)


# ---- the CPU backend ----

def test_evaluate_under_jit(env, cenv, c_evaluate):
  """B = 3 under jit: validity, cost = cost of the successor, NaN action / state -> invalid."""
  nodes = env.initial_nodes(jax.random.split(jax.random.PRNGKey(3), 3))
  actions = jax.random.uniform(jax.random.PRNGKey(4), (3, 7), minval=-1, maxval=1)
  actions = actions.at[1, 2].set(jnp.nan)
  out = c_evaluate(nodes, actions)
  np.testing.assert_array_equal(out.is_valid, [True, False, True])
  assert not out.is_goal[1]
  assert np.isfinite(np.asarray(out.next_node.qpos)).all()
  # The cost is the env's cost of the successor (tip by MJX forward kinematics).
  mjx_tip = jax.jit(jax.vmap(env.tip_position))(out.next_node)
  np.testing.assert_allclose(cenv.tip_position(out.next_node), mjx_tip, atol=1e-5)
  want = jax.vmap(env._cost)(out.next_node, mjx_tip)
  np.testing.assert_allclose(np.asarray(out.cost)[[0, 2]], np.asarray(want)[[0, 2]], atol=1e-5)
  obs = jax.jit(cenv.observe)(out.next_node)  # PushT's observation with the C tip
  np.testing.assert_allclose(obs[:, 14:17], mjx_tip, atol=1e-5)
  np.testing.assert_array_equal(out.is_goal, jax.vmap(env.goal_reached)(out.next_node)
                                & out.is_valid)
  # The arm moved toward its targets.
  assert np.abs(np.asarray(out.next_node.qpos[0, :7] - nodes.qpos[0, :7])).max() > 1e-3
  # A non-finite node is invalid and its successor stays finite.
  bad = nodes.replace(qvel=nodes.qvel.at[2, 0].set(jnp.inf))
  out_bad = c_evaluate(bad, jnp.zeros((3, 7)))
  np.testing.assert_array_equal(out_bad.is_valid, [True, True, False])
  assert np.isfinite(np.asarray(out_bad.next_node.qvel)).all()
  # vmap makes one batched call with the same results; transition = batched path with B = 1.
  twice = jax.jit(jax.vmap(cenv.evaluate))(jax.tree.map(lambda x: jnp.stack([x, x]), nodes),
                                           jnp.stack([actions, actions]))
  np.testing.assert_array_equal(twice.cost[1], out.cost)
  single = jax.jit(cenv.transition)(jax.tree.map(lambda x: x[0], nodes), actions[0])
  np.testing.assert_array_equal(single.next_node.qpos, out.next_node.qpos[0])
  with pytest.raises(ValueError, match='actions'):
    cenv.evaluate(nodes, actions[:, :3])


def test_delegation_and_make_backend(env, cenv):
  assert cenv.config is env.config and cenv.mj_model is env.mj_model
  assert cenv.observation_size == env.observation_size
  assert cenv.action_size == 7
  assert backends.make_backend(env, 'mjx') is env
  with pytest.raises(ValueError, match='backend'):
    backends.make_backend(env, 'gpu')
  auto = backends.make_backend(env, 'auto', nthread=1)
  assert isinstance(auto, mujoco_c.MujocoCEnv) == (jax.default_backend() == 'cpu')
  if isinstance(auto, mujoco_c.MujocoCEnv):
    auto.close()
  with pytest.raises(ValueError, match='nthread'):
    mujoco_c.MujocoCEnv(env, nthread=0)


# ---- the world ----

def test_world_executes_and_perturbations_change_the_outcome(env, push):
  nodes, actions = push
  start = jax.tree.map(lambda x: x[0], nodes)
  world = world_lib.World(env)
  assert np.array_equal(world.reset(start).qpos, np.asarray(start.qpos))
  path = world.execute(actions)
  assert len(path) == len(actions) and int(path[-1].t) == len(actions)
  # The unperturbed world replays the closed-loop push that generated the actions.
  np.testing.assert_allclose(path[-2].qpos, nodes.qpos[-1], atol=1e-6)
  ref = world_lib.World(env)
  ref.reset(start)
  np.testing.assert_array_equal(ref.execute(actions)[-1].qpos, path[-1].qpos)
  moved = np.linalg.norm(path[-1].qpos[7:9] - start.qpos[7:9])
  assert moved > 0.02
  # T-table friction and the other contacts' friction each change where the push leaves the T
  for change in (dict(friction=0.3), dict(contact_friction=0.3)):
    perturbed = world_lib.World(env, world_lib.Perturbation(**change))
    perturbed.reset(start)
    apart = np.linalg.norm(perturbed.execute(actions)[-1].qpos[7:9] - path[-1].qpos[7:9])
    assert apart > 0.01, (change, apart)
  # only the perturbed copy changes: the T-table pairs' friction x 0.3, the others' kept
  slippery = world_lib.World(env, world_lib.Perturbation(friction=0.3)).model
  t_table = np.array([world_lib._is_t_table_pair(env.mj_model, p)
                      for p in range(env.mj_model.npair)])
  assert t_table.sum() == 2
  np.testing.assert_allclose(slippery.pair_friction[t_table],
                             0.3 * env.mj_model.pair_friction[t_table])
  np.testing.assert_array_equal(slippery.pair_friction[~t_table],
                                env.mj_model.pair_friction[~t_table])
  assert env.mj_model.pair_friction[t_table][0, 0] == pytest.approx(1.65)
  heavy = world_lib.Perturbation(t_mass=2.0, actuator_gain=0.5)
  m = heavy.apply(env.mj_model)
  t_body = env.mj_model.body('tblock').id
  assert m.body_mass[t_body] == pytest.approx(2 * env.mj_model.body_mass[t_body])
  np.testing.assert_allclose(m.actuator_gainprm[:, 0], 0.5 * env.mj_model.actuator_gainprm[:, 0])
  with pytest.raises(ValueError, match='friction'):
    world_lib.Perturbation(friction=-1.0)
  with pytest.raises(ValueError, match='actions'):
    world.execute(actions[:, :3])


# ---- the search end to end ----

def test_search_on_the_cpu_backend_stops_at_its_iteration_limit(env, cenv):
  from pachs_jax.runtime import programs
  from pachs_jax.search import pachs
  from pachs_jax.search.capacity import Capacities
  from pachs_jax.search.config import SearchConfig
  from pachs_jax.search.result import StopReason
  from pachs_jax.search.baselines import replay
  starts = env.canonical_instances(2)
  # two iterations evaluate at most 2 K = 8 edges, far below the budget of 64, and no canonical
  # instance starts at its goal or is reached in two random steps: the iteration limit stops both
  config = SearchConfig(num_actions=4, pop_size=4, budget=64)
  search = pachs.make_search(cenv, UniformActorCritic(7), config,
                             capacities=Capacities(max_iterations=2))
  result = programs.plan(cenv, UniformActorCritic(7), starts, config, jax.random.PRNGKey(0),
                         search=search)
  np.testing.assert_array_equal(np.asarray(result.stop_reason), StopReason.ITERATIONS)
  np.testing.assert_array_equal(np.asarray(result.found), False)
  np.testing.assert_array_equal(np.asarray(result.iterations), 2)
  evaluated = np.asarray(result.evaluated)
  assert (evaluated >= 1).all() and (evaluated <= 2 * config.pop_size).all(), evaluated
  assert (np.asarray(result.generated) > 1).all()  # successors from MuJoCo C entered the pool
  # the returned partial paths (an edge or more) replay in MuJoCo C: valid, not at the goal,
  # the same cost
  assert (np.asarray(result.path_length) >= 1).all()
  _, cost, valid, is_goal = replay(cenv, starts, result.path_actions, result.path_length)
  np.testing.assert_array_equal(np.asarray(valid), True)
  np.testing.assert_array_equal(np.asarray(is_goal), False)
  np.testing.assert_allclose(np.asarray(cost), np.asarray(result.cost), rtol=1e-5, atol=1e-6)


def test_edges_from_a_t_outside_the_table_square_stay_open(env, c_evaluate):
  # a world can leave the T outside the square around the goal that edges must keep it in;
  # edges that leave it no farther outside stay valid, so that a plan can bring it back
  node = env.sample_instance(jax.random.PRNGKey(0))
  qpos = np.asarray(node.qpos).copy()
  qpos[7:9] = np.asarray(pusht.FIXED_GOAL[:2]) + [0.0, -pusht.TABLE_HALF_EXTENT - 0.02]
  outside = node.replace(qpos=jnp.asarray(qpos))
  nodes = jax.tree.map(lambda x: jnp.stack([x, x]), outside)
  actions = jnp.zeros((2, env.action_size), jnp.float32)  # the arm stays, the T rests
  out = c_evaluate(nodes, actions)
  np.testing.assert_array_equal(np.asarray(out.is_valid), [True, True])
  excess = pusht.box_excess(jnp.asarray([qpos, qpos]))
  np.testing.assert_allclose(excess, 0.02, atol=1e-6)
  # the rule itself: inside is fine, farther outside is not, back towards the square is
  inside = qpos.copy()
  inside[7:9] = pusht.FIXED_GOAL[:2]
  farther = qpos.copy()
  farther[8] -= 0.01
  np.testing.assert_array_equal(
      pusht.stays_on_table(jnp.asarray([inside, inside, qpos, qpos, farther]),
                           jnp.asarray([inside, qpos, farther, inside, qpos])),
      [True, False, False, True, True])
