"""A binary heap of sorted blocks (after BGPQ, He et al. 2012), batched over I instances.

Every heap node holds a block of B entries sorted by (key, sequence number); each entry of a
node is <= every entry of its children, so the root holds the B best entries of the blocks.
Pushes first join a partial block `buf` (fewer than B entries); every B entries that collect
go down as a full block from the root to the new last node, each node on the path keeping the
smaller half of (its block, the incoming block). A pop takes the B best of (root, buf), moves
the last node into the root and sifts it down: at each level the two children are merged, the
larger half goes to the child whose largest entry is larger (that subtree stays a heap), the
node keeps the smallest half of (its block, the smaller half) and the rest sifts on into the
other child. Each merge is one `lax.sort` of 2B entries. A pop pops exactly B = K entries.

Costs per call, with D = log2(capacity / B) levels: pop 2 D sorts of 2B entries; push of M
entries ceil((M + B - 1) / B) block insertions of D sorts each. Memory: 12 bytes per entry.
"""

from __future__ import annotations

from typing import Optional, Tuple

import jax
import jax.numpy as jnp
from flax import struct

INF = float('inf')
NO_SEQ = jnp.iinfo(jnp.int32).max  # sequence number of an empty entry (sorts last)


@struct.dataclass
class BlockedHeap:
  """Blocks [I, NB, B] (node i has children 2i+1, 2i+2) and a partial block [I, B].

  keys / seqs / values: [I, NB, B] float32 / int32 / int32, each block sorted.
  num_blocks: [I] int32 full blocks in the heap.
  buf_keys / buf_seqs / buf_values: [I, B] the partial block, sorted, +inf / NO_SEQ padded.
  buf_count: [I] int32 entries in the partial block (< B).
  next_seq: [I] int32 insertion counter (ties break by it).
  count: [I] int32 entries stored; overflow: [I] int32 entries dropped for lack of blocks.
  capacity: entries per instance (static).
  """

  keys: jax.Array
  seqs: jax.Array
  values: jax.Array
  num_blocks: jax.Array
  buf_keys: jax.Array
  buf_seqs: jax.Array
  buf_values: jax.Array
  buf_count: jax.Array
  next_seq: jax.Array
  count: jax.Array
  overflow: jax.Array
  capacity: int = struct.field(pytree_node=False)

  @property
  def block(self) -> int:
    return self.keys.shape[2]

  @property
  def depth(self) -> int:
    """Levels of a full heap of NB blocks."""
    return int(self.keys.shape[1]).bit_length()


def init(num_instances: int, capacity: int, block: int) -> BlockedHeap:
  """An empty heap of ceil(capacity / block) blocks of `block` entries per instance."""
  num_blocks = max(1, -(-capacity // block))
  shape = (num_instances, num_blocks, block)
  zeros = jnp.zeros((num_instances,), jnp.int32)
  return BlockedHeap(
      keys=jnp.full(shape, INF, jnp.float32), seqs=jnp.full(shape, NO_SEQ, jnp.int32),
      values=jnp.zeros(shape, jnp.int32), num_blocks=zeros,
      buf_keys=jnp.full((num_instances, block), INF, jnp.float32),
      buf_seqs=jnp.full((num_instances, block), NO_SEQ, jnp.int32),
      buf_values=jnp.zeros((num_instances, block), jnp.int32), buf_count=zeros,
      next_seq=zeros, count=zeros, overflow=zeros, capacity=capacity)


Entries = Tuple[jax.Array, jax.Array, jax.Array]  # (keys, seqs, values) with a shared shape


def storable(keys: jax.Array, mask: jax.Array) -> Tuple[jax.Array, jax.Array]:
  """(keys as float32 with -0.0 made +0.0, mask of the entries a push stores: not NaN or +inf).

  Shared by all heap designs: +inf marks an empty slot, and -0.0 would sort before +0.0.
  """
  keys = keys.astype(jnp.float32)
  keys = jnp.where(keys == 0.0, jnp.zeros_like(keys), keys)
  return keys, mask & (keys < INF)


def _sorted(entries: Entries) -> Entries:
  """Sorts along the last axis by (key, seq)."""
  return tuple(jax.lax.sort(entries, dimension=-1, num_keys=2))


def _merge(a: Entries, b: Entries) -> Tuple[Entries, Entries]:
  """(smaller half, larger half) of two [I, B] entry sets."""
  block = a[0].shape[-1]
  both = _sorted(tuple(jnp.concatenate([x, y], axis=-1) for x, y in zip(a, b)))
  return tuple(x[:, :block] for x in both), tuple(x[:, block:] for x in both)


def _read(heap: BlockedHeap, node: jax.Array) -> Entries:
  """Blocks [I, B] at node [I] (clipped into range)."""
  node = jnp.clip(node, 0, heap.keys.shape[1] - 1)[:, None, None]
  return tuple(jnp.take_along_axis(x, node, axis=1)[:, 0]
               for x in (heap.keys, heap.seqs, heap.values))


def _write(heap: BlockedHeap, node: jax.Array, entries: Entries, mask: jax.Array) -> BlockedHeap:
  """Writes blocks [I, B] at node [I] where mask [I]."""
  rows = jnp.arange(node.shape[0])
  node = jnp.where(mask, node, heap.keys.shape[1])  # out of bounds: dropped
  k, s, v = (x.at[rows, node].set(e, mode='drop')
             for x, e in zip((heap.keys, heap.seqs, heap.values), entries))
  return heap.replace(keys=k, seqs=s, values=v)


def _greater(a: Entries, b: Entries) -> jax.Array:
  """[I] bool: the largest entry of sorted blocks a is after that of b in (key, seq) order."""
  ka, sa, kb, sb = a[0][:, -1], a[1][:, -1], b[0][:, -1], b[1][:, -1]
  return (ka > kb) | ((ka == kb) & (sa > sb))


def _insert_block(heap: BlockedHeap, entries: Entries, mask: jax.Array) -> BlockedHeap:
  """Inserts one full sorted block [I, B] per instance where mask [I] as the new last node."""
  target = heap.num_blocks
  fits = mask & (target < heap.keys.shape[1])
  level_of_target = 31 - jax.lax.clz(target + 1)  # floor(log2(target + 1))

  def level(lvl, carry):
    heap, incoming = carry
    on_path = fits & (lvl < level_of_target)
    node = ((target + 1) >> jnp.maximum(level_of_target - lvl, 0)) - 1
    keep, down = _merge(_read(heap, node), incoming)
    heap = _write(heap, node, keep, on_path)
    incoming = tuple(jnp.where(on_path[:, None], d, x) for d, x in zip(down, incoming))
    return heap, incoming

  heap, incoming = jax.lax.fori_loop(0, heap.depth, level, (heap, entries))
  heap = _write(heap, target, incoming, fits)
  dropped = jnp.where(mask & ~fits, heap.block, 0)
  return heap.replace(num_blocks=heap.num_blocks + fits.astype(jnp.int32),
                      overflow=heap.overflow + dropped, count=heap.count - dropped)


def push(heap: BlockedHeap, keys: jax.Array, values: jax.Array, mask: jax.Array) -> BlockedHeap:
  """Stores the masked entries keys/values/mask [I, M] (sequence numbers in M order)."""
  keys, valid = storable(keys, mask)
  num_new = jnp.sum(valid, axis=1, dtype=jnp.int32)
  seqs = heap.next_seq[:, None] + jnp.cumsum(valid, axis=1, dtype=jnp.int32) - 1
  heap = heap.replace(next_seq=heap.next_seq + num_new)
  return _push_entries(heap, (keys, seqs, values), valid)


def _push_entries(heap: BlockedHeap, incoming: Entries, valid: jax.Array) -> BlockedHeap:
  """Stores the entries (keys, seqs, values) [I, M] where valid, with the given sequence
  numbers (next_seq is left to the caller)."""
  keys, seqs, values = incoming
  num_new = jnp.sum(valid, axis=1, dtype=jnp.int32)
  incoming = (jnp.where(valid, keys, INF), jnp.where(valid, seqs, NO_SEQ),
              jnp.where(valid, values.astype(jnp.int32), 0))
  pending = _sorted(tuple(jnp.concatenate([b, x], axis=1) for b, x in zip(
      (heap.buf_keys, heap.buf_seqs, heap.buf_values), incoming)))
  block = heap.block
  total = heap.buf_count + num_new
  num_full = total // block
  heap = heap.replace(count=heap.count + num_new)

  max_full = pending[0].shape[1] // block

  def insert(j, heap):
    entries = tuple(jax.lax.dynamic_slice_in_dim(x, j * block, block, axis=1) for x in pending)
    return _insert_block(heap, entries, j < num_full)

  heap = jax.lax.fori_loop(0, max_full, insert, heap)
  # The entries after the full blocks become the partial block.
  rest = num_full[:, None] * block + jnp.arange(block)
  in_buf = jnp.arange(block) < (total - num_full * block)[:, None]
  rest = jnp.minimum(rest, pending[0].shape[1] - 1)
  buf = [jnp.take_along_axis(x, rest, axis=1) for x in pending]
  return heap.replace(
      buf_keys=jnp.where(in_buf, buf[0], INF), buf_seqs=jnp.where(in_buf, buf[1], NO_SEQ),
      buf_values=jnp.where(in_buf, buf[2], 0), buf_count=total - num_full * block)


def _sift_down(heap: BlockedHeap, active: jax.Array) -> BlockedHeap:
  """Restores the heap order below the root for the instances in active [I]."""
  empty = (jnp.full_like(heap.buf_keys, INF), jnp.full_like(heap.buf_seqs, NO_SEQ),
           jnp.zeros_like(heap.buf_values))

  def level(_, carry):
    heap, node, alive = carry
    left, right = 2 * node + 1, 2 * node + 2
    has_left = alive & (left < heap.num_blocks)
    has_right = alive & (right < heap.num_blocks)
    here = _read(heap, node)
    a = _read(heap, left)
    b = tuple(jnp.where(has_right[:, None], x, e) for x, e in zip(_read(heap, right), empty))
    small, large = _merge(a, b)
    right_is_big = _greater(b, a)
    big = jnp.where(right_is_big, right, left)
    other = jnp.where(right_is_big, left, right)
    keep, down = _merge(here, small)
    heap = _write(heap, node, keep, has_left)
    heap = _write(heap, big, large, has_left & (has_right | ~right_is_big))
    heap = _write(heap, other, down, has_left)
    return heap, other, has_left

  start = (heap, jnp.zeros_like(heap.num_blocks), active)
  heap, _, _ = jax.lax.fori_loop(0, heap.depth, level, start)
  return heap


def _best(heap: BlockedHeap) -> Tuple[Entries, Entries]:
  """(the B best entries, the rest of the partial block) of (root, partial block), sorted."""
  has_root = heap.num_blocks > 0
  root = _read(heap, jnp.zeros_like(heap.num_blocks))
  root = (jnp.where(has_root[:, None], root[0], INF),
          jnp.where(has_root[:, None], root[1], NO_SEQ), root[2])
  return _merge(root, (heap.buf_keys, heap.buf_seqs, heap.buf_values))


def pop(heap: BlockedHeap, k: int, active: jax.Array, limit: Optional[jax.Array] = None
        ) -> Tuple[BlockedHeap, jax.Array, jax.Array, jax.Array]:
  """Removes the k = B best entries of each active instance (see `heap.pop`); with a limit
  [I], the best B are taken out and those with key > limit go back with their sequence
  numbers (one more push of at most B entries)."""
  block = heap.block
  if k != block:
    raise ValueError(f'the blocked heap pops exactly its block size {block} entries, got k={k}')
  has_root = heap.num_blocks > 0
  best, rest = _best(heap)
  taken = (best[0] < INF) & active[:, None]
  popped = jnp.sum(taken, axis=1, dtype=jnp.int32)
  act = active[:, None]
  heap = heap.replace(
      buf_keys=jnp.where(act, rest[0], heap.buf_keys),
      buf_seqs=jnp.where(act, rest[1], heap.buf_seqs),
      buf_values=jnp.where(act, rest[2], heap.buf_values),
      buf_count=jnp.where(active, jnp.sum(rest[0] < INF, axis=1, dtype=jnp.int32),
                          heap.buf_count),
      count=heap.count - popped)
  # The last block replaces the root, then sifts down.
  moves = active & has_root
  last = heap.num_blocks - 1
  heap = _write(heap, jnp.zeros_like(last), _read(heap, last), moves)
  heap = heap.replace(num_blocks=heap.num_blocks - moves.astype(jnp.int32))
  heap = _sift_down(heap, moves)
  mask = taken
  if limit is not None:
    mask = taken & (best[0] <= limit[:, None])
    heap = _push_entries(heap, best, taken & ~mask)
  return heap, jnp.where(mask, best[0], INF), jnp.where(mask, best[2], 0), mask


def kth_key(heap: BlockedHeap, k: int) -> jax.Array:
  """[I] the k-th smallest key (k <= B; +inf when fewer than k entries are stored)."""
  if not 1 <= k <= heap.block:
    raise ValueError(f'the blocked heap finds the k-th key for k <= its block size '
                     f'{heap.block}, got k={k}')
  return _best(heap)[0][0][:, k - 1]


def peek(heap: BlockedHeap) -> Tuple[jax.Array, jax.Array, jax.Array]:
  """(key [I], value [I], mask [I]) of the best entry: the first of the root or the partial
  block."""
  root = _read(heap, jnp.zeros_like(heap.num_blocks))
  has_root = heap.num_blocks > 0
  rk = jnp.where(has_root, root[0][:, 0], INF)
  rs = jnp.where(has_root, root[1][:, 0], NO_SEQ)
  bk, bs = heap.buf_keys[:, 0], heap.buf_seqs[:, 0]
  use_root = (rk < bk) | ((rk == bk) & (rs < bs))
  key = jnp.where(use_root, rk, bk)
  mask = key < INF
  value = jnp.where(use_root, root[2][:, 0], heap.buf_values[:, 0])
  return key, jnp.where(mask, value, 0), mask
