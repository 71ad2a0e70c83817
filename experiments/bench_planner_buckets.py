"""What a new instance count costs `Planner` on this machine: the programs of a new bucket
(instance counts are padded to the next power of two; at least 32 on an accelerator, 1 on a
CPU) against the search time that padding one instance to a larger bucket would add.
Writes JSON and a markdown table."""

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
  parser.add_argument('--budget', type=int, default=3000)
  parser.add_argument('--buckets', default='1,2,4,32')
  parser.add_argument('--out', default='experiments/results/bench_planner_buckets_cpu')
  args = parser.parse_args()
  plans = planner.Planner(args.task, budget=args.budget, cache=False)
  starts = plans.canonical([0])
  rows = []
  for bucket in (int(b) for b in args.buckets.split(',')):
    def run():
      began = time.perf_counter()
      out = programs.plan(plans.env, plans.model, starts, plans.config, jax.random.PRNGKey(0),
                          search=plans.search, min_bucket=bucket)
      return time.perf_counter() - began, float(out.wall_time_s), out
    first_wall, _, _ = run()  # compiles this bucket's programs
    searches = [run()[1] for _ in range(3)]
    _, _, out = run()
    rows.append({'bucket': bucket, 'first_call_s': first_wall,
                 'search_s_median': float(np.median(searches)),
                 'evaluated': int(np.asarray(out.evaluated)[0]),
                 'stop': planner.StopReason.name(np.asarray(out.stop_reason)[0])})
  payload = dict(common.provenance(), task=args.task, budget=args.budget, instance=0,
                 rows=rows)
  common.write_json(args.out + '.json', payload)
  table = common.markdown_table(rows, ['bucket', 'first_call_s', 'search_s_median',
                                       'evaluated', 'stop'])
  with open(args.out + '.md', 'w') as f:
    f.write(f'# One instance planned in buckets of several sizes\n\n{payload["command"]}\n\n'
            f'device {payload["device"]}, revision {payload["git_revision"]}, '
            f'{payload["date_utc"]} UTC; {args.task} instance 0, budget {args.budget}, cache '
            f'off; first_call_s: the first plan of a bucket, compilation included; '
            f'search_s_median: 3 later plans, compilation excluded\n\n{table}\n')
  print(table)


if __name__ == '__main__':
  main()
