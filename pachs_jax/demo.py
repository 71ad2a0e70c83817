"""`pachs demo`: a scripted pusher (no learning) that pushes the T of a PushT task towards its
goal, around the obstacles' ends, through the task's own transition; drawn to a PNG."""

from __future__ import annotations

import os
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from matplotlib.path import Path
from tqdm import tqdm

from pachs_jax import envs, outputs
from pachs_jax.envs import backends, coverage, pusht, render

MAX_STEPS = 2000  # control steps a demo may take (100 s of simulated time)
REST_Z, LIFT_Z = 0.015, 0.07  # m: tip height when pushing, and when passing over the T
TIP_RADIUS = 0.008  # m
GAP = 0.025  # m: from the T's outline to where the tip starts a push


def _rotation(yaw: float) -> np.ndarray:
  c, s = np.cos(yaw), np.sin(yaw)
  return np.array([[c, -s], [s, c]])


def _wrap(angle: float) -> float:
  return (angle + np.pi) % (2 * np.pi) - np.pi


def _entry(polygon: np.ndarray, aim: np.ndarray, direction: np.ndarray) -> np.ndarray:
  """[2] where the line through aim along direction first meets polygon [V, 2], coming from
  behind (aim when it misses)."""
  origin = aim - 0.5 * direction
  best = None
  for a, b in zip(polygon, np.roll(polygon, -1, axis=0)):
    m = np.array([direction, a - b]).T
    if abs(np.linalg.det(m)) < 1e-12:
      continue
    t, u = np.linalg.solve(m, a - origin)
    if 0 <= u <= 1 and t >= 0 and (best is None or t < best):
      best = t
  return aim if best is None else origin + best * direction


def _near(polygon: np.ndarray, point: np.ndarray, margin: float) -> bool:
  """point [2] lies inside polygon [V, 2] or within margin (m) of its outline."""
  if Path(polygon).contains_point(point):
    return True
  for a, b in zip(polygon, np.roll(polygon, -1, axis=0)):
    t = np.clip(np.dot(point - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
    if np.linalg.norm(a + t * (b - a) - point) < margin:
      return True
  return False


def waypoint(t_xy: np.ndarray, goal_xy: np.ndarray, obstacles: np.ndarray) -> np.ndarray:
  """[2] where the T's centre goes next: the goal, or, when a box of obstacles [M, 5] lies
  across the way, a point in front of the box's nearer end and then one past it."""
  for cx, cy, hx, hy, yaw in obstacles:
    rot, centre = _rotation(yaw), np.array([cx, cy])
    a, b = rot.T @ (t_xy - centre), rot.T @ (goal_xy - centre)
    way = a[None] + np.linspace(0, 1, 50)[:, None] * (b - a)[None]
    crosses = np.any((np.abs(way[:, 0]) < hx + 0.1) & (np.abs(way[:, 1]) < hy + 0.1))
    if crosses and np.sign(a[1]) != np.sign(b[1]):
      end = min((-(hx + 0.12), hx + 0.12), key=lambda x: abs(x - a[0]) + abs(b[0] - x))
      lined_up = abs(a[0] - end) < 0.03
      local = np.array([end, (-1 if lined_up else 1) * np.sign(a[1]) * (hy + 0.11)])
      return centre + rot @ local
  return goal_xy


def tip_target(qpos: np.ndarray, tip: np.ndarray, goal: np.ndarray,
               obstacles: np.ndarray) -> tuple[np.ndarray, str]:
  """([3] where the stick tip goes next (m), phase name) for a PushT state.

  The T's centre is pushed towards `waypoint`, off its centre line in proportion to the yaw
  error (a turning push); near the goal the bar's end is pushed sideways to turn it. The tip
  starts each push `GAP` behind the T's outline; it passes over the T lifted to `LIFT_Z`.
  """
  pose = np.asarray(pusht.t_pose(qpos), np.float64)
  goal = np.asarray(goal, np.float64)
  target = waypoint(pose[:2], goal[:2], obstacles)
  error = target - pose[:2]
  yaw_error = _wrap(goal[2] - pose[2])
  outline = render.t_polygon(pose)
  at_goal = np.array_equal(target, goal[:2])
  if np.linalg.norm(error) > 0.02 or not at_goal:
    direction = error / max(np.linalg.norm(error), 1e-9)
    normal = np.array([-direction[1], direction[0]])
    lever = -np.clip(0.05 * yaw_error / (np.pi / 2), -0.05, 0.05) if at_goal else 0.0
    aim = pose[:2] + lever * normal
  else:  # turn in place: push the bar's end sideways
    rot = _rotation(pose[2])
    aim = pose[:2] + rot @ np.array([np.sign(yaw_error) * 0.08, -0.0375])
    direction = rot @ np.array([0.0, 1.0])
  entry = _entry(outline, aim, direction)
  start = entry - (GAP + TIP_RADIUS) * direction
  rel = tip[:2] - entry
  along, across = np.dot(rel, direction), abs(rel[0] * direction[1] - rel[1] * direction[0])
  if across < 0.015 and -0.06 < along < 0.01 and tip[2] < 0.03:
    return np.array([*(entry + 0.03 * direction), REST_Z]), 'push'
  far = np.linalg.norm(tip[:2] - start) > 0.015
  if tip[2] > 0.035 and far:
    return np.array([*start, LIFT_Z]), 'over'
  way = tip[:2] + np.linspace(0, 1, 12)[:, None] * (start - tip[:2])[None]
  if far and any(_near(outline, p, 0.03) for p in way):
    return np.array([*tip[:2], LIFT_Z]), 'lift'
  return np.array([*start, REST_Z]), 'approach'


def scripted_push(env, node, num_steps: int, progress: bool = False):
  """Rolls the scripted pusher (`tip_target`, one `pusht.jacobian_action` step towards it per
  control step) out of a single node through env's transition for num_steps (T) steps.

  env: a PushT env (MJX or MuJoCo C physics). Returns (nodes NodeState [T + 1] (numpy), tip
  positions [T + 1, 3] (m), coverage [T + 1], pushes: the steps spent pushing the T).
  """
  transition, tip_position = jax.jit(env.transition), jax.jit(env.tip_position)
  data = mujoco.MjData(env.mj_model)
  obstacles = np.asarray(env.obstacles, np.float64).reshape(-1, 5)
  goal = np.asarray(node.goal)
  nodes, tips, pushes = [jax.device_get(node)], [np.asarray(tip_position(node))], 0
  for _ in tqdm(range(num_steps), desc='scripted pusher', unit='step', disable=not progress,
                mininterval=0.5):
    qpos = np.asarray(nodes[-1].qpos, np.float64)
    target, phase = tip_target(qpos, tips[-1], goal, obstacles)
    pushes += phase == 'push'
    action = pusht.jacobian_action(env.mj_model, data, target, qpos=qpos)
    node = transition(node, jnp.asarray(action, jnp.float32)).next_node
    nodes.append(jax.device_get(node))
    tips.append(np.asarray(tip_position(node)))
  nodes = jax.tree.map(lambda *x: np.stack(x), *nodes)
  cov = np.asarray(coverage.coverage(pusht.t_pose(nodes.qpos), goal[None]))
  return nodes, np.array(tips), cov, pushes


def run_demo(task: str, instance: int, out: str, num_steps: int, gif: str | None,
             progress: bool = False, backend: str = 'auto') -> dict:
  """Runs `scripted_push` on a canonical instance of a PushT task on its planar physics preset
  (engine `backend`, see `backends.make_backend`), draws it to the image `out` (and, with
  `gif`, an animation with the MuJoCo rendering of the arm); returns a JSON-ready summary.
  Files are written atomically; ValueError for bad arguments before any work."""
  if isinstance(num_steps, bool) or not isinstance(num_steps, int) or \
      not 1 <= num_steps <= MAX_STEPS:
    raise ValueError(f'steps must be an integer in 1..{MAX_STEPS}, got {num_steps!r}')
  outputs.check_distinct({'--out': out, '--gif': gif})
  if not task.startswith('pusht'):
    raise ValueError(f'the scripted demo drives PushT tasks; got {task!r}')
  # the scripted pusher is a controller for the planar T: on the free T (the default physics)
  # its pushes stall against the T's friction
  env = backends.make_backend(envs.make(task, physics='planar'), backend)
  node = jax.tree.map(lambda x: x[instance], env.canonical_instances(instance + 1))
  start = time.perf_counter()
  nodes, tips, cov, pushes = scripted_push(env, node, num_steps, progress)
  elapsed = time.perf_counter() - start
  poses = pusht.t_pose(nodes.qpos)
  obstacles = np.asarray(env.obstacles).reshape(-1, 5)
  title = (f'{task} instance {instance}: scripted pusher, {num_steps} steps\n'
           f'final coverage {cov[-1]:.2f} (best {cov.max():.2f})')

  def figure(f):
    fig = render.Figure(figsize=(6.0, 6.0), dpi=120)
    render.FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    render.draw_pusht(ax, poses, np.asarray(node.goal), pusher_xy=tips[:, :2],
                      obstacles=obstacles if len(obstacles) else None,
                      every=max(1, num_steps // 12))
    ax.set_title(title, fontsize='small')
    fig.tight_layout()
    fig.savefig(f, format=os.path.splitext(out)[1].lstrip('.').lower() or 'png')

  outputs.write_atomically(out, figure)
  summary = {'task': task, 'instance': instance, 'steps': num_steps,
             'final_coverage': float(cov[-1]), 'best_coverage': float(cov.max()),
             'push_steps': int(pushes),
             'T_travel_m': float(np.sum(np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1))),
             'seconds': elapsed, 'figure': out}
  if gif:
    frames, note = render.animation_frames(env, nodes, title)
    shown = render.frame_steps(num_steps + 1)
    stride = float(np.mean(np.diff(shown))) if len(shown) > 1 else 1.0
    outputs.write_atomically(
        gif, lambda f: render.save_gif(f, frames, fps=outputs.control_hz(env) / stride))
    summary['gif'] = gif
    if note:
      summary['gif_note'] = note
  return summary


if __name__ == '__main__':
  os.environ.setdefault('MUJOCO_GL', 'egl')
  print(run_demo('pusht-obs', 0, 'demo.png', 300, None))
