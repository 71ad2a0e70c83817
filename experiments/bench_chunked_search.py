"""Does planning in chunks (a stop check and a progress report every ~0.3 s) slow the search?
One process, programs compiled once, the same search run alternately in one call and in
adaptive chunks; the results must be identical. Writes JSON and a markdown table."""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from experiments import common  # noqa: E402
from pachs_jax import planner, programs  # noqa: E402


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__)
  parser.add_argument('--task', default='pusht-obs')
  parser.add_argument('--instances', default='0-7')
  parser.add_argument('--budget', type=int, default=20000)
  parser.add_argument('--rounds', type=int, default=8)
  parser.add_argument('--out', default='experiments/results/bench_chunked_search_cpu')
  args = parser.parse_args()
  plans = planner.Planner(args.task, budget=args.budget, cache=False)
  instances = planner.parse_instances(args.instances, 30)
  starts = plans.canonical(instances)
  chunks = {'one call': 2**30, 'adaptive chunks': None}
  times = {name: [] for name in chunks}
  counts = {name: [] for name in chunks}
  results = {}
  for round_ in range(args.rounds + 1):  # round 0 compiles and warms up
    for name, iterations in (chunks.items() if round_ % 2 else reversed(chunks.items())):
      reports = []
      out = programs.plan(plans.env, plans.model, starts, plans.config, jax.random.PRNGKey(0),
                          chunk_iterations=iterations, search=plans.search,
                          progress=reports.append)
      if round_:
        times[name].append(float(out.wall_time_s))
        counts[name].append(len(reports))
      results[name] = jax.tree.map(np.asarray, out.replace(wall_time_s=np.float32(0)))
  same = all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(results['one call']),
                                                  jax.tree.leaves(results['adaptive chunks'])))
  rows = [{'mode': name, 'median_search_s': float(np.median(times[name])),
           'min_search_s': float(np.min(times[name])), 'chunks': int(np.median(counts[name])),
           'evaluations': int(results[name].evaluated.sum()),
           'found': int(results[name].found.sum())} for name in chunks]
  payload = dict(common.provenance(), task=args.task, instances=args.instances,
                 budget=args.budget, rounds=args.rounds, identical_results=bool(same),
                 times_s=times, rows=rows)
  common.write_json(args.out + '.json', payload)
  table = common.markdown_table(rows, ['mode', 'median_search_s', 'min_search_s', 'chunks',
                                       'evaluations', 'found'])
  with open(args.out + '.md', 'w') as f:
    f.write(f'# Search in one call vs adaptive chunks\n\n{payload["command"]}\n\n'
            f'device {payload["device"]}, revision {payload["git_revision"]}, '
            f'{payload["date_utc"]} UTC; {args.task} instances {args.instances}, budget '
            f'{args.budget}, {args.rounds} alternating rounds after a warm-up; results '
            f'identical: {same}\n\n{table}\n')
  print(table)
  print('identical results:', same)


if __name__ == '__main__':
  main()
