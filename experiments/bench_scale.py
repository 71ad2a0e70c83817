"""PACHS over several devices of one host: the 150-run PushT-Obs benchmark on 1, 2 and 4 devices.

Per device count: wall time, edges/s, speed-up and whether the results equal the first count's
(docs/sharding.md); CPU: XLA_FLAGS=--xla_force_host_platform_device_count=4."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time

import jax
import numpy as np

import common
import open_loop
import stats
from pachs_jax import planner
from pachs_jax.search import pachs
from pachs_jax import sharding
from pachs_jax.search.result import StopReason


def peak_memory_bytes(device):
  stats = device.memory_stats() or {}
  return stats.get('peak_bytes_in_use')


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--task', default='pusht-obs')
  parser.add_argument('--checkpoint', default=None, help='default: the shipped model')
  parser.add_argument('--devices', default='1,2,4', help='device counts, comma separated')
  parser.add_argument('--seeds', type=int, default=5, help='runs (rounds) per instance')
  parser.add_argument('--budget', type=int, default=100_000, help='evaluations per run')
  parser.add_argument('--pop-sizes', default=None,
                      help="K values, comma separated (default: the task's tuned K); each K is "
                      'measured on every device count')
  parser.add_argument('--compact-fractions', default='',
                      help='SearchConfig.compact_fractions, comma separated (default: none)')
  parser.add_argument('--repeats', type=int, default=1,
                      help='timed calls per device count (the median is reported)')
  common.add_common_args(parser, out='experiments/results/bench_scale.json', instances=30,
                         backend=True, seed=True)
  parser.add_argument('--plot-from', default=None,
                      help='only plot: speed-up against devices from these result JSON files '
                      '(comma separated) into the --out stem + .png')
  args = parser.parse_args()
  if args.plot_from:
    rows = []
    for path in args.plot_from.split(','):
      with open(path) as f:
        payload = json.load(f)
      rows += [dict(r, source=os.path.basename(path)) for r in payload['rows']]
    plot_speedup(rows, os.path.splitext(args.out)[0] + '.png',
                 f"{payload['task']}, {payload['runs']} runs")
    return
  counts = [int(d) for d in args.devices.split(',')]
  if not counts or min(counts) < 1 or min(args.instances, args.seeds, args.repeats) < 1:
    parser.error('--devices, --instances, --seeds and --repeats must be positive')

  env, model = planner.load_model(args.task, args.checkpoint, args.backend)
  tuned = planner.default_config(args.task, max_evaluations=args.budget)
  try:
    pop_sizes = list(dict.fromkeys(int(k) for k in args.pop_sizes.split(','))) \
        if args.pop_sizes else [tuned.pop_size]
    fractions = tuple(float(f) for f in args.compact_fractions.split(',') if f)
    dataclasses.replace(tuned, compact_fractions=fractions)  # checks the fractions
  except ValueError as error:
    parser.error(f'--pop-sizes / --compact-fractions: {error}')
  if min(pop_sizes) < 1:
    parser.error('--pop-sizes must be positive')
  num_runs = args.instances * args.seeds
  # the runs and keys of experiments/open_loop.py: run r * I + i is round r of instance i
  instance = np.tile(np.arange(args.instances), args.seeds)
  round_ = np.repeat(np.arange(args.seeds), args.instances)
  starts = jax.tree.map(lambda x: x[instance], env.canonical_instances(args.instances))
  keys = open_loop.run_keys(args.seed, args.instances, args.seeds)
  available = jax.device_count()
  result = {'provenance': common.provenance(), 'task': args.task,
            'model': args.checkpoint or planner.checkpoint_path(args.task),
            'backend': type(env).__name__, 'configs': {},
            'instances': args.instances, 'seeds': args.seeds, 'runs': num_runs,
            'devices_available': available, 'rows': [], 'skipped': [], 'per_run': {}}
  for pop_size in pop_sizes:
    config = dataclasses.replace(tuned, pop_size=pop_size, compact_fractions=fractions)
    result['configs'][pop_size] = repr(config)
    search = pachs.make_search(env, model, config)
    reference = None  # (device count, host result) of the first count measured with this K
    for count in counts:
      if count > available:
        print(f'skipping {count} devices: only {available} available', flush=True)
        result['skipped'].append({'devices': count, 'K': pop_size,
                                  'reason': f'only {available} device(s) available'})
        continue
      row, host = measure(env, model, starts, config, keys, count, args.repeats, search)
      row = {'K': pop_size, **row}
      if reference is None:
        reference = (count, host)
        result['per_run'][pop_size] = [
            {'instance': int(i), 'round': int(r), 'found': bool(f), 'cost': float(c),
             'evaluated': int(e), 'stop': StopReason.name(s)}
            for i, r, f, c, e, s in zip(instance, round_, host.found, host.cost,
                                        host.evaluated, host.stop_reason)]
      row.update(compare(host, *reference))
      print({k: v for k, v in row.items() if k != 'wall_s_all'}, flush=True)
      result['rows'].append(row)
      common.write_json(args.out, result)

  for row in result['rows']:
    one = next((r for r in result['rows'] if r['devices'] == 1 and r['K'] == row['K']), None)
    row['speedup'] = one['wall_s'] / row['wall_s'] if one else None
    row['efficiency'] = row['speedup'] / row['devices'] if one else None
  result['all_identical_found_cost'] = all(r['identical_found_cost'] for r in result['rows'])
  common.write_json(args.out, result)
  skipped = ''.join(f"\nskipped: {s['devices']} devices at K={s['K']} ({s['reason']})"
                    for s in result['skipped'])
  md = [f"# PACHS over devices ({args.task}, {num_runs} runs = {args.instances} instances x "
        f"{args.seeds} seeds, budget {args.budget}, env {result['backend']})\n\n"
        f"{result['provenance']}\n{skipped}\n",
        common.markdown_table(result['rows'], [
            'K', 'devices', 'runs_per_device', 'wall_s', 'iterations_max', 'evaluated',
            'edges_per_s', 'found', 'speedup', 'efficiency', 'identical_found_cost',
            'identical_all_fields'])]
  with open(os.path.splitext(args.out)[0] + '.md', 'w') as f:
    f.write('\n'.join(md) + '\n')
  plot_speedup(result['rows'], os.path.splitext(args.out)[0] + '.png',
               f'{args.task}, {num_runs} runs')
  print('\n'.join(md))


def plot_speedup(rows, path, what):
  """Speed-up over one device against device count, one line per K (and source file)."""
  import matplotlib
  matplotlib.use('Agg')
  import matplotlib.pyplot as plt
  fig, ax = plt.subplots(figsize=(5, 4))
  lines = {}
  for r in rows:
    if r.get('speedup') is not None:
      lines.setdefault((r.get('K', '?'), r.get('source', '')), []).append(
          (r['devices'], r['speedup']))
  most = max([d for pts in lines.values() for d, _ in pts] + [1])
  ax.plot([1, most], [1, most], 'k:', label='linear')
  for (k, source), pts in sorted(lines.items(), key=lambda item: (
      item[0][1], item[0][0] if isinstance(item[0][0], int) else -1)):
    d, s = zip(*sorted(pts))
    ax.plot(d, s, 'o-', label=f'K={k}' + (f' ({source})' if source else ''))
  ax.set_xlabel('devices')
  ax.set_ylabel('speed-up over one device')
  ax.set_title(f'PACHS over devices: {what}')
  ax.legend(fontsize=7)
  fig.tight_layout()
  fig.savefig(path, dpi=110)
  plt.close(fig)


def measure(env, model, starts, config, keys, count, repeats, search):
  """Plans all runs over the first `count` devices `repeats` times; returns (row, host result)."""
  mesh = sharding.instance_mesh(jax.devices()[:count])
  walls, first = [], None
  for _ in range(repeats):
    t0 = time.perf_counter()
    out = sharding.plan_sharded(env, model, starts, config, keys, mesh=mesh, search=search)
    first = first if first is not None else time.perf_counter() - t0
    walls.append(float(out.wall_time_s))
  host = jax.tree.map(np.asarray, out.replace(wall_time_s=None))
  wall = float(np.median(walls))
  evaluated = int(host.evaluated.sum())
  num_runs = host.found.shape[0]
  row = {'devices': count, 'runs_per_device': -(-num_runs // count), 'wall_s': wall,
         'wall_s_all': walls, 'first_call_s_incl_compile': first, 'evaluated': evaluated,
         'edges_per_s': evaluated / wall, 'found': int(host.found.sum()),
         'iterations_max': int(host.iterations.max()),
         'stop_reasons': stats.stop_counts(host.stop_reason),
         'overflow': int((host.heap_overflow + host.pool_overflow
                          + host.table_overflow).sum()),
         'device0_peak_bytes_so_far': peak_memory_bytes(jax.devices()[0])}
  return row, host


def compare(host, ref_count, ref):
  """Whether every run's result equals that of the reference device count."""
  same_found_cost = (np.array_equal(host.found, ref.found)
                     and np.array_equal(host.cost, ref.cost, equal_nan=True))
  differing = np.flatnonzero((host.found != ref.found)
                             | ~((host.cost == ref.cost)
                                 | (np.isnan(host.cost) & np.isnan(ref.cost))))
  return {'compared_with_devices': ref_count,
          'identical_found_cost': bool(same_found_cost),
          'identical_all_fields': all(np.array_equal(a, b, equal_nan=a.dtype.kind == 'f')
                                      for a, b in zip(jax.tree.leaves(host),
                                                      jax.tree.leaves(ref))),
          'differing_runs': differing.tolist()[:20]}


if __name__ == '__main__':
  main()
