"""A search whose tree begins with a known path (`search.seed`, `pachs.plant`), on the analytic
point mass (CPU): the path's nodes, their costs and segments, and a search that answers with it."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import UniformActorCritic

from pachs_jax import replan
from pachs_jax.envs.point_mass import PointMassEnv
from pachs_jax.search import SearchConfig, make_search
from pachs_jax.search.capacity import Capacities
from pachs_jax.search import seed as seed_lib
from pachs_jax.search.result import StopReason

HORIZON = 12


def _straight_paths(env, starts, goals, moves):
  """Straight paths from starts to goals in `moves` equal moves, followed in env's physics:
  (start nodes [E], Followed [E])."""
  starts, goals = np.asarray(starts, np.float32), np.asarray(goals, np.float32)
  nodes = jax.vmap(env.node_from_positions)(jnp.asarray(starts), jnp.asarray(goals))
  actions = np.zeros((len(starts), HORIZON, 2), np.float32)
  for e, m in enumerate(moves):
    if m:
      actions[e, :m] = (goals[e] - starts[e]) / (0.1 * m)
  stay = lambda obs: jnp.zeros((obs.shape[0], 2))
  followed = replan.follow(env, stay, nodes, jnp.asarray(actions),
                           jnp.asarray(moves, jnp.int32), jnp.zeros((len(starts),), bool))
  return nodes, followed


@pytest.fixture(scope='module')
def env():
  return PointMassEnv()


@pytest.mark.parametrize('edge_steps', [1, 3])
def test_a_planted_path_is_nodes_every_h_transitions_and_answers_the_search(env, edge_steps):
  # episode 0: 10 moves to its goal (the last edge of 3 transitions holds 1); episode 1: 7
  # moves of a path of 10, short of its goal; episode 2: no path
  nodes, path = _straight_paths(env, [[-0.3, 0.0], [0.0, -0.4], [0.2, 0.2]],
                                [[0.3, 0.2], [0.0, 0.4], [-0.3, -0.2]], [10, 10, 0])
  path = path.replace(steps=jnp.array([10, 7, 0], jnp.int32))
  seed = seed_lib.Seed(actions=path.actions, states=path.states, step_cost=path.step_cost,
                       length=path.steps)
  # a budget of 2 edges: uniform proposals find no goal in it; room for the planted nodes
  config = SearchConfig(weight=1.0, pop_size=2, num_actions=2, budget=2 * edge_steps,
                        edge_steps=edge_steps)
  search = make_search(env, UniformActorCritic(2), config,
                       capacities=Capacities(planted=HORIZON))
  state = search.init(nodes, jax.random.split(jax.random.PRNGKey(0), 3), None, seed)
  pool = jax.tree.map(np.asarray, state.pool)
  # the planted nodes: one per edge of H transitions, each the child of the one before
  planted = [-(-10 // edge_steps), -(-7 // edge_steps), 0]
  np.testing.assert_array_equal(pool.size, np.add(planted, 1))
  for e in range(2):
    ends = [min((j + 1) * edge_steps, int(path.steps[e])) for j in range(planted[e])]
    rows = np.arange(1, planted[e] + 1)
    np.testing.assert_array_equal(pool.depth[e, rows], ends)
    np.testing.assert_array_equal(pool.parent[e, rows], rows - 1)
    np.testing.assert_allclose(pool.nodes.qpos[e, rows], np.asarray(path.states.qpos)[e, ends],
                               atol=1e-6)
    cum = np.concatenate([[0.0], np.cumsum(np.asarray(path.step_cost)[e])])
    np.testing.assert_allclose(pool.g[e, rows], cum[ends], rtol=1e-5)
    np.testing.assert_array_equal(pool.is_goal[e, rows], [j == planted[e] - 1 and e == 0
                                                          for j in range(planted[e])])
  # every planted node's dummy edge is in OPEN, with the start's
  np.testing.assert_array_equal(np.asarray(state.dummy_heap.size), np.add(planted, 1))
  out = jax.tree.map(np.asarray, search.result(search.run(state)))
  # episode 0 answers with the planted path to its goal, actions and cost as followed
  assert out.found[0] and out.stop_reason[0] == StopReason.GOAL
  assert out.path_length[0] == 10
  np.testing.assert_allclose(out.path_actions[0, :10], np.asarray(path.actions)[0, :10],
                             atol=1e-6)
  np.testing.assert_allclose(out.cost[0], float(path.cost[0]), rtol=1e-5)
  assert not out.found[1:].any()


def test_planting_changes_nothing_without_a_path(env):
  nodes, path = _straight_paths(env, [[0.0, 0.0]] * 2, [[0.3, 0.0]] * 2, [0, 0])
  seed = seed_lib.Seed(actions=path.actions, states=path.states, step_cost=path.step_cost,
                       length=path.steps)
  search = make_search(env, UniformActorCritic(2),
                       SearchConfig(weight=1.0, pop_size=4, num_actions=4, budget=40))
  keys = jax.random.split(jax.random.PRNGKey(3), 2)
  plain = search.result(search.run(search.init(nodes, keys)))
  planted = search.result(search.run(search.init(nodes, keys, None, seed)))
  for a, b in zip(jax.tree.leaves(plain), jax.tree.leaves(planted)):
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
