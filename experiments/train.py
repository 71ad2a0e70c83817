"""Train the SAC actor-critic of a task; resumable and time-bounded for 10-minute GPU commands.

--out gets checkpoints, model/ (for the search), metrics.csv (appended to) and status.json; a call
stopped by --minutes, SIGINT (Ctrl-C) or SIGTERM saves a checkpoint after the current epoch and
continues with --resume, bit for bit (XLA deterministic ops unless --nondeterministic); a second
signal stops at once without saving. Exit status: 0 finished or stopped by --minutes, 130 / 143
stopped by SIGINT / SIGTERM, 1 or 2 bad input (one line on stderr)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import signal
import sys
import threading
import time

from pachs_jax import argtypes
from pachs_jax.runtime import files, xla_cpu

SEED_LIMIT = 2**32  # pachs_jax.sac.config.SEED_LIMIT (not imported: no JAX before the checks)
TRAIN_SEED = argtypes.integer(0, SEED_LIMIT, f'must be in [0, 2**32) = [0, {SEED_LIMIT - 1}]')


def parse_args(argv=None) -> argparse.Namespace:
  p = argtypes.OneLineParser(description=__doc__.split('\n')[0])
  p.add_argument('--task', '--env', dest='task', required=True,
                 help="'point-mass', a name of pachs_jax.envs.make, or playground:NAME (a MuJoCo "
                      "Playground env; needs pip install -e '.[playground]')")
  p.add_argument('--steps', type=argtypes.integer(1), required=True,
                 help='total environment steps of the run')
  p.add_argument('--out', required=True, help='run directory')
  p.add_argument('--seed', type=TRAIN_SEED, default=None,
                 help='PRNG seed in [0, 2**32) (preset: 0)')
  p.add_argument('--resume', action='store_true',
                 help='continue the run in --out (an error if it holds none)')
  p.add_argument('--start-if-missing', action='store_true',
                 help='with --resume: start a new run when --out holds none (for job scripts '
                      'that repeat one command)')
  p.add_argument('--minutes', type=argtypes.positive_float, default=None,
                 help='wall-time budget of the command, its start-up and compilation included')
  p.add_argument('--checkpoint-minutes', type=argtypes.positive_float, default=5.0)
  p.add_argument('--checkpoint-every', type=argtypes.integer(0), default=0,
                 help='also save every N epochs')
  p.add_argument('--keep', type=argtypes.integer(1), default=3, help='training checkpoints kept')
  p.add_argument('--progress', choices=('bar', 'lines', 'none'), default=None,
                 help='default: bar on a terminal, else lines')
  p.add_argument('--no-tensorboard', action='store_true')
  p.add_argument('--physics', choices=('auto', 'mjx', 'warp', 'mujoco-c'), default='auto',
                 help="PushT physics engine: 'auto' is MuJoCo C when JAX runs on the CPU (much "
                      "faster there), else Warp where installed (the 'cuda' extra), else MJX")
  p.add_argument('--physics-preset', default=None,
                 help="PushT only: a named physics model (pachs_jax.envs.pusht.PHYSICS_PRESETS; "
                      "default: the task's)")
  p.add_argument('--learner-from', default=None,
                 help='start a new run from a learner file (--learner-out of an earlier run: '
                      'networks, optimisers, temperature, normaliser, counters), its replay '
                      'buffer refilled by its policy')
  p.add_argument('--init-from', default=None,
                 help='a new run fine-tunes this exported model (a model directory, e.g. '
                      "pachs_jax/checkpoints/pusht-fixed; same task and network sizes)")
  p.add_argument('--learner-out', default=None,
                 help='also write the learner (no replay buffer, no env states) to this .npz '
                      'file at every save: a run that moves between machines')
  p.add_argument('--nondeterministic', action='store_true',
                 help='allow non-deterministic GPU ops and autotuning (faster, not resumable '
                      'bit for bit)')
  g = p.add_argument_group('hyperparameter overrides (default: the task preset)')
  g.add_argument('--num-envs', type=int)
  g.add_argument('--batch-size', type=int)
  g.add_argument('--grad-updates', type=int, help='gradient updates per training step')
  g.add_argument('--steps-per-epoch', type=int)
  g.add_argument('--hidden', help="widths of actor and critic, e.g. '256,256,256'")
  g.add_argument('--actor-hidden')
  g.add_argument('--critic-hidden')
  g.add_argument('--lr', type=float, help='learning rate of actor, critic and temperature')
  g.add_argument('--discount', type=float)
  g.add_argument('--reward-scaling', type=float)
  g.add_argument('--replay-capacity', type=int)
  g.add_argument('--min-replay', type=int)
  g.add_argument('--init-alpha', type=float)
  g.add_argument('--eval-instances', type=int)
  g.add_argument('--failure-cost', type=float,
                 help="charged at an episode's failed end (SACConfig.failure_cost)")
  g.add_argument('--absorbing-failure', action=argparse.BooleanOptionalAction, default=None,
                 help="charge a failed end as if its state were kept for ever "
                      "(SACConfig.absorbing_failure)")
  args = p.parse_args(argv)
  if args.start_if_missing and not args.resume:
    p.error('--start-if-missing only goes with --resume')
  return args


def _widths(text: str, flag: str) -> tuple:
  try:
    widths = tuple(int(w) for w in text.split(','))
  except ValueError:
    raise SystemExit(f'{flag} must be comma-separated integers, got {text!r}') from None
  return widths


# SACConfig field -> the flag that sets it (`overrides`), so that a refused value is named as typed
FLAG_OF = {'num_envs': '--num-envs', 'batch_size': '--batch-size',
           'grad_updates_per_step': '--grad-updates', 'steps_per_epoch': '--steps-per-epoch',
           'discount': '--discount', 'reward_scaling': '--reward-scaling',
           'replay_capacity': '--replay-capacity', 'min_replay_size': '--min-replay',
           'init_alpha': '--init-alpha', 'eval_instances': '--eval-instances', 'seed': '--seed',
           'failure_cost': '--failure-cost', 'absorbing_failure': '--absorbing-failure',
           'actor_learning_rate': '--lr', 'critic_learning_rate': '--lr',
           'alpha_learning_rate': '--lr', 'actor_hidden': '--actor-hidden',
           'critic_hidden': '--critic-hidden'}


def with_flags(message: str, changes: dict, args: argparse.Namespace) -> str:
  """A SACConfig refusal with each field the flags set (changes) named by its flag."""
  flag_of = dict(FLAG_OF)
  for side in ('actor', 'critic'):  # widths set by --hidden alone
    if args.hidden is not None and getattr(args, f'{side}_hidden') is None:
      flag_of[f'{side}_hidden'] = '--hidden'
  for field in sorted(changes, key=len, reverse=True):
    flag = flag_of.get(field)
    if flag is not None:
      message = re.sub(rf'\b(SACConfig\.)?{field}\b', flag, message)
  return message


def overrides(args: argparse.Namespace) -> dict:
  """SACConfig fields set by flags."""
  out = {}
  simple = {'num_envs': args.num_envs, 'batch_size': args.batch_size,
            'grad_updates_per_step': args.grad_updates, 'steps_per_epoch': args.steps_per_epoch,
            'discount': args.discount, 'reward_scaling': args.reward_scaling,
            'replay_capacity': args.replay_capacity, 'min_replay_size': args.min_replay,
            'init_alpha': args.init_alpha, 'eval_instances': args.eval_instances,
            'seed': args.seed, 'failure_cost': args.failure_cost,
            'absorbing_failure': args.absorbing_failure}
  out.update({k: v for k, v in simple.items() if v is not None})
  if args.lr is not None:
    out.update(actor_learning_rate=args.lr, critic_learning_rate=args.lr,
               alpha_learning_rate=args.lr)
  if args.hidden is not None:
    out['actor_hidden'] = out['critic_hidden'] = _widths(args.hidden, '--hidden')
  if args.actor_hidden is not None:
    out['actor_hidden'] = _widths(args.actor_hidden, '--actor-hidden')
  if args.critic_hidden is not None:
    out['critic_hidden'] = _widths(args.critic_hidden, '--critic-hidden')
  return out


def make_env(task: str, physics_preset: str | None = None):
  """The task's environment; 'point-mass' is built here, others come from pachs_jax.envs.make
  (PushT with `physics_preset`, a name of `pusht.PHYSICS_PRESETS`, when given)."""
  if physics_preset is not None and not task.startswith('pusht'):
    raise SystemExit(f'error: --physics-preset applies to the PushT tasks, not {task!r}')
  if task == 'point-mass':
    from pachs_jax.envs import point_mass
    return point_mass.PointMassEnv()
  from pachs_jax import envs
  make = getattr(envs, 'make', None)
  if make is None:
    raise SystemExit(f'unknown task {task!r}: pachs_jax.envs.make is not available')
  try:
    envs.spec(task)
  except ValueError as e:
    raise SystemExit(f"{e} (or 'point-mass')") from None
  try:
    return make(task, physics=physics_preset) if physics_preset else make(task)
  except ImportError as e:
    raise SystemExit(f'error: {e}') from None
  except ValueError as e:  # the task is known: with a preset, the preset is what is wrong
    raise SystemExit(f'error: --physics-preset: {e}' if physics_preset
                     else f"{e} (or 'point-mass')") from None


def _holds_run(out: str) -> bool:
  """Whether --out has a training checkpoint directory (a numbered step in state/); cheap, no
  JAX. The exact check (a complete, readable checkpoint) is train.read_run_config."""
  state = os.path.join(out, 'state')
  return os.path.isdir(state) and any(name.isdigit() for name in os.listdir(state))


def _stop_outside_training(out: str):
  """Handler of SIGINT/SIGTERM outside train() (which saves on them): nothing to save, so end
  at once with one line (os._exit: an exception raised inside JAX's compiler can crash the
  interpreter's exit)."""

  def handler(signum, frame):
    del frame
    sys.stdout.flush()
    print(f'stopped by {signal.Signals(signum).name}; {out} keeps its latest checkpoint (if any)',
          file=sys.stderr, flush=True)
    os._exit(128 + signum)  # pylint: disable=protected-access

  return handler


def main(argv=None) -> int:
  args = parse_args(argv)
  args.started_at = time.time()  # --minutes counts from here: imports and compilation included
  # Cheap checks of --out first: no JAX import, nothing written yet.
  if os.path.exists(args.out) and not os.path.isdir(args.out):
    raise SystemExit(f'error: --out {args.out} is a file, not a directory')
  if args.learner_from is not None and not os.path.isfile(args.learner_from):
    raise SystemExit(f'error: --learner-from {args.learner_from} is not a file')
  if args.learner_out is not None and not os.path.isdir(
      os.path.dirname(os.path.abspath(args.learner_out))):
    raise SystemExit(f'error: --learner-out {args.learner_out}: its directory does not exist')
  if args.resume and not args.start_if_missing and not _holds_run(args.out):
    raise SystemExit(f'error: --resume: {args.out} holds no training run (no checkpoint in '
                     f'{os.path.join(args.out, "state")}); drop --resume to start one, or add '
                     '--start-if-missing')
  # Outside train() (which saves on them) SIGINT/SIGTERM end the command with one line.
  previous = {}
  main_thread = threading.current_thread() is threading.main_thread()
  for signum in (signal.SIGINT, signal.SIGTERM) if main_thread else ():
    if signal.getsignal(signum) is not signal.SIG_IGN:
      previous[signum] = signal.signal(signum, _stop_outside_training(args.out))
  try:
    return _main(args)
  finally:
    for signum, handler in previous.items():
      signal.signal(signum, handler)


def _main(args: argparse.Namespace) -> int:
  if not args.nondeterministic:
    flags = os.environ.get('XLA_FLAGS', '')
    if 'xla_gpu_deterministic_ops' not in flags:
      os.environ['XLA_FLAGS'] = (flags + ' --xla_gpu_deterministic_ops=true').strip()
  xla_cpu.configure(os.environ)  # before JAX starts: batched LAPACK calls cannot deadlock

  import jax  # pylint: disable=import-outside-toplevel
  from pachs_jax.sac import (  # pylint: disable=import-outside-toplevel
      checkpoint, learner_file, presets, train)
  from pachs_jax.sac.config import (  # pylint: disable=import-outside-toplevel
      SACConfig, config_from_dict, config_to_dict)
  from pachs_jax.sac.reporting import RunReporter  # pylint: disable=import-outside-toplevel
  from pachs_jax.sac.trainer import make_trainer  # pylint: disable=import-outside-toplevel
  from pachs_jax.envs import backends  # pylint: disable=import-outside-toplevel

  created = not os.path.exists(args.out)
  try:
    train.check_run_dir(args.out)  # every output path writable, before any work
    meta = train.read_run_config(args.out)
  except (train.RunDirError, checkpoint.CheckpointError) as e:
    raise SystemExit(f'error: {e}') from None
  env = make_env(args.task, args.physics_preset)
  changes = overrides(args)
  if meta is None and args.resume and not args.start_if_missing:
    raise SystemExit(f'error: --resume: {args.out} holds no complete training checkpoint; drop '
                     '--resume to start a new run, or add --start-if-missing')
  if meta is not None and args.resume:
    config = config_from_dict(SACConfig, meta['sac_config'])
    clash = {k: (getattr(config, k), v) for k, v in changes.items() if getattr(config, k) != v}
    if clash:
      listed = ', '.join(f'{k} stored {a!r} vs flag {b!r}' for k, (a, b) in clash.items())
      raise SystemExit(f'--resume: flags disagree with the stored config of {args.out}: {listed}')
    print(f'resuming {args.out} at epoch {meta["epoch"]} ({meta["env_steps"]} env steps) of '
          f'{args.steps} env steps', flush=True)
  else:
    if meta is not None:
      raise SystemExit(f'{args.out} already holds a run (epoch {meta["epoch"]}); pass --resume '
                       'to continue it or choose another --out')
    if args.resume:
      print(f'--start-if-missing: {args.out} holds no run; starting a new one', flush=True)
    platform = jax.default_backend()
    if args.task in presets.PRESETS:
      base = presets.preset(args.task, platform)
      if base is not presets.PRESETS[args.task]:
        print(f'{platform} preset for {args.task} (smaller than the GPU one)', flush=True)
    else:
      print(f'no preset for {args.task!r}: using SACConfig defaults', flush=True)
      base = SACConfig()
    try:
      config = dataclasses.replace(base, **changes)
    except ValueError as e:
      if created and not os.listdir(args.out):  # nothing left of a refused run
        os.rmdir(args.out)
      raise SystemExit(f'train.py: error: {with_flags(str(e), changes, args)}') from None
  try:
    env = backends.make_backend(env, args.physics)
  except ValueError as e:
    raise SystemExit(f'error: --physics: {e}') from None
  physics = {'mujoco-c': 'MuJoCo C', 'warp': 'MuJoCo Warp', 'mjx': 'MJX'}.get(env.physics, 'JAX')
  print(f'task {env.name}: obs {env.observation_size}, action {env.action_size}, episode '
        f'{env.episode_length}; device {jax.devices()[0]}; physics {physics}; '
        f'config {json.dumps(config_to_dict(config))}',
        flush=True)
  trainer = make_trainer(env, config)
  init_from = None
  if args.init_from is not None:
    try:
      init_from = checkpoint.load_actor_critic(args.init_from, task=env.name)
    except checkpoint.CheckpointError as e:
      raise SystemExit(f'error: --init-from: {e}') from None
  one_epoch = trainer.env_steps(1)
  updates = config.steps_per_epoch * config.grad_updates_per_step
  print(f'an epoch: {trainer.env_steps_per_epoch} env steps ({config.num_envs} envs x '
        f'{config.steps_per_epoch} steps) and {updates} gradient updates; an evaluation: '
        f'{train.evaluation_env_steps(trainer)} env steps at most', flush=True)
  if args.steps < one_epoch and not (meta is not None and args.resume):
    print(f'note: --steps {args.steps} is below one epoch: this run takes '
          f'{trainer.prefill_env_steps} random prefill steps and one epoch, {one_epoch} env steps '
          '(lower --num-envs, --steps-per-epoch or --min-replay for fewer)', flush=True)
  progress = args.progress or ('bar' if sys.stderr.isatty() else 'lines')
  reporter = RunReporter(args.out, progress=progress, tensorboard=not args.no_tensorboard,
                         description=args.task)
  try:
    result = train.train(trainer, args.out, args.steps, resume=args.resume,
                         start_if_missing=args.start_if_missing, max_minutes=args.minutes,
                         checkpoint_minutes=args.checkpoint_minutes,
                         checkpoint_every_epochs=args.checkpoint_every,
                         keep_checkpoints=args.keep, reporter=reporter, handle_signals=True,
                         started_at=args.started_at, learner_from=args.learner_from,
                         learner_out=args.learner_out, init_from=init_from)
  except (train.RunDirError, checkpoint.CheckpointError, learner_file.LearnerFileError) as e:
    raise SystemExit(f'error: {e}') from None
  interrupted = None if result.finished else result.interrupted
  status = {'task': env.name, 'finished': result.finished, 'epoch': result.epoch,
            'env_steps': result.env_steps, 'total_env_steps': args.steps,
            'interrupted': interrupted,
            'model': os.path.join(os.path.abspath(args.out), 'model')}
  try:
    files.write_json(os.path.join(args.out, 'status.json'), status)
  except files.WriteError as e:
    raise SystemExit(f'error: {e}') from None
  if interrupted is not None:
    if result.epoch > result.start_epoch:
      line = (f'stopped by {interrupted}: saved epoch {result.epoch} ({result.env_steps} env '
              f'steps) in {args.out}; continue with --resume')
    else:
      line = f'stopped by {interrupted} before the first epoch of this call: nothing new to save'
      if result.start_epoch > 0:
        line += f'; {args.out} holds epoch {result.epoch}, continue with --resume'
    print(line, file=sys.stderr, flush=True)
    return 128 + int(getattr(signal, interrupted))
  print(('FINISHED ' if result.finished else 'PARTIAL (run again with --resume) ')
        + json.dumps(status), flush=True)
  return 0


if __name__ == '__main__':
  sys.exit(main())
