"""The edge heap against Python's heapq on random push / pop sequences."""

import functools
import heapq

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pachs_jax.search import heap as heap_lib

NUM_INSTANCES = 3
K = 4
M = 9  # entries offered per push

# (capacity, segment size): small segments (many segments), segments larger than K entries,
# a K larger than the number of segments, and the default segment size.
DESIGNS = [(600, 4), (600, 64), (40, 16), (600, None)]


@functools.lru_cache(maxsize=None)
def _ops(capacity, segment, k=K):
  """(init, jitted push, jitted pop) of one design, shared by the tests."""
  init = lambda: heap_lib.init(NUM_INSTANCES, capacity, k, segment_size=segment)
  push = jax.jit(heap_lib.push)
  pop = jax.jit(lambda h, active: heap_lib.pop(h, k, active))
  return init, push, pop


peek = jax.jit(heap_lib.peek)


class Model:
  """heapq per instance, with the rule that capacity counts all stored pushes."""

  def __init__(self, capacity):
    self.queues = [[] for _ in range(NUM_INSTANCES)]
    self.seq = [0] * NUM_INSTANCES
    self.capacity = capacity
    self.overflow = [0] * NUM_INSTANCES

  def push(self, keys, values, mask):
    for i in range(NUM_INSTANCES):
      for key, value, m in zip(keys[i], values[i], mask[i]):
        if not m or not key < np.inf:
          continue
        if self.seq[i] >= self.capacity:
          self.overflow[i] += 1
          continue
        heapq.heappush(self.queues[i], (float(key), self.seq[i], int(value)))
        self.seq[i] += 1

  def pop(self, k, active, limit=None):
    out = []
    for i in range(NUM_INSTANCES):
      got = []
      bound = np.inf if limit is None else limit[i]
      while active[i] and self.queues[i] and len(got) < k and self.queues[i][0][0] <= bound:
        key, _, value = heapq.heappop(self.queues[i])
        got.append((key, value))
      out.append(got)
    return out

  def kth_key(self, k):
    return [sorted(q)[k - 1][0] if len(q) >= k else np.inf for q in self.queues]


def _random_push(rng):
  # Few distinct keys (many ties), some random floats, negative zero and a few -inf.
  keys = rng.choice([0.0, -0.0, 1.0, 2.0, 2.5, 7.0], size=(NUM_INSTANCES, M))
  floats = rng.uniform(0, 10, size=(NUM_INSTANCES, M))
  keys = np.where(rng.random((NUM_INSTANCES, M)) < 0.3, floats, keys).astype(np.float32)
  values = rng.integers(0, 1000, size=(NUM_INSTANCES, M)).astype(np.int32)
  mask = rng.random((NUM_INSTANCES, M)) < 0.7
  return keys, values, mask


def _check_pop(model, got_keys, got_values, got_mask, active, limit=None):
  want = model.pop(K, active, limit)
  for i in range(NUM_INSTANCES):
    n = int(got_mask[i].sum())
    assert n == len(want[i]), (i, n, want[i])
    assert got_mask[i, :n].all()  # valid entries first
    pairs = list(zip(got_keys[i, :n].tolist(), got_values[i, :n].tolist()))
    assert pairs == want[i], (i, pairs, want[i])


@pytest.mark.parametrize('capacity,segment', DESIGNS)
def test_matches_heapq(capacity, segment):
  init, push, pop = _ops(capacity, segment)
  rng = np.random.default_rng(0)
  model = Model(capacity)
  heap = init()
  for step in range(60):
    if rng.random() < 0.55 or step < 3:
      keys, values, mask = _random_push(rng)
      heap = push(heap, jnp.asarray(keys), jnp.asarray(values), jnp.asarray(mask))
      model.push(keys, values, mask)
    else:
      key, value, present = peek(heap)  # the best entry, left in place
      for i in range(NUM_INSTANCES):
        assert bool(present[i]) == bool(model.queues[i])
        if model.queues[i]:
          assert (float(key[i]), int(value[i])) == (model.queues[i][0][0], model.queues[i][0][2])
      active = rng.random(NUM_INSTANCES) < 0.8
      heap, k, v, m = pop(heap, jnp.asarray(active))
      _check_pop(model, np.asarray(k), np.asarray(v), np.asarray(m), active)
    np.testing.assert_array_equal(np.asarray(heap.count),
                                  [len(q) for q in model.queues])
  # Drain everything.
  while any(model.queues):
    heap, k, v, m = pop(heap, jnp.ones(NUM_INSTANCES, bool))
    _check_pop(model, np.asarray(k), np.asarray(v), np.asarray(m), [True] * NUM_INSTANCES)
  heap, k, v, m = pop(heap, jnp.ones(NUM_INSTANCES, bool))
  assert not np.asarray(m).any()  # empty
  np.testing.assert_array_equal(np.asarray(heap.overflow), model.overflow)


@pytest.mark.parametrize('capacity,segment', DESIGNS)
def test_limited_pop_and_kth_key_match_heapq(capacity, segment):
  # A pop up to a key limit takes only the entries <= limit and leaves the others in place:
  # later pops see them in the same (key, insertion) order.
  init, push, _ = _ops(capacity, segment)
  pop_limited = _limited_pop(capacity, segment)
  rng = np.random.default_rng(3)
  model = Model(capacity)
  heap = init()
  limited = 0
  for step in range(50):
    np.testing.assert_array_equal(np.asarray(_kth_key(heap)), model.kth_key(K))
    if rng.random() < 0.5 or step < 3:
      keys, values, mask = _random_push(rng)
      heap = push(heap, jnp.asarray(keys), jnp.asarray(values), jnp.asarray(mask))
      model.push(keys, values, mask)
    else:
      active = rng.random(NUM_INSTANCES) < 0.8
      limit = rng.choice([0.0, 1.0, 2.0, 2.5, 5.0, np.inf], size=NUM_INSTANCES).astype(np.float32)
      heap, k, v, m = pop_limited(heap, jnp.asarray(active), jnp.asarray(limit))
      limited += int(np.sum(active & (np.asarray(m).sum(axis=1) < np.minimum(
          K, [len(q) for q in model.queues]))))
      _check_pop(model, np.asarray(k), np.asarray(v), np.asarray(m), active, limit)
    np.testing.assert_array_equal(np.asarray(heap.count),
                                  [len(q) for q in model.queues])
  assert limited >= 5  # the limit held entries back in several pops
  np.testing.assert_array_equal(np.asarray(heap.overflow), model.overflow)


@functools.lru_cache(maxsize=None)
def _limited_pop(capacity, segment):
  return jax.jit(lambda h, active, limit: heap_lib.pop(h, K, active, limit))


_kth_key = jax.jit(lambda h: heap_lib.kth_key(h, K))


def test_overflow_is_counted():
  capacity = 20
  init, push, pop = _ops(capacity, 8)
  model = Model(capacity)
  heap = init()
  rng = np.random.default_rng(1)
  for _ in range(4):
    keys, values, mask = _random_push(rng)
    heap = push(heap, jnp.asarray(keys), jnp.asarray(values), jnp.asarray(mask))
    model.push(keys, values, mask)
    heap, k, v, m = pop(heap, jnp.ones(NUM_INSTANCES, bool))
    _check_pop(model, np.asarray(k), np.asarray(v), np.asarray(m), [True] * NUM_INSTANCES)
  assert min(model.overflow) > 0
  np.testing.assert_array_equal(np.asarray(heap.overflow), model.overflow)


@pytest.mark.parametrize('capacity,segment', DESIGNS[1:3])
def test_non_finite_keys_are_not_stored(capacity, segment):
  init, push, pop = _ops(capacity, segment)
  keys = jnp.array([[jnp.nan, jnp.inf, 3.0, -jnp.inf, 1.0]] * NUM_INSTANCES, jnp.float32)
  values = jnp.broadcast_to(jnp.arange(5, dtype=jnp.int32), keys.shape)
  heap = push(init(), keys, values, jnp.ones(keys.shape, bool))
  np.testing.assert_array_equal(np.asarray(heap.count), [3] * NUM_INSTANCES)
  _, k, v, m = pop(heap, jnp.ones(NUM_INSTANCES, bool))
  np.testing.assert_array_equal(np.asarray(v)[:, :3], [[3, 4, 2]] * NUM_INSTANCES)
  np.testing.assert_array_equal(np.asarray(m)[:, :4], [[True, True, True, False]] * NUM_INSTANCES)
  assert np.asarray(k)[0, 0] == -np.inf


def test_inactive_instances_do_not_change():
  init, push, pop = _ops(600, None)
  keys = jnp.arange(2 * NUM_INSTANCES * M, dtype=jnp.float32).reshape(NUM_INSTANCES, 2 * M)
  heap = push(init(), keys, keys.astype(jnp.int32), jnp.ones(keys.shape, bool))
  active = jnp.array([True, False, True])
  new, _, _, m = pop(heap, active)
  assert not np.asarray(m)[1].any()
  for old_leaf, new_leaf in zip(jax.tree.leaves(heap), jax.tree.leaves(new)):
    np.testing.assert_array_equal(np.asarray(old_leaf)[1], np.asarray(new_leaf)[1])


def test_bad_arguments():
  with pytest.raises(ValueError, match='capacity'):
    heap_lib.init(1, 0, 2)
  with pytest.raises(ValueError, match='k >= 1'):
    heap_lib.kth_key(heap_lib.init(1, 16, 4), 0)
