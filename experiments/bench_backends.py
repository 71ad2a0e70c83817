"""The original's architecture against ours, on one host and in one run: the same PACHS planning
problems with MJX on the GPU, and on the CPU (JAX on the CPU, edges simulated by MuJoCo C on
`--cpu-threads` threads, the original's thread-parallel edge evaluation).

Both runs plan the same instances with the same keys toward their budget (`bench_search.py
--run-to-budget`: goals are never accepted); an instance may still stop early when its OPEN
list empties, so the two sides' edge counts can differ a little and both are reported (the
comparison is of rates, edges per second). Each side runs in its own process (JAX_PLATFORMS=cpu for the CPU
side); compilation is excluded. Reported: edges evaluated per second of each and their ratio,
next to each side's raw batched env-step throughput at the same batch.

  python experiments/bench_backends.py --task pusht-obs --instances 30 --pop-sizes 64 \
      --budget 20000 --cpu-threads 16 --out experiments/results/bench_backends.json
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

import common

HERE = os.path.dirname(os.path.abspath(__file__))


def run_side(args, backend: str, out: str, cpu: bool) -> dict:
  cmd = [sys.executable, os.path.join(HERE, 'bench_search.py'), '--task', args.task,
         '--instances', args.instances, '--pop-sizes', args.pop_sizes,
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


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--task', default='pusht-obs')
  parser.add_argument('--instances', default='30')
  parser.add_argument('--pop-sizes', default='64')
  parser.add_argument('--budget', type=int, default=20_000)
  parser.add_argument('--cpu-threads', type=int, default=16)
  parser.add_argument('--raw-steps', type=int, default=20)
  parser.add_argument('--out', default='experiments/results/bench_backends.json')
  args = parser.parse_args()
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


if __name__ == '__main__':
  main()
