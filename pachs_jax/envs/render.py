"""Drawings of PushT runs (matplotlib figures on an Agg canvas, no pyplot), GIFs (PIL) and
MuJoCo offscreen frames."""

from __future__ import annotations

import os
from typing import Any, Optional, Sequence

import numpy as np
from matplotlib import patches
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from pachs_jax.envs.coverage import T_OUTLINE

GOAL_COLOR = 'tab:green'
T_COLOR = 'tab:blue'
T_START_COLOR = 'tab:orange'
T_FINAL_COLOR = 'tab:red'
OBSTACLE_COLOR = '0.55'
PUSHER_COLOR = 'black'


def _rotation(yaw: float) -> np.ndarray:
  c, s = np.cos(yaw), np.sin(yaw)
  return np.array([[c, -s], [s, c]])


def t_polygon(pose: Sequence[float]) -> np.ndarray:
  """[8, 2] world vertices (m) of the T outline at pose (x, y, yaw)."""
  x, y, yaw = (float(v) for v in pose)
  return T_OUTLINE.astype(np.float64) @ _rotation(yaw).T + np.array([x, y])


def box_polygon(box: Sequence[float]) -> np.ndarray:
  """[4, 2] world corners (m) of a box row (cx, cy, half_x, half_y, yaw)."""
  cx, cy, hx, hy, yaw = (float(v) for v in box)
  corners = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
  return corners @ _rotation(yaw).T + np.array([cx, cy])


def _as_array(name: str, value: Any, shape_doc: str, ndim: int, last: int) -> np.ndarray:
  """A float64 array of `ndim` dims whose last axis has `last` entries, else ValueError."""
  arr = np.asarray(value, dtype=np.float64)
  if arr.ndim != ndim or arr.shape[-1] != last:
    raise ValueError(f'{name} must have shape {shape_doc}, got {arr.shape}')
  return arr


def draw_pusht(
    ax,
    t_poses,
    goal_pose,
    pusher_xy=None,
    obstacles=None,
    every: int = 1,
    legend: bool = True,
):
  """Draws a PushT run top-down on a matplotlib Axes; returns ax.

  t_poses: [T, 3] T poses (x, y, yaw) over time (m, rad); every `every`-th one is drawn (the
    first and last always), as filled polygons whose alpha grows with time.
  goal_pose: [3] goal T pose, drawn as a dashed outline.
  pusher_xy: [T', 2] pusher (stick tip) positions (m), drawn as a line from a marked start.
  obstacles: [M, 5] boxes (cx, cy, half_x, half_y, yaw), filled grey.
  """
  t_poses = _as_array('t_poses', t_poses, '[T, 3]', 2, 3)
  goal_pose = _as_array('goal_pose', goal_pose, '[3]', 1, 3)
  if t_poses.shape[0] == 0:
    raise ValueError('t_poses must hold at least one pose, got shape (0, 3)')
  if int(every) < 1:
    raise ValueError(f'every must be a positive integer, got {every}')
  if not np.all(np.isfinite(t_poses)) or not np.all(np.isfinite(goal_pose)):
    raise ValueError('t_poses and goal_pose must be finite')
  if pusher_xy is not None:
    pusher_xy = _as_array('pusher_xy', pusher_xy, '[T, 2]', 2, 2)
  if obstacles is not None:
    obstacles = _as_array('obstacles', obstacles, '[M, 5] (cx, cy, half_x, half_y, yaw)', 2, 5)

  points = [t_polygon(goal_pose)]
  if obstacles is not None:
    for i, box in enumerate(obstacles):
      corners = box_polygon(box)
      points.append(corners)
      ax.add_patch(patches.Polygon(
          corners, closed=True, facecolor=OBSTACLE_COLOR, edgecolor='0.3', linewidth=0.8,
          label='obstacle' if i == 0 else None, zorder=1))

  num = t_poses.shape[0]
  shown = sorted(set(range(0, num, int(every))) | {num - 1})
  for rank, i in enumerate(shown):
    verts = t_polygon(t_poses[i])
    points.append(verts)
    frac = (rank + 1) / len(shown)
    if i == 0:
      style = dict(facecolor=T_START_COLOR, edgecolor=T_START_COLOR, alpha=0.45, linewidth=1.5,
                   label='T start')
    elif i == num - 1:
      style = dict(facecolor=T_FINAL_COLOR, edgecolor=T_FINAL_COLOR, alpha=0.7, linewidth=2.0,
                   label='T final')
    else:
      style = dict(facecolor=T_COLOR, edgecolor=T_COLOR, alpha=0.08 + 0.4 * frac, linewidth=0.5,
                   label='T over time' if rank == 1 else None)
    ax.add_patch(patches.Polygon(verts, closed=True, zorder=2, **style))

  ax.add_patch(patches.Polygon(
      t_polygon(goal_pose), closed=True, fill=False, edgecolor=GOAL_COLOR, linestyle='--',
      linewidth=2.0, label='goal', zorder=3))

  if pusher_xy is not None and pusher_xy.shape[0] > 0:
    finite = np.all(np.isfinite(pusher_xy), axis=-1)
    trace = pusher_xy[finite]
    if trace.shape[0] > 0:
      points.append(trace)
      ax.plot(trace[:, 0], trace[:, 1], color=PUSHER_COLOR, linewidth=1.2, label='pusher',
              zorder=4)
      ax.plot(trace[0, 0], trace[0, 1], marker='o', color=PUSHER_COLOR, markersize=6,
              linestyle='none', label='pusher start', zorder=5)

  allpts = np.concatenate(points, axis=0)
  lo, hi = allpts.min(axis=0), allpts.max(axis=0)
  pad = 0.05 * float(np.max(hi - lo)) + 0.02
  ax.set_xlim(lo[0] - pad, hi[0] + pad)
  ax.set_ylim(lo[1] - pad, hi[1] + pad)
  ax.set_aspect('equal')
  ax.set_xlabel('x (m)')
  ax.set_ylabel('y (m)')
  if legend:
    ax.legend(loc='best', fontsize='small', framealpha=0.8)
  return ax


def save_pusht_figure(
    path: str | os.PathLike,
    t_poses,
    goal_pose,
    pusher_xy=None,
    obstacles=None,
    every: int = 1,
    title: Optional[str] = None,
    figsize: tuple[float, float] = (6.0, 6.0),
    dpi: int = 120,
) -> str:
  """Draws a PushT run (see `draw_pusht`) into a new figure saved at path; returns the path."""
  fig = Figure(figsize=figsize, dpi=dpi)
  FigureCanvasAgg(fig)
  ax = fig.add_subplot(1, 1, 1)
  draw_pusht(ax, t_poses, goal_pose, pusher_xy=pusher_xy, obstacles=obstacles, every=every)
  if title:
    ax.set_title(title)
  fig.tight_layout()
  fig.savefig(os.fspath(path))
  return os.fspath(path)


def save_gif(path: str | os.PathLike, frames, fps: float = 20.0) -> str:
  """Writes frames [T, H, W, 3] uint8 as a looping GIF at fps frames per second; returns path."""
  from PIL import Image

  frames = np.asarray(frames)
  if frames.ndim != 4 or frames.shape[-1] != 3 or frames.shape[0] == 0:
    raise ValueError(f'frames must have shape [T, H, W, 3] with T >= 1, got {frames.shape}')
  if frames.dtype != np.uint8:
    raise ValueError(f'frames must be uint8, got {frames.dtype}')
  if not np.isfinite(fps) or fps <= 0:
    raise ValueError(f'fps must be positive, got {fps}')
  images = [Image.fromarray(f) for f in frames]
  duration_ms = max(int(round(1000.0 / fps)), 1)
  images[0].save(os.fspath(path), save_all=True, append_images=images[1:],
                 duration=duration_ms, loop=0)
  return os.fspath(path)


def render_mujoco_frames(mj_model, qpos_seq, width: int, height: int, camera=None) -> np.ndarray:
  """[T, height, width, 3] uint8 offscreen frames of a MuJoCo model at qpos_seq [T, nq].

  camera: a camera name or id of the model, or None for the default free camera. Needs an
  OpenGL backend chosen before `mujoco` is imported (MUJOCO_GL=egl or osmesa on a headless
  machine); raises RuntimeError saying so when no renderer can be created.
  """
  import mujoco

  qpos_seq = np.asarray(qpos_seq, dtype=np.float64)
  if qpos_seq.ndim != 2 or qpos_seq.shape[1] != mj_model.nq:
    raise ValueError(f'qpos_seq must have shape [T, nq={mj_model.nq}], got {qpos_seq.shape}')
  width, height = int(width), int(height)
  if width < 1 or height < 1:
    raise ValueError(f'width and height must be positive, got {width} x {height}')
  offwidth, offheight = mj_model.vis.global_.offwidth, mj_model.vis.global_.offheight
  if width > offwidth or height > offheight:
    raise ValueError(
        f'{width} x {height} exceeds the model offscreen buffer {offwidth} x {offheight}; '
        'raise <visual><global offwidth=... offheight=.../></visual> in the model')
  try:
    renderer = mujoco.Renderer(mj_model, height=height, width=width)
  except Exception as err:  # mujoco raises FatalError / RuntimeError / ImportError variants
    raise RuntimeError(
        'MuJoCo offscreen rendering is not available: no OpenGL context could be created '
        f'({type(err).__name__}: {err}). On a headless machine set MUJOCO_GL=egl (GPU or Mesa '
        'EGL) or MUJOCO_GL=osmesa before importing mujoco.') from err
  data = mujoco.MjData(mj_model)
  frames = np.empty((qpos_seq.shape[0], height, width, 3), np.uint8)
  try:
    for i, qpos in enumerate(qpos_seq):
      data.qpos[:] = qpos
      mujoco.mj_forward(mj_model, data)
      renderer.update_scene(data, camera=-1 if camera is None else camera)
      frames[i] = renderer.render()
  finally:
    renderer.close()
  return frames
