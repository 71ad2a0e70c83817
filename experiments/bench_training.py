"""SAC training throughput of PushT per physics engine in one run: env steps/s of the physics
alone (a jitted scan of batched steps with random actions) and of whole training epochs (env
step, replay insert and the preset's gradient updates), MuJoCo Warp against MJX's JAX
implementation, on a named physics preset.

  python experiments/bench_training.py --preset faithful --num-envs 4096 --engines warp,mjx
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import common
from pachs_jax import argtypes
from pachs_jax.envs import physics_presets


def build_parser() -> argtypes.OneLineParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argtypes.OneLineParser(description=__doc__.split('\n')[0])
  parser.add_argument('--task', default='pusht-fixed', choices=('pusht-fixed', 'pusht-rand'))
  parser.add_argument('--preset', default='faithful', choices=physics_presets.NAMES)
  parser.add_argument('--engines', default='warp,mjx')
  parser.add_argument('--num-envs', type=argtypes.positive_int, default=4096)
  parser.add_argument('--physics-steps', type=argtypes.positive_int, default=20,
                      help='batched env steps per timed physics call')
  parser.add_argument('--epochs', type=argtypes.positive_int, default=3,
                      help='timed training epochs per engine (after a first, compiling one)')
  parser.add_argument('--min-replay', type=argtypes.positive_int, default=None,
                      help="replay transitions prefilled before training (default: the preset's)")
  common.add_common_args(parser, out='experiments/results/training/bench_training.json')
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import jax  # noqa: E402

from pachs_jax.envs import backends, pusht, registry  # noqa: E402
from pachs_jax.sac import presets, train  # noqa: E402
from pachs_jax.sac.trainer import make_trainer  # noqa: E402
# pylint: enable=wrong-import-position


def epoch_throughput(env, config, epochs: int) -> dict:
  """Times init (prefill, compilation included) and `epochs` training epochs after the first."""
  trainer = make_trainer(env, config)
  t = time.perf_counter()
  state = train.wait_ready(trainer.init())
  init_s = time.perf_counter() - t
  t = time.perf_counter()
  state, _ = trainer.epoch(state)
  state = train.wait_ready(state)
  first_s = time.perf_counter() - t
  t = time.perf_counter()
  for _ in range(epochs):
    state, metrics = trainer.epoch(state)
  train.wait_ready(metrics)
  per_epoch = (time.perf_counter() - t) / epochs
  return {'init_s': init_s, 'first_epoch_s': first_s, 'epoch_s': per_epoch,
          'env_steps_per_epoch': trainer.env_steps_per_epoch,
          'training_env_steps_per_s': trainer.env_steps_per_epoch / per_epoch}


def write(args: argparse.Namespace, config, rows: list) -> dict:
  """Writes the results JSON and markdown table of `rows`; returns warp / mjx ratios."""
  by = {r['engine']: r for r in rows}
  ratio = {}
  if 'warp' in by and 'mjx' in by:
    ratio = {k: by['warp'][k] / by['mjx'][k]
             for k in ('physics_env_steps_per_s', 'training_env_steps_per_s')}
  payload = {'provenance': common.provenance(), 'task': args.task, 'preset': args.preset,
             'sac_config': dataclasses.asdict(config), 'rows': rows, 'warp_over_mjx': ratio}
  columns = ['engine', 'num_envs', 'physics_env_steps_per_s', 'training_env_steps_per_s',
             'epoch_s', 'init_s', 'physics_compile_s']
  common.write_result(args.out, payload, [common.markdown_table(rows, columns)])
  return ratio


def main() -> None:
  parser = build_parser()
  args = parser.parse_args()
  engines = [e for e in args.engines.split(',') if e]
  bad = sorted(set(engines) - {'warp', 'mjx'})
  if not engines or bad:
    parser.error(f'--engines: a comma list of warp and mjx, got {args.engines!r}')
  common.check_out(parser, args.out)
  config = dataclasses.replace(presets.preset(args.task), num_envs=args.num_envs)
  if args.min_replay is not None:
    config = dataclasses.replace(config, min_replay_size=args.min_replay)
  rows = []
  for engine in engines:
    env = backends.make_backend(registry.make(args.task, physics=args.preset), engine)
    physics = common.env_throughput(env, args.num_envs, args.physics_steps, repeats=3)
    epochs = epoch_throughput(env, config, args.epochs)
    row = {'engine': engine, 'preset': args.preset, 'num_envs': args.num_envs,
           'physics_env_steps_per_s': physics['env_steps_per_s'],
           'physics_compile_s': physics['compile_s'],
           'invalid_edges': physics['invalid_edges'], **epochs}
    rows.append(row)
    print(row, flush=True)
    ratio = write(args, config, rows)  # after each engine: a cut run keeps what it measured
  print('warp / mjx:', ratio)


if __name__ == '__main__':
  main()
