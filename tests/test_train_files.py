"""Training and checkpoint files under failure: atomic writes, full disks, kills and signals
while XLA computes (real subprocesses), and the time-budget bookkeeping."""

import errno
import json
import os
import shutil
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import jax_cache_env

from pachs_jax.runtime import files
from pachs_jax.sac import checkpoint, reporting, train

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TRAIN_PY = os.path.join(REPO, 'experiments', 'train.py')
SHIPPED = os.path.join(REPO, 'pachs_jax', 'checkpoints', 'playground-ReacherEasy')


def _no_space(*args, **kwargs):
  raise OSError(errno.ENOSPC, 'No space left on device')


# ------------------------------------------------------------------------ files.py ----

def test_atomic_write_replaces_whole_or_not_at_all(tmp_path, monkeypatch):
  path = str(tmp_path / 'out.json')
  files.write_json(path, {'a': 1})
  with open(path) as f:
    assert json.load(f) == {'a': 1}
  monkeypatch.setattr(os, 'fsync', _no_space)
  with pytest.raises(files.WriteError, match=f'^cannot write {re.escape(path)}: No space left'):
    files.write_json(path, {'a': 2})
  monkeypatch.undo()
  with open(path) as f:
    assert json.load(f) == {'a': 1}  # the old file, whole
  with pytest.raises(TypeError):
    files.write_json(path, {'a': object()})  # not serializable: nothing touched
  with open(path) as f:
    assert json.load(f) == {'a': 1}
  assert os.listdir(tmp_path) == ['out.json']  # no temporary file left


def test_atomic_write_refuses_what_is_not_a_regular_file(tmp_path):
  for target in (str(tmp_path), '/dev/null'):
    with pytest.raises(files.WriteError, match='not a regular file'):
      files.write_text(target, 'x')
  with pytest.raises(files.WriteError, match='No such file or directory'):
    files.write_bytes(str(tmp_path / 'missing' / 'x'), b'x')


# --------------------------------------------------------------- full disk on save ----

def test_training_save_on_a_full_disk_is_one_line_and_leaves_no_partial_step(tmp_path):
  ckpts = checkpoint.TrainingCheckpoints(str(tmp_path / 'state'))
  state = {'w': np.arange(4, dtype=np.float32)}
  ckpts.save(1, state, {'epoch': 1})

  def full_disk(step, *args, **kwargs):
    os.makedirs(os.path.join(ckpts.directory, f'{step}.orbax-checkpoint-tmp-17'))
    _no_space()

  ckpts._manager.save = full_disk
  with pytest.raises(checkpoint.CheckpointError) as info:
    ckpts.save(2, state, {'epoch': 2})
  message = str(info.value)
  assert message == (f'cannot save training checkpoint {os.path.join(ckpts.directory, "2")}: '
                     'no space left on device')
  assert sorted(os.listdir(ckpts.directory)) == ['1']
  assert ckpts.latest_epoch() == 1
  ckpts.close()


def test_a_training_save_that_cannot_fit_is_refused_before_orbax_writes(tmp_path, monkeypatch):
  ckpts = checkpoint.TrainingCheckpoints(str(tmp_path / 'state'))
  state = {'w': np.zeros(2**18, np.float32)}  # 1 MiB
  monkeypatch.setattr(ckpts._manager, 'save', lambda *a, **k: pytest.fail('orbax was called'))
  usage = shutil.disk_usage(str(tmp_path))
  monkeypatch.setattr(shutil, 'disk_usage', lambda path: usage._replace(free=2**19))
  with pytest.raises(checkpoint.CheckpointError) as info:
    ckpts.save(1, state, {'epoch': 1})
  assert str(info.value) == (f'cannot save training checkpoint {os.path.join(ckpts.directory, "1")}'
                             ': no space left on device (0.5 MiB free, the state needs about '
                             '1.0 MiB)')
  assert os.listdir(ckpts.directory) == [] and ckpts.latest_epoch() is None
  ckpts.close()


def test_export_save_on_a_full_disk_keeps_the_old_export(tmp_path, monkeypatch):
  ac = checkpoint.load_actor_critic(SHIPPED)
  path = checkpoint.save_actor_critic(str(tmp_path / 'model'), ac, extra={'epoch': 1})
  monkeypatch.setattr(files, 'write_json', _no_space)
  with pytest.raises(checkpoint.CheckpointError,
                     match=f'^cannot save the actor-critic in {re.escape(path)}: no space left'):
    checkpoint.save_actor_critic(path, ac, extra={'epoch': 2})
  monkeypatch.undo()
  assert os.listdir(tmp_path) == ['model']
  with open(os.path.join(path, checkpoint.CONFIG_FILE)) as f:
    assert json.load(f)['epoch'] == 1
  checkpoint.load_actor_critic(path)


def test_exports_a_killed_save_left_are_cleaned_up(tmp_path):
  ac = checkpoint.load_actor_critic(SHIPPED)
  path = str(tmp_path / 'model')
  checkpoint.save_actor_critic(path, ac)
  dead = 999_999_999  # no such process
  os.rename(path, f'{path}.old-{dead}')  # killed between the two renames
  os.makedirs(f'{path}.tmp-{dead}')
  alive = f'{path}.tmp-{os.getppid()}'  # another live process's save: left alone
  os.makedirs(alive)
  checkpoint.remove_stale_exports(path)
  assert sorted(os.listdir(tmp_path)) == sorted(['model', os.path.basename(alive)])
  checkpoint.load_actor_critic(path)


# --------------------------------------------------------------------- metrics.csv ----

def test_resume_keeps_only_the_rows_up_to_its_checkpoint(tmp_path):
  path = tmp_path / 'metrics.csv'
  path.write_text('env_steps,epoch,x\r\n100,1.0,5\r\n200,2.0,6\r\n300,3.0,7\r\n400,4')
  reporter = reporting.RunReporter(str(tmp_path), progress='none', tensorboard=False)
  reporter.start(200, 1000)  # resuming epoch 2: rows 3 (never checkpointed) and 4 (cut) go
  reporter.report(300, {'epoch': 3.0})
  reporter.close()
  rows = path.read_text().splitlines()
  assert rows[1:3] == ['100,1.0,5', '200,2.0,6']
  assert [r.split(',')[:2] for r in rows[3:]] == [['300', '3.0']]
  assert len(rows) == 4


# -------------------------------------------------------------------- time budget ----

class _Trainer:
  env_steps_per_epoch = 1000
  config = type('C', (), {'eval_instances': 10, 'steps_per_epoch': 10,
                          'grad_updates_per_step': 1})()
  env = type('E', (), {'episode_length': 50})()


def test_budget_counts_evaluations_once_two_epochs_are_measured():
  timing = train._Timing(_Trainer(), evaluates=True)
  notes = []
  timing.add_epoch(30.0, notes.append, 1)  # compilation included
  assert timing.next_epoch() == pytest.approx(36.0)  # no evaluation guess from one epoch
  timing.add_epoch(2.0, notes.append, 2)
  # 1000 env steps of evaluation at 2 ms each, plus the 28 s the first epoch spent compiling
  assert timing.evaluation_estimate() == pytest.approx(2.0 + 28.0)
  assert timing.next_epoch() == pytest.approx(2.4 + 30.0)
  timing.evaluation_seconds, timing.save_seconds = 5.0, 1.0
  assert timing.next_epoch() == pytest.approx(2.4 + 1.0 + 5.0)
  assert notes[0].startswith('epoch 1: 1000 env steps and 10 gradient updates took 30.0 s')
  assert notes[1] == 'an epoch takes about 2 s here; an evaluation about 30 s (estimated)'


# ------------------------------------------------- signals while XLA computes ----

def _train_cmd(out, *extra):
  return [sys.executable, TRAIN_PY, '--task', 'point-mass', '--out', out, '--progress', 'lines',
          '--no-tensorboard', '--nondeterministic', '--eval-instances', '0', *extra]


@pytest.fixture
def train_env(compilation_cache_dir):
  """The training processes' environment: the test run's persistent compilation cache, so
  that the processes of these tests compile the training programs once."""
  return jax_cache_env(compilation_cache_dir)


def test_signals_are_handled_while_an_epoch_runs(tmp_path, train_env):
  """An epoch of minutes: the first SIGINT is acknowledged and the second ends the process
  during it, not after it (as a deadlocked or very long epoch needs)."""
  out = str(tmp_path / 'run')
  previous = {s: signal.signal(s, signal.default_int_handler) for s in (signal.SIGINT,
                                                                         signal.SIGTERM)}
  try:
    proc = subprocess.Popen(_train_cmd(out, '--steps', '10000000', '--steps-per-epoch',
                                       '1000000'), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO, env=train_env)
  finally:
    for s, handler in previous.items():
      signal.signal(s, handler)
  try:
    for line in proc.stdout:
      if 'prefill:' in line:  # init is done; the long first epoch is next
        break
    time.sleep(8.0)  # past the epoch's compilation, into its computation
    proc.send_signal(signal.SIGINT)
    time.sleep(4.0)  # the notice comes after 3 s
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
  finally:
    proc.kill()
  assert proc.returncode == 128 + signal.SIGINT, err[-2000:]
  lines = err.strip().splitlines()
  assert lines[-2].startswith('SIGINT: saving a checkpoint after the current epoch'), err
  assert lines[-1] == f'stopped by SIGINT without saving; {out} keeps its latest checkpoint'


def test_steps_below_one_epoch_are_named_before_work(tmp_path, train_env):
  out = str(tmp_path / 'run')
  proc = subprocess.run(_train_cmd(out, '--steps', '10'), capture_output=True, text=True,
                        timeout=300, cwd=REPO, env=train_env)
  assert proc.returncode == 0, proc.stderr[-2000:]
  lines = proc.stdout.splitlines()
  note = [i for i, line in enumerate(lines) if line.startswith('note: --steps 10 is below one')]
  work = [i for i, line in enumerate(lines) if 'prefill:' in line]
  assert note and work and note[0] < work[0], proc.stdout
  assert 'this run takes 256 random prefill steps and one epoch, 656 env steps' in lines[note[0]]


def test_resume_after_sigkill_has_one_row_per_epoch(tmp_path, train_env):
  out = str(tmp_path / 'run')
  proc = subprocess.Popen(_train_cmd(out, '--steps', '10000000', '--checkpoint-every', '3'),
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO,
                          env=train_env)
  csv_path = os.path.join(out, 'metrics.csv')
  try:
    deadline = time.time() + 240
    while time.time() < deadline:  # some epochs written, checkpoints among them
      if os.path.exists(csv_path) and len(open(csv_path).read().splitlines()) > 8:
        break
      time.sleep(0.2)
    proc.kill()  # SIGKILL: no handler runs
    proc.wait(timeout=60)
  finally:
    proc.kill()
  saved = train.read_run_config(out)['epoch']
  resumed = subprocess.run(_train_cmd(out, '--steps', '10000000', '--resume', '--minutes',
                                      '0.1'), capture_output=True, text=True, timeout=300,
                           cwd=REPO, env=train_env)
  assert resumed.returncode == 0, resumed.stderr[-2000:]
  with open(csv_path) as f:
    epochs = [int(float(row.split(',')[1])) for row in f.read().splitlines()[1:]]
  assert epochs == list(range(1, len(epochs) + 1))  # each epoch once, in order
  assert len(epochs) > saved
  assert not [d for d in os.listdir(os.path.join(out, 'state')) if 'tmp' in d]
  # the export records the physics it was trained on (the point mass: its own JAX transition)
  assert checkpoint.trained_physics(os.path.join(out, checkpoint.MODEL_SUBDIR)) == {
      'engine': 'jax', 'settings': None}
