"""Train the SAC actor-critic of a task; resumable and time-bounded for 10-minute GPU commands.

--out gets checkpoints, model/ (for the search), metrics.csv and status.json; a call stopped by
--minutes continues with --resume, bit for bit (XLA deterministic ops unless --nondeterministic)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys


def parse_args(argv=None) -> argparse.Namespace:
  p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
  p.add_argument('--task', required=True, help="'point-mass' or a name of pachs_jax.envs.make")
  p.add_argument('--steps', type=int, required=True, help='total environment steps of the run')
  p.add_argument('--out', required=True, help='run directory')
  p.add_argument('--seed', type=int, default=None, help='PRNG seed (preset: 0)')
  p.add_argument('--resume', action='store_true', help="continue the run in --out")
  p.add_argument('--minutes', type=float, default=None, help='wall-time budget of this call')
  p.add_argument('--checkpoint-minutes', type=float, default=5.0)
  p.add_argument('--checkpoint-every', type=int, default=0, help='also save every N epochs')
  p.add_argument('--keep', type=int, default=3, help='training checkpoints kept')
  p.add_argument('--progress', choices=('bar', 'lines', 'none'), default=None,
                 help='default: bar on a terminal, else lines')
  p.add_argument('--no-tensorboard', action='store_true')
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
  return p.parse_args(argv)


def _widths(text: str, flag: str) -> tuple:
  try:
    widths = tuple(int(w) for w in text.split(','))
  except ValueError:
    raise SystemExit(f'{flag} must be comma-separated integers, got {text!r}') from None
  return widths


def overrides(args: argparse.Namespace) -> dict:
  """SACConfig fields set by flags."""
  out = {}
  simple = {'num_envs': args.num_envs, 'batch_size': args.batch_size,
            'grad_updates_per_step': args.grad_updates, 'steps_per_epoch': args.steps_per_epoch,
            'discount': args.discount, 'reward_scaling': args.reward_scaling,
            'replay_capacity': args.replay_capacity, 'min_replay_size': args.min_replay,
            'init_alpha': args.init_alpha, 'eval_instances': args.eval_instances,
            'seed': args.seed}
  out.update({k: v for k, v in simple.items() if v is not None})
  if args.lr is not None:
    out.update(actor_learning_rate=args.lr, critic_learning_rate=args.lr,
               alpha_learning_rate=args.lr)
  if args.hidden:
    out['actor_hidden'] = out['critic_hidden'] = _widths(args.hidden, '--hidden')
  if args.actor_hidden:
    out['actor_hidden'] = _widths(args.actor_hidden, '--actor-hidden')
  if args.critic_hidden:
    out['critic_hidden'] = _widths(args.critic_hidden, '--critic-hidden')
  return out


def make_env(task: str):
  """The task's environment; 'point-mass' is built here, others come from pachs_jax.envs.make."""
  if task == 'point-mass':
    from pachs_jax.envs import point_mass
    return point_mass.PointMassEnv()
  from pachs_jax import envs
  make = getattr(envs, 'make', None)
  if make is None:
    raise SystemExit(f'unknown task {task!r}: pachs_jax.envs.make is not available')
  try:
    return make(task)
  except ValueError as e:
    raise SystemExit(f"{e} (or 'point-mass')") from None


def main(argv=None) -> int:
  args = parse_args(argv)
  if not args.nondeterministic:
    flags = os.environ.get('XLA_FLAGS', '')
    if 'xla_gpu_deterministic_ops' not in flags:
      os.environ['XLA_FLAGS'] = (flags + ' --xla_gpu_deterministic_ops=true').strip()

  import jax  # pylint: disable=import-outside-toplevel
  from pachs_jax.sac import presets, train  # pylint: disable=import-outside-toplevel
  from pachs_jax.sac.config import (  # pylint: disable=import-outside-toplevel
      SACConfig, config_from_dict, config_to_dict)
  from pachs_jax.sac.reporting import RunReporter  # pylint: disable=import-outside-toplevel
  from pachs_jax.sac.trainer import make_trainer  # pylint: disable=import-outside-toplevel

  env = make_env(args.task)
  changes = overrides(args)
  meta = train.read_run_config(args.out)
  if meta is not None and args.resume:
    config = config_from_dict(SACConfig, meta['sac_config'])
    clash = {k: (getattr(config, k), v) for k, v in changes.items() if getattr(config, k) != v}
    if clash:
      listed = ', '.join(f'{k} stored {a!r} vs flag {b!r}' for k, (a, b) in clash.items())
      raise SystemExit(f'--resume: flags disagree with the stored config of {args.out}: {listed}')
    print(f'resuming {args.out} at epoch {meta["epoch"]} ({meta["env_steps"]} env steps)',
          flush=True)
  else:
    if meta is not None:
      raise SystemExit(f'{args.out} already holds a run (epoch {meta["epoch"]}); pass --resume '
                       'to continue it or choose another --out')
    base = presets.PRESETS.get(args.task)
    if base is None:
      print(f'no preset for {args.task!r}: using SACConfig defaults', flush=True)
      base = SACConfig()
    try:
      config = dataclasses.replace(base, **changes)
    except ValueError as e:
      raise SystemExit(str(e)) from None
  print(f'task {env.name}: obs {env.observation_size}, action {env.action_size}, episode '
        f'{env.episode_length}; device {jax.devices()[0]}; '
        f'config {json.dumps(config_to_dict(config))}',
        flush=True)
  trainer = make_trainer(env, config)
  progress = args.progress or ('bar' if sys.stderr.isatty() else 'lines')
  reporter = RunReporter(args.out, progress=progress, tensorboard=not args.no_tensorboard,
                         description=args.task)
  result = train.train(trainer, args.out, args.steps, resume=args.resume,
                       max_minutes=args.minutes, checkpoint_minutes=args.checkpoint_minutes,
                       checkpoint_every_epochs=args.checkpoint_every,
                       keep_checkpoints=args.keep, reporter=reporter)
  status = {'task': env.name, 'finished': result.finished, 'epoch': result.epoch,
            'env_steps': result.env_steps, 'total_env_steps': args.steps,
            'model': os.path.join(os.path.abspath(args.out), 'model')}
  with open(os.path.join(args.out, 'status.json'), 'w') as f:
    json.dump(status, f, indent=2)
  print(('FINISHED ' if result.finished else 'PARTIAL (run again with --resume) ')
        + json.dumps(status), flush=True)
  return 0


if __name__ == '__main__':
  sys.exit(main())
