"""`pachs plan` in real processes: SIGINT or SIGTERM during the search stops it within a chunk,
prints the table, writes the JSON (unfinished rows 'interrupted') and exits 130 / 143; a signal
during start-up prints one line and no traceback. `pachs loop`: a signal while the episodes run
ends them before the next query and writes what ran."""

import json
import os
import queue
import signal
import subprocess
import sys
import threading

import pytest

# a search that runs for minutes: uniform-cost order (w = 0), one-step edges, no rollout lanes
# about a minute of search on a 2-core CPU, neither instance solved
LONG_PLAN = ['plan', '--task', 'pusht-obs', '--layout', 'detour', '--instances', '2,3',
             '--budget', '200000']


@pytest.fixture(scope='module')
def cache_dir(compilation_cache_dir, tmp_path_factory):
  """One compilation cache for the processes: the test run's (conftest.py), else one of the
  module's own; the later processes load what the first compiled."""
  return compilation_cache_dir or str(tmp_path_factory.mktemp('cache'))


def default_sigint():
  """In the child: SIGINT's default action, also where the tests run with SIGINT ignored (a
  background job), so that Python installs its own handler."""
  signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(args, cache_dir):
  env = dict(os.environ, PACHS_COMPILATION_CACHE=cache_dir,
             PYTHONPATH=os.pathsep.join([os.getcwd()] + sys.path))
  process = subprocess.Popen([sys.executable, '-m', 'pachs_jax.cli'] + args,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                             preexec_fn=default_sigint)
  lines = queue.Queue()
  stderr = []

  def read():
    for line in process.stderr:
      stderr.append(line)
      lines.put(line)
    lines.put(None)

  process.stderr_reader = threading.Thread(target=read, daemon=True)
  process.stderr_reader.start()
  return process, lines, stderr


def _wait_for(lines, text, timeout=300):
  while True:
    line = lines.get(timeout=timeout)
    if line is None:
      raise AssertionError(f'the process ended before {text!r}')
    if text in line:
      return line


def _finish(process, stderr, timeout=120):
  """(exit status, stdout, stderr) once the process ends; a process still running after
  timeout seconds (a signal it missed: the search would run for minutes) is killed and
  reported."""
  try:
    process.wait(timeout=timeout)  # stderr is read by _start's thread; stdout holds a few lines
  except subprocess.TimeoutExpired:
    process.kill()
    process.wait()
    raise AssertionError(f'still running {timeout} s after the signal; stderr:\n'
                         + ''.join(stderr)) from None
  out = process.stdout.read()
  process.stderr_reader.join(timeout=timeout)  # all of stderr read
  return process.returncode, out, ''.join(stderr)


@pytest.mark.parametrize('signame,code', [('SIGINT', 130), ('SIGTERM', 143)])
def test_a_signal_during_the_search_keeps_the_rows(tmp_path, cache_dir, signame, code):
  rows = tmp_path / 'rows.json'
  process, lines, stderr = _start(LONG_PLAN + ['--json', str(rows)], cache_dir)
  _wait_for(lines, 'searching:')  # the progress line: the search runs
  process.send_signal(getattr(signal, signame))
  returncode, out, err = _finish(process, stderr)
  assert returncode == code, err
  assert f'pachs plan: {signame}: stopping after the current chunk' in err
  assert 'Traceback' not in err
  table = [line.split() for line in out.splitlines() if line.split()[:1] in (['2'], ['3'])]
  saved = json.loads(rows.read_text())
  stops = [r['stop'] for r in saved['rows']]
  # instance 2 searches for a minute; instance 3 may find its goal sooner
  assert stops[0] == 'interrupted' and stops[1] in ('interrupted', 'goal')
  assert [row[6] for row in table] == stops
  assert f'interrupted: {stops.count("interrupted")} of 2 instances stopped early' in out
  assert saved['interrupted'] is True
  for row in saved['rows']:  # the anytime answer: a path to the best state so far
    assert 0 < row['evaluated'] < 200000 and row['path_length'] > 0
    assert len(row['plan']['actions']) == row['path_length']


def test_a_second_signal_exits_at_once(tmp_path, cache_dir):
  process, lines, stderr = _start(LONG_PLAN, cache_dir)
  _wait_for(lines, 'searching:')
  process.send_signal(signal.SIGINT)
  _wait_for(lines, 'stopping after the current chunk')
  process.send_signal(signal.SIGINT)
  returncode, _, err = _finish(process, stderr)
  assert returncode == 130
  assert 'Traceback' not in err


@pytest.mark.parametrize('wait_for', [None, 'planning'])
def test_a_signal_during_start_up_prints_one_line(cache_dir, wait_for):
  # None: during the imports; 'planning': while the programs compile or load
  process, lines, stderr = _start(LONG_PLAN + ['--no-cache'], cache_dir)
  if wait_for is None:
    import time
    time.sleep(1.0)
  else:
    assert 'planning' in process.stdout.readline()  # (the CPU's notes go to stderr)
  process.send_signal(signal.SIGINT)
  returncode, out, err = _finish(process, stderr)
  assert returncode == 130, err
  assert 'Traceback' not in err
  assert [line for line in err.strip().splitlines() if not line.startswith('note: ')] == [
      'pachs plan: SIGINT: stopped during start-up; nothing written'], err
  assert not [line for line in out.splitlines() if line.startswith(('instance', 'found '))]


def test_a_signal_during_the_closed_loop_keeps_the_episodes(tmp_path, cache_dir):
  """Detour's episodes rarely reach the goal: 30 queries of 1 s would run long after the
  signal, which ends them before the next query; the table and the JSON hold what ran."""
  saved = tmp_path / 'loop.json'
  process, lines, stderr = _start(['loop', '--task', 'pusht-obs', '--layout', 'detour',
                                   '--instances', '0-1', '--query-time', '1', '--json',
                                   str(saved)], cache_dir)
  _wait_for(lines, 'query 0: answered 2 running episodes')
  process.send_signal(signal.SIGINT)
  returncode, out, err = _finish(process, stderr)
  assert returncode == 130, err
  assert 'pachs loop: SIGINT: stopping before the next query' in err
  assert 'Traceback' not in err
  document = json.loads(saved.read_text())
  stopped = document['interrupted_at_query']
  assert stopped is not None and 0 < stopped < 30
  assert f'(interrupted before query {stopped}: the episodes end there)' in out
  assert [row['instance'] for row in document['rows']] == [0, 1]
  assert all(row['queries'] <= stopped for row in document['rows'])
