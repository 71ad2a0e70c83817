"""A search that replays a known path in its first chain lane (`search.replay`), on the
analytic point mass (CPU): the lane follows the path edge by edge from the start, stops at an
edge that is not kept, and a replayed path to a goal is the search's answer."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import UniformActorCritic

from pachs_jax import replan
from pachs_jax.envs.point_mass import PointMassEnv
from pachs_jax.search import SearchConfig, make_search
from pachs_jax.search import replay as replay_lib
from pachs_jax.search.capacity import Capacities
from pachs_jax.search.result import StopReason

HORIZON = 12


def _straight_paths(env, starts, goals, moves):
  """Straight paths from starts to goals in `moves` equal moves: (start nodes [E], actions
  [E, HORIZON, 2], the paths followed in env's physics)."""
  starts, goals = np.asarray(starts, np.float32), np.asarray(goals, np.float32)
  nodes = jax.vmap(env.node_from_positions)(jnp.asarray(starts), jnp.asarray(goals))
  actions = np.zeros((len(starts), HORIZON, 2), np.float32)
  for e, m in enumerate(moves):
    if m:
      actions[e, :m] = (goals[e] - starts[e]) / (0.1 * m)
  stay = lambda obs: jnp.zeros((obs.shape[0], 2))
  followed = replan.follow(env, stay, nodes, jnp.asarray(actions),
                           jnp.asarray(moves, jnp.int32), jnp.zeros((len(starts),), bool))
  return nodes, actions, followed


@pytest.fixture(scope='module')
def env():
  return PointMassEnv()


@pytest.mark.parametrize('edge_steps', [1, 3])
def test_the_first_chain_lane_replays_the_path_edge_by_edge(env, edge_steps):
  # episode 0: 10 moves to its goal; episode 1: 7 moves of a path of 10, short of its goal;
  # episode 2: nothing to replay
  nodes, actions, path = _straight_paths(env, [[-0.3, 0.0], [0.0, -0.4], [0.2, 0.2]],
                                         [[0.3, 0.2], [0.0, 0.4], [-0.3, -0.2]], [10, 10, 0])
  length = np.array([10, 7, 0], np.int32)
  config = SearchConfig(weight=1.0, pop_size=4, num_actions=2, budget=400,
                        edge_steps=edge_steps, rollout_share=0.5, chain_restart='start')
  search = make_search(env, UniformActorCritic(2), config,
                       capacities=Capacities(replay=HORIZON))
  state = search.init(nodes, jax.random.split(jax.random.PRNGKey(0), 3), None,
                      (jnp.asarray(actions), jnp.asarray(length)))
  states = np.asarray(path.states.qpos)
  for iteration in range(1, -(-10 // edge_steps) + 1):
    state = search.run_chunk(state, 1)
    done = np.asarray(state.replay.done)
    want = np.minimum(iteration * edge_steps, length)
    np.testing.assert_array_equal(done[:2], want[:2])
    # the replaying chain's tip is where the path is after `done` actions
    tips = np.asarray(state.chain)[:, 0]
    qpos = np.asarray(state.pool.nodes.qpos)
    for e in np.flatnonzero(done < length):
      np.testing.assert_allclose(qpos[e, tips[e]], states[e, done[e]], atol=1e-5)
  assert not np.asarray(state.replay.active).any()
  out = jax.tree.map(np.asarray, search.result(state))
  # episode 0's replayed path reaches its goal: the search's answer, as followed
  assert out.found[0] and out.stop_reason[0] == StopReason.GOAL
  assert out.path_length[0] == 10
  np.testing.assert_allclose(out.path_actions[0, :10], actions[0, :10], atol=1e-6)
  np.testing.assert_allclose(out.cost[0], float(path.cost[0]), rtol=1e-5)


def test_a_replay_ends_at_an_edge_that_is_not_kept(env):
  nodes, actions, _ = _straight_paths(env, [[0.0, 0.0]], [[0.6, 0.0]], [10])
  actions[0, 5] = np.nan  # the sixth action is invalid
  config = SearchConfig(weight=1.0, pop_size=4, num_actions=2, budget=400, edge_steps=2,
                        rollout_share=0.5, chain_restart='start')
  search = make_search(env, UniformActorCritic(2), config,
                       capacities=Capacities(replay=HORIZON))
  state = search.init(nodes, jax.random.PRNGKey(1)[None], None,
                      (jnp.asarray(actions), jnp.array([10], jnp.int32)))
  for _ in range(6):
    state = search.run_chunk(state, 1)
  # edges (0, 1), (2, 3) replayed; (4, 5) stops before its invalid step (one transition
  # kept), and the next edge, from the invalid action, is not: the replay ends there
  assert not bool(state.replay.active[0]) and int(state.replay.done[0]) == 10
  assert np.all(np.isfinite(np.asarray(state.pool.nodes.qpos)[0, :int(state.pool.size[0])]))


def test_nothing_to_replay_changes_nothing(env):
  nodes, actions, _ = _straight_paths(env, [[0.0, 0.0]] * 2, [[0.3, 0.0]] * 2, [0, 0])
  config = SearchConfig(weight=1.0, pop_size=4, num_actions=4, budget=40, rollout_share=0.5,
                        chain_restart='start')
  search = make_search(env, UniformActorCritic(2), config,
                       capacities=Capacities(replay=HORIZON))
  keys = jax.random.split(jax.random.PRNGKey(3), 2)
  plain = search.result(search.run(search.init(nodes, keys)))
  replayed = search.result(search.run(search.init(
      nodes, keys, None, (jnp.asarray(actions), jnp.zeros((2,), jnp.int32)))))
  for a, b in zip(jax.tree.leaves(plain), jax.tree.leaves(replayed)):
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_a_path_longer_than_the_replay_horizon_is_refused():
  with pytest.raises(ValueError, match='exceed the search.s replay horizon 4'):
    replay_lib.init(1, 4, 2, (jnp.zeros((1, 6, 2)), jnp.array([6])))
