"""The BFS-3D heuristic of the ePA*SE baseline (distances over a voxel grid of the workspace
from the goal cell) and the Panda-Shelf setup built on it (docs/baselines.md)."""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from pachs_jax.envs import base
from pachs_jax.search.baselines import epase

CONNECTIVITIES = (6, 26)


@dataclasses.dataclass(frozen=True)
class VoxelGrid:
  """lower: (x, y, z) corner of the grid (m); cell: edge length (m); shape: cells per axis."""

  lower: Tuple[float, float, float]
  cell: float
  shape: Tuple[int, int, int]

  def __post_init__(self):
    if len(self.lower) != 3 or len(self.shape) != 3:
      raise ValueError(f'VoxelGrid needs 3 lower corner values and 3 sizes, got {self.lower}, '
                       f'{self.shape}')
    if not (math.isfinite(self.cell) and self.cell > 0):
      raise ValueError(f'VoxelGrid.cell must be a positive length, got {self.cell!r}')
    if any(int(s) < 1 for s in self.shape):
      raise ValueError(f'VoxelGrid.shape must be positive, got {self.shape}')

  @classmethod
  def covering(cls, lower, upper, cell: float) -> 'VoxelGrid':
    """The grid of cells of `cell` m covering the box lower [3] - upper [3] (m)."""
    lower, upper = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
    if lower.shape != (3,) or upper.shape != (3,) or np.any(upper <= lower):
      raise ValueError(f'need lower < upper, 3 values each; got {lower}, {upper}')
    shape = tuple(int(s) for s in np.ceil((upper - lower) / cell - 1e-9))
    return cls(tuple(float(v) for v in lower), float(cell), shape)

  def centres(self) -> np.ndarray:
    """[X, Y, Z, 3] cell centres (m)."""
    axes = [self.lower[i] + (np.arange(self.shape[i]) + 0.5) * self.cell for i in range(3)]
    return np.stack(np.meshgrid(*axes, indexing='ij'), axis=-1)

  def cell_of(self, points: jax.Array) -> Tuple[jax.Array, jax.Array]:
    """(int32 cell indices [..., 3], [...] bool inside the grid) of points [..., 3] (m)."""
    idx = jnp.floor((points - jnp.asarray(self.lower, jnp.float32)) / self.cell)
    inside = jnp.all((idx >= 0) & (idx < jnp.asarray(self.shape)), axis=-1)
    idx = jnp.clip(idx, 0, jnp.asarray(self.shape) - 1).astype(jnp.int32)
    return idx, inside


def box_occupancy(grid: VoxelGrid, centres, halves, inflation: float) -> np.ndarray:
  """[X, Y, Z] bool: the cell centre lies within `inflation` m of one of the axis-aligned boxes
  centres [n, 3], half extents halves [n, 3] (m)."""
  p = grid.centres()[..., None, :] - np.asarray(centres)[None, None, None]  # [X, Y, Z, n, 3]
  q = np.abs(p) - np.asarray(halves)
  sdf = np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(np.max(q, axis=-1), 0.0)
  return np.any(sdf < inflation, axis=-1)


def _neighbour_min(d: jax.Array, connectivity: int) -> jax.Array:
  """[X, Y, Z] minimum of d over each cell's neighbours (the cell itself included for 26)."""
  def shifted(x, axis, s):
    pad = [(0, 0)] * 3
    pad[axis] = (1, 1)
    xp = jnp.pad(x, pad, constant_values=jnp.inf)
    return jax.lax.slice_in_dim(xp, 1 + s, 1 + s + x.shape[axis], axis=axis)

  if connectivity == 26:
    for axis in range(3):
      d = jnp.minimum(d, jnp.minimum(shifted(d, axis, -1), shifted(d, axis, 1)))
    return d
  out = jnp.full_like(d, jnp.inf)
  for axis in range(3):
    out = jnp.minimum(out, jnp.minimum(shifted(d, axis, -1), shifted(d, axis, 1)))
  return out


def bfs_distance(blocked: jax.Array, goal_cell: jax.Array, connectivity: int = 26) -> jax.Array:
  """[X, Y, Z] float32 BFS steps from goal_cell [3] (int) over the free cells of blocked
  [X, Y, Z] (bool); +inf where unreachable or blocked (the goal cell counts as free)."""
  if connectivity not in CONNECTIVITIES:
    raise ValueError(f'connectivity must be one of {CONNECTIVITIES}, got {connectivity}')
  blocked = jnp.asarray(blocked, bool)
  if blocked.ndim != 3:
    raise ValueError(f'blocked must be [X, Y, Z], got shape {blocked.shape}')
  g = tuple(jnp.asarray(goal_cell, jnp.int32)[i] for i in range(3))
  blocked = blocked.at[g].set(False)
  d0 = jnp.full(blocked.shape, jnp.inf, jnp.float32).at[g].set(0.0)

  def cond(c):
    return c[1]

  def body(c):
    d, _ = c
    new = jnp.where(blocked, jnp.inf, jnp.minimum(d, _neighbour_min(d, connectivity) + 1.0))
    return new, jnp.any(new != d)

  d, _ = jax.lax.while_loop(cond, body, (d0, jnp.bool_(True)))
  return d


def grid_heuristic(grid: VoxelGrid, blocked: np.ndarray, point_fn: Callable,
                   goal_fn: Callable, connectivity: int = 26,
                   unreachable: float = 10.0, spread: int = 0) -> epase.Heuristic:
  """An ePA*SE heuristic: BFS distance (m) of point_fn(node) [3] from goal_fn(node) [3]'s cell.

  init(start_nodes [I]) runs one BFS per instance ([I, X, Y, Z] grids in metres); spread > 0
  extends the distances into the blocked cells up to `spread` cells deep (a blocked cell gets
  its nearest valued neighbour's distance + 1 cell), so a state whose point lies in an inflated
  cell (its edge was collision-checked) keeps an informative value. On the shelf the states
  closest to a target (the tip just inside a compartment, near its floor board) lie in such
  cells. A point outside the grid, or blocked (beyond the spread) or unreachable gets
  `unreachable` (m; finite, so such states stay in OPEN, last).
  """
  blocked = np.asarray(blocked, bool)
  if blocked.shape != tuple(grid.shape):
    raise ValueError(f'blocked has shape {blocked.shape}, the grid {grid.shape}')
  if not (math.isfinite(unreachable) and unreachable >= 0):
    raise ValueError(f'unreachable must be a finite length >= 0, got {unreachable!r}')

  def init(start_nodes: base.NodeState) -> jax.Array:
    goals = jax.vmap(goal_fn)(start_nodes)
    cells, _ = grid.cell_of(goals)
    steps = jax.vmap(lambda c: bfs_distance(jnp.asarray(blocked), c, connectivity))(cells)
    for _ in range(spread):
      steps = jnp.where(jnp.isfinite(steps), steps,
                        jax.vmap(lambda d: _neighbour_min(d, connectivity))(steps) + 1.0)
    return jnp.where(jnp.isfinite(steps), steps * grid.cell, unreachable)

  def value(dist: jax.Array, nodes: base.NodeState) -> jax.Array:
    points = jax.vmap(jax.vmap(point_fn))(nodes)  # [I, K, 3]
    idx, inside = grid.cell_of(points)
    rows = jnp.arange(idx.shape[0])[:, None]
    h = dist[rows, idx[..., 0], idx[..., 1], idx[..., 2]]
    return jnp.where(inside, h, unreachable)

  return epase.Heuristic(init=init, value=value)


# ---------------------------------------------------------------- Panda-Shelf


@dataclasses.dataclass(frozen=True)
class ShelfEpaseSetup:
  """primitives [14, 7] joint moves (rad); edge_fn(nodes [B], deltas [B, 7]) -> EdgeOutcome via
  `ShelfEnv.move`; heuristic: BFS-3D of the tip; lattice_resolution: half a primitive step per
  joint (the reachable configurations lie on a lattice of one step); grid, blocked: the voxels."""

  primitives: np.ndarray
  edge_fn: Callable
  heuristic: epase.Heuristic
  lattice_resolution: Tuple[float, ...]
  grid: VoxelGrid
  blocked: np.ndarray


def shelf_setup(env, step_deg: float = 7.0, cell: float = 0.02, inflation: float = 0.02,
                connectivity: int = 26, num_checks: Optional[int] = None,
                bounds: Optional[Tuple[Tuple[float, ...], Tuple[float, ...]]] = None,
                unreachable: float = 10.0, spread: int = 0) -> ShelfEpaseSetup:
  """ePA*SE's pieces for a `ShelfEnv`: +-step_deg single-joint moves, checked at num_checks
  points (None: as densely as the env checks one action), and the BFS-3D heuristic over
  `bounds` ((lower, upper) m; None: the arm's side of the shelf up to past its back)."""
  if not (math.isfinite(step_deg) and step_deg > 0):
    raise ValueError(f'step_deg must be a positive angle, got {step_deg!r}')
  step = math.radians(step_deg)
  dof = env.action_size
  primitives = np.concatenate([np.eye(dof), -np.eye(dof)]).astype(np.float32) * step
  if num_checks is None:
    c = env.config
    num_checks = max(1, math.ceil(c.num_checks * step / c.action_scale))
  checks = int(num_checks)
  edge_fn = jax.vmap(lambda n, d: env.move(n, d, checks))
  if bounds is None:
    c = env.config
    top = c.board_z[-1] + c.thickness
    bounds = ((-0.3, -0.5 * c.width - 0.2, 0.0),
              (c.front_x + c.depth + 0.1, 0.5 * c.width + 0.2, top + 0.3))
  grid = VoxelGrid.covering(bounds[0], bounds[1], cell)
  centres = np.array([b[0] for b in env.boxes.values()])
  halves = np.array([b[1] for b in env.boxes.values()])
  blocked = box_occupancy(grid, centres, halves, inflation)
  heuristic = grid_heuristic(grid, blocked, lambda n: env.tip_position(n.qpos),
                             lambda n: n.goal, connectivity, unreachable, spread)
  return ShelfEpaseSetup(primitives=primitives, edge_fn=edge_fn, heuristic=heuristic,
                         lattice_resolution=(0.5 * step,) * dof, grid=grid, blocked=blocked)
