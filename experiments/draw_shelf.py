"""A picture of a Panda-Shelf problem: the shelf, the arm at home and at an IK goal, the target.

Side (x-z), top (x-y) and front (y-z) views. The arm is drawn as its collision geometry
projected onto each view (capsules as stadiums, boxes as hulls) over its link skeleton; the
front view also marks all canonical targets.

  python experiments/draw_shelf.py --instance 0 --out experiments/results/shelf_problem.png
"""

from __future__ import annotations

import argparse
import os


def build_parser() -> argparse.ArgumentParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argparse.ArgumentParser()
  parser.add_argument('--instance', type=int, default=0, help='canonical instance to draw')
  parser.add_argument('--num', type=int, default=100, help='canonical instances (seed 0)')
  parser.add_argument('--out', default='experiments/results/shelf_problem.png')
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Circle, Polygon, Rectangle  # noqa: E402
from shapely.geometry import LineString, MultiPoint, Point  # noqa: E402

from pachs_jax.envs import shelf  # noqa: E402
# pylint: enable=wrong-import-position

# (horizontal axis, vertical axis, title, shelf boxes drawn filled)
VIEWS = (
    ((0, 2), 'side view (x-z)', ('board', 'back')),
    ((0, 1), 'top view (x-y)', ('side', 'divider', 'back')),
    ((1, 2), 'front view from the robot (y-z)', ('board', 'side', 'divider')),
)
HOME_COLOR = 'tab:blue'
GOAL_COLOR = 'tab:orange'
TARGET_COLOR = 'tab:red'
AXIS_LABEL = 'xyz'


def arm_shapes(env: shelf.ShelfEnv, qpos: np.ndarray):
  """(skeleton points [K, 3], [(geom type, centre [3], mat [3, 3], size [3])]) of the arm."""
  m = env.mj_model
  xpos, xmat = (np.asarray(a) for a in env.chain.bodies(jnp.asarray(qpos, jnp.float32)))
  ids = np.flatnonzero(m.geom_bodyid > 0)
  pos, mat = (np.asarray(a) for a in env.chain.geoms(jnp.asarray(xpos), jnp.asarray(xmat), ids))
  geoms = [(int(m.geom_type[g]), pos[k], mat[k], m.geom_size[g]) for k, g in enumerate(ids)]
  chain = [m.body(f'link{i}').id for i in range(8)]
  tip = np.asarray(env.chain.site(jnp.asarray(xpos), jnp.asarray(xmat), env.tip_site))
  return np.vstack([xpos[chain], tip[None]]), geoms


def projected_outline(kind: int, centre, mat, size, axes):
  """Shapely polygon of a sphere / capsule / box projected onto the plane of `axes`."""
  a = list(axes)
  if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
    return Point(centre[a]).buffer(size[0])
  if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
    half = mat[:, 2] * size[1]
    return LineString([(centre - half)[a], (centre + half)[a]]).buffer(size[0])
  signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
  corners = centre + (signs * size[:3]) @ mat.T
  return MultiPoint([tuple(c[a]) for c in corners]).convex_hull


def draw_arm(ax, env, qpos, axes, color, label):
  skeleton, geoms = arm_shapes(env, qpos)
  for k, (kind, centre, mat, size) in enumerate(geoms):
    poly = projected_outline(kind, centre, mat, size, axes)
    ax.add_patch(Polygon(np.asarray(poly.exterior.coords), closed=True, fc=color, ec=color,
                         alpha=0.25, lw=0.6, zorder=3))
  a = list(axes)
  ax.plot(skeleton[:, a[0]], skeleton[:, a[1]], '-o', color=color, lw=2.0, ms=3.5, zorder=4,
          label=label)


def draw_shelf(ax, env, axes, filled):
  a = list(axes)
  for name, (centre, half) in env.boxes.items():
    lo, size = centre[a] - half[a], 2 * half[a]
    if name == 'floor':
      if a[1] == 2:  # the floor's top face, z = 0
        ax.axhline(0.0, color='0.35', lw=1.5, zorder=1)
      continue
    solid = any(name.startswith(f) for f in filled)
    ax.add_patch(Rectangle(lo, size[0], size[1], fc='tan' if solid else 'none',
                           ec='saddlebrown', lw=0.8 if solid else 0.5, alpha=0.9 if solid else 0.5,
                           ls='-' if solid else ':', zorder=2 if solid else 1))


def draw_target(ax, env, target, axes, label=True):
  a = list(axes)
  ax.add_patch(Circle(target[a], env.config.goal_tolerance, fc='none', ec=TARGET_COLOR, ls='--',
                      lw=1.2, zorder=5))
  ax.plot(*target[a], marker='*', color=TARGET_COLOR, ms=12, zorder=6,
          label='target (circle: 5 cm goal tolerance)' if label else None)


def main():
  args = build_parser().parse_args()
  if not 0 <= args.instance < args.num:
    raise ValueError(f'--instance must be in [0, {args.num}), got {args.instance}')

  env = shelf.ShelfEnv()
  targets, configs = env.reachable_targets(args.num, 0)
  target, goal_q = targets[args.instance], configs[args.instance]
  home = env.home_qpos

  fig = Figure(figsize=(17, 5.6))
  FigureCanvasAgg(fig)
  limits = {0: (-0.35, 0.95), 1: (-0.6, 0.6), 2: (-0.05, 1.15)}
  for k, (axes, title, filled) in enumerate(VIEWS):
    ax = fig.add_subplot(1, 3, k + 1)
    draw_shelf(ax, env, axes, filled)
    if k == 2:
      ax.scatter(targets[:, 1], targets[:, 2], s=8, color='0.3', zorder=4,
                 label=f'all {args.num} canonical targets')
    draw_arm(ax, env, home, axes, HOME_COLOR, 'arm at home')
    draw_arm(ax, env, goal_q, axes, GOAL_COLOR, 'arm at an IK goal configuration')
    draw_target(ax, env, target, axes)
    ax.set_xlim(*limits[axes[0]])
    ax.set_ylim(*limits[axes[1]])
    ax.set_aspect('equal')
    ax.set_xlabel(f'{AXIS_LABEL[axes[0]]} (m)')
    ax.set_ylabel(f'{AXIS_LABEL[axes[1]]} (m)')
    ax.set_title(title)
    ax.grid(alpha=0.25)
  fig.axes[2].invert_xaxis()  # seen from the robot, +y (its left) is on the left
  fig.axes[0].legend(loc='upper left', fontsize=8)
  fig.axes[2].legend(loc='upper right', fontsize=8)
  fig.suptitle(f'Panda-Shelf, canonical instance {args.instance} (seed 0): target '
               f'({target[0]:.2f}, {target[1]:.2f}, {target[2]:.2f}) m; the tip site sits '
               f'between the fingers', fontsize=11)
  fig.tight_layout()
  os.makedirs(os.path.dirname(args.out) or '.', exist_ok=True)
  fig.savefig(args.out, dpi=110)
  print(args.out)


if __name__ == '__main__':
  main()
