"""The improvement phase after the first goal (SearchConfig.after_goal='improve',
search/improve.py) on the grid world: never costlier than the first goal, within the budget and
the allowance, 'stop' as before, paths that replay, and a known shortcut found."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pachs_jax.envs import gridworld
from pachs_jax.search import SearchConfig, StopReason, make_search
from pachs_jax.search import improve, novelty
from pachs_jax.search import pool as pool_lib
from pachs_jax.search import rules as rules_lib

from test_segment import GOALS, OBSTACLES, STARTS, NoisyGridActor, _replay

CONFIG = SearchConfig(weight=1.0, num_actions=8, pop_size=4, budget=3000,
                      edge_steps=3, rollout_share=0.5, chain_restart='novel')
COARSENING = 2  # the novel restarts' coarse cells: lattice cells merged 2 to a side


def _run(config, env=None, starts=STARTS, goals=GOALS, seed=3):
  env = env or gridworld.GridWorld(OBSTACLES, connectivity=8, episode_length=24)
  actor = NoisyGridActor(env)
  rules = rules_lib.from_config(env, actor, config)
  if config.chain_restart == 'novel':
    rules = rules._replace(restart=rules_lib.restart_novel(coarsening=COARSENING))
  search = make_search(env, actor, config, rules)
  keys = jax.random.split(jax.random.PRNGKey(seed), len(starts))
  state = search.run(search.init(env.node(starts, goals), keys))
  return env, search, state, search.result(state)


@pytest.fixture(scope='module')
def runs():
  return {after: _run(dataclasses.replace(CONFIG, after_goal=after))
          for after in ('stop', 'improve')}


def test_improve_never_returns_a_costlier_path_than_the_first_goal(runs):
  stop = jax.tree.map(np.asarray, runs['stop'][3])
  better = jax.tree.map(np.asarray, runs['improve'][3])
  assert better.found.all() and stop.found.all()
  # the same search up to the first goal, which 'improve' also takes from the best-first lanes
  # at generation: no later than 'stop''s
  assert (better.first_goal_evaluated <= stop.evaluated).all()
  assert (better.cost <= better.first_goal_cost).all()
  assert (better.cost < better.first_goal_cost).sum() >= 2, (better.cost, stop.cost)
  np.testing.assert_array_equal(better.stop_reason, StopReason.GOAL)


def test_improved_paths_replay_to_a_goal_at_their_cost(runs):
  env, _, _, result = runs['improve']
  for i in range(len(STARTS)):
    cost, node = _replay(env, result, i)
    np.testing.assert_allclose(cost, np.asarray(result.cost)[i], rtol=1e-6)
    assert bool(env.is_goal(node)[0])


def test_stop_is_the_search_without_an_improvement_phase(runs):
  # after_goal='stop' stops at the first goal: the first goal's fields are the result's
  result = jax.tree.map(np.asarray, runs['stop'][3])
  np.testing.assert_array_equal(result.first_goal_evaluated, result.evaluated)
  np.testing.assert_array_equal(result.first_goal_iterations, result.iterations)
  np.testing.assert_array_equal(result.first_goal_cost, result.cost)
  assert CONFIG.after_goal == 'stop'


@pytest.mark.parametrize('allowance', [0.0, 1.0, np.inf])
def test_evaluations_stay_within_the_allowance_and_the_budget(runs, allowance):
  # allowance inf is the `runs` fixture's 'improve' search (CONFIG's budget)
  budget = CONFIG.budget
  config = dataclasses.replace(CONFIG, after_goal='improve', improve_allowance=allowance)
  result = jax.tree.map(np.asarray, (runs['improve'] if np.isinf(allowance) else _run(config))[3])
  assert (result.evaluated <= budget).all()
  solved = result.found
  first = result.first_goal_evaluated[solved]
  limit = budget if np.isinf(allowance) else np.minimum(np.ceil(first * (1 + allowance)), budget)
  assert (result.evaluated[solved] <= limit).all(), (result.evaluated, first)
  if allowance == 0:  # no improvement phase: the first goal's path
    np.testing.assert_array_equal(result.evaluated[solved], first)
    np.testing.assert_array_equal(result.cost[solved], result.first_goal_cost[solved])
  else:  # the phase spends most of what it may (an edge of 3 evaluations may not fit), unless
    # the start is the goal (cost 0: every edge is pruned)
    spent = result.evaluated[solved] >= limit - 3 * CONFIG.pop_size
    assert (spent | (result.cost[solved] == 0)).all(), (result.evaluated, limit)


def test_improve_finds_the_known_shortcut_across_an_open_field():
  # an open 12 x 12 grid: the optimal path from a corner to the opposite one is the diagonal,
  # 11 diagonal moves (cost 11 sqrt 2); the noisy actor's first goal wanders, the improvement
  # phase comes within a move of the optimum and returns the cheapest goal it generated
  env = gridworld.GridWorld(np.zeros((12, 12), bool), connectivity=8, episode_length=36)
  starts, goals = np.array([[0, 0], [11, 0]]), np.array([[11, 11], [0, 11]])
  optimal = 11 * np.sqrt(2)
  config = dataclasses.replace(CONFIG, budget=4000, after_goal='improve')
  _, _, state, result = _run(config, env, starts, goals)
  result = jax.tree.map(np.asarray, result)
  assert (result.first_goal_cost > optimal + 10).any(), result.first_goal_cost
  assert (result.cost <= optimal + 1.5).all(), result.cost
  pool = jax.tree.map(np.asarray, state.pool)
  used = np.arange(pool.capacity)[None] < pool.size[:, None]
  np.testing.assert_array_equal(result.cost, np.where(pool.is_goal & used, pool.g, np.inf).min(1))


def test_on_path_marks_the_path_of_the_incumbent():
  # node 0 <- 1 <- 3 <- 4 (node 2 elsewhere), instance 1 has no incumbent
  parent = jnp.array([[-1, 0, 0, 1, 3], [-1, 0, 1, 2, 3]])
  pool = pool_lib.NodePool(
      nodes=None, g=jnp.zeros((2, 5)), parent=parent, action=None, depth=None, closed=None,
      is_goal=None, open_key=None, edge_actions=None, edge_q=None, segment_actions=None,
      segment_nodes=None, size=jnp.array([5, 5]), overflow=None)
  mask = np.asarray(improve.on_path(pool, jnp.array([4, improve.NO_NODE])))
  np.testing.assert_array_equal(mask, [[1, 1, 0, 1, 1], [0, 0, 0, 0, 0]])


def test_path_restarts_prefer_early_nodes():
  # a path 0 -> 1 -> 2 -> 3 (goal) with g 0, 2, 6, 8: restart weights 8, 6, 2 (cost - g)
  parent = jnp.array([[-1, 0, 1, 2, 0]])
  pool = pool_lib.NodePool(
      nodes=None, g=jnp.array([[0.0, 2.0, 6.0, 8.0, 1.0]]), parent=parent, action=None,
      depth=None, closed=None, is_goal=jnp.array([[False, False, False, True, False]]),
      open_key=None, edge_actions=None, edge_q=None, segment_actions=None, segment_nodes=None,
      size=jnp.array([5]), overflow=None)
  incumbent = improve.init(1, 100).replace(node=jnp.array([3]), cost=jnp.array([8.0]))
  fits = jnp.ones((1, 5), bool)
  drawn = np.asarray(improve.path_restarts(pool, incumbent, jax.random.PRNGKey(0)[None], fits,
                                           30_000))[0]
  share = np.bincount(drawn, minlength=5) / drawn.size
  np.testing.assert_allclose(share, [8 / 16, 6 / 16, 2 / 16, 0, 0], atol=0.01)


def test_draw_never_picks_weight_zero():
  weight = jnp.array([[0, 3, 0, 1], [0, 0, 0, 0]], jnp.int32)
  drawn = np.asarray(novelty.draw(weight, jax.random.split(jax.random.PRNGKey(2), 2), 4000))
  share = np.bincount(drawn[0], minlength=4) / drawn.shape[1]
  np.testing.assert_allclose(share, [0, 0.75, 0, 0.25], atol=0.03)
  assert (drawn[1] == 0).all()


@pytest.mark.parametrize('changes, match', [
    (dict(after_goal='continue'), 'after_goal'),
    (dict(improve_allowance=-1.0), 'improve_allowance'),
    (dict(improve_allowance=float('nan')), 'improve_allowance'),
    (dict(improve_allowance=True), 'improve_allowance'),
])
def test_after_goal_validation(changes, match):
  with pytest.raises(ValueError, match=match):
    SearchConfig(**changes)


def test_open_loop_rows_report_the_first_goal_and_the_curve_counts_from_it(runs):
  import open_loop  # pylint: disable=import-outside-toplevel
  result = runs['improve'][3].replace(wall_time_s=jnp.float32(10.0))
  rows = open_loop.run_rows(result, 1, len(STARTS))
  r = jax.tree.map(np.asarray, result)
  assert [row['first_goal_evaluated'] for row in rows] == r.first_goal_evaluated.tolist()
  assert [row['evaluated'] for row in rows] == r.evaluated.tolist()
  np.testing.assert_allclose([row['first_goal_cost'] for row in rows], r.first_goal_cost)
  curve_rows = open_loop.first_goal_rows(rows)
  assert [row['evaluated'] for row in curve_rows] == r.first_goal_evaluated.tolist()
  # a planner whose first goal is its answer (no first-goal fields): its own counts
  plain = open_loop.run_rows(result.replace(first_goal_evaluated=None, first_goal_iterations=None,
                                            first_goal_cost=None), 1, len(STARTS))
  assert [row['first_goal_evaluated'] for row in plain] == r.evaluated.tolist()
