"""Policy-alone success on every PushT-Obs layout: one deterministic rollout of the shipped
PushT-Fixed model (100-step episodes) per canonical instance, optionally PACHS too.

  python experiments/eval_layouts.py                        # all layouts, 30 instances each
  python experiments/eval_layouts.py --pachs-budget 20000   # and PACHS (results/eval_layouts_cpu)

A layout is meant to need search: the policy alone should solve at most half of its instances
(`MAX_POLICY_SUCCESS`). With `--pachs-budget B` each layout is also planned by PACHS with
`pachs plan`'s settings on this machine at budget B (evidence that its instances can be solved).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

import common
from pachs_jax import argtypes
from pachs_jax.envs import layouts

TASK = 'pusht-obs'
MAX_POLICY_SUCCESS = 0.5


def build_parser() -> argtypes.OneLineParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argtypes.OneLineParser(description=__doc__.splitlines()[0])
  parser.add_argument('--layouts', default=','.join(layouts.NAMES),
                      help=f'comma list of layouts (default: all, {", ".join(layouts.NAMES)})')
  parser.add_argument('--pachs-budget', type=argtypes.integer(0), default=0,
                      help='also plan each layout with PACHS at this budget (0: no)')
  common.add_common_args(parser, out=None, instances=None, backend=True, seed=True)
  parser.set_defaults(backend='auto')  # MuJoCo C physics on a machine without an accelerator
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import jax  # noqa: E402

from pachs_jax import planner  # noqa: E402
from pachs_jax.runtime import programs  # noqa: E402
from pachs_jax.envs import coverage, pusht  # noqa: E402
from pachs_jax.search import baselines as bl  # noqa: E402
# pylint: enable=wrong-import-position


def region_text(layout: layouts.Layout) -> str:
  yaw = layout.start_yaw
  yaw_text = ('any' if np.isclose(yaw[1] - yaw[0], 2 * np.pi)
              else f'[{np.degrees(yaw[0]):.0f}, {np.degrees(yaw[1]):.0f}] deg')
  return (f'x [{layout.start_x[0]:.3f}, {layout.start_x[1]:.3f}], '
          f'y [{layout.start_y[0]:.3f}, {layout.start_y[1]:.3f}], yaw {yaw_text}')


def final_coverage(env, result) -> np.ndarray:
  """[I] coverage of the goal by the T at the path's last node."""
  last = np.asarray(result.path_length)
  rows = np.arange(len(last))
  pose = np.asarray(pusht.t_pose(np.asarray(result.path_nodes.qpos)[rows, np.minimum(last, env.episode_length)]))
  goal = np.asarray(result.path_nodes.goal)[rows, 0]
  return np.asarray(coverage.coverage(pose, goal))


def evaluate(name: str, num: int, backend: str, pachs_budget: int, seed: int) -> dict:
  layout = layouts.layout(name)
  env, model = planner.load_model(TASK, backend=backend, layout=name)
  nodes = env.canonical_instances(num)
  start = time.perf_counter()
  result = jax.block_until_ready(bl.make_single_rollout(env, model)(nodes))
  found = np.asarray(result.found)
  row = {
      'layout': name, 'kind': layout.kind, 'env': env.name, 'blocks': len(layout.blocks),
      'start_region': region_text(layout), 'instances': num,
      'policy_solved': int(found.sum()), 'policy_success': float(found.mean()),
      'policy_invalid': int(np.asarray(result.invalid).sum()),
      'policy_final_coverage_mean': float(final_coverage(env, result).mean()),
      'policy_solved_instances': np.flatnonzero(found).tolist(),
      'policy_s_incl_compile': time.perf_counter() - start,
      'at_most_half': bool(found.mean() <= MAX_POLICY_SUCCESS),
  }
  if pachs_budget:
    # `pachs plan`'s settings on this machine (on a CPU: its CPU overrides), at this budget
    config = dataclasses.replace(
        planner.command_config(TASK, jax.default_backend() == 'cpu',
                               env.physics == 'mujoco-c'),
        budget=pachs_budget)
    plan = programs.plan(env, model, nodes, config, jax.random.PRNGKey(seed))
    plan_found = np.asarray(plan.found)
    row.update({'pachs_budget': pachs_budget, 'pachs_config': repr(config),
                'pachs_solved': int(plan_found.sum()),
                'pachs_success': float(plan_found.mean()),
                'pachs_search_s': float(plan.wall_time_s),
                'pachs_solved_instances': np.flatnonzero(plan_found).tolist()})
  if hasattr(env, 'close'):
    env.close()
  print({k: v for k, v in row.items() if not k.endswith('_instances')}, flush=True)
  return row


def main():
  parser = build_parser()
  args = parser.parse_args()
  names = args.layouts.split(',')
  for name in names:
    try:
      layouts.layout(name)  # unknown names fail before any work
    except ValueError as err:
      parser.error(str(err))
  num = common.task_instances(TASK, args.instances, parser)
  common.check_out(parser, args.out)
  out = args.out or f'experiments/results/eval_layouts_{jax.default_backend()}.json'
  rows = [evaluate(n, num, args.backend, args.pachs_budget, args.seed) for n in names]
  provenance = common.provenance()
  columns = ['layout', 'kind', 'blocks', 'start_region', 'policy_solved', 'instances',
             'policy_success', 'policy_invalid', 'policy_final_coverage_mean', 'at_most_half']
  if args.pachs_budget:
    columns += ['pachs_budget', 'pachs_solved', 'pachs_search_s']
  common.write_result(
      out, {'provenance': provenance, 'task': TASK, 'model': 'pusht-fixed',
            'max_policy_success': MAX_POLICY_SUCCESS, 'rows': rows},
      common.markdown_header(
          'PushT-Obs layouts: single-rollout policy success (shipped PushT-Fixed model, '
          'deterministic action, 100-step episodes)', provenance,
          f'Command: `{provenance["command"]}`') + [common.markdown_table(rows, columns)])
  print(out)


if __name__ == '__main__':
  main()
