"""Compilation of the search's loop with the GPU's compaction settings, on this machine: the
time of a `pachs.plan` call minus its search time, no persistent cache, for a task's first
instances padded to a bucket (as on a GPU). `--source DIR` imports pachs_jax from another
checkout (e.g. a `git worktree` of an earlier revision), to compare two revisions in one
session.

  python experiments/bench_compile.py --out /tmp/after.json
  git worktree add /tmp/before REV && python experiments/bench_compile.py --source /tmp/before
"""

from __future__ import annotations

import argparse
import json
import sys
import time


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument('--task', default='pusht-fixed')
  parser.add_argument('--instances', type=int, default=2)
  parser.add_argument('--bucket', type=int, default=32, help='padded instance count')
  parser.add_argument('--budget', type=int, default=200)
  parser.add_argument('--source', default=None, help='a checkout whose pachs_jax to import')
  parser.add_argument('--out', required=True)
  args = parser.parse_args()
  if args.source:
    sys.path.insert(0, args.source)
  import jax
  import common
  from pachs_jax import planner, programs
  from pachs_jax.search import pachs
  env, model = planner.load_model(args.task, None, 'mjx')
  config = planner.command_config(args.task, False, False, args.budget)  # GPU settings
  starts = env.canonical_instances(args.instances)
  search = programs.Programs(pachs.make_search(env, model, config))
  began = time.perf_counter()
  out = jax.block_until_ready(programs.plan(env, model, starts, config, jax.random.PRNGKey(0),
                                            search=search, min_bucket=args.bucket))
  total = time.perf_counter() - began
  provenance = common.provenance()
  if args.source:
    provenance['source'] = args.source
    provenance['source_revision'] = common.git_revision(args.source)
  row = {'provenance': provenance, 'task': args.task, 'instances': args.instances,
         'bucket': args.bucket, 'pop_size': config.pop_size,
         'compact_fractions': list(config.compact_fractions), 'plan_call_s': total,
         'search_s': float(out.wall_time_s), 'compile_s': total - float(out.wall_time_s),
         'found': out.found.tolist(), 'evaluated': out.evaluated.tolist(),
         'loops_compiled': [str(key[1]) for compiled in search.compiled.values()
                            for key in compiled if isinstance(key, tuple)]}
  common.write_json(args.out, row)
  print(json.dumps(row))


if __name__ == '__main__':
  main()
