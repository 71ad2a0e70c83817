"""Times the edge-heap designs: one search iteration's heap work (pop K, push K (N + 1) slots).

For each design, capacity C and pop size K, the heap of I instances is pre-filled to half its
capacity with random keys, then a jitted loop runs T iterations of: pop the K best entries, push
K (N + 1) slots of which K are valid at random positions (so the number of entries stays about
the same; the flat designs use up K fresh slots per iteration). Times exclude compilation and
pre-filling; the median over repetitions is reported as ms per iteration.

  python experiments/bench_heap.py --out results/bench_heap.json
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time

import jax
import jax.numpy as jnp

from pachs_jax.search import heap as heap_lib


def prefilled(kind, num_instances, capacity, k, key):
  """A heap holding capacity // 2 random entries per instance."""
  fill = capacity // 2
  keys = jax.random.uniform(key, (num_instances, fill), jnp.float32, 0.0, 100.0)
  values = jnp.broadcast_to(jnp.arange(fill, dtype=jnp.int32), keys.shape)
  heap = heap_lib.init(kind, num_instances, capacity, k)
  if kind != 'blocked':
    return heap_lib.push(heap, keys, values, jnp.ones(keys.shape, bool))
  # Bulk build: sorted entries laid out block by block in level order form a valid heap.
  full = (fill // k) * k
  order = jnp.argsort(keys[:, :full], axis=1, stable=True)
  sorted_keys = jnp.take_along_axis(keys[:, :full], order, axis=1).reshape(num_instances, -1, k)
  seqs = order.astype(jnp.int32).reshape(sorted_keys.shape)
  nb = full // k
  return heap.replace(
      keys=heap.keys.at[:, :nb].set(sorted_keys), seqs=heap.seqs.at[:, :nb].set(seqs),
      values=heap.values.at[:, :nb].set(seqs), num_blocks=jnp.full((num_instances,), nb),
      next_seq=jnp.full((num_instances,), full), count=jnp.full((num_instances,), full))


def make_loop(k, width, iterations):
  """Jitted T iterations of pop k / push `width` slots (k valid) on a donated heap."""

  def loop(heap, key):
    def body(t, carry):
      heap, total = carry
      heap, keys, _, mask = heap_lib.pop(heap, k)
      step_key = jax.random.fold_in(key, t)
      new = jnp.min(jnp.where(mask, keys, 100.0), axis=1, keepdims=True) + jax.random.uniform(
          step_key, (keys.shape[0], width), jnp.float32, 0.0, 50.0)
      slots = jax.random.uniform(jax.random.fold_in(step_key, 1), new.shape)
      valid = slots <= jnp.sort(slots, axis=1)[:, k - 1:k]  # k random valid slots
      heap = heap_lib.push(heap, new, jnp.zeros(new.shape, jnp.int32), valid)
      return heap, total + jnp.sum(mask)

    return jax.lax.fori_loop(0, iterations, body, (heap, jnp.zeros((), jnp.int32)))

  return jax.jit(loop, donate_argnums=0)


def bench(kind, num_instances, capacity, k, num_actions, reps, max_iterations):
  width = k * (num_actions + 1)
  iterations = max(1, min(max_iterations, (capacity // 2) // k - 1))
  fill = jax.jit(lambda key: prefilled(kind, num_instances, capacity, k, key))
  loop = make_loop(k, width, iterations)
  key = jax.random.PRNGKey(0)
  start = time.perf_counter()
  heap, popped = loop(fill(key), key)  # compile and warm up
  jax.block_until_ready(popped)
  compile_s = time.perf_counter() - start
  times = []
  for rep in range(reps):
    heap = jax.block_until_ready(fill(jax.random.fold_in(key, rep)))
    start = time.perf_counter()
    heap, popped = loop(heap, key)
    jax.block_until_ready((heap, popped))
    times.append((time.perf_counter() - start) / iterations)
  overflow = int(jnp.sum(heap_lib.overflow(heap)))
  return dict(kind=kind, capacity=capacity, k=k, instances=num_instances, push_width=width,
              iterations=iterations, reps=reps, ms_per_iteration=1e3 * statistics.median(times),
              ms_min=1e3 * min(times), compile_and_first_run_s=compile_s,
              popped_per_iteration=int(popped) / iterations / num_instances, overflow=overflow)


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--kinds', nargs='+', default=['flat', 'segmented', 'blocked'])
  parser.add_argument('--capacities', nargs='+', type=float, default=[1e4, 1e5, 1e6])
  parser.add_argument('--ks', nargs='+', type=int, default=[16, 64, 256])
  parser.add_argument('--instances', type=int, default=30)
  parser.add_argument('--num-actions', type=int, default=16)
  parser.add_argument('--iterations', type=int, default=50, help='timed iterations per rep')
  parser.add_argument('--reps', type=int, default=5)
  parser.add_argument('--out', default='results/bench_heap.json')
  args = parser.parse_args()

  rows = []
  for capacity in args.capacities:
    for k in args.ks:
      for kind in args.kinds:
        row = bench(kind, args.instances, int(capacity), k, args.num_actions, args.reps,
                    args.iterations)
        rows.append(row)
        print(json.dumps(row), flush=True)
  device = jax.devices()[0]
  out = dict(device=f'{device.platform}: {device.device_kind}', jax=jax.__version__,
             host=platform.node(), num_actions=args.num_actions, results=rows)
  with open(args.out, 'w') as f:
    json.dump(out, f, indent=1)
  print('wrote', args.out)


if __name__ == '__main__':
  main()
