"""A sweep of the shelf's ePA*SE baseline: heuristic weight, obstacle inflation of the BFS-3D
grid, primitive step and the heuristic's spread into blocked cells, on the canonical targets."""

from __future__ import annotations

import argparse
import itertools
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

import common
import stats
from pachs_jax import envs
from pachs_jax.runtime import programs
from pachs_jax.search import baselines as bl


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--weights', default='2,10')
  parser.add_argument('--inflations', default='0.02', help='m, comma separated')
  parser.add_argument('--steps', default='7', help='primitive steps in degrees, comma separated')
  parser.add_argument('--spreads', default='0', help='cells the BFS distances extend into the '
                      'blocked cells (voxel.grid_heuristic), comma separated')
  parser.add_argument('--targets', type=int, default=100, metavar='N',
                      help='the first N canonical shelf targets')
  parser.add_argument('--pop-size', type=int, default=16)
  parser.add_argument('--budget', type=int, default=120_000)
  common.add_common_args(parser, out='experiments/results/tune_epase.json')
  args = parser.parse_args()
  env = envs.make('shelf')
  starts = env.canonical_instances(100)
  starts = jax.tree.map(lambda x: x[:args.targets], starts)
  payload = {'provenance': common.provenance(), 'targets': args.targets, 'rows': []}
  for w, inflation, step, spread in itertools.product(
      [float(x) for x in args.weights.split(',')], [float(x) for x in args.inflations.split(',')],
      [float(x) for x in args.steps.split(',')], [int(x) for x in args.spreads.split(',')]):
    setup = bl.shelf_setup(env, step_deg=step, inflation=inflation, spread=spread)
    config = bl.EpaseConfig(weight=w, pop_size=args.pop_size, budget=args.budget,
                            lattice_resolution=setup.lattice_resolution)
    search = bl.make_epase(env, setup.primitives, setup.heuristic, config, edge_fn=setup.edge_fn)
    start = time.perf_counter()
    result = programs.timed(search.plan, starts)
    compile_s = time.perf_counter() - start - float(result.wall_time_s)
    r = jax.tree.map(np.asarray, result)
    h0 = np.asarray(setup.heuristic.value(setup.heuristic.init(starts),
                                          jax.tree.map(lambda x: jnp.asarray(x)[:, None],
                                                       starts)))[:, 0]
    row = {'w': w, 'inflation_m': inflation, 'step_deg': step, 'spread_cells': spread,
           'budget': args.budget,
           'found': int(r.found.sum()), 'targets': args.targets,
           'wall_s': float(r.wall_time_s), 'compile_s': compile_s,
           'evaluated_mean': float(r.evaluated.mean()), 'expanded_mean': float(r.expanded.mean()),
           'cost_success_mean': stats.mean_where(r.cost, r.found),
           'h_start_mean': float(h0.mean()),
           'stops': stats.stop_counts(r.stop_reason)}
    print(row, flush=True)
    payload['rows'].append(row)
    common.write_json(args.out, payload)
    with open(os.path.splitext(args.out)[0] + '.md', 'w') as f:
      f.write(f'# ePA*SE sweep on the shelf ({args.targets} canonical targets)\n\n'
              f'{payload["provenance"]}\n\n')
      f.write(common.markdown_table(payload['rows'], list(row)) + '\n')


if __name__ == '__main__':
  main()
