"""Single rollout, parallel rollout and PACHS on a MuJoCo Playground task at equal budgets.

python experiments/playground_results.py --task playground:ReacherEasy --budgets 1000,5000
writes experiments/results/playground_<name>.json and .md (provenance included). The model is
the shipped one of the task unless --checkpoint. Each planner plans the canonical instances in
one batched, jitted call; wall times exclude compilation."""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from pachs_jax import argtypes


def build_parser() -> argparse.ArgumentParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--task', default='playground:ReacherEasy',
                      help='playground:NAME (a task with a model)')
  parser.add_argument('--checkpoint', default=None, help='model (default: the shipped one)')
  parser.add_argument('--instances', type=int, default=30, help='canonical instances 0..N-1')
  parser.add_argument('--budgets', default='1000,5000,20000',
                      help='edge evaluations per instance of the parallel rollout and PACHS, '
                      'comma separated (each budget is one row of each)')
  parser.add_argument('--copies', type=int, default=16, help='parallel-rollout copies')
  parser.add_argument('--pop-size', type=int, default=None, help='PACHS K (default: the task\'s)')
  parser.add_argument('--seed', type=argtypes.seed, default=0)
  parser.add_argument('--out', default=None, help='results JSON (default: '
                      'experiments/results/playground_<name>.json)')
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import jax  # noqa: E402

import common  # noqa: E402
from pachs_jax import envs, planner  # noqa: E402
from pachs_jax.runtime import programs  # noqa: E402
from pachs_jax.search import baselines as bl  # noqa: E402
from pachs_jax.search import pachs  # noqa: E402
from pachs_jax.search.result import StopReason  # noqa: E402
# pylint: enable=wrong-import-position


def _rows(result):
  r = jax.tree.map(np.asarray, result)
  return [{'found': bool(r.found[i]), 'cost': float(r.cost[i]),
           'path_length': int(r.path_length[i]), 'evaluated': int(r.evaluated[i]),
           'stop': StopReason.name(r.stop_reason[i])} for i in range(len(r.found))]


def _summary(name: str, config: str, rows, wall: float, compile_s: float) -> dict:
  ok = [r for r in rows if r['found']]
  return {'planner': name, 'config': config, 'instances': len(rows), 'solved': len(ok),
          'success_rate': len(ok) / len(rows),
          'mean_cost_solved': float(np.mean([r['cost'] for r in ok])) if ok else None,
          'mean_path_length_solved': float(np.mean([r['path_length'] for r in ok])) if ok
          else None,
          'mean_evaluated': float(np.mean([r['evaluated'] for r in rows])),
          'wall_s': wall, 'compile_s': compile_s}


def main(argv=None) -> int:
  args = build_parser().parse_args(argv)
  name = args.task.split(':', 1)[-1].lower()
  out = args.out or os.path.join(os.path.dirname(os.path.abspath(__file__)), 'results',
                                 f'playground_{name}.json')
  env, model = planner.load_model(args.task, args.checkpoint, backend='mjx')
  starts = planner.canonical_instances(env, args.instances)
  key = jax.random.PRNGKey(args.seed)
  summaries, per_planner = [], {}

  def run(label, config_text, fn, *fn_args):
    start = time.perf_counter()
    compiled = fn.lower(*fn_args).compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    result = jax.block_until_ready(compiled(*fn_args))
    wall = time.perf_counter() - start
    rows = _rows(result)
    per_planner[label] = rows
    summaries.append(_summary(label, config_text, rows, wall, compile_s))
    print(summaries[-1], flush=True)

  single = bl.SingleRolloutConfig()
  run('single rollout', f'deterministic policy, {env.episode_length} steps',
      jax.jit(bl.make_single_rollout(env, model, single)), starts)
  budgets = [int(b) for b in args.budgets.split(',')]
  for budget in budgets:
    parallel = bl.ParallelRolloutConfig(num_copies=args.copies, budget=budget)
    run(f'parallel rollout {budget}', f'{args.copies} stochastic copies, budget {budget}',
        jax.jit(bl.make_parallel_rollout(env, model, parallel).plan), starts,
        jax.random.split(key, args.instances))
    config = planner.default_config(args.task, budget=budget, pop_size=args.pop_size)
    search = programs.Programs(pachs.make_search(env, model, config))
    start = time.perf_counter()
    programs.plan(env, model, starts, config, key, search=search)  # compiles
    compile_s = time.perf_counter() - start
    result = programs.plan(env, model, starts, config, key, search=search)
    rows = _rows(result)
    per_planner[f'PACHS {budget}'] = rows
    summaries.append(_summary(
        f'PACHS {budget}', f'w {config.weight}, N {config.num_actions}, K {config.pop_size}, '
        f'budget {budget}, default lattice', rows, float(result.wall_time_s),
        compile_s - float(result.wall_time_s)))
    print(summaries[-1], flush=True)

  pachs_rows = per_planner[f'PACHS {budgets[-1]}']
  both = [i for i in range(args.instances)
          if pachs_rows[i]['found'] and per_planner['single rollout'][i]['found']]
  single_cost = sum(per_planner['single rollout'][i]['cost'] for i in both)
  ratio = (sum(pachs_rows[i]['cost'] for i in both) / single_cost
           if both and single_cost > 0 else None)
  payload = {'task': args.task, 'provenance': common.provenance(),
             'model': os.path.relpath(args.checkpoint or planner.checkpoint_path(args.task),
                                      os.path.dirname(os.path.dirname(os.path.abspath(
                                          __file__)))),
             'summaries': summaries, 'rows': per_planner,
             'pachs_over_single_cost_ratio': ratio, 'instances_both_solved': len(both)}
  prov = payload['provenance']
  columns = ['planner', 'config', 'solved', 'success_rate', 'mean_cost_solved',
             'mean_path_length_solved', 'mean_evaluated', 'wall_s', 'compile_s']
  lines = [f'# {args.task}: single rollout, parallel rollout and PACHS', '',
           f'{args.instances} canonical instances (the env\'s reset, keys split from seed 0), '
           f'model `{payload["model"]}`; cost = 1 - reward per step (reward in [0, 1]), '
           f'goal rule: `{env.config.is_goal}` >= {env.config.goal_threshold}; episode '
           f'{env.episode_length} steps. Wall time of the batched call, compile excluded.', '',
           common.markdown_table(summaries, columns), '',
           f'PACHS ({budgets[-1]}) cost / single-rollout cost, summed over the {len(both)} '
           'instances both solved: '
           f'{ratio if ratio is None else round(ratio, 3)}', '',
           f'Device: {prov["device"]} ({prov["host_cpus"]} host CPUs); command: '
           f'`{prov["command"]}`; revision {prov["git_revision"]}; JAX {prov["jax"]}; '
           f'{prov["date_utc"]} UTC.']
  common.write_result(out, payload, lines)
  print(f'wrote {out} and .md')
  return 0


if __name__ == '__main__':
  raise SystemExit(main())
