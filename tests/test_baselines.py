"""Planning baselines on the analytic grid world (and ePA*SE end to end on Panda-Shelf)."""

import collections
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import assert_results_equal, take

from pachs_jax.envs import gridworld
from pachs_jax.search import Capacities, StopReason
from pachs_jax.search import baselines as bl
from pachs_jax.search.baselines import common
from pachs_jax.search import instance_keys

SIZE = 10


def _obstacles():
  obstacles = np.zeros((SIZE, SIZE), bool)
  obstacles[5, 2:8] = True  # a wall across the middle
  return obstacles


def _octile(a, b):
  d = np.abs(np.asarray(a, float) - np.asarray(b, float))
  return d.max() + (math.sqrt(2.0) - 1.0) * d.min()


class Greedy(gridworld.GridActorCritic):
  """The stand-in actor-critic with a deterministic policy: the move of the best Q."""

  def deterministic_action(self, obs):
    moves = jnp.asarray(self.env.moves)
    q = self.q_values(obs, jnp.broadcast_to(moves, obs.shape[:1] + moves.shape))
    return moves[jnp.argmax(q, axis=1)]


class Oscillating(gridworld.GridActorCritic):
  """A policy that walks right on even columns and left on odd ones: valid forever, never
  reaching a goal in another row."""

  def sample_actions(self, key, obs, num):
    del key
    right = (obs[:, 1] % 2 == 0)[:, None, None]
    return jnp.broadcast_to(jnp.where(right, jnp.array([0.0, 1.0]), jnp.array([0.0, -1.0])),
                            (obs.shape[0], num, 2))


@pytest.fixture(scope='module')
def env():
  return gridworld.GridWorld(_obstacles(), connectivity=8, episode_length=30)


STARTS = np.array([[0, 0], [9, 9], [0, 5], [2, 2]], np.float32)
GOALS = np.array([[3, 7], [0, 0], [9, 5], [2, 2]], np.float32)  # the last: start == goal


@pytest.fixture(scope='module')
def start(env):
  return env.node(STARTS, GOALS)


# ---------------------------------------------------------------- single rollout


def test_single_rollout_walks_straight_to_goal(env, start):
  result = bl.make_single_rollout(env, Greedy(env))(start)
  # instance 0: an open straight line; 1: the policy walks into the wall; 3: start is the goal
  assert bool(result.found[0]) and int(result.stop_reason[0]) == StopReason.GOAL
  np.testing.assert_allclose(float(result.cost[0]), _octile(STARTS[0], GOALS[0]), rtol=1e-6)
  assert int(result.path_length[0]) == 7 and int(result.evaluated[0]) == 7
  assert not bool(result.found[1]) and int(result.stop_reason[1]) == StopReason.OPEN_EMPTY
  assert int(result.invalid[1]) == 1 and int(result.evaluated[1]) == int(result.path_length[1]) + 1
  assert bool(result.found[3]) and int(result.path_length[3]) == 0
  nodes, cost, valid, is_goal = common.replay(env, start, result.path_actions, result.path_length)
  np.testing.assert_allclose(np.asarray(cost), np.asarray(result.cost), rtol=1e-6)
  assert bool(jnp.all(valid)) and np.array_equal(np.asarray(is_goal), np.asarray(result.found))
  np.testing.assert_array_equal(np.asarray(nodes.qpos), np.asarray(result.path_nodes.qpos))


def test_replay_matches_the_edges_applied_one_by_one(env, start):
  # paths of lengths 0, 2, 5 and 1 in a buffer of 8 rows, the third one's last edge into the wall
  moves = np.array([[0, 1], [1, 0], [1, 1], [1, 0], [0, 1], [1, 1], [0, 1], [1, 0]], np.float32)
  actions = np.broadcast_to(moves, (4, 8, 2)).copy()
  actions[1] = -1.0  # from (9, 9) towards (0, 0)
  actions[2] = [1.0, 0.0]  # from (0, 5) down into the wall's row 5 at the fifth edge
  length = np.array([0, 2, 5, 1], np.int32)
  nodes, cost, valid, is_goal = jax.jit(lambda a, n: common.replay(env, start, a, n))(
      jnp.asarray(actions), jnp.asarray(length))
  evaluate = jax.jit(env.evaluate)
  for i in range(4):
    node, total, ok = take(start, i), 0.0, True  # a batch of one
    rows = [np.asarray(node.qpos)[0]]
    for t in range(length[i]):
      out = evaluate(node, jnp.asarray(actions[i, t:t + 1]))
      node, total = out.next_node, total + float(out.cost[0])
      ok = ok and bool(out.is_valid[0])
      rows.append(np.asarray(node.qpos)[0])
    rows += [rows[-1]] * (8 + 1 - len(rows))  # rows past the path repeat its last state
    np.testing.assert_array_equal(np.asarray(nodes.qpos)[i], np.stack(rows))
    np.testing.assert_allclose(float(cost[i]), total, rtol=1e-6)
    assert bool(valid[i]) == ok and bool(is_goal[i]) == bool(env.is_goal(node)[0])
  assert bool(valid[1]) and not bool(valid[2])
  # a buffer of no rows: the starts themselves
  nodes, cost, valid, _ = common.replay(env, start, jnp.zeros((4, 0, 2)), jnp.zeros(4, jnp.int32))
  np.testing.assert_array_equal(np.asarray(nodes.qpos)[:, 0], np.asarray(start.qpos))
  assert nodes.qpos.shape[1] == 1 and not np.any(np.asarray(cost)) and np.all(np.asarray(valid))


def test_single_rollout_stops_at_episode_length(env, start):
  result = bl.make_single_rollout(env, Greedy(env), bl.SingleRolloutConfig(max_steps=3))(start)
  assert int(result.stop_reason[0]) == StopReason.BUDGET and int(result.path_length[0]) == 3
  assert result.path_actions.shape == (4, 3, 2)


# ---------------------------------------------------------------- parallel rollout


def test_parallel_rollout_budget_and_restarts(env, start):
  config = bl.ParallelRolloutConfig(num_copies=3, budget=40, episode_length=5)
  rollout = bl.make_parallel_rollout(env, Oscillating(env), config)
  state = rollout.init(take(start, 0), jax.random.PRNGKey(0))
  for i in range(1, 6):
    state = rollout.step(state)
    expected = i % 5
    assert np.all(np.asarray(state.episode_step) == expected), (i, state.episode_step)
  # after 5 steps every copy restarted from the start
  np.testing.assert_array_equal(np.asarray(state.node.qpos)[0], np.repeat(STARTS[:1], 3, 0))
  assert int(state.restarts[0]) == 3
  result = rollout.result(rollout.run(state))
  assert int(result.evaluated[0]) == 40 and int(result.stop_reason[0]) == StopReason.BUDGET
  assert int(result.iterations[0]) == math.ceil(40 / 3)
  assert not bool(result.found[0]) and int(result.path_length[0]) == 5
  # the returned best-reward rollout replays validly
  _, cost, valid, _ = common.replay(env, take(start, 0), result.path_actions, result.path_length)
  assert bool(valid[0]) and np.isclose(float(cost[0]), float(result.cost[0]))


def test_parallel_rollout_compacted_steps_match_full_steps(env, start):
  # instance 3 starts at its goal: its copies leave the physics batch, and the 3 running
  # instances' 9 copies fit a batch of 9 lanes; every step matches the full batch's
  config = bl.ParallelRolloutConfig(num_copies=3, budget=40, episode_length=5)
  rollout = bl.make_parallel_rollout(env, gridworld.GridActorCritic(env), config)
  full = small = rollout.init(start, jax.random.PRNGKey(0))
  assert not bool(full.active[3])
  for _ in range(7):
    full, small = rollout.step(full), rollout.step(small, size=9)
  assert_results_equal(rollout.result(small), rollout.result(full))
  np.testing.assert_array_equal(np.asarray(small.node.qpos), np.asarray(full.node.qpos))


def test_parallel_rollout_stop_returns_an_unfinished_copy(env, start):
  # episodes of 5 steps; stopped after 3 steps no copy has finished, yet a 3-step rollout is
  # returned (TIME_LIMIT), and an instance that already stopped keeps its result
  config = bl.ParallelRolloutConfig(num_copies=3, budget=40, episode_length=5)
  rollout = bl.make_parallel_rollout(env, Oscillating(env), config)
  state = rollout.init(take(start, 0), jax.random.PRNGKey(0))
  for _ in range(3):
    state = rollout.step(state)
  assert int(state.best_length[0]) == 0  # nothing finished yet
  stopped = rollout.stop(state)
  assert not bool(stopped.active[0]) and int(stopped.stop_reason[0]) == StopReason.TIME_LIMIT
  result = rollout.result(stopped)
  assert int(result.path_length[0]) == 3 and not bool(result.found[0])
  _, cost, valid, _ = common.replay(env, take(start, 0), result.path_actions, result.path_length)
  assert bool(valid[0]) and np.isclose(float(cost[0]), float(result.cost[0]))
  again = rollout.stop(stopped)
  assert int(again.stop_reason[0]) == StopReason.TIME_LIMIT
  np.testing.assert_array_equal(np.asarray(again.best_actions), np.asarray(stopped.best_actions))


def test_parallel_rollout_finds_goal_and_batches(env):
  # the stand-in actor always proposes its first move (down): goals below the start are reached
  ac = gridworld.GridActorCritic(env)
  start = env.node(np.array([[0, 1], [6, 3], [1, 9]], np.float32),
                   np.array([[4, 1], [9, 3], [0, 0]], np.float32))
  config = bl.ParallelRolloutConfig(num_copies=4, budget=50, episode_length=6)
  rollout = bl.make_parallel_rollout(env, ac, config)
  result = rollout.plan(start, jax.random.PRNGKey(1))
  np.testing.assert_array_equal(np.asarray(result.found), [True, True, False])
  np.testing.assert_array_equal(np.asarray(result.path_length)[:2], [4, 3])
  np.testing.assert_allclose(np.asarray(result.cost)[:2], [4.0, 3.0])
  assert bool(jnp.all(result.path_is_goal[:2]))
  assert int(result.evaluated[0]) == 16 and int(result.evaluated[2]) == 50
  keys = instance_keys(jax.random.PRNGKey(1), 3)
  for i in range(3):
    assert_results_equal(rollout.plan(take(start, i), keys[i:i + 1]), take(result, i))


# ---------------------------------------------------------------- beam search


@pytest.fixture(scope='module')
def beam_search(env):
  config = bl.BeamConfig(beam_width=4, num_actions=8, budget=1000)
  return bl.make_beam_search(env, gridworld.GridActorCritic(env), config)


def test_beam_finds_replayable_paths(env, start, beam_search):
  result = beam_search(start, jax.random.PRNGKey(0))
  assert bool(jnp.all(result.found))
  for i in range(4):
    assert float(result.cost[i]) >= gridworld.shortest_path_cost(_obstacles(), tuple(STARTS[i].astype(int)),
                                              tuple(GOALS[i].astype(int))) - 1e-5
  node, total = start, np.zeros(4)
  for t in range(int(jnp.max(result.path_length))):
    out = env.evaluate(node, result.path_actions[:, t])
    live = t < np.asarray(result.path_length)
    assert np.all(np.asarray(out.is_valid)[live])
    total += np.where(live, np.asarray(out.cost), 0.0)
    node = jax.tree.map(lambda n, o: jnp.where(
        live.reshape((-1,) + (1,) * (n.ndim - 1)), n, o), out.next_node, node)
  assert bool(jnp.all(env.is_goal(node)))
  np.testing.assert_allclose(total, np.asarray(result.cost), rtol=1e-6)
  assert np.all(np.asarray(result.evaluated) <= 1000)


def test_beam_batch_equals_one_by_one(env, start, beam_search):
  keys = instance_keys(jax.random.PRNGKey(0), 4)
  result = beam_search(start, keys)
  for i in range(4):
    assert_results_equal(beam_search(take(start, i), keys[i:i + 1]), take(result, i))


def test_beam_budget_is_exact(env, start):
  config = bl.BeamConfig(beam_width=2, num_actions=8, budget=21, score='next')
  result = bl.make_beam_search(env, Greedy(env), config)(start, jax.random.PRNGKey(0))
  # instance 1 needs more than 21 evaluations (2 beam states x 8 moves per step)
  assert int(result.stop_reason[1]) == StopReason.BUDGET and int(result.evaluated[1]) == 21
  assert int(result.stop_reason[3]) == StopReason.GOAL and int(result.evaluated[3]) == 0


# ---------------------------------------------------------------- ePA*SE


def _grid_heuristic(env):
  ac = gridworld.GridActorCritic(env)
  return bl.Heuristic(init=lambda s: jnp.zeros((s.t.shape[0],)),
                      value=lambda data, n: ac.heuristic(n.qpos, n.goal))


@pytest.fixture(scope='module')
def grid_epase(env):
  return bl.make_epase(env, env.moves, _grid_heuristic(env),
                       bl.EpaseConfig(pop_size=1, budget=3000))


def test_epase_capacities_bound_its_pool(env, start, grid_epase):
  capped = bl.make_epase(env, env.moves, _grid_heuristic(env), grid_epase.config,
                         capacities=Capacities(pool=6))
  assert (grid_epase.sizes.pool, capped.sizes.pool) == (3001, 6)
  result = jax.tree.map(np.asarray, capped.plan(start))
  assert (result.generated <= 6).all()
  stopped = result.stop_reason == StopReason.CAPACITY
  assert stopped.any() and (stopped | result.found).all()
  with pytest.raises(ValueError, match='power of two'):
    bl.make_epase(env, env.moves, _grid_heuristic(env), capacities=Capacities(table=100))


def test_epase_k1_is_optimal_and_batches(env, start, grid_epase):
  result = grid_epase.plan(start)
  assert bool(jnp.all(result.found)) and bool(jnp.all(result.path_is_goal))
  for i in range(4):
    want = gridworld.shortest_path_cost(_obstacles(), tuple(STARTS[i].astype(int)), tuple(GOALS[i].astype(int)))
    np.testing.assert_allclose(float(result.cost[i]), want, rtol=1e-5)
  _, cost, valid, is_goal = common.replay(env, start, result.path_actions, result.path_length)
  assert bool(jnp.all(valid & is_goal))
  np.testing.assert_allclose(np.asarray(cost), np.asarray(result.cost), rtol=1e-5)
  assert_results_equal(grid_epase.plan(take(start, 1)), take(result, 1))


def _python_bfs(blocked, goal, connectivity):
  blocked = blocked.copy()
  blocked[goal] = False
  if connectivity == 6:
    moves = [m for m in np.ndindex(3, 3, 3) if sum(abs(v - 1) for v in m) == 1]
  else:
    moves = [m for m in np.ndindex(3, 3, 3) if m != (1, 1, 1)]
  dist = np.full(blocked.shape, np.inf)
  dist[goal] = 0
  queue = collections.deque([goal])
  while queue:
    c = queue.popleft()
    for m in moves:
      n = tuple(c[i] + m[i] - 1 for i in range(3))
      if all(0 <= n[i] < blocked.shape[i] for i in range(3)) and not blocked[n] and \
          dist[n] == np.inf:
        dist[n] = dist[c] + 1
        queue.append(n)
  return dist


@pytest.mark.parametrize('connectivity', [6, 26])
def test_bfs_matches_python_bfs(connectivity):
  rng = np.random.default_rng(3)
  blocked = rng.random((7, 6, 5)) < 0.3
  blocked[:, 3, :] = True
  blocked[3, 3, 2] = False  # one hole in a wall
  goal = (1, 1, 1)
  got = np.asarray(bl.bfs_distance(blocked, jnp.array(goal), connectivity))
  want = _python_bfs(blocked, goal, connectivity)
  np.testing.assert_array_equal(got, want)
  assert np.isinf(want).any() and np.isfinite(want[:, 5]).any()


def test_grid_heuristic_spread_into_blocked_cells():
  # a 1-D corridor along x with a wall of 2 blocked cells at x = 4, 5 (and a free way around
  # through y = 1): without spread the wall reads `unreachable`, with spread 2 it reads the
  # nearest free neighbour's distance + 1 cell per layer
  grid = bl.VoxelGrid((0.0, 0.0, 0.0), 0.1, (9, 2, 1))
  blocked = np.zeros((9, 2, 1), bool)
  blocked[4:6, 0, 0] = True
  goal = np.array([0.05, 0.05, 0.05], np.float32)
  point = lambda node: node  # nodes are points here
  plain = bl.grid_heuristic(grid, blocked, point, lambda n: goal, 26, 10.0)
  spread = bl.grid_heuristic(grid, blocked, point, lambda n: goal, 26, 10.0, spread=2)
  starts = jnp.zeros((1, 3))
  cells = jnp.array([[[0.45, 0.05, 0.05], [0.55, 0.05, 0.05], [0.35, 0.05, 0.05]]])
  h_plain = np.asarray(plain.value(plain.init(starts), cells))[0]
  h_spread = np.asarray(spread.value(spread.init(starts), cells))[0]
  np.testing.assert_allclose(h_plain, [10.0, 10.0, 0.3], atol=1e-6)
  np.testing.assert_allclose(h_spread, [0.4, 0.5, 0.3], atol=1e-6)


def test_box_occupancy_inflates():
  grid = bl.VoxelGrid((0.0, 0.0, 0.0), 0.1, (5, 5, 5))
  occ = bl.box_occupancy(grid, [[0.25, 0.25, 0.25]], [[0.05, 0.05, 0.05]], 0.06)
  assert occ[2, 2, 2] and occ[1, 2, 2] and not occ[0, 2, 2] and not occ[1, 1, 1]


def test_epase_finds_a_goal_on_the_shelf():
  from pachs_jax.envs import shelf
  env = shelf.ShelfEnv()
  setup = bl.shelf_setup(env)
  start = env.initial_nodes(jax.random.split(jax.random.PRNGKey(0), 1))
  # this start needs about 1,200 evaluations at w = 10, K = 8 (1,185 when written)
  config = bl.EpaseConfig(weight=10.0, pop_size=8, budget=2000,
                          lattice_resolution=setup.lattice_resolution)
  search = bl.make_epase(env, setup.primitives, setup.heuristic, config, edge_fn=setup.edge_fn)
  state = search.init(start)
  result = search.result(search.run(state))
  assert int(result.stop_reason[0]) == StopReason.GOAL and bool(result.found[0])
  assert 0 < int(result.evaluated[0]) < 2000 and int(result.expanded[0]) > 0
  length = int(result.path_length[0])
  assert length >= 1
  replay = jax.jit(common.replay, static_argnums=0, static_argnames='edge_fn')  # one program
  _, cost, valid, is_goal = replay(env, start, result.path_actions, result.path_length,
                                   edge_fn=setup.edge_fn)
  assert bool(valid[0]) and bool(is_goal[0])
  np.testing.assert_allclose(float(cost[0]), float(result.cost[0]), rtol=1e-5)
  # each step moves one joint by +-7 degrees
  steps = np.asarray(result.path_actions[0, :length])
  assert np.all(np.sum(np.abs(steps) > 0, axis=1) == 1)
  np.testing.assert_allclose(np.abs(steps).max(axis=1), math.radians(7.0), rtol=1e-6)
  # the heuristic at the start is below the straight-line tip distance (26-connected BFS)
  h = float(jax.jit(setup.heuristic.value)(state.heuristic,
                                           jax.tree.map(lambda x: x[:, None], start))[0, 0])
  tip = np.asarray(env.tip_position(start.qpos[0]))
  assert 0 < h <= np.linalg.norm(tip - np.asarray(start.goal[0])) + 1e-6


# ---------------------------------------------------------------- validation


@pytest.mark.parametrize('make, match', [
    (lambda: bl.ParallelRolloutConfig(num_copies=0), 'num_copies'),
    (lambda: bl.ParallelRolloutConfig(fallback='mean'), 'fallback'),
    (lambda: bl.SingleRolloutConfig(max_steps=-1), 'max_steps'),
    (lambda: bl.BeamConfig(score='value'), 'score'),
    (lambda: bl.BeamConfig(weight=float('nan')), 'weight'),
    (lambda: bl.VoxelGrid((0.0, 0.0, 0.0), -1.0, (2, 2, 2)), 'cell'),
])
def test_bad_configs_raise(make, match):
  with pytest.raises(ValueError, match=match):
    make()


def test_bad_inputs_raise(env, start):
  with pytest.raises(ValueError, match='deterministic_action'):
    bl.make_single_rollout(env, gridworld.GridActorCritic(env))
  with pytest.raises(ValueError, match='motion_primitives'):
    bl.make_epase(env, np.zeros((3, 5)), bl.Heuristic(lambda s: None, lambda d, n: 0.0))
  with pytest.raises(ValueError, match='start_nodes'):
    bl.make_single_rollout(env, Greedy(env))(jax.tree.map(lambda x: x[0], start))
  with pytest.raises(ValueError, match='connectivity'):
    bl.bfs_distance(np.zeros((2, 2, 2), bool), jnp.zeros(3, jnp.int32), 8)
