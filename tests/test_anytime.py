"""The anytime wall-clock rule on a simulated clock: chunks stop where the next chunk and the
result, timed as their last runs, would pass the limit."""

import gc
import threading

import numpy as np
import pytest

from fakes import Result, State, patch_clock
from pachs_jax.runtime import anytime
from pachs_jax.search.result import StopReason


@pytest.fixture
def clock(monkeypatch):
  return patch_clock(monkeypatch, start=100.0)


def make_planner(clock, chunk_s, result_s, stop_after=None):
  def advance(state):
    clock.now += chunk_s
    chunks = state.done + 1
    done = stop_after is not None and chunks >= stop_after
    return State(np.array([not done, False]), chunks)

  def result(state):
    clock.now += result_s
    result.chunks = state.done
    return Result(np.where(state.active, StopReason.RUNNING, StopReason.GOAL))
  return advance, result


def test_result_time_is_held_in_reserve(clock):
  advance, result = make_planner(clock, chunk_s=0.25, result_s=0.6)
  timing = {}
  first = anytime.timed_result(advance, State(np.array([True, False])), result, 3.0,
                               timing=timing)
  # no result time known yet: chunks run while the next one ends by 3 s (12 x 0.25 = 3)
  assert result.chunks == 12
  np.testing.assert_allclose(first.wall_time_s, 3.0 + 0.6, rtol=1e-6)
  np.testing.assert_allclose(timing['result_s'], 0.6)
  second = anytime.timed_result(advance, State(np.array([True, False])), result, 3.0,
                                timing=timing)
  # the next chunk and the 0.6 s result must end by 3 s: 9 chunks (2.25 + 0.6 = 2.85)
  assert result.chunks == 9
  np.testing.assert_allclose(second.wall_time_s, 2.85, rtol=1e-6)
  assert list(second.stop_reason) == [StopReason.TIME_LIMIT, StopReason.GOAL]


def test_clock_counts_from_the_given_start(clock):
  advance, result = make_planner(clock, chunk_s=0.25, result_s=0.0)
  start = clock.now
  clock.now += 1.0  # e.g. an init between the start and the first chunk
  out = anytime.timed_result(advance, State(np.array([True, False])), result, 3.0, start)
  assert result.chunks == 8  # 1 + 8 x 0.25 = 3
  np.testing.assert_allclose(out.wall_time_s, 3.0, rtol=1e-6)


def test_finished_instances_stop_the_run_early(clock):
  advance, result = make_planner(clock, chunk_s=0.25, result_s=0.1, stop_after=3)
  out = anytime.timed_result(advance, State(np.array([True, False])), result, 3.0)
  assert result.chunks == 3
  assert list(out.stop_reason) == [StopReason.GOAL, StopReason.GOAL]


def test_at_least_one_chunk_runs(clock):
  advance, result = make_planner(clock, chunk_s=5.0, result_s=0.0)
  out = anytime.timed_result(advance, State(np.array([True, False])), result, 1.0,
                             timing={'result_s': 10.0})
  assert result.chunks == 1
  assert out.stop_reason[0] == StopReason.TIME_LIMIT


def test_a_limit_too_far_to_count_in_chunks_runs_to_the_end(clock):
  """A time limit whose chunks' count overflows an int (1e308 s) runs until the instances
  stop, as no limit does."""
  advance, result = make_planner(clock, chunk_s=0.25, result_s=0.0, stop_after=5)
  out = anytime.timed_result(lambda state, iterations: advance(state),
                             State(np.array([True, False])), result, 1e308,
                             sizes=anytime.ChunkSizes())
  assert result.chunks == 5
  assert list(out.stop_reason) == [StopReason.GOAL, StopReason.GOAL]


def test_the_collector_waits_for_the_clocked_loop_of_every_thread(clock):
  """A clocked loop runs with Python's garbage collector paused (a full collection takes a short
  query's iterations), resumed when the last loop of any thread is out, also after an error;
  a loop without a limit leaves it on, and a collector the caller turned off stays off."""
  seen = []

  def advance(state):
    seen.append(gc.isenabled())
    clock.now += 0.25
    return State(np.array([state.done < 1, False]), state.done + 1)

  def result(state):
    seen.append(gc.isenabled())
    return Result(np.full(2, StopReason.GOAL))

  assert gc.isenabled()
  anytime.timed_result(advance, State(np.array([True, False])), result, 3.0)
  assert seen == [False, False, False] and gc.isenabled()
  seen.clear()
  anytime.timed_result(advance, State(np.array([True, False])), result, None)
  assert seen == [True, True, True]

  inside, leave = threading.Event(), threading.Event()

  def held(state):  # another thread's loop, in its clock until `leave`
    inside.set()
    leave.wait(10)
    return State(np.array([False, False]))

  other = threading.Thread(target=anytime.timed_result,
                           args=(held, State(np.array([True, False])), result, 3.0))
  other.start()
  inside.wait(10)
  seen.clear()
  anytime.timed_result(advance, State(np.array([True, False])), result, 3.0)
  assert not gc.isenabled()  # the other loop is still in its clock
  leave.set()
  other.join(10)
  assert gc.isenabled()

  def failing(state):
    raise RuntimeError('chunk failed')

  with pytest.raises(RuntimeError, match='chunk failed'):
    anytime.timed_result(failing, State(np.array([True, False])), result, 3.0)
  assert gc.isenabled()
  gc.disable()
  try:
    anytime.timed_result(advance, State(np.array([True, False])), result, 3.0)
    assert not gc.isenabled()
  finally:
    gc.enable()
