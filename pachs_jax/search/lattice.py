"""The lattice hash table: integer lattice coordinates -> node index per problem instance, with
open addressing and linear probing, batched over instances and keys."""

from __future__ import annotations

from typing import Tuple

import jax
import jax.numpy as jnp
from flax import struct

NO_VALUE = -1  # value of a slot that holds no node


@struct.dataclass
class LatticeTable:
  """T slots (a power of two) of I instances. Keys of one batch that reach the same empty slot
  resolve in batch order (the first inserts, later ones find it); a key that meets no empty
  slot within max_probes probes of its home slot is not stored (lookups use the same limit).

  keys: [I, T, L] int32 lattice coordinates stored in each slot.
  occupied: [I, T] bool, the slot holds a key.
  values: [I, T] int32 node index of the slot's key (NO_VALUE until set).
  count: [I] int32 occupied slots.
  overflow: [I] int32 insertions that found no free slot.
  max_probes: probe limit per key (static).
  """

  keys: jax.Array
  occupied: jax.Array
  values: jax.Array
  count: jax.Array
  overflow: jax.Array
  max_probes: int = struct.field(pytree_node=False)

  @property
  def capacity(self) -> int:
    return self.keys.shape[1]


def init(num_instances: int, capacity: int, key_size: int, max_probes: int = 256) -> LatticeTable:
  """An empty table of `capacity` (a power of two) slots for keys [key_size] per instance."""
  if capacity < 1 or capacity & (capacity - 1):
    raise ValueError(f'lattice table capacity must be a power of two >= 1, got {capacity}')
  if num_instances < 1 or key_size < 1 or max_probes < 1:
    raise ValueError('lattice table needs num_instances, key_size and max_probes >= 1, got '
                     f'{num_instances}, {key_size}, {max_probes}')
  zeros = jnp.zeros((num_instances,), jnp.int32)
  return LatticeTable(
      keys=jnp.zeros((num_instances, capacity, key_size), jnp.int32),
      occupied=jnp.zeros((num_instances, capacity), bool),
      values=jnp.full((num_instances, capacity), NO_VALUE, jnp.int32),
      count=zeros, overflow=zeros, max_probes=min(max_probes, capacity))


def _rotl(x: jax.Array, r: int) -> jax.Array:
  return (x << r) | (x >> (32 - r))


def hash_keys(keys: jax.Array) -> jax.Array:
  """[...] uint32 MurmurHash3 (x86, 32 bit) of int32 keys [..., L]."""
  words = keys.astype(jnp.uint32)
  h = jnp.zeros(words.shape[:-1], jnp.uint32)
  for l in range(words.shape[-1]):
    k = _rotl(words[..., l] * jnp.uint32(0xCC9E2D51), 15) * jnp.uint32(0x1B873593)
    h = _rotl(h ^ k, 13) * jnp.uint32(5) + jnp.uint32(0xE6546B64)
  h = h ^ jnp.uint32(4 * words.shape[-1])
  h = (h ^ (h >> 16)) * jnp.uint32(0x85EBCA6B)
  h = (h ^ (h >> 13)) * jnp.uint32(0xC2B2AE35)
  return h ^ (h >> 16)


def _probe(table: LatticeTable, keys: jax.Array, mask: jax.Array, claim: bool):
  """Probe loop shared by insert and lookup; returns (table, slot, found, is_new, failed)."""
  num_instances, batch = mask.shape
  capacity = table.capacity
  rows = jnp.arange(num_instances)[:, None]
  home = (hash_keys(keys) & jnp.uint32(capacity - 1)).astype(jnp.int32)
  position = jnp.arange(batch)
  earlier = position[None, :] < position[:, None]  # [a, b]: b comes before a

  def cond(carry):
    _, _, _, _, pending, _, _, rounds = carry
    # A probe either resolves, advances, or loses a claim and resolves or advances next round.
    return jnp.any(pending) & (rounds < 2 * table.max_probes + 1)

  def body(carry):
    table, offset, found, is_new, pending, failed, slot, rounds = carry
    slot = jnp.where(pending, (home + offset) & (capacity - 1), slot)
    occupied = table.occupied[rows, slot]
    match = occupied & jnp.all(table.keys[rows, slot] == keys, axis=-1)
    hit = pending & match
    free = pending & ~occupied & (offset < table.max_probes)
    if claim:
      rival = (slot[:, None, :] == slot[:, :, None]) & free[:, None, :] & earlier[None]
      wins = free & ~jnp.any(rival, axis=2)
      # (~match: no claim where the key is found, which wins already implies; it orders the
      # keys' read before their write, so that XLA writes the table in place)
      target = jnp.where(wins & ~match, slot, capacity)
      table = table.replace(
          keys=table.keys.at[rows, target].set(keys, mode='drop'),
          occupied=table.occupied.at[rows, target].set(True, mode='drop'),
          count=table.count + jnp.sum(wins, axis=1, dtype=jnp.int32))
    else:
      wins = jnp.zeros_like(free)
      hit = hit | free  # a lookup ends at the first empty slot: not present
    offset = offset + (pending & occupied & ~match)
    out_of_probes = pending & ~hit & ~wins & (offset >= table.max_probes)
    found = found | (pending & match)
    is_new = is_new | wins
    failed = failed | out_of_probes
    pending = pending & ~hit & ~wins & ~out_of_probes
    return table, offset, found, is_new, pending, failed, slot, rounds + 1

  false = jnp.zeros_like(mask)
  start = (table, jnp.zeros_like(home), false, false, mask, false, jnp.zeros_like(home), 0)
  table, _, found, is_new, pending, failed, slot, _ = jax.lax.while_loop(cond, body, start)
  return table, slot, found, is_new, failed | pending


def insert(table: LatticeTable, keys: jax.Array, mask: jax.Array
           ) -> Tuple[LatticeTable, jax.Array, jax.Array, jax.Array]:
  """Finds or inserts the masked keys [I, B, L].

  Returns (table, slot [I, B] int32, is_new [I, B] bool: this entry inserted the key, ok [I, B]
  bool: the key has a slot). A key met twice in the batch is inserted by its first occurrence;
  the later ones get the same slot with is_new False. Failed keys are counted in overflow.
  """
  table, slot, found, is_new, failed = _probe(table, keys, mask, claim=True)
  failed = failed & mask
  table = table.replace(overflow=table.overflow + jnp.sum(failed, axis=1, dtype=jnp.int32))
  return table, slot, is_new, mask & (found | is_new)


def lookup(table: LatticeTable, keys: jax.Array, mask: jax.Array) -> Tuple[jax.Array, jax.Array]:
  """(slot [I, B] int32, found [I, B] bool) of the masked keys [I, B, L]; the table is unchanged."""
  _, slot, found, _, _ = _probe(table, keys, mask, claim=False)
  return slot, found & mask


def get_values(table: LatticeTable, slot: jax.Array) -> jax.Array:
  """[I, B] int32 values at slot [I, B]."""
  return jnp.take_along_axis(table.values, slot, axis=1)


def set_values(table: LatticeTable, slot: jax.Array, values: jax.Array,
               mask: jax.Array) -> LatticeTable:
  """Writes values [I, B] at slot [I, B] where mask."""
  rows = jnp.arange(slot.shape[0])[:, None]
  target = jnp.where(mask, slot, table.capacity)
  return table.replace(values=table.values.at[rows, target].set(values, mode='drop'))
