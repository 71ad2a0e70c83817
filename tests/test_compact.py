"""Compacted edge evaluation: only the live lanes are simulated, with the same outcomes, and
PACHS with compaction equals PACHS without on the grid world."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import assert_results_equal
from pachs_jax.envs import gridworld
from pachs_jax.search import SearchConfig, compact, make_search, pachs
from pachs_jax.runtime.programs import Programs, plan


def test_batch_sizes():
  assert compact.batch_sizes(64, (0.25, 0.0625, 0.25)) == (4, 16)
  assert compact.batch_sizes(64, ()) == ()
  assert compact.batch_sizes(3, (0.1, 0.99)) == (1,)  # ceil(2.97) = 3 is no smaller batch
  assert compact.batch_sizes(64, (0.25, 0.0625), minimum=8) == (16,)  # 4 < one instance's 8


@pytest.fixture(scope='module')
def lanes():
  env = gridworld.GridWorld(np.zeros((8, 8), bool), connectivity=8)
  rng = np.random.default_rng(0)
  nodes = env.node(rng.integers(0, 8, (16, 2)), rng.integers(0, 8, (16, 2)))
  actions = jnp.asarray(rng.uniform(-1, 1, (16, 2)), jnp.float32)
  return env, nodes, actions


@pytest.mark.parametrize('num_live,size', [(0, 4), (3, 4), (4, 4), (5, 8), (8, 8), (9, None),
                                           (16, None)])
def test_evaluate_live_matches_full_evaluation(lanes, num_live, size):
  env, nodes, actions = lanes
  compacted = size is not None
  live = np.zeros(16, bool)
  live[np.random.default_rng(num_live).permutation(16)[:num_live]] = True
  full = env.evaluate(nodes, actions)
  got = jax.jit(lambda n, a, m: compact.evaluate_live(env.evaluate, n, a, m, size))(
      nodes, actions, jnp.asarray(live))
  for g, f in zip(jax.tree.leaves(got), jax.tree.leaves(full)):
    g, f = np.asarray(g), np.asarray(f)
    np.testing.assert_array_equal(g[live], f[live])
    if compacted:  # the other lanes were not simulated
      assert not g[~live].any()
    else:
      np.testing.assert_array_equal(g, f)
  if compacted:  # the zeros above are a real difference from the full evaluation
    assert any(np.asarray(f)[~live].any() for f in jax.tree.leaves(full))


class CountingGrid(gridworld.GridWorld):
  """A grid world that records the batch size of every evaluation actually run."""

  def __init__(self, *args, **kwargs):
    super().__init__(*args, **kwargs)
    self.batches = []

  def evaluate(self, nodes, actions):
    size = actions.shape[0]
    jax.debug.callback(lambda: self.batches.append(size))  # at run time: the branch taken
    return super().evaluate(nodes, actions)


def test_pachs_with_compaction_equals_without():
  obstacles = np.zeros((10, 10), bool)
  obstacles[3:7, 5] = True
  env = CountingGrid(obstacles, connectivity=8)
  ac = gridworld.GridActorCritic(env)
  starts = np.array([[0, 0], [9, 9], [2, 8], [5, 1], [0, 9], [8, 3]])
  goals = np.array([[1, 1], [0, 0], [8, 2], [5, 3], [9, 0], [8, 3]])
  nodes = env.node(starts, goals)
  config = SearchConfig(weight=1.5, num_actions=8, pop_size=4, budget=300)
  key = jax.random.PRNGKey(1)
  want = plan(env, ac, nodes, config, key)
  assert np.asarray(want.found).sum() >= 4
  assert len(set(np.asarray(want.iterations).tolist())) > 1  # instances stop at different times
  compacted = dataclasses.replace(config, compact_fractions=(0.25, 0.5))
  search = Programs(make_search(env, ac, compacted))
  # without shrinking (the one-shot command): the search stays in the first size's loop
  env.batches.clear()
  assert_results_equal(plan(env, ac, nodes, compacted, key, search=search, shrink=False), want)
  jax.effects_barrier()
  assert set(env.batches) == {32}, env.batches
  loops = lambda: [name for name in search.compiled[(8, jax.default_backend())]
                   if isinstance(name, tuple)]
  assert loops() == [('loop', pachs.Lanes(None))]
  # shrinking, with the same programs (the smaller sizes' loops compile now)
  env.batches.clear()
  got = plan(env, ac, nodes, compacted, key, search=search)
  jax.effects_barrier()
  # 6 instances padded to 8 (programs.bucket_size) x K 4 = 32 lanes: the smaller batches (8, 16)
  # ran once at most 4 and then 2 instances were still searching
  assert {8, 16} <= set(env.batches) and 32 in env.batches, env.batches
  assert len(loops()) == 3, loops()
  assert_results_equal(got, want)
  # (inside shard_map: test_segment.py, test_segments_with_compaction_equal_without)
  for bad in ((0.5, 1.0), 0.5, (float('nan'),)):
    with pytest.raises(ValueError, match='compact_fractions'):
      dataclasses.replace(config, compact_fractions=bad)


def test_loops_are_compiled_for_the_sizes_reached():
  # One instance in a bucket of 8 (32 lanes, K 4) holds at most 4 lanes from the start: only
  # the loop of the 8-lane batch is compiled and run, never the full one.
  env = CountingGrid(np.zeros((6, 6), bool), connectivity=8)
  ac = gridworld.GridActorCritic(env)
  config = SearchConfig(weight=1.0, num_actions=8, pop_size=4, budget=200,
                        compact_fractions=(0.25, 0.5))
  search = Programs(make_search(env, ac, config))
  nodes = env.node(np.array([[0, 0]]), np.array([[5, 4]]))
  out = plan(env, ac, nodes, config, jax.random.PRNGKey(0), search=search, min_bucket=8)
  jax.effects_barrier()
  assert bool(out.found[0])
  loops = [key for key in search.compiled[(8, jax.default_backend())] if isinstance(key, tuple)]
  assert loops == [('loop', pachs.Lanes(8))]
  assert set(env.batches) == {8}
