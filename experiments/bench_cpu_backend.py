"""CPU physics backends side by side on this host: MJX on the CPU vs MuJoCo C (all threads).

Times one jitted `env.evaluate` of B PushT edges (physics, cost, coverage) with each backend, and
one PACHS plan of a PushT-Obs instance with the MuJoCo C backend.

  python experiments/bench_cpu_backend.py --out experiments/results/bench_cpu_backend.json
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import jax.numpy as jnp

import common
from pachs_jax import envs, planner
from pachs_jax.envs import mujoco_c
from pachs_jax.search import pachs


def evaluate_speed(env, batch: int, repeats: int) -> dict:
  nodes = env.canonical_instances(30)
  nodes = jax.tree.map(lambda x: x[jnp.arange(batch) % 30], nodes)
  actions = jax.random.uniform(jax.random.PRNGKey(0), (batch, env.action_size), minval=-1,
                               maxval=1)
  fn = jax.jit(env.evaluate)
  t = common.time_call(lambda: fn(nodes, actions), repeats=repeats)
  return {'batch': batch, **t, 'edges_per_s': batch / t['median_s']}


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--batch', type=int, default=64)
  parser.add_argument('--out', default='experiments/results/bench_cpu_backend.json')
  args = parser.parse_args()
  mjx_env = envs.make('pusht-fixed')
  c_env = mujoco_c.MujocoCEnv(mjx_env)
  rows = [{'backend': 'mjx (cpu)', **evaluate_speed(mjx_env, args.batch, 2)},
          {'backend': 'mujoco-c', **evaluate_speed(c_env, args.batch, 5)}]
  rows.append({'backend': 'speed-up', 'edges_per_s': rows[1]['edges_per_s'] /
               rows[0]['edges_per_s']})
  for r in rows:
    print(r, flush=True)
  env, model = planner.load_model('pusht-obs', backend='mujoco-c')
  starts = jax.tree.map(lambda x: x[:1], env.canonical_instances(30))
  config = planner.default_config('pusht-obs', max_evaluations=2000)
  start = time.perf_counter()
  result = pachs.plan(env, model, starts, config, jax.random.PRNGKey(0))
  plan_row = {'task': 'pusht-obs', 'instance': 0, 'budget': 2000,
              'search_s': float(result.wall_time_s),
              'total_s_incl_compile': time.perf_counter() - start,
              **planner.result_rows(result, [0])[0]}
  print(plan_row)
  out = {'provenance': common.provenance(), 'evaluate': rows, 'plan': plan_row}
  common.write_json(args.out, out)
  with open(os.path.splitext(args.out)[0] + '.md', 'w') as f:
    f.write(f"# CPU physics backends (this host)\n\n{out['provenance']}\n\n")
    f.write(common.markdown_table(rows, ['backend', 'batch', 'median_s', 'edges_per_s']))
    f.write('\n\nPACHS with MuJoCo C, PushT-Obs instance 0, budget 2000: ' +
            ', '.join(f'{k} {v}' for k, v in plan_row.items()) + '\n')


if __name__ == '__main__':
  main()
