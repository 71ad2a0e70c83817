"""Panda-Shelf: geometry against MuJoCo C, edge validity, cost, goals, instances, reward."""

import itertools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from conftest import pad_rows

from pachs_jax.envs import ik, panda, shelf

NUM_CANONICAL = 4
PAD = 16  # every batched call is padded to this many rows (or GEOMETRY_PAD): one compile each
GEOMETRY_PAD = 64


@pytest.fixture(scope='module')
def env():
  return shelf.ShelfEnv()


@pytest.fixture(scope='module')
def fns(env):
  """Jitted functions shared by the tests (compiled once)."""
  return {
      'evaluate': jax.jit(env.evaluate),
      'observe': jax.jit(env.observe),
      'geometry': jax.jit(jax.vmap(env.geometry)),
      'step': jax.jit(env.step),
      'move': jax.jit(env.move, static_argnums=2),
      'reset': jax.jit(env.reset),
  }


@pytest.fixture(scope='module')
def canonical(env):
  """(NodeState [N], targets [N, 3], IK configurations [N, 7])."""
  nodes = env.canonical_instances(NUM_CANONICAL, seed=0)
  targets, configs = env.reachable_targets(NUM_CANONICAL, 0)
  return nodes, targets, configs


def _node(env, qpos, goal=(0.6, 0.0, 0.5)):
  return env.node_from(jnp.asarray(qpos, jnp.float32), jnp.asarray(goal, jnp.float32))


def _batch(node):
  return jax.tree.map(lambda x: x[None], node)


def _evaluate(fns, nodes, actions):
  b = actions.shape[0]
  out = fns['evaluate'](pad_rows(nodes, PAD), pad_rows(jnp.asarray(actions, jnp.float32), PAD))
  return jax.tree.map(lambda x: x[:b], out)


def _observe(fns, nodes):
  b = nodes.qpos.shape[0]
  return fns['observe'](pad_rows(nodes, PAD))[:b]


def _geometry(fns, qs):
  """(tips [B, 3], per-geom distances [B, G]) of configurations qs [B, 7]."""
  b = qs.shape[0]
  tips, dists = fns['geometry'](pad_rows(jnp.asarray(qs, jnp.float32), GEOMETRY_PAD))
  return np.asarray(tips[:b]), np.asarray(dists[:b])


def _one(fns, node, action):
  out = _evaluate(fns, _batch(node), np.asarray(action, np.float32)[None])
  return jax.tree.map(lambda x: x[0], out)


def _assert_finite(tree):
  for leaf in jax.tree.leaves(tree):
    if jnp.issubdtype(jnp.asarray(leaf).dtype, jnp.floating):
      assert bool(jnp.all(jnp.isfinite(leaf)))


def _c_distances(env, data, q):
  """[G] per-collision-geom min distance over the model's pairs, by MuJoCo C."""
  m = env.mj_model
  data.qpos[:] = q
  mujoco.mj_kinematics(m, data)
  out = np.full(len(env.geom_ids), shelf.FAR_DISTANCE)
  for i in range(m.npair):
    d = mujoco.mj_geomDistance(m, data, m.pair_geom1[i], m.pair_geom2[i], 10.0, None)
    out[env.pair_geom[i]] = min(out[env.pair_geom[i]], d)
  return out


def test_distances_and_tip_match_mujoco_c(env, fns):
  m, data = env.mj_model, mujoco.MjData(env.mj_model)
  rng = np.random.default_rng(0)
  qs = rng.uniform(panda.JOINT_LOWER, panda.JOINT_UPPER, (60, 7))
  tips, dists = _geometry(fns, qs)
  ref = np.array([_c_distances(env, data, q) for q in qs])
  ref_tip = []
  for q in qs:
    data.qpos[:] = q
    mujoco.mj_kinematics(m, data)
    ref_tip.append(data.site_xpos[env.tip_site].copy())
  np.testing.assert_allclose(tips, np.array(ref_tip), atol=1e-5)
  dists = np.asarray(dists)
  assert np.any(ref < 0) and np.any((ref > 0) & (ref < 0.05))  # both cases are exercised
  np.testing.assert_array_equal(dists < 0, ref < 0)
  separated = ref > 0
  np.testing.assert_allclose(dists[separated], ref[separated], atol=1e-4)


def test_mjx_kinematics_option_agrees(env):
  mjx_env = shelf.ShelfEnv(shelf.ShelfConfig(kinematics='mjx'))
  q = jnp.asarray(env.home_qpos + 0.3, jnp.float32)
  ids = env.geom_ids
  a = env._poses(q, ids)  # pylint: disable=protected-access
  b = mjx_env._poses(q, ids)  # pylint: disable=protected-access
  for x, y in zip(a, b):
    np.testing.assert_allclose(x, y, atol=1e-5)


def test_left_out_geoms_never_closer_than_kept_ones(env):
  """Joint spheres lie inside a kept capsule; base geoms do not move and stay clear of the shelf
  (the base stands on the floor); pairs left out of the model stay apart."""
  m, data = env.mj_model, mujoco.MjData(env.mj_model)
  contained = {'link3_joint': 'link2', 'link4_joint': 'link3', 'link5_joint': 'link4',
               'link6_joint': 'link4', 'link7_joint': 'link6'}
  fixed = ['link0', 'link1_joint', 'link2_joint']
  boxes = [m.geom('shelf_' + b).id for b in env.boxes]
  paired = {(int(a), int(b)) for a, b in zip(m.pair_geom1, m.pair_geom2)}
  paired |= {(b, a) for a, b in paired}
  rng = np.random.default_rng(1)
  fixed_dist = None
  for q in rng.uniform(panda.JOINT_LOWER, panda.JOINT_UPPER, (40, 7)):
    data.qpos[:] = q
    mujoco.mj_kinematics(m, data)
    dist = lambda g, b: mujoco.mj_geomDistance(m, data, m.geom(g).id, b, 10.0, None)
    for b in boxes:
      for sphere, capsule in contained.items():
        assert dist(sphere, b) >= dist(capsule, b) - 1e-6
      for g in env.config.collision_geoms:
        if (m.geom(g).id, b) not in paired:
          assert dist(g, b) > 0.0
    now = [[dist(g, b) for b in boxes if b != m.geom('shelf_floor').id] for g in fixed]
    assert np.min(now) > 0.0
    if fixed_dist is not None:
      np.testing.assert_allclose(now, fixed_dist, atol=1e-9)
    fixed_dist = now


def test_home_is_valid_and_zero_action_costs_nothing(env, fns):
  node = _node(env, env.home_qpos)
  out = _one(fns, node, np.zeros(7))
  assert bool(out.is_valid) and not bool(out.is_goal)
  assert float(out.cost) == 0.0
  _, dists = _geometry(fns, env.home_qpos[None])
  assert float(np.min(dists)) > env.config.margin
  np.testing.assert_array_equal(out.next_node.qpos, node.qpos)
  assert int(out.next_node.t) == 1


def test_moving_up_inside_a_compartment_hits_the_board_above(env, fns, canonical):
  _, targets, configs = canonical
  tip_jac = jax.jit(jax.jacfwd(env.tip_position))
  q = jnp.asarray(configs[0])
  node = _node(env, q, targets[0])
  up = np.array([0.0, 0.0, 1.0])
  for _ in range(60):
    jac = np.asarray(tip_jac(node.qpos))
    action = np.linalg.pinv(jac) @ up
    action /= np.max(np.abs(action))
    out = _one(fns, node, action)
    if not bool(out.is_valid):
      break
    node = out.next_node
  assert not bool(out.is_valid)
  q_next = np.asarray(out.next_node.qpos)
  assert np.all(q_next >= panda.JOINT_LOWER) and np.all(q_next <= panda.JOINT_UPPER)
  tip = np.asarray(env.tip_position(node.qpos))
  assert tip[2] > targets[0][2] + 0.02  # it did move up first
  # The first colliding check of the last edge touches the board above the compartment.
  frac = np.arange(1, env.config.num_checks + 1)[:, None] / env.config.num_checks
  path = np.asarray(node.qpos)[None] + frac * (q_next - np.asarray(node.qpos))[None]
  _, dists = _geometry(fns, path)
  hit = path[np.flatnonzero(np.min(dists, axis=1) < 0.0)[0]]
  row = [k for k, c in enumerate(env.compartments)
         if np.all(c[0] <= targets[0]) and np.all(targets[0] <= c[1])][0] // env.config.num_columns
  m, data = env.mj_model, mujoco.MjData(env.mj_model)
  data.qpos[:] = hit
  mujoco.mj_kinematics(m, data)
  touching = {m.geom(g).name for i in range(m.npair) for g in (m.pair_geom1[i], m.pair_geom2[i])
              if mujoco.mj_geomDistance(m, data, m.pair_geom1[i], m.pair_geom2[i], 1.0, None) < 0}
  assert f'shelf_board{row + 1}' in touching, touching


def test_motion_through_a_board_is_caught_between_checks(env, fns, canonical):
  """Both end configurations are free, the straight motion between them is not."""
  _, _, configs = canonical
  frac = np.arange(1, 6) / 5.0
  found = None
  for i, j in itertools.permutations(range(len(configs)), 2):
    path = configs[i][None] + frac[:, None] * (configs[j] - configs[i])[None]
    _, dists = _geometry(fns, path)
    mins = np.min(dists, axis=1)
    if mins[-1] > 0 and np.any(mins[:-1] < 0):
      found = i, j
      break
  assert found is not None, 'no canonical pair crosses a board'
  i, j = found
  move = fns['move']
  node = _node(env, configs[i])
  delta = jnp.asarray(configs[j] - configs[i], jnp.float32)
  assert not bool(move(node, delta, 5).is_valid)
  assert bool(move(node, delta, 1).is_valid)  # checking only the end misses the board


def test_move_matches_transition_and_rejects_bad_input(env, fns):
  node = _node(env, env.home_qpos)
  action = jnp.array([0.3, -0.2, 0.5, 0.1, -0.4, 0.2, 0.9], jnp.float32)
  moved = fns['move'](node, env.config.action_scale * action, 5)
  stepped = _one(fns, node, action)
  np.testing.assert_allclose(moved.next_node.qpos, stepped.next_node.qpos, atol=1e-7)
  np.testing.assert_allclose(moved.cost, stepped.cost, atol=1e-6)
  assert bool(moved.is_valid) and bool(stepped.is_valid)
  with pytest.raises(ValueError, match='delta must have shape'):
    fns['move'](node, jnp.zeros(3), 5)
  with pytest.raises(ValueError, match='num_checks'):
    fns['move'](node, jnp.zeros(7), 0)
  bad = fns['move'](node, jnp.full(7, jnp.nan), 5)
  assert not bool(bad.is_valid)
  _assert_finite(bad)


def test_cost_is_the_tip_displacement(env, fns):
  m, data = env.mj_model, mujoco.MjData(env.mj_model)
  keys = jax.random.split(jax.random.PRNGKey(0), 16)
  nodes = env.initial_nodes(keys)
  actions = jax.random.uniform(jax.random.PRNGKey(1), (16, 7), minval=-1.0, maxval=1.0)
  out = _evaluate(fns, nodes, actions)
  assert bool(jnp.all(out.is_valid))
  for k in range(16):
    tips = []
    for q in (nodes.qpos[k], out.next_node.qpos[k]):
      data.qpos[:] = np.asarray(q, np.float64)
      mujoco.mj_kinematics(m, data)
      tips.append(data.site_xpos[env.tip_site].copy())
    np.testing.assert_allclose(float(out.cost[k]), np.linalg.norm(tips[1] - tips[0]), atol=2e-6)
  np.testing.assert_allclose(out.next_node.qpos, nodes.qpos + 0.05 * actions, atol=1e-6)
  assert float(jnp.max(out.cost)) > 0.01


def test_ik_configuration_of_a_canonical_target_is_a_goal(env, fns, canonical):
  nodes, targets, configs = canonical
  goal_nodes = jax.vmap(env.node_from)(jnp.asarray(configs), jnp.asarray(targets))
  out = _evaluate(fns, goal_nodes, jnp.zeros((NUM_CANONICAL, 7)))
  assert bool(jnp.all(out.is_valid)) and bool(jnp.all(out.is_goal))
  assert bool(jnp.all(env.is_goal(goal_nodes)))
  assert not bool(jnp.any(env.is_goal(nodes)))  # the home start is far from every target
  # Just outside the tolerance is not a goal.
  tips = jax.vmap(env.tip_position)(jnp.asarray(configs))
  away = tips + jnp.array([0.0, 0.0, 1.01 * env.config.goal_tolerance])
  assert not bool(jnp.any(env.is_goal(goal_nodes.replace(goal=away))))


def test_observations_are_finite_and_of_the_declared_size(env, fns, canonical):
  nodes, _, configs = canonical
  obs = _observe(fns, nodes)
  assert obs.shape == (NUM_CANONICAL, env.observation_size)
  assert env.observation_size == 7 + 3 + 3 + 3 + len(env.config.collision_geoms)
  assert bool(jnp.all(jnp.isfinite(obs)))
  np.testing.assert_allclose(obs[:, 10:13], nodes.goal, atol=1e-6)
  np.testing.assert_allclose(obs[:, 13:16], obs[:, 10:13] - obs[:, 7:10], atol=1e-6)
  assert bool(jnp.all(jnp.abs(obs[:, :7]) <= 1.0))
  assert bool(jnp.all((obs[:, 16:] >= 0) & (obs[:, 16:] <= 1)))
  # At a goal configuration inside a compartment some link is within the margin.
  near = _observe(fns, jax.vmap(env.node_from)(jnp.asarray(configs), nodes.goal))
  assert float(jnp.min(near[:, 16:])) < 1.0
  bad = nodes.replace(qpos=nodes.qpos.at[0, 2].set(jnp.nan))
  assert bool(jnp.all(jnp.isfinite(_observe(fns, bad))))


def test_canonical_instances_are_deterministic_and_inside_compartments(env, canonical):
  nodes, targets, _ = canonical
  again, _ = ik.reachable_targets(env.mj_model, env.target_regions, NUM_CANONICAL, 0,
                                  home=env.home_qpos, clearance=env.config.ik_clearance,
                                  restarts=env.config.ik_restarts)
  np.testing.assert_array_equal(targets, again)
  np.testing.assert_array_equal(nodes.goal, targets)
  np.testing.assert_allclose(nodes.qpos, np.tile(env.home_qpos, (NUM_CANONICAL, 1)))
  assert nodes.goal.shape == (NUM_CANONICAL, 3) and nodes.t.shape == (NUM_CANONICAL,)
  lo, hi = env.compartments[:, 0], env.compartments[:, 1]
  inside = np.all((targets[:, None] > lo[None]) & (targets[:, None] < hi[None]), axis=2)
  assert np.all(inside.sum(axis=1) == 1)
  other, _ = env.reachable_targets(NUM_CANONICAL, 1)
  assert not np.allclose(other, targets)


def test_non_finite_action_or_state_is_invalid_and_finite(env, fns):
  node = _node(env, env.home_qpos)
  action = np.zeros(7)
  action[3] = np.nan
  out = _one(fns, node, action)
  assert not bool(out.is_valid) and not bool(out.is_goal)
  _assert_finite(out)
  bad_node = node.replace(qpos=node.qpos.at[1].set(jnp.inf))
  out = _one(fns, bad_node, np.zeros(7))
  assert not bool(out.is_valid)
  _assert_finite(out)
  lattice = env.lattice_key(_batch(bad_node))
  assert lattice.shape == (1, 7)


def test_joint_limit_is_invalid_and_actions_are_clipped(env, fns):
  q = np.array(env.home_qpos)
  q[6] = panda.JOINT_UPPER[6] - 0.01
  action = np.zeros(7)
  action[6] = 1.0
  assert not bool(_one(fns, _node(env, q), action).is_valid)
  action[6] = -1.0
  assert bool(_one(fns, _node(env, q), action).is_valid)
  big = _one(fns, _node(env, env.home_qpos), np.full(7, 5.0))
  np.testing.assert_allclose(big.next_node.qpos, env.home_qpos + 0.05, atol=1e-6)


def test_lattice_coordinates_are_discretised_joint_angles(env):
  nodes = env.initial_nodes(jax.random.split(jax.random.PRNGKey(2), 3))
  keys = env.lattice_key(nodes)
  np.testing.assert_array_equal(keys, np.floor(np.asarray(nodes.qpos) / 0.05).astype(np.int32))
  moved = nodes.replace(qpos=nodes.qpos.at[:, 0].add(0.05))
  assert np.all(np.asarray(env.lattice_key(moved))[:, 0] == np.asarray(keys)[:, 0] + 1)
  assert env.lattice_key(nodes, jnp.full(7, 0.1)).dtype == jnp.int32


def test_training_step_uses_the_dense_reward(env, fns):
  state = fns['reset'](jax.random.PRNGKey(5))
  assert state.obs.shape == (env.observation_size,)
  assert set(state.metrics) == {'success', 'cost', 'target_distance', 'min_distance'}
  action = jnp.full((7,), 0.5)
  nxt = fns['step'](state, action)
  assert set(nxt.metrics) == set(state.metrics)
  tip, dists = _geometry(fns, nxt.pipeline_state.qpos[None])
  d_target = float(np.linalg.norm(tip[0] - state.pipeline_state.goal))
  near = max(env.config.margin - float(np.min(dists)), 0.0) / env.config.margin
  np.testing.assert_allclose(float(nxt.reward), -d_target - env.config.clearance_weight * near,
                             atol=1e-5)
  assert float(nxt.done) == 0.0 and float(nxt.metrics['cost']) > 0.0
  assert float(nxt.reward) != -float(nxt.metrics['cost'])  # not the search cost
  # An invalid edge ends the episode with the invalid penalty.
  bad = fns['step'](state, jnp.full((7,), jnp.nan))
  tip0 = env.tip_position(state.pipeline_state.qpos)
  penalty = (env.config.invalid_horizon * float(jnp.linalg.norm(tip0 - state.pipeline_state.goal))
             + env.config.invalid_penalty)
  assert float(bad.done) == 1.0 and float(bad.info['truncation']) == 0.0
  np.testing.assert_allclose(float(bad.reward), -penalty, rtol=1e-5)
  assert bool(jnp.all(jnp.isfinite(bad.obs)))
  with pytest.raises(ValueError, match='actions must have shape'):
    env.step(state, jnp.zeros(6))


def test_training_targets_lie_in_the_target_regions(env):
  nodes = env.initial_nodes(jax.random.split(jax.random.PRNGKey(3), 64))
  lo, hi = env.target_regions[:, 0], env.target_regions[:, 1]
  g = np.asarray(nodes.goal)[:, None]
  inside = np.all((g >= lo[None] - 1e-6) & (g <= hi[None] + 1e-6), axis=2)
  assert np.all(inside.any(axis=1))
  assert len(np.unique(inside.argmax(axis=1))) > 3  # several compartments are used


def test_bad_configuration_and_arguments_raise_value_errors(env):
  with pytest.raises(ValueError, match='num_checks'):
    shelf.ShelfEnv(shelf.ShelfConfig(num_checks=0))
  with pytest.raises(ValueError, match='board_z'):
    shelf.ShelfEnv(shelf.ShelfConfig(board_z=(0.5, 0.2)))
  with pytest.raises(ValueError, match='collision geom'):
    shelf.ShelfEnv(shelf.ShelfConfig(collision_geoms=('link2', 'nope')))
  with pytest.raises(ValueError, match='kinematics'):
    shelf.ShelfEnv(shelf.ShelfConfig(kinematics='fast'))
  with pytest.raises(ValueError, match='num must be'):
    env.canonical_instances(0)
  with pytest.raises(ValueError, match='actions must have shape'):
    env.evaluate(env.canonical_instances(NUM_CANONICAL), jnp.zeros((NUM_CANONICAL, 3)))
