"""Edges of several transitions (SearchConfig.edge_steps, search/segment.py) and rollout lanes
(SearchConfig.rollout_share) on the grid world,
with a stochastic actor: paths replay exactly, segments stop at a goal and before an invalid
step, the budget counts every transition, and compaction does not change the result."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import assert_results_equal
from pachs_jax import planner
from pachs_jax.envs import gridworld
from pachs_jax.search import SearchConfig, StopReason, make_search
from pachs_jax.runtime.programs import Programs, plan
from pachs_jax.runtime import sharding
from pachs_jax.search import capacity, segment

OBSTACLES = np.zeros((12, 12), bool)
OBSTACLES[2:10, 6] = True  # a wall with gaps at both ends
STARTS = np.array([[5, 1], [0, 0], [11, 11], [5, 4], [9, 2], [3, 3]])
GOALS = np.array([[5, 10], [11, 11], [0, 0], [5, 5], [1, 10], [3, 3]])


class NoisyGridActor(gridworld.GridActorCritic):
  """The grid's stand-in critic with a stochastic actor: moves drawn with probabilities
  softmax(Q), so that the actor's steps inside a segment depend on the key."""

  def sample_actions(self, key, obs, num):
    moves = super().sample_actions(key, obs, 8)  # [B, 8, 2]
    logits = self.q_values(obs, moves)
    pick = jax.random.categorical(key, logits[:, None, :], shape=(obs.shape[0], num))
    return jnp.take_along_axis(moves, pick[..., None], axis=1)


@pytest.fixture(scope='module')
def grid():
  env = gridworld.GridWorld(OBSTACLES, connectivity=8)
  return env, NoisyGridActor(env), env.node(STARTS, GOALS)


CONFIG = SearchConfig(weight=1.0, num_actions=8, pop_size=4, budget=3000, edge_steps=3)


@pytest.fixture(scope='module')
def result(grid):
  env, ac, nodes = grid
  return plan(env, ac, nodes, CONFIG, jax.random.PRNGKey(2))


def _replay(env, result, i):
  """Steps instance i's path actions one at a time; returns (cost, final node) after checking
  every state against path_nodes bit for bit."""
  r = jax.tree.map(np.asarray, result)
  node = jax.tree.map(lambda x: x[i, :1], result.path_nodes)
  cost = 0.0
  for t in range(int(r.path_length[i])):
    out = env.evaluate(node, jnp.asarray(r.path_actions[i, t:t + 1]))
    assert bool(out.is_valid[0])
    cost += float(out.cost[0])
    node = out.next_node
    for got, want in zip(jax.tree.leaves(node), jax.tree.leaves(r.path_nodes)):
      np.testing.assert_array_equal(np.asarray(got)[0], want[i, t + 1])
  assert not r.path_actions[i, int(r.path_length[i]):].any()
  return cost, node


def test_segment_paths_replay_and_end_at_goals(grid, result):
  env, _, _ = grid
  r = jax.tree.map(np.asarray, result)
  assert r.found.all(), r.stop_reason
  lengths = r.path_length[:-1]  # the last instance starts at its goal
  assert (lengths % CONFIG.edge_steps != 0).any()  # some segment stopped at the goal
  for i in range(len(STARTS)):
    cost, node = _replay(env, result, i)
    np.testing.assert_allclose(cost, r.cost[i], rtol=1e-6)
    assert bool(env.is_goal(node)[0])
  # every evaluated edge costs H transitions
  assert (r.evaluated % CONFIG.edge_steps == 0).all() and (r.evaluated <= 3000).all()
  np.testing.assert_allclose(r.lane_utilization[:-1],
                             r.evaluated[:-1] / (CONFIG.pop_size * 3 * r.iterations[:-1]))


def test_segment_stops_at_goal_and_before_an_invalid_step(grid):
  env, ac, _ = grid
  fn = jax.jit(segment.make_segment_fn(env, ac, 4))
  # lane 0: one step from its goal; lane 1: the first step hits the wall; lane 2: free to go
  nodes = env.node(np.array([[5, 4], [5, 5], [0, 0]]), np.array([[5, 5], [5, 10], [0, 5]]))
  actions = jnp.array([[0.0, 1.0], [0.0, 1.0], [0.0, 1.0]])
  keys = jax.random.split(jax.random.PRNGKey(0), 3)
  out = jax.tree.map(np.asarray, fn(nodes, (actions, keys)))
  assert out.length[0] == 1 and out.is_goal[0] and out.is_valid[0]
  assert out.length[1] == 0 and not out.is_valid[1] and out.cost[1] == 0
  assert out.is_valid[2] and out.length[2] == 4 and out.cost[2] >= 4
  # past the length the inner actions are zero and the inner states repeat the last state
  assert not out.actions[0].any()
  np.testing.assert_array_equal(out.nodes.qpos[0], np.broadcast_to([5.0, 5.0], (3, 2)))
  np.testing.assert_array_equal(out.nodes.qpos[1], np.broadcast_to([5.0, 5.0], (3, 2)))
  np.testing.assert_array_equal(out.next_node.qpos[:2], [[5.0, 5.0], [5.0, 5.0]])
  # h: the critic's cost-to-go at the last state, at least the octile distance left (5)
  assert out.h[1] >= 5.0 and np.isfinite(out.h).all()


def test_budget_counts_every_transition(grid):
  env, ac, nodes = grid
  config = dataclasses.replace(CONFIG, budget=10, edge_steps=4, pop_size=1)
  r = jax.tree.map(np.asarray, plan(env, ac, nodes, config, jax.random.PRNGKey(0)))
  far = r.path_length[:3] > 8
  assert (r.evaluated <= 10).all() and (r.evaluated % 4 == 0).all()
  assert (r.stop_reason[:3][far] == StopReason.BUDGET).all()


@pytest.mark.parametrize('share, restart, sharded', [(0.0, 'start', False), (0.5, 'novel', True)])
def test_segments_with_compaction_equal_without(grid, share, restart, sharded):
  """Compacted evaluation (smaller physics batches as instances stop) gives the uncompacted
  result leaf for leaf, for the original algorithm's chains (no rollout lanes, restarts at the
  start) and the default's (rollout lanes, restarts at novel nodes); the default's also inside
  shard_map (the default mesh)."""
  env, ac, nodes = grid
  key = jax.random.PRNGKey(2)
  config = dataclasses.replace(CONFIG, rollout_share=share, chain_restart=restart)
  # one smaller batch (two: test_compact.py); without shrinking the whole search runs in the
  # full batch's loop, which the compacted search also runs first (one program for both;
  # test_compact.py checks that this equals a config without compaction)
  compacted = dataclasses.replace(config, compact_fractions=(0.5,))
  search = Programs(make_search(env, ac, compacted))
  want = plan(env, ac, nodes, compacted, key, search=search, shrink=False)
  got = plan(env, ac, nodes, compacted, key, search=search)
  assert len(set(np.asarray(want.iterations).tolist())) > 2
  loops = [name for name in search.compiled[(8, jax.default_backend())] if isinstance(name, tuple)]
  assert len(loops) == 2, loops  # the full batch's loop (both calls) and the half batch's
  assert_results_equal(got, want)
  if sharded:
    sharded = sharding.plan_sharded(env, ac, nodes, compacted, key, search=search.search)
    assert_results_equal(sharded, want)


@pytest.mark.parametrize('changes, match', [
    (dict(edge_steps=0), 'edge_steps'),
    (dict(edge_steps=2.5), 'edge_steps'),
    (dict(edge_steps=3001), 'exceeds budget'),
    (dict(pop_size=300_000_000, edge_steps=8), 'pop_size \\* edge_steps must stay below'),
])
def test_edge_steps_validation(changes, match):
  with pytest.raises(ValueError, match=match):
    dataclasses.replace(CONFIG, **changes)


def test_pool_and_heaps_are_sized_per_edge():
  sizes = capacity.sizes(None, CONFIG.budget, CONFIG.num_actions + 1,
                         CONFIG.edge_steps, heap_per_node=CONFIG.num_actions)
  assert sizes.pool == 3000 // 3 + 1
  assert sizes.dummy_heap == 1001
  assert sizes.heap == 8 * 1001


def test_algorithms_are_named():
  default = planner.default_config('pusht-obs')
  original = planner.default_config('pusht-obs', 'original')
  assert (default.edge_steps, default.rollout_lanes) == (8, 56)
  assert (original.edge_steps, original.rollout_lanes) == (1, 0)
  assert (default.chain_restart, original.chain_restart) == ('novel', 'start')
  assert planner.default_config('pusht-obs', pop_size=4).rollout_lanes == 3
  assert planner.default_config('pusht-fixed').rollout_lanes == 0
  assert original.pop_size == 256 and original.lattice_resolution == (0.005, 0.005, 0.05,
                                                                      0.01, 0.01)
  assert planner.default_config('pusht-fixed', 'original').edge_steps == 1
  assert planner.default_config(None, 'original').edge_steps == 1
  with pytest.raises(ValueError, match="unknown algorithm 'astar'; valid: pachs, original"):
    planner.default_config('pusht-fixed', 'astar')


def test_rollout_lanes_paths_replay_and_a_chain_goal_ends_the_search(grid):
  env, ac, nodes = grid
  config = dataclasses.replace(CONFIG, rollout_share=0.5)
  search = make_search(env, ac, config)
  state = search.run(search.init(nodes, jax.random.split(jax.random.PRNGKey(3), len(STARTS))))
  result = jax.tree.map(np.asarray, search.result(state))
  assert result.found.all(), result.stop_reason
  assert state.chain.shape == (len(STARTS), 2)
  for i in range(len(STARTS)):
    cost, node = _replay(env, search.result(state), i)
    np.testing.assert_allclose(cost, result.cost[i], rtol=1e-6)
    assert bool(env.is_goal(node)[0])


def test_a_chain_goal_ends_the_search_at_once(grid):
  env, _, _ = grid
  ac = gridworld.GridActorCritic(env)  # its one sample is the first move
  start = np.array([[4, 4]])
  node = env.node(start, start + np.asarray(env.moves)[:1])
  one = SearchConfig(weight=1.0, num_actions=8, pop_size=2, budget=100)
  popped = jax.tree.map(np.asarray, plan(env, ac, node, one, jax.random.PRNGKey(0)))
  chained = jax.tree.map(np.asarray, plan(env, ac, node,
                                          dataclasses.replace(one, rollout_share=0.5),
                                          jax.random.PRNGKey(0)))
  # without chains the goal ends the search when its dummy edge is popped (iteration 2); a
  # chain's goal ends it when generated
  assert popped.found[0] and popped.iterations[0] == 2
  assert chained.found[0] and chained.iterations[0] == 1 and chained.path_length[0] == 1


@pytest.mark.parametrize('share', [-0.1, 1.0, '0.5', True, float('nan')])
def test_rollout_share_validation(share):
  with pytest.raises(ValueError, match='rollout_share'):
    dataclasses.replace(CONFIG, rollout_share=share)
