"""Widening at the tail of a batch: once few instances still search, each pops m x K edges so
that the physics batch stays full; checked on the grid world against the unwidened search."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pachs_jax.search import SearchConfig, StopReason, make_search, pachs
from test_search import BASE, NUM_FOUND, Problem, _np

WIDE = dataclasses.replace(BASE, pop_size=8, widen_factors=(4, 2))


def test_lanes_of_picks_the_widest_factor_that_fits_then_the_smallest_batch():
  config = SearchConfig(pop_size=4, widen_factors=(2, 4), compact_fractions=(0.25,))
  # I = 8 instances, K = 4: 32 lanes, one compacted size of 8
  got = {a: pachs.lanes_of(config, a, 8) for a in range(8, 0, -1)}
  assert got[8] == got[5] == pachs.Lanes(None, 1)
  assert got[4] == got[3] == pachs.Lanes(32, 2)  # 4 x 4 x 2 = 32 edges fit 32 lanes
  assert got[2] == pachs.Lanes(32, 4)
  assert got[1] == pachs.Lanes(32, 4)  # 16 edges: more than the compacted 8
  assert pachs.reachable(config, 8, 8) == (pachs.Lanes(None, 1), pachs.Lanes(32, 2),
                                           pachs.Lanes(32, 4))
  plain = SearchConfig(pop_size=4, compact_fractions=(0.25,))
  assert pachs.lanes_of(plain, 2, 8) == pachs.Lanes(8, 1)  # compaction alone, as before
  assert pachs.lanes_of(plain, 3, 8) == pachs.Lanes(None, 1)


@pytest.mark.parametrize('factors', [(1,), (2.5,), (True,), 'ab', (65,)])
def test_bad_widen_factors_are_named(factors):
  with pytest.raises(ValueError, match='widen_factors'):
    SearchConfig(widen_factors=factors)


@pytest.fixture(scope='module')
def problem():
  return Problem(seed=4)


def test_tail_instances_pop_m_k_edges_and_paths_stay_exact(problem):
  # The pocket instance (unreachable goal) searches alone at the end: once it holds at most
  # 1 / m of the 7 x 8 lanes it evaluates min(m K, edges in OPEN) per iteration.
  search = make_search(problem.env, problem.actor_critic, WIDE)
  k, n = WIDE.pop_size, WIDE.num_actions
  state = search.init(problem.nodes, problem.keys)
  widened = {1: 0, 2: 0, 4: 0}
  while bool(jnp.any(state.active)):
    lanes = search.lanes_for(state)
    active, evaluated, expanded, in_open = _np((state.active, state.evaluated, state.expanded,
                                                state.edge_heap.count))
    state = search.run_chunk(state, jnp.int32(1))
    found = active & (np.asarray(state.stop_reason) == StopReason.GOAL)
    in_open = in_open + n * (np.asarray(state.expanded) - expanded)
    want = np.where(found, 0, np.minimum(lanes.widen * k, in_open))
    delta = np.asarray(state.evaluated) - evaluated
    np.testing.assert_array_equal(delta[active], want[active])
    np.testing.assert_array_equal(delta[~active], 0)
    widened[lanes.widen] += int(np.sum(active & (delta == lanes.widen * k)))
  assert widened[4] >= 20  # the pocket instance alone ran full 4 K iterations
  out = _np(search.result(state))
  np.testing.assert_array_equal(out.found, np.isfinite(problem.optimal))
  assert (out.evaluated <= WIDE.budget).all()
  assert (out.lane_utilization <= 1.0 + 1e-6).all()  # of the m K lanes a widened step offers
  for i in np.flatnonzero(out.found):  # each path replays to its goal at its cost
    length = int(out.path_length[i])
    nodes = jax.tree.map(lambda x: x[i:i + 1], problem.nodes)
    cost = 0.0
    for action in out.path_actions[i, :length]:
      step = problem.env.evaluate(nodes, jnp.asarray(action)[None])
      cost += float(step.cost[0])
      nodes = step.next_node
    assert bool(problem.env.is_goal(nodes)[0])
    np.testing.assert_allclose(cost, out.cost[i], rtol=1e-5)


def test_run_equals_chunks_with_widening(problem):
  search = make_search(problem.env, problem.actor_critic, WIDE)
  whole = _np(search.result(search.run(search.init(problem.nodes, problem.keys))))
  state = search.init(problem.nodes, problem.keys)
  while bool(jnp.any(state.active)):
    state = search.run_chunk(state, jnp.int32(7))
  chunked = _np(search.result(state))
  for name in ('found', 'cost', 'evaluated', 'iterations', 'path_length'):
    np.testing.assert_array_equal(getattr(whole, name), getattr(chunked, name))
