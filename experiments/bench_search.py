"""PACHS search benchmarks, one mode a concept (each writes JSON and a markdown table):

  (no mode)   search throughput against raw batched env steps at the same batch, bytes per
              node and instance, peak memory (`--run-to-budget`: goals never accepted)
  scale       the 150-run PushT-Obs benchmark over 1, 2 and 4 devices, and compaction
  chunked     planning in one call against adaptive chunks (identical results, time)
  buckets     the programs of a new instance-count bucket against padding's search time
  live-lanes  iteration time against live instances, all lanes and compacted sizes

  python experiments/bench_search.py --task pusht-fixed --out bench_search.json
  python experiments/bench_search.py scale --devices 1,2,4 --out bench_scale.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from typing import List, Optional, Sequence, Tuple

import numpy as np

import common
from pachs_jax import argtypes
from pachs_jax.envs import registry


def throughput_parser() -> argparse.ArgumentParser:
  """Search throughput against raw batched env steps at the same batch (the default mode)."""
  parser = argparse.ArgumentParser(prog='bench_search.py',
                                   description=throughput_parser.__doc__)
  parser.add_argument('--task', default='pusht-fixed')
  parser.add_argument('--checkpoint', default=None, help='default: the shipped model, else '
                      'an untrained one')
  parser.add_argument('--instances', default='1,30')
  parser.add_argument('--pop-sizes', default='16,64,256')
  parser.add_argument('--num-actions', type=int, default=8)
  parser.add_argument('--budget', type=int, default=100_000)
  parser.add_argument('--weight', type=float, default=2.0)
  parser.add_argument('--backend', default='mjx', choices=registry.BACKENDS,
                      help='physics of the edges (mujoco-c: MuJoCo C on the CPU threads; warp: '
                      'MuJoCo Warp)')
  parser.add_argument('--raw-steps', type=int, default=20,
                      help='evaluate calls per raw-throughput measurement')
  parser.add_argument('--cpu-threads', type=int, default=None,
                      help='MuJoCo C threads of --backend mujoco-c (default: all CPUs)')
  parser.add_argument('--run-to-budget', action='store_true',
                      help='never accept a goal: every instance spends its whole budget')
  parser.add_argument('--out', default='experiments/results/bench_search.json')
  return parser


def scale_parser() -> argparse.ArgumentParser:
  """The 150-run PushT-Obs benchmark on 1, 2 and 4 devices of one host (and compaction): per
  device count wall time, edges/s, speed-up and whether the results equal the first count's
  (docs/sharding.md); CPU: XLA_FLAGS=--xla_force_host_platform_device_count=4."""
  parser = argparse.ArgumentParser(prog='bench_search.py scale',
                                   description=scale_parser.__doc__)
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
  return parser


def chunked_parser() -> argparse.ArgumentParser:
  """Does planning in chunks (a stop check and a progress report every ~0.3 s) slow the
  search? Programs compiled once, the same search run alternately in one call and in adaptive
  chunks; the results must be identical."""
  parser = argparse.ArgumentParser(prog='bench_search.py chunked',
                                   description=chunked_parser.__doc__)
  parser.add_argument('--task', default='pusht-obs')
  parser.add_argument('--instances', default='0-7')
  parser.add_argument('--budget', type=int, default=20000)
  parser.add_argument('--rounds', type=int, default=8)
  parser.add_argument('--out', default='experiments/results/bench_chunked_search_cpu')
  return parser


def buckets_parser() -> argparse.ArgumentParser:
  """What a new instance count costs `Planner`: the programs of a new bucket (instance counts
  are padded to the next power of two; at least 32 on an accelerator, 1 on a CPU) against the
  search time that padding one instance to a larger bucket would add."""
  parser = argparse.ArgumentParser(prog='bench_search.py buckets',
                                   description=buckets_parser.__doc__)
  parser.add_argument('--task', default='pusht-obs')
  parser.add_argument('--budget', type=int, default=3000)
  parser.add_argument('--buckets', default='1,2,4,32')
  parser.add_argument('--out', default='experiments/results/bench_planner_buckets_cpu')
  return parser


def live_lanes_parser() -> argparse.ArgumentParser:
  """Iteration time against live instances: the open-loop batch (instances x rounds) stepped
  one iteration per call, with the whole batch's lanes throughout and with the compacted
  physics sizes, to show where the loop turns latency-bound as instances finish."""
  parser = argparse.ArgumentParser(prog='bench_search.py live-lanes',
                                   description=live_lanes_parser.__doc__)
  parser.add_argument('--rounds', type=int, default=5, help='runs per instance')
  parser.add_argument('--budget', type=int, default=100_000)
  common.add_common_args(parser, out='experiments/results/engines/live_lanes.json',
                         instances=30, backend=True, layout=True)
  return parser


# the modes' flags by name (None: the default mode, throughput)
PARSERS = {None: throughput_parser, 'scale': scale_parser, 'chunked': chunked_parser,
           'buckets': buckets_parser, 'live-lanes': live_lanes_parser}


def build_parser(mode: Optional[str] = None) -> argparse.ArgumentParser:
  """A mode's flags, None: the default mode's (light modules only: a bad flag is refused before
  JAX loads)."""
  return PARSERS[mode]()


def split_mode(argv: Sequence[str]) -> Tuple[Optional[str], List[str]]:
  """The mode a command line names first (None: the default mode) and the mode's arguments."""
  if argv[:1] and argv[0] in PARSERS:
    return argv[0], list(argv[1:])
  return None, list(argv)


def parse_args(argv: Sequence[str]) -> argparse.Namespace:
  """The flags of the mode a command line names (else of the default mode), parsed."""
  mode, rest = split_mode(argv)
  return build_parser(mode).parse_args(rest)


if __name__ == '__main__':
  parse_args(sys.argv[1:])  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import open_loop  # noqa: E402
import stats  # noqa: E402
from pachs_jax import envs, planner  # noqa: E402
from pachs_jax.runtime import programs, sharding  # noqa: E402
from pachs_jax.sac import actor_critic as ac_lib  # noqa: E402
from pachs_jax.search import pachs  # noqa: E402
from pachs_jax.search.checks import instance_keys  # noqa: E402
from pachs_jax.search.memory import tree_bytes  # noqa: E402
from pachs_jax.search.result import StopReason  # noqa: E402
# pylint: enable=wrong-import-position


def untrained_model(env, hidden=(256, 256, 256), seed=0) -> ac_lib.SacActorCritic:
  """A randomly initialised actor-critic of the task's shapes (throughput only)."""
  config = ac_lib.ModelConfig(task=env.name, observation_size=env.observation_size,
                              action_size=env.action_size, actor_hidden=hidden,
                              critic_hidden=hidden, episode_length=env.episode_length)
  nets = config.networks()
  kp, kq = jax.random.split(jax.random.PRNGKey(seed))
  params = ac_lib.ActorCriticParams(
      normalizer={'mean': jnp.zeros(env.observation_size), 'std': jnp.ones(env.observation_size)},
      policy=nets.policy_init(kp), q=nets.q_init(kq))
  return ac_lib.SacActorCritic(params=params, config=config)


class NeverGoal:
  """env with the goal test switched off (every other method delegated): searches run to their
  budget."""

  def __init__(self, env):
    self._env = env

  def __getattr__(self, name):
    return getattr(self._env, name)

  def is_goal(self, nodes):
    return jnp.zeros(jax.tree.leaves(nodes)[0].shape[:1], bool)

  def evaluate(self, nodes, actions):
    out = self._env.evaluate(nodes, actions)
    return out.replace(is_goal=jnp.zeros_like(out.is_goal))


def peak_memory_bytes(device=None):
  """The device's peak bytes in use so far (None where the backend does not say)."""
  stats = (device or jax.devices()[0]).memory_stats() or {}
  return stats.get('peak_bytes_in_use')


def throughput(argv):
  """The default mode, described by `throughput_parser`."""
  args = build_parser().parse_args(argv)

  try:
    env, model = planner.load_model(args.task, args.checkpoint, args.backend,
                                    args.cpu_threads)
    model_name = args.checkpoint or planner.checkpoint_path(args.task)
  except FileNotFoundError:
    env = envs.make(args.task)
    model, model_name = untrained_model(env), 'untrained 3x256 (no checkpoint yet)'
  result = {'provenance': common.provenance(), 'task': args.task, 'model': model_name,
            'backend': type(env).__name__, 'run_to_budget': args.run_to_budget, 'rows': []}
  starts_all = env.canonical_instances(30)
  if args.run_to_budget:
    env = NeverGoal(env)
  for num_instances, k in [(i, k) for i in map(int, args.instances.split(','))
                           for k in map(int, args.pop_sizes.split(','))]:
    config = planner.default_config(args.task, pop_size=k, num_actions=args.num_actions,
                                    budget=args.budget, weight=args.weight)
    index = np.arange(num_instances) % 30
    starts = jax.tree.map(lambda x: x[index], starts_all)
    search = programs.Programs(pachs.make_search(env, model, config))
    t0 = time.perf_counter()
    out = programs.plan(env, model, starts, config, jax.random.PRNGKey(0), search=search)
    first = time.perf_counter() - t0  # wall_time_s excludes compilation; this includes it
    wall = float(out.wall_time_s)
    evaluated = int(np.sum(out.evaluated))
    iterations = int(np.max(out.iterations))
    raw = common.env_throughput(env, num_instances * k, steps=args.raw_steps, repeats=3)
    state_shape = jax.eval_shape(search.search.init, starts, instance_keys(
        jax.random.PRNGKey(0), num_instances))
    row = {
        'instances': num_instances, 'K': k, 'N': args.num_actions,
        'budget': args.budget,
        'wall_s': wall, 'first_call_s_incl_compile': first, 'evaluated': evaluated,
        'iterations': iterations, 'found': int(np.sum(out.found)),
        'expanded': int(np.sum(out.expanded)),
        'edges_per_s': evaluated / wall,
        'evaluated_per_iteration_per_instance': evaluated / max(iterations, 1) / num_instances,
        'lane_utilization_mean': float(np.mean(out.lane_utilization)),
        'raw_env_steps_per_s_same_batch': raw['env_steps_per_s'],
        'search_over_raw': evaluated / wall / raw['env_steps_per_s'],
        'state_bytes_per_instance': tree_bytes(state_shape) // num_instances,
        'pool_bytes_per_node': (tree_bytes(state_shape.pool)
                                // (num_instances * search.search.sizes.pool)),
        'stop_reasons': np.bincount(np.asarray(out.stop_reason), minlength=7).tolist(),
        'overflow': int(np.sum(out.heap_overflow + out.pool_overflow + out.table_overflow)),
        'device_peak_bytes_so_far': peak_memory_bytes(),
    }
    print(row, flush=True)
    result['rows'].append(row)
    common.write_json(args.out, result)
  md = common.markdown_header(
      f"PACHS search throughput ({args.task}, model: {model_name}, env: {result['backend']}"
      f"{', run to budget (goals never accepted)' if args.run_to_budget else ''})",
      result['provenance'])
  md.append(common.markdown_table(result['rows'], [
      'instances', 'K', 'N', 'budget', 'wall_s', 'first_call_s_incl_compile',
      'evaluated', 'iterations', 'found', 'edges_per_s', 'raw_env_steps_per_s_same_batch',
      'search_over_raw',
      'lane_utilization_mean', 'evaluated_per_iteration_per_instance',
      'state_bytes_per_instance', 'device_peak_bytes_so_far']))
  common.write_result(args.out, result, md)


def scale(argv):
  """The 'scale' mode, described by `scale_parser`."""
  parser = build_parser('scale')
  args = parser.parse_args(argv)
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
  tuned = planner.default_config(args.task, budget=args.budget)
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
    result['configs'][pop_size] = common.config_record(config)
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
  skipped = '\n'.join(f"skipped: {s['devices']} devices at K={s['K']} ({s['reason']})"
                     for s in result['skipped'])
  md = common.markdown_header(
      f"PACHS over devices ({args.task}, {num_runs} runs = {args.instances} instances x "
      f"{args.seeds} seeds, budget {args.budget}, env {result['backend']})",
      result['provenance'], *([skipped] if skipped else []))
  md.append(common.markdown_table(result['rows'], [
      'K', 'devices', 'runs_per_device', 'wall_s', 'iterations_max', 'evaluated',
      'edges_per_s', 'found', 'speedup', 'efficiency', 'identical_found_cost',
      'identical_all_fields']))
  common.write_result(args.out, result, md)
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


def run_lines(title: str, provenance: dict, settings: str) -> list:
  """The first markdown lines of a result that keeps its provenance at its top level: the
  title, the command, then device, revision and date with the settings in one sentence."""
  return [f'# {title}', '', provenance['command'], '',
          f'device {provenance["device"]}, revision {provenance["git_revision"]}, '
          f'{provenance["date_utc"]} UTC; {settings}', '']


def chunked(argv):
  """The 'chunked' mode, described by `chunked_parser`."""
  args = build_parser('chunked').parse_args(argv)
  plans = planner.Planner(args.task, budget=args.budget, cache=False)
  instances = argtypes.instance_indices(args.instances, 30)
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
  table = common.markdown_table(rows, ['mode', 'median_search_s', 'min_search_s', 'chunks',
                                       'evaluations', 'found'])
  common.write_result(args.out + '.json', payload, run_lines(
      'Search in one call vs adaptive chunks', payload,
      f'{args.task} instances {args.instances}, budget {args.budget}, {args.rounds} alternating '
      f'rounds after a warm-up; results identical: {same}') + [table])
  print(table)
  print('identical results:', same)


def buckets(argv):
  """The 'buckets' mode, described by `buckets_parser`."""
  args = build_parser('buckets').parse_args(argv)
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
  table = common.markdown_table(rows, ['bucket', 'first_call_s', 'search_s_median',
                                       'evaluated', 'stop'])
  common.write_result(args.out + '.json', payload, run_lines(
      'One instance planned in buckets of several sizes', payload,
      f'{args.task} instance 0, budget {args.budget}, cache off; first_call_s: the first plan '
      'of a bucket, compilation included; search_s_median: 3 later plans, compilation '
      'excluded') + [table])
  print(table)


def trace_iterations(search, starts, keys, compacted: bool) -> list:
  """One row per iteration: live instances before it, physics lanes, wall ms; the loop of
  `lanes_for(state)` (compaction), else of all I * K lanes."""
  num = keys.shape[0]
  live = jax.device_put(np.ones(num, bool))
  state = search.init(starts, keys, live)
  k = search.config.pop_size
  sizes = {}
  rows = []
  while True:
    active = int(np.sum(np.asarray(state.active)))
    if active == 0:
      break
    size = search.lanes_for(state) if compacted else None
    if size not in sizes:  # compile outside the clock
      began = time.perf_counter()
      lowered = jax.jit(lambda s, n, size=size: search.loop(s, n, size, False),
                        donate_argnums=0).lower(state, np.int32(1))
      sizes[size] = (lowered.compile(), time.perf_counter() - began)
    began = time.perf_counter()
    state = sizes[size][0](state, np.int32(1))
    jax.block_until_ready(state.active)
    rows.append({'live': active, 'lanes': (size and size.size) or num * k,
                 'useful_lanes': active * k,
                 'ms': 1e3 * (time.perf_counter() - began)})
  return rows, {str(s): c for s, (_, c) in sizes.items()}


def live_summary(rows: list, num: int) -> list:
  """Iteration time and wall share by live fraction (bins of the batch's instances)."""
  edges = [1.0, 0.75, 0.5, 0.25, 0.1, 0.0]
  total = sum(r['ms'] for r in rows)
  out = []
  for high, low in zip(edges[:-1], edges[1:]):
    part = [r for r in rows if low * num < r['live'] <= high * num]
    if not part:
      continue
    ms = [r['ms'] for r in part]
    out.append({'live_fraction': f'({low:g}, {high:g}]', 'iterations': len(part),
                'ms_per_iteration_median': float(np.median(ms)),
                'share_of_wall': sum(ms) / total,
                'lanes_used': sum(r['useful_lanes'] for r in part) / sum(r['lanes'] for r in part)})
  return out


def live_lanes(argv):
  """The 'live-lanes' mode, described by `live_lanes_parser`."""
  args = build_parser('live-lanes').parse_args(argv)
  env, model = planner.load_model('pusht-obs', backend=args.backend, layout=args.layout)
  config = planner.default_config('pusht-obs', budget=args.budget,
                                  **planner.accelerator_settings(False))
  search = pachs.make_search(env, model, config)
  canonical = env.canonical_instances(args.instances)
  starts = jax.tree.map(lambda x: np.concatenate([np.asarray(x)] * args.rounds), canonical)
  keys = open_loop.run_keys(0, args.instances, args.rounds)
  result = {'provenance': common.provenance(), 'settings': vars(args), 'config': repr(config),
            'env': type(env).__name__, 'modes': {}}
  num = keys.shape[0]
  for mode, compacted in (('all lanes', False), ('compacted sizes', True)):
    rows, compile_s = trace_iterations(search, starts, keys, compacted)
    result['modes'][mode] = {'iterations': rows, 'compile_s': compile_s,
                             'wall_s': sum(r['ms'] for r in rows) / 1e3,
                             'summary': live_summary(rows, num)}
    print(mode, result['modes'][mode]['wall_s'], result['modes'][mode]['summary'], flush=True)
  md = common.markdown_header(
      f'PACHS iteration time against live instances ({env.name}, {num} runs, '
      f'{type(env).__name__})', result['provenance'], f'Config: {result["config"]}')
  for mode, m in result['modes'].items():
    md += [f'## {mode}: {m["wall_s"]:.2f} s over {len(m["iterations"])} iterations '
           f'(compile {m["compile_s"]})\n',
           common.markdown_table(m['summary'], ['live_fraction', 'iterations',
                                                'ms_per_iteration_median', 'share_of_wall',
                                                'lanes_used']), '']
  common.write_result(args.out, result, md)


MODES = {None: throughput, 'scale': scale, 'chunked': chunked, 'buckets': buckets,
         'live-lanes': live_lanes}


def main(argv=None):
  mode, argv = split_mode(sys.argv[1:] if argv is None else argv)
  return MODES[mode](argv)


if __name__ == '__main__':
  main()
