"""Bad input to planning refused with one line before any work, and the host-side pieces of
chunked planning: chunk sizes, the stop request, the progress line, the memory check of one
iteration's working set."""

import argparse
import dataclasses
import io

import jax
import numpy as np
import pytest

from fakes import Result, State, patch_clock
from pachs_jax import argtypes, cli, planner
from pachs_jax.envs import pusht
from pachs_jax.runtime import anytime, programs, progress
from pachs_jax.search import memory
from pachs_jax.search.result import StopReason


def test_an_instance_range_is_bounded_before_it_is_built():
  with pytest.raises(ValueError, match=r"instances must lie in 0\.\.29, got '0-99999999999'"):
    argtypes.instance_indices('0-99999999999', 30)
  with pytest.raises(ValueError, match='the range 5-3 is empty'):
    argtypes.instance_indices('5-3', 30)
  assert argtypes.instance_indices('3,0-2,2', 30) == [0, 1, 2, 3]


@pytest.mark.parametrize('flag', ['--json', '--render', '--animate', '--checkpoint'])
def test_empty_paths_are_refused(flag, capsys):
  with pytest.raises(SystemExit) as exit_:
    cli.main(['plan', flag, ''])
  assert exit_.value.code == 2
  err = capsys.readouterr().err.strip()
  assert err.startswith(f'pachs plan: error: argument {flag}: must name a ')
  assert 'got an empty string' in err and len(err.splitlines()) == 1


def test_path_type_keeps_a_real_path():
  assert argtypes.path('a file')('out.json') == 'out.json'
  with pytest.raises(argparse.ArgumentTypeError):
    argtypes.path('a file')('  ')


def test_a_missing_playground_checkpoint_fails_at_once_naming_the_env_flag(tmp_path):
  missing = tmp_path / 'none'
  with pytest.raises(FileNotFoundError, match='train one with experiments/train.py --env '
                     'playground:CartpoleBalance'):
    planner.load_model('playground:CartpoleBalance')  # before the (slow) Playground env
  with pytest.raises(FileNotFoundError, match=f'no checkpoint at {str(missing)!r}; train one '
                     'with experiments/train.py --task pusht-fixed'):
    planner.load_model('pusht-fixed', str(missing))
  with pytest.raises(ValueError, match="checkpoint must name a model directory, got ''"):
    planner.load_model('pusht-fixed', '')


def test_a_wrong_playground_name_is_named_before_its_checkpoint():
  pytest.importorskip('mujoco_playground')
  with pytest.raises(ValueError, match="unknown Playground env 'NoSuchEnv'; valid names"):
    planner.load_model('playground:NoSuchEnv')
  with pytest.raises(ValueError, match="did you mean 'ReacherEasy'"):
    planner.load_model('playground:reachereasy')


# -- chunks and stop requests on a simulated clock (as tests/test_anytime.py) --------------------

@pytest.fixture
def clock(monkeypatch):
  return patch_clock(monkeypatch, start=0.0)


def _planner(clock, iteration_s, total_iterations):
  chunks = []

  def advance(state, iterations):
    done = min(iterations, total_iterations - state.done)
    clock.now += done * iteration_s
    chunks.append(iterations)
    total = state.done + done
    return State(np.array([total < total_iterations, False]), total)

  def result(state):
    return Result(np.where(state.active, StopReason.RUNNING, StopReason.GOAL))
  return advance, result, chunks


def test_chunks_grow_to_the_target_time_and_cover_the_search(clock):
  advance, result, chunks = _planner(clock, iteration_s=0.01, total_iterations=500)
  out = anytime.timed_result(advance, State(np.array([True, False])), result, None,
                             sizes=anytime.ChunkSizes(first=2, target_s=0.3, growth=4.0))
  # 2, 8, 30 (0.3 s at 0.01 s per iteration), then 30 each until the 500 are done
  assert chunks[:4] == [2, 8, 30, 30]
  assert sum(chunks[:-1]) < 500 <= sum(chunks)
  assert list(out.stop_reason) == [StopReason.GOAL, StopReason.GOAL]


def test_a_time_limit_cuts_the_last_chunk_to_what_fits(clock):
  advance, result, chunks = _planner(clock, iteration_s=0.01, total_iterations=10**6)
  out = anytime.timed_result(advance, State(np.array([True, False])), result, 1.0,
                             sizes=anytime.ChunkSizes(first=2, target_s=0.3))
  assert sum(chunks) == 100  # 1 s at 0.01 s per iteration, the last chunk cut to fit
  assert list(out.stop_reason) == [StopReason.TIME_LIMIT, StopReason.GOAL]


def test_a_stop_request_ends_the_run_between_chunks(clock):
  advance, result, chunks = _planner(clock, iteration_s=0.01, total_iterations=10**6)
  seen = []
  out = anytime.timed_result(advance, State(np.array([True, False])), result, None,
                             stop=lambda: len(seen) >= 3,
                             on_chunk=lambda state, elapsed: seen.append(elapsed),
                             sizes=anytime.ChunkSizes(first=2))
  assert len(chunks) == 3
  np.testing.assert_allclose(seen, [0.02, 0.1, 0.4])
  assert list(out.stop_reason) == [StopReason.INTERRUPTED, StopReason.GOAL]


def test_fixed_chunks_keep_their_size():
  sizes = anytime.ChunkSizes.fixed(5)
  assert sizes.first == 5 and sizes.next(5, 100.0) == 5 and sizes.next(5, 1e-6) == 5


# -- the progress line ---------------------------------------------------------------------------

def _progress(elapsed, iterations=0, iterations_left=0):
  return programs.Progress(finished=1, instances=4, evaluations=1000, budget=4000,
                           elapsed_s=elapsed, iterations=iterations,
                           iterations_left=iterations_left)


def test_progress_on_a_terminal_rewrites_one_line():
  stream = io.StringIO()
  line = progress.ProgressLine(stream, after_s=2.0, tty=True)
  line(_progress(1.0, 10, 90))
  assert stream.getvalue() == ''  # a short search says nothing
  line(_progress(3.0, 30, 70))
  line(_progress(4.0, 40, 60))
  line.close()
  text = stream.getvalue()
  assert text.count('\r\033[K') == 3 and '\n' not in text
  # 0.1 s per iteration (30 iterations in 3 s) and 60 iterations left
  assert text.endswith('at most about 6 s left\r\033[K')
  assert 'searching: 1/4 instances finished, 1,000/4,000 evaluations, 4 s' in text


def test_the_time_left_follows_the_recent_pace():
  pace = progress.Pace(window_s=5.0)
  assert pace.left_s(_progress(0.5, 0, 100)) is None  # no iteration timed yet
  assert pace.left_s(_progress(1.0, 10, 90)) == pytest.approx(90 * 0.05)
  # the batch slows down to 1 s per iteration; older reports leave the window
  for elapsed, done in ((7.0, 16), (13.0, 22)):
    left = pace.left_s(_progress(elapsed, done, 100 - done))
  assert left == pytest.approx(78 * 1.0)


def test_progress_in_a_log_prints_a_line_now_and_then():
  stream = io.StringIO()
  line = progress.ProgressLine(stream, after_s=2.0, every_s=10.0, tty=False)
  for elapsed in (1.0, 2.5, 5.0, 12.0, 12.6, 22.7):
    line(_progress(elapsed))
  line.close()
  lines = stream.getvalue().splitlines()
  assert [l.split(', ')[2] for l in lines] == ['2 s', '13 s', '23 s']  # at 2.5, 12.6, 22.7


# -- memory: one iteration's working set ---------------------------------------------------------

class _Env:
  """The sizes `memory.iteration_bytes` reads: a node of 16 float32 positions and t."""
  observation_size, action_size = 20, 7
  node_spec = {'qpos': jax.ShapeDtypeStruct((16,), np.float32),
               't': jax.ShapeDtypeStruct((), np.int32)}


@dataclasses.dataclass(frozen=True)
class _Config:
  pop_size: int
  num_actions: int = 8
  edge_steps: int = 8
  budget: int = 1000


def test_iteration_bytes_follow_k_n_and_the_instances():
  small = memory.iteration_bytes(_Env(), _Config(pop_size=16), 4)
  node = 16 * 4 + 4
  per_lane = node + 4 * 20 + 8 * 4 * (7 + 1) + 8 * (node + 4 * 7 + 8)
  assert small == 2 * 4 * 16 * per_lane
  assert memory.iteration_bytes(_Env(), _Config(pop_size=32), 8) == 4 * small


def test_a_k_whose_iteration_cannot_fit_is_refused_naming_k(monkeypatch):
  monkeypatch.setattr(memory, 'device_memory', lambda device=None: (10**9, 'the machine has '
                                                                     '1 GB of RAM'))
  config = _Config(pop_size=100_000_000)
  search = type('S', (), {'config': config})()
  working = memory.iteration_bytes(_Env(), config, 4)

  monkeypatch.setattr(memory, 'search_bytes', lambda *args: 10**6)  # a small search state
  with pytest.raises(ValueError, match=r'K=100000000 \(pop_size\) and N=8 need at least .* per '
                     'iteration for 4 instances per device, but the machine has 1 GB of RAM: '
                     'lower -K or -N'):
    memory.check_fits(None, search, None, 4, working=working)


# -- the compilation cache: garbage entries are replaced -----------------------------------------

def test_garbage_cache_entries_are_removed_and_good_ones_kept(tmp_path):
  import zlib
  from jax._src import compilation_cache as jax_cache
  from pachs_jax.runtime import compile_cache
  good = tmp_path / 'jit_good-0123-cache'
  try:
    good.write_bytes(jax_cache.compress_executable(b'an executable'))
  except AttributeError:  # a JAX without compress_executable: its default, zlib
    good.write_bytes(zlib.compress(b'an executable'))
  bad = tmp_path / 'jit_bad-4567-cache'
  bad.write_bytes(b'\x00garbage')
  cut = tmp_path / 'jit_cut-89ab-cache'
  cut.write_bytes(good.read_bytes()[:-4])
  other = tmp_path / 'jit_bad-4567-atime'
  other.write_bytes(b'\x00')
  assert sorted(compile_cache.drop_unreadable_entries(str(tmp_path))) == [bad.name, cut.name]
  assert good.exists() and other.exists() and not bad.exists() and not cut.exists()
  listed = (tmp_path / compile_cache.CHECKED).read_text().split()
  assert listed[0] == good.name
  # a checked entry is not read again: damage that keeps its size and time goes unseen
  assert compile_cache.drop_unreadable_entries(str(tmp_path)) == []


def test_shelf_on_a_cpu_says_that_it_plans_instance_0_only(monkeypatch, capsys):
  def stop_here(*args, **kwargs):
    raise ValueError('stopped before planning')
  monkeypatch.setattr(programs, 'plan', stop_here)
  with pytest.raises(SystemExit):
    cli.main(['plan', '--task', 'shelf', '--no-cache'])
  out = capsys.readouterr()
  assert ('note: on this CPU (MJX physics) only instance 0 of 0-99 is planned; --instances 0-99 '
          '(or all) plans more') in out.err.splitlines()  # notes on stderr, beside the table
  assert 'note: JAX has no accelerator here' in out.err and 'note:' not in out.out
  assert 'A GPU plans 100 instances x 20,000 evaluations' in out.err
  assert 'planning shelf instances 0 ' in out.out
  assert 'stopped before planning' in out.err


def test_a_physics_preset_reaches_the_planners_env_and_is_refused_where_it_does_not_apply():
  env, _ = planner.load_model('pusht-obs', layout='wall', physics='soft-blocks')
  want = pusht.physics_preset('soft-blocks', variant='obs', layout='wall')
  assert env.config == want and want.block_margin == 0.0
  default = pusht.physics_preset('faithful', variant='obs', layout='wall')
  assert env.config != default and default.block_margin == 0.003
  assert planner.load_model('pusht-obs', layout='wall')[0].config == default
  with pytest.raises(ValueError, match="task 'shelf' has no option physics"):
    planner.load_model('shelf', physics='planar')
  with pytest.raises(ValueError, match="unknown physics preset 'soft'"):
    planner.load_model('pusht-fixed', physics='soft')
