"""Pictures of the PushT tasks: the canonical start poses, goals and PushT-Obs's obstacles
(pusht_tasks.png), and every PushT-Obs layout with its start region (pusht_layouts.png).

  python experiments/draw_pusht_tasks.py --out experiments/results
"""

from __future__ import annotations

import argparse
import os


def build_parser() -> argparse.ArgumentParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argparse.ArgumentParser()
  parser.add_argument('--out', default='experiments/results')
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import numpy as np  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Polygon, Rectangle  # noqa: E402

from pachs_jax import envs  # noqa: E402
from pachs_jax.envs import layouts, pusht, render  # noqa: E402
# pylint: enable=wrong-import-position


def draw_instances(ax, env, title: str, legend: bool = True) -> None:
  nodes = env.canonical_instances(30)
  poses, goals = np.asarray(pusht.t_pose(nodes.qpos)), np.asarray(nodes.goal)
  for i, pose in enumerate(poses):
    ax.add_patch(Polygon(render.t_polygon(pose), closed=True, fc='tab:orange', ec='tab:red',
                         alpha=0.18, lw=0.6, label='start poses' if i == 0 else None))
  for i, goal in enumerate({tuple(g) for g in goals.round(5)}):
    ax.add_patch(Polygon(render.t_polygon(goal), closed=True, fill=False, ec='tab:green',
                         ls='--', lw=1.5, label='goal' if i == 0 else None))
  for i, box in enumerate(env.obstacles):
    ax.add_patch(Polygon(render.box_polygon(box), closed=True, fc='0.45', ec='k',
                         label='obstacles' if i == 0 else None))
  if env.layout is not None:
    lay = env.layout
    ax.add_patch(Rectangle((lay.start_x[0], lay.start_y[0]), lay.start_x[1] - lay.start_x[0],
                           lay.start_y[1] - lay.start_y[0], fill=False, ec='tab:blue', ls=':',
                           lw=1.5, label="start region (T's origin)"))
  ax.plot([pusht.TIP_START_XY[0]], [pusht.TIP_START_XY[1]], 'ko', label='stick tip at start')
  ax.plot([pusht.BASE_POS[0]], [pusht.BASE_POS[1]], 'ks', label='robot base')
  ax.set_xlim(-0.65, 0.3)
  ax.set_ylim(-0.55, 0.45)
  ax.set_aspect('equal')
  ax.set_xlabel('x (m)')
  ax.set_ylabel('y (m)')
  ax.set_title(title)
  if legend:
    ax.legend(loc='lower right', fontsize=7)


def main():
  args = build_parser().parse_args()
  os.makedirs(args.out, exist_ok=True)
  fig = Figure(figsize=(15, 5.6))
  FigureCanvasAgg(fig)
  for k, name in enumerate(['pusht-fixed', 'pusht-rand', 'pusht-obs']):
    suffix = f' ({layouts.DEFAULT})' if name == 'pusht-obs' else ''
    draw_instances(fig.add_subplot(1, 3, k + 1), envs.make(name),
                   f'{name}{suffix}: 30 canonical instances (seed 0)')
  fig.tight_layout()
  path = os.path.join(args.out, 'pusht_tasks.png')
  fig.savefig(path, dpi=110)
  print(path)
  columns = 3
  rows = -(-len(layouts.NAMES) // columns)
  fig = Figure(figsize=(5 * columns, 5.4 * rows))
  FigureCanvasAgg(fig)
  for k, name in enumerate(layouts.NAMES):
    lay = layouts.layout(name)
    default = ' (default)' if name == layouts.DEFAULT else ''
    ax = fig.add_subplot(rows, columns, k + 1)
    draw_instances(ax, envs.make('pusht-obs', layout=name), f"layout '{name}'{default}: {lay.kind}",
                   legend=False)
  fig.suptitle('PushT-Obs layouts: blocks, start region and the 30 canonical instances (seed 0)')
  fig.legend(*ax.get_legend_handles_labels(), loc='lower center', ncol=6, fontsize=9)
  fig.tight_layout(rect=(0, 0.03, 1, 1))
  path = os.path.join(args.out, 'pusht_layouts.png')
  fig.savefig(path, dpi=90)
  print(path)


if __name__ == '__main__':
  main()
