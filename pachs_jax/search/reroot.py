"""A new search that keeps the last one's subtree below the node where the world now is: after
the world executed the first transitions of a search's answer, the answer's node at that depth
becomes the start (its state the world's), its descendants stay with their g and depth less the
root's, and the OPEN entries, lattice cells and visit counts of the nodes kept go with them, so
that a replanning query goes on from the last query's search (docs/closed_loop.md)."""

from __future__ import annotations

from typing import Callable, Tuple

import jax
import jax.numpy as jnp

from pachs_jax import trees
from pachs_jax.search import heap as heap_lib
from pachs_jax.search import lattice as lattice_lib
from pachs_jax.search import pool as pool_lib

# the nodes inserted into the lattice table per probe batch when a kept subtree's cells are
# (its probe compares every pair of a batch)
TABLE_BATCH = 128


def ancestor_at_depth(pool: pool_lib.NodePool, final: jax.Array, depth: jax.Array) -> jax.Array:
  """[I] int32 the node on the path from the start to final [I] (itself included) whose depth
  is depth [I] transitions; NO_PARENT where the path has no node at that depth (an edge spans
  it, the path is shorter, or depth < 0)."""
  rows = jnp.arange(final.shape[0])
  depth_of = lambda node: pool.depth[rows, jnp.maximum(node, 0)]

  def cond(node):
    return jnp.any((node != pool_lib.NO_PARENT) & (depth_of(node) > depth))

  def body(node):
    deeper = (node != pool_lib.NO_PARENT) & (depth_of(node) > depth)
    return jnp.where(deeper, pool.parent[rows, jnp.maximum(node, 0)], node)

  node = jax.lax.while_loop(cond, body, final.astype(jnp.int32))
  at = (node != pool_lib.NO_PARENT) & (depth_of(node) == depth) & (depth >= 0)
  return jnp.where(at, node, pool_lib.NO_PARENT).astype(jnp.int32)


def subtree(pool: pool_lib.NodePool, root: jax.Array) -> jax.Array:
  """[I, P] bool the pool's nodes whose path from the start passes root [I] (root included;
  none where root is NO_PARENT)."""
  rows = jnp.arange(root.shape[0])[:, None]
  index = jnp.arange(pool.capacity)[None, :]
  node = jnp.where(index < pool.size[:, None], index, pool_lib.NO_PARENT)
  has = (root != pool_lib.NO_PARENT)[:, None]

  def cond(carry):
    return jnp.any(carry[0] != pool_lib.NO_PARENT)

  def body(carry):
    node, kept = carry
    kept = kept | (has & (node == root[:, None]))
    up = pool.parent[rows, jnp.maximum(node, 0)]
    return jnp.where(node != pool_lib.NO_PARENT, up, pool_lib.NO_PARENT), kept

  return jax.lax.while_loop(cond, body, (node, jnp.zeros(node.shape, bool)))[1]


def within_room(kept: jax.Array, depth: jax.Array, room: int) -> jax.Array:
  """kept [I, P] cut to at most room nodes an instance by depth [I, P]: where more are kept,
  those shallower than the (room + 1)-th shallowest."""
  if room >= kept.shape[1]:
    return kept
  if room < 1:
    return jnp.zeros_like(kept)
  sorted_depth = jnp.sort(jnp.where(kept, depth, jnp.iinfo(jnp.int32).max), axis=1)
  cut = sorted_depth[:, room]  # int max where room or fewer are kept
  return kept & ((depth < cut[:, None]) | (cut[:, None] == jnp.iinfo(jnp.int32).max))


def compaction(kept: jax.Array, root: jax.Array) -> Tuple[jax.Array, jax.Array, jax.Array]:
  """(source [I, P] int32 the old index of each new pool entry, new_index [I, P] int32 each old
  node's new index (-1: dropped), size [I] int32) of the kept nodes [I, P], root [I] first and
  the others in their order."""
  num_instances, capacity = kept.shape
  index = jnp.arange(capacity)[None, :]
  is_root = index == root[:, None]
  others = kept & ~is_root
  new_index = jnp.where(is_root & kept, 0,
                        jnp.where(others, jnp.cumsum(others, axis=1, dtype=jnp.int32), -1))
  rows = jnp.arange(num_instances)[:, None]
  source = jnp.zeros(kept.shape, jnp.int32).at[
      rows, jnp.where(new_index >= 0, new_index, capacity)].set(
          jnp.broadcast_to(index, kept.shape), mode='drop')
  return source, new_index.astype(jnp.int32), jnp.sum(kept, axis=1, dtype=jnp.int32)


def _carry_pool(old: pool_lib.NodePool, fresh: pool_lib.NodePool, root: jax.Array,
                source: jax.Array, new_index: jax.Array, size: jax.Array,
                used: jax.Array) -> pool_lib.NodePool:
  """fresh (a new search's pool, its start at index 0) holding old's nodes source [I, P] where
  used [I, P], their g and depth less the root's and parents renumbered; the start keeps its
  state and goal flag, and takes the root's expansion (closed, sampled edges, open key)."""
  take = lambda x: pool_lib.gather(x, source)
  g_root = pool_lib.gather(old.g, jnp.maximum(root, 0)[:, None])
  depth_root = pool_lib.gather(old.depth, jnp.maximum(root, 0)[:, None])
  parent = take(old.parent)
  parent = jnp.where(parent >= 0, pool_lib.gather(new_index, jnp.maximum(parent, 0)),
                     pool_lib.NO_PARENT)
  carried = fresh.replace(
      nodes=jax.tree.map(take, old.nodes), g=take(old.g) - g_root, parent=parent,
      action=take(old.action), depth=take(old.depth) - depth_root, closed=take(old.closed),
      is_goal=take(old.is_goal), open_key=take(old.open_key) - g_root,
      edge_actions=take(old.edge_actions), edge_q=take(old.edge_q),
      segment_actions=take(old.segment_actions),
      segment_nodes=jax.tree.map(take, old.segment_nodes))
  start = jnp.arange(old.capacity)[None, :] == pool_lib.ROOT_INDEX
  carried = carried.replace(nodes=trees.where(start, fresh.nodes, carried.nodes),
                            is_goal=jnp.where(start, fresh.is_goal, carried.is_goal))
  fields = ('nodes', 'g', 'parent', 'action', 'depth', 'closed', 'is_goal', 'open_key',
            'edge_actions', 'edge_q', 'segment_actions', 'segment_nodes')
  has = root != pool_lib.NO_PARENT
  return fresh.replace(size=jnp.where(has, size, fresh.size), **{
      name: trees.where(used, getattr(carried, name), getattr(fresh, name)) for name in fields})


def _carry_edges(old: heap_lib.Heap, fresh: heap_lib.Heap, kept: jax.Array,
                 new_index: jax.Array, g_root: jax.Array, slots: int) -> heap_lib.Heap:
  """fresh (empty) with old's entries (value node * slots + slot) of the kept nodes [I, P]:
  keys less g_root [I], nodes renumbered, in their order."""
  node, slot = old.values // slots, old.values % slots
  keep = (old.keys < heap_lib.INF) & pool_lib.gather(kept, node)
  return heap_lib.push(fresh, old.keys - g_root[:, None],
                       pool_lib.gather(new_index, node) * slots + slot, keep)


def _insert_cells(table: lattice_lib.LatticeTable, cells: jax.Array, mask: jax.Array,
                  size: jax.Array) -> lattice_lib.LatticeTable:
  """table with the cells [I, P, L] of the nodes where mask [I, P] (below size [I]) mapped to
  their index, TABLE_BATCH nodes a probe batch; a cell already held keeps its node."""
  num_instances, capacity = mask.shape
  batch = min(TABLE_BATCH, capacity)
  pad = -capacity % batch
  cells = jnp.pad(cells, ((0, 0), (0, pad), (0, 0)))
  mask = jnp.pad(mask, ((0, 0), (0, pad)))

  def body(i, table):
    at = i * batch
    part = jax.lax.dynamic_slice_in_dim(cells, at, batch, axis=1)
    want = jax.lax.dynamic_slice_in_dim(mask, at, batch, axis=1)
    table, slot, is_new, _ = lattice_lib.insert(table, part, want)
    node = jnp.broadcast_to(at + jnp.arange(batch, dtype=jnp.int32), want.shape)
    return lattice_lib.set_values(table, slot, node, is_new)

  batches = (jnp.max(size) + batch - 1) // batch
  return jax.lax.fori_loop(0, batches, body, table)


def _carry_table(old: lattice_lib.LatticeTable, fresh: lattice_lib.LatticeTable,
                 source: jax.Array, used: jax.Array, size: jax.Array) -> lattice_lib.LatticeTable:
  """fresh (its start's cell mapped to 0) with the cells of old's nodes source [I, P] that old
  held, where used [I, P] (the start excluded)."""
  num_instances, capacity = source.shape
  rows = jnp.arange(num_instances)[:, None]
  held = old.occupied & (old.values >= 0)
  at = jnp.where(held, old.values, capacity)
  in_table = jnp.zeros(source.shape, bool).at[rows, at].set(True, mode='drop')
  cell = jnp.zeros(source.shape + old.keys.shape[-1:], jnp.int32).at[rows, at].set(
      old.keys, mode='drop')
  start = jnp.arange(capacity)[None, :] == pool_lib.ROOT_INDEX
  mask = used & ~start & pool_lib.gather(in_table, source)
  return _insert_cells(fresh, pool_lib.gather(cell, source), mask, size)


def reroot(fresh, old, root: jax.Array, slots: int, keep_visits: Callable, room: int):
  """The search state `fresh` (a new search's start, PACHS's `SearchState`) keeping old's
  subtree below root [I] (NO_PARENT: none, fresh as it is): at most room nodes, the shallowest
  (`within_room`), root first, as the start with fresh's state. Its real edges in OPEN, the
  dummy edges of its open nodes (slot slots - 1), its lattice cells and its visit counts
  (keep_visits(fresh visits, old visits, source [I, P], used [I, P]) -> visits) go with it;
  the chains, replay, incumbent and counters are fresh's."""
  pool = old.pool
  # a goal below the root was reached from states simulated from the planned start, not the
  # world's: it is not kept (nodes at a goal are leaves), so that the new search finds its
  # goals from the world's state (the replayed remainder's among them)
  is_root = jnp.arange(pool.capacity)[None, :] == root[:, None]
  kept = within_room(subtree(pool, root) & (~pool.is_goal | is_root), pool.depth, room)
  has = pool_lib.gather(kept, jnp.maximum(root, 0)[:, None])[:, 0] & (root != pool_lib.NO_PARENT)
  root = jnp.where(has, root, pool_lib.NO_PARENT)
  kept = kept & has[:, None]
  source, new_index, size = compaction(kept, root)
  used = has[:, None] & (jnp.arange(pool.capacity)[None, :] < size[:, None])
  new_pool = _carry_pool(pool, fresh.pool, root, source, new_index, size, used)
  g_root = jnp.where(has, pool_lib.gather(pool.g, jnp.maximum(root, 0)[:, None])[:, 0], 0.0)
  edge_heap = _carry_edges(old.edge_heap, fresh.edge_heap, kept, new_index, g_root, slots)
  # the open nodes' dummy edges from the pool (a fresh start's: key 0)
  index = jnp.arange(pool.capacity)[None, :]
  is_open = ((index < new_pool.size[:, None]) & ~new_pool.closed
             & (new_pool.open_key < heap_lib.INF))
  dummy_heap = heap_lib.push(heap_lib.empty(fresh.dummy_heap), new_pool.open_key,
                             jnp.broadcast_to(index * slots + slots - 1, is_open.shape), is_open)
  table = _carry_table(old.table, fresh.table, source, used, size)
  visits = keep_visits(fresh.visits, old.visits, source, used)
  return fresh.replace(pool=new_pool, edge_heap=edge_heap, dummy_heap=dummy_heap, table=table,
                       visits=visits)
