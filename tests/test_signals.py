"""SignalGuard in real processes: a signal before `keep()` raises, after it the first one is
recorded and the second one ends the process with 128 + its number."""

import signal
import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent('''
    import os, signal, sys, time
    from pachs_jax.runtime.signals import Interrupted, SignalGuard
    mode, signame = sys.argv[1], sys.argv[2]
    signum = getattr(signal, signame)
    with SignalGuard('prog') as guard:
      if mode == 'before':
        try:
          os.kill(os.getpid(), signum)
          time.sleep(5)
          print('not raised')
        except Interrupted as err:
          print('raised', err.exit_code)
        sys.exit(0)
      if mode == 'dropped':  # the handler runs inside a gc callback, which drops its exception
        import gc
        def during_gc(phase, info):
          if phase == 'start':
            gc.callbacks.remove(during_gc)
            os.kill(os.getpid(), signum)
            time.sleep(0.5)
        gc.callbacks.append(during_gc)
        gc.collect()
        print('dropped', flush=True)
        try:
          guard.keep()
          print('not raised')
        except Interrupted as err:
          print('raised', err.exit_code)
        sys.exit(0)
      stop = guard.keep()
      os.kill(os.getpid(), signum)
      for _ in range(100):  # a chunked loop that checks stop()
        if stop():
          break
        time.sleep(0.01)
      print('stopped', stop(), guard.exit_code, flush=True)
      if mode == 'twice':
        os.kill(os.getpid(), signum)
        time.sleep(5)
        print('still running')
    print('restored', signal.getsignal(signal.SIGINT) is signal.default_int_handler)
''')


def _run(mode, signame):
  return subprocess.run([sys.executable, '-c', SCRIPT, mode, signame], capture_output=True,
                        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
                        text=True, timeout=60)


@pytest.mark.parametrize('signame,code', [('SIGINT', 130), ('SIGTERM', 143)])
def test_signal_before_keep_raises_interrupted_with_the_shell_code(signame, code):
  out = _run('before', signame)
  assert out.returncode == 0, out.stderr
  assert out.stdout.split() == ['raised', str(code)]


def test_a_signal_whose_exception_python_dropped_is_raised_at_keep():
  # Python drops an exception raised inside a garbage-collector callback ('dropped' is printed
  # after gc.collect() returned): the guard prints no "Exception ignored" traceback for it and
  # raises it again at the next safe point
  out = _run('dropped', 'SIGINT')
  assert out.returncode == 0, out.stderr
  assert out.stdout.split() == ['dropped', 'raised', '130']
  assert out.stderr == ''


@pytest.mark.parametrize('signame,code', [('SIGINT', 130), ('SIGTERM', 143)])
def test_first_signal_after_keep_asks_to_stop_and_the_guard_restores_handlers(signame, code):
  out = _run('once', signame)
  assert out.returncode == 0, out.stderr
  assert out.stdout.splitlines() == [f'stopped True {code}', 'restored True']
  assert f'prog: {signame}: stopping after the current chunk' in out.stderr
  assert 'Traceback' not in out.stderr


@pytest.mark.parametrize('signame,code', [('SIGINT', 130), ('SIGTERM', 143)])
def test_second_signal_exits_at_once(signame, code):
  out = _run('twice', signame)
  assert out.returncode == code
  assert 'still running' not in out.stdout
  assert f'prog: {signame} again: exiting now' in out.stderr
  assert 'Traceback' not in out.stderr


def test_a_signal_that_breaks_an_import_during_start_up_prints_one_line(monkeypatch, capsys):
  # a signal during a C extension's initialization (e.g. `import mujoco`) surfaces as the
  # ImportError it caused: start-up stopped, one line, the signal's exit code; another
  # ImportError is not taken for a signal
  from pachs_jax import cli
  from pachs_jax.runtime.signals import Interrupted

  def broken_import(words, guard):
    try:
      raise Interrupted(signal.SIGINT)
    except Interrupted as err:
      raise ImportError('initialization failed') from err

  monkeypatch.setattr(cli, '_main_prefetching', broken_import)
  assert cli.main(['plan', '--no-cache']) == 130
  assert capsys.readouterr().err == ('pachs plan: SIGINT: stopped during start-up; nothing '
                                     'written\n')

  def missing(words, guard):
    raise ImportError('no module named x')

  monkeypatch.setattr(cli, '_main_prefetching', missing)
  with pytest.raises(ImportError, match='no module named x'):
    cli.main(['plan', '--no-cache'])
