"""Point mass: an analytic task for fast tests of training and search (no physics engine)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from pachs_jax.envs import base


@dataclasses.dataclass(frozen=True)
class PointMassConfig:
  """Parameters of the point-mass task (lengths in arena units).

  dim: number of position (and action) dimensions.
  step_size: displacement per unit action per step.
  arena_half_extent: positions are clipped to [-arena_half_extent, arena_half_extent]^dim.
  start_half_extent: starts and goals are uniform in [-start_half_extent, start_half_extent]^dim.
  success_radius: success when the distance to the goal is at most this.
  action_cost: weight of |action|^2 in the step cost.
  lattice_resolution: default lattice cell size.
  """

  dim: int = 2
  episode_length: int = 50
  step_size: float = 0.1
  arena_half_extent: float = 1.0
  start_half_extent: float = 0.5
  success_radius: float = 0.05
  action_cost: float = 0.01
  lattice_resolution: float = 0.025

  def __post_init__(self):
    if self.dim < 1:
      raise ValueError(f'PointMassConfig.dim must be >= 1, got {self.dim}')
    if self.episode_length < 1:
      raise ValueError(f'PointMassConfig.episode_length must be >= 1, got {self.episode_length}')
    if not 0 < self.start_half_extent <= self.arena_half_extent:
      raise ValueError('PointMassConfig needs 0 < start_half_extent <= arena_half_extent, got '
                       f'{self.start_half_extent} and {self.arena_half_extent}')


class PointMassEnv(base.Env):
  """A point that moves toward a random goal; observation = [position, goal - position].

  The point moves by `step_size * action` per control step (clipped to the arena); start and
  goal are uniform in a smaller box. Cost per step (= -reward): the distance to the goal after
  the move plus a small quadratic action cost; success: within `success_radius` of the goal. A
  non-finite action is an invalid edge (the node does not move). Node layout as in MJX:
  qpos = position [D]; qvel, ctrl, qacc_warmstart = zeros [D]; goal = goal position [D].
  """

  name = 'point-mass'

  def __init__(self, config: PointMassConfig = PointMassConfig()):
    self.config = config
    self.episode_length = config.episode_length
    self.goal_size = config.dim

  fingerprint = property(base.config_fingerprint)

  @property
  def action_size(self) -> int:
    return self.config.dim

  @property
  def default_lattice_resolution(self) -> jax.Array:
    return jnp.full((self.config.dim,), self.config.lattice_resolution, jnp.float32)

  @property
  def lattice_extent(self):
    # positions are clipped to the arena
    return (float(self.config.arena_half_extent),) * self.config.dim

  def node_from_positions(self, position: jax.Array, goal: jax.Array) -> base.NodeState:
    """A start node at position [D] with goal [D]; no batch axis."""
    zeros = jnp.zeros((self.config.dim,), jnp.float32)
    return base.NodeState(qpos=jnp.asarray(position, jnp.float32), qvel=zeros, ctrl=zeros,
                          qacc_warmstart=zeros, goal=jnp.asarray(goal, jnp.float32),
                          t=jnp.zeros((), jnp.int32))

  def sample_instance(self, key: jax.Array) -> base.NodeState:
    c = self.config
    k_pos, k_goal = jax.random.split(key)
    low, high = -c.start_half_extent, c.start_half_extent
    position = jax.random.uniform(k_pos, (c.dim,), jnp.float32, low, high)
    goal = jax.random.uniform(k_goal, (c.dim,), jnp.float32, low, high)
    return self.node_from_positions(position, goal)

  def transition(self, node: base.NodeState, action: jax.Array) -> base.EdgeOutcome:
    c = self.config
    clean, ok = base.sanitize_actions(action)
    moved = jnp.clip(node.qpos + c.step_size * clean, -c.arena_half_extent, c.arena_half_extent)
    position = jnp.where(ok, moved, node.qpos)
    next_node = node.replace(qpos=position, t=node.t + 1)
    distance = jnp.linalg.norm(position - node.goal)
    cost = distance + c.action_cost * jnp.sum(jnp.square(clean))
    worst = 2.0 * c.arena_half_extent * jnp.sqrt(float(c.dim)) + c.action_cost * c.dim
    cost = jnp.where(ok, cost, worst).astype(jnp.float32)
    is_goal = (distance <= c.success_radius) & ok
    return base.EdgeOutcome(next_node, cost, is_goal, ok)

  def observation(self, node: base.NodeState) -> jax.Array:
    return jnp.concatenate([node.qpos, node.goal - node.qpos]).astype(jnp.float32)

  def lattice_coords(self, node: base.NodeState, resolution: jax.Array) -> jax.Array:
    return jnp.floor(node.qpos / resolution).astype(jnp.int32)

  def goal_reached(self, node: base.NodeState) -> jax.Array:
    return jnp.linalg.norm(node.qpos - node.goal) <= self.config.success_radius
