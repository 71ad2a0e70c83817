"""Drawings of PushT runs (matplotlib figures on an Agg canvas, no pyplot), GIFs (PIL) and
MuJoCo offscreen frames."""

from __future__ import annotations

import copy
import os
from typing import Any, Optional, Sequence

import jax
import mujoco
import numpy as np
from matplotlib import patches
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

from pachs_jax.envs import kinematics, pusht
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


def save_gif(path, frames, fps: float = 20.0):
  """Writes frames [T, H, W, 3] uint8 as a looping GIF at fps frames per second to path (or a
  binary file object); returns path."""
  frames = np.asarray(frames)
  if frames.ndim != 4 or frames.shape[-1] != 3 or frames.shape[0] == 0:
    raise ValueError(f'frames must have shape [T, H, W, 3] with T >= 1, got {frames.shape}')
  if frames.dtype != np.uint8:
    raise ValueError(f'frames must be uint8, got {frames.dtype}')
  if not np.isfinite(fps) or fps <= 0:
    raise ValueError(f'fps must be positive, got {fps}')
  images = [Image.fromarray(f) for f in frames]
  duration_ms = max(int(round(1000.0 / fps)), 1)
  target = path if hasattr(path, 'write') else os.fspath(path)
  images[0].save(target, format='GIF', save_all=True, append_images=images[1:],
                 duration=duration_ms, loop=0)
  return path


def render_mujoco_frames(mj_model, qpos_seq, width: int, height: int, camera=None) -> np.ndarray:
  """[T, height, width, 3] uint8 offscreen frames of a MuJoCo model at qpos_seq [T, nq].

  camera: a camera name or id of the model, a mujoco.MjvCamera, or None for the default free
  camera. Needs an
  OpenGL backend chosen before `mujoco` is imported (MUJOCO_GL=egl or osmesa on a headless
  machine); raises RuntimeError saying so when no renderer can be created.
  """
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


# ---------------------------------------------------------------- plans: stills and animations

ARM_COLOR = '0.35'
PLAN_COLOR = 'tab:purple'  # a plan being executed in closed loop
TARGET_COLOR = 'tab:green'
SHELF_COLOR = (0.6, 0.45, 0.3)
MAX_FRAMES = 240  # longer plans are subsampled to this many frames


def figure_pixels(fig: Figure) -> np.ndarray:
  """[H, W, 3] uint8 pixels of a figure on an Agg canvas (drawn now)."""
  canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
  canvas.draw()
  return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def frame_steps(num_states: int, max_frames: int = MAX_FRAMES) -> np.ndarray:
  """The state indices an animation shows: all of them, or `max_frames` evenly spaced (the
  first and the last always)."""
  if num_states <= max_frames:
    return np.arange(num_states)
  return np.unique(np.round(np.linspace(0, num_states - 1, max_frames)).astype(int))


def arm_points(mj_model, qpos_seq) -> np.ndarray:
  """[T, P, 3] world positions (m) of the arm's bodies from its base to the tip site, along
  qpos_seq [T, nq] (forward kinematics of `kinematics.ChainKinematics`, hinge joints)."""
  site = mj_model.site('tip').id
  body = int(mj_model.site_bodyid[site])
  chain = kinematics.ChainKinematics(mj_model, [body])
  path = []
  while body > 0:
    path.append(body)
    body = int(mj_model.body_parentid[body])
  path = np.array(path[::-1])

  def points(qpos):
    xpos, xmat = chain.bodies(qpos)
    return jax.numpy.concatenate([xpos[path], chain.site(xpos, xmat, site)[None]])

  return np.asarray(jax.jit(jax.vmap(points))(np.asarray(qpos_seq, np.float32)))


class _PushTScene:
  """A top-down PushT picture whose T, arm and tip trail move from frame to frame."""

  def __init__(self, t_poses, goal_pose, tips, arms, obstacles, title, size_px):
    self.fig = Figure(figsize=(size_px / 100, size_px / 100), dpi=100)
    FigureCanvasAgg(self.fig)
    ax = self.fig.add_subplot(1, 1, 1)
    self.tips, self.arms, self.t_poses, self.title = tips, arms, t_poses, title
    # the fixed view: everything the plan visits, plus the goal and the obstacles
    points = [t_polygon(p) for p in t_poses[::max(1, len(t_poses) // 30)]]
    points += [t_polygon(goal_pose), tips]
    for box in obstacles:
      points.append(box_polygon(box))
      ax.add_patch(patches.Polygon(box_polygon(box), closed=True, facecolor=OBSTACLE_COLOR,
                                   edgecolor='0.3', zorder=1))
    ax.add_patch(patches.Polygon(t_polygon(goal_pose), closed=True, fill=False, linewidth=2.0,
                                 edgecolor=GOAL_COLOR, linestyle='--', label='goal', zorder=3))
    ax.add_patch(patches.Polygon(t_polygon(t_poses[0]), closed=True, fill=False, linewidth=1.0,
                                 edgecolor=T_START_COLOR, label='T start', zorder=2))
    self.t_patch = patches.Polygon(t_polygon(t_poses[0]), closed=True, facecolor=T_COLOR,
                                   alpha=0.7, label='T', zorder=2)
    ax.add_patch(self.t_patch)
    (self.arm_line,) = ax.plot([], [], color=ARM_COLOR, linewidth=3, alpha=0.6, zorder=4,
                               solid_capstyle='round', label='arm (top view)')
    (self.trail,) = ax.plot([], [], color=PUSHER_COLOR, linewidth=1.0, zorder=5)
    (self.tip,) = ax.plot([], [], 'o', color=PUSHER_COLOR, markersize=5, zorder=6,
                          label='stick tip')
    # a plan being executed (`show`'s plan): the tip's planned path and the T where it ends
    (self.plan_line,) = ax.plot([], [], linestyle='--', color=PLAN_COLOR, linewidth=1.2,
                                zorder=5, label='plan')
    self.plan_t = patches.Polygon(t_polygon(t_poses[0]), closed=True, fill=False,
                                  linestyle='--', edgecolor=PLAN_COLOR, linewidth=1.2,
                                  visible=False, zorder=3)
    ax.add_patch(self.plan_t)
    allpts = np.concatenate(points)
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pad = 0.05 * float(np.max(hi - lo)) + 0.02
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect('equal')
    ax.tick_params(labelsize='x-small')
    ax.legend(loc='upper right', fontsize='x-small', framealpha=0.7)
    self.ax = ax

  def show(self, i: int, plan=None) -> np.ndarray:
    """The frame of state i; plan: (planned tip positions [L, 2], planned last T pose [3]) of
    the plan being executed, drawn dashed (None: none)."""
    self.plan_line.set_data(*((plan[0][:, 0], plan[0][:, 1]) if plan is not None else ([], [])))
    self.plan_t.set_visible(plan is not None)
    if plan is not None:
      self.plan_t.set_xy(t_polygon(plan[1]))
    self.t_patch.set_xy(t_polygon(self.t_poses[i]))
    if self.arms is not None:
      self.arm_line.set_data(self.arms[i, :, 0], self.arms[i, :, 1])
    self.trail.set_data(self.tips[:i + 1, 0], self.tips[:i + 1, 1])
    self.tip.set_data(self.tips[i:i + 1, 0], self.tips[i:i + 1, 1])
    self.ax.set_title(f'{self.title}\nstep {i} of {len(self.t_poses) - 1}', fontsize='small')
    return figure_pixels(self.fig)


class _ShelfScene:
  """Side (x-z) and top (x-y) views of the shelf, its target, the arm and the tip's path."""

  def __init__(self, boxes, target, arms, title, size_px):
    self.fig = Figure(figsize=(2 * size_px / 100, size_px / 100), dpi=100)
    FigureCanvasAgg(self.fig)
    self.arms, self.title = arms, title
    tips = arms[:, -1]
    self.views = []
    for col, (a, b, name) in enumerate(((0, 2, 'side view (x, z)'), (0, 1, 'top view (x, y)'))):
      ax = self.fig.add_subplot(1, 2, col + 1)
      for box_name, (centre, half) in boxes.items():
        if box_name == 'floor':
          continue
        ax.add_patch(patches.Rectangle((centre[a] - half[a], centre[b] - half[b]),
                                       2 * half[a], 2 * half[b], facecolor=SHELF_COLOR,
                                       alpha=0.35, edgecolor=SHELF_COLOR, zorder=1))
      ax.plot(tips[:, a], tips[:, b], color='0.7', linewidth=1.0, linestyle=':', zorder=2,
              label='tip path')
      ax.plot(*np.asarray(target)[[a, b]], marker='*', color=TARGET_COLOR, markersize=14,
              linestyle='none', zorder=5, label='target')
      (arm,) = ax.plot([], [], '-o', color=ARM_COLOR, linewidth=3, markersize=3, zorder=3,
                       label='arm')
      (trail,) = ax.plot([], [], color=PUSHER_COLOR, linewidth=1.2, zorder=4)
      (tip,) = ax.plot([], [], 'o', color=PUSHER_COLOR, markersize=5, zorder=6)
      pts = np.concatenate([arms.reshape(-1, 3)[:, [a, b]],
                            np.concatenate([[c - h, c + h] for n, (c, h) in boxes.items()
                                            if n != 'floor'])[:, [a, b]]])
      lo, hi = pts.min(axis=0), pts.max(axis=0)
      pad = 0.05 * float(np.max(hi - lo)) + 0.02
      ax.set_xlim(lo[0] - pad, hi[0] + pad)
      ax.set_ylim(lo[1] - pad, hi[1] + pad)
      ax.set_aspect('equal')
      ax.set_xlabel('x (m)', fontsize='small')
      ax.set_ylabel(('z (m)', 'y (m)')[col], fontsize='small')
      ax.tick_params(labelsize='x-small')
      ax.set_title(name, fontsize='small')
      if col == 0:
        ax.legend(loc='lower left', fontsize='x-small', framealpha=0.7)
      self.views.append((a, b, arm, trail, tip))

  def show(self, i: int) -> np.ndarray:
    tips = self.arms[:, -1]
    for a, b, arm, trail, tip in self.views:
      arm.set_data(self.arms[i, :, a], self.arms[i, :, b])
      trail.set_data(tips[:i + 1, a], tips[:i + 1, b])
      tip.set_data(tips[i:i + 1, a], tips[i:i + 1, b])
    self.fig.suptitle(f'{self.title}\nstep {i} of {len(self.arms) - 1}', fontsize='small')
    return figure_pixels(self.fig)


def _scene(env, states, title: str, size_px: int):
  """The moving picture of a plan's states NodeState [T, ...] of a PushT or shelf env."""
  qpos = np.asarray(states.qpos)
  goal = np.asarray(states.goal)[0]
  if env.name.startswith('pusht'):
    arms = arm_points(env.mj_model, qpos)
    return _PushTScene(np.asarray(pusht.t_pose(qpos)), goal, arms[:, -1, :2], arms[..., :2],
                       np.asarray(env.obstacles).reshape(-1, 5), title, size_px)
  if env.name == 'shelf':
    return _ShelfScene(env.boxes, goal, arm_points(env.mj_model, qpos), title, size_px)
  raise ValueError(f'drawing a plan is implemented for the PushT tasks and the shelf, not '
                   f'{env.name!r}')


def loop_frames(env, states, plans, title: str, size_px: int = 360,
                max_frames: int = MAX_FRAMES) -> np.ndarray:
  """frames [F, H, W, 3] uint8 of a PushT world's states NodeState [S + 1, ...] in closed loop;
  plans: per state s, the planned states NodeState [L + 1, ...] being executed there (None:
  none), drawn dashed: the tip's planned path and where the plan leaves the T."""
  if not env.name.startswith('pusht'):
    raise ValueError(f'a closed loop is drawn for the PushT tasks, not {env.name!r}')
  qpos = np.asarray(states.qpos)
  arms = arm_points(env.mj_model, qpos)
  scene = _PushTScene(np.asarray(pusht.t_pose(qpos)), np.asarray(states.goal)[0],
                      arms[:, -1, :2], arms[..., :2], np.asarray(env.obstacles).reshape(-1, 5),
                      title, size_px)
  distinct = {id(p): p for p in plans if p is not None}
  drawn = {}
  if distinct:  # every plan's tip path in one kinematics call
    planned = list(distinct.values())
    tips = arm_points(env.mj_model, np.concatenate([np.asarray(p.qpos) for p in planned]))
    at = np.cumsum([0] + [len(p.qpos) for p in planned])
    for n, p in enumerate(planned):
      drawn[id(p)] = (tips[at[n]:at[n + 1], -1, :2],
                      np.asarray(pusht.t_pose(np.asarray(p.qpos)[-1])))
  steps = frame_steps(len(qpos), max_frames)
  return np.stack([scene.show(i, drawn.get(id(plans[i])) if plans[i] is not None else None)
                   for i in steps])


def can_draw(env) -> bool:
  """Whether `plan_figure` and `animation_frames` draw this env's plans (PushT tasks, shelf)."""
  return env.name.startswith('pusht') or env.name == 'shelf'


def plan_figure(env, states, title: str, size_px: int = 600) -> Figure:
  """A still figure (Agg canvas) of a plan's states NodeState [T, ...]. PushT: the T over time
  (`draw_pusht`), goal, obstacles and the tip's path; shelf: side and top views of the shelf,
  the target, the tip's path and the arm at its last state."""
  qpos = np.asarray(states.qpos)
  if env.name.startswith('pusht'):
    fig = Figure(figsize=(size_px / 100, size_px / 100), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    tips = arm_points(env.mj_model, qpos)[:, -1, :2]
    obstacles = np.asarray(env.obstacles).reshape(-1, 5)
    draw_pusht(ax, np.asarray(pusht.t_pose(qpos)), np.asarray(states.goal)[0], pusher_xy=tips,
               obstacles=obstacles if len(obstacles) else None,
               every=max(1, (len(qpos) - 1) // 12))
    ax.set_title(title, fontsize='small')
    fig.tight_layout()
    return fig
  scene = _scene(env, states, title, size_px // 2 + 100)
  scene.show(len(qpos) - 1)
  scene.fig.suptitle(title, fontsize='small')
  return scene.fig


# A view of the scene for the MuJoCo renderer: (lookat xyz (m), distance (m), azimuth,
# elevation (deg)); the PushT model has its own camera, 'overview'.
SHELF_CAMERA = ((0.4, 0.0, 0.45), 2.0, 50.0, -20.0)


def _scene_model(env, goal):
  """The env's MjModel, copied with its 'goal' body (PushT) moved to the instance's goal
  [x, y, yaw]."""
  model = env.mj_model
  names = [model.body(i).name for i in range(model.nbody)]
  if 'goal' not in names or len(goal) != 3:
    return model
  model = copy.copy(model)
  body = names.index('goal')
  model.body_pos[body, :2] = goal[:2]
  model.body_quat[body] = [np.cos(goal[2] / 2), 0.0, 0.0, np.sin(goal[2] / 2)]
  return model


def _mujoco_camera(env):
  """A camera name or a free mujoco.MjvCamera framing the env's scene."""
  if env.mj_model.ncam:
    return 0
  lookat, distance, azimuth, elevation = SHELF_CAMERA
  camera = mujoco.MjvCamera()
  camera.lookat[:] = lookat
  camera.distance, camera.azimuth, camera.elevation = distance, azimuth, elevation
  return camera


def animation_frames(env, states, title: str, arm: bool = True, size_px: int = 360,
                     max_frames: int = MAX_FRAMES) -> tuple[np.ndarray, str | None]:
  """(frames [F, H, W, 3] uint8, note) of a plan's states NodeState [T, ...] executing.

  Each frame holds the drawing of `_scene`; with `arm`, the MuJoCo rendering of the arm beside
  it where an OpenGL context can be made (else note says why it is left out; None: it is in).
  """
  steps = frame_steps(len(np.asarray(states.t)), max_frames)
  scene = _scene(env, states, title, size_px)
  drawn = np.stack([scene.show(i) for i in steps])
  note = None
  if arm:
    qpos = np.asarray(states.qpos, np.float64)[steps]
    height = drawn.shape[1]
    width = min(int(round(height * 4 / 3)), env.mj_model.vis.global_.offwidth)
    height = min(height, env.mj_model.vis.global_.offheight)
    try:
      model = _scene_model(env, np.asarray(states.goal)[0])
      rendered = render_mujoco_frames(model, qpos, width, height,
                                      camera=_mujoco_camera(env))
    except RuntimeError as err:
      note = f'the arm is drawn only: MuJoCo cannot render here ({str(err).split(":")[0]})'
    else:
      canvas = np.full((len(steps), drawn.shape[1], width, 3), 255, np.uint8)
      canvas[:, :height] = rendered
      drawn = np.concatenate([canvas, drawn], axis=2)
  return drawn, note
