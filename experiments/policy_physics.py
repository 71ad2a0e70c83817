"""How a PushT policy pushes under each physics preset: its deterministic rollouts in MuJoCo C
on canonical instances, counting successes, episodes ended by a tipped T or another invalid
edge, and the stick tip's height (median over steps with the tip within 10 cm of the T).
--presets takes `pusht.PHYSICS_PRESETS` names and physics_agreement.py's penetration
candidates (a shorter step, a contact margin), the policy trained on one physics pushed in
another.

  python experiments/policy_physics.py --presets faithful --instances 30
  python experiments/policy_physics.py --presets 'faithful,faithful 1.25ms x40' --instances 30
"""

from __future__ import annotations

import os

import numpy as np

import common
from pachs_jax import argtypes


def build_parser() -> argtypes.OneLineParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argtypes.OneLineParser(description=__doc__.split('\n')[0])
  parser.add_argument('--task', default='pusht-fixed', choices=('pusht-fixed', 'pusht-rand'))
  parser.add_argument('--presets', default='faithful')
  parser.add_argument('--instances', type=argtypes.positive_int, default=16)
  parser.add_argument('--model', default=None, type=argtypes.path('a model directory'),
                      help='model directory (default: the shipped)')
  common.add_common_args(parser, out='experiments/results/training/policy_physics.json')
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import jax  # noqa: E402

from pachs_jax import planner  # noqa: E402
from pachs_jax.envs import backends, pusht  # noqa: E402
# pylint: enable=wrong-import-position


def config_of(task: str, preset: str) -> pusht.PushTConfig:
  """The task's config with a `pusht.PHYSICS_PRESETS` entry or a physics_agreement.py
  penetration candidate (physics fields over the planar preset)."""
  variant = task.split('-')[1]
  if preset in pusht.PHYSICS_PRESETS:
    return pusht.physics_preset(preset, variant=variant)
  import physics_agreement  # pylint: disable=import-outside-toplevel
  return pusht.PushTConfig(variant=variant, **{**physics_agreement.BASE,
                                               **physics_agreement.PENETRATION[preset]})


def rollouts(task: str, preset: str, instances: int, model_dir: str) -> dict:
  """The summary row of the policy of `model_dir` on `preset` (MuJoCo C, deterministic)."""
  config = config_of(task, preset)
  env = backends.make_backend(pusht.PushTEnv(config), 'mujoco-c')
  _, model = planner.load_model(task, path=model_dir)
  nodes = env.canonical_instances(instances)
  alive = np.ones(instances, bool)
  success = np.zeros(instances, bool)
  tipped = np.zeros(instances, bool)
  heights = []
  for _ in range(env.episode_length):
    out = env.evaluate(nodes, model.deterministic_action(env.observe(nodes)))
    valid, goal = np.asarray(out.is_valid), np.asarray(out.is_goal)
    tilt = np.asarray(pusht.t_tilt(out.next_node.qpos))
    success |= alive & goal
    tipped |= alive & ~valid & (tilt >= pusht.MAX_T_TILT)
    tip = np.asarray(jax.vmap(env.tip_position)(out.next_node))
    near = alive & valid & (np.linalg.norm(
        tip[:, :2] - np.asarray(pusht.t_pose(out.next_node.qpos))[:, :2], axis=1) < 0.1)
    heights.extend(tip[near, 2].tolist())
    alive &= valid & ~goal
    nodes = out.next_node
  return {'task': task, 'preset': preset, 'instances': instances,
          'success': int(success.sum()), 'tipped': int(tipped.sum()),
          'other_invalid': int((~alive & ~success & ~tipped).sum()),
          'tip_height_near_t_median_m': float(np.median(heights)) if heights else None,
          't_top_m': 2 * pusht.T_HALF_HEIGHT}


def main() -> None:
  parser = build_parser()
  args = parser.parse_args()
  presets = [p for p in args.presets.split(',') if p]
  import physics_agreement  # pylint: disable=import-outside-toplevel
  known = list(dict.fromkeys(list(pusht.PHYSICS_PRESETS) + list(physics_agreement.PENETRATION)))
  bad = sorted(set(presets) - set(known))
  if not presets or bad:
    parser.error(f'--presets: names of {", ".join(known)}; got {bad}')
  common.check_out(parser, args.out)
  common.task_instances(args.task, args.instances, parser)
  if args.model is not None and not os.path.isdir(args.model):
    parser.error(f'--model {args.model!r}: not a model directory')
  rows = []
  for preset in presets:
    rows.append(rollouts(args.task, preset, args.instances, args.model))
    print(rows[-1], flush=True)
  common.write_result(args.out, {'provenance': common.provenance(),
                                 'model': args.model or 'shipped', 'rows': rows},
                      [common.markdown_table(rows, list(rows[0]))])


if __name__ == '__main__':
  main()
