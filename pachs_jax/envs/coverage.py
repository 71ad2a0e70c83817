"""PushT success measure: the fraction of the goal T's area that the T covers, rasterised on a
64 x 64 grid over +-0.15 m in the goal frame (ManiSkill's PushT-v1). Poses are x, y (m) and
yaw (rad), which turns the T frame counter-clockwise about world z."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

# The T in its own frame, as boxes (cx, cy, half_x, half_y) in metres: the bar, then the stem.
T_BOXES = np.array(
    [
        [0.0, -0.0375, 0.1, 0.025],  # bar 0.2 x 0.05, spans y in [-0.0625, -0.0125]
        [0.0, 0.0625, 0.025, 0.075],  # stem 0.05 x 0.15, spans y in [-0.0125, 0.1375]
    ],
    dtype=np.float32,
)

# The T's outline in its own frame: [8, 2] vertices (m), counter-clockwise.
T_OUTLINE = np.array(
    [
        [-0.1, -0.0625],
        [0.1, -0.0625],
        [0.1, -0.0125],
        [0.025, -0.0125],
        [0.025, 0.1375],
        [-0.025, 0.1375],
        [-0.025, -0.0125],
        [-0.1, -0.0125],
    ],
    dtype=np.float32,
)

T_AREA = float(np.sum(4.0 * T_BOXES[:, 2] * T_BOXES[:, 3]))  # m^2, the boxes do not overlap

GRID_SIZE = 64  # cells per side
GRID_HALF_EXTENT = 0.15  # m, the grid spans [-0.15, 0.15]^2 in the goal frame
GRID_CELL = 2.0 * GRID_HALF_EXTENT / GRID_SIZE  # m, side of one cell

SUCCESS_THRESHOLD = 0.9  # coverage needed for success


def _points_in_boxes(points: np.ndarray | jax.Array, xp=jnp):
  """[...] bool: points [..., 2] (T frame, m) inside the T (the union of `T_BOXES`)."""
  px = points[..., 0:1]
  py = points[..., 1:2]
  inside_x = xp.abs(px - T_BOXES[:, 0]) <= T_BOXES[:, 2]
  inside_y = xp.abs(py - T_BOXES[:, 1]) <= T_BOXES[:, 3]
  return xp.any(inside_x & inside_y, axis=-1)


def _grid_cell_centres() -> np.ndarray:
  """[GRID_SIZE, GRID_SIZE, 2] float32 cell centres in the goal frame (m); [i, j] is (x_i, y_j)."""
  axis = -GRID_HALF_EXTENT + (np.arange(GRID_SIZE) + 0.5) * GRID_CELL
  gx, gy = np.meshgrid(axis, axis, indexing='ij')
  return np.stack([gx, gy], axis=-1).astype(np.float32)


def goal_mask() -> np.ndarray:
  """[GRID_SIZE, GRID_SIZE] bool: the cells whose centre lies inside the goal T."""
  return _points_in_boxes(_grid_cell_centres(), xp=np)


GOAL_CELLS = _grid_cell_centres()[goal_mask()]  # [P, 2] goal-frame centres of the goal T's cells
GOAL_CELL_COUNT = int(GOAL_CELLS.shape[0])  # P (740 for this T and grid)


def points_in_t(points: jax.Array, t_pose: jax.Array, xp=jnp) -> jax.Array:
  """[..., P] bool: world points [..., P, 2] (m) inside the T at t_pose [..., 3]; xp: jax.numpy
  (traceable) or numpy (host checks, nothing compiled)."""
  points = xp.asarray(points, xp.float32)
  t_pose = xp.asarray(t_pose, xp.float32)
  c, s = xp.cos(t_pose[..., 2:3]), xp.sin(t_pose[..., 2:3])
  dx = points[..., 0] - t_pose[..., 0:1]
  dy = points[..., 1] - t_pose[..., 1:2]
  local = xp.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)
  return _points_in_boxes(local, xp)


def _check_poses(t_pose, goal_pose, xp=jnp) -> tuple[jax.Array, jax.Array]:
  """Converts to float32 and checks the (static) shapes; raises ValueError when wrong."""
  t_pose = xp.asarray(t_pose, xp.float32)
  goal_pose = xp.asarray(goal_pose, xp.float32)
  for name, pose in (('t_pose', t_pose), ('goal_pose', goal_pose)):
    if pose.ndim < 1 or pose.shape[-1] != 3:
      raise ValueError(f'{name} must have shape [..., 3] (x, y, yaw), got {tuple(pose.shape)}')
  try:
    np.broadcast_shapes(t_pose.shape[:-1], goal_pose.shape[:-1])
  except ValueError:
    raise ValueError(
        'the leading axes of t_pose and goal_pose must broadcast, got '
        f'{tuple(t_pose.shape)} and {tuple(goal_pose.shape)}'
    ) from None
  return t_pose, goal_pose


def coverage(t_pose: jax.Array, goal_pose: jax.Array, xp=jnp) -> jax.Array:
  """[...] float32 area(T n goal T) / area(goal T), rasterised; t_pose, goal_pose [..., 3].

  A grid cell belongs to a shape when its centre lies inside it; the result is the fraction of
  the goal T's cells (`GOAL_CELLS`) inside the T. Leading axes broadcast; a non-finite pose
  gives 0. xp: jax.numpy (traceable) or numpy (host checks, nothing compiled).
  """
  t_pose, goal_pose = _check_poses(t_pose, goal_pose, xp)
  # Pose of the goal frame in the T frame: a goal-frame point p maps to R(d) p + offset.
  d_yaw = goal_pose[..., 2] - t_pose[..., 2]
  ct, st = xp.cos(t_pose[..., 2]), xp.sin(t_pose[..., 2])
  gx = goal_pose[..., 0] - t_pose[..., 0]
  gy = goal_pose[..., 1] - t_pose[..., 1]
  off_x = (ct * gx + st * gy)[..., None]
  off_y = (-st * gx + ct * gy)[..., None]
  cd, sd = xp.cos(d_yaw)[..., None], xp.sin(d_yaw)[..., None]
  cx, cy = GOAL_CELLS[:, 0], GOAL_CELLS[:, 1]
  local = xp.stack([cd * cx - sd * cy + off_x, sd * cx + cd * cy + off_y], axis=-1)
  inside = _points_in_boxes(local, xp)  # [..., P]
  cov = xp.sum(inside, axis=-1, dtype=xp.int32).astype(xp.float32) / xp.float32(GOAL_CELL_COUNT)
  finite = xp.all(xp.isfinite(t_pose), axis=-1) & xp.all(xp.isfinite(goal_pose), axis=-1)
  return xp.where(finite, cov, xp.float32(0.0))


def is_success(
    t_pose: jax.Array, goal_pose: jax.Array, threshold: float = SUCCESS_THRESHOLD
) -> jax.Array:
  """[...] bool: coverage(t_pose, goal_pose) >= threshold; t_pose, goal_pose [..., 3]."""
  return coverage(t_pose, goal_pose) >= threshold
