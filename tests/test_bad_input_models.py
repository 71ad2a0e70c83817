"""Bad model checkpoints and bad training input: each is refused with one line naming the file
(`checkpoint.CheckpointError`, `train.RunDirError`, one-line CLI errors), nothing loads silently,
and an interrupted training run saves a checkpoint that --resume continues.

Damage is done to copies (in tmp_path) of the shipped checkpoints; the training runs are tiny
point-mass runs of experiments/train.py in subprocesses, sharing a JAX compilation cache.
"""

import gc
import glob
import importlib.util
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import jax_cache_env

from pachs_jax.sac import checkpoint, train, verify
from pachs_jax.sac.config import SACConfig
from pachs_jax.sac.trainer import make_trainer

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHIPPED = sorted(glob.glob(os.path.join(REPO, 'pachs_jax', 'checkpoints', '*')))
TRAIN_PY = os.path.join(REPO, 'experiments', 'train.py')
SMALLEST = min(SHIPPED, key=lambda d: sum(os.path.getsize(f) for f in glob.glob(
    os.path.join(d, '**', '*'), recursive=True) if os.path.isfile(f)))


def _copy(tmp_path, name='ck'):
  dst = str(tmp_path / name)
  shutil.copytree(SMALLEST, dst)
  return dst


def _largest_file(directory):
  files = [f for f in glob.glob(os.path.join(directory, '**', '*'), recursive=True)
           if os.path.isfile(f)]
  return max(files, key=os.path.getsize)


def _refused(path, pattern, **kwargs):
  """The one-line CheckpointError that loading `path` raises; it names `path`."""
  with pytest.raises(checkpoint.CheckpointError, match=pattern) as info:
    checkpoint.load_actor_critic(path, **kwargs)
  message = str(info.value)
  assert '\n' not in message, message
  assert path in message, message
  return message


def _edit_json(path, edit):
  file = os.path.join(path, checkpoint.CONFIG_FILE)
  with open(file) as f:
    meta = json.load(f)
  edit(meta)
  with open(file, 'w') as f:
    json.dump(meta, f)


# ------------------------------------------------------------------ shipped checkpoints ----

def test_shipped_checkpoints_carry_and_verify_their_hash():
  assert {os.path.basename(d) for d in SHIPPED} >= {'pusht-fixed', 'pusht-rand', 'shelf'}
  for path in SHIPPED:
    with open(os.path.join(path, checkpoint.CONFIG_FILE)) as f:
      meta = json.load(f)
    recorded = meta[checkpoint.HASH_KEY]
    assert re.fullmatch('[0-9a-f]{64}', recorded), path
    assert meta[checkpoint.META_HASH_KEY] == checkpoint.meta_hash(meta), path
    ac = checkpoint.load_actor_critic(path)  # verifies the hash
    tree = {'normalizer': dict(ac.params.normalizer), 'policy': ac.params.policy,
            'q': ac.params.q}
    assert checkpoint.params_hash(tree) == recorded, path
  assert verify.main(SHIPPED) == 0


def test_params_hash_sees_every_bit_and_name():
  tree = {'a': np.arange(6, dtype=np.float32).reshape(2, 3), 'b': {'c': np.zeros(2, np.float32)}}
  digest = checkpoint.params_hash(tree)
  assert digest == checkpoint.params_hash({'b': {'c': np.zeros(2, np.float32)},
                                           'a': np.arange(6, dtype=np.float32).reshape(2, 3)})
  flipped = tree['a'].copy()
  flipped.view(np.uint32)[1, 2] ^= 1  # one bit of one weight
  assert checkpoint.params_hash(dict(tree, a=flipped)) != digest
  assert checkpoint.params_hash(dict(tree, a=tree['a'].reshape(3, 2))) != digest
  assert checkpoint.params_hash({'x': tree['a'], 'b': tree['b']}) != digest


# ---------------------------------------------------------------- damaged checkpoints ----

def test_overwritten_weights_are_refused_by_the_hash(tmp_path):
  path = _copy(tmp_path)
  data = _largest_file(os.path.join(path, 'params'))
  with open(data, 'r+b') as f:  # 4 KiB in the middle of the largest weight file, inverted
    f.seek(os.path.getsize(data) // 2)
    block = f.read(4096)
    f.seek(-len(block), os.SEEK_CUR)
    f.write(bytes(b ^ 0xFF for b in block))
  # The damage reads back without any error: only the hash catches it.
  config, _ = checkpoint._read_model_config(path)
  damaged = checkpoint._restore_params(path, config)
  original = checkpoint.load_actor_critic(SMALLEST)
  assert checkpoint.params_hash(damaged) != checkpoint.params_hash(
      {'normalizer': dict(original.params.normalizer), 'policy': original.params.policy,
       'q': original.params.q})
  _refused(path, r'params hash mismatch \(file damaged\?\)')
  assert verify.main([path]) == 1
  with pytest.raises(checkpoint.CheckpointError, match='params hash mismatch'):
    checkpoint.add_hashes(path)  # --add-hash does not paper over damage


def test_truncated_or_missing_params_files_are_one_line_errors(tmp_path, capfd):
  truncated = _copy(tmp_path, 'truncated')
  data = _largest_file(os.path.join(truncated, 'params'))
  os.truncate(data, os.path.getsize(data) // 2)
  _refused(truncated, r'cannot read params/ \(file truncated, damaged or missing\?\)')
  missing = _copy(tmp_path, 'missing')
  os.remove(_largest_file(os.path.join(missing, 'params')))
  _refused(missing, r'cannot read params/ \(file truncated')
  no_metadata = _copy(tmp_path, 'no_metadata')
  os.remove(os.path.join(no_metadata, 'params', '_METADATA'))
  _refused(no_metadata, r'params/_METADATA is missing')
  no_params = _copy(tmp_path, 'no_params')
  shutil.rmtree(os.path.join(no_params, 'params'))
  _refused(no_params, r'missing params/ directory')
  _refused(str(tmp_path / 'nowhere'), 'does not exist')
  _refused(str(tmp_path), 'not an actor-critic checkpoint')
  gc.collect()
  err = capfd.readouterr().err
  assert 'Traceback' not in err and 'TensorStore' not in err, err[-2000:]


def test_model_json_without_required_entries(tmp_path):
  no_model = _copy(tmp_path, 'no_model')
  _edit_json(no_model, lambda m: m.pop('model'))
  _refused(no_model, 'has no "model" object')
  no_size = _copy(tmp_path, 'no_size')
  _edit_json(no_size, lambda m: m['model'].pop('action_size'))
  _refused(no_size, r"\"model\" lacks required fields \['action_size'\]")
  bad_activation = _copy(tmp_path, 'bad_activation')
  _edit_json(bad_activation, lambda m: m['model'].update(activation='bogus'))
  _refused(bad_activation, 'invalid "model" config')
  not_json = _copy(tmp_path, 'not_json')
  with open(os.path.join(not_json, checkpoint.CONFIG_FILE), 'r+') as f:
    f.truncate(40)
  _refused(not_json, 'is not valid JSON')
  wrong_format = _copy(tmp_path, 'wrong_format')
  _edit_json(wrong_format, lambda m: m.update(format='other/1'))
  _refused(wrong_format, 'unknown checkpoint format')
  wrong_hash = _copy(tmp_path, 'wrong_hash')
  _edit_json(wrong_hash, lambda m: m.update({checkpoint.HASH_KEY: '0' * 64}))
  _refused(wrong_hash, 'changed after it was written')
  rehashed = _copy(tmp_path, 'rehashed')  # a wrong parameter hash with a matching meta hash
  _edit_json(rehashed, lambda m: m.update({checkpoint.HASH_KEY: '0' * 64,
                                           checkpoint.META_HASH_KEY: checkpoint.meta_hash(
                                               dict(m, **{checkpoint.HASH_KEY: '0' * 64}))}))
  _refused(rehashed, 'params hash mismatch')
  # Without hashes (exports from before them, or before metadata hashes): refused, until
  # --add-hash records them; the files then equal the shipped ones.
  for name, keys in (('no_hash', (checkpoint.HASH_KEY, checkpoint.META_HASH_KEY)),
                     ('no_meta_hash', (checkpoint.META_HASH_KEY,))):
    path = _copy(tmp_path, name)
    _edit_json(path, lambda m, keys=keys: [m.pop(k) for k in keys])
    _refused(path, rf'has no "{keys[0]}" \(written before .*hashes.*\).*run: '
                   rf'python -m pachs_jax\.sac\.verify --add-hash {re.escape(path)}$')
    assert verify.main(['--add-hash', path]) == 0
    with open(os.path.join(path, checkpoint.CONFIG_FILE)) as f, \
         open(os.path.join(SMALLEST, checkpoint.CONFIG_FILE)) as g:
      assert json.load(f) == json.load(g)
    checkpoint.load_actor_critic(path)


def test_metadata_naming_another_task_is_refused(tmp_path):
  """The parameters are untouched; only actor_critic.json names another task (same sizes)."""
  path = _copy(tmp_path)
  with open(os.path.join(path, checkpoint.CONFIG_FILE)) as f:
    task = json.load(f)['model']['task']
  other = 'playground:ReacherHard' if task != 'playground:ReacherHard' else (
      'playground:ReacherEasy')
  _edit_json(path, lambda m: m['model'].update(task=other))
  message = _refused(path, r'changed after it was written \(meta hash mismatch; it now names '
                           rf"task '{re.escape(other)}'\).*--add-hash")
  _refused(path, 'changed after it was written', task=other)  # also when asked for that task
  assert verify.main([path]) == 1
  assert 'verify --add-hash' in message
  for key in ('discount', 'reward_scaling', 'episode_length'):  # any field counts
    edited = _copy(tmp_path, key)
    _edit_json(edited, lambda m, key=key: m['model'].update({key: m['model'][key] * 2 + 1}))
    _refused(edited, 'meta hash mismatch')


def test_saved_export_round_trips_its_hash(tmp_path):
  ac = checkpoint.load_actor_critic(SMALLEST)
  path = checkpoint.save_actor_critic(str(tmp_path / 'export'), ac, extra={'epoch': 3})
  with open(os.path.join(path, checkpoint.CONFIG_FILE)) as f:
    meta = json.load(f)
  with open(os.path.join(SMALLEST, checkpoint.CONFIG_FILE)) as f:
    assert meta[checkpoint.HASH_KEY] == json.load(f)[checkpoint.HASH_KEY]
  assert meta['epoch'] == 3
  checkpoint.load_actor_critic(path)


# ------------------------------------------------------------ training: bad arguments ----

@pytest.fixture(scope='module')
def cli():
  spec = importlib.util.spec_from_file_location('train_cli', TRAIN_PY)
  module = importlib.util.module_from_spec(spec)
  spec.loader.exec_module(module)
  return module


def _cli_error(cli, capsys, args):
  """(exit code, the one line printed) of a train.py call that must fail before training."""
  base = ['--task', 'point-mass', '--progress', 'none', '--nondeterministic']
  with pytest.raises(SystemExit) as info:
    cli.main(base + args)
  err = capsys.readouterr().err.strip()
  code = info.value.code
  if isinstance(code, str):  # SystemExit(message): Python prints it to stderr and exits 1
    err, code = code, 1
  assert err and '\n' not in err, err
  return code, err


def test_train_cli_argument_errors(cli, capsys, tmp_path):
  out = str(tmp_path / 'run')
  cases = [
      (['--steps', '0', '--out', out], 2, 'argument --steps: must be >= 1, got 0'),
      (['--steps', '-5', '--out', out], 2, 'argument --steps: must be >= 1, got -5'),
      (['--steps', '100', '--out', out, '--seed', str(2**64)], 2,
       r'argument --seed: must be in \[0, 2\*\*32\)'),
      (['--steps', '100', '--out', out, '--seed', '-1'], 2, 'argument --seed: must be in'),
      (['--steps', '100', '--out', out, '--minutes', '0'], 2, 'argument --minutes'),
      (['--steps', '100', '--out', out, '--start-if-missing'], 2,
       '--start-if-missing only goes with --resume'),
      (['--steps', '100', '--out', out, '--resume'], 1,
       '--resume: .* holds no training run .*--start-if-missing'),
      # config values are named by the flags that set them
      (['--steps', '100', '--out', out, '--batch-size', '0'], 1,
       r'^train.py: error: --batch-size must be > 0, got 0$'),
      (['--steps', '100', '--out', out, '--min-replay', '5', '--replay-capacity', '2'], 1,
       r'--replay-capacity \(2\) must hold .* --min-replay \(5\)'),
      (['--steps', '100', '--out', out, '--hidden', '0,4'], 1,
       r'--hidden must be non-empty positive widths'),
  ]
  for args, want_code, pattern in cases:
    code, err = _cli_error(cli, capsys, args)
    assert code == want_code and re.search(pattern, err), (args, code, err)
  assert not os.path.exists(out)  # nothing was created
  a_file = tmp_path / 'file'
  a_file.write_text('x')
  code, err = _cli_error(cli, capsys, ['--steps', '100', '--out', str(a_file)])
  assert code == 1 and err == f'error: --out {a_file} is a file, not a directory'
  assert a_file.read_text() == 'x'
  # A run directory whose parts are the wrong kind: found before any training.
  os.makedirs(out)
  (tmp_path / 'run' / 'state').write_text('')
  code, err = _cli_error(cli, capsys, ['--steps', '100', '--out', out])
  assert code == 1 and 'error: run directory' in err and 'state must be a directory' in err
  os.remove(os.path.join(out, 'state'))
  os.makedirs(os.path.join(out, 'metrics.csv'))
  code, err = _cli_error(cli, capsys, ['--steps', '100', '--out', out])
  assert code == 1 and 'metrics.csv must be a file' in err


def _unwritable_dir(tmp_path):
  """A directory this process cannot create files in, or None."""
  locked = tmp_path / 'locked'
  locked.mkdir()
  os.chmod(locked, 0o555)
  for candidate in (str(locked), '/sys'):
    try:
      with open(os.path.join(candidate, '.probe'), 'w'):
        pass
      os.remove(os.path.join(candidate, '.probe'))
    except OSError:
      return candidate
  return None


def test_unwritable_out_is_refused_before_training(cli, capsys, tmp_path):
  directory = _unwritable_dir(tmp_path)
  if directory is None:
    pytest.skip('no unwritable directory available (root without a read-only mount)')
  for out in (directory, os.path.join(directory, 'run')):
    code, err = _cli_error(cli, capsys, ['--steps', '100', '--out', out])
    assert code == 1 and re.search(r'^error: run directory .*: cannot (write in|be created)',
                                   err), err
    with pytest.raises(train.RunDirError, match='cannot'):
      train.check_run_dir(out)
  os.chmod(tmp_path / 'locked', 0o755)


def test_seed_error_is_one_line_from_the_command_line():
  proc = subprocess.run([sys.executable, TRAIN_PY, '--task', 'point-mass', '--steps', '10',
                         '--out', 'unused', '--seed', str(2**64)],
                        capture_output=True, text=True, timeout=60, cwd=REPO)
  assert proc.returncode == 2
  assert proc.stderr.strip().splitlines() == [
      f'train.py: error: argument --seed: must be in [0, 2**32) = [0, {2**32 - 1}], got '
      f'{2**64} (see --help)']


def test_library_resume_needs_a_run(tmp_path):
  from pachs_jax.envs.point_mass import PointMassEnv  # pylint: disable=import-outside-toplevel
  trainer = make_trainer(PointMassEnv(), SACConfig(num_envs=4, batch_size=8, min_replay_size=8,
                                                   replay_capacity=64, eval_instances=0))
  with pytest.raises(train.RunDirError, match='holds no training run to resume'):
    train.train(trainer, str(tmp_path / 'empty'), 100, resume=True)
  with pytest.raises(ValueError, match='seed must be an integer in'):
    SACConfig(seed=2**32)


# ------------------------------------------------------ training: interrupt and resume ----

def _train_cmd(out, *extra):
  return [sys.executable, TRAIN_PY, '--task', 'point-mass', '--out', out, '--progress', 'lines',
          '--no-tensorboard', '--nondeterministic', '--eval-instances', '0', *extra]


def _popen_with_default_signals(*args, **kwargs):
  """Popen whose child gets SIGINT and SIGTERM as in a terminal: a background shell job (e.g. a
  CI runner's) starts with them ignored, children inherit that, and training respects an
  ignored signal. A handled signal is reset to default in the child by exec."""
  previous = {s: signal.signal(s, signal.default_int_handler) for s in (signal.SIGINT,
                                                                         signal.SIGTERM)}
  try:
    return subprocess.Popen(*args, **kwargs)
  finally:
    for s, handler in previous.items():
      signal.signal(s, handler)


@pytest.fixture(scope='module')
def run_env(compilation_cache_dir, tmp_path_factory):
  """Environment of the training subprocesses: one JAX compilation cache for all of them, the
  test run's (conftest.py) or else the module's own."""
  return jax_cache_env(compilation_cache_dir or str(tmp_path_factory.mktemp('jax_cache')))


@pytest.fixture(scope='module')
def interrupted_run(tmp_path_factory, run_env):
  """A point-mass run sent SIGINT after its first progress line: (out, returncode, stdout,
  stderr, copy of out as the signal left it)."""
  out = str(tmp_path_factory.mktemp('sigint') / 'run')
  proc = _popen_with_default_signals(_train_cmd(out, '--steps', '10000000'),
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     cwd=REPO, env=run_env)
  lines = []
  deadline = time.time() + 120
  for line in proc.stdout:
    lines.append(line)
    if line.startswith('[point-mass] env_steps=') or time.time() > deadline:
      proc.send_signal(signal.SIGINT)
      break
  try:
    rest, err = proc.communicate(timeout=120)
  finally:
    proc.kill()  # a no-op once it exited; never leave a 10M-step run behind
  copy = out + '-as-interrupted'
  if os.path.isdir(out):
    shutil.copytree(out, copy)
  return out, proc.returncode, ''.join(lines) + rest, err, copy


def test_sigint_saves_a_resumable_checkpoint(interrupted_run):
  out, code, stdout, stderr, _ = interrupted_run
  assert any(line.startswith('[point-mass] env_steps=') for line in stdout.splitlines()), stdout
  assert code == 128 + signal.SIGINT, (code, stderr[-2000:])
  assert 'Traceback' not in stderr and 'KeyboardInterrupt' not in stderr, stderr[-2000:]
  last = stderr.strip().splitlines()[-1]
  match = re.fullmatch(r'stopped by SIGINT: saved epoch (\d+) \((\d+) env steps\) in (.*); '
                       r'continue with --resume', last)
  assert match and match.group(3) == out, last
  meta = train.read_run_config(out)
  assert meta['epoch'] == int(match.group(1)) >= 1
  assert meta['env_steps'] == int(match.group(2))
  assert re.fullmatch('[0-9a-f]{64}', meta[checkpoint.STATE_HASH_KEY])
  with open(os.path.join(out, 'status.json')) as f:
    status = json.load(f)
  assert status['interrupted'] == 'SIGINT' and not status['finished']
  assert status['epoch'] == meta['epoch']
  exported = checkpoint.load_actor_critic(out)  # the model export, hash verified
  assert exported.config.task == 'point-mass'


def _metric_rows(out):
  with open(os.path.join(out, 'metrics.csv')) as f:
    return f.read().splitlines()


def test_resume_continues_and_appends_metrics(interrupted_run, run_env):
  out, _, _, _, _ = interrupted_run
  meta = train.read_run_config(out)
  rows = _metric_rows(out)
  assert rows[0].startswith('env_steps,') and len(rows) >= 2
  # A row past the checkpoint and a row cut short, as a hard kill (SIGKILL) mid-run leaves, and
  # the temporary directories of a save cut short: all dropped on resume.
  late = rows[-1].split(',')
  late[:2] = [str(meta['env_steps'] + 400), f'{meta["epoch"] + 1}.0']
  with open(os.path.join(out, 'metrics.csv'), 'a') as f:
    f.write(','.join(late) + '\r\n' + ','.join(late)[:9])
  partial = [os.path.join(out, 'state', f'{meta["epoch"] + 1}.orbax-checkpoint-tmp-1234'),
             os.path.join(out, 'model.tmp-999999999')]
  for directory in partial:
    os.makedirs(directory)
  before = rows
  # Two more epochs of 400 env steps.
  total = meta['env_steps'] + 800
  proc = subprocess.run(_train_cmd(out, '--steps', str(total), '--resume'), capture_output=True,
                        text=True, timeout=180, cwd=REPO, env=run_env)
  assert proc.returncode == 0, proc.stderr[-2000:]
  assert (f'resuming {out} at epoch {meta["epoch"]} ({meta["env_steps"]} env steps)'
          in proc.stdout), proc.stdout
  assert 'FINISHED' in proc.stdout
  after = _metric_rows(out)
  assert after[:len(before)] == before  # the rows up to the checkpoint stay as they were
  new = after[len(before):]
  assert [int(r.split(',')[1].split('.')[0]) for r in new] == [meta['epoch'] + 1,
                                                                meta['epoch'] + 2]
  assert not any(os.path.exists(d) for d in partial)
  assert train.read_run_config(out)['epoch'] == meta['epoch'] + 2


def test_sigterm_before_the_first_epoch_saves_nothing(tmp_path, run_env):
  out = str(tmp_path / 'run')
  proc = _popen_with_default_signals(_train_cmd(out, '--steps', '10000000'),
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     cwd=REPO, env=run_env)
  for line in proc.stdout:  # 'task ...': JAX is imported, training not started
    if line.startswith('task point-mass'):
      break
  proc.send_signal(signal.SIGTERM)
  try:
    _, err = proc.communicate(timeout=120)
  finally:
    proc.kill()
  assert proc.returncode == 128 + signal.SIGTERM, (proc.returncode, err[-2000:])
  assert 'Traceback' not in err, err[-2000:]
  last = err.strip().splitlines()[-1]
  # Caught by the command (before train()) or by train() before its first epoch ends.
  assert (last == f'stopped by SIGTERM; {out} keeps its latest checkpoint (if any)' or
          last == 'stopped by SIGTERM before the first epoch of this call: nothing new to save'
          ), last
  assert train.read_run_config(out) is None


def test_damaged_training_state_is_refused(interrupted_run, run_env):
  _, _, _, _, copy = interrupted_run
  meta = train.read_run_config(copy)
  epoch_dir = os.path.join(copy, train.STATE_SUBDIR, str(meta['epoch']))
  data = _largest_file(epoch_dir)
  with open(data, 'r+b') as f:
    f.seek(os.path.getsize(data) // 2)
    block = f.read(4096)
    f.seek(-len(block), os.SEEK_CUR)
    f.write(bytes(b ^ 0xFF for b in block))
  proc = subprocess.run(_train_cmd(copy, '--steps', '100000', '--resume'), capture_output=True,
                        text=True, timeout=180, cwd=REPO, env=run_env)
  assert proc.returncode == 1, (proc.returncode, proc.stderr[-2000:])
  last = proc.stderr.strip().splitlines()[-1]
  assert re.fullmatch(r'error: training checkpoint .*: (state hash mismatch \(file damaged\?\)|'
                      r'cannot read the training state \(file truncated, damaged or missing\?\)'
                      r'.*)', last), last
  assert 'Traceback' not in proc.stderr
