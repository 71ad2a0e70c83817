"""Writes docs/results.md and the README's headline table from the committed result files.

  python experiments/report.py            # rewrite both
  python experiments/report.py --check    # exit 1 where either differs from the files
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import sys
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import stats

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RESULTS = 'experiments/results'
README = 'README.md'
RESULTS_MD = 'docs/results.md'
BEGIN, END = '<!-- results:begin -->', '<!-- results:end -->'
LAYOUTS = ('gate', 'slot', 'wall', 'detour', 'two-gaps')
CURVE_POINTS = (1000, 3000, 10000, 30000, 100000)  # evaluations; the nearest budget of a curve
PLACEHOLDER_NOTE = 'not measured yet; the maintainer runs `{command}`'


class ReportError(Exception):
  """A result file the report reads is missing, not JSON, or lacks what a section needs."""


class Sources:
  """Reads result files under ROOT and remembers which ones a report cites (in order)."""

  def __init__(self, root: str = ROOT):
    self.root = root
    self.cited: List[str] = []

  def exists(self, name: str) -> bool:
    """Whether experiments/results/NAME exists."""
    return os.path.exists(os.path.join(self.root, RESULTS, name))

  def load(self, name: str) -> Dict:
    """The payload of experiments/results/NAME, recorded as cited."""
    path = f'{RESULTS}/{name}'
    if path not in self.cited:
      self.cited.append(path)
    return read_result(self.root, path)


def read_result(root: str, path: str) -> Dict:
  """The JSON payload at root/path; ReportError naming the file when it is missing or not a
  JSON object."""
  try:
    with open(os.path.join(root, path)) as f:
      payload = json.load(f)
  except FileNotFoundError:
    raise ReportError(f'{path}: missing (the report reads it)') from None
  except (json.JSONDecodeError, UnicodeDecodeError) as err:
    raise ReportError(f'{path}: not valid JSON ({err})') from None
  if not isinstance(payload, dict):
    raise ReportError(f'{path}: not a result (a JSON object), got {type(payload).__name__}')
  return payload


def read_section(title: str, section: Callable, src: 'Sources'):
  """section(src), with a missing key or a value of the wrong kind in its files reported as a
  ReportError naming the section and the last file it read."""
  try:
    return section(src)
  except (KeyError, TypeError, IndexError, ValueError, AttributeError) as err:
    last = src.cited[-1] if src.cited else 'no file'
    raise ReportError(f'section {title!r} (last read {last}): {type(err).__name__} {err}') \
        from None


# formatting -------------------------------------------------------------------------------------

def pct(rate: Optional[float]) -> str:
  """A rate in [0, 1] as a percentage with at most one decimal ('96.7%', '100%')."""
  if rate is None:
    return '-'
  text = f'{100 * rate:.1f}'
  return (text[:-2] if text.endswith('.0') else text) + '%'


def ci(low: Optional[float], high: Optional[float]) -> str:
  """A 95% interval of rates as ' [a, b]' in percent, '' where it is a point."""
  if low is None or high is None or abs(high - low) < 1e-9:
    return ''
  return f' [{100 * low:.0f}, {100 * high:.0f}]'


def num(value: Optional[float], digits: int = 3) -> str:
  """A number with `digits` significant digits and thousands separators; '-' for None."""
  if value is None:
    return '-'
  if abs(value) >= 10 ** digits:
    return f'{value:,.0f}'
  return f'{value:,.{digits}g}'


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
  """A markdown table."""
  lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
  lines += ['| ' + ' | '.join(str(c) for c in row) + ' |' for row in rows]
  return '\n'.join(lines)


def link(path: str, from_dir: str) -> str:
  """A markdown link to repository path `path` from a document in `from_dir`."""
  return f'[`{os.path.basename(path)}`]({os.path.relpath(path, from_dir)})'


def short_revision(revision: str) -> str:
  """A git revision cut to 7 hex digits, keeping a '+dirty' mark."""
  base, plus, rest = revision.partition('+')
  return (base[:7] if re.fullmatch(r'[0-9a-f]{8,40}', base) else base) + plus + rest


def runs_of(payload: Dict) -> List[Dict]:
  """The provenance records of a result file: its own, or each merged source's."""
  prov = payload.get('provenance', {})
  return prov.get('merged_from') or [prov]


def provenance_lines(path: str, payload: Dict, from_dir: str) -> List[str]:
  """Markdown bullet lines naming a cited file and the device, revision and command of each run
  in it."""
  lines = [f'- {link(path, from_dir)}']
  seen = set()
  for run in runs_of(payload):
    key = (run.get('device'), run.get('git_revision'), run.get('command'))
    if key in seen:
      continue
    seen.add(key)
    lines.append(f'  - {run.get("device", "?")}; revision {short_revision(run.get("git_revision", "?"))}'
                 f'; `{run.get("command", "?")}`')
  return lines


# sections ---------------------------------------------------------------------------------------

def summary_of(payload: Dict, planner: str) -> Optional[Dict]:
  """The summary row of a planner in an open- or closed-loop result, None where absent."""
  return next((row for row in payload['summary'] if row['planner'] == planner), None)


def solved(row: Optional[Dict]) -> str:
  """'n/N (x%)' of an open-loop summary row."""
  if row is None:
    return '-'
  return f'{row["successes"]}/{row["runs"]} ({pct(row["success_rate"])})'


def curve_at(payload: Dict, planner: str, budget: int) -> Tuple[int, Optional[float]]:
  """(the curve budget nearest `budget`, the planner's share of runs solved within it)."""
  budgets = payload['curve_budgets']
  index = min(range(len(budgets)), key=lambda i: abs(budgets[i] - budget))
  curve = payload['success_curve'].get(planner)
  return budgets[index], (curve[index] if curve else None)


def cost_ratio(payload: Dict, a: str, b: str) -> str:
  """Mean cost of planner a over b on the runs both solved."""
  ratio = payload.get('cost_ratios', {}).get(a, {}).get(b, {}).get('mean_ratio')
  return '-' if ratio is None else f'{ratio:.2f}'


OPEN_PLANNERS = (('pachs', 'PACHS'), ('parallel', 'parallel rollout (256)'),
                 ('single', 'policy alone'), ('beam', 'beam search (64 x 16)'),
                 ('pachs-original', 'original PACHS'))
VARIANTS = (('pachs', 'default'), ('pachs-start', 'chains restart at the start'),
            ('pachs-share0.5', 'rollout share 0.5'), ('pachs-h8', 'edges of 8, no chains'),
            ('pachs-original', 'original (one-step edges)'))


def open_loop_layouts(src: Sources) -> str:
  """PushT-Obs, the five layouts: success, curves, costs and times, and the PACHS variants."""
  payloads = {layout: src.load(f'open_loop_pusht-obs_{layout}.json') for layout in LAYOUTS}
  first = payloads['gate']['settings']
  success = [[layout] + [solved(summary_of(p, name)) for name, _ in OPEN_PLANNERS]
             + [cost_ratio(p, 'pachs', 'parallel')] for layout, p in payloads.items()]
  budgets = [curve_at(payloads['gate'], 'pachs', b)[0] for b in CURVE_POINTS]
  curves = [[layout] + [f'{pct(curve_at(p, "pachs", b)[1])} / {pct(curve_at(p, "parallel", b)[1])}'
                        for b in CURVE_POINTS] for layout, p in payloads.items()]
  effort = []
  for layout, p in payloads.items():
    for name, label in OPEN_PLANNERS[:2]:
      row = summary_of(p, name)
      effort.append([layout, label, num(row['cost_success_mean']), num(row['evaluated_mean']),
                     num(row['batch_wall_s'])])
  variants = [[layout] + [solved(summary_of(p, name)) for name, _ in VARIANTS]
              for layout, p in payloads.items()]
  return '\n\n'.join([
      'PACHS here is its default before the first goal\'s path was improved and before novel '
      'restarts weighed cells by 1 / sqrt(nodes) (the first goal ends the search, cells drawn '
      'alike): the baselines and the variants that chose the default\'s edges and chains. The '
      'default of today is in [PushT-Obs suite at the default](#pusht-obs-suite-at-the-default). '
      f'{first["instances"]} canonical instances x {first["rounds"]} seeds = '
      f'{first["instances"] * first["rounds"]} runs per planner and layout, '
      f'{first["budget"]:,} edge evaluations per run, each planner\'s runs in one batched call. '
      'Success with the 95% interval from resampling the instances in the files; cost ratio '
      'over the runs both solved.',
      table(['layout'] + [label for _, label in OPEN_PLANNERS] + ['PACHS / parallel cost'],
            success),
      'Share of runs solved within a number of edge evaluations, PACHS / parallel rollout:',
      table(['layout'] + [f'{b:,}' for b in budgets], curves),
      'Path cost, effort and time (runs of one command shared the GPU as concurrent processes, '
      'so the wall times are upper bounds):',
      table(['layout', 'planner', 'mean cost (solved)', 'mean evaluations', 'wall of the call (s)'],
            effort),
      'The PACHS variants behind the PushT-Obs defaults (docs/task_defaults.md), same runs:',
      table(['layout'] + [label for _, label in VARIANTS], variants)])


def open_loop_beyond(src: Sources) -> str:
  """PACHS and the parallel rollout on a second instance set and on two held-out layouts."""
  files = [(f'{layout}, instance set 1', f'instance_set1/open_loop_pusht-obs_{layout}_set1.json')
           for layout in LAYOUTS]
  files += [(f'{layout} (held out)', f'heldout_gpu/open_loop_pusht-obs_{layout}.json')
            for layout in ('gate-mirror', 'wall-right')]
  rows = []
  for label, name in files:
    p = src.load(name)
    curve = ', '.join(f'{pct(curve_at(p, "pachs", b)[1])} / {pct(curve_at(p, "parallel", b)[1])}'
                      for b in CURVE_POINTS[1:4])
    rows.append([label, solved(summary_of(p, 'pachs')), solved(summary_of(p, 'parallel')), curve,
                 cost_ratio(p, 'pachs', 'parallel')])
  budgets = ' / '.join(f'{curve_at(p, "pachs", b)[0]:,}' for b in CURVE_POINTS[1:4])
  return '\n\n'.join([
      'The same protocol on instances drawn by the same rules with another seed, and on two '
      'layouts held out from every choice of defaults (the gate mirrored, the wall moved right); '
      'PACHS as in the section above, before the first goal\'s path was improved. The default '
      'of today on the second instance set (detour, wall) and on the held-out layouts: [Rarely '
      'visited cells first](#rarely-visited-cells-first).',
      table(['layout', 'PACHS', 'parallel rollout', f'solved within {budgets} (PACHS / parallel)',
             'PACHS / parallel cost'], rows)])


def policy_per_layout(src: Sources) -> str:
  """What the policy alone solves on each layout (the layouts are built so that it fails)."""
  p = src.load('eval_layouts_cpu.json')
  rows = [[r['layout'], r['kind'], r['start_region'], f'{r["policy_solved"]}/{r["instances"]}']
          for r in p['rows']]
  return '\n\n'.join([
      'One deterministic rollout of the PushT-Fixed policy per canonical instance, MuJoCo C physics:',
      table(['layout', 'the T must', 'start region', 'policy alone'], rows)])


def open_loop_tasks(src: Sources) -> str:
  """PushT-Fixed, PushT-Rand and Panda-Shelf: every planner's success, cost, effort and time."""
  rows = []
  notes = []
  for task, name in (('PushT-Fixed', 'open_loop_pusht-fixed.json'),
                     ('PushT-Rand', 'open_loop_pusht-rand.json'),
                     ('Panda-Shelf', 'open_loop_shelf.json')):
    p = src.load(name)
    s = p['settings']
    notes.append(f'{task}: {s["instances"]} instances x {s["rounds"]} '
                 f'seed{"s" * (s["rounds"] > 1)}, {s["budget"]:,} '
                 'evaluations per run' + (f', {s["time_limit_s"]:g} s limit per call'
                                          if s.get('time_limit_s') else ''))
    for row in p['summary']:
      rows.append([task, row['planner'], solved(row) + ci(row.get('instance_ci95_low'),
                                                           row.get('instance_ci95_high')),
                   num(row['cost_success_mean']), num(row['evaluated_mean']),
                   num(row.get('evaluated_per_expanded')), num(row['batch_wall_s'])])
  return '\n\n'.join([
      '; '.join(notes) + '. ePA*SE on the shelf runs its own budget (its config in the file).',
      table(['task', 'planner', 'success', 'mean cost (solved)', 'mean evaluations',
             'evaluations per expansion', 'wall of the call (s)'], rows)])


def closed_row(label: str, p: Dict, planner: str) -> List[str]:
  """A closed-loop table row: success with its interval, edges and goal answers per query."""
  row = summary_of(p, planner)
  goal = row.get('goal_answers')
  queries = (row['queries_per_episode_mean'] * row['episodes']
             if row.get('queries_per_episode_mean') else None)
  return [label, f'{pct(row["success_rate"])}{ci(row["ci95_low"], row["ci95_high"])}',
          num(row.get('evaluations_per_query_mean')),
          f'{goal:,} / {queries:,.0f}' if goal is not None and queries else '-']


def closed_loop(src: Sources) -> str:
  """Plans executed in a simulated world: PushT-Fixed/-Rand, the PushT-Obs layouts, the answer
  rule of an unfinished query."""
  header = ['', 'success', 'edges per query and episode', 'goal answers / queries']
  easy = []
  for task, name in (('PushT-Fixed', 'closed_loop_pusht-fixed.json'),
                     ('PushT-Rand', 'closed_loop_pusht-rand.json')):
    p = src.load(name)
    easy += [closed_row(f'{task}, {row["planner"]}', p, row['planner']) for row in p['summary']]
  obs = []
  for layout in LAYOUTS:
    obs.append(closed_row(f'{layout}, PACHS', src.load(f'closed_loop_pusht-obs_{layout}_pachs.json'),
                          'pachs'))
    if layout in ('gate', 'wall', 'detour'):
      obs.append(closed_row(f'{layout}, parallel rollout',
                            src.load(f'closed_loop_pusht-obs_{layout}_parallel.json'), 'parallel'))
  world = [closed_row(f'wall, {label}', src.load(f'closed_loop_pusht-obs_wall_planner-world_{name}.json'),
                      name) for name, label in (('pachs', 'PACHS'), ('parallel', 'parallel rollout'))]
  answers = [closed_row(f'{layout}, {rule}',
                        src.load(f'closed_loop_pusht-obs_{layout}_answer-{rule}.json'), 'pachs')
             for layout, rules in (('gate', ('best_f', 'min_h', 'min_cost')),
                                   ('wall', ('min_h', 'min_cost')))
             for rule in rules]
  s = src.load('closed_loop_pusht-obs_wall_pachs.json')['settings']
  return '\n\n'.join([
      f'{s["instances"]} instances x {s["rounds"]} rounds = {s["instances"] * s["rounds"]} '
      f'episodes per planner; each query gets {s["query_time"]:g} s of wall clock for all '
      f'episodes together, {s["execute"]} actions of each plan are executed, at most '
      f'{s["max_queries"]} queries; success is judged in the world (95% intervals over the '
      'instances). The plans are made in MJX (float32) and executed in MuJoCo C (float64) '
      'unless stated.',
      table(header, easy),
      'PushT-Obs layouts (parallel rollout runs exist for three of them):',
      table(header, obs),
      'Wall with the plans executed in the planners\' own physics (`closed_loop.py --world '
      'planner`), which measures the search rather than the transfer of a float32 plan:',
      table(header, world),
      'The answer of an unfinished query (`realtime_answer`; chains restarting at the start, '
      'the default when these ran):',
      table(header, answers)])


def answer_counts(row: Dict) -> str:
  """A replanning session's answers by kind ('goal path 510, partial 548, ...')."""
  answers = row.get('answers')
  if not answers:
    return '-'
  names = (('goal_path', 'goal'), ('partial_path', 'partial'), ('remainder', 'remainder'),
           ('policy', 'policy'), ('none', 'none'))
  return ', '.join(f'{label} {answers[name]:,}' for name, label in names)


def closed_loop_sessions(src: Sources) -> str:
  """The closed loop on one GPU with Warp planners: PACHS replanning through `replan.Session`
  against the parallel rollout, and the two layouts measured before the table-square fix."""
  folder = 'closed_loop_gpu'
  rows = []
  for layout in LAYOUTS + ('gate-mirror', 'wall-right'):
    p = src.load(f'{folder}/{layout}_pachs.json')
    r = (src.load(f'{folder}/{layout}_parallel.json')
         if src.exists(f'{folder}/{layout}_parallel.json') else None)
    a, b = summary_of(p, 'pachs'), r and summary_of(r, 'parallel')
    ratio = (num(a['evaluations_per_query_mean'] / b['evaluations_per_query_mean'], 2)
             if b else '-')
    rows.append([layout, f'{pct(a["success_rate"])}{ci(a["ci95_low"], a["ci95_high"])}',
                 f'{pct(b["success_rate"])}{ci(b["ci95_low"], b["ci95_high"])}' if b else '-',
                 num(a['evaluations_per_query_mean']), ratio,
                 num(a['iterations_per_query_mean']), num(a['follow_s_mean'], 2),
                 answer_counts(a), str(a['empty_search']['t_off_table_queries'])])
  before = []
  for layout in ('detour', 'wall-right'):
    for name, label in (('pachs', 'PACHS, session'), ('pachs-alone', 'PACHS, its path alone'),
                        ('parallel', 'parallel rollout')):
      p = src.load(f'{folder}/before_table_fix/{layout}_{name}.json')
      row = summary_of(p, 'parallel' if name == 'parallel' else 'pachs')
      empty = row.get('empty_search') or {}
      before.append([f'{layout}, {label}',
                     f'{pct(row["success_rate"])}{ci(row["ci95_low"], row["ci95_high"])}',
                     num(row['evaluations_per_query_mean']), answer_counts(row),
                     str(empty.get('queries', '-'))])
  p = src.load(f'{folder}/gate_pachs.json')
  s, prov = p['settings'], p['provenance']
  return '\n\n'.join([
      f'One GPU ({prov["device"]}), Warp planners, MuJoCo C worlds; each planner alone on the '
      f'GPU (`{folder}/run.sh`). {s["instances"]} instances x {s["rounds"]} rounds per layout '
      f'and planner, {s["query_time"]:g} s per query for all episodes together, '
      f'{s["execute"]} actions executed per query, at most {s["max_queries"]} queries; 95% '
      'intervals over the instances. PACHS replans through `replan.Session`: each answer is the '
      "best of the search's path, the last answer's unexecuted remainder and the policy's "
      "rollout, simulated in the planner's physics (docs/closed_loop.md). gate-mirror and "
      'wall-right are the held-out layouts. The slot rollout run was cut by the command\'s time '
      'limit.',
      table(['layout', 'PACHS', 'parallel rollout', 'PACHS edges per query and episode',
             'PACHS / rollout edges', 'PACHS iterations per query',
             'candidates followed (s per query)', 'PACHS answers',
             'queries with the T off the table'], rows),
      'Before an edge could start with the T outside the table square (`pusht.stays_on_table`), '
      'every edge from such a world state was invalid: the search answered with nothing '
      '(empty searches: queries whose search generated no node but the start):',
      table(['', 'success', 'edges per query and episode', 'answers', 'empty searches'],
            before)])


def command_walls(p: Dict, count: int) -> Tuple[Optional[float], List[float], str]:
  """(cold wall, warm walls, search summary) of the real `pachs plan` command of `count`
  instances in a bench_startup result."""
  rows = [c for c in p['commands'] if c['instances'] == count]
  cold = next((c['process_wall_s'] for c in rows if c['run'] == 'cold'), None)
  warm = [c['process_wall_s'] for c in rows if c['run'] == 'warm']
  return cold, warm, next((c['summary'] for c in rows if c['run'] == 'warm'), '')


def span(values: Sequence[float]) -> str:
  """'a-b s' of the values (or 'a s' for one)."""
  if not values:
    return '-'
  low, high = min(values), max(values)
  return f'{low:.1f} s' if f'{low:.1f}' == f'{high:.1f}' else f'{low:.1f}-{high:.1f} s'


def placeholder(p: Dict) -> Optional[str]:
  """The note of a placeholder result file, None for a measured one."""
  return PLACEHOLDER_NOTE.format(command=p['measure_with']) if p.get('placeholder') else None


def cpu_claims(src: Sources) -> Dict[str, str]:
  """The CPU main job's and the test suite's wall time on 2 cores, as README phrases."""
  job = src.load('cpu_main_job.json')
  suite = src.load('test_suite_cpu.json')
  out = {}
  if placeholder(job):
    out['job'] = placeholder(job)
  else:
    cold, warm, _ = command_walls(job, 30)
    out['job'] = (f'{cold:.1f} s cold, {span(warm)} warm ({job["provenance"]["device"]}, '
                  f'{job["provenance"]["host_cpus"]} CPUs)')
  if placeholder(suite):
    out['suite'] = placeholder(suite)
  else:
    cold = ', an empty compilation cache' if 'cache empty' in suite['provenance'].get('note', '') else ''
    out['suite'] = (f'{suite["process_wall_s"] / 60:.1f} min ({suite["summary"]}; '
                    f'{suite["provenance"]["host_cpus"]} CPUs{cold})')
  return out


def speed(src: Sources) -> str:
  """Start-up of `pachs plan`, search throughput, CPU against GPU edges, compaction, devices."""
  start = src.load('bench_startup_gpu.json')
  rows = []
  for count in (30, 1):
    cold, warm, summary = command_walls(start, count)
    rows.append([f'`pachs plan --task {start["task"]}`, {count} instance{"s" * (count > 1)}',
                 f'{cold:.1f} s', span(warm), summary.split(';')[1].strip() if ';' in summary
                 else summary])
  claims = cpu_claims(src)
  search = []
  for name in ('bench_search_budget_i1_150.json', 'bench_search_budget_i30.json'):
    for r in src.load(name)['rows']:
      search.append([r['instances'], r['K'], num(r['evaluated']), num(r['wall_s']),
                     num(r['edges_per_s']), f'{r["search_over_raw"]:.2f}',
                     pct(r['lane_utilization_mean'])])
  search.sort(key=lambda r: (r[0], r[1]))
  backends = src.load('bench_backends.json')
  engines = [[r['K'], num(r['gpu_mjx_edges_per_s']), num(r['cpu_mujoco_c_edges_per_s']),
              f'{r["gpu_over_cpu"]:.1f}x', f'{r["cpu_search_over_raw"]:.2f}']
             for r in backends['rows']]
  cpu = src.load('bench_cpu_backend.json')['evaluate']
  by_backend = {r['backend']: r for r in cpu}
  compact = src.load('bench_compact.json')['rows'][0]
  baseline = src.load('bench_compact_baseline.json')['rows'][0]
  scale = []
  for name in ('bench_scale.json', 'bench_scale_k1024_2048.json'):
    for r in src.load(name)['rows']:
      scale.append([r['K'], r['devices'], num(r['wall_s']), f'{r["speedup"]:.2f}x', r['found'],
                    f'`{name}`'])
  return '\n\n'.join([
      'Process wall of the real command, cold (empty compilation cache) and warm, one GPU:',
      table(['command', 'cold', 'warm', 'search'], rows),
      f'On a CPU-only machine (MuJoCo C edges, 20,000 evaluations per instance), '
      f'`pachs plan --task pusht-obs`: {claims["job"]}. The test suite '
      f'(`python -m pytest`): {claims["suite"]}.',
      'Search throughput when every instance spends its whole budget (goals never accepted), '
      'against `env.evaluate` alone at the same batch:',
      table(['instances', 'K', 'edges evaluated', 'wall (s)', 'edges/s', 'search / raw',
             'lanes used'], search),
      f'GPU edges (MJX) against CPU edges (MuJoCo C on {backends["cpu_threads"]} threads of the '
      f'same host), PushT-Obs, {backends["rows"][0]["instances"]} instances at '
      f'{backends["rows"][0]["budget"]:,} evaluations:',
      table(['K', 'GPU edges/s', 'CPU edges/s', 'GPU / CPU', 'CPU search / raw'], engines),
      f'On a 2-core CPU, MuJoCo C evaluates a batch of {by_backend["mujoco-c"]["batch"]} PushT '
      f'edges in {1000 * by_backend["mujoco-c"]["median_s"]:.1f} ms, MJX on the CPU in '
      f'{by_backend["mjx (cpu)"]["median_s"]:.1f} s ({by_backend["speed-up"]["edges_per_s"]:,.0f}x).',
      f'Compaction (simulating only the live instances\' edges), {compact["runs_per_device"]} '
      f'PushT-Obs runs, K {compact["K"]}: {num(compact["wall_s"])} s against '
      f'{num(baseline["wall_s"])} s without ({compact["found"]} and {baseline["found"]} found).',
      'The instance axis over several GPUs of one host (150 PushT-Obs runs, K as given):',
      table(['K', 'GPUs', 'wall (s)', 'speed-up', 'found', 'file'], scale)])


def warp_physics(src: Sources) -> str:
  """MuJoCo Warp physics: engines, the open-loop suite beside MJX-JAX, `pachs plan` start-up,
  search throughput over the raw step and iteration time against live instances."""
  engines = src.load('engines/bench_engines_h200.json')
  ratio = [[r['layout'], r['engine'], f'{r["worlds"]:,}', f'{r["over_mujoco_c"]:.1f}x']
           for r in engines['ratios'] if r['worlds'] == 16384]
  suite = []
  for layout in LAYOUTS:
    warp = src.load(f'engines/open_loop_{layout}_warp.json')
    mjx = src.load(f'open_loop_pusht-obs_{layout}.json')
    for planner, label in (('pachs', 'PACHS'), ('parallel', 'parallel rollout')):
      w, m = summary_of(warp, planner), summary_of(mjx, planner)
      suite.append([layout, label, solved(w), num(w['batch_wall_s']), solved(m),
                    num(m['batch_wall_s'])])
  same = src.load('engines/open_loop_two-gaps_mjx.json')
  same_rows = [[label, solved(summary_of(same, planner)),
                num(summary_of(same, planner)['batch_wall_s'])]
               for planner, label in (('pachs', 'PACHS'), ('parallel', 'parallel rollout'))]
  pop = []
  for name in ('open_loop_two-gaps_warp', 'open_loop_two-gaps_warp_k128',
               'open_loop_two-gaps_warp_k256', 'open_loop_two-gaps_warp_k512'):
    payload = src.load(f'engines/{name}.json')
    row = summary_of(payload, 'pachs')
    k = re.search(r'pop_size=(\d+)', payload['configs']['pachs']).group(1)
    pop.append([k, solved(row), num(row['batch_wall_s']), num(row['evaluated_mean']),
                num(row['cost_success_mean'])])
  tail = []
  for layout in LAYOUTS + ('gate-mirror', 'wall-right'):
    row = [layout]
    for suffix in ('', '_compact', '_widen', '_k128'):
      name = f'engines/open_loop_{layout}_warp{suffix}.json'
      if not src.exists(name):
        row += ['-', '-', '-']
        continue
      payload = src.load(name)
      r = summary_of(payload, 'pachs')
      late = 'Warp compiled its kernels' in payload['provenance'].get('note', '')
      row += [solved(r), num(r['batch_wall_s']) + ' (kernel compile)' * late,
              num(r['cost_success_mean'])]
    tail.append(row)
  start = src.load('engines/plan_startup_warp.json')
  walls = {}
  for r in start['walls']:
    if r['run'] == 'B':
      walls.setdefault(r['label'], []).append(r['process_wall_s'])
  plan_rows = [[label, span(walls[key])] for label, key in (
      ('first run on a fresh machine (Warp compiles its kernels)', 'first_on_fresh_machine'),
      ('cold (JAX caches empty, Warp kernels cached)', 'cold'), ('warm', 'warm'),
      ('warm, XLA_PYTHON_CLIENT_PREALLOCATE=false', 'warm, XLA_PYTHON_CLIENT_PREALLOCATE=false'))]
  search_s = lambda r: float(re.search(r'search time ([0-9.]+) s', r['printed']).group(1))
  now = src.load('engines/plan_startup_improve_warp.json')['runs']
  now_rows = [[label, span([r['process_wall_s'] for r in now if r['run'] == key]),
               span([search_s(r) for r in now if r['run'] == key])]
              for label, key in (('first run on a fresh machine (Warp compiles its kernels)',
                                  'first run on a fresh machine'),
                                 ('cold', 'cold'), ('warm', 'warm'))]
  h100 = src.load('engines/plan_startup_h100.json')
  h100_rows = []
  for job, label, keys in (
      ('D', 'first run on a fresh machine (Warp compiles its kernels)', ('first_on_fresh_machine',)),
      ('D', 'cold', ('cold',)), ('D', 'warm', ('warm1', 'warm2', 'warm3')),
      ('C', 'cold, packages without compiled bytecode', ('cold',)),
      ('C', 'warm, packages without compiled bytecode', ('warm1', 'warm2', 'warm3'))):
    chosen = [r for r in h100['runs'] if r['job'] == job and r['run'] in keys]
    h100_rows.append([label, span([r['process_wall_s'] for r in chosen]),
                      span([search_s(r) for r in chosen])])
  h100_imports = h100['imports_s']
  transfer = src.load('engines/plan_startup_first_transfer.json')['runs']
  transfer_rows = []
  for label, prefix in (('without', 'without'), ('with the first transfer in a thread', 'with')):
    chosen = [r for r in transfer if re.fullmatch(prefix + r'\d', r['run'])]
    outside = [r['process_wall_s'] - float(re.search(r'([0-9.]+) s with compilation',
                                                     r['printed']).group(1)) for r in chosen]
    transfer_rows.append([label, span([r['process_wall_s'] for r in chosen]),
                          f'{sum(r["process_wall_s"] for r in chosen) / len(chosen):.1f} s',
                          f'{sum(outside) / len(outside):.1f} s'])
  h100_warm = next(p for p in h100['phases'] if p['label'] == 'warm')['phases']
  h100_phases = [[name, f'{h100_warm[key]:.1f}'] for name, key in (
      ('import jax', 'import jax'), ('checkpoint load', 'checkpoint load'),
      ('model, env and Warp model', 'load_model (env + physics + checkpoint)'),
      ('search loop: trace, lower, JAX cache load', 'trace+lower+XLA compile/JAX-cache load '
                                                    '(not stored)'),
      ('search', 'search run (result.wall_time_s, in pachs.plan)'),
      ('the command in the profiling process (imports of MuJoCo and the package excluded)',
       'cli.main (all of the command)'))]
  warm = next(p for p in start['phases'] if p['run'] == 'B' and p['label'] == 'warm')['phases']
  phase_rows = [[name, f'{warm[key]:.1f}'] for name, key in (
      ('import jax', 'import jax'), ('import MuJoCo, MJX and MuJoCo Warp',
                                     'import mujoco, mjx (warp part)'),
      ('model, env and Warp model', 'load_model (env + physics + checkpoint)'),
      ('search loop: trace, lower, JAX cache load', 'trace+lower+XLA compile/JAX-cache load '
                                                    '(not stored)'),
      ('search', 'search run (result.wall_time_s, in pachs.plan)'))]
  search = [[r['instances'], r['K'], num(r['edges_per_s']),
             num(r['raw_env_steps_per_s_same_batch']), f'{r["search_over_raw"]:.2f}']
            for r in src.load('engines/search_over_raw_warp.json')['rows']]
  lanes = src.load('engines/live_lanes_two-gaps_warp.json')
  runs = lanes['settings']['instances'] * lanes['settings']['rounds']
  lane_rows = []
  for mode, m in lanes['modes'].items():
    for r in m['summary']:
      lane_rows.append([mode, r['live_fraction'], r['iterations'],
                        num(r['ms_per_iteration_median']), pct(r['share_of_wall']),
                        pct(r['lanes_used'])])
  return '\n\n'.join([
      'Env steps/s at 16,384 worlds on policy-rollout states in contact, over MuJoCo C on all '
      'the host\'s threads in the same run:',
      table(['layout', 'engine', 'worlds', 'over MuJoCo C'], ratio),
      'The open-loop suite with Warp physics (150 runs each, 100,000 evaluations, one H200; '
      'batch wall in s) beside the MJX-JAX results of the section above (an H100, earlier '
      'revisions, walls inflated where runs shared the GPU: see their sources):',
      table(['layout', 'planner', 'Warp', 'Warp wall', 'MJX-JAX', 'MJX-JAX wall'], suite),
      'MJX-JAX on two-gaps again, at the revision and on the machine of the Warp two-gaps row:',
      table(['planner', 'MJX-JAX', 'wall'], same_rows),
      'PACHS on two-gaps with Warp physics and more edges per iteration (K; 150 runs, 100,000 '
      'evaluations, batch wall in s):',
      table(['K', 'solved', 'wall', 'mean evaluations', 'mean cost (solved)'], pop),
      'Keeping the GPU full at the tail of the suite (PACHS, K 64, Warp physics, 150 runs, '
      '100,000 evaluations, one H200): every lane simulated; compaction (the live instances\' '
      'edges gathered into the smallest of 1/8 and 1/64 of the lanes; the accelerator default '
      'then, see "the compaction ladder" below); '
      'compaction and widening (`--widen-factors 2,4,8`: once the instances still searching hold '
      'at most 1/m of the lanes, each pops m x 64 edges); and K 128 throughout. Solved, batch '
      'wall (s) and mean cost of the solved runs:',
      table(['layout', 'all lanes', 'wall', 'cost', 'compaction', 'wall', 'cost',
             'compaction + widening', 'wall', 'cost', 'K 128', 'wall', 'cost'], tail),
      '`pachs plan --task pusht-obs` on one GPU with Warp physics (`--backend auto` picks it), '
      'process wall in s:',
      table(['run', 'process wall'], plan_rows),
      'The same command with today\'s PushT-Obs default (after_goal \'improve\': the search '
      'goes on after the first goal), process wall and the search time it prints (s):',
      table(['run', 'process wall', 'search'], now_rows),
      'Where a warm run\'s time goes (s, one profiled run):',
      table(['phase', 's'], phase_rows),
      f'The same command on an H100 host at a later revision (two fresh machines; process wall '
      f'and printed search time). The GPU machine unpacks its packages without compiled '
      f'bytecode (pip compiles it on install): there the imports of the package, JAX, MuJoCo, '
      f'MJX and MuJoCo Warp took {span(h100_imports["without_bytecode"])}, and '
      f'{span(h100_imports["with_bytecode"])} once compiled (`python -X importtime`):',
      table(['run', 'process wall', 'search'], h100_rows),
      'Where a warm run\'s time went on that H100 host (s, one profiled run, packages without '
      'compiled bytecode):',
      table(['phase', 's'], h100_phases),
      'A process\'s first transfer to the GPU sets the device up (about 1 s of that host\'s '
      'model load). Started in a thread beside the imports of MuJoCo and the package, it saved '
      'nothing measurable (warm runs on one H100 host, alternating, 4 each; "outside": the '
      'process wall less the planning call with its compilation), so it is not done:',
      table(['warm runs', 'process wall', 'mean', 'mean outside the planning call'],
            transfer_rows),
      'PACHS run to budget with Warp physics against `env.evaluate` alone at the same batch:',
      table(['instances', 'K', 'edges/s', 'raw env steps/s', 'search / raw'], search),
      f'Iteration time against live instances, {runs} two-gaps runs stepped one iteration '
      'per call:',
      table(['physics batch', 'live instances', 'iterations', 'ms / iteration',
             'share of wall', 'lanes used'], lane_rows)])


AFTER_GOAL_SETS = tuple((layout, layout) for layout in LAYOUTS) + (
    ('gate-mirror (held out)', 'gate-mirror'), ('wall-right (held out)', 'wall-right'),
    ('wall, instance set 1', 'wall_set1'), ('detour, instance set 1', 'detour_set1'))


def p_value(p: float) -> str:
  """A p-value as the report prints it: 'p 0.xx', or 'p < 0.01'."""
  return f'p {p:.2f}' if p >= 0.01 else 'p < 0.01'


def lag(a: Dict, a_planner: str, b: Dict, b_planner: str, start: int = 3000) -> Tuple[int, str]:
  """(the most runs by which a_planner's success curve in payload a trails b_planner's in b at
  a budget >= start, 0 where it never trails; that number as a table cell, with the exact
  McNemar p of the paired runs there: `stats.most_behind`); both payloads of the same runs."""
  runs, _, p = stats.most_behind(a['runs'][a_planner], b['runs'][b_planner],
                                 a['curve_budgets'], start)
  if not runs:
    return runs, '0'
  return runs, f'{runs} ({p_value(p)})'


def most_behind(a: Dict, a_planner: str, b: Dict, b_planner: str) -> str:
  """The table cell of `lag`."""
  return lag(a, a_planner, b, b_planner)[1]


def paired_ratio(a: Dict, a_planner: str, b: Dict, b_planner: str) -> str:
  """`cost_ratio` across two payloads of the same runs: a_planner's in a over b_planner's in b."""
  ratios = stats.cost_ratios({'a': a['runs'][a_planner], 'b': b['runs'][b_planner]})
  ratio = ratios['a']['b']['mean_ratio']
  return '-' if ratio is None else f'{ratio:.2f}'


WIDEN_PAIRS = (  # (label, (file, planner) with compaction alone, (file, planner) with widening)
    ('detour, seed 0', ('after_goal_gpu/detour', 'pachs-improve'), ('widen_gpu/suite/detour', 'pachs')),
    ('detour, seed 0 again', ('widen_gpu/detour_repeat', 'pachs'),
     ('widen_gpu/detour_widen', 'pachs')),
    ('detour, seed 1', ('widen_gpu/detour_seed1', 'pachs'), ('widen_gpu/detour_widen_seed1', 'pachs')),
    ('two-gaps, seed 0', ('after_goal_gpu/two-gaps', 'pachs-improve'),
     ('widen_gpu/suite/two-gaps', 'pachs')),
    ('two-gaps, seed 0 again', ('after_goal_gpu/two-gaps', 'pachs-improve'),
     ('widen_gpu/two-gaps_widen', 'pachs')),
    ('two-gaps, seed 1', ('widen_gpu/two-gaps_seed1', 'pachs'),
     ('widen_gpu/two-gaps_widen_seed1', 'pachs')),
    ('wall, seed 0', ('after_goal_gpu/wall', 'pachs-improve'), ('widen_gpu/wall_widen', 'pachs')))


def after_goal_gpu(src: Sources) -> str:
  """PushT-Obs's default (after_goal 'improve') beside 'stop', the parallel rollout and the
  default with widening: 150 runs per layout and instance set with Warp physics on a GPU."""
  rows, effort = [], []
  for label, name in AFTER_GOAL_SETS:
    p = src.load(f'after_goal_gpu/{name}.json')
    widened = src.load(f'widen_gpu/suite/{name}.json')
    inf = src.load(f'after_goal_gpu/{name}_inf.json') if src.exists(
        f'after_goal_gpu/{name}_inf.json') else None
    improve, stop = summary_of(p, 'pachs-improve'), summary_of(p, 'pachs-stop')
    parallel = summary_of(p, 'parallel')
    lead = 100 * (improve['success_rate'] - parallel['success_rate'])
    rows.append([label, solved(improve), solved(stop), solved(parallel), f'{lead:+.1f}',
                 most_behind(p, 'pachs-improve', p, 'parallel'),
                 cost_ratio(p, 'pachs-improve', 'parallel'), cost_ratio(p, 'pachs-stop', 'parallel'),
                 '-' if inf is None else f'{solved(summary_of(inf, "pachs-improve"))}, '
                 f'{paired_ratio(inf, "pachs-improve", p, "parallel")}',
                 f'{solved(summary_of(widened, "pachs"))}, '
                 f'{most_behind(widened, "pachs", p, "parallel")}'])
    effort.append([label, num(improve['first_goal_evaluated_mean']),
                   num(improve['evaluated_success_mean']), num(parallel['evaluated_success_mean']),
                   num(improve['first_goal_time_s_mean'], 2),
                   num(improve['time_s_success_mean'], 2), num(improve['batch_wall_s'], 3),
                   num(stop['batch_wall_s'], 3), num(parallel['batch_wall_s'], 3),
                   num(summary_of(widened, 'pachs')['batch_wall_s'], 3)])
  tasks = []
  for name in ('pusht-fixed', 'pusht-rand', 'shelf'):
    row = summary_of(src.load(f'widen_gpu/suite/{name}.json'), 'pachs')
    tasks.append([name, solved(row), num(row['batch_wall_s'], 3)])
  widen = []
  for label, without, with_ in WIDEN_PAIRS:
    a, b = (summary_of(src.load(f'{name}.json'), planner) for name, planner in (without, with_))
    widen.append([label, solved(a), num(a['batch_wall_s'], 3), solved(b),
                  num(b['batch_wall_s'], 3)])
  return '\n\n'.join([
      'PushT-Obs\'s default as it was then (novel restarts drew every coarse cell alike, see '
      '"Rarely visited cells first"): after the first goal an instance spends up to 3 times the '
      'evaluations it took to find it (`after_goal=\'improve\'`, allowance 3), restarting chains '
      'on the cheapest goal\'s path; on a GPU the physics batch shrinks to the live lanes '
      '(compaction). Beside it: `stop` (the first goal is the answer), the parallel rollout, '
      'the allowance inf, and the default with widening (the last instances pop 2, 4 or 8 x K '
      'edges); 30 instances x 5 seeds = 150 runs each, 100,000 evaluations, MuJoCo Warp physics '
      'on one GPU. Lead: points of success over the rollout. Behind: the most runs by which a '
      'success curve trails the rollout\'s at any budget from 3,000 evaluations, with the exact '
      'McNemar p of the paired runs (same instance and seed) at that budget: a p this large says '
      'the lag is within chance (the p-value treats the 5 rounds of an instance as independent, '
      'so it understates the uncertainty). Cost: mean of '
      'the per-run ratios over the runs both solved. With Warp physics a run\'s outcome varies '
      'from call to call (the same detour command twice: the first two rows of the widening '
      'table\'s compaction column), so differences of a few runs between columns are within '
      'that variation.',
      table(['layout', 'default', 'stop', 'parallel rollout', 'lead', 'behind',
             'cost / parallel', 'stop cost / parallel', 'allowance inf: solved, cost / parallel',
             'with widening: solved, behind'], rows),
      'Evaluations to the first goal and to the returned path (the default; means over solved '
      'runs), time estimated per run from the batch\'s iterations (s), and each call\'s batch '
      'wall (s):',
      table(['layout', 'evaluations to the first goal', 'to the returned path',
             'parallel: to its goal', 'time to the first goal', 'to the returned path',
             'default wall', 'stop wall', 'parallel wall', 'with widening'], effort),
      'Widening on the tasks without obstacles and on the shelf (150 runs; shelf: 100 targets '
      'at 20,000 evaluations), solved and batch wall (s):',
      table(['task', 'solved', 'wall'], tasks),
      'Widening against compaction alone, the rest of the default the same (150 runs each; '
      'seed: the search\'s, `--seed`), solved and batch wall (s). Widening cuts the wall by '
      '20-50% and solves as many runs at 100,000 evaluations within the variation, but it '
      'spends evaluations less well: its success curves trail compaction alone\'s between '
      'about 8,000 and 17,000 evaluations, where they fall behind the rollout\'s (the '
      '"behind" column above), so it is not the default:',
      table(['layout', 'compaction', 'wall', 'compaction + widening', 'wall'], widen)])


# The default's runs on more seeds and calls, and the two compaction ladders they were run with:
# (file in default_gpu_runs/, layout label, instance set, search seed, compaction, how timed)
DEFAULT_RUNS = (
    ('two-gaps_seed0_eighth', 'two-gaps', 0, 0, 'eighth', 'beside'),
    ('two-gaps_seed0_halving', 'two-gaps', 0, 0, 'halving', 'beside'),
    ('two-gaps_seed0_eighth_2', 'two-gaps', 0, 0, 'eighth', 'beside'),
    ('two-gaps_seed0_halving_2', 'two-gaps', 0, 0, 'halving', 'beside'),
    ('two-gaps_seed0_eighth_first', 'two-gaps', 0, 0, 'eighth', 'first'),
    ('two-gaps_seed0_halving_first', 'two-gaps', 0, 0, 'halving', 'first'),
    ('wall_seed0_eighth', 'wall', 0, 0, 'eighth', 'beside'),
    ('wall_seed0_halving', 'wall', 0, 0, 'halving', 'beside'),
    ('detour_seed0_halving', 'detour', 0, 0, 'halving', 'beside'),
    ('detour_set1_seed1_halving', 'detour', 1, 1, 'halving', 'beside'),
    ('detour_set1_seed2_halving', 'detour', 1, 2, 'halving', 'beside'),
    ('slot_seed0_halving', 'slot', 0, 0, 'halving', 'beside'),
    ('slot_seed0_eighth_first', 'slot', 0, 0, 'eighth', 'first'),
    ('slot_seed0_halving_first', 'slot', 0, 0, 'halving', 'first'),
    ('gate_seed0_halving', 'gate', 0, 0, 'halving', 'beside'),
    ('gate_seed1_halving', 'gate', 0, 1, 'halving', 'beside'),
    ('gate_seed2_halving', 'gate', 0, 2, 'halving', 'beside'),
    ('gate_seed0_eighth_first', 'gate', 0, 0, 'eighth', 'first'),
    ('gate_seed0_halving_first', 'gate', 0, 0, 'halving', 'first'),
    ('gate-mirror_seed1_halving', 'gate-mirror (held out)', 0, 1, 'halving', 'beside'),
    ('gate-mirror_seed2_halving', 'gate-mirror (held out)', 0, 2, 'halving', 'beside'),
    ('wall-right_seed0_halving', 'wall-right (held out)', 0, 0, 'halving', 'beside'))
LADDERS = {'eighth': '1/8, 1/64', 'halving': '1/2, 1/4, 1/8, 1/64'}


def default_runs(src: Sources) -> str:
  """PushT-Obs's default on more search seeds, instance sets and calls (outcomes against the
  rollout of the same call), and the physics batch sizes of compaction compared by wall."""
  outcome, pooled = [], {}
  for name, layout, instance_set, seed, ladder, timed in DEFAULT_RUNS:
    p = src.load(f'default_gpu_runs/{name}.json')
    if summary_of(p, 'parallel') is None:
      continue
    improve, parallel = summary_of(p, 'pachs-improve'), summary_of(p, 'parallel')
    lead = 100 * (improve['success_rate'] - parallel['success_rate'])
    runs_behind, behind = lag(p, 'pachs-improve', p, 'parallel')
    outcome.append([layout, str(instance_set), str(seed), solved(improve), solved(parallel),
                    f'{lead:+.1f}', behind, cost_ratio(p, 'pachs-improve', 'parallel')])
    pooled.setdefault((layout, instance_set), []).append((lead, runs_behind))
  for label, name in AFTER_GOAL_SETS:  # the suite's call of each set (seed 0)
    p = src.load(f'after_goal_gpu/{name}.json')
    improve, parallel = summary_of(p, 'pachs-improve'), summary_of(p, 'parallel')
    key = (label.replace(', instance set 1', ''), 1 if 'instance set 1' in label else 0)
    if key in pooled:
      pooled[key].append((100 * (improve['success_rate'] - parallel['success_rate']),
                          lag(p, 'pachs-improve', p, 'parallel')[0]))
  pooled_rows = [[layout, str(instance_set), str(len(v)),
                  f'{statistics.mean(x for x, _ in v):+.1f}',
                  f'{min(x for x, _ in v):+.1f} to {max(x for x, _ in v):+.1f}',
                  str(max(b for _, b in v)), str(sum(b > 0 for _, b in v))]
                 for (layout, instance_set), v in pooled.items()]
  walls = {}
  for name, layout, instance_set, seed, ladder, timed in DEFAULT_RUNS:
    if instance_set == 0 and seed == 0 and layout in LAYOUTS:
      r = summary_of(src.load(f'default_gpu_runs/{name}.json'), 'pachs-improve')
      walls.setdefault((layout, timed), {}).setdefault(ladder, []).append(
          f'{r["successes"]}/{r["runs"]} in {r["batch_wall_s"]:.2f} s')
  wall_rows = [[layout, 'compiled first' if timed == 'first' else 'compiling beside the search',
                '; '.join(v.get('eighth', ['-'])), '; '.join(v.get('halving', ['-']))]
               for (layout, timed), v in walls.items()]
  same = [summary_of(src.load(f'default_gpu_runs/{name}.json'), 'pachs-improve')['successes']
          for name, layout, instance_set, seed, _, _ in DEFAULT_RUNS
          if (layout, instance_set, seed) == ('two-gaps', 0, 0)]
  return '\n\n'.join([
      'The default as it was then (after_goal \'improve\', allowance 3, novel restarts drawing '
      'every coarse cell alike) and the parallel rollout in the same '
      'call, on more search seeds (`--seed`), the second instance set (`--instance-seed 1`) and '
      'repeated calls, 150 runs each at 100,000 evaluations with Warp physics on one H200. Lead, '
      'behind and cost as in the section above. With Warp physics the same command gives '
      f'different outcomes from call to call (two-gaps, seed 0: {min(same)} to {max(same)} of '
      f'150 over {len(same)} calls), so each call is a sample:',
      table(['layout', 'instance set', 'seed', 'default', 'parallel rollout', 'lead', 'behind',
             'cost / parallel'], outcome),
      'Pooled with the suite\'s call above: calls, mean lead (points), its range, the most runs '
      'behind at any budget from 3,000 evaluations, and the calls that were behind at some '
      'budget:',
      table(['layout', 'instance set', 'calls', 'mean lead', 'lead range', 'most behind',
             'calls behind'], pooled_rows),
      'Compaction gathers the live instances\' edges into the smallest of a ladder of physics '
      'batch sizes (fractions of the padded I x K lanes; 150 instances are padded to 256). '
      f'Batch wall of PACHS\'s default with the ladder {LADDERS["eighth"]} against '
      f'{LADDERS["halving"]} (the accelerator default since), solved and wall per call. '
      '"Compiled first": every loop program compiled before the clock starts '
      '(`programs.plan(compile_first=True)`, what `open_loop.py` does now); "compiling '
      'beside": the smaller sizes\' loops compiled in threads while the search runs, as the '
      'earlier walls of this page were measured:',
      table(['layout', 'timed', LADDERS['eighth'], LADDERS['halving']], wall_rows)])


def variant_cells(p: Dict, v: Dict, both_ways: bool = False) -> List[str]:
  """Table cells of the default ('pachs-improve' in p) against a variant ('pachs-improve' in v,
  the same runs) and the rollout of p's call: solved by each, each behind the rollout, (with
  both_ways the default behind the variant,) the variant behind the default, and the cost
  ratios to the rollout."""
  default = [most_behind(p, 'pachs-improve', v, 'pachs-improve')] if both_ways else []
  return ([solved(summary_of(p, 'pachs-improve')), solved(summary_of(v, 'pachs-improve')),
           solved(summary_of(p, 'parallel')), most_behind(p, 'pachs-improve', p, 'parallel'),
           most_behind(v, 'pachs-improve', p, 'parallel')] + default
          + [most_behind(v, 'pachs-improve', p, 'pachs-improve'),
             cost_ratio(p, 'pachs-improve', 'parallel'),
             paired_ratio(v, 'pachs-improve', p, 'parallel')])


def start_share(src: Sources) -> str:
  """The default against chains that restart at the start state with probability 1/4 (else at
  novel cells), with the parallel rollout of the default's call: 150 runs per layout, Warp."""
  rows = [[layout] + variant_cells(src.load(f'start_share_gpu/{layout}.json'),
                                   src.load(f'start_share_gpu/{layout}_start25.json'))
          for layout in ('gate', 'two-gaps', 'detour')]
  share = src.load('start_share_gpu/detour_start25.json')['settings']['start_share']
  return '\n\n'.join([
      'Where the default trails the rollout (by a few runs at middle budgets on some calls, '
      'the sections above), the rollout\'s episodes from the start solve runs on which the '
      'default\'s chains, restarting at novel cells, took longer. A variant restarts each chain '
      f'at the start state with probability {share} and at a novel cell otherwise (the '
      'commands in the sources; their option left with the variant); one call of each on one '
      'H100, 150 runs per layout at 100,000 evaluations, '
      'Warp physics. Behind: as above, against the rollout of the default\'s call; the column '
      '"start share behind the default" compares the variant with the default. The variant '
      'removes no lag on gate and solves fewer runs than the default on two-gaps and detour, '
      'so it was removed:',
      table(['layout', 'default', 'start share', 'parallel rollout', 'default behind',
             'start share behind', 'start share behind the default', 'default cost / parallel',
             'start share cost / parallel'], rows)])


def pooled_runs(src: Sources, calls) -> Tuple[List[Dict], List[Dict]]:
  """The runs of two planners over several calls, each call ((file a, planner a), (file b,
  planner b)) of the same runs: (runs of a, runs of b), every run's instance tagged with its call
  so that `stats` pairs runs within a call."""
  pooled = ([], [])
  for i, pair in enumerate(calls):
    for rows, (name, planner) in zip(pooled, pair):
      rows += [dict(r, instance=(i, r['instance']))
               for r in src.load(f'{name}.json')['runs'][planner]]
  return pooled


# The suite's calls at the default: (label, file stem in suite_gpu/)
SUITE_CALLS = tuple((layout, layout) for layout in LAYOUTS) + (
    ('gate, seed 1', 'gate_seed1'), ('gate, seed 2', 'gate_seed2'))


# The calls of the earlier default (every coarse cell drawn alike) on gate beside the rollout
EARLIER_GATE = ('after_goal_gpu/gate', 'default_gpu_runs/gate_seed0_eighth_first',
                'default_gpu_runs/gate_seed0_halving', 'default_gpu_runs/gate_seed1_halving',
                'default_gpu_runs/gate_seed2_halving', 'start_share_gpu/gate',
                'novelty_power_gpu/gate')


def suite(src: Sources) -> str:
  """PushT-Obs's default and the parallel rollout on the five suite layouts, one call each on
  one GPU with Warp physics (the README's headline reads these files)."""
  rows, effort = [], []
  calls = ([((f'suite_gpu/{name}', 'pachs-improve'), (f'suite_gpu/{name}', 'parallel'))
            for _, name in SUITE_CALLS]
           + [((f'novelty_power_gpu/{name}_power05', 'pachs-improve'),
               (f'novelty_power_gpu/{name}', 'parallel')) for _, name in NOVELTY_CALLS])
  default, rollout = pooled_runs(src, calls)
  gate = src.load('suite_gpu/gate.json')
  budgets, settings = gate['curve_budgets'], gate['settings']
  lag_runs, lag_budget, lag_p = stats.most_behind(default, rollout, budgets)
  pooled_lag = ('at no budget' if not lag_runs else
                f'by at most {lag_runs} runs ({lag_budget:,} evaluations, {p_value(lag_p)})')
  solved_of = lambda runs: sum(bool(r['found']) for r in runs)
  earlier = pooled_runs(src, [((name, 'pachs-improve'), (name, 'parallel'))
                              for name in EARLIER_GATE])
  earlier_runs, earlier_budget, earlier_p = stats.most_behind(*earlier, budgets)
  earlier_lag = f'{earlier_runs} runs behind at {earlier_budget:,} evaluations, {p_value(earlier_p)}'
  layouts = {name.split('_')[0] for _, name in SUITE_CALLS + NOVELTY_CALLS}
  for layout, name in SUITE_CALLS:
    p = src.load(f'suite_gpu/{name}.json')
    pachs, parallel = summary_of(p, 'pachs-improve'), summary_of(p, 'parallel')
    lead = 100 * (pachs['success_rate'] - parallel['success_rate'])
    rows.append([layout, solved(pachs), solved(parallel), f'{lead:+.1f}',
                 most_behind(p, 'pachs-improve', p, 'parallel'),
                 cost_ratio(p, 'pachs-improve', 'parallel')])
    if layout not in LAYOUTS:  # a repeat with another seed: its wall may hold Warp's compile
      continue
    effort.append([layout, num(pachs['first_goal_evaluated_mean']),
                   num(pachs['evaluated_success_mean']), num(parallel['evaluated_success_mean']),
                   num(pachs['first_goal_time_s_mean'], 2), num(pachs['time_s_success_mean'], 2),
                   num(pachs['batch_wall_s'], 3), num(parallel['batch_wall_s'], 3)])
  return '\n\n'.join([
      'PACHS\'s PushT-Obs default (edges of 8 transitions, 56 of 64 lanes extending chains of '
      'the actor\'s edges that restart at rarely visited cells, the first goal\'s path improved '
      'with up to 3 times the evaluations it took) and the parallel rollout of 256 copies, one '
      'call per layout, the calls one after another on one GPU with MuJoCo Warp physics '
      f'(Warp\'s kernels compiled before the first): {settings["instances"]} instances x '
      f'{settings["rounds"]} seeds = {settings["instances"] * settings["rounds"]} runs each, '
      f'{settings["budget"]:,} evaluations; gate again with the search seeds 1 and 2 '
      '(`--seed`), where the earlier default trailed the rollout (pooled over its '
      f'{len(EARLIER_GATE)} GPU calls on gate, {len(earlier[0]):,} paired runs: {earlier_lag}). '
      'Lead: points of success over the rollout. Behind: the most runs by which PACHS\'s '
      'success curve trails the rollout\'s at any budget from 3,000 '
      'evaluations, with the exact McNemar p of the paired runs there (`stats.most_behind`). '
      'Cost: mean of the per-run ratios over the runs both solved:',
      table(['layout', 'PACHS', 'parallel rollout', 'lead', 'behind', 'cost / parallel'], rows),
      f'Pooled with the {len(NOVELTY_CALLS)} calls of the same cell weights in "Rarely visited '
      'cells first" (the column 1 / sqrt(n) there, the weights then scaled to integers a '
      'little differently; each paired with the rollout of the every-cell-alike call of the '
      f'same command line; {len(calls)} calls, {len(default):,} paired runs on '
      f'{len(layouts)} layouts and two instance sets), PACHS solved '
      f'{solved_of(default):,} and the rollout {solved_of(rollout):,}, and PACHS trails the '
      f'rollout {pooled_lag} from '
      '3,000 evaluations.',
      'Evaluations to the first goal and to the returned path (means over solved runs), the '
      'time a run took, estimated from its batch\'s iterations (s), and each call\'s batch '
      'wall (s):',
      table(['layout', 'evaluations to the first goal', 'to the returned path',
             'parallel: to its goal', 'time to the first goal', 'to the returned path',
             'PACHS wall', 'parallel wall'], effort)])


# The calls that compare novel restarts drawing every coarse cell alike with cells of n nodes
# weighed 1 / sqrt(n): (label, file stem in novelty_power_gpu/), each with its _power05 twin
NOVELTY_CALLS = (
    ('gate, seed 0', 'gate'), ('wall, seed 0', 'wall'), ('detour, seed 0', 'detour'),
    ('two-gaps, seed 0', 'two-gaps'), ('gate-mirror (held out), seed 0', 'gate-mirror'),
    ('detour, instance set 1, seed 1', 'detour_set1_seed1'),
    ('wall, instance set 1, seed 1', 'wall_set1_seed1'), ('two-gaps, seed 1', 'two-gaps_seed1'),
    ('gate-mirror (held out), seed 1', 'gate-mirror_seed1'),
    ('wall-right (held out), seed 1', 'wall-right_seed1'))


def novelty_weights(src: Sources) -> str:
  """Novel restarts drawing every coarse cell alike against cells weighed 1 / sqrt(nodes), with
  the parallel rollout of the first's call: ten calls of 150 runs, Warp, one GPU."""
  rows, wins, losses = [], 0, 0
  for label, name in NOVELTY_CALLS:
    p = src.load(f'novelty_power_gpu/{name}.json')
    v = src.load(f'novelty_power_gpu/{name}_power05.json')
    rows.append([label] + variant_cells(p, v, both_ways=True))
    gain = (summary_of(v, 'pachs-improve')['successes']
            - summary_of(p, 'pachs-improve')['successes'])
    wins, losses = wins + (gain > 0), losses + (gain < 0)
  files = [f'novelty_power_gpu/{name}' for _, name in NOVELTY_CALLS]
  alike, parallel = pooled_runs(src, [((f, 'pachs-improve'), (f, 'parallel')) for f in files])
  root, _ = pooled_runs(src, [((f'{f}_power05', 'pachs-improve'), (f, 'parallel'))
                              for f in files])
  first = src.load(f'{files[0]}.json')
  budgets, settings = first['curve_budgets'], first['settings']
  solved_of = lambda runs: sum(bool(r['found']) for r in runs)
  alike_of = {(r['instance'], r['round']): r['found'] for r in alike}
  only_root = sum(bool(r['found']) and not alike_of[(r['instance'], r['round'])] for r in root)
  only_alike = sum(not r['found'] and bool(alike_of[(r['instance'], r['round'])]) for r in root)
  rollout_by = lambda budget: sum(bool(r['found']) and r['first_goal_evaluated'] <= budget
                                  for r in parallel)
  alike_lag, root_lag = (stats.most_behind(a, b, budgets) for a, b in ((alike, root),
                                                                        (root, alike)))
  behind = lambda lag: f'{lag[0]} at {lag[1]:,} evaluations ({p_value(lag[2])})'
  differences = []
  for budget in (alike_lag[1], budgets[-1]):
    difference, low, high = stats.paired_difference(root, alike, budget)
    differences.append(f'{difference:+d} at {budget:,} evaluations ({low:+.0f} to {high:+.0f})')
  return '\n\n'.join([
      'A chain that ends restarts at a node drawn by novelty. The earlier default drew every '
      'coarse cell found so far alike (each node 1 / n for the n nodes of its cell); the '
      'default now draws a cell of n nodes with weight 1 / sqrt(n), Go-Explore\'s count bonus, '
      'so that rarely visited cells come first (`search/novelty.py`). '
      f'{len(NOVELTY_CALLS)} calls of each on one H100, the rollout in the every-cell-alike '
      f'call, {settings["instances"] * settings["rounds"]} runs per call at '
      f'{settings["budget"]:,} evaluations, Warp physics; the first job\'s gate call alone (it '
      'compiled Warp\'s kernels), the others three at a time on the GPU (the commands in the '
      'sources; their option left with the '
      'losing weights). Behind: as in the suite above; "alike behind 1/sqrt(n)" compares the '
      'two variants on the same runs:',
      table(['call', 'cells alike', '1 / sqrt(n)', 'parallel rollout', 'alike behind rollout',
             '1/sqrt(n) behind rollout', 'alike behind 1/sqrt(n)', '1/sqrt(n) behind alike',
             'alike cost / parallel', '1/sqrt(n) cost / parallel'], rows),
      f'Pooled over the {len(NOVELTY_CALLS)} calls ({len(root):,} paired runs): every cell '
      f'alike solved {solved_of(alike):,}, 1 / sqrt(n) {solved_of(root):,} and the rollout '
      f'{solved_of(parallel):,} at {settings["budget"]:,} evaluations; 1 / sqrt(n) solved more '
      f'runs in {wins} calls and fewer in {losses}; {only_root} runs only 1 / sqrt(n) solved '
      f'against {only_alike} only every cell alike did (McNemar '
      f'{p_value(stats.mcnemar_p(only_root, only_alike))}). Every cell alike trails 1 / '
      f'sqrt(n) by {behind(alike_lag)}; 1 / sqrt(n) trails every cell alike by '
      f'{behind(root_lag)}, where the rollout has solved {rollout_by(root_lag[1])} runs. '
      'These p-values treat '
      'the runs as independent; the rounds of one instance are not, so they understate the '
      'uncertainty. Resampling the instances of the calls instead (`stats.paired_difference`), '
      'runs solved by 1 / sqrt(n) minus every cell alike, with 95% intervals: '
      + '; '.join(differences) + '. 1 / sqrt(n) is the default: it reaches goals sooner at middle budgets, and by the '
      'end of the budget it solves as many runs or more.'])


def after_goal(src: Sources) -> str:
  """PACHS after its first goal, stop or improve, against the parallel rollout on the same runs
  (10 instances per layout, MuJoCo C physics on a CPU)."""
  groups = (('gate', ('gate_3', 'gate_a3', 'gate_prune_a3')),
            ('wall', ('wall_base', 'wall_a3', 'wall_impinf', 'wall_prune_a3')),
            ('slot', ('slot_3',)), ('detour', ('detour_3', 'detour_a3')),
            ('two-gaps', ('twogaps_3',)),
            ('wall, instance set 1', ('wall_set1',)))
  rows = []
  for layout, names in groups:
    payloads = [src.load(f'after_goal_cpu/{name}.json') for name in names]
    runs = {}
    for payload in payloads:
      for planner, planner_runs in payload['runs'].items():
        allowance = re.search(r'improve_allowance=([\d.inf]+)', payload['configs'].get(planner, ''))
        label = planner if planner == 'parallel' else (
            'pachs-stop' if planner in ('pachs', 'pachs-stop') else
            f'{planner} ({allowance.group(1) if allowance else "?"})')
        runs.setdefault(label, planner_runs)
    parallel = {(r['instance'], r['round']): r for r in runs.pop('parallel') if r['found']}
    for label, planner_runs in runs.items():
      ok = [r for r in planner_runs if r['found']]
      both = [r for r in ok if (r['instance'], r['round']) in parallel]
      ratio = statistics.fmean([r['cost'] / parallel[(r['instance'], r['round'])]['cost'] for r in both])
      rows.append([layout, label, f'{len(ok)}/{len(planner_runs)}', len(parallel),
                   num(statistics.fmean([r['cost'] for r in both])),
                   num(statistics.fmean([parallel[(r['instance'], r['round'])]['cost'] for r in both])),
                   f'{ratio:.2f}', num(statistics.fmean([r.get('first_goal_evaluated', r['evaluated']) for r in ok])),
                   num(statistics.fmean([r['evaluated'] for r in ok]))])
  return '\n\n'.join([
      'PACHS on PushT-Obs after its first goal: `stop` (the first goal is the answer) or '
      '`improve` (chains restarted on the cheapest goal\'s path for up to the allowance times '
      'the evaluations of the first goal; inf: to the budget); `prune`, the same without the '
      'restarts on the path, lost and was removed. 10 instances x 1 round per layout, 100,000 '
      'evaluations, MuJoCo C physics on a 2-core CPU. Cost: means over the runs that the planner '
      'and the parallel rollout both solved; ratio: mean of the per-run ratios:',
      table(['layout', 'planner', 'solved', 'parallel solved', 'cost', 'parallel cost', 'ratio',
             'evaluations to the first goal', 'evaluations to the returned path'], rows)])


def physics(src: Sources) -> str:
  """PushT physics candidates: MJX against the MuJoCo C float64 world after 10 control steps,
  and the deepest penetration into the blocks (experiments/physics_agreement.py)."""
  agree = {}
  for name in ('agreement_suite_2', 'agreement_free_suite'):
    for r in src.load(f'physics/{name}.json')['rows']:
      if r['horizon'] == 10:
        agree.setdefault(r['physics'], {})[r['layout']] = (
            f'{r["position_mm_p90"]:.1f} / {r["angle_deg_p90"]:.1f}')
  agree_rows = [[p] + [cells.get(layout, '-') for layout in LAYOUTS] for p, cells in agree.items()]
  deep = {}
  for name in ('penetration', 'penetration_free'):
    for r in src.load(f'physics/{name}.json')['rows']:
      deep.setdefault(r['physics'], {})[r['layout']] = (
          f'{r["t_block_max_mm"]:.1f} / {r["stick_block_max_mm"]:.1f}')
  deep_rows = [[p] + [cells.get(layout, '-') for layout in LAYOUTS] for p, cells in deep.items()]
  return '\n\n'.join([
      'MJX (float32, the GPU planners\' physics) against the MuJoCo C float64 world on the '
      'shipped policy\'s pushes: the T\'s position (mm) / angle (degrees) error at the 90th '
      'percentile after 10 control steps, per layout ("today": the planar T of the shipped '
      'models; "free": the free T under gravity, friction 3):',
      table(['physics'] + list(LAYOUTS), agree_rows),
      'The deepest T-block / stick-block penetration (mm) over policy rollouts in MuJoCo C:',
      table(['physics'] + list(LAYOUTS), deep_rows)])


def playground(src: Sources) -> str:
  """MuJoCo Playground's reacher tasks: the policy, the parallel rollout and PACHS."""
  rows = []
  for name in ('playground_reachereasy.json', 'playground_reacherhard.json'):
    p = src.load(name)
    for s in p['summaries']:
      rows.append([p['task'].split(':')[-1], s['planner'], f'{s["solved"]}/{s["instances"]}',
                   num(s['mean_cost_solved']), num(s['mean_evaluated']), num(s['wall_s'])])
  return '\n\n'.join([
      'The shipped Playground models on their 30 canonical instances (budgets in the planner '
      'names):',
      table(['task', 'planner', 'solved', 'mean cost (solved)', 'mean evaluations', 'wall (s)'],
            rows)])


SECTIONS: Tuple[Tuple[str, Callable[[Sources], str]], ...] = (
    ('Open loop: PushT-Obs layouts', open_loop_layouts),
    ('Open loop: other instances and held-out layouts', open_loop_beyond),
    ('The layouts: the policy alone', policy_per_layout),
    ('Open loop: PushT-Fixed, PushT-Rand, Panda-Shelf', open_loop_tasks),
    ('Closed loop: replanning sessions on Warp', closed_loop_sessions),
    ('Closed loop', closed_loop),
    ('Speed and start-up', speed),
    ('MuJoCo Playground', playground),
    ('MuJoCo Warp physics', warp_physics),
    ('PushT-Obs suite at the default', suite),
    ('Rarely visited cells first', novelty_weights),
    ('PACHS after the first goal', after_goal_gpu),
    ('PACHS\'s default on more seeds, and the compaction ladder', default_runs),
    ('Chains restarting at the start', start_share),
    ('PACHS after the first goal: the CPU runs behind the default', after_goal),
    ('PushT physics: agreement and penetration', physics),
)


def anchor(title: str) -> str:
  """GitHub's anchor of a markdown heading."""
  return re.sub(r'[^a-z0-9 -]', '', title.lower()).replace(' ', '-')


def results_markdown(root: str = ROOT) -> Tuple[str, List[str]]:
  """docs/results.md and the result files it cites."""
  parts = ['# Results', '',
           'Generated by `python experiments/report.py` from the result files in '
           '`experiments/results/`; do not edit by hand. Each section lists its files with the '
           'device, revision and command of every run in them. The protocol is in '
           '[experiments.md](experiments.md).', '']
  cited = []
  for title, section in SECTIONS:
    src = Sources(root)
    body = read_section(title, section, src)
    parts += [f'## {title}', '', body, '', '**Sources**', '']
    for path in src.cited:
      parts += read_section(title, lambda _, path=path: provenance_lines(
          path, read_result(root, path), 'docs'), src)
      cited.append(path)
    parts.append('')
  return '\n'.join(parts).rstrip() + '\n', cited


def headline_table(root: str = ROOT) -> Tuple[str, List[str]]:
  """The README's headline block (between the markers) and the files it cites."""
  src = Sources(root)
  rows = []
  for task, name in (('PushT-Fixed', 'open_loop_pusht-fixed.json'),
                     ('PushT-Rand', 'open_loop_pusht-rand.json')):
    p = src.load(name)
    rows.append((task, p, 'pachs', p))  # (runs, PACHS's default there, the policy alone's)
  for layout in LAYOUTS:
    rows.append((f'PushT-Obs, {layout}', src.load(f'suite_gpu/{layout}.json'),
                 'pachs-improve', src.load(f'open_loop_pusht-obs_{layout}.json')))
  shelf = src.load('open_loop_shelf.json')
  rows.append(('Panda-Shelf', shelf, 'pachs', shelf))
  body = []
  for task, p, name, policy in rows:
    pachs, parallel = summary_of(p, name), summary_of(p, 'parallel')
    single = summary_of(policy, 'single')
    at_10k = f'{pct(curve_at(p, name, 10000)[1])} / {pct(curve_at(p, "parallel", 10000)[1])}'
    body.append([task, pct(pachs['success_rate']), pct(parallel['success_rate']),
                 pct(single['success_rate']) if single else '-', at_10k,
                 num(pachs['evaluated_mean']), f'{num(pachs["batch_wall_s"], 2)} s',
                 cost_ratio(p, name, 'parallel')])
  budgets = sorted({r[1]['settings']['budget'] for r in rows}, reverse=True)
  start = src.load('engines/plan_main_job_warp.json')
  cold, warm, _ = command_walls(start, 30)
  again = src.load('engines/plan_startup_improve_warp.json')['runs']  # another machine, later
  cold = [cold] + [r['process_wall_s'] for r in again if r['run'] == 'cold']
  warm = list(warm) + [r['process_wall_s'] for r in again if r['run'] == 'warm']
  h100 = [r for r in src.load('engines/plan_startup_h100.json')['runs'] if r['job'] == 'D']
  cold += [r['process_wall_s'] for r in h100 if r['run'] == 'cold']
  warm += [r['process_wall_s'] for r in h100 if r['run'].startswith('warm')]
  claims = cpu_claims(src)
  devices = sorted({run['device'].split(': ')[-1].replace(' x1', '')
                    for r in rows for run in runs_of(r[1])})
  lines = [
      table(['task', 'PACHS', 'parallel rollout (256 copies)', 'policy alone',
             'solved within 10,000 evaluations (PACHS / rollout)', 'PACHS evaluations per run',
             'PACHS wall, all runs in one call', 'PACHS path cost / rollout\'s'], body),
      '',
      f'Open loop: share of runs solved (30 instances x 5 seeds; shelf: 100 targets) within '
      f'{" (shelf: ".join(f"{b:,}" for b in budgets)}) edge evaluations per run, on one '
      f'{" or one ".join(devices)}, each task\'s default (PushT-Obs: MuJoCo Warp physics, the '
      f'first goal\'s path improved; the policy alone there from MJX runs). Path cost: mean '
      f'ratio over the runs both solved. Start-up of `pachs plan --task pusht-obs` (30 '
      f'instances, one GPU, Warp; three machines, H200 and H100): {span(cold)} cold, '
      f'{span(warm)} warm. On a '
      f'2-core CPU: '
      f'{claims["job"]}. '
      f'Tests: {claims["suite"]}. Every table, its device, command and revision: '
      f'[docs/results.md](docs/results.md).',
  ]
  return '\n'.join(lines), src.cited


def readme_with_table(readme: str, block: str) -> str:
  """The README text with the block between the markers replaced."""
  begin, end = readme.find(BEGIN), readme.find(END)
  if begin < 0 or end < begin:
    raise ValueError(f'{README} lacks the markers {BEGIN} ... {END}')
  return readme[:begin + len(BEGIN)] + '\n' + block + '\n' + readme[end:]


def generate(root: str = ROOT) -> Dict[str, str]:
  """{repository path: the text the report writes there}."""
  results, _ = results_markdown(root)
  block, _ = read_section('README headline', lambda _: headline_table(root), Sources(root))
  with open(os.path.join(root, README)) as f:
    readme = readme_with_table(f.read(), block)
  return {RESULTS_MD: results, README: readme}


def cited_files(root: str = ROOT) -> List[str]:
  """Every result file the report reads."""
  return sorted(set(results_markdown(root)[1]) | set(headline_table(root)[1]))


def main(argv: Optional[Sequence[str]] = None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--check', action='store_true',
                      help='write nothing; exit 1 where a written file differs')
  args = parser.parse_args(argv)
  try:
    written = generate()
  except ReportError as err:
    print(f'report.py: error: {err}', file=sys.stderr)
    return 2
  stale = []
  for path, text in written.items():
    full = os.path.join(ROOT, path)
    old = open(full).read() if os.path.exists(full) else None
    if old == text:
      continue
    stale.append(path)
    if not args.check:
      with open(full, 'w') as f:
        f.write(text)
  if args.check and stale:
    print(f'stale: {", ".join(stale)}; run python experiments/report.py', file=sys.stderr)
    return 1
  print(f'{"rewrote" if stale else "up to date:"} {", ".join(stale) or RESULTS_MD + ", " + README}')
  return 0


if __name__ == '__main__':
  sys.exit(main())
