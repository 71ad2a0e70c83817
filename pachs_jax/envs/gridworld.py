"""A 2D grid world with obstacles, an analytic `Env` for testing the search, and a stand-in
actor-critic whose critic is exact up to a consistent heuristic."""

from __future__ import annotations

import heapq
import math

import jax
import jax.numpy as jnp
import numpy as np

from pachs_jax.envs import base

MOVES_4 = ((1, 0), (-1, 0), (0, 1), (0, -1))
MOVES_8 = MOVES_4 + ((1, 1), (1, -1), (-1, 1), (-1, -1))


def shortest_path_cost(obstacles, start, goal, moves=MOVES_8) -> float:
  """The reference answer for tests: Dijkstra's cheapest path cost (float64) from cell start to
  cell goal over the free cells of obstacles [H, W], inf when unreachable."""
  obstacles = np.asarray(obstacles, bool)
  height, width = obstacles.shape
  start, goal = tuple(int(x) for x in start), tuple(int(x) for x in goal)
  dist = {start: 0.0}
  queue = [(0.0, start)]
  while queue:
    d, (r, c) = heapq.heappop(queue)
    if (r, c) == goal:
      return d
    if d > dist[(r, c)]:
      continue
    for dr, dc in moves:
      nr, nc = r + dr, c + dc
      if 0 <= nr < height and 0 <= nc < width and not obstacles[nr, nc]:
        nd = d + math.hypot(dr, dc)
        if nd < dist.get((nr, nc), math.inf):
          dist[(nr, nc)] = nd
          heapq.heappush(queue, (nd, (nr, nc)))
  return math.inf


class GridWorld(base.Env):
  """Grid world on obstacles [H, W] bool (True = blocked), 4- or 8-connected.

  A node's qpos [2] holds the cell (row, column) as floats; goal [2] the goal cell; the other
  NodeState fields are zero arrays of size 1 and t counts moves. The action in [-1, 1]^2 is
  rounded to a move: with 8 moves each coordinate becomes -1, 0 or 1 (|a| >= 0.5 counts); with
  4 moves only the larger coordinate moves (ties: the row). The zero move, moves leaving the
  grid and moves into an obstacle are invalid. Cost is the move's length (1 or sqrt(2)).
  """

  goal_size = 2

  def __init__(self, obstacles, connectivity: int = 8, episode_length: int | None = None):
    obstacles = np.asarray(obstacles, bool)
    if obstacles.ndim != 2 or obstacles.size == 0:
      raise ValueError(f'obstacles must be a non-empty [H, W] array, got shape {obstacles.shape}')
    if connectivity not in (4, 8):
      raise ValueError(f'connectivity must be 4 or 8, got {connectivity}')
    if obstacles.all():
      raise ValueError('the grid has no free cell')
    self.obstacles = obstacles
    self.connectivity = connectivity
    self.name = f'gridworld{obstacles.shape[0]}x{obstacles.shape[1]}'
    self.episode_length = episode_length or obstacles.size

  @property
  def moves(self) -> np.ndarray:
    """[M, 2] float32 the moves in their fixed enumeration order."""
    return np.asarray(MOVES_8 if self.connectivity == 8 else MOVES_4, np.float32)

  @property
  def action_size(self) -> int:
    return 2

  @property
  def default_lattice_resolution(self) -> jax.Array:
    return jnp.ones((2,), jnp.float32)

  @property
  def lattice_extent(self) -> np.ndarray:
    # cells (row, column) lie in [0, H - 1] x [0, W - 1]
    return np.asarray(self.obstacles.shape, np.float64) - 1.0

  def node(self, cell, goal) -> base.NodeState:
    """A node at cell [..., 2] with goal [..., 2] (any leading batch shape)."""
    cell = jnp.asarray(cell, jnp.float32)
    batch = cell.shape[:-1]
    one = jnp.zeros(batch + (1,), jnp.float32)
    return base.NodeState(qpos=cell, qvel=one, ctrl=one, qacc_warmstart=one,
                          goal=jnp.broadcast_to(jnp.asarray(goal, jnp.float32), cell.shape),
                          t=jnp.zeros(batch, jnp.int32))

  def move(self, action: jax.Array) -> jax.Array:
    """[..., 2] float32 move of actions [..., 2] (zero for the invalid zero move)."""
    a = jnp.clip(jnp.nan_to_num(action.astype(jnp.float32)), -1.0, 1.0)
    step = jnp.where(jnp.abs(a) >= 0.5, jnp.sign(a), 0.0)
    if self.connectivity == 4:
      row_wins = jnp.abs(a[..., :1]) >= jnp.abs(a[..., 1:])
      step = jnp.where(jnp.concatenate([row_wins, ~row_wins], axis=-1), step, 0.0)
    return step

  def sample_instance(self, key: jax.Array) -> base.NodeState:
    free = jnp.asarray(~self.obstacles).ravel()
    start_key, goal_key = jax.random.split(key)
    width = self.obstacles.shape[1]
    cells = [jax.random.choice(k, free.size, p=free / free.sum()) for k in (start_key, goal_key)]
    to_cell = lambda c: jnp.stack([c // width, c % width]).astype(jnp.float32)
    return self.node(to_cell(cells[0]), to_cell(cells[1]))

  def transition(self, node: base.NodeState, action: jax.Array) -> base.EdgeOutcome:
    step = self.move(action)
    nxt = node.qpos + step
    shape = jnp.asarray(self.obstacles.shape, jnp.float32)
    inside = jnp.all((nxt >= 0) & (nxt < shape))
    cell = jnp.clip(nxt, 0, shape - 1).astype(jnp.int32)
    free = ~jnp.asarray(self.obstacles)[cell[0], cell[1]]
    valid = inside & free & jnp.any(step != 0)
    next_node = node.replace(qpos=jnp.where(valid, nxt, node.qpos), t=node.t + 1)
    cost = jnp.sqrt(jnp.sum(step * step))
    return base.EdgeOutcome(next_node=next_node, cost=cost,
                            is_goal=valid & self.goal_reached(next_node), is_valid=valid)

  def observation(self, node: base.NodeState) -> jax.Array:
    return jnp.concatenate([node.qpos, node.goal]).astype(jnp.float32)

  def lattice_coords(self, node: base.NodeState, resolution: jax.Array) -> jax.Array:
    return jnp.floor(node.qpos / resolution).astype(jnp.int32)

  def goal_reached(self, node: base.NodeState) -> jax.Array:
    return jnp.all(node.qpos == node.goal)


class GridActorCritic:
  """Stand-in actor-critic for a GridWorld.

  sample_actions proposes the moves in their fixed order (cycled if num exceeds them);
  q_values = -(move cost + h(successor)), h the octile (8 moves) or Manhattan (4 moves)
  distance to the goal, which ignores obstacles and is consistent.
  """

  def __init__(self, env: GridWorld):
    self.env = env

  def sample_actions(self, key: jax.Array, obs: jax.Array, num: int) -> jax.Array:
    """[..., num, 2] the moves in their fixed order for obs [..., 4] (key unused)."""
    del key
    moves = jnp.asarray(self.env.moves)[jnp.arange(num) % len(self.env.moves)]
    return jnp.broadcast_to(moves, obs.shape[:-1] + (num, 2))

  def heuristic(self, cell: jax.Array, goal: jax.Array) -> jax.Array:
    """[...] octile (8 moves) or Manhattan (4 moves) distance of cell [..., 2] to goal [..., 2]."""
    d = jnp.abs(cell - goal)
    if self.env.connectivity == 4:
      return d[..., 0] + d[..., 1]
    lo, hi = jnp.minimum(d[..., 0], d[..., 1]), jnp.maximum(d[..., 0], d[..., 1])
    return hi + (math.sqrt(2.0) - 1.0) * lo

  def q_values(self, obs: jax.Array, actions: jax.Array) -> jax.Array:
    """[..., num] -(move cost + heuristic of the successor) of actions [..., num, 2]."""
    step = self.env.move(actions)
    cell, goal = obs[..., None, :2], obs[..., None, 2:]
    cost = jnp.sqrt(jnp.sum(step * step, axis=-1))
    return -(cost + self.heuristic(cell + step, goal))
