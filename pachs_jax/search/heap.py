"""OPEN: a fixed-capacity priority queue of edges per problem instance, batched and masked."""

from __future__ import annotations

import math
from typing import Optional, Tuple

import jax
import jax.numpy as jnp
from flax import struct

INF = float('inf')  # the key of an empty or popped slot


@struct.dataclass
class Heap:
  """An append-only entry buffer of I instances, cut into S segments of b entries.

  A pop takes the k segments with the smallest minima (they hold the k best entries), then the
  k best of their k * b entries; ties pop in insertion order. Popped slots are not reused.

  keys: [I, S * b] float32 priorities, INF where empty or popped.
  values: [I, S * b] int32 payloads.
  segment_min: [I, S] float32 the smallest key of each segment.
  size: [I] int32 entries ever stored (the next write position).
  count: [I] int32 entries currently stored.
  overflow: [I] int32 entries dropped because the buffer was full.
  capacity: entries per instance over the whole run (static).
  segment_size: b, entries per segment (static).
  """

  keys: jax.Array
  values: jax.Array
  segment_min: jax.Array
  size: jax.Array
  count: jax.Array
  overflow: jax.Array
  capacity: int = struct.field(pytree_node=False)
  segment_size: int = struct.field(pytree_node=False)


def default_segment_size(capacity: int, pop_size: int) -> int:
  """A power of two near sqrt(capacity / pop_size), at least 8: balances the two top_k of a pop."""
  target = math.sqrt(max(1, capacity) / max(1, pop_size))
  return max(8, 1 << int(round(math.log2(max(1.0, target)))))


def init(num_instances: int, capacity: int, pop_size: int,
         segment_size: Optional[int] = None) -> Heap:
  """An empty queue of `capacity` entries per instance; `pop_size` is the k of `pop`."""
  if num_instances < 1 or capacity < 1 or pop_size < 1:
    raise ValueError('heap needs num_instances, capacity and pop_size >= 1, got '
                     f'{num_instances}, {capacity}, {pop_size}')
  segment = segment_size or default_segment_size(capacity, pop_size)
  if segment < 1:
    raise ValueError(f'segment_size must be >= 1, got {segment}')
  num_segments = -(-capacity // segment)
  width = num_segments * segment
  zeros = jnp.zeros((num_instances,), jnp.int32)
  return Heap(keys=jnp.full((num_instances, width), INF, jnp.float32),
              values=jnp.zeros((num_instances, width), jnp.int32),
              segment_min=jnp.full((num_instances, num_segments), INF, jnp.float32),
              size=zeros, count=zeros, overflow=zeros, capacity=capacity, segment_size=segment)


def push(heap: Heap, keys: jax.Array, values: jax.Array, mask: jax.Array) -> Heap:
  """Stores the masked entries keys/values/mask [I, M] in their order along M.

  Keys that are NaN or +inf are not stored (such an entry could never be popped); -0.0 is
  stored as +0.0. Entries beyond capacity are dropped and counted in `overflow`.
  """
  keys = keys.astype(jnp.float32)
  keys = jnp.where(keys == 0.0, jnp.zeros_like(keys), keys)
  valid = mask & (keys < INF)
  num_instances, width = heap.keys.shape
  rows = jnp.arange(num_instances)[:, None]
  pos = heap.size[:, None] + jnp.cumsum(valid, axis=1, dtype=jnp.int32) - 1
  ok = valid & (pos < heap.capacity)
  pos = jnp.where(ok, pos, width)  # out of bounds: dropped by the scatters
  stored = jnp.sum(ok, axis=1, dtype=jnp.int32)
  return heap.replace(
      keys=heap.keys.at[rows, pos].set(keys, mode='drop'),
      values=heap.values.at[rows, pos].set(values.astype(jnp.int32), mode='drop'),
      segment_min=heap.segment_min.at[rows, pos // heap.segment_size].min(keys, mode='drop'),
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


def _segment_slots(segments: jax.Array, segment_size: int) -> jax.Array:
  """[I, s * b] buffer indices of the segments [I, s]."""
  slots = segments[:, :, None] * segment_size + jnp.arange(segment_size)
  return slots.reshape(segments.shape[0], -1)


def _candidates(heap: Heap, k: int) -> Tuple[jax.Array, ...]:
  """(keys [I, k], buffer indices [I, k], segments [I, s], the segments' keys [I, s * b], the
  k best entries' positions among them [I, k]) of the k best entries in (key, insertion)
  order, +inf padded; segments are the ones searched."""
  _, segments = _smallest(heap.segment_min, min(k, heap.segment_min.shape[1]))
  segments = jnp.sort(segments, axis=1)  # buffer order, so ties keep insertion order
  slots = _segment_slots(segments, heap.segment_size)
  segment_keys = jnp.take_along_axis(heap.keys, slots, axis=1)
  keys, j = _smallest(segment_keys, k)
  return keys, jnp.take_along_axis(slots, j, axis=1), segments, segment_keys, j


def pop(heap: Heap, k: int, active: Optional[jax.Array] = None,
        limit: Optional[jax.Array] = None) -> Tuple[Heap, jax.Array, jax.Array, jax.Array]:
  """Removes the k best entries of each active instance.

  active: [I] bool, instances that pop (None: all); the others are left unchanged.
  limit: [I] float32, pop only entries with key <= limit (None: no limit).
  Returns (heap, keys [I, k], values [I, k], mask [I, k]) in (key, insertion) order; mask is
  False where an instance had fewer than k entries (within the limit) or is inactive (values 0,
  keys INF there). The masked entries come first.
  """
  num_instances = heap.keys.shape[0]
  if active is None:
    active = jnp.ones((num_instances,), bool)
  rows = jnp.arange(num_instances)[:, None]
  keys, idx, segments, segment_keys, j = _candidates(heap, k)
  mask = (keys < INF) & active[:, None]
  if limit is not None:
    mask = mask & (keys <= limit[:, None])
  values = jnp.where(mask, jnp.take_along_axis(heap.values, idx, axis=1), 0)
  new_keys = heap.keys.at[rows, jnp.where(mask, idx, heap.keys.shape[1])].set(INF, mode='drop')
  # the searched segments' keys after the pop, from their copy read above (not read back from
  # the buffer just written, which would make XLA copy the buffer)
  left = segment_keys.at[rows, jnp.where(mask, j, segment_keys.shape[1])].set(INF, mode='drop')
  segment_min = heap.segment_min.at[rows, segments].set(
      jnp.min(left.reshape(num_instances, -1, heap.segment_size), axis=2))
  heap = heap.replace(keys=new_keys, segment_min=segment_min,
                      count=heap.count - jnp.sum(mask, axis=1, dtype=jnp.int32))
  return heap, jnp.where(mask, keys, INF), values, mask


def kth_key(heap: Heap, k: int) -> jax.Array:
  """[I] float32 the k-th smallest key of each instance (+inf when it holds fewer than k)."""
  if k < 1:
    raise ValueError(f'kth_key needs k >= 1, got {k}')
  return _candidates(heap, k)[0][:, k - 1]


def peek(heap: Heap) -> Tuple[jax.Array, jax.Array, jax.Array]:
  """(key [I], value [I], mask [I]) of each instance's best entry, without removing it."""
  rows = jnp.arange(heap.keys.shape[0])
  slots = _segment_slots(jnp.argmin(heap.segment_min, axis=1)[:, None], heap.segment_size)
  idx = slots[rows, jnp.argmin(jnp.take_along_axis(heap.keys, slots, axis=1), axis=1)]
  key = heap.keys[rows, idx]
  mask = key < INF
  return key, jnp.where(mask, heap.values[rows, idx], 0), mask
