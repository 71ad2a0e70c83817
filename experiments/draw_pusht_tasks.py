"""Pictures of the PushT tasks: the canonical start poses, goals and PushT-Obs's obstacles.

  python experiments/draw_pusht_tasks.py --out experiments/results
"""

from __future__ import annotations

import argparse
import os

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Polygon

from pachs_jax import envs
from pachs_jax.envs import pusht, render


def draw_instances(ax, env, title: str) -> None:
  nodes = env.canonical_instances(30)
  poses, goals = np.asarray(nodes.qpos[:, 7:10]), np.asarray(nodes.goal)
  for i, pose in enumerate(poses):
    ax.add_patch(Polygon(render.t_polygon(pose), closed=True, fc='tab:orange', ec='tab:red',
                         alpha=0.18, lw=0.6, label='start poses' if i == 0 else None))
  for i, goal in enumerate({tuple(g) for g in goals.round(5)}):
    ax.add_patch(Polygon(render.t_polygon(goal), closed=True, fill=False, ec='tab:green',
                         ls='--', lw=1.5, label='goal' if i == 0 else None))
  for i, box in enumerate(env.obstacles):
    ax.add_patch(Polygon(render.box_polygon(box), closed=True, fc='0.45', ec='k',
                         label='obstacles' if i == 0 else None))
  ax.plot([-0.40], [-0.32], 'ko', label='stick tip at start')
  ax.plot([pusht.BASE_POS[0]], [pusht.BASE_POS[1]], 'ks', label='robot base')
  ax.set_xlim(-0.65, 0.1)
  ax.set_ylim(-0.4, 0.3)
  ax.set_aspect('equal')
  ax.set_xlabel('x (m)')
  ax.set_ylabel('y (m)')
  ax.set_title(title)
  ax.legend(loc='lower left', fontsize=7)


def main():
  parser = argparse.ArgumentParser()
  parser.add_argument('--out', default='experiments/results')
  args = parser.parse_args()
  fig = Figure(figsize=(15, 5.2))
  FigureCanvasAgg(fig)
  for k, name in enumerate(['pusht-fixed', 'pusht-rand', 'pusht-obs']):
    draw_instances(fig.add_subplot(1, 3, k + 1), envs.make(name),
                   f'{name}: 30 canonical instances (seed 0)')
  fig.tight_layout()
  os.makedirs(args.out, exist_ok=True)
  path = os.path.join(args.out, 'pusht_tasks.png')
  fig.savefig(path, dpi=110)
  print(path)


if __name__ == '__main__':
  main()
