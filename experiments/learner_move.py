"""What moving a SAC run through its learner file does to learning, on the analytic point-mass
task (CPU, seconds per run): per seed, a run trained straight to --steps against the same run
moved at --move-at env steps (its learner file only; the replay buffer refilled by its policy),
both scored by their final policy's deterministic success and cost on 256 start nodes.

  python experiments/learner_move.py --seeds 5
"""

from __future__ import annotations

import dataclasses
import os
import tempfile

import numpy as np

import common
from pachs_jax import argtypes


def build_parser() -> argtypes.OneLineParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argtypes.OneLineParser(description=__doc__.split('\n')[0])
  parser.add_argument('--seeds', type=argtypes.positive_int, default=5)
  parser.add_argument('--steps', type=argtypes.positive_int, default=3000)
  parser.add_argument('--move-at', type=argtypes.positive_int, default=1500)
  common.add_common_args(parser, out='experiments/results/training/learner_move.json')
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import jax  # noqa: E402

from pachs_jax.envs.point_mass import PointMassEnv  # noqa: E402
from pachs_jax.sac import evaluator, presets, train  # noqa: E402
from pachs_jax.sac.trainer import make_trainer  # noqa: E402
# pylint: enable=wrong-import-position


def score(env, model, nodes) -> dict:
  """Deterministic success rate and mean cost of the policy from nodes."""
  out = evaluator.make_rollout_fn(env, deterministic=True)(model, nodes, jax.random.PRNGKey(0))
  return {'success': float(np.mean(out.success)), 'cost': float(np.mean(out.cost))}


def main() -> None:
  parser = build_parser()
  args = parser.parse_args()
  if args.move_at >= args.steps:
    parser.error(f'--move-at ({args.move_at}) must be below --steps ({args.steps})')
  common.check_out(parser, args.out)
  env = PointMassEnv()
  nodes = env.initial_nodes(jax.random.split(jax.random.PRNGKey(2024), 256))
  rows = []
  for seed in range(args.seeds):
    config = dataclasses.replace(presets.preset('point-mass'), seed=seed, eval_instances=0)
    trainer = make_trainer(env, config)
    with tempfile.TemporaryDirectory() as tmp:
      straight = train.train(trainer, os.path.join(tmp, 'straight'), args.steps)
      learner = os.path.join(tmp, 'learner.npz')
      train.train(trainer, os.path.join(tmp, 'before'), args.move_at, learner_out=learner)
      moved = train.train(trainer, os.path.join(tmp, 'moved'), args.steps, learner_from=learner)
    row = {'seed': seed, 'straight': score(env, straight.actor_critic, nodes),
           'moved': score(env, moved.actor_critic, nodes),
           'gradient_steps': [int(straight.state.gradient_steps),
                              int(moved.state.gradient_steps)]}
    rows.append(row)
    print(row, flush=True)
  mean = lambda run, key: float(np.mean([r[run][key] for r in rows]))
  summary = {run: {key: mean(run, key) for key in ('success', 'cost')}
             for run in ('straight', 'moved')}
  table = [{'run': run, **values} for run, values in summary.items()]
  common.write_result(args.out, {'provenance': common.provenance(), 'settings': vars(args),
                                 'rows': rows, 'summary': summary},
                      [common.markdown_table(table, ['run', 'success', 'cost'])])
  print(summary)


if __name__ == '__main__':
  main()
