"""Planning in chunks leaves the result unchanged; a stop request or Ctrl-C in the middle of
`Planner.plan` returns the search so far, its unfinished instances marked 'interrupted'."""

import os
import signal

import jax
import numpy as np
import pytest

from pachs_jax import planner
from pachs_jax.runtime import anytime, programs, signals
from pachs_jax.search import checks
from pachs_jax.search.result import StopReason


@pytest.fixture(scope='module')
def small():
  # PushT-Fixed on MuJoCo C physics, K=16: instance 0 and 1 find goals within 400 evaluations
  return planner.Planner('pusht-fixed', budget=400, cache=False, pop_size=16, num_actions=8)


def _plan(small, **kwargs):
  return programs.plan(small.env, small.model, small.canonical([0, 1]), small.config,
                       jax.random.PRNGKey(0), search=small.search, **kwargs)


def _same(a, b):
  for name in ('found', 'stop_reason', 'cost', 'evaluated', 'expanded', 'iterations',
               'path_length', 'path_actions'):
    np.testing.assert_array_equal(np.asarray(getattr(a, name)), np.asarray(getattr(b, name)),
                                  err_msg=name)


def test_chunk_sizes_do_not_change_the_result(small):
  adaptive = _plan(small)
  _same(adaptive, _plan(small, chunk_iterations=1))
  _same(adaptive, _plan(small, chunk_iterations=10**6))  # the whole search in one call
  assert set(np.asarray(adaptive.stop_reason)) <= {StopReason.GOAL, StopReason.BUDGET}


def test_stop_after_one_chunk_marks_the_unfinished_instances(small):
  reports = []
  out = _plan(small, chunk_iterations=1, stop=lambda: bool(reports), progress=reports.append)
  assert len(reports) == 1  # one chunk of one iteration, then the stop request
  assert reports[0].instances == 2 and reports[0].finished == 0
  assert list(np.asarray(out.stop_reason)) == [StopReason.INTERRUPTED] * 2
  assert list(np.asarray(out.iterations)) == [1, 1]
  # the anytime answer: a path to the best state so far, which the pool holds
  assert (np.asarray(out.evaluated) > 0).all() and (np.asarray(out.path_length) > 0).all()
  assert StopReason.name(StopReason.INTERRUPTED) == 'interrupted'


@pytest.fixture
def python_sigint():
  """Python's own SIGINT handler, also where pytest started with SIGINT ignored (a background
  job); the previous handler is put back afterwards."""
  previous = signal.signal(signal.SIGINT, signal.default_int_handler)
  yield
  signal.signal(signal.SIGINT, previous)


def test_ctrl_c_during_planner_plan_returns_the_partial_result(small, python_sigint):
  del python_sigint
  small.plan([0, 1])  # compiled: the next call's first chunk runs at once

  def press_ctrl_c(progress):
    del progress
    os.kill(os.getpid(), signal.SIGINT)

  assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
  out = small.plan([0, 1], progress=press_ctrl_c)
  # the first SIGINT asks to stop, so the plan returns after one chunk (2 iterations here:
  # instance 1 finds its goal in them, instance 0 is still searching)
  assert int(np.max(np.asarray(out.iterations))) == anytime.ChunkSizes().first
  assert list(np.asarray(out.stop_reason)) == [StopReason.INTERRUPTED, StopReason.GOAL]
  assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored


def test_a_stop_before_the_search_raises(small):
  with pytest.raises(signals.StoppedBeforeSearch):
    small.plan([0, 1], stop=lambda: True)


@pytest.mark.parametrize('instances,message', [
    ([99], 'instances must lie in 0..29, got 99'),
    ([-1], 'instances must lie in 0..29, got -1'),
    ([], 'instances must be a non-empty list'),
    ([0.5], 'instances must be integers'),
    ([True], 'instances must be integers'),
    ((0, 3, 0), 'instances must not repeat: 0 is listed 2 times'),
])
def test_bad_instances_are_refused(small, instances, message):
  with pytest.raises(ValueError, match=message.replace('.', r'\.')):
    small.plan(instances)


@pytest.mark.parametrize('kwargs, message', [
    ({'devices': 'cpu'}, 'devices must be a sequence of jax devices'),
    ({'devices': ['cpu']}, 'devices must be a sequence of jax devices'),
    ({'shrink': 'no'}, 'shrink must be True or False'),
])
def test_bad_plan_options_are_refused_by_name(small, kwargs, message):
  with pytest.raises(ValueError, match=message):
    small.plan([0], **kwargs)


@pytest.mark.parametrize('seed,message', [(2**70, 'seed must fit in 64 bits'),
                                          (-2**63 - 1, 'seed must fit in 64 bits'),
                                          (1.5, 'seed must be an integer')])
def test_bad_seeds_are_refused(small, seed, message):
  with pytest.raises(ValueError, match=message):
    small.plan([0], seed=seed)


def test_int_qpos_is_cast_and_a_float_step_count_is_refused(small):
  starts = small.canonical([0, 1])
  ints = np.rint(np.asarray(starts.qpos)).astype(np.int32)
  cast = checks.conform_start_nodes(starts.replace(qpos=ints), small.env)
  assert cast.qpos.dtype == np.float32
  np.testing.assert_array_equal(np.asarray(cast.qpos), ints.astype(np.float32))
  with pytest.raises(ValueError, match='start_nodes.t has dtype float32, but the environment '
                     'pusht-fixed uses int32'):
    checks.conform_start_nodes(starts.replace(t=np.zeros(2, np.float32)), small.env)


@pytest.mark.parametrize('field,value,limit', [('qpos', 1e30, '1e\\+06'),
                                               ('qvel', 1e30, '1e\\+03'),
                                               ('qvel', 9e5, '1e\\+03')])
def test_start_states_beyond_the_physical_bound_are_refused(small, field, value, limit):
  starts = small.canonical([0, 1, 2])
  values = np.array(getattr(starts, field))
  values[1, 0] = value  # (a joint velocity of 9e5 rad/s overflows MuJoCo's accelerations)
  with pytest.raises(ValueError, match=rf'start_nodes\.{field} of instance \[1\] exceeds {limit}'):
    small.plan(start_nodes=starts.replace(**{field: values}))
