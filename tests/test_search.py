"""PACHS on the analytic grid world: optimality, bounds, batching, replay, anytime, stops."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import assert_results_equal, take
from pachs_jax.runtime import compile_cache
from pachs_jax.envs import gridworld
from pachs_jax.search import Capacities, SearchConfig, StopReason, instance_keys, make_search
from pachs_jax.runtime.programs import Programs, plan

SIZE = 14
POCKET = (1, 12)  # a free cell walled in: unreachable from outside
NUM_FOUND = 6  # instances 0..5 have reachable goals (instance 5: start == goal)


def _grid(seed, density):
  rng = np.random.default_rng(seed)
  obstacles = rng.random((SIZE, SIZE)) < density
  obstacles[:4, 10:] = False
  obstacles[3, 10:] = True  # the pocket's walls: row 3 and column 10 around rows 0-2
  obstacles[:3, 10] = True
  return obstacles


class Problem:
  """Random far-apart start / goal pairs on a random grid, one with start == goal and one with
  the goal in the walled pocket, as one batch of instances."""

  def __init__(self, seed, density=0.28):
    self.obstacles = _grid(seed, density)
    self.env = gridworld.GridWorld(self.obstacles, connectivity=8)
    self.actor_critic = gridworld.GridActorCritic(self.env)
    rng = np.random.default_rng(seed + 100)
    outside = np.argwhere(~self.obstacles)
    outside = outside[~((outside[:, 0] < 3) & (outside[:, 1] > 10))]
    starts, goals = [], []
    while len(starts) < NUM_FOUND - 1:  # reachable, far-apart pairs
      a, b = outside[rng.choice(len(outside), 2, replace=False)]
      if np.isfinite(gridworld.shortest_path_cost(self.obstacles, tuple(a), tuple(b))) and np.abs(a - b).max() >= 7:
        starts.append(a)
        goals.append(b)
    starts.append(outside[0])
    goals.append(outside[0])  # start == goal
    starts.append(outside[1])
    goals.append(np.array(POCKET))  # unreachable
    self.starts, self.goals = np.array(starts), np.array(goals)
    self.optimal = np.array([gridworld.shortest_path_cost(self.obstacles, tuple(s), tuple(g))
                             for s, g in zip(starts, goals)])
    self.nodes = self.env.node(self.starts, self.goals)
    self.keys = instance_keys(jax.random.PRNGKey(0), len(starts))

  def subset(self, i):
    return take(self.nodes, i), self.keys[i:i + 1]


BASE = SearchConfig(weight=1.0, num_actions=8, pop_size=1, budget=3000)


@pytest.fixture(scope='module')
def problem():
  return Problem(seed=4)


@pytest.fixture(scope='module')
def config():
  return BASE


@pytest.fixture(scope='module')
def search(problem, config):
  return make_search(problem.env, problem.actor_critic, config)


@pytest.fixture(scope='module')
def base_result(problem, config, search):
  return plan(problem.env, problem.actor_critic, problem.nodes, config, problem.keys,
              search=search)


def _np(tree):
  return jax.tree.map(np.asarray, tree)


@functools.lru_cache(maxsize=None)
def _jitted_evaluate(env):
  return jax.jit(env.evaluate)


def _replay(env, result, i):
  """Replays instance i's actions from its start; checks the states and returns the cost."""
  res = _np(result)
  length = int(res.path_length[i])
  node = jax.tree.map(lambda x: x[i, :1], result.path_nodes)
  cost = np.float32(0.0)
  evaluate = _jitted_evaluate(env)
  for t in range(length):
    out = evaluate(node, jnp.asarray(res.path_actions[i, t:t + 1]))
    assert bool(out.is_valid[0])
    cost = cost + np.float32(out.cost[0])
    node = out.next_node
    for got, want in zip(jax.tree.leaves(node), jax.tree.leaves(res.path_nodes)):
      np.testing.assert_array_equal(np.asarray(got)[0], want[i, t + 1])  # bit for bit
  assert not res.path_actions[i, length:].any()
  return cost, node


def test_k1_w1_is_optimal(problem, base_result):
  res = _np(base_result)
  reachable = np.isfinite(problem.optimal)
  np.testing.assert_array_equal(res.found, reachable)
  np.testing.assert_allclose(res.cost[reachable], problem.optimal[reachable], atol=1e-4)
  np.testing.assert_array_equal(res.stop_reason[reachable], StopReason.GOAL)
  assert res.path_length[NUM_FOUND - 1] == 0 and res.cost[NUM_FOUND - 1] == 0.0
  assert res.wall_time_s > 0
  assert (res.expanded[:NUM_FOUND - 1] > 0).all() and (res.evaluated > 0).sum() >= NUM_FOUND - 1
  assert not (res.heap_overflow.any() or res.pool_overflow.any() or res.table_overflow.any())


def test_k1_w1_is_optimal_on_a_denser_grid():
  other = Problem(seed=11, density=0.36)
  res = _np(plan(other.env, other.actor_critic, other.nodes, BASE, other.keys))
  reachable = np.isfinite(other.optimal)
  np.testing.assert_array_equal(res.found, reachable)
  np.testing.assert_allclose(res.cost[reachable], other.optimal[reachable], atol=1e-4)


def test_unreachable_goal_empties_open(problem, base_result):
  res = _np(base_result)
  i = NUM_FOUND  # the pocket goal
  assert not res.found[i]
  assert res.stop_reason[i] == StopReason.OPEN_EMPTY
  # Every reachable cell was generated once (the lattice merges revisits) and expanded.
  reachable = sum(np.isfinite(gridworld.shortest_path_cost(problem.obstacles, tuple(problem.starts[i]), (r, c)))
                  for r in range(SIZE) for c in range(SIZE))
  assert res.generated[i] == reachable
  assert res.expanded[i] == reachable


def test_replay_reproduces_path_states(problem, search, base_result):
  # The run replaced the state of some open node by a cheaper one found later (its dummy
  # edges: one per new node and one per improvement), so replay covers that case too.
  state = search.run(search.init(problem.nodes, problem.keys))
  dummy_pushes = np.asarray(state.dummy_heap.size) - 1  # a heap's size counts every push
  np.testing.assert_array_equal(state.edge_heap.size,
                                BASE.num_actions * np.asarray(state.expanded))
  improvements = dummy_pushes - (np.asarray(state.pool.size) - 1)
  assert improvements.sum() > 0
  for i in range(NUM_FOUND + 1):  # the goal paths and the unreachable goal's best-state path
    cost, node = _replay(problem.env, base_result, i)
    np.testing.assert_allclose(cost, np.asarray(base_result.cost)[i], rtol=1e-6)
    assert bool(problem.env.is_goal(node)[0]) == (i < NUM_FOUND)


def test_batch_equals_one_by_one(problem, config, search, base_result):
  for i in (0, 3, NUM_FOUND):
    nodes, keys = problem.subset(i)
    single = plan(problem.env, problem.actor_critic, nodes, config, keys, search=search)
    assert_results_equal(single, take(base_result, i))


def test_anytime_chunks_equal_one_run(problem, search, base_result):
  state = search.init(problem.nodes, problem.keys)
  partial = None
  for chunk in range(1000):
    state = search.run_chunk(state, jnp.int32(4))
    if chunk == 1:
      partial = _np(search.result(state))
    if not bool(jnp.any(state.active)):
      break
  chunked = search.result(state)
  assert_results_equal(chunked, base_result)
  # Mid-run (8 iterations): unfinished instances return a replayable path to an open node.
  running = partial.stop_reason == StopReason.RUNNING
  assert running[:NUM_FOUND - 1].all()
  assert not partial.found[running].any()
  assert (partial.path_length[running] > 0).all()
  for i in np.flatnonzero(running):
    cost, _ = _replay(problem.env, jax.tree.map(jnp.asarray, partial), i)
    np.testing.assert_allclose(cost, partial.cost[i], rtol=1e-6)


def test_time_limit_returns_best_open_paths(problem, config, search):
  res = _np(plan(problem.env, problem.actor_critic, problem.nodes, config, problem.keys,
                 time_limit_s=1e-6, chunk_iterations=5, search=search))
  assert res.stop_reason[NUM_FOUND - 1] == StopReason.GOAL  # found in the first iteration
  timed_out = res.stop_reason == StopReason.TIME_LIMIT
  assert timed_out[:NUM_FOUND - 1].all()
  np.testing.assert_array_equal(res.iterations[timed_out], 5)
  assert not res.found[timed_out].any()
  assert res.path_length[timed_out].max() >= 1
  for i in np.flatnonzero(timed_out):  # paths to the states of the best OPEN entries
    cost, _ = _replay(problem.env, jax.tree.map(jnp.asarray, res), i)
    np.testing.assert_allclose(cost, res.cost[i], rtol=1e-6)


@pytest.mark.parametrize('weight', [1.5, 2.0])
def test_weighted_within_bound(problem, weight):
  config = dataclasses.replace(BASE, weight=weight)
  res = plan(problem.env, problem.actor_critic, problem.nodes, config, problem.keys)
  reachable = np.isfinite(problem.optimal)
  np.testing.assert_array_equal(np.asarray(res.found), reachable)
  cost = np.asarray(res.cost)[reachable]
  assert (cost <= weight * problem.optimal[reachable] + 1e-4).all()
  assert (cost >= problem.optimal[reachable] - 1e-4).all()
  for i in range(NUM_FOUND):
    replayed, _ = _replay(problem.env, res, i)
    np.testing.assert_allclose(replayed, cost[i], rtol=1e-6)


def test_pop_many_finds_paths_with_correct_cost(problem):
  config = dataclasses.replace(BASE, pop_size=6)
  res = plan(problem.env, problem.actor_critic, problem.nodes, config, problem.keys)
  reachable = np.isfinite(problem.optimal)
  np.testing.assert_array_equal(np.asarray(res.found), reachable)
  assert np.asarray(res.stop_reason)[NUM_FOUND] == StopReason.OPEN_EMPTY
  cost = np.asarray(res.cost)
  assert (cost[reachable] >= problem.optimal[reachable] - 1e-4).all()
  for i in range(NUM_FOUND):
    replayed, node = _replay(problem.env, res, i)
    np.testing.assert_allclose(replayed, cost[i], rtol=1e-6)
    assert bool(problem.env.is_goal(node)[0])


def test_tiny_budget_stops_on_budget(problem):
  config = dataclasses.replace(BASE, pop_size=4, budget=6)
  res = _np(plan(problem.env, problem.actor_critic, problem.nodes, config, problem.keys))
  hit = res.stop_reason == StopReason.BUDGET
  assert hit[:NUM_FOUND - 1].all()
  np.testing.assert_array_equal(res.evaluated[hit], 6)  # never more than the budget
  assert not res.found[hit].any()
  assert (res.path_length[hit] >= 1).all()  # the real-time answer: a path to an open node


def _plan_capped(problem, config, **capacities):
  """plan() of config with the search's Capacities(**capacities)."""
  search = make_search(problem.env, problem.actor_critic, config,
                       capacities=Capacities(**capacities))
  return plan(problem.env, problem.actor_critic, problem.nodes, config, problem.keys,
              search=search)


def test_tiny_pool_stops_on_capacity(problem):
  res = _np(_plan_capped(problem, BASE, pool=6))  # paths need >= 8 nodes
  hit = res.stop_reason == StopReason.CAPACITY
  assert hit[:NUM_FOUND - 1].all()
  assert (res.pool_overflow[hit] > 0).all()
  np.testing.assert_array_equal(res.generated[hit], 6)


def test_tiny_heap_stops_on_capacity(problem):
  res = _np(_plan_capped(problem, BASE, heap=20))  # R: two expansions' edges and 4 more
  hit = res.stop_reason == StopReason.CAPACITY
  assert hit[:NUM_FOUND - 1].all() and hit[NUM_FOUND]
  np.testing.assert_array_equal(res.heap_overflow[hit], 4)  # the third expansion's last 4
  np.testing.assert_array_equal(res.expanded[hit], 3)
  assert (res.evaluated[hit] <= 20).all() and not res.found[hit].any()


def test_iteration_limit(problem):
  res = _np(_plan_capped(problem, BASE, max_iterations=3))
  running = slice(0, NUM_FOUND - 1)
  np.testing.assert_array_equal(res.stop_reason[running], StopReason.ITERATIONS)
  np.testing.assert_array_equal(res.iterations[running], 3)
  # Each iteration evaluates one edge (R is never empty), after expanding at most one node.
  np.testing.assert_array_equal(res.evaluated[running], 3)
  assert ((res.expanded[running] >= 1) & (res.expanded[running] <= 3)).all()
  np.testing.assert_allclose(res.lane_utilization[running], 1.0)


LANES = dataclasses.replace(BASE, pop_size=8)


@pytest.fixture(scope='module')
def lane_search(problem):
  return make_search(problem.env, problem.actor_critic, LANES)


def test_lanes_idle_only_in_the_last_iteration(problem, lane_search):
  out = _np(lane_search.result(lane_search.run(lane_search.init(problem.nodes, problem.keys))))
  np.testing.assert_array_equal(out.found, np.isfinite(problem.optimal))
  lanes = LANES.pop_size * out.iterations
  np.testing.assert_allclose(out.lane_utilization,
                             np.where(lanes > 0, out.evaluated / np.maximum(lanes, 1), 0))
  searched = np.arange(len(problem.optimal)) != NUM_FOUND - 1  # all but start == goal
  # Here the lanes idle only in the last iteration (goal popped or OPEN empty).
  np.testing.assert_array_equal(out.evaluated[searched],
                                LANES.pop_size * (out.iterations[searched] - 1))


def test_iterations_evaluate_k_edges_while_r_holds_k(problem, lane_search):
  # Every iteration evaluates min(K, edges in R after the expansion phase) edges, and none in
  # the iteration that pops a goal.
  k, n = LANES.pop_size, LANES.num_actions
  search = lane_search
  state = search.init(problem.nodes, problem.keys)
  full = 0
  while bool(jnp.any(state.active)):
    before = _np((state.active, state.evaluated, state.expanded, state.edge_heap.count))
    state = search.run_chunk(state, jnp.int32(1))
    active, evaluated, expanded, r_size = before
    found = active & (np.asarray(state.stop_reason) == StopReason.GOAL)
    in_r = r_size + n * (np.asarray(state.expanded) - expanded)
    want = np.where(found, 0, np.minimum(k, in_r))
    delta = np.asarray(state.evaluated) - evaluated
    np.testing.assert_array_equal(delta[active], want[active])
    np.testing.assert_array_equal(delta[~active], 0)
    full += int(np.sum(active & (delta == k)))
  assert full >= 100  # the pocket instance alone runs > 100 full iterations
  assert not np.asarray(state.edge_heap.overflow + state.dummy_heap.overflow).any()


@pytest.mark.parametrize('changes,match', [
    (dict(budget=0), 'budget'), (dict(pop_size=0), 'pop_size'),
    (dict(num_actions=0), 'num_actions'), (dict(weight=-1.0), 'weight'),
    (dict(weight=float('nan')), 'weight'),
    (dict(lattice_resolution=(1.0, 0.0)), 'lattice')])
def test_config_validation(changes, match):
  with pytest.raises(ValueError, match=match):
    dataclasses.replace(BASE, **changes)


@pytest.mark.parametrize('capacities,match', [
    (dict(table=100), 'power of two'), (dict(max_iterations=-3), 'max_iterations'),
    (dict(heap=0), 'heap'), (dict(max_path_length=0), 'max_path_length')])
def test_capacities_validation(capacities, match):
  with pytest.raises(ValueError, match=match):
    Capacities(**capacities)


@pytest.mark.parametrize('config,capacities', [
    (BASE, Capacities(pool=2**30)), (dataclasses.replace(BASE, budget=2**28), None)])
def test_int32_limits_are_refused_before_any_work(problem, config, capacities):
  with pytest.raises(ValueError, match='below 2\\*\\*31'):
    make_search(problem.env, problem.actor_critic, config, capacities=capacities)
  with pytest.raises(ValueError, match='must be a Capacities'):
    make_search(problem.env, problem.actor_critic, BASE, capacities=dict(pool=6))


def test_mismatched_pieces_are_rejected(problem):
  env, ac = problem.env, problem.actor_critic
  with pytest.raises(ValueError, match='lattice_resolution'):
    make_search(env, ac, dataclasses.replace(BASE, lattice_resolution=(1.0, 1.0, 1.0)))

  class WrongShape:
    sample_actions = ac.sample_actions

    def q_values(self, obs, actions):
      return ac.q_values(obs, actions)[..., None]

  with pytest.raises(ValueError, match='q_values'):
    make_search(env, WrongShape(), BASE)
  with pytest.raises(ValueError, match='sample_actions'):
    make_search(env, object(), BASE)
  bad_start = env.node(jnp.zeros((2, 3)), jnp.zeros((2, 3)))
  with pytest.raises(ValueError, match='start_nodes'):
    plan(env, ac, bad_start, BASE, jax.random.PRNGKey(0))


def test_stand_in_critic_is_exact_on_free_moves(problem):
  env, ac = problem.env, problem.actor_critic
  sampled = env.initial_nodes(jax.random.split(jax.random.PRNGKey(1), 16))
  for cells in (sampled.qpos, sampled.goal):  # random instances start and end on free cells
    cells = np.asarray(cells).astype(int)
    assert not problem.obstacles[cells[:, 0], cells[:, 1]].any()
  obs = env.observe(problem.nodes)
  actions = ac.sample_actions(jax.random.PRNGKey(0), obs, 8)
  np.testing.assert_array_equal(np.asarray(env.move(actions[0])), env.moves)
  q = np.asarray(ac.q_values(obs, actions))
  out = env.evaluate(jax.tree.map(lambda x: jnp.repeat(x, 8, axis=0), problem.nodes),
                     actions.reshape(-1, 2))
  h = np.asarray(ac.heuristic(out.next_node.qpos, out.next_node.goal)).reshape(q.shape)
  cost = np.asarray(out.cost).reshape(q.shape)
  valid = np.asarray(out.is_valid).reshape(q.shape)
  np.testing.assert_allclose(-q[valid], (cost + h)[valid], rtol=1e-6)


def test_coarse_lattice_merges_states_and_paths_replay(problem):
  # 2 x 2 grid cells share a lattice cell, so at most (SIZE / 2)^2 nodes exist; most moves
  # land in an already closed lattice cell and are dropped.
  config = dataclasses.replace(BASE, lattice_resolution=(2.0, 2.0), pop_size=2)
  res = plan(problem.env, problem.actor_critic, problem.nodes, config, problem.keys)
  out = _np(res)
  assert (out.generated <= (SIZE // 2) ** 2).all()
  for i in range(len(out.found)):
    cost, node = _replay(problem.env, res, i)
    np.testing.assert_allclose(cost, out.cost[i], rtol=1e-6)
    assert bool(problem.env.is_goal(node)[0]) == out.found[i]


def _stopped_early(problem, config, realtime_answer):
  """(result, pool, running) of the search stopped after 4 iterations with that answer rule;
  running [I]: the instances the iteration limit stopped (at least 2)."""
  stop_early = dataclasses.replace(config, realtime_answer=realtime_answer)
  search = make_search(problem.env, problem.actor_critic, stop_early,
                       capacities=Capacities(max_iterations=4))
  state = search.run(search.init(problem.nodes, problem.keys))
  res = _np(search.result(state))
  running = res.stop_reason == StopReason.ITERATIONS
  assert running.sum() >= 2
  return res, jax.tree.map(np.asarray, state.pool), running


def _assert_path_ends_at(problem, res, pool, i, end):
  """Instance i's returned path replays to its cost and ends in pool node end's state."""
  cost, node = _replay(problem.env, jax.tree.map(jnp.asarray, res), i)
  np.testing.assert_allclose(cost, res.cost[i], rtol=1e-6)
  np.testing.assert_allclose(res.cost[i], pool.g[i, end], rtol=1e-6)
  for got, want in zip(jax.tree.leaves(node), jax.tree.leaves(pool.nodes)):
    np.testing.assert_array_equal(np.asarray(got)[0], want[i, end])


def test_min_h_realtime_answer(problem, config):
  """'min_h' returns the path to the non-start node with the least (dummy key - g), the
  answer that 'best_f' often leaves at the start early in a search."""
  best_f = _np(_plan_capped(problem, config, max_iterations=4))
  res, pool, running = _stopped_early(problem, config, 'min_h')
  # the search itself is the same; only the answer differs
  np.testing.assert_array_equal(res.evaluated, best_f.evaluated)
  for i in np.flatnonzero(running):
    size = pool.size[i]
    weighted_h = (pool.open_key[i] - pool.g[i])[1:size]
    assert size > 1 and res.path_length[i] >= 1
    ties = np.flatnonzero(weighted_h == weighted_h.min()) + 1  # ties go to the smaller g
    _assert_path_ends_at(problem, res, pool, i, int(ties[np.argmin(pool.g[i, ties])]))
  # a different answer from 'best_f' for at least one instance
  assert (res.path_length[running] != best_f.path_length[running]).any() or \
      (res.cost[running] != best_f.cost[running]).any()
  with pytest.raises(ValueError, match='realtime_answer'):
    dataclasses.replace(config, realtime_answer='closest')
  with pytest.raises(ValueError, match='weight > 0'):
    dataclasses.replace(config, weight=0.0, realtime_answer='min_h')


def test_min_cost_realtime_answer(problem, config):
  """'min_cost' returns the path to the non-start node whose incoming edge costs least per
  transition (ties to the smaller g)."""
  res, pool, running = _stopped_early(problem, config, 'min_cost')
  for i in np.flatnonzero(running):
    size = pool.size[i]
    parent = pool.parent[i, 1:size]
    per_step = ((pool.g[i, 1:size] - pool.g[i, parent])
                / (pool.depth[i, 1:size] - pool.depth[i, parent]))
    ties = np.flatnonzero(per_step == per_step.min()) + 1
    _assert_path_ends_at(problem, res, pool, i, int(ties[np.argmin(pool.g[i, ties])]))


def test_min_cost_answer_takes_the_cheapest_edge_per_transition():
  # a hand-made pool: the 8-transition edges into nodes 4 and 5 cost 0.375 per transition, the
  # least, and node 5 has the smaller g (11 against 15); node 3's one-step edge costs 0.5, as
  # do node 2's 8 transitions; node 1's cost 1.0
  from pachs_jax.search import path as path_lib
  from pachs_jax.search import pool as pool_lib
  env = gridworld.GridWorld(np.zeros((3, 3), bool))
  pool = pool_lib.init(env.node(np.zeros((1, 2)), np.ones((1, 2))), jnp.zeros(1, bool), 8, 2, 2)
  pool = pool.replace(
      g=jnp.array([[0.0, 8.0, 12.0, 0.5, 15.0, 11.0, 0.0, 0.0]]),
      parent=jnp.array([[-1, 0, 1, 0, 2, 1, -1, -1]], jnp.int32),
      depth=jnp.array([[0, 8, 16, 1, 24, 16, 0, 0]], jnp.int32),
      size=jnp.array([6], jnp.int32))
  value, has = path_lib.min_cost_answer(pool, slots=3)
  assert bool(has[0]) and int(value[0]) == 5 * 3
  # only the start: no answer
  _, has = path_lib.min_cost_answer(pool.replace(size=jnp.array([1], jnp.int32)), slots=3)
  assert not bool(has[0])
  # min_h on the same pool: w * h = key - g, least (0) at node 3 among the generated nodes
  # (the start excluded)
  pool = pool.replace(open_key=pool.g + jnp.array([[0.0, 4.0, 3.0, 0.0, 1.0, 2.0, 0.0, 0.0]]))
  assert int(path_lib.min_h_answer(pool, slots=3)[0][0]) == 3 * 3


def test_plans_of_one_bucket_share_compiled_programs(problem):
  # 3 and 4 instances pad to one bucket of 4 (and 3 to 8 with min_bucket 8): one compilation
  # each, and padding changes no instance's result.
  env, ac = problem.env, problem.actor_critic
  search = Programs(make_search(env, ac, BASE))
  rows = lambda tree, n: jax.tree.map(lambda x: x[:n] if jnp.ndim(x) else x, tree)
  three = plan(env, ac, rows(problem.nodes, 3), BASE, problem.keys[:3], search=search,
               min_bucket=1)
  four = plan(env, ac, rows(problem.nodes, 4), BASE, problem.keys[:4], search=search,
              min_bucket=1)
  assert list(search.compiled) == [(4, jax.default_backend())]
  assert_results_equal(three, rows(four, 3))
  eight = plan(env, ac, rows(problem.nodes, 3), BASE, problem.keys[:3], search=search,
               min_bucket=8)
  assert sorted(search.compiled) == [(4, jax.default_backend()), (8, jax.default_backend())]
  assert_results_equal(eight, three)
  assert three.found.shape == (3,)


def test_traced_loop_is_stored_and_reused(problem, base_result, tmp_path, monkeypatch):
  # A process with the cache on stores the traced programs (init, loop, result: jax.export)
  # and, on an accelerator, their executables; a new Search with the same fingerprint loads
  # the executables (else compiles the stored traces) without tracing and plans identically;
  # another config is other programs; a program with a host callback is compiled as usual.
  env, ac = problem.env, problem.actor_critic
  monkeypatch.setattr(type(env), 'fingerprint', property(lambda self: 'grid seed 4'))
  monkeypatch.setattr(type(ac), 'fingerprint', 'grid critic', raising=False)
  previous = jax.config.jax_compilation_cache_dir
  jax.config.update('jax_compilation_cache_dir', str(tmp_path))
  stored = lambda: sorted(p.name for p in (tmp_path / 'traces').iterdir())
  programs = lambda: {name.split('.')[0] for name in stored()}
  try:
    first = plan(env, ac, problem.nodes, BASE, problem.keys, search=make_search(env, ac, BASE))
    kinds = {'exported'} if jax.default_backend() == 'cpu' else {'executable', 'exported'}
    assert len(programs()) >= 3 and {n.split('.')[1] for n in stored()} == kinds, stored()
    assert len(stored()) == len(programs()) * len(kinds)
    export, deserialize, lattice_key = (jax.export.export, jax.export.deserialize,
                                        type(env).lattice_key)
    monkeypatch.setattr(jax.export, 'export', lambda *a, **k: pytest.fail('traced again'))
    monkeypatch.setattr(type(env), 'lattice_key', lambda *a: pytest.fail('init traced again'))
    if len(kinds) == 2:  # the executables are loaded: the traces are not even read
      monkeypatch.setattr(jax.export, 'deserialize', lambda *a, **k: pytest.fail('compiled'))
    again = plan(env, ac, problem.nodes, BASE, problem.keys, search=make_search(env, ac, BASE))
    assert_results_equal(again, first)
    assert_results_equal(first, base_result)
    monkeypatch.setattr(jax.export, 'deserialize', deserialize)
    if len(kinds) == 2:  # without the executables: compiled from the traces, and stored again
      executables = [tmp_path / 'traces' / n for n in stored() if n.endswith('.executable')]
      for path in executables:
        path.unlink()
      from_trace = plan(env, ac, problem.nodes, BASE, problem.keys,
                        search=make_search(env, ac, BASE))
      assert_results_equal(from_trace, first)
      assert all(path.exists() for path in executables)
    monkeypatch.setattr(jax.export, 'export', export)
    monkeypatch.setattr(type(env), 'lattice_key', lattice_key)
    before = programs()
    other = dataclasses.replace(BASE, weight=2.0)
    plan(env, ac, problem.nodes, other, problem.keys, search=make_search(env, ac, other))
    assert len(programs() - before) >= 3
    callback = jax.jit(lambda x: jax.pure_callback(np.sin, x, x))
    x = jnp.arange(3.0)
    fn = compile_cache.compiled_program(callback, (x,), 'sin')
    np.testing.assert_allclose(fn(x), np.sin(np.arange(3.0)), rtol=1e-6)
    assert any(p.name.endswith('.unexportable') for p in (tmp_path / 'traces').iterdir())
  finally:
    jax.config.update('jax_compilation_cache_dir', previous)


class _OneMove:
  """The grid's stand-in actor-critic, its actor proposing the first move alone."""

  def __init__(self, actor_critic):
    self.actor_critic = actor_critic

  def sample_actions(self, key, obs, num):
    return jnp.broadcast_to(self.actor_critic.env.moves[0], obs.shape[:-1] + (num, 2))

  def q_values(self, obs, actions):
    return self.actor_critic.q_values(obs, actions)


def test_uniform_share_leaves_where_the_actor_cannot(problem):
  """An actor that proposes one move leaves the far-apart instances unsolved (OPEN empties);
  with half of the search's draws uniform over the action box some are solved (a node's few
  draws can still miss the move a wall leaves open), and their paths replay; `UniformMix`
  draws the share it is given."""
  from pachs_jax.search import model as model_lib
  one_move = _OneMove(problem.actor_critic)
  far = np.arange(NUM_FOUND - 1)
  config = dataclasses.replace(BASE, num_actions=8)
  alone = _np(plan(problem.env, one_move, problem.nodes, config, problem.keys))
  mixed = plan(problem.env, one_move, problem.nodes,
               dataclasses.replace(config, uniform_share=0.5), problem.keys)
  assert not alone.found[far].any()
  assert set(alone.stop_reason[far].tolist()) == {int(StopReason.OPEN_EMPTY)}
  solved = far[np.asarray(mixed.found)[far]]
  assert len(solved) >= 2
  for i in solved:
    cost, _ = _replay(problem.env, mixed, i)
    np.testing.assert_allclose(cost, np.asarray(mixed.cost)[i], rtol=1e-5)
  assert model_lib.with_uniform_actions(one_move, 0.0) is one_move
  obs = jnp.zeros((4096, 4))
  drawn = model_lib.with_uniform_actions(one_move, 0.25).sample_actions(
      jax.random.PRNGKey(1), obs, 2)
  uniform = np.any(np.asarray(drawn) != problem.env.moves[0], axis=-1)
  assert abs(uniform.mean() - 0.25) < 0.02 and np.abs(np.asarray(drawn)).max() <= 1.0
  with pytest.raises(ValueError, match=r'uniform_share must be a number in \[0, 1\]'):
    dataclasses.replace(config, uniform_share=1.5)
