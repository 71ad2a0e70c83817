"""Iteration time of PACHS against its live instances: the open-loop batch (instances x rounds)
stepped one iteration per call, with the whole batch's lanes throughout and with the
compacted physics sizes, to show where the loop turns latency-bound as instances finish.

  python experiments/live_lanes.py --layout two-gaps --backend warp --out live_lanes.json
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import numpy as np

import common
from pachs_jax import planner
from pachs_jax.search import pachs


def run_keys(seed: int, num_instances: int, rounds: int) -> jax.Array:
  """[rounds * I, 2]: run r of instance i gets fold_in(fold_in(seed, r), i) (as open_loop)."""
  base = jax.random.PRNGKey(seed)
  return jax.numpy.stack([jax.random.fold_in(jax.random.fold_in(base, r), i)
                          for r in range(rounds) for i in range(num_instances)])


def trace_iterations(search, starts, keys, compacted: bool) -> list:
  """One row per iteration: live instances before it, physics lanes, wall ms; the loop of
  `lanes_for(state)` (compaction and widening), else of all I * K lanes."""
  num = keys.shape[0]
  live = jax.device_put(np.ones(num, bool))
  state = search.init(starts, keys, live)
  k = search.config.pop_size
  sizes = {}
  rows = []
  while True:
    active = int(np.sum(np.asarray(state.active)))
    if active == 0:
      break
    size = search.lanes_for(state) if compacted else None
    if size not in sizes:  # compile outside the clock
      began = time.perf_counter()
      lowered = jax.jit(lambda s, n, size=size: search.loop(s, n, size, False),
                        donate_argnums=0).lower(state, np.int32(1))
      sizes[size] = (lowered.compile(), time.perf_counter() - began)
    began = time.perf_counter()
    state = sizes[size][0](state, np.int32(1))
    jax.block_until_ready(state.active)
    rows.append({'live': active, 'lanes': (size and size.size) or num * k,
                 'useful_lanes': active * k * (size.widen if size else 1),
                 'ms': 1e3 * (time.perf_counter() - began)})
  return rows, {str(s): c for s, (_, c) in sizes.items()}


def summary(rows: list, num: int) -> list:
  """Iteration time and wall share by live fraction (bins of the batch's instances)."""
  edges = [1.0, 0.75, 0.5, 0.25, 0.1, 0.0]
  total = sum(r['ms'] for r in rows)
  out = []
  for high, low in zip(edges[:-1], edges[1:]):
    part = [r for r in rows if low * num < r['live'] <= high * num]
    if not part:
      continue
    ms = [r['ms'] for r in part]
    out.append({'live_fraction': f'({low:g}, {high:g}]', 'iterations': len(part),
                'ms_per_iteration_median': float(np.median(ms)),
                'share_of_wall': sum(ms) / total,
                'lanes_used': sum(r['useful_lanes'] for r in part) / sum(r['lanes'] for r in part)})
  return out


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--rounds', type=int, default=5, help='runs per instance')
  parser.add_argument('--budget', type=int, default=100_000)
  common.add_common_args(parser, out='experiments/results/engines/live_lanes.json',
                         instances=30, backend=True, layout=True)
  args = parser.parse_args()
  env, model = planner.load_model('pusht-obs', backend=args.backend, layout=args.layout)
  config = planner.default_config('pusht-obs', max_evaluations=args.budget,
                                  compact_fractions=planner.COMMAND_COMPACT_FRACTIONS)
  search = pachs.make_search(env, model, config)
  canonical = env.canonical_instances(args.instances)
  starts = jax.tree.map(lambda x: np.concatenate([np.asarray(x)] * args.rounds), canonical)
  keys = run_keys(0, args.instances, args.rounds)
  result = {'provenance': common.provenance(), 'settings': vars(args), 'config': repr(config),
            'env': type(env).__name__, 'modes': {}}
  num = keys.shape[0]
  for mode, compacted in (('all lanes', False), ('compacted sizes', True)):
    rows, compile_s = trace_iterations(search, starts, keys, compacted)
    result['modes'][mode] = {'iterations': rows, 'compile_s': compile_s,
                             'wall_s': sum(r['ms'] for r in rows) / 1e3,
                             'summary': summary(rows, num)}
    print(mode, result['modes'][mode]['wall_s'], result['modes'][mode]['summary'], flush=True)
  common.write_json(args.out, result)
  md = [f'# PACHS iteration time against live instances ({env.name}, {num} runs, '
        f'{type(env).__name__})\n', str(result['provenance']), '',
        f'Config: {result["config"]}', '']
  for mode, m in result['modes'].items():
    md += [f'## {mode}: {m["wall_s"]:.2f} s over {len(m["iterations"])} iterations '
           f'(compile {m["compile_s"]})\n',
           common.markdown_table(m['summary'], ['live_fraction', 'iterations',
                                                'ms_per_iteration_median', 'share_of_wall',
                                                'lanes_used']), '']
  with open(os.path.splitext(args.out)[0] + '.md', 'w') as f:
    f.write('\n'.join(md) + '\n')


if __name__ == '__main__':
  main()
