"""Chains that restart at rarely visited coarse cells (SearchConfig.chain_restart='novel',
search/novelty.py): the visit counts, the draw's weights, and the search on the grid world."""


import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pachs_jax.envs import gridworld
from pachs_jax.search import SearchConfig, make_search, novelty
from pachs_jax.search import rules as rules_lib

from test_segment import GOALS, OBSTACLES, STARTS, NoisyGridActor, _replay


def test_add_counts_new_nodes_in_their_cells():
  visits = novelty.init(jnp.array([5, 2]), pool_size=6, num_cells=8)
  node = jnp.array([[1, 2, 3], [1, 2, 3]])
  new = jnp.array([[True, True, False], [True, False, False]])
  cell = jnp.array([[5, 7, 7], [0, 0, 1]])
  visits = jax.tree.map(np.asarray, novelty.add(visits, node, new, cell))
  np.testing.assert_array_equal(visits.nodes_per_cell, [[0, 0, 0, 0, 0, 2, 0, 1],
                                                        [1, 0, 1, 0, 0, 0, 0, 0]])
  np.testing.assert_array_equal(visits.node_cell, [[5, 5, 7, -1, -1, -1],
                                                   [2, 0, -1, -1, -1, -1]])
  with pytest.raises(ValueError, match='power of two'):
    novelty.init(jnp.array([0]), pool_size=6, num_cells=12)


def test_sample_weighs_each_cell_by_one_over_the_root_of_its_count():
  # instance 0: nodes 0-2 share cell 4 (3 nodes), node 3 alone in cell 1, node 4 not eligible,
  # node 5 unused; instance 1: nothing eligible
  visits = novelty.Visits(
      nodes_per_cell=jnp.zeros((2, 8), jnp.int32).at[0, 4].set(3).at[0, 1].set(1)
      .at[0, 6].set(1),
      node_cell=jnp.array([[4, 4, 4, 1, 6, -1], [0, 0, 0, 0, 0, 0]]))
  eligible = jnp.array([[True, True, True, True, False, True], [False] * 6])
  keys = jax.random.split(jax.random.PRNGKey(0), 2)
  drawn = np.asarray(novelty.sample(visits, keys, eligible, 40_000))
  share = np.bincount(drawn[0], minlength=6) / drawn.shape[1]
  # cell 4 weighs 1 / sqrt(3), shared by its three nodes; cell 1 weighs 1
  cell_4 = 3**-0.5 / (3**-0.5 + 1)
  np.testing.assert_allclose(share, [cell_4 / 3] * 3 + [1 - cell_4, 0, 0], atol=0.01)
  assert (drawn[1] == 0).all()


def test_sample_never_draws_a_node_of_weight_zero_in_a_large_pool():
  # 12,500 nodes, most in crowded cells, one in five eligible: every draw is eligible
  pool_size, num_cells = 12_500, 2**15
  rng = np.random.default_rng(0)
  node_cell = rng.integers(0, 64, pool_size).astype(np.int32)
  node_cell[6_000:] = novelty.NO_CELL
  visits = novelty.Visits(
      nodes_per_cell=jnp.asarray(np.bincount(node_cell[:6_000], minlength=num_cells)[None]
                                 .astype(np.int32)),
      node_cell=jnp.asarray(node_cell[None]))
  eligible = jnp.asarray((rng.random(pool_size) < 0.2)[None])
  keys = jax.random.PRNGKey(1)[None]
  drawn = np.asarray(novelty.sample(visits, keys, eligible, 200_000))[0]
  ok = np.asarray(eligible)[0] & (node_cell != novelty.NO_CELL)
  assert ok[drawn].all()
  assert len(np.unique(drawn)) > 0.9 * ok.sum()


def test_below_is_the_high_word_of_random_bits_times_the_bound():
  key = jax.random.PRNGKey(5)
  bits = np.asarray(jax.random.bits(key, (50_000,), jnp.uint32)).astype(np.uint64)
  for bound in (1, 3, 65_537, 805_306_362, 2**31 - 1):
    drawn = np.asarray(novelty.below(key, jnp.int32(bound), 50_000))
    np.testing.assert_array_equal(drawn, (bits * np.uint64(bound)) >> np.uint64(32))


def test_draw_follows_its_weights_at_a_total_where_randint_is_biased():
  # three equal thirds of a total of 805,306,362: jax.random.randint(0, total) reduces one
  # word modulo the total and draws the first third 37.5% of the time
  weight = jnp.array([[268_435_455] + [67_108_863] * 4 + [268_435_455, 0]], jnp.int32)
  drawn = np.asarray(novelty.draw(weight, jax.random.PRNGKey(0)[None], 200_000))[0]
  share = np.bincount(drawn, minlength=7) / drawn.size
  np.testing.assert_allclose([share[0], share[1:5].sum(), share[5]], [1 / 3] * 3, atol=0.005)


@pytest.fixture(scope='module')
def novel_search():
  env = gridworld.GridWorld(OBSTACLES, connectivity=8, episode_length=24)
  ac = NoisyGridActor(env)
  config = SearchConfig(weight=1.0, num_actions=8, pop_size=4, budget=3000,
                        edge_steps=3, rollout_share=0.5, chain_restart='novel')
  rules = rules_lib.from_config(env, ac, config)._replace(
      restart=rules_lib.restart_novel(coarsening=2))
  search = make_search(env, ac, config, rules=rules)
  nodes = env.node(STARTS, GOALS)
  state = search.run(search.init(nodes, jax.random.split(jax.random.PRNGKey(3), len(STARTS))))
  return env, config, search, state


def test_novel_restarts_find_goals_on_paths_that_replay(novel_search):
  env, _, search, state = novel_search
  result = search.result(state)
  assert np.asarray(result.found).all(), result.stop_reason
  for i in range(len(STARTS)):
    cost, node = _replay(env, result, i)
    np.testing.assert_allclose(cost, np.asarray(result.cost)[i], rtol=1e-6)
    assert bool(env.is_goal(node)[0])


def test_every_node_is_counted_in_its_coarse_cell(novel_search):
  env, _, _, state = novel_search
  pool = state.pool
  num_cells = 2**11  # the power of two >= 2 x (3000 // 3 + 1) nodes
  assert state.visits.nodes_per_cell.shape[1] == num_cells
  cells = novelty.coarse_cells(env.lattice_key(jax.tree.map(lambda x: x.reshape(
      (-1,) + x.shape[2:]), pool.nodes)), 2, num_cells).reshape(pool.g.shape)
  used = np.arange(pool.capacity)[None, :] < np.asarray(pool.size)[:, None]
  node_cell = np.asarray(state.visits.node_cell)
  np.testing.assert_array_equal(node_cell[used], np.asarray(cells)[used])
  assert (node_cell[~used] == novelty.NO_CELL).all()
  counts = np.asarray(state.visits.nodes_per_cell)
  for i in range(len(STARTS)):
    np.testing.assert_array_equal(
        counts[i], np.bincount(node_cell[i][used[i]], minlength=counts.shape[1]))


@pytest.mark.parametrize('restart', ['start', 'novel'])
def test_chains_restart_at_the_start_or_at_earlier_nodes_that_fit_an_episode(restart):
  # episodes of 12 transitions (4 edges of 3): chains restart every few iterations. After an
  # iteration a chain holds its new successor (a node added in it) or its restart node.
  env = gridworld.GridWorld(OBSTACLES, connectivity=8, episode_length=12)
  config = SearchConfig(weight=1.0, num_actions=8, pop_size=4, budget=3000,
                        edge_steps=3, rollout_share=0.5, chain_restart=restart)
  search = make_search(env, NoisyGridActor(env), config)
  starts, goals = np.array([[5, 1], [0, 0]]), np.array([[11, 11], [11, 0]])
  state = search.init(env.node(starts, goals), jax.random.split(jax.random.PRNGKey(1), 2))
  restarts = []
  for _ in range(12):
    size = np.asarray(state.pool.size)
    state = search.loop(state, 1)
    chain = np.asarray(state.chain)
    assert (chain < np.asarray(state.pool.size)[:, None]).all()  # nodes in use
    restarted = chain < size[:, None]
    restarts.append(chain[restarted])
    rows = np.nonzero(restarted)[0]
    depth = np.asarray(state.pool.depth)[rows, chain[restarted]]
    assert (depth + 3 <= 12).all()
    assert not np.asarray(state.pool.is_goal)[rows, chain[restarted]].any()
  restarts = np.concatenate(restarts)
  assert len(restarts) >= 4
  if restart == 'start':
    assert (restarts == 0).all()
  else:
    assert (restarts > 0).sum() >= len(restarts) // 2, restarts


def test_chain_restart_validation():
  with pytest.raises(ValueError, match='chain_restart'):
    SearchConfig(chain_restart='random')
  with pytest.raises(ValueError, match='coarsening'):
    rules_lib.restart_novel(coarsening=0)
