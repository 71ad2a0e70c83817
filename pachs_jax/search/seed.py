"""A known path put into a new search's tree: a replanning query's last answer, followed from
the new start, becomes nodes every H transitions (the search's edges), so the search goes on
from where the last one got instead of starting over (`pachs.plant`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax.envs import base
from pachs_jax.search import segment


@struct.dataclass
class Seed:
  """Paths from the search's start states, lanes [I].

  actions: [I, T, A] float32 the actions applied (rows >= length ignored).
  states: NodeState [I, T + 1, ...] the states passed, the start first.
  step_cost: [I, T] float32 each transition's cost (the env's cost units).
  length: [I] int32 transitions in the path (0: no path).
  """

  actions: jax.Array
  states: base.NodeState
  step_cost: jax.Array
  length: jax.Array

  @property
  def horizon(self) -> int:
    return self.actions.shape[1]


def num_edges(horizon: int, edge_steps: int) -> int:
  """The most edges of edge_steps transitions a path of `horizon` transitions splits into."""
  return -(-horizon // edge_steps)


def edge(seed: Seed, index: int, edge_steps: int):
  """The seed's edge `index` (its transitions index * H up to (index + 1) * H or the path's
  end): (first action [I, A], outcome [I] (a `segment.SegmentOutcome` without h when H > 1,
  else a `base.EdgeOutcome`), present [I] bool the path reaches into the edge)."""
  begin = index * edge_steps
  end = jnp.minimum(begin + edge_steps, seed.length)  # [I]
  present = begin < seed.length
  rows = jnp.arange(seed.length.shape[0])[:, None]
  at = lambda tree, t: jax.tree.map(lambda x: x[rows[:, 0], t], tree)
  cum = jnp.concatenate([jnp.zeros_like(seed.step_cost[:, :1]),
                         jnp.cumsum(seed.step_cost, axis=1)], axis=1)
  cost = at(cum, end) - cum[:, begin]
  last = at(seed.states, end)
  first_action = seed.actions[:, begin]
  if edge_steps == 1:
    return first_action, base.EdgeOutcome(next_node=last, cost=cost, is_goal=None,
                                           is_valid=present), present
  inside = begin + 1 + jnp.arange(edge_steps - 1)[None]  # [1, H - 1]
  before_end = inside < end[:, None]
  index_actions = jnp.minimum(inside, seed.horizon - 1)
  actions = jnp.where(before_end[..., None], seed.actions[rows, index_actions], 0.0)
  index_nodes = jnp.minimum(inside, end[:, None])
  nodes = jax.tree.map(lambda x: x[rows, index_nodes], seed.states)
  outcome = segment.SegmentOutcome(
      next_node=last, cost=cost, is_goal=None, is_valid=present, actions=actions, nodes=nodes,
      length=jnp.where(present, end - begin, 0).astype(jnp.int32), h=None)
  return first_action, outcome, present
