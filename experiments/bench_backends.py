"""MJX against MuJoCo C physics on one host (README, 'The original's architecture, measured').

--mode search: PACHS run to budget with MJX on the accelerator and with MuJoCo C on CPU threads;
--mode evaluate: one `env.evaluate` of PushT edges per backend on the CPU, and a MuJoCo C plan."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import jax
import jax.numpy as jnp

import common
from pachs_jax import envs, planner, programs
from pachs_jax.envs import mujoco_c

HERE = os.path.dirname(os.path.abspath(__file__))


def run_side(args, backend: str, out: str, cpu: bool) -> dict:
  """One side of --mode search: `bench_search.py --run-to-budget` in its own process (JAX on
  the CPU for the MuJoCo C side); compilation excluded."""
  cmd = [sys.executable, os.path.join(HERE, 'bench_search.py'), '--task', args.task,
         '--instances', str(args.instances), '--pop-sizes', args.pop_sizes,
         '--budget', str(args.budget), '--run-to-budget', '--backend', backend,
         '--raw-steps', str(args.raw_steps), '--out', out]
  env = dict(os.environ)
  if cpu:
    cmd += ['--cpu-threads', str(args.cpu_threads)]
    env['JAX_PLATFORMS'] = 'cpu'
  print(' '.join(cmd), flush=True)
  subprocess.run(cmd, check=True, env=env)
  with open(out) as f:
    return json.load(f)


def search_mode(args) -> None:
  """The same instances and keys planned by both sides; an instance may still stop early when
  its OPEN list empties, so both sides' edge counts are reported (the comparison is of rates)."""
  with tempfile.TemporaryDirectory() as tmp:
    gpu = run_side(args, 'mjx', os.path.join(tmp, 'gpu.json'), cpu=False)
    cpu = run_side(args, 'mujoco-c', os.path.join(tmp, 'cpu.json'), cpu=True)
  rows = []
  for g, c in zip(gpu['rows'], cpu['rows']):
    assert (g['instances'], g['K']) == (c['instances'], c['K'])
    rows.append({
        'instances': g['instances'], 'K': g['K'], 'budget': g['budget'],
        'gpu_evaluated': g['evaluated'], 'cpu_evaluated': c['evaluated'],
        'gpu_stops': g['stop_reasons'], 'cpu_stops': c['stop_reasons'],
        'gpu_mjx_edges_per_s': g['edges_per_s'], 'cpu_mujoco_c_edges_per_s': c['edges_per_s'],
        'gpu_over_cpu': g['edges_per_s'] / c['edges_per_s'],
        'gpu_raw_env_steps_per_s': g['raw_env_steps_per_s_same_batch'],
        'cpu_raw_env_steps_per_s': c['raw_env_steps_per_s_same_batch'],
        'gpu_search_over_raw': g['search_over_raw'], 'cpu_search_over_raw': c['search_over_raw'],
        'gpu_wall_s': g['wall_s'], 'cpu_wall_s': c['wall_s']})
  payload = {'provenance': common.provenance(), 'task': args.task,
             'cpu_threads': args.cpu_threads, 'gpu_side': gpu, 'cpu_side': cpu, 'rows': rows}
  common.write_json(args.out, payload)
  with open(os.path.splitext(args.out)[0] + '.md', 'w') as f:
    f.write(f'# PACHS on the GPU (MJX) against the CPU (MuJoCo C, {args.cpu_threads} threads), '
            f'{args.task}, same host, run to budget\n\n'
            f'{payload["provenance"]}\n\nGPU side: {gpu["provenance"]["device"]}; CPU side: '
            f'{cpu["provenance"]["device"]}, {cpu["provenance"]["host_cpus"]} host CPUs\n\n')
    f.write(common.markdown_table(rows, list(rows[0])) + '\n\nStop reason counts: '
            '[running, goal, budget, iterations, open_empty, capacity, time_limit].\n')
  print(common.markdown_table(rows, list(rows[0])))


def evaluate_speed(env, batch: int, repeats: int) -> dict:
  """Edges/s of one jitted `env.evaluate` of `batch` edges from the canonical instances."""
  nodes = env.canonical_instances(30)
  nodes = jax.tree.map(lambda x: x[jnp.arange(batch) % 30], nodes)
  actions = jax.random.uniform(jax.random.PRNGKey(0), (batch, env.action_size), minval=-1,
                               maxval=1)
  fn = jax.jit(env.evaluate)
  t = common.time_call(lambda: fn(nodes, actions), repeats=repeats)
  return {'batch': batch, **t, 'edges_per_s': batch / t['median_s']}


def evaluate_mode(args) -> None:
  """PushT-Fixed edges with MJX and with MuJoCo C on this host's CPU, then one PACHS plan of
  PushT-Obs instance 0 with MuJoCo C (budget 2000)."""
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
  result = programs.plan(env, model, starts, config, jax.random.PRNGKey(0))
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


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--mode', default='search', choices=['search', 'evaluate'])
  parser.add_argument('--task', default='pusht-obs', help='search: the task')
  parser.add_argument('--pop-sizes', default='64', help='search: K values, comma separated')
  parser.add_argument('--budget', type=int, default=20_000, help='search: evaluations per run')
  parser.add_argument('--cpu-threads', type=int, default=16, help='search: MuJoCo C threads')
  parser.add_argument('--raw-steps', type=int, default=20,
                      help='search: evaluate calls per raw-throughput measurement')
  parser.add_argument('--batch', type=int, default=64, help='evaluate: edges per call')
  common.add_common_args(parser, out=None, instances=30)
  args = parser.parse_args()
  args.out = args.out or {'search': 'experiments/results/bench_backends.json',
                          'evaluate': 'experiments/results/bench_cpu_backend.json'}[args.mode]
  (search_mode if args.mode == 'search' else evaluate_mode)(args)


if __name__ == '__main__':
  main()
