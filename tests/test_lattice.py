"""The lattice hash table: batched insert / lookup with duplicates, values, overflow."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pachs_jax.search import lattice as lattice_lib

NUM_INSTANCES = 2
KEY_SIZE = 3


@functools.lru_cache(maxsize=None)
def _ops():
  insert = jax.jit(lattice_lib.insert)
  lookup = jax.jit(lattice_lib.lookup)
  set_values = jax.jit(lattice_lib.set_values)
  get_values = jax.jit(lattice_lib.get_values)
  return insert, lookup, set_values, get_values


def _random_batch(rng, batch, span=4):
  # A small coordinate range gives many repeated keys, within and across batches.
  keys = rng.integers(-span, span, size=(NUM_INSTANCES, batch, KEY_SIZE)).astype(np.int32)
  mask = rng.random((NUM_INSTANCES, batch)) < 0.8
  return keys, mask


def test_insert_lookup_against_dict():
  insert, lookup, set_values, get_values = _ops()
  table = lattice_lib.init(NUM_INSTANCES, 1024, KEY_SIZE)
  rng = np.random.default_rng(0)
  seen = [dict() for _ in range(NUM_INSTANCES)]  # key -> (slot, value)
  for _ in range(12):
    keys, mask = _random_batch(rng, 24)
    table, slot, is_new, ok = insert(table, jnp.asarray(keys), jnp.asarray(mask))
    slot, is_new, ok = map(np.asarray, (slot, is_new, ok))
    np.testing.assert_array_equal(ok, mask)  # plenty of room: every masked key has a slot
    values = np.where(is_new, rng.integers(0, 10**6, size=slot.shape), 0).astype(np.int32)
    table = set_values(table, jnp.asarray(slot), jnp.asarray(values), jnp.asarray(is_new))
    for i in range(NUM_INSTANCES):
      first_here = set()
      for b in range(keys.shape[1]):
        if not mask[i, b]:
          assert not is_new[i, b]
          continue
        key = tuple(keys[i, b])
        want_new = key not in seen[i] and key not in first_here
        assert is_new[i, b] == want_new, (i, b, key)
        if want_new:
          first_here.add(key)
          seen[i][key] = (slot[i, b], values[i, b])
        assert slot[i, b] == seen[i][key][0]  # duplicates (also within the batch) share a slot
    np.testing.assert_array_equal(np.asarray(table.count), [len(s) for s in seen])
  # Every stored key is found with its value; absent keys are not found.
  for i in range(NUM_INSTANCES):
    slots = {s for s, _ in seen[i].values()}
    assert len(slots) == len(seen[i])  # distinct keys, distinct slots
  stored = np.zeros((NUM_INSTANCES, max(len(s) for s in seen), KEY_SIZE), np.int32)
  stored_mask = np.zeros(stored.shape[:2], bool)
  for i in range(NUM_INSTANCES):
    for j, key in enumerate(seen[i]):
      stored[i, j], stored_mask[i, j] = key, True
  slot, found = lookup(table, jnp.asarray(stored), jnp.asarray(stored_mask))
  np.testing.assert_array_equal(np.asarray(found), stored_mask)
  got = np.asarray(get_values(table, slot))
  for i in range(NUM_INSTANCES):
    for j, key in enumerate(seen[i]):
      assert got[i, j] == seen[i][key][1]
  absent = jnp.full((NUM_INSTANCES, 3, KEY_SIZE), 100, jnp.int32).at[:, :, 0].set(
      jnp.arange(3) + 50)
  _, found = lookup(table, absent, jnp.ones((NUM_INSTANCES, 3), bool))
  assert not np.asarray(found).any()
  assert not np.asarray(table.overflow).any()


def test_duplicates_within_one_batch_first_occurrence_inserts():
  insert, _, _, _ = _ops()
  table = lattice_lib.init(NUM_INSTANCES, 16, KEY_SIZE)
  keys = np.zeros((NUM_INSTANCES, 5, KEY_SIZE), np.int32)
  keys[:, :, 0] = [[7, 3, 7, 7, 3], [1, 1, 1, 1, 1]]
  mask = np.array([[False, True, True, True, True], [True] * 5])
  table, slot, is_new, ok = insert(table, jnp.asarray(keys), jnp.asarray(mask))
  np.testing.assert_array_equal(np.asarray(is_new), [[False, True, True, False, False],
                                                     [True, False, False, False, False]])
  np.testing.assert_array_equal(np.asarray(ok), mask)
  slot = np.asarray(slot)
  assert slot[0, 2] == slot[0, 3] and slot[0, 1] == slot[0, 4] and slot[0, 1] != slot[0, 2]
  assert len(set(slot[1])) == 1
  np.testing.assert_array_equal(np.asarray(table.count), [2, 1])


def test_overflow_is_counted_and_stored_keys_stay_exact():
  insert, lookup, _, _ = _ops()
  table = lattice_lib.init(NUM_INSTANCES, 8, KEY_SIZE)
  keys = np.zeros((NUM_INSTANCES, 12, KEY_SIZE), np.int32)
  keys[:, :, 1] = np.arange(12)
  mask = np.ones((NUM_INSTANCES, 12), bool)
  table, slot, is_new, ok = insert(table, jnp.asarray(keys), jnp.asarray(mask))
  ok = np.asarray(ok)
  np.testing.assert_array_equal(ok.sum(axis=1), [8, 8])
  np.testing.assert_array_equal(np.asarray(table.overflow), [4, 4])
  np.testing.assert_array_equal(np.asarray(table.count), [8, 8])
  np.testing.assert_array_equal(np.asarray(is_new), ok)
  _, found = lookup(table, jnp.asarray(keys), jnp.asarray(mask))
  np.testing.assert_array_equal(np.asarray(found), ok)
  # A full table still finds its keys and rejects the rest again.
  table, _, is_new, ok2 = insert(table, jnp.asarray(keys), jnp.asarray(mask))
  np.testing.assert_array_equal(np.asarray(ok2), ok)
  assert not np.asarray(is_new).any()
  np.testing.assert_array_equal(np.asarray(table.overflow), [8, 8])


def test_probe_limit_overflows_but_lookups_stay_exact():
  insert, lookup, _, _ = _ops()
  table = lattice_lib.init(NUM_INSTANCES, 64, KEY_SIZE, max_probes=1)
  rng = np.random.default_rng(3)
  keys = rng.permutation(1000)[:48].reshape(1, 48, 1) * np.ones((NUM_INSTANCES, 1, KEY_SIZE))
  keys = jnp.asarray(keys, jnp.int32)
  mask = jnp.ones(keys.shape[:2], bool)
  table, _, _, ok = insert(table, keys, mask)
  ok = np.asarray(ok)
  overflow = np.asarray(table.overflow)
  assert (overflow > 0).all()  # 48 keys in 64 slots with one probe each must collide
  np.testing.assert_array_equal(overflow + ok.sum(axis=1), [48, 48])
  _, found = lookup(table, keys, mask)
  np.testing.assert_array_equal(np.asarray(found), ok)


def test_hash_spreads_lattice_points():
  cells = jnp.stack(jnp.meshgrid(jnp.arange(32), jnp.arange(32), jnp.arange(4)), -1)
  home = np.asarray(lattice_lib.hash_keys(cells.reshape(-1, 3).astype(jnp.int32)) % 8192)
  # 4096 keys into 8192 slots: a uniform hash leaves about 8192 (1 - e^-0.5) = 3223 distinct.
  assert len(set(home.tolist())) > 3000


def test_bad_arguments():
  with pytest.raises(ValueError, match='power of two'):
    lattice_lib.init(1, 12, 2)
  with pytest.raises(ValueError, match='key_size'):
    lattice_lib.init(1, 16, 0)
