"""The OPEN list: a fixed-capacity edge priority queue per problem instance.

Entries are (key float32, value int32); pops come in (key, insertion order) order, so ties
break deterministically by insertion order. All operations are batched over a leading
instance axis I and take masks; `init`, `push`, `pop` (optionally only keys up to a limit),
`peek` and `kth_key` are one API for three designs, picked by `kind`:

- 'flat': an append-only buffer keys/values [I, C]; a pop is one `lax.top_k` over the whole
  buffer (`top_k` puts the lower index first on equal keys, and in an append-only buffer the
  index is the insertion order); popped entries become +inf. Per pop O(C) work, per push of M
  entries O(M) scatter.
- 'segmented': the same buffer cut into S segments of b entries with each segment's minimum
  kept up to date ([I, S]). A pop takes the K segments with the smallest minima (they hold the K
  best entries: any entry outside them is beaten by K segment minima), then one top_k over
  their K*b entries, and refreshes those K minima. Per pop O(S + K*b) (b about sqrt(C/K)), per
  push O(M) scatter-min.
- 'blocked': a binary heap of sorted blocks of K entries plus a partial block (see
  `blocked_heap`): per pop O(K log(C/K)), per push O((M/K + 1) K log(C/K)), sequential depth
  O((M/K + 1) log(C/K)).

Measured (experiments/bench_heap.py, NVIDIA H200, jax 0.11, I = 30, one pop of K plus one push
of K (N + 1) slots with N = 16, results in experiments/results/bench_heap_h200.json), ms per
iteration at capacity 1e4 / 1e5 / 1e6 per instance:
  'segmented' 0.07-0.17 / 0.12-0.20 / 0.17-0.25 (K = 16..256), the default;
  'flat' 0.13-0.17 / 0.29-0.62 / 1.8-7.1 (top_k falls back to sorting the buffer);
  'blocked' 2.4-2.5 / 3.6-3.7 / 8.6-9.6 (latency of its sequential small sorts).

Capacity is in entries per instance: for the flat designs, pushes over the whole run (popped
slots are not reused); for 'blocked', entries held at once. A push beyond capacity drops the
entries and counts them in `overflow`; keys that are NaN or +inf are not stored (+inf marks an
empty slot, and such an entry could never be popped before the queue is empty). Memory per
entry: 8 bytes (flat) plus 4/b (segment minima), 12 bytes (blocked: key, sequence, value).
"""

from __future__ import annotations

import math
from typing import Optional, Tuple, Union

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax.search import blocked_heap

INF = float('inf')


@struct.dataclass
class FlatHeap:
  """Append-only entry buffer of I instances.

  keys: [I, S*b] float32 priorities, +inf where empty or popped.
  values: [I, S*b] int32 payloads.
  seg_min: [I, S] float32 minimum key of each segment ([I, 1] and unused for 'flat').
  size: [I] int32 entries ever stored (the next write position).
  count: [I] int32 entries currently stored.
  overflow: [I] int32 entries dropped because the buffer was full.
  capacity: entries per instance (static); segment: b entries per segment, 0 for 'flat'.
  """

  keys: jax.Array
  values: jax.Array
  seg_min: jax.Array
  size: jax.Array
  count: jax.Array
  overflow: jax.Array
  capacity: int = struct.field(pytree_node=False)
  segment: int = struct.field(pytree_node=False)


Heap = Union[FlatHeap, blocked_heap.BlockedHeap]


def default_segment_size(capacity: int, pop_size: int) -> int:
  """A power of two near sqrt(capacity / pop_size): balances the two top_k of a pop."""
  target = math.sqrt(max(1, capacity) / max(1, pop_size))
  return max(8, 1 << int(round(math.log2(max(1.0, target)))))


def init(kind: str, num_instances: int, capacity: int, pop_size: int,
         segment_size: Optional[int] = None) -> Heap:
  """An empty queue of `capacity` entries per instance; `pop_size` is the K of `pop`."""
  if num_instances < 1 or capacity < 1 or pop_size < 1:
    raise ValueError('heap needs num_instances, capacity and pop_size >= 1, got '
                     f'{num_instances}, {capacity}, {pop_size}')
  if kind == 'blocked':
    return blocked_heap.init(num_instances, capacity, pop_size)
  if kind not in ('flat', 'segmented'):
    raise ValueError(f"heap kind must be 'flat', 'segmented' or 'blocked', got {kind!r}")
  if kind == 'flat':
    segment, num_segments = 0, 1
    width = capacity
  else:
    segment = segment_size or default_segment_size(capacity, pop_size)
    if segment < 1:
      raise ValueError(f'segment_size must be >= 1, got {segment}')
    num_segments = -(-capacity // segment)
    width = num_segments * segment
  zeros = jnp.zeros((num_instances,), jnp.int32)
  return FlatHeap(
      keys=jnp.full((num_instances, width), INF, jnp.float32),
      values=jnp.zeros((num_instances, width), jnp.int32),
      seg_min=jnp.full((num_instances, num_segments), INF, jnp.float32),
      size=zeros, count=zeros, overflow=zeros, capacity=capacity, segment=segment)


def push(heap: Heap, keys: jax.Array, values: jax.Array, mask: jax.Array) -> Heap:
  """Stores the masked entries keys/values/mask [I, M] in their order along M."""
  if isinstance(heap, blocked_heap.BlockedHeap):
    return blocked_heap.push(heap, keys, values, mask)
  keys, valid = blocked_heap.storable(keys, mask)
  num_instances, width = heap.keys.shape
  rows = jnp.arange(num_instances)[:, None]
  pos = heap.size[:, None] + jnp.cumsum(valid, axis=1, dtype=jnp.int32) - 1
  ok = valid & (pos < heap.capacity)
  pos = jnp.where(ok, pos, width)  # out of bounds: dropped by the scatters
  stored = jnp.sum(ok, axis=1, dtype=jnp.int32)
  seg_min = heap.seg_min
  if heap.segment:
    seg_min = seg_min.at[rows, pos // heap.segment].min(keys, mode='drop')
  return heap.replace(
      keys=heap.keys.at[rows, pos].set(keys, mode='drop'),
      values=heap.values.at[rows, pos].set(values.astype(jnp.int32), mode='drop'),
      seg_min=seg_min,
      size=heap.size + stored,
      count=heap.count + stored,
      overflow=heap.overflow + jnp.sum(valid & ~ok, axis=1, dtype=jnp.int32))


def _smallest(keys: jax.Array, k: int) -> Tuple[jax.Array, jax.Array]:
  """(values [I, k], indices [I, k]) of the k smallest keys, lower index first on ties; k may
  exceed the row length (the tail is +inf at index 0)."""
  width = keys.shape[1]
  neg, idx = jax.lax.top_k(-keys, min(k, width))
  if k > width:
    pad = ((0, 0), (0, k - width))
    neg = jnp.pad(neg, pad, constant_values=-INF)
    idx = jnp.pad(idx, pad)
  return -neg, idx


def _candidates(heap: FlatHeap, k: int):
  """(keys [I, k], buffer indices [I, k], segments [I, k'] or None) of the k best entries of a
  flat or segmented buffer, in (key, insertion) order (+inf padded)."""
  num_instances = heap.keys.shape[0]
  if not heap.segment:
    keys, idx = _smallest(heap.keys, k)
    return keys, idx, None
  seg = heap.segment
  num_segments = heap.seg_min.shape[1]
  _, segs = _smallest(heap.seg_min, min(k, num_segments))
  segs = jnp.sort(segs, axis=1)  # candidates in buffer order, so ties keep insertion order
  cand = (segs[:, :, None] * seg + jnp.arange(seg)).reshape(num_instances, -1)
  keys, j = _smallest(jnp.take_along_axis(heap.keys, cand, axis=1), k)
  return keys, jnp.take_along_axis(cand, j, axis=1), segs


def pop(heap: Heap, k: int, active: Optional[jax.Array] = None,
        limit: Optional[jax.Array] = None) -> Tuple[Heap, jax.Array, jax.Array, jax.Array]:
  """Removes the k best entries of each active instance.

  active: [I] bool, instances that pop (None: all); the others are left unchanged.
  limit: [I] float32, pop only entries with key <= limit (None: no limit); the k best entries
    above it stay in the queue in their place (same order, same ties).
  Returns (heap, keys [I, k], values [I, k], mask [I, k]) in (key, insertion) order; mask is
  False where an instance had fewer than k entries (within the limit) or is inactive (values 0
  there). The masked entries come first.
  """
  num_instances = heap.keys.shape[0]
  if active is None:
    active = jnp.ones((num_instances,), bool)
  if isinstance(heap, blocked_heap.BlockedHeap):
    return blocked_heap.pop(heap, k, active, limit)
  rows = jnp.arange(num_instances)[:, None]
  keys, idx, segs = _candidates(heap, k)
  mask = (keys < INF) & active[:, None]
  if limit is not None:
    mask = mask & (keys <= limit[:, None])
  values = jnp.where(mask, jnp.take_along_axis(heap.values, idx, axis=1), 0)
  new_keys = heap.keys.at[rows, jnp.where(mask, idx, heap.keys.shape[1])].set(INF, mode='drop')
  seg_min = heap.seg_min
  if heap.segment:
    seg = heap.segment
    cand = (segs[:, :, None] * seg + jnp.arange(seg)).reshape(num_instances, -1)
    fresh = jnp.take_along_axis(new_keys, cand, axis=1).reshape(num_instances, -1, seg)
    seg_min = seg_min.at[rows, segs].set(jnp.min(fresh, axis=2))
  popped = jnp.sum(mask, axis=1, dtype=jnp.int32)
  heap = heap.replace(keys=new_keys, seg_min=seg_min, count=heap.count - popped)
  return heap, jnp.where(mask, keys, INF), values, mask


def kth_key(heap: Heap, k: int) -> jax.Array:
  """[I] float32 the k-th smallest key of each instance (+inf when it holds fewer than k);
  nothing is removed. Costs about what `pop` of k costs."""
  if k < 1:
    raise ValueError(f'kth_key needs k >= 1, got {k}')
  if isinstance(heap, blocked_heap.BlockedHeap):
    return blocked_heap.kth_key(heap, k)
  keys, _, _ = _candidates(heap, k)
  return keys[:, k - 1]


def peek(heap: Heap) -> Tuple[jax.Array, jax.Array, jax.Array]:
  """(key [I], value [I], mask [I]) of each instance's best entry, without removing it."""
  if isinstance(heap, blocked_heap.BlockedHeap):
    return blocked_heap.peek(heap)
  rows = jnp.arange(heap.keys.shape[0])
  if heap.segment:
    best_seg = jnp.argmin(heap.seg_min, axis=1)
    cand = best_seg[:, None] * heap.segment + jnp.arange(heap.segment)
    idx = cand[rows, jnp.argmin(jnp.take_along_axis(heap.keys, cand, axis=1), axis=1)]
  else:
    idx = jnp.argmin(heap.keys, axis=1)  # the first of equal keys: the earliest pushed
  key = heap.keys[rows, idx]
  mask = key < INF
  return key, jnp.where(mask, heap.values[rows, idx], 0), mask


def size(heap: Heap) -> jax.Array:
  """[I] int32 entries currently stored."""
  return heap.count


def overflow(heap: Heap) -> jax.Array:
  """[I] int32 entries dropped because the queue was full."""
  return heap.overflow
