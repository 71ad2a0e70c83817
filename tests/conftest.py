"""Helpers shared by the test files: `from conftest import take, assert_results_equal, ...`,
and the test run's one persistent compilation cache (`compilation_cache_dir`).

pytest puts this directory on sys.path (the tests are not a package), so the plain import works;
experiments/ goes there too, for the tests of the experiment scripts (which import their siblings).
"""

import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pachs_jax.runtime import compile_cache

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                'experiments'))

try:  # the tests compile MuJoCo Warp's CPU kernels (once per machine) at -O0: on a new 2-core
  import warp  # machine about 40 s of kernel compilation become 21 s
  warp.config.optimization_level = 0
except ImportError:
  pass


# The test files that take longest on an empty compilation cache (2 cores), longest first.
# They run first, the other files after them in name order (pyproject.toml runs each file in one
# of two worker processes, in collection order: --dist loadfile --no-loadscope-reorder), so the
# two workers end together instead of one of them starting a long file last.
LONGEST_FILES = (
    'test_playground.py', 'test_pusht.py', 'test_sharding.py', 'test_search.py',
    'test_segment.py', 'test_plan_signals.py', 'test_baselines.py', 'test_improve.py',
    'test_shelf.py', 'test_bad_input_search.py', 'test_train_files.py',
    'test_bad_input_models.py', 'test_layouts.py', 'test_protocol.py', 'test_plan_outputs.py',
    'test_compact.py', 'test_mujoco_c.py', 'test_sac.py', 'test_warp.py', 'test_plan.py',
    'test_saved_plans.py', 'test_novelty.py', 'test_plan_interrupt.py',
    'test_coverage.py', 'test_mppi.py')


# The slow tier (`python -m pytest -m slow`, run by .ci/run after the default tier): whole files
# ('name.py') or tests ('name.py::test', all its parameters) of end-to-end commands in
# subprocesses, signals, several devices and long equivalence checks. Each measured at 12 s or
# more from an empty compilation cache on 2 cores (8 s or more where the default tier needs the
# room); the default tier keeps every other test.
SLOW = (
    'test_playground.py', 'test_sharding.py', 'test_plan_signals.py', 'test_serve.py',
    'test_docs.py',
    'test_train_files.py::test_signals_are_handled_while_an_epoch_runs',
    'test_train_files.py::test_resume_after_sigkill_has_one_row_per_epoch',
    'test_train_files.py::test_steps_below_one_epoch_are_named_before_work',
    'test_bad_input_search.py::test_a_budget_that_cannot_fit_is_refused_naming_the_largest_that_can',
    'test_bad_input_search.py::test_without_the_check_a_nan_critic_looks_like_an_exhausted_search',
    'test_bad_input_search.py::test_the_json_is_written_when_drawing_fails',
    'test_bad_input_models.py::test_sigint_saves_a_resumable_checkpoint',
    'test_search.py::test_traced_loop_is_stored_and_reused',
    'test_warp.py::test_restore_then_step_reproduces_the_transition',
    'test_plan_inputs.py::test_shelf_on_a_cpu_says_that_it_plans_instance_0_only',
    'test_mujoco_c.py::test_search_on_the_cpu_backend_stops_at_its_iteration_limit',
    'test_mujoco_c.py::test_c_step_matches_mjx_step_along_a_push',
    'test_xla_cpu.py::test_concurrent_batched_cholesky_on_two_cpus_finishes_with_the_setting',
    'test_shelf.py::test_mjx_kinematics_option_agrees',
    'test_pusht.py::test_bad_actions_and_states',
    'test_pusht.py::test_step_is_restore_and_evaluate_bit_for_bit',
    'test_pusht.py::test_restored_node_continues_a_carried_simulation_exactly',
    'test_segment.py::test_segments_with_compaction_equal_without',
    'test_baselines.py::test_epase_finds_a_goal_on_the_shelf',
    'test_layouts.py::test_mujoco_c_and_mjx_see_the_same_blocks',
    'test_compact.py::test_pachs_with_compaction_equals_without',
    'test_protocol.py::test_doc_task_trains_and_plans_end_to_end',
    'test_serve.py::test_sigterm_answers_the_request_in_flight_and_exits_0',
    'test_programs.py::test_compile_first_compiles_every_reachable_loop_before_the_search',
    'test_plan.py::test_sharded_plan_runs_end_to_end',
    'test_plan_outputs.py::test_short_pusht_plan_finds_paths_that_replay_and_writes_them',
    'test_episodes.py::test_pachs_loop_runs_episodes_and_writes_rows_and_a_video',
)


def is_slow(nodeid: str) -> bool:
  """Whether a test ('tests/name.py::test[param]') is in the slow tier (`SLOW`)."""
  path, _, name = nodeid.partition('::')
  file = os.path.basename(path)
  test = name.split('[')[0]
  return any(entry == file or entry == f'{file}::{test}' for entry in SLOW)


@pytest.hookimpl(tryfirst=True)  # before `-m` deselects by marker
def pytest_collection_modifyitems(items):
  """Marks the slow tier (`SLOW`); runs the files of LONGEST_FILES first, in its order, each
  file's tests in their order."""
  for item in items:
    if is_slow(item.nodeid):
      item.add_marker(pytest.mark.slow)
  rank = {name: i for i, name in enumerate(LONGEST_FILES)}
  items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.fixture(scope='session', autouse=True)
def compilation_cache_dir():
  """The persistent compilation cache of the whole test run, the same the CLI uses
  ($PACHS_COMPILATION_CACHE, else the user's cache directory): on in this process from the
  first test on, and named in $PACHS_COMPILATION_CACHE for the `pachs` processes the tests
  start, so a program compiled once (in this run or an earlier one) is loaded, not compiled
  again. None where the variable turns the cache off."""
  path = compile_cache.enable()
  if path is None:
    yield None
    return
  previous = os.environ.get(compile_cache.ENV_VAR)
  os.environ[compile_cache.ENV_VAR] = path
  yield path
  if previous is None:
    del os.environ[compile_cache.ENV_VAR]
  else:
    os.environ[compile_cache.ENV_VAR] = previous


def jax_cache_env(cache_dir, **extra):
  """The environment for a Python child process (a script, not `pachs`) that compiles with
  JAX's persistent cache at cache_dir (None: no cache), plus the variables in extra."""
  env = dict(os.environ, **extra)
  if cache_dir is not None:
    env.update(JAX_COMPILATION_CACHE_DIR=cache_dir,
               JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS='0',
               JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES='-1')
  return env


def take(tree, i):
  """Row i of a batched pytree as a batch of one; scalar leaves (a wall time) unchanged."""
  return jax.tree.map(lambda x: x[i:i + 1] if jnp.ndim(x) else x, tree)


def pad_rows(tree, rows):
  """A batched pytree padded to `rows` rows by repeating its last row (a fixed compiled batch)."""
  def pad(x):
    x = jnp.asarray(x)
    return jnp.concatenate([x, jnp.repeat(x[-1:], rows - x.shape[0], axis=0)])
  return jax.tree.map(pad, tree)


def trees_equal(a, b) -> bool:
  """Bit-for-bit equality of two pytrees: leaf count, shapes, dtypes and bytes (NaNs included)."""
  la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
  return len(la) == len(lb) and all(
      x.shape == y.shape and x.dtype == y.dtype
      and np.asarray(x).tobytes() == np.asarray(y).tobytes() for x, y in zip(la, lb))


def result_leaves(result):
  """A SearchResult's arrays as numpy arrays, without the wall time (it differs run to run)."""
  return [np.asarray(x) for x in jax.tree.leaves(result.replace(wall_time_s=None))]


def assert_results_equal(got, want):
  """Two SearchResults hold equal arrays, leaf for leaf (NaN equals NaN), the wall time aside."""
  got, want = result_leaves(got), result_leaves(want)
  assert len(got) == len(want), (len(got), len(want))
  for g, w in zip(got, want):
    np.testing.assert_array_equal(g, w)


class UniformActorCritic:
  """A stand-in actor-critic that knows nothing: uniform random proposals in [-1, 1], a
  deterministic policy that stays put (zero action), Q = 0."""

  def __init__(self, action_size: int):
    self.action_size = action_size

  def deterministic_action(self, obs):
    return jnp.zeros((obs.shape[0], self.action_size), jnp.float32)

  def sample_actions(self, key, obs, num):
    return jax.random.uniform(key, (obs.shape[0], num, self.action_size), jnp.float32,
                              -1.0, 1.0)

  def q_values(self, obs, actions):
    return jnp.zeros(actions.shape[:2], jnp.float32)
