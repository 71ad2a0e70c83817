"""The node pool: every search node of I instances in fixed-capacity arrays [I, P, ...]
(bytes per node: docs/search_loop.md)."""

from __future__ import annotations

from typing import Tuple

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax.envs import base
from pachs_jax.search import lattice as lattice_lib

ROOT_INDEX = 0
NO_PARENT = -1


@struct.dataclass
class NodePool:
  """Nodes of I instances, capacity P (entries at index >= size are unused).

  nodes: NodeState [I, P, ...] the state of each node.
  g: [I, P] float32 cost of the best known path from the start (cost units).
  parent: [I, P] int32 parent node index (NO_PARENT for the start).
  action: [I, P, A] float32 the action from the parent that reached the node.
  depth: [I, P] int32 transitions from the start (an edge of H transitions adds H).
  closed: [I, P] bool, the node was expanded.
  is_goal: [I, P] bool, the node satisfies the goal rule.
  open_key: [I, P] float32 priority of the node's latest dummy edge (a popped dummy edge with
    another key is stale).
  edge_actions: [I, P, N, A] float32 the actions sampled when the node was expanded.
  edge_q: [I, P, N] float32 their cost-to-go estimates q = max(-Q, 0).
  segment_actions: [I, P, H - 1, A] float32 with edges of H steps (`segment`), the actor's
    actions after `action` on the way to the node; segment_nodes: NodeState [I, P, H - 1, ...]
    the states passed (H = 1: empty).
  size: [I] int32 nodes in use; overflow: [I] int32 new nodes that found no room.
  """

  nodes: base.NodeState
  g: jax.Array
  parent: jax.Array
  action: jax.Array
  depth: jax.Array
  closed: jax.Array
  is_goal: jax.Array
  open_key: jax.Array
  edge_actions: jax.Array
  edge_q: jax.Array
  segment_actions: jax.Array
  segment_nodes: base.NodeState
  size: jax.Array
  overflow: jax.Array

  @property
  def capacity(self) -> int:
    return self.g.shape[1]


def _rows(index: jax.Array) -> jax.Array:
  return jnp.arange(index.shape[0]).reshape((-1,) + (1,) * (index.ndim - 1))


def init(start: base.NodeState, start_is_goal: jax.Array, capacity: int, num_actions: int,
         action_size: int, edge_steps: int = 1) -> NodePool:
  """A pool of `capacity` nodes per instance holding the start nodes start [I, ...] at index 0;
  edge_steps: the transitions of one edge (the segment fields hold edge_steps - 1)."""
  num_instances = start_is_goal.shape[0]
  shape = (num_instances, capacity)

  def leaf(x):
    x = jnp.asarray(x)
    out = jnp.zeros(shape + x.shape[1:], x.dtype)
    return out.at[:, ROOT_INDEX].set(x)

  return NodePool(
      nodes=jax.tree.map(leaf, start),
      g=jnp.zeros(shape, jnp.float32),
      parent=jnp.full(shape, NO_PARENT, jnp.int32),
      action=jnp.zeros(shape + (action_size,), jnp.float32),
      depth=jnp.zeros(shape, jnp.int32),
      closed=jnp.zeros(shape, bool),
      is_goal=jnp.zeros(shape, bool).at[:, ROOT_INDEX].set(start_is_goal),
      open_key=jnp.full(shape, jnp.inf, jnp.float32).at[:, ROOT_INDEX].set(0.0),
      edge_actions=jnp.zeros(shape + (num_actions, action_size), jnp.float32),
      edge_q=jnp.zeros(shape + (num_actions,), jnp.float32),
      segment_actions=jnp.zeros(shape + (edge_steps - 1, action_size), jnp.float32),
      segment_nodes=jax.tree.map(
          lambda x: jnp.zeros(shape + (edge_steps - 1,) + jnp.shape(x)[1:], jnp.asarray(x).dtype),
          start),
      size=jnp.ones((num_instances,), jnp.int32),
      overflow=jnp.zeros((num_instances,), jnp.int32))


def gather(values: jax.Array, index: jax.Array) -> jax.Array:
  """values [I, P, ...] at index [I, K] -> [I, K, ...]."""
  return values[_rows(index), index]


def gather_nodes(pool: NodePool, index: jax.Array) -> base.NodeState:
  """NodeState [I, K, ...] of the nodes at index [I, K]."""
  return jax.tree.map(lambda x: gather(x, index), pool.nodes)


def _scatter(values: jax.Array, index: jax.Array, mask: jax.Array, new: jax.Array) -> jax.Array:
  """values [I, P, ...] with new [I, K, ...] written at index [I, K] where mask."""
  target = jnp.where(mask, index, values.shape[1])  # out of bounds: dropped
  return values.at[_rows(index), target].set(new.astype(values.dtype), mode='drop')


def allocate(pool: NodePool, want: jax.Array) -> Tuple[NodePool, jax.Array, jax.Array]:
  """New node indices for the entries of want [I, K] in order: (pool, index [I, K], ok [I, K]).

  Entries that do not fit get ok False and are counted in overflow.
  """
  index = pool.size[:, None] + jnp.cumsum(want, axis=1, dtype=jnp.int32) - 1
  ok = want & (index < pool.capacity)
  pool = pool.replace(
      size=pool.size + jnp.sum(ok, axis=1, dtype=jnp.int32),
      overflow=pool.overflow + jnp.sum(want & ~ok, axis=1, dtype=jnp.int32))
  return pool, index, ok


def set_nodes(pool: NodePool, index: jax.Array, mask: jax.Array, nodes: base.NodeState,
              g: jax.Array, parent: jax.Array, action: jax.Array, depth: jax.Array,
              is_goal: jax.Array, open_key: jax.Array) -> NodePool:
  """Writes the (open) nodes [I, K] at index [I, K] where mask."""
  put = lambda values, new: _scatter(values, index, mask, new)
  return pool.replace(
      nodes=jax.tree.map(put, pool.nodes, nodes), g=put(pool.g, g),
      parent=put(pool.parent, parent), action=put(pool.action, action),
      depth=put(pool.depth, depth), closed=put(pool.closed, jnp.zeros_like(mask)),
      is_goal=put(pool.is_goal, is_goal), open_key=put(pool.open_key, open_key))


def set_segments(pool: NodePool, index: jax.Array, mask: jax.Array, actions: jax.Array,
                 nodes: base.NodeState) -> NodePool:
  """Writes the insides of the segments [I, K] (actions [I, K, H - 1, A], nodes NodeState
  [I, K, H - 1, ...]) that reached the nodes at index [I, K] where mask."""
  put = lambda values, new: _scatter(values, index, mask, new)
  return pool.replace(segment_actions=put(pool.segment_actions, actions),
                      segment_nodes=jax.tree.map(put, pool.segment_nodes, nodes))


def close(pool: NodePool, index: jax.Array, mask: jax.Array, edge_actions: jax.Array,
          edge_q: jax.Array) -> NodePool:
  """Marks the nodes at index [I, K] expanded (where mask) and stores their sampled edges
  edge_actions [I, K, N, A] and edge_q [I, K, N]."""
  return pool.replace(
      closed=_scatter(pool.closed, index, mask, jnp.ones_like(mask)),
      edge_actions=_scatter(pool.edge_actions, index, mask, edge_actions),
      edge_q=_scatter(pool.edge_q, index, mask, edge_q))


def best_of_cell(cell: jax.Array, g: jax.Array, mask: jax.Array) -> jax.Array:
  """[I, K] bool: mask and no other masked entry of the same cell [I, K, L] has a smaller
  (g, position)."""
  k = g.shape[1]
  earlier = jnp.arange(k)[None, :] < jnp.arange(k)[:, None]
  same = jnp.all(cell[:, :, None] == cell[:, None, :], axis=-1) & mask[:, None, :]
  better = (g[:, None, :] < g[:, :, None]) | ((g[:, None, :] == g[:, :, None]) & earlier)
  return mask & ~jnp.any(same & better, axis=2)


def merge_successors(pool: NodePool, table: lattice_lib.LatticeTable, cell: jax.Array,
                     g: jax.Array, usable: jax.Array, unmerged=None):
  """Duplicate detection with the g-value test for a batch of successors [I, K].

  cell: [I, K, L] int32 lattice keys; g: [I, K] float32 path costs through the new edges;
  usable: [I, K] bool, evaluated valid edges. A successor counts when it is the best of its cell
  in the batch and its cell is new (a node is allocated) or the cell's node is open and its g
  improves (closed nodes are never updated, so their children keep replaying exactly).
  unmerged: [I, K] bool or None, usable successors that always get a node of their own (outside
  the table). Returns (pool, table, node [I, K] int32 node to write, write [I, K] bool).
  """
  own = jnp.zeros_like(usable) if unmerged is None else usable & unmerged
  candidate = best_of_cell(cell, g, usable & ~own)
  table, slot, _, has_slot = lattice_lib.insert(table, cell, candidate)
  known = lattice_lib.get_values(table, slot)
  old = jnp.maximum(known, 0)
  is_new = candidate & has_slot & (known == lattice_lib.NO_VALUE)
  improves = (candidate & has_slot & (known >= 0) & ~gather(pool.closed, old)
              & (g < gather(pool.g, old)))
  pool, new_node, fits = allocate(pool, is_new | own)
  table = lattice_lib.set_values(table, slot, new_node, fits & ~own)
  return pool, table, jnp.where(fits, new_node, old), fits | improves
