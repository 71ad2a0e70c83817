"""The original's open-loop experiments on PushT and Panda-Shelf (README, 'Open loop').

Each planner plans all runs in one batched call: success with 95% intervals, cost, time, success
against edges evaluated and pairwise cost ratios (JSON, markdown table, plot)."""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from typing import Dict, List

import numpy as np

import common
from pachs_jax import argtypes, flags

PUSHT_PLANNERS = ('pachs', 'pachs-original', 'single', 'parallel', 'beam')
# PACHS with the first goal ending the search, or with an improvement phase after it
# (SearchConfig.after_goal; the planner 'pachs' follows --after-goal or the task's default)
AFTER_GOAL_PLANNERS = {'pachs-stop': 'stop', 'pachs-improve': 'improve'}
SHELF_PLANNERS = ('pachs', 'epase', 'parallel', 'beam')
# The original's open-loop success rates where it states them (quoted in the README).
ORIGINAL = {
    'pusht-fixed': {'pachs': '100%', 'single': '93%'},
    'pusht-rand': {'pachs': '100%', 'single': '20%'},
    'pusht-obs': {'pachs': 'far above both rollouts'},
    'shelf': {'pachs': '100%', 'epase': '100%'},
}


def build_parser() -> argtypes.OneLineParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argtypes.OneLineParser(description=__doc__.splitlines()[0])
  parser.add_argument('--task', default='pusht-obs',
                      choices=['pusht-fixed', 'pusht-rand', 'pusht-obs', 'shelf'])
  parser.add_argument('--planners', default=None, help='comma list (default: all of the task)')
  parser.add_argument('--rounds', type=argtypes.positive_int, default=None,
                      help='runs per instance (default: 5 PushT, 1 shelf)')
  parser.add_argument('--budget', type=argtypes.positive_int, default=None,
                      help='evaluations per run (default: 100,000 PushT, 20,000 shelf)')
  parser.add_argument('--time-limit', type=argtypes.positive_float, default=None,
                      help='PACHS wall-clock limit of the batch (s; default: none PushT, 60 shelf)')
  flags.add_search_flags(parser, ['pop_size', 'num_actions', 'weight', 'edge_steps',
                                 'rollout_share', 'chain_restart', 'compact_fractions',
                                 'after_goal', 'improve_allowance', 'uniform_share'])
  parser.add_argument('--lattice-scale', type=argtypes.positive_float, default=None,
                      help='PACHS lattice resolution = this x the default (default: 1)')
  parser.add_argument('--copies', type=argtypes.positive_int, default=256,
                      help='parallel-rollout copies')
  parser.add_argument('--instance-seed', type=int, default=0,
                      help='the seed of the instance set (default 0: the canonical set; another '
                      'seed draws a new set from the same start region, by the same rules)')
  parser.add_argument('--beam-width', type=argtypes.positive_int, default=64)
  parser.add_argument('--epase-weight', type=argtypes.positive_float, default=20.0,
                      help='w of ePA*SE (chosen by a sweep: commit f3cad6e, results/tune_epase.md)')
  parser.add_argument('--epase-budget', type=argtypes.positive_int, default=200_000)
  parser.add_argument('--epase-spread', type=argtypes.integer(0), default=3,
                      help='cells the BFS-3D distances extend into blocked cells')
  parser.add_argument('--devices', type=argtypes.positive_int, default=1,
                      help='shard the runs over this many local devices (no PACHS time limit)')
  common.add_common_args(parser, out=None, instances=None, backend=True, seed=True, layout=True,
                         physics=True)
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import stats  # noqa: E402
from pachs_jax import envs, planner  # noqa: E402
from pachs_jax.runtime import programs, sharding  # noqa: E402
from pachs_jax.search import baselines as bl  # noqa: E402
from pachs_jax.search import pachs  # noqa: E402
from pachs_jax.search.result import StopReason  # noqa: E402
# pylint: enable=wrong-import-position


def run_keys(seed: int, num_instances: int, rounds: int) -> jax.Array:
  """[rounds * I, 2] keys: run r of instance i gets fold_in(fold_in(seed, r), i)."""
  base = jax.random.PRNGKey(seed)
  return jnp.stack([jax.random.fold_in(jax.random.fold_in(base, r), i)
                    for r in range(rounds) for i in range(num_instances)])


def make_planner(name: str, task: str, env, model, args, mesh=None):
  """(fn(starts, keys) -> SearchResult with wall_time_s set, config description).

  mesh: None runs on the default device; a `sharding.instance_mesh` splits the instances over
  its devices (no time limit then).
  """
  budget = args.budget
  if name in ('pachs', 'pachs-original') or name in AFTER_GOAL_PLANNERS:
    # the default PACHS, the published algorithm, or the default with after_goal set
    overrides = planner.accelerator_settings(jax.default_backend() == 'cpu')
    overrides.update({k: v for k, v in flags.search_overrides(args).items() if v is not None})
    overrides['after_goal'] = AFTER_GOAL_PLANNERS.get(name, overrides.get('after_goal'))
    config = planner.default_config(task, 'original' if name == 'pachs-original' else 'pachs',
                                    budget=budget, **overrides)
    if args.lattice_scale is not None:
      base = config.lattice_resolution or np.asarray(env.default_lattice_resolution).tolist()
      config = dataclasses.replace(config, lattice_resolution=tuple(
          float(x) * args.lattice_scale for x in base))
    search = programs.Programs(pachs.make_search(env, model, config))
    if mesh is not None:
      return (lambda starts, keys: sharding.plan_sharded(env, model, starts, config, keys, mesh,
                                                         search=search)), config
    limit = args.time_limit

    def fn(starts, keys):  # every program compiled before the clock starts
      return programs.plan(env, model, starts, config, keys, time_limit_s=limit, search=search,
                           compile_first=True)
    return fn, config
  if name == 'single':
    config = bl.SingleRolloutConfig()
    shard_fn = sharding.keyless(bl.make_single_rollout(env, model, config))
  elif name == 'parallel':
    config = bl.ParallelRolloutConfig(num_copies=args.copies, budget=budget)
    shard_fn = bl.make_parallel_rollout(env, model, config).plan
  elif name == 'beam':
    config = bl.BeamConfig(beam_width=args.beam_width, num_actions=16, budget=budget)
    shard_fn = bl.make_beam_search(env, model, config)
  elif name == 'epase':
    setup = bl.shelf_setup(env, spread=args.epase_spread)
    config = bl.EpaseConfig(weight=args.epase_weight, pop_size=args.pop_size or 16,
                            budget=args.epase_budget,
                            lattice_resolution=setup.lattice_resolution)
    shard_fn = sharding.keyless(bl.make_epase(env, setup.primitives, setup.heuristic, config,
                                              edge_fn=setup.edge_fn).plan)
  else:
    raise ValueError(f'unknown planner {name!r}')
  if mesh is not None:
    return (lambda starts, keys: sharding.plan_sharded_fn(shard_fn, starts, keys, mesh)), config
  jitted = jax.jit(shard_fn)
  return (lambda starts, keys: programs.timed(jitted, starts, keys)), config


def run_rows(result, rounds: int, num_instances: int) -> List[Dict]:
  """Per-run rows; a run's time is estimated as the call's wall time x its iterations / the
  call's largest iteration count (the runs finish at different iterations of one loop). The
  first goal's evaluations, time and cost are the returned path's for a planner whose first
  goal ends its search."""
  r = jax.tree.map(np.asarray, result)
  wall = float(r.wall_time_s)
  most = max(int(r.iterations.max()), 1)
  first = r.first_goal_evaluated is not None
  rows = []
  for j in range(len(r.found)):
    found = bool(r.found[j])
    first_evaluated = int(r.first_goal_evaluated[j]) if first else int(r.evaluated[j])
    first_iterations = int(r.first_goal_iterations[j]) if first else int(r.iterations[j])
    first_cost = float(r.first_goal_cost[j]) if first else float(r.cost[j])
    rows.append({
        'first_goal_evaluated': first_evaluated if found else None,
        'first_goal_time_s_est': wall * first_iterations / most if found else None,
        'first_goal_cost': first_cost if found else None,
        'instance': j % num_instances, 'round': j // num_instances, 'found': bool(r.found[j]),
        'cost': float(r.cost[j]), 'path_length': int(r.path_length[j]),
        'evaluated': int(r.evaluated[j]), 'expanded': int(r.expanded[j]),
        'iterations': int(r.iterations[j]), 'stop': StopReason.name(r.stop_reason[j]),
        'time_s_est': wall * int(r.iterations[j]) / most,
        'overflow': int(r.heap_overflow[j] + r.pool_overflow[j] + r.table_overflow[j])})
  return rows


def first_goal_rows(rows: List[Dict]) -> List[Dict]:
  """rows with evaluated = the evaluations to the first goal where one was found (a run's
  success against the budget: with a smaller budget it returns its first goal's path)."""
  return [dict(r, evaluated=r['first_goal_evaluated']) if r['found'] else r for r in rows]


def summarise(name: str, rows: List[Dict], wall: float, compile_s: float) -> Dict:
  ok = [r for r in rows if r['found']]
  n, k = len(rows), len(ok)
  low, high = stats.wilson_interval(k, n)
  boot_low, boot_high = stats.instance_bootstrap_interval([r['found'] for r in rows],
                                                          [r['instance'] for r in rows])
  mean = stats.mean_or_none
  stops = {}
  for r in rows:
    stops[r['stop']] = stops.get(r['stop'], 0) + 1
  return {
      'planner': name, 'runs': n, 'successes': k, 'success_rate': k / n,
      'ci95_low': low, 'ci95_high': high, 'instance_ci95_low': boot_low,
      'instance_ci95_high': boot_high, 'batch_wall_s': wall, 'compile_s': compile_s,
      'time_s_success_mean': mean([r['time_s_est'] for r in ok]),
      'cost_success_mean': mean([r['cost'] for r in ok]),
      'first_goal_cost_mean': mean([r['first_goal_cost'] for r in ok]),
      'first_goal_evaluated_mean': mean([r['first_goal_evaluated'] for r in ok]),
      'evaluated_success_mean': mean([r['evaluated'] for r in ok]),
      'first_goal_time_s_mean': mean([r['first_goal_time_s_est'] for r in ok]),
      'evaluated_mean': mean([r['evaluated'] for r in rows]),
      'expanded_mean': mean([r['expanded'] for r in rows]),
      'evaluated_per_expanded': (sum(r['evaluated'] for r in rows)
                                 / max(1, sum(r['expanded'] for r in rows))),
      'edges_per_s': sum(r['evaluated'] for r in rows) / max(wall, 1e-9),
      'overflow_runs': sum(r['overflow'] > 0 for r in rows), 'stop_reasons': stops}


def plot(task: str, payload: Dict, path: str) -> None:
  import matplotlib
  matplotlib.use('Agg')
  import matplotlib.pyplot as plt
  rows = payload['runs']
  shelf = task == 'shelf'
  fig, axes = plt.subplots(1, 3 if shelf else 2, figsize=(15 if shelf else 10, 4))
  budgets = payload['curve_budgets']
  for name, curve in payload['success_curve'].items():
    axes[0].plot(budgets, curve, label=name)
  axes[0].set_xscale('log')
  axes[0].set_xlabel('edges evaluated (budget)')
  axes[0].set_ylabel('success rate')
  axes[0].set_title(f'{task}: success against edges evaluated')
  axes[0].legend()
  names = [s['planner'] for s in payload['summary']]
  rates = [s['success_rate'] for s in payload['summary']]
  err = [[max(0.0, s['success_rate'] - s['instance_ci95_low']) for s in payload['summary']],
         [max(0.0, s['instance_ci95_high'] - s['success_rate']) for s in payload['summary']]]
  axes[1].bar(names, rates, yerr=err, capsize=4)
  axes[1].set_ylim(0, 1.05)
  axes[1].set_title(f'success rate, {payload["summary"][0]["runs"]} runs (95% CI, instances '
                    'resampled)')
  if shelf:
    for name, planner_rows in rows.items():
      axes[2].scatter([max(r['expanded'], 1) for r in planner_rows],
                      [max(r['evaluated'], 1) for r in planner_rows], s=8, label=name)
    axes[2].set_xscale('log')
    axes[2].set_yscale('log')
    axes[2].set_xlabel('states expanded')
    axes[2].set_ylabel('edges evaluated')
    axes[2].set_title('evaluated against expanded (per target)')
    axes[2].legend()
  fig.tight_layout()
  fig.savefig(path, dpi=110)
  plt.close(fig)


def markdown(task: str, payload: Dict) -> List[str]:
  """The markdown lines of an open-loop result: the planners' summary rows, the pairwise cost
  ratios and the stop reasons."""
  lines = common.markdown_header(f'Open loop, {task}', payload['provenance'],
                                 f'Settings: {payload["settings"]}')
  rows = []
  for s in payload['summary']:
    row = dict(s)
    row['success'] = (f'{s["successes"]}/{s["runs"]} = {100 * s["success_rate"]:.1f}% '
                      f'[{100 * s["instance_ci95_low"]:.1f}, {100 * s["instance_ci95_high"]:.1f}]')
    row['wilson_runs'] = f'[{100 * s["ci95_low"]:.1f}, {100 * s["ci95_high"]:.1f}]'
    row['original'] = ORIGINAL.get(task, {}).get(s['planner'], '')
    rows.append(row)
  lines.append('Success: 95% interval with the instances resampled (cluster bootstrap: the '
               'rounds of an instance are not independent); wilson_runs treats every run as '
               'independent.\n')
  lines.append(common.markdown_table(rows, [
      'planner', 'success', 'wilson_runs', 'original', 'batch_wall_s', 'time_s_success_mean',
      'first_goal_time_s_mean', 'cost_success_mean', 'first_goal_cost_mean',
      'evaluated_success_mean', 'first_goal_evaluated_mean', 'evaluated_mean', 'expanded_mean',
      'evaluated_per_expanded', 'edges_per_s', 'overflow_runs', 'within_time_limit',
      'compile_s']))
  lines.append('\nSolved runs: time_s_success_mean, cost_success_mean and evaluated_success_mean '
               "are the returned path's (evaluations and time to the search's end), first_goal_* "
               "the first goal's (the same for a planner that stops at its first goal); the "
               'success curve counts a run as solved from its first goal on.\n')
  if 'cost_ratios' in payload:
    names = list(payload['cost_ratios'])
    lines.append('\nPairwise cost ratios (row / column, mean over targets both solved; runs):\n')
    table = [{'planner': a, **{b: (f'{c["mean_ratio"]:.3f} ({c["runs"]})'
                                   if c['mean_ratio'] is not None else '-')
                               for b, c in payload['cost_ratios'][a].items()}} for a in names]
    lines.append(common.markdown_table(table, ['planner'] + names))
  lines.append('\nStop reasons: ' + '; '.join(f'{s["planner"]}: {s["stop_reasons"]}'
                                             for s in payload['summary']))
  return lines


def main():
  parser = build_parser()
  args = parser.parse_args()
  common.check_layout(parser, args.task, args.layout)
  common.check_physics(parser, args.task, args.physics)
  shelf = args.task == 'shelf'
  args.instances = common.task_instances(args.task, args.instances, parser)
  args.rounds = args.rounds or (1 if shelf else 5)
  args.budget = args.budget or (20_000 if shelf else 100_000)
  if shelf and args.devices > 1:
    parser.error("the shelf's 60 s limit uses PACHS's anytime chunks, which need --devices 1")
  if args.time_limit is None and shelf:
    args.time_limit = 60.0
  if args.devices < 1 or args.devices > jax.device_count():
    parser.error(f'--devices must be in 1..{jax.device_count()} (the local devices)')
  if args.devices > 1 and args.time_limit is not None:
    parser.error('--time-limit (anytime chunks) needs --devices 1')
  mesh = sharding.instance_mesh(jax.devices()[:args.devices]) if args.devices > 1 else None
  if args.planners is not None and not [n for n in args.planners.split(',') if n]:
    parser.error('--planners: none named (leave it out for all of the task)')
  names = ([n for n in args.planners.split(',') if n] if args.planners
           else list(SHELF_PLANNERS if shelf else PUSHT_PLANNERS))
  unknown = [n for n in names if n not in PUSHT_PLANNERS + SHELF_PLANNERS
             + tuple(AFTER_GOAL_PLANNERS)]
  if unknown:
    parser.error(f'unknown planner(s) {", ".join(unknown)}; valid: '
                 f'{", ".join(PUSHT_PLANNERS + tuple(AFTER_GOAL_PLANNERS))} (PushT), '
                 f'{", ".join(SHELF_PLANNERS)} (shelf)')
  for name in names:  # a bad search setting before any work
    if name in ('pachs', 'pachs-original') or name in AFTER_GOAL_PLANNERS:
      common.checked(parser, lambda name=name: planner.default_config(
          args.task, 'original' if name == 'pachs-original' else 'pachs',
          budget=args.budget,
          **{k: v for k, v in flags.search_overrides(args).items() if v is not None}))
  common.check_out(parser, args.out)
  label = common.task_label(args.task, args.layout, args.physics)
  out = args.out or f'experiments/results/open_loop_{label}.json'

  env, model = planner.load_model(args.task, backend=args.backend, layout=args.layout,
                                  physics=args.physics)
  starts = env.canonical_instances(args.instances, seed=args.instance_seed)
  index = np.tile(np.arange(args.instances), args.rounds)
  starts = jax.tree.map(lambda x: x[index], starts)
  keys = run_keys(args.seed, args.instances, args.rounds)
  budgets = np.unique(np.geomspace(100, max(args.budget, args.epase_budget if shelf else 0),
                                   40).astype(int)).tolist()
  payload = {'provenance': common.provenance(), 'task': args.task, 'env': env.name,
             'model': envs.spec(args.task).model_task,
             'settings': {'instances': args.instances, 'rounds': args.rounds,
                          'instance_seed': args.instance_seed, 'budget': args.budget,
                          'time_limit_s': args.time_limit, 'devices': args.devices,
                          'physics': args.physics,
                          **({'epase_weight': args.epase_weight,
                              'epase_spread_cells': args.epase_spread}
                             if 'epase' in names else {})},
             'configs': {}, 'summary': [], 'runs': {}, 'curve_budgets': budgets,
             'success_curve': {}}
  for name in names:
    fn, config = make_planner(name, args.task, env, model, args, mesh)
    payload['configs'][name] = common.config_record(config)
    start = time.perf_counter()
    result = fn(starts, keys)  # compiles, then runs (wall_time_s excludes compilation)
    compile_s = time.perf_counter() - start - float(result.wall_time_s)
    rows = run_rows(result, args.rounds, args.instances)
    summary = summarise(name, rows, float(result.wall_time_s), compile_s)
    if args.time_limit and not name.startswith('pachs'):
      summary['within_time_limit'] = float(result.wall_time_s) <= args.time_limit
    print(summary, flush=True)
    payload['summary'].append(summary)
    payload['runs'][name] = rows
    payload['success_curve'][name] = stats.success_curve(first_goal_rows(rows), budgets)
    payload['cost_ratios'] = stats.cost_ratios(payload['runs'])
    common.write_result(out, payload, markdown(args.task, payload))
  plot(args.task, payload, os.path.splitext(out)[0] + '.png')


if __name__ == '__main__':
  main()
