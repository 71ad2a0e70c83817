"""Writes docs/results.md and the README's headline table from the committed result files.

  python experiments/report.py            # rewrite both
  python experiments/report.py --check    # exit 1 where either differs from the files
"""

from __future__ import annotations

import argparse
import json
import math
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
# the closed loop's layouts: the suite's and the held-out ones
CLOSED_LOOP_LAYOUTS = LAYOUTS + ('gate-mirror', 'wall-right')
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
  check_numbers(path, payload)
  return payload


RATES = ('success_rate', 'ci95_low', 'ci95_high', 'instance_ci95_low', 'instance_ci95_high')
COUNTS = ('runs', 'successes', 'episodes', 'failures', 'empty_answers', 'goal_answers')


def check_numbers(path: str, payload: Dict) -> None:
  """ReportError naming the file, row and field where a summary row holds a number no run can
  give: a rate outside [0, 1], a count that is negative, fractional or above the runs, or a
  value that is not finite."""
  rows = payload.get('summary')
  if not isinstance(rows, list):
    return
  for row in rows:
    if not isinstance(row, dict):
      continue
    name = row.get('planner', '?')
    for field, value in row.items():
      if isinstance(value, float) and not math.isfinite(value):
        raise ReportError(f'{path}: {name} {field} is {value} (not a finite number)')
    for field in RATES:
      value = row.get(field)
      if value is not None and not (isinstance(value, (int, float)) and 0 <= value <= 1):
        raise ReportError(f'{path}: {name} {field} must lie in [0, 1], got {value!r}')
    for field in COUNTS:
      value = row.get(field)
      if value is not None and not (isinstance(value, int) and not isinstance(value, bool)
                                    and value >= 0):
        raise ReportError(f'{path}: {name} {field} must be a count (an int >= 0), got '
                          f'{value!r}')
    total = row.get('runs', row.get('episodes'))
    if isinstance(total, int) and isinstance(row.get('successes'), int) and (
        row['successes'] > total):
      raise ReportError(f'{path}: {name} successes {row["successes"]} exceed its {total} runs')


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
  """The provenance records of a result file: its own (under 'provenance', or at its top level),
  or each merged source's."""
  prov = payload.get('provenance', payload)
  return prov.get('merged_from') or [prov]


def provenance_lines(files: Sequence[Tuple[str, Dict]], from_dir: str) -> List[str]:
  """Markdown bullet lines naming cited files (path, payload) by the device and revision of the
  runs in them: one line per device and revision, its files in the order given."""
  groups: Dict[str, List[str]] = {}
  for path, payload in files:
    revisions: Dict[str, List[str]] = {}  # device: its runs' revisions, in order
    for run in runs_of(payload):
      seen = revisions.setdefault(run.get('device', '?'), [])
      revision = short_revision(run.get('git_revision', '?'))
      if revision not in seen:
        seen.append(revision)
    runs = '; '.join(f'{device}, revision{"s" * (len(seen) > 1)} {", ".join(seen)}'
                     for device, seen in revisions.items())
    groups.setdefault(runs, []).append(link(path, from_dir))
  return [f'- {runs}: {", ".join(links)}' for runs, links in groups.items()]


# sections ---------------------------------------------------------------------------------------

def summary_of(payload: Dict, planner: str) -> Optional[Dict]:
  """The summary row of a planner in an open- or closed-loop result, None where absent."""
  return next((row for row in payload['summary'] if row['planner'] == planner), None)


def solved(row: Optional[Dict]) -> str:
  """'n/N (x%)' of an open-loop summary row."""
  if row is None:
    return '-'
  return f'{row["successes"]}/{row["runs"]} ({pct(row["success_rate"])})'


def episodes_solved(row: Dict) -> str:
  """'x% [low, high]' of a closed-loop summary row: its episodes solved, 95% interval."""
  return f'{pct(row["success_rate"])}{ci(row["ci95_low"], row["ci95_high"])}'


def solved_ci(row: Optional[Dict]) -> str:
  """`solved` and the 95% interval over instances of an open-loop summary row."""
  if row is None:
    return '-'
  return solved(row) + ci(row.get('instance_ci95_low'), row.get('instance_ci95_high'))


def planner_row(task: str, row: Dict) -> List[str]:
  """[task, planner, solved with interval, mean cost (solved), mean evaluations] of a row."""
  return [task, row['planner'], solved_ci(row), num(row['cost_success_mean']),
          num(row['evaluated_mean'])]


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


def policy_per_layout(src: Sources) -> str:
  """What the policy alone solves on each layout (the layouts are built so that it fails)."""
  p = src.load('eval_layouts_cpu.json')
  rows = [[r['layout'], r['kind'], r['start_region'], f'{r["policy_solved"]}/{r["instances"]}']
          for r in p['rows']]
  return '\n\n'.join([
      'One deterministic rollout of the PushT-Fixed policy per canonical instance, the default '
      '(faithful) physics in MuJoCo C:',
      table(['layout', 'the T must', 'start region', 'policy alone'], rows)])


def open_loop_tasks(src: Sources) -> str:
  """Panda-Shelf: every planner's success, cost, effort and time (PushT's: the faithful
  physics' section)."""
  rows = []
  notes = []
  for task, name in (('Panda-Shelf', 'open_loop_shelf.json'),):
    p = src.load(name)
    s = p['settings']
    notes.append(f'{task}: {s["instances"]} instances x {s["rounds"]} '
                 f'seed{"s" * (s["rounds"] > 1)}, {s["budget"]:,} '
                 'evaluations per run' + (f', {s["time_limit_s"]:g} s limit per call'
                                          if s.get('time_limit_s') else ''))
    for row in p['summary']:
      rows.append(planner_row(task, row) + [num(row.get('evaluated_per_expanded')),
                                            num(row['batch_wall_s'])])
  return '\n\n'.join([
      '; '.join(notes) + '. ePA*SE on the shelf runs its own budget (its config in the file).',
      table(['task', 'planner', 'success', 'mean cost (solved)', 'mean evaluations',
             'evaluations per expansion', 'wall of the call (s)'], rows)])

FAITHFUL_LAYOUTS = ('gate', 'wall', 'detour', 'slot')  # measured open loop on the faithful physics


def faithful(src: Sources) -> str:
  """The shipped models on the default (faithful) PushT physics: open loop on PushT-Fixed,
  -Rand and three PushT-Obs layouts with Warp planners, the policy alone in MuJoCo C, Warp
  against MuJoCo C and the penetration into the blocks."""
  rows = []
  for task, name in (('PushT-Fixed', 'pusht-fixed'), ('PushT-Rand', 'pusht-rand')):
    for row in src.load(f'faithful_gpu/{name}.json')['summary']:
      rows.append(planner_row(task, row) + [num(row['batch_wall_s'])])
  cpu_rand = summary_of(src.load('faithful_cpu/pusht-rand.json'), 'pachs')
  settings = src.load('faithful_gpu/gate.json')['settings']
  obs, colliders = [], set()
  for layout in FAITHFUL_LAYOUTS:
    p = src.load(f'faithful_gpu/{layout}.json')
    colliders.add(box_contacts(p))
    pachs, parallel = summary_of(p, 'pachs-improve'), summary_of(p, 'parallel')
    obs.append([layout, solved_ci(pachs), solved_ci(parallel),
                num(pachs['evaluated_mean']), num(pachs['batch_wall_s']),
                num(parallel['batch_wall_s']) if parallel else '-',
                cost_ratio(p, 'pachs-improve', 'parallel') if parallel else '-'])
  policy = [src.load('training/policy_physics.json')['rows'][0],
            src.load('training/policy_physics_rand.json')['rows'][0]]
  policy += [r for name in ('training/policy_physics_fine.json',
                            'training/policy_physics_fine_rand.json')
             for r in src.load(name)['rows'] if r['preset'] != 'faithful']
  policy_rows = [[r['task'], r['preset'], f'{r["success"]}/{r["instances"]}', str(r['tipped']),
                  num(100 * r['tip_height_near_t_median_m'], 2)] for r in policy]
  agree = {r['layout']: r for r in src.load('faithful_gpu/agreement.json')['rows']
           if r['horizon'] == 10}
  deep = {r['layout']: r for r in src.load('physics/penetration_margin3mm.json')['rows']
          if r['physics'] == 'faithful margin3mm'}  # the default's settings
  candidates = {}
  for r in (src.load('physics/penetration_faithful.json')['rows']
            + src.load('physics/penetration_margins.json')['rows']):
    cell = candidates.setdefault(r['physics'], [0.0, 0.0, r['mujoco_c_us_per_physics_step'],
                                                r['physics_steps_per_control_step']])
    cell[0], cell[1] = max(cell[0], r['t_block_max_mm']), max(cell[1], r['stick_block_max_mm'])
  candidate_rows = [[name, num(t, 2), num(stick, 2), num(us * steps / 1000, 3)]
                    for name, (t, stick, us, steps) in candidates.items()]
  physics_rows = [[layout, num(agree[layout]['position_mm_p90'], 2),
                   num(agree[layout]['angle_deg_p90'], 2),
                   num(agree[layout]['position_mm_p99'], 2),
                   num(deep[layout]['t_block_max_mm'], 2),
                   num(deep[layout]['stick_block_max_mm'], 2)] for layout in LAYOUTS]
  return '\n\n'.join([
      'PushT\'s default physics is ManiSkill PushT-v1\'s: a free T of 0.8 kg under gravity, '
      'T-table friction 1.65, 20 Hz control of 20 physics steps of 2.5 ms, stiff blocks whose '
      'contacts act from 3 mm (docs/tasks.md); the shipped PushT models were trained on it with MuJoCo Warp '
      '([training](#training-on-the-faithful-physics-with-warp)). Open loop with Warp '
      f'planners, one GPU per call: {settings["instances"]} instances x {settings["rounds"]} '
      f'seeds, {settings["budget"]:,} evaluations per run:',
      table(['task', 'planner', 'success', 'mean cost (solved)', 'mean evaluations',
             'wall of the call (s)'], rows),
      f'PACHS\'s one unsolved PushT-Rand run emptied its open list. The same 150 runs with '
      f'MuJoCo C physics on a 2-core CPU (`--backend mujoco-c`): {solved(cpu_rand)}, '
      f'{num(cpu_rand["evaluated_mean"])} evaluations per run, {num(cpu_rand["batch_wall_s"])} '
      f's for the call.',
      f'PushT-Obs, the PushT-Fixed model (trained without obstacles) on {len(obs)} layouts: '
      'PACHS (its default: the first goal\'s path improved, a quarter of its actions drawn '
      'uniformly from the action box, `uniform_share` 0.25) and the parallel rollout of 256 '
      'copies. Cost: mean per-run ratio over the runs both solved'
      + ('; the Warp planners\' T-block contacts by Warp\'s convex collider, before they used '
         'MuJoCo C\'s box-box routine ([closed loop](#closed-loop-on-the-faithful-physics))'
         if colliders == {'convex'} else '') + ':',
      table(['layout', 'PACHS', 'parallel rollout', 'PACHS evaluations', 'PACHS wall (s)',
             'parallel wall (s)', 'cost / parallel'], obs),
      'The actor, trained without obstacles, drives the stick against the hard blocks, '
      'where every action it proposes leaves the stick where it is (the original algorithm\'s '
      'OPEN empties; PACHS\'s chains spend the budget). Hence PushT-Obs\'s uniform draws; '
      'with every action drawn from the actor, the same GPU runs solved far fewer '
      '([measured and not kept](#measured-and-not-kept)).',
      'The policy alone, deterministic, in MuJoCo C on the canonical instances '
      '(`policy_physics.py`); the stick tip\'s median height while within 10 cm of the T '
      '(the T is 4 cm tall). The shipped models were trained on the faithful physics; the '
      'other rows push with them in a candidate below, untrained on it:',
      table(['task', 'physics', 'solved', 'tipped', 'tip height (cm)'], policy_rows),
      'Warp (float32, the planners\' physics) against the MuJoCo C float64 world on the '
      'policy\'s stochastic pushes: the T\'s position (mm) and angle (degrees) error 10 '
      'control steps after a common state (16 instances x 2 starts per layout); the deepest '
      'T-block and stick-block penetration (mm) over policy rollouts in MuJoCo C (8 instances x '
      '60 steps per layout):',
      table(['layout', 'position p90 (mm)', 'angle p90 (deg)', 'position p99 (mm)',
             'T-block max (mm)', 'stick-block max (mm)'], physics_rows),
      'How the blocks\' margin was chosen. Candidates for shallower block contacts than blocks '
      'without a margin ("faithful" in these tables, the preset `soft-blocks`), the same '
      'rollouts (deepest over the five '
      'layouts; a control step\'s physics on this CPU, one thread, in ms): contact margins '
      'of 1 and 2 mm on the blocks (their contacts act from that distance, so nothing sinks '
      'into the block itself), 1.25 ms steps with the blocks\' solref at its 2-step limit, '
      'and both:',
      table(['physics', 'T-block max (mm)', 'stick-block max (mm)', 'control step (ms)'],
            candidate_rows),
      'Again in one run, so that the costs compare (each physics step\'s cost is the median '
      'over the layouts; the margin adds no cost per step): a 3 mm margin at the faithful '
      'step is the default:',
      table(['physics', 'T-block max (mm)', 'stick-block max (mm)', 'control step (ms)'],
            one_run_candidates(src.load('physics/penetration_margin3mm.json'))),
      'Warp against the MuJoCo C world for the candidates, measured as above but with Warp\'s '
      'CPU kernels on a 2-core CPU (their float32 results differ from the GPU\'s, hence '
      '"faithful" again): the T\'s position error p90 (mm) / angle error p90 (degrees) after '
      '10 control steps:',
      candidate_agreement(src, ('physics/agreement_fine_cpu.json',
                                'physics/agreement_fine_cpu_2.json',
                                'physics/agreement_margin3mm_cpu.json')),
      'The same on the GPU (Warp\'s CUDA kernels, '
      f'{src.load("physics/agreement_hard_gpu.json")["provenance"]["device"]}), the 1.25 ms '
      'candidate and blocks without a margin in one run:',
      candidate_agreement(src, ('physics/agreement_hard_gpu.json',))])


def one_run_candidates(run: Dict) -> List[List[str]]:
  """Rows of the penetration candidates of one run: deepest T-block and stick-block contact over
  its layouts and the median control step's physics (ms)."""
  by_physics = {}
  for r in run['rows']:
    by_physics.setdefault(r['physics'], []).append(r)
  return [[name, num(max(r['t_block_max_mm'] for r in rows), 2),
           num(max(r['stick_block_max_mm'] for r in rows), 2),
           num(statistics.median([r['mujoco_c_us_per_physics_step']
                                  * r['physics_steps_per_control_step'] for r in rows]) / 1000,
               3)]
          for name, rows in by_physics.items()]


def candidate_agreement(src: Sources, names: Sequence[str]) -> str:
  """The physics candidates' Warp against MuJoCo C agreement in the files names, per layout."""
  cells, layouts = {}, []
  for name in names:
    for r in src.load(name)['rows']:
      if r['horizon'] == 10:
        cells.setdefault(r['physics'], {})[r['layout']] = (
            f'{num(r["position_mm_p90"], 2)} / {num(r["angle_deg_p90"], 2)}')
        layouts += [] if r['layout'] in layouts else [r['layout']]
  return table(['physics'] + layouts,
               [[name] + [row.get(layout, '-') for layout in layouts]
                for name, row in cells.items()])


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


def answer_counts(row: Dict) -> str:
  """A replanning session's answers by kind ('goal path 510, partial 548, ...')."""
  answers = row.get('answers')
  if not answers:
    return '-'
  names = (('goal_path', 'goal'), ('partial_path', 'partial'), ('remainder', 'remainder'),
           ('policy', 'policy'), ('none', 'none'))
  cut = row.get('cut_answers')
  return ', '.join(f'{label} {answers[name]:,}' for name, label in names) + (
      f'; {cut:,} cut by the check' if cut else '')


# the closed-loop runs on the default physics (closed_loop_gpu/): file suffix -> what ran
CLOSED_LOOP_VARIANTS = (
    ('pachs', "PACHS (the default at 3 s: the search's path, the last answer's remainder "
              "replayed in the search, K 128, the policy's fill checked)"),
    ('parallel', 'parallel rollout (256 copies)'),
    ('pachs-q1', "PACHS, 1 s per query (the default there: K 64, the policy's fill not "
                 "checked)"),
    ('parallel-q1', 'parallel rollout, 1 s per query'),
)
# the revisions of runs (closed_loop_gpu/, faithful_gpu/) whose Warp planners collided the T
# with the blocks by Warp's general convex collider, before they used MuJoCo C's box-box
# routine (`fa9f384`)
CONVEX_BOX_REVISIONS = frozenset({'b5c3c48', 'cdaabdc', '0b31967', '65008e1', '2954da4',
                                  'b687e0b'})


def box_contacts(payload: Dict) -> str:
  """How a run's Warp planners collided the T with the blocks: 'convex' or 'box-box'."""
  revision = payload['provenance']['git_revision'].split('+')[0][:7]
  return 'convex' if revision in CONVEX_BOX_REVISIONS else 'box-box'


# closed_loop_gpu/repeat/: runs of the table made again at a later revision (same file names),
# shown below their first runs and pooled with them in the README's sentence
CLOSED_LOOP_REPEATS = 'repeat'


def failures(summary: Dict) -> str:
  """A closed-loop run's failed episodes, how many failed on the policy's steps where the run
  counted them ('-': a run from before the count), and the policy fills it stopped
  (`--fill-check 1`)."""
  if summary.get('failures') is None:
    return '-'
  on_policy, cut = summary.get('failures_on_policy_steps'), summary.get('cut_fills')
  notes = ([] if on_policy is None else [f'{on_policy} on policy steps']) + (
      [f'{cut} fill{"" if cut == 1 else "s"} stopped'] if cut else [])
  return str(summary['failures']) + (f' ({", ".join(notes)})' if notes else '')


def points(value: float) -> str:
  """'N points' of a difference in percentage points, rounded ('1 point')."""
  rounded = f'{value:.0f}'
  return f'{rounded} point' + ('' if rounded in ('1', '-1') else 's')


def closed_loop_rows(src: Sources, folder: str, variants: Sequence[Tuple[str, str]],
                     repeats: Optional[str] = None):
  """The closed-loop table's rows of one folder's runs (and of the same runs made again, in its
  subfolder `repeats`, each below its first run), the rows of the planners' drop from their own
  physics to MuJoCo C, the pooled drops of the layouts run more than once, the first run read,
  and the layouts without a PACHS run."""
  rows, drops, missing, first, pairs = [], [], [], None, {}
  places = ((folder, ''),) + (((f'{folder}/{repeats}', ', run again'),) if repeats else ())
  for layout in CLOSED_LOOP_LAYOUTS:
    if not src.exists(f'{folder}/{layout}_pachs.json'):
      missing.append(layout)
    for variant, label in variants:
      for where, again in places:
        name = f'{where}/{layout}_{variant}.json'
        if not src.exists(name):
          continue
        p = src.load(name)
        first = first or p
        planner = variant.split('-')[0]
        clock = ''.join(f'-{o}' for o in variant.split('-')[1:] if re.fullmatch(r'q[\d.]+', o))
        # the rollout's run at the same clock, of the same place where it has one
        same = next((n for n in (f'{w}/{layout}_parallel{clock}.json' for w in (where, folder))
                     if src.exists(n)), None)
        rollout = summary_of(src.load(same), 'parallel') if same else None
        a = summary_of(p, planner)
        edges = a['evaluations_per_query_mean']
        is_pachs = planner == 'pachs'
        ratio = '-'
        if rollout and is_pachs:  # per query, and per second of query (a search may stop early)
          theirs = rollout['evaluations_per_query_mean']
          per_s = (edges / a['query_time_s_mean']) / (theirs / rollout['query_time_s_mean'])
          clocked = a.get('evaluations_per_clocked_query_mean')
          ratio = f'{num(edges / theirs, 2)} ({num(per_s, 2)}' + (
              f'; {num(clocked / theirs, 2)} to the clock' if clocked else '') + ')'
        rows.append([layout, label + again, box_contacts(p), episodes_solved(a), num(edges),
                     ratio,
                     num(a['iterations_per_query_mean'], 1),
                     num(1000 * a['query_time_s_mean'] / a['iterations_per_query_mean']),
                     str(a['empty_answers']), failures(a),
                     answer_counts(a) if is_pachs else '-'])
        own = f'{where}/{layout}_{variant}-planner-world.json'
        if src.exists(own):
          own_run = src.load(own)
          b = summary_of(own_run, planner)
          drops.append([layout, label + again,
                        ' / '.join(dict.fromkeys([box_contacts(own_run), box_contacts(p)])),
                        episodes_solved(b), episodes_solved(a),
                        points(100 * (b['success_rate'] - a['success_rate'])),
                        f'{failures(b)} / {failures(a)}',
                        ' / '.join(f'`{r["provenance"]["git_revision"][:7]}`'
                                   for r in (own_run, p))])
          pairs.setdefault((layout, variant), []).append((b['success_rate'], a['success_rate']))
  pooled = [f'{layout}, {"PACHS" if variant.startswith("pachs") else "the rollout"} '
            f'{pct(sum(o for o, _ in runs) / len(runs))} in its own physics and '
            f'{pct(sum(c for _, c in runs) / len(runs))} in MuJoCo C, a drop of '
            f'{100 * sum(o - c for o, c in runs) / len(runs):.0f} points ({len(runs)} runs)'
            for (layout, variant), runs in pairs.items() if len(runs) > 1]
  return rows, drops, first, missing, pooled


def query_split(src: Sources, folder: str) -> str:
  """Where the default PACHS's closed-loop queries went, per query time: the search's seconds
  against the whole query's (means over each run's queries, the range over the runs), the
  follow's milliseconds, and the longest query of PACHS and of the rollout."""
  def summaries(variant: str, clock: str) -> List[Dict]:
    names = [f'{where}/{layout}_{variant}{clock}.json' for layout in CLOSED_LOOP_LAYOUTS
             for where in (folder, f'{folder}/{CLOSED_LOOP_REPEATS}')]
    return [summary_of(src.load(name), variant.split('-')[0]) for name in names
            if src.exists(name)]

  parts = []
  for clock, label in (('', '3 s'), ('-q1', '1 s')):
    pachs, rollout = summaries('pachs', clock), summaries('parallel', clock)
    if not pachs:
      continue
    # (runs that wait for the fill after the answer: their choice leaves its follow out)
    after = [a for a in pachs if a.get('fill_wait_s_mean') is not None]
    chosen = [a['choose_s_mean'] for a in after]
    text = (f'at {label} the search took {span([a["search_s_mean"] for a in pachs], 2)} of '
            f'{span([a["query_time_s_mean"] for a in pachs], 2)} a query, following the '
            f'(empty) candidates {span([1e3 * a["follow_s_mean"] for a in pachs], 1, "ms")}'
            + (f', the choice {span([1e3 * c for c in chosen], 0, "ms")}, and after the answer '
               f'the wait for the policy\'s checked fill '
               f'{span([1e3 * a["fill_wait_s_mean"] for a in after], 0, "ms")}, '
               f'{span([1e3 * a["fill_charged_s_mean"] for a in after], 1, "ms")} of it '
               'charged to the next query' if after else '') + '; '
            f'the longest query {max(a["query_time_s_max"] for a in pachs):.2f} s')
    if rollout:
      text += (f' (the rollout\'s {max(a["query_time_s_max"] for a in rollout):.2f} s, '
               f'{span([a["query_time_s_mean"] for a in rollout], 2)} a query)')
    parts.append(text)
  return ('Where a PACHS query went: ' + '; '.join(parts) + '. The rest of a query is the '
          'search\'s setup (the model check on the new states, its arrays) and the choice.'
          ) if parts else ''


CLOSED_LOOP_COLUMNS = ['layout', 'planner', 'T-block contacts', 'solved',
                       'edges per query and episode',
                       '/ rollout\'s (per second of query)', 'iterations per query',
                       'ms per iteration',
                       'empty answers', 'T tipped (failed)', 'PACHS answers']


def closed_loop_sessions(src: Sources) -> str:
  """The closed loop on the default physics, one GPU per planner, Warp planners: PACHS
  against the parallel rollout, with each planner's drop from its own physics to MuJoCo C."""
  folder = 'closed_loop_gpu'
  rows, drops, first, missing, pooled = closed_loop_rows(
      src, folder, CLOSED_LOOP_VARIANTS, CLOSED_LOOP_REPEATS)
  s, prov = first['settings'], first['provenance']
  steps = summary_of(first, 'pachs')['config']['edge_steps']
  return '\n\n'.join([
      f'PushT-Obs on the default physics, the PushT-Fixed model; Warp planners, MuJoCo C '
      f'worlds, each planner alone on its GPU ({prov["device"]}; `{folder}/run.sh`, one line '
      f'of runs per GPU). {s["instances"]} instances x {s["rounds"]} rounds per layout and '
      f'planner, all {s["instances"] * s["rounds"]} episodes planned together, '
      f'{s["query_time"]:g} s per query, {s["execute"]} actions executed per query, at most '
      f'{s["max_queries"]} queries; 95% intervals over the instances. gate-mirror and '
      'wall-right are the held-out layouts (`heldout_layouts.py`). PACHS replans through '
      '`replan.Session` (docs/closed_loop.md). An empty answer plays one policy action. Each '
      'file is named by what ran (`run.sh` runs it by that name). '
      + (f'", run again": the same run made again at a later revision '
         f'(`{folder}/{CLOSED_LOOP_REPEATS}/`). '
         if src.exists(f'{folder}/{CLOSED_LOOP_REPEATS}')
         else '')
      + 'T-block contacts: how the '
      'Warp planners collided the T with the blocks: "box-box" by MuJoCo C\'s box-box routine, '
      'as the world does (the default since `fa9f384`); "convex" by Warp\'s general convex '
      'collider, whose contacts differ from MuJoCo C\'s in about a third of the T\'s block '
      'contacts ([physics](#pusht-physics-agreement-and-penetration)): runs made before.',
      table(CLOSED_LOOP_COLUMNS, rows),
      '/ rollout\'s: PACHS\'s edges over the rollout\'s at the same clock; in parentheses per '
      'second of query (a PACHS query ends before its time once every episode\'s search has '
      'stopped, its goal found and improved)'
      + (', and PACHS\'s edges in the searches that ran to the clock ("to the clock": an '
         'episode whose search stopped before it evaluated no more that query)'
         if any('to the clock' in cell for row in rows for cell in row) else '') + '. '
      'ms per iteration: a query\'s time over its iterations (a PACHS iteration evaluates '
      f'edges of {steps} control steps, so {steps} physics calls one after another; a rollout '
      'iteration one call of one step for every copy). '
      'An episode whose T tipped over has failed: no edge leaves that state (`env.is_failure`; '
      '"on policy steps": failed while playing an empty answer\'s policy action or the '
      'policy\'s fill of a short answer).'
      + (f' The default at 3 s (K 128) not run on: {", ".join(missing)}.' if missing else '')
      + ' ' + query_split(src, folder),
      'The plans executed in the planners\' own physics (`--world planner`, Warp) against the '
      'MuJoCo C world, same protocol (where the two runs\' revisions differ, so may the code '
      'they ran: the drop then also holds what changed between them):',
      table(['layout', 'planner', 'T-block contacts', 'own physics', 'MuJoCo C', 'drop',
             'T tipped (failed), own physics / MuJoCo C', 'revisions, own physics / MuJoCo C'],
            drops)
      + ('\n\nOver the runs of a layout run again: ' + '; '.join(pooled) + '.' if pooled else ''),
      traced_tilts(src),
      traced_tilts(src, 'closed_loop_trace_gpu'),
      'The variants that lost (the session\'s candidates, K 256, no replay, no policy fill, '
      'the fill unchecked at 3 s and checked at 1 s) and the screens on blocks without a '
      'margin: [measured and not kept](#measured-and-not-kept).'])


def traced_tilts(src: Sources, folder: str = 'closed_loop_trace_cpu',
                 margin_deg: float = 20.0) -> str:
  """The traced closed loops (`closed_loop.py --trace 1`) of a folder: per run, the episodes
  solved and failed, how far PACHS's plans tilted the T, and the failed episodes whose plan
  had tilted it past margin_deg in the 10 world steps before the world's T crossed
  `pusht.MAX_T_TILT`."""
  import numpy as np  # pylint: disable=import-outside-toplevel
  from pachs_jax.envs import pusht  # pylint: disable=import-outside-toplevel
  tilt = lambda q: np.degrees(np.asarray(pusht.t_tilt(np.nan_to_num(q).astype(np.float32))))
  rows, replays, first = [], [], None
  for layout in CLOSED_LOOP_LAYOUTS:
    name = f'{folder}/{layout}_pachs.json'
    if not src.exists(name):
      continue
    p = first = src.load(name)
    trace = np.load(os.path.join(src.root, RESULTS, name[:-len('.json')] + '.pachs.trace.npz'))
    a, steps = summary_of(p, 'pachs'), trace['steps']
    planned = np.where(np.isnan(trace['planned_qpos'][..., 0]), 0.0,
                       tilt(trace['planned_qpos']))
    planned = [planned[e, :steps[e] + 1] for e in range(len(steps))]  # per world state
    failed = np.flatnonzero(trace['failed'])
    again = f'{name[:-len(".json")]}.replay.json'
    if src.exists(again):  # `trace_replay.py`: the failed episodes' last queries replayed
      replays.append(replay_sentence(layout, again, src.load(again), margin_deg))
    rows.append([layout, 'PACHS', box_contacts(p), f'{a["successes"]}/{a["episodes"]}',
                 failures(a),
                 f'{sum(bool(np.any(t > margin_deg)) for t in planned)}/{len(planned)}',
                 f'{max(t.max() for t in planned):.1f}',
                 f'{sum(bool(np.any(planned[e][-11:] > margin_deg)) for e in failed)}'
                 f'/{len(failed)}'])
  if not rows:
    return ''
  s = first['settings']
  how = (f'Warp planners on the CPU, MuJoCo C worlds, {s["instances"]} instances, '
         f'{s["budget"]:,} evaluations an episode and query, K {s["pop_size"]}, no clock'
         if first['provenance']['device'].startswith('cpu') else
         f'the default at {s["query_time"]:g} s per query, MuJoCo C worlds, {s["instances"]} '
         f'instances x {s["rounds"]} rounds')
  return '\n\n'.join([
      f'Traced closed loops (`closed_loop.py --trace 1`; {first["provenance"]["device"]}, '
      f'{how}): how far the plans tilt the T (the world\'s T tips over at '
      f'{np.degrees(pusht.MAX_T_TILT):g} degrees, where the episode fails).',
      table(['layout', 'planner', 'T-block contacts', 'solved', 'T tipped (failed)',
             f'episodes whose plans tilted the T past {margin_deg:g} degrees',
             'largest planned tilt (degrees)',
             f'failed episodes whose plan tilted the T past {margin_deg:g} degrees in the 10 '
             'steps before it tipped'], rows)] + replays)


def replay_sentence(layout: str, name: str, r: Dict, margin_deg: float) -> str:
  """A sentence on `trace_replay.py`'s result r (file name): how closely its replays reproduced
  the world and the plan, and how each failed episode's T tipped: in both engines alike (the
  executed actions, the plan's or the policy's, tip it), in MuJoCo C only where the plan kept
  it within margin_deg (an engine difference), or after a plan that tilted it past that."""
  from pachs_jax.envs import pusht  # pylint: disable=import-outside-toplevel
  limit = math.degrees(pusht.MAX_T_TILT)
  both = [ep for ep in r['episodes'] if ep['planner_replay_tilt_at_failure'] >= limit]
  flat = [ep for ep in r['episodes'] if ep not in both
          and (ep['plan_max_tilt'] or 0.0) < margin_deg]
  rows = [row for ep in r['episodes'] for row in ep['rows']]
  apart = lambda a, b: max((abs(row[a] - row[b]) for row in rows if row[b] is not None),
                           default=0.0)
  count = len(r['episodes'])
  touching = lambda ep: ', '.join(sorted({c for row in ep['rows'] for c in row['t_contacts']})
                                  ) or 'neither a block nor the stick'
  after = lambda ep: (' with no planned step in its last query' if ep['plan_max_tilt'] is None
                      else f' after a plan of at most {ep["plan_max_tilt"]:.1f} degrees')
  engine = '; '.join(
      f'episode {ep["episode"]}: {ep["planner_replay_tilt_at_failure"]:.1f} degrees in '
      f'{r["planner_physics"]}, {ep["rows"][-1]["tilt_c_replay"]:.1f} in MuJoCo C, the T '
      f'touching {touching(ep)}' for ep in flat)
  alike = '; '.join(
      f'episode {ep["episode"]}: {ep["rows"][-1]["tilt_c_replay"]:.1f} degrees in MuJoCo C, '
      f'{ep["planner_replay_tilt_at_failure"]:.1f} in {r["planner_physics"]}, '
      + ('on a policy step' if ep.get('on_policy_step') else 'on a step of the plan')
      + f'{after(ep)}, the T touching {touching(ep)}' for ep in both)
  parts = []
  if both:
    parts.append(f'in {len(both)} both engines tipped the T alike ({alike})')
  if flat:
    parts.append(f'in {len(flat)} the plan kept the T within {margin_deg:g} degrees and the '
                 f'planner\'s physics did too, where MuJoCo C tipped it, an engine difference '
                 f'({engine})')
  rest = count - len(both) - len(flat)
  if rest:
    parts.append(f'in {"the others" if parts else "each"} the plan had tilted the T past '
                 f'{margin_deg:g} degrees itself')
  text = '; '.join(parts)
  return (f'{layout}\'s {count} failed episode{"" if count == 1 else "s"}, each last query\'s '
          f'actions replayed from the world\'s state (`trace_replay.py`, '
          f'{r["planner_physics"]}; `{name}`): the MuJoCo C replay\'s tilt at most '
          f'{apart("tilt_c_replay", "tilt_world"):.2f} degrees from the world\'s, the '
          f'planner\'s at most {apart("tilt_planner_replay", "tilt_plan"):.2f} from the plan\'s. '
          + text[0].upper() + text[1:] + '.')


def command_walls(p: Dict, count: int) -> Tuple[Optional[float], List[float], str]:
  """(cold wall, warm walls, search summary) of the real `pachs plan` command of `count`
  instances in a bench_startup result."""
  rows = [c for c in p['commands'] if c['instances'] == count]
  cold = next((c['process_wall_s'] for c in rows if c['run'] == 'cold'), None)
  warm = [c['process_wall_s'] for c in rows if c['run'] == 'warm']
  return cold, warm, next((c['summary'] for c in rows if c['run'] == 'warm'), '')


def span(values: Sequence[float], digits: int = 1, unit: str = 's') -> str:
  """'a-b s' of the values with `digits` decimals (or 'a s' where they round alike)."""
  if not values:
    return '-'
  low, high = f'{min(values):.{digits}f}', f'{max(values):.{digits}f}'
  return f'{low} {unit}' if low == high else f'{low}-{high} {unit}'


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
    cold, warm, summary = command_walls(job, 30)
    found = re.search(r'found (\d+/\d+)', summary)
    out['job'] = (f'{cold:.1f} s cold, {span(warm)} warm' + (
        f', goals found in {found.group(1)} instances at the CPU budget' if found else '')
        + f' ({job["provenance"]["device"]}, {job["provenance"]["host_cpus"]} CPUs)')
  if placeholder(suite):
    out['suite'] = placeholder(suite)
  else:
    cold = ', an empty compilation cache' if 'cache empty' in suite['provenance'].get('note', '') else ''
    out['suite'] = (f'{suite["process_wall_s"] / 60:.1f} min for `{suite["command"]}`, the '
                    f'default tier ({suite["summary"]}; {suite["provenance"]["host_cpus"]} '
                    f'CPUs{cold})')
  return out


def search_seconds(run: Dict) -> float:
  """The search time a `pachs plan` run printed."""
  return float(re.search(r'search time ([0-9.]+) s', run['printed']).group(1))


def speed(src: Sources) -> str:
  """Start-up of `pachs plan`, search throughput, compaction, several GPUs."""
  start = src.load('engines/plan_startup_warp.json')
  walls = {}
  for r in start['walls']:
    if r['run'] == 'B':
      walls.setdefault(r['label'], []).append(r['process_wall_s'])
  plan_rows = [[label, span(walls[key])] for label, key in (
      ('first run on a fresh machine (Warp compiles its kernels)', 'first_on_fresh_machine'),
      ('cold (JAX caches empty, Warp kernels cached)', 'cold'), ('warm', 'warm'),
      ('warm, XLA_PYTHON_CLIENT_PREALLOCATE=false', 'warm, XLA_PYTHON_CLIENT_PREALLOCATE=false'))]
  now = src.load('engines/plan_startup_improve_warp.json')['runs']
  now_rows = [[label, span([r['process_wall_s'] for r in now if r['run'] == key]),
               span([search_seconds(r) for r in now if r['run'] == key])]
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
                      span([search_seconds(r) for r in chosen])])
  imports = h100['imports_s']
  claims = cpu_claims(src)
  search = []
  for name in ('bench_search_budget_i1_150.json', 'bench_search_budget_i30.json'):
    for r in src.load(name)['rows']:
      search.append([r['instances'], r['K'], num(r['evaluated']), num(r['wall_s']),
                     num(r['edges_per_s']), f'{r["search_over_raw"]:.2f}',
                     pct(r['lane_utilization_mean'])])
  search.sort(key=lambda r: (r[0], r[1]))
  compact = src.load('bench_compact.json')['rows'][0]
  baseline = src.load('bench_compact_baseline.json')['rows'][0]
  scale = [[r['K'], r['devices'], num(r['wall_s']), f'{r["speedup"]:.2f}x', r['found']]
           for r in src.load('bench_scale.json')['rows']]
  reacher = src.load('bench_search_reacher_cpu.json')['rows'][0]
  return '\n\n'.join([
      '`pachs plan --task pusht-obs` (30 instances) on one GPU with Warp physics (`--backend '
      'auto` picks it), today\'s default, process wall and the search time it prints (s), one '
      'H200:',
      table(['run', 'process wall', 'search'], now_rows),
      'The same command on an H100 host at a later revision (two fresh machines). The GPU '
      'machine unpacks its packages without compiled bytecode (pip compiles it on install): '
      'there the imports of the package, JAX, MuJoCo, MJX and MuJoCo Warp took '
      f'{span(imports["without_bytecode"])}, and {span(imports["with_bytecode"])} once compiled '
      '(`python -X importtime`):',
      table(['run', 'process wall', 'search'], h100_rows),
      'The command with the default before the first goal\'s path was improved, on an H200, '
      'with and without the GPU memory preallocated at the first allocation:',
      table(['run', 'process wall'], plan_rows),
      f'On a CPU-only machine (MuJoCo C edges, 20,000 evaluations per instance), '
      f'`pachs plan --task pusht-obs`: {claims["job"]}. The test suite '
      f'(`python -m pytest`): {claims["suite"]}.',
      'Search throughput (MJX physics) when every instance spends its whole budget (goals never '
      'accepted), against `env.evaluate` alone at the same batch:',
      table(['instances', 'K', 'edges evaluated', 'wall (s)', 'edges/s', 'search / raw',
             'lanes used'], search),
      f'On a CPU-only machine the search\'s own arrays grow with the budget: '
      f'{reacher["instances"]} Playground ReacherEasy instances at {num(reacher["budget"])} '
      f'evaluations each (MJX, K {reacher["K"]}) searched {reacher["iterations"]} iterations '
      f'in {num(reacher["wall_s"])} s ({reacher["wall_s"] / reacher["iterations"] * 1e3:.1f} ms '
      f'each), {reacher["search_over_raw"]:.3f} of raw env steps at the same batch.',
      f'Compaction (simulating only the live instances\' edges), {compact["runs_per_device"]} '
      f'PushT-Obs runs, K {compact["K"]}, MJX: {num(compact["wall_s"])} s against '
      f'{num(baseline["wall_s"])} s without ({compact["found"]} and {baseline["found"]} found).',
      'The instance axis over several GPUs of one host (150 PushT-Obs runs, MJX):',
      table(['K', 'GPUs', 'wall (s)', 'speed-up', 'found'], scale)])


def engines(src: Sources) -> str:
  """MuJoCo Warp, MJX and MuJoCo C: step rates, the same search on each, search over raw."""
  bench = src.load('engines/bench_engines_h200.json')
  ratio = [[r['layout'], r['engine'], f'{r["over_mujoco_c"]:.1f}x']
           for r in bench['ratios'] if r['worlds'] == 16384]
  same = []
  for name, label in (('open_loop_two-gaps_warp', 'MuJoCo Warp'), ('open_loop_two-gaps_mjx', 'MJX')):
    payload = src.load(f'engines/{name}.json')
    for planner, who in (('pachs', 'PACHS'), ('parallel', 'parallel rollout')):
      row = summary_of(payload, planner)
      same.append([label, who, solved(row), num(row['batch_wall_s']),
                   num(row['cost_success_mean'])])
  search = [[r['instances'], r['K'], num(r['edges_per_s']),
             num(r['raw_env_steps_per_s_same_batch']), f'{r["search_over_raw"]:.2f}']
            for r in src.load('engines/search_over_raw_warp.json')['rows']]
  backends = src.load('bench_backends.json')
  gpu_cpu = [[r['K'], num(r['gpu_mjx_edges_per_s']), num(r['cpu_mujoco_c_edges_per_s']),
              f'{r["gpu_over_cpu"]:.1f}x', f'{r["cpu_search_over_raw"]:.2f}']
             for r in backends['rows']]
  cpu = {r['backend']: r for r in src.load('bench_cpu_backend.json')['evaluate']}
  return '\n\n'.join([
      'PushT env steps/s at 16,384 worlds on policy-rollout states in contact, over MuJoCo C on '
      'all the host\'s threads in the same run (one H200):',
      table(['layout', 'engine', 'over MuJoCo C'], ratio),
      'PushT-Obs two-gaps, PACHS (the default before the first goal\'s path was improved) and the '
      'parallel rollout with each GPU engine, one machine and revision, 150 runs at 100,000 '
      'evaluations (batch wall in s):',
      table(['physics', 'planner', 'solved', 'wall', 'mean cost (solved)'], same),
      'PACHS run to budget with Warp physics against `env.evaluate` alone at the same batch:',
      table(['instances', 'K', 'edges/s', 'raw env steps/s', 'search / raw'], search),
      f'GPU edges (MJX) against CPU edges (MuJoCo C on {backends["cpu_threads"]} threads of the '
      f'same host), PushT-Obs, {backends["rows"][0]["instances"]} instances at '
      f'{backends["rows"][0]["budget"]:,} evaluations:',
      table(['K', 'GPU edges/s', 'CPU edges/s', 'GPU / CPU', 'CPU search / raw'], gpu_cpu),
      f'On a 2-core CPU, MuJoCo C evaluates a batch of {cpu["mujoco-c"]["batch"]} PushT '
      f'edges in {1000 * cpu["mujoco-c"]["median_s"]:.1f} ms, MJX on the CPU in '
      f'{cpu["mjx (cpu)"]["median_s"]:.1f} s ({cpu["speed-up"]["edges_per_s"]:,.0f}x).'])


# the planar physics' open-loop files of the variants below (MJX, five layouts)
PLANAR_OPEN_LOOP = '`c5c1a4f`: `open_loop_pusht-obs_<layout>.json`'

# What was measured and not kept: (what it changed, its result: text or a function of the
# files, the commit whose tree holds its result files and where they are under experiments/results)
LEDGER: Tuple[Tuple[str, object, str], ...] = (
    ('Open loop on the planar physics (planar T, soft blocks): the suite with Warp, the second '
     'instance set and the held-out layouts, PushT-Fixed and -Rand with every planner, the '
     'original paper\'s planners on the layouts (MJX), the policy alone per layout',
     'PACHS ahead of or level with the rollout on every layout (detour 122 against 86 of 150); '
     'superseded by the faithful physics\' runs',
     '`c5c1a4f`: `suite_gpu/`, `novelty_power_gpu/`, `open_loop_pusht-*.json`, '
     '`eval_layouts_cpu.json`'),
    ('Chains restart at the start, not at novel cells (MJX)',
     '648/750 solved against 706/750 for the default then', PLANAR_OPEN_LOOP),
    ('Rollout share 0.5: half the lanes extend chains (MJX)',
     '616/750 solved against 706/750 for the default then', PLANAR_OPEN_LOOP),
    ('Edges of 8 transitions without chain lanes (MJX)',
     '556/750 solved against 706/750 for the default then', PLANAR_OPEN_LOOP),
    ('Novel restarts draw every coarse cell alike (each node 1 / n for the n nodes of its cell)',
     '571/600 solved against 579/600 for 1 / sqrt(n) on the 4 calls of the other instance set '
     'and the held-out layouts; over ten calls it reached goals later at middle budgets',
     '`faabee8`: `novelty_power_gpu/` (ten calls)'),
    ('After the first goal, stop: the first goal\'s path is the answer',
     'as many runs solved within the call-to-call variation; its paths cost more than the '
     'rollout\'s on every layout and instance set, the default\'s less',
     '`fe3f7b1`: `after_goal_gpu/`; `3f7dc23`: `after_goal_cpu/` (MuJoCo C, 10 instances)'),
    ('Improve to the budget (allowance inf instead of 3)',
     'paths a little cheaper than with allowance 3, but every instance spends its whole budget',
     '`fe3f7b1`: `after_goal_gpu/*_inf`; `3f7dc23`: `after_goal_cpu/`'),
    ('Improve without restarting chains on the goal\'s path (prune)',
     'paths no cheaper than the default\'s on gate and wall', '`3f7dc23`: `after_goal_cpu/`'),
    ('Widening: the last instances pop 2, 4 or 8 x K edges (`--widen-factors 2,4,8`)',
     'shorter batch walls and as many runs solved at 100,000 evaluations, but its success '
     'curves trail compaction alone\'s at middle budgets, where they fall behind the rollout\'s',
     '`b19e7db`: `widen_gpu/`, `engines/open_loop_*_warp_widen.json`'),
    ('More edges per iteration with Warp physics (K 128, 256, 512 on two-gaps; K 128 on the '
     'suite)', 'shorter walls; from K 256 more evaluations per run, and K 512 solved fewer runs',
     '`9212aa1`: `engines/open_loop_*_warp_k*.json`'),
    ('Compaction ladder of 1/8 and 1/64 of the lanes (the default: 1/2, 1/4, 1/8, 1/64)',
     'batch walls as long or longer on every layout measured',
     '`856107d`: `default_gpu_runs/` (with the default of then on more seeds and calls)'),
    ('Chains restart at the start with probability 0.25, at novel cells otherwise',
     'no lag behind the rollout removed on gate; fewer runs solved on two-gaps and detour',
     '`9e669eb`: `start_share_gpu/`'),
    ('Closed loop: the session\'s candidates (the remainder and the policy\'s rollout, '
     'followed before each search; faithful physics, one H200 per planner)',
     'wall 78% against 92% for the search\'s path alone (K 256: 80% against 90%), gate 80%, '
     'detour 2% against 5%; following them took 1.5 s of each 3 s query and they won 17 of '
     '1,329 answers on wall; on the planar physics they had won',
     '`19d1b29`: `closed_loop_gpu/*_pachs-remainder-policy.json`, '
     '`*_pachs-k256-remainder-policy.json`; planar: `9053f4e`: `closed_loop_gpu/`'),
    ('Closed loop: K 256 edges per iteration (the search\'s path alone)',
     '1.56x the rollout\'s edges per query on wall (14,470 against 9,303; K 64: 0.62x), but fewer '
     'episodes solved: wall 88% against 90%, gate-mirror 67% against 78%; at 1 s per query wall '
     '54% against 66%, gate-mirror 4% against 27% (1.8-3.5 iterations a query: too shallow). Before, '
     'wall 90% against 92%, detour 5% against 5%',
     '`e5d802a`: `closed_loop_gpu/*_pachs-k256*.json`; `19d1b29`: '
     '`closed_loop_gpu/wall_pachs-k256.json`, `detour_pachs-k256.json`'),
    ('Closed loop: the search\'s path alone, without the last answer\'s remainder replayed in '
     'the search (the default before)',
     'as many episodes solved (wall 92% against 89%, gate 90% against 94%, detour 5% against '
     '4%), but 57 of wall\'s 1,019 answers empty against none with the replay, which also '
     'keeps every answer at least as good as the remainder in the planners\' physics',
     '`39f8ec9`: `closed_loop_gpu/wall_pachs.json`, `detour_pachs.json`, `gate_pachs-k256.json` '
     '(gate\'s run without replay, at `39f8ec9`, was not committed)'),
    ('Closed loop: the planners\' edges may tilt the T at most 20 degrees (unless no further '
     'than it was), not 30 (where an episode fails)',
     'on the soft blocks (one H200, K 64) wall 81% against 89%, slot 72% against 72%, '
     'gate-mirror 82% against 78%, T tipped in MuJoCo C in 12, 2 and 15 episodes against 10, 11 '
     'and 17; on the default physics, traced on two-gaps (Warp planners on a CPU, 8 episodes, '
     '8,000 evaluations a query) 1 solved against 2, 3 goal answers against 11, 3 Ts tipped '
     'against 4, all on policy steps: the plans that reach two-gaps\' goal tilt the T past 20 '
     'degrees; the code left the tree',
     '`17207d4`: `closed_loop_gpu/*_pachs-tilt20.json`; `ac8ec30`: '
     '`closed_loop_trace_cpu/two-gaps_pachs-tilt20.json`'),
    ('Closed loop: the parallel rollout\'s answer replaying its best path over the whole '
     'episode length (the rollouts\' result before `311dda7`): about 1.3 s of each query',
     'on wall 27 iterations and 6,309 edges per query, 50% solved, against 51, 9,303 and 64% '
     'replaying the path\'s length; at 1 s per query 4% (one action an answer) against 25%; '
     'gate 29% against 62%, slot 30% against 53%, two-gaps 8% against 12%, gate-mirror 13% '
     'against 23%, wall-right 26% against 42%',
     '`9053f4e`: `closed_loop_gpu/wall_parallel.json`; `fa40569`: `closed_loop_gpu/*_parallel*.json`'),
    ('PushT-Obs with every action drawn from the actor (no uniform draws), faithful physics, '
     'open loop on one H200',
     'PACHS solved gate 39/150, wall 94/150, detour 5/150, against 143, 149 and 8 with a quarter '
     'drawn uniformly; on a 2-core CPU (MuJoCo C, 10 instances, 20,000 evaluations) 1, 6 and 0 '
     'of 10 against 5, 8 and 0, the actor-only searches stopping at the budget (gate 9 times, '
     'wall 4, detour 10)',
     '`39f8ec9`: `faithful_gpu/gate.json`, `wall.json`, `detour.json`; `4efca4c`: `uniform_cpu/`'),
    ('Harder block impedance against penetration (block solimp 0.999-0.9999, also with a 1 mm '
     'margin), the faithful 2.5 ms step',
     'the stick-block maximum unchanged on every layout (gate 4.45, wall 2.38, two-gaps 3.61 mm) '
     'and the T-block maximum 2.1-3.6 mm (0.2-4.3 mm with the margin): at the 2.5 ms step\'s '
     'stiffness limit only a shorter step lowers both (1.25 ms x 40, above)',
     '`57c2f98`: `physics/penetration_impedance.json`'),
    ('PushT-Obs open loop on blocks without a margin (the default before the 3 mm margin; Warp, '
     'one H200), and Warp against MuJoCo C on them',
     'PACHS solved gate 143, wall 149, detour 8 and slot 144 of 150, the rollout 11, 64, 0 and '
     '44: the same lead as with the margin; superseded by the default\'s runs',
     '`cdaabdc`: `faithful_gpu/gate.json`, `wall.json`, `detour.json`, `slot.json`, '
     '`agreement.json`'),
    ('Closed loop on the planar physics (Warp planners, sessions with both candidates)',
     'superseded by the faithful physics\' runs', '`9053f4e`: `closed_loop_gpu/`'),
    ('Closed loop with MJX planners (float32 plans executed in MuJoCo C), also with the plans '
     'executed in the planners\' own physics',
     'PushT-Fixed and PushT-Rand solved in nearly every episode by every planner; on the layouts '
     'the Warp sessions above replace it', '`f10a75b`: `closed_loop_pusht-*`'),
    ('Real-time answer of an unfinished query: best f (the original\'s) or min h, against min '
     'cost', 'best f mostly answers with a state one edge from the start',
     '`f10a75b`: `closed_loop_pusht-obs_*_answer-*`'),
    ('The default before the first goal\'s path was improved, on the second instance set and '
     'the held-out layouts (MJX), and on the suite with Warp physics',
     'superseded by the default\'s planar runs (the first ledger row)',
     '`9212aa1`: `instance_set1/`, `heldout_gpu/`, `engines/open_loop_*_warp.json`'),
    ('The first transfer to the GPU in a thread beside the imports',
     'saved nothing measurable in warm runs', '`787deab`: `engines/plan_startup_first_transfer.json`'),
    ('XLA\'s GPU autotuning off at start-up', 'no faster cold',
     '`7452f30`: `engines/plan_startup_autotune_*.json`'),
    ('SAC on the free T with a failed end charged 25 (not absorbing), with the tip height cost',
     lambda src: training_run(src, 'height, failure cost 25, scratch'),
     'in this tree: `training/runs.json`'),
    ('The free T\'s cost without the tip height term (four runs, failure cost 0 or 25)',
     lambda src: training_run(src, 'friction 1.65, fine-tuned'),
     'in this tree: `training/runs.json`'),
    ('The planar-physics PushT-Fixed model on the faithful physics (the fine-tuning\'s start)',
     '1 of 16 canonical instances solved in MuJoCo C, 10 T tipped: its tip rode at the T\'s '
     'top edge (4.6 cm)', '`5476e47`: `training/policy_physics.json`'),
    ('Closed loop on blocks without a margin (the `soft-blocks` preset, the default before '
     'the 3 mm margin) on gate, slot, detour and wall-right, K 64',
     'PACHS / rollout 94% / 62%, 72% / 53%, 4% / 1%, 85% / 42%: superseded by the default\'s '
     'runs', '`a1346a3`: `closed_loop_soft_gpu/gate_*`, `slot_*`, `detour_*`, `wall-right_*`'),
    ('Closed loop on blocks without a margin (the `soft-blocks` preset) on wall, two-gaps and '
     'gate-mirror: K 64 against K 128, at 3 s and 1 s per query, and gate-mirror\'s plans '
     'executed in the planners\' own physics',
     'at 3 s PACHS K 64 / K 128 / rollout: wall 90 / 94 / 64%, two-gaps 52 / 60 / 12%, '
     'gate-mirror 78 / 80 / 23% (K 64 0.62-0.76x the rollout\'s edges per query, K 128 '
     '0.93-1.1x); at 1 s wall 66 / 65 / 25%, gate-mirror 27 / 13 / 1%; gate-mirror\'s drop '
     'from the planners\' physics to MuJoCo C 8 points for PACHS (86% to 78%), 22 for the '
     'rollout: superseded by the default physics\' runs, which keep K 128 at 3 s and K 64 at 1 s',
     '`c32036e`: `closed_loop_soft_gpu/`'),
    ('Closed loop: a short answer not followed by policy actions (the next query comes sooner; '
     '`--fill-with-policy 0`), soft blocks, K 64',
     'at 3 s level (wall 89% against 90%, gate-mirror 77% against 78%); at 1 s wall 82% against '
     '66% but gate-mirror 22% against 27%, with 14 empty answers: the fill stays',
     '`a1346a3`: `closed_loop_soft_gpu/*_pachs-nofill*.json`'),
    ('Closed loop: each answer executed up to the first action one of 8 perturbed copies of '
     'its start could not take (`--check-copies 8`, 1 mm / 0.01 rad), K 64, default physics',
     'wall 87% against 88%, gate-mirror 76% against 80%, two-gaps 37% against 32%; Ts tipped '
     '7, 13, 28 against 10, 16, 36; 101, 139 and 236 answers cut: off by default',
     '`4304295`: `closed_loop_gpu/*_pachs-k64-check.json`'),
    ('Closed loop at 3 s per query with K 64 (the default before; default physics, one H200 '
     'per planner, 100 episodes per layout)',
     'solved gate 83%, slot 64%, wall 88%, detour 2%, two-gaps 32%, gate-mirror 80%, '
     'wall-right 86% against K 128\'s 94, 65, 91, 4, 46, 76 and 82%, with 0.60-0.77x the '
     'rollout\'s edges per query (K 128: 0.86-1.2x)',
     '`0be5a14`: `closed_loop_gpu/*_pachs-k64.json`'),
    ('The lattice table\'s probe loop writing a claim without first reading the slot\'s keys '
     '(XLA then copied the whole table at every probe round; CPU, 64 ReacherEasy instances at '
     '100,000 evaluations, MJX, K 16)',
     'the same search (737 iterations, 55,776 evaluations, 64 goals) in 34.6 s against 11.0 s '
     'with the table written in place; first call with compiling 50.5 s against 28.0 s',
     '`78eaed8`: `bench_search_reacher_cpu_table_copied.json`'),
    ('The heap\'s pop reading its searched segments back from the buffer it had just written '
     '(XLA then copied the edge heap\'s keys at every iteration; the same CPU benchmark)',
     'the same search in 11.0 s against 8.9 s with the minima taken from the keys it read',
     '`78eaed8`: `bench_search_reacher_cpu.json`'),
    ('The improve offer reading the popped goal\'s g from the pool apart from the edges\' f '
     '(XLA then copied the pool\'s costs, f32 [I, P], twice at every iteration; the same CPU '
     'benchmark)', 'the same search in 9.6 and 10.4 s against 7.7 and 8.5 s with g read once '
     '(two runs each, alternating, one machine); 8.9 s at the time of its run',
     '`413791f`: `bench_search_reacher_cpu.json`'),
    ('Closed loop: each query searches to its clock\'s end, improving a goal it found '
     '(`--improve-allowance inf` instead of 3; default physics, K 128, one H200)',
     'edges per query 0.92-1.15x the rollout\'s (wall 9,994, gate 9,423, gate-mirror 9,396), '
     'but no more episodes solved: wall 89% against 91% and 84% (the default run again, 9.0 '
     'queries an episode; its first run 5.9, this 8.7), gate 93% against 94%, gate-mirror 75% '
     'against 76% and 75%: the default\'s queries still end once every search has improved its '
     'goal', '`796d8ed`: `closed_loop_gpu/*_pachs-full.json`'),
    ('Closed loop: each search starts from the episode\'s last search\'s nodes per coarse '
     'cell, so that its chains restart away from where the earlier searches went '
     '(`Session.keep_cells`; default physics, K 128, one H200)',
     'fewer episodes solved: gate 87% against 94% (its goals per query otherwise as the '
     'default\'s), wall 84% against 91% and 84% (the default run again), detour 3% against 4%; '
     'the code left the tree', '`796d8ed`: `closed_loop_gpu/*_pachs-cells.json`'),
    ('Closed loop: a real-time answer at least 10 actions deep where the search has such a '
     'state (`SearchConfig.realtime_min_depth` 10, the actions executed per query), so that no '
     'executed action is a policy fill outside the search; default physics, one H200',
     'fewer Ts tipped (episodes failed on policy steps 0-3 against 0-28, policy fill steps '
     '203-242 against 13-1,650 a run) but not more episodes solved: gate-mirror 82% against '
     '76% and two-gaps 51% against 46% (the screen), then gate 93% against 94%, wall 85% '
     'against 91% and 84% (the default run again), slot 61% against 65%, wall-right 78% against 82%, and at 1 s per query wall '
     '67% against 73%, gate-mirror 27% against 29%: the episodes it kept from tipping ran out '
     'of queries; the code left the tree', '`4662f89`: `closed_loop_gpu/*_pachs*-depth10.json`'),
    ('Edges of 5 and 10 transitions on PushT-Obs (divisors of the 10 actions a closed-loop '
     'query executes, so that the executed answer ends on a node of the last search), open loop, '
     'MuJoCo C on a 2-core CPU, 10 instances x 1 seed at 20,000 evaluations',
     'gate 7 and 8 of 10 against 5 with 8 transitions, wall 9 and 8 against 9: no loss on this '
     'small sample; in the closed loop 10 transitions solved no more episodes (the next row)',
     '`97ee399`: `edge_steps_cpu/`'),
    ('Closed loop with edges of 10 transitions (the 10 actions a query executes end on a node '
     'of its search; default physics, one H200)',
     'detour 2% against 4%, wall 85% against 91% and 84%, gate-mirror 69% against 76% and 75%: '
     'no better anywhere (within the intervals); edges stay 8 transitions',
     '`1486d8a`: `closed_loop_gpu/*_pachs-h10.json`'),
    ('Closed loop keeping the last search\'s subtree, edges of 10 transitions: each query\'s '
     'search started from the last one\'s answer node at the executed depth, the world\'s state '
     'as its state, with its descendants (g and depth less the root\'s), their OPEN entries, '
     'lattice cells and visit counts, at most half the budget\'s nodes (default physics, one '
     'H200)',
     'against edges of 10 alone: detour 2% against 2%, wall 86% against 85%, gate-mirror 62% '
     'against 69%, with 14.7 queries an episode against 11.7 and 361 policy fill steps against '
     '33: goals below the new root, reached from states simulated from the planned start, '
     'ended answers short of the world\'s goal; with those goals dropped, gate-mirror 65% and '
     'wall 77% (10.6 queries an episode against 7.8): the kept states are the planned ones, so '
     'paths through them need not hold from the world\'s state; detour gained nothing; the '
     'code left the tree', '`1486d8a`: `closed_loop_gpu/*_pachs-h10-keep*.json`'),
    ('Detour, the search\'s settings and budget in open loop (PushT-Obs, the PushT-Fixed model, '
     'MuJoCo C on a 2-core CPU, 10 instances x 1 seed at 100,000 evaluations): rollout share '
     '0.5 (more best-first lanes), w 1, uniform share 0.5; and the default at 500,000 (5 '
     'instances)',
     'none beyond noise: the default 0 of 10, rollout share 0.5 0, w 1 0, uniform share 0.5 1; '
     'at 500,000 evaluations 1 of 5, its first goal after 347,648: the T must first be pushed '
     'away from the goal, against the critic, and a closed-loop query gives the search about '
     '10,000 evaluations an episode, so no setting of the search reaches detour in closed loop '
     'with this model (the GPU suite: 6 of 150 at 100,000)',
     '`d314823`: `detour_cpu/`'),
    ('Closed loop at 1 s per query with K 96 (toward the rollout\'s edges per query there; '
     'default physics, one H200)',
     'edges per query 1.01x the rollout\'s on wall (2,681 against 2,646) and gate-mirror '
     '(2,452 against 2,419), against K 64\'s 0.84x and 0.80x, but fewer episodes solved where '
     'depth counts: gate-mirror 18% [7, 31] against 29% (3.7 iterations a query against 4.1, '
     '38 episodes failed on policy steps against 28), wall 74% against 73%: K stays 64 at 1 s',
     '`bb4f809`: `closed_loop_gpu/*_pachs-q1-k96.json`'),
    ('Closed loop at 1 s per query with K 80 (between K 64, the default there, and K 96; '
     'default physics, one H200)',
     'edges per query 0.92x the rollout\'s on wall (2,442 against 2,646) and 0.86x on '
     'gate-mirror (2,088 against 2,419), against K 64\'s 0.84x and 0.80x, but fewer episodes '
     'solved: wall 67% [56, 77] against 73%, gate-mirror 25% [16, 34] against 29% (3.7 '
     'iterations a query against 4.1, 45 Ts tipped against 38): K stays 64 at 1 s',
     '`315898a`: `closed_loop_gpu/*_pachs-q1-k80.json`'),
    ('PushT-Obs open loop on blocks without a margin against the 3 mm margin, a screen before '
     'the GPU runs (PACHS, MuJoCo C planners on a 2-core CPU, 10 instances x 1 seed, 20,000 '
     'evaluations)',
     'solved gate 5 against 5, wall 8 against 9, slot 2 against 3, two-gaps 0 against 0; the '
     'margin stayed', '`0a630fe`: `hard_blocks_cpu/`'),
    ('Warp planners colliding the T with the blocks by Warp\'s general convex collider (MuJoCo '
     'Warp\'s default for box pairs), not by MuJoCo C\'s box-box routine as the world does '
     '(default physics; closed loop at 3 s on one H200, MuJoCo C worlds)',
     'closed loop, PACHS in MuJoCo C: slot 65% against 90%, two-gaps 46% against 71%, '
     'gate-mirror 75.5% (two runs) against 84%, gate 94% against 99%, wall 87.5% (two runs) '
     'against 94%, wall-right 82% against 93%, detour 4% against 5%; its drop from its own '
     'physics 20, 34 and 17 points against 3, 3 and 6, on wall-right not measured against 2; '
     'the rollout in MuJoCo C 37%, 0%, 22%, 57%, 52%, 41% and 2% against 52%, 20%, 42%, 73%, '
     '62%, 59% and 2%, its drop on slot and two-gaps 9 and 19 points against 9 and -3; on gate '
     'and wall both planners\' own-physics runs (PACHS 95% and 94%, the rollout 61% and 76%) '
     'left with their collider; the policy\'s pushes '
     'replayed in Warp (on a CPU, 16 starts a layout): the T\'s position error p90 after 10 '
     'steps 2.9 mm on two-gaps, 3.1 on gate-mirror, 2.1 on wall-right, 1.3 on detour, against '
     'at most 0.01 mm; T-block contacts differing from MuJoCo C\'s in 29-43% of drawn poses '
     'against under 1%; traced on a CPU (8 episodes, 8,000 evaluations a query), two-gaps 2 '
     'solved against 6; the convex era\'s traces (slot, gate-mirror, wall-right) found plans '
     'tilting the T past 20 degrees in most episodes and one failure where Warp kept the T flat '
     '(17.4 degrees) and MuJoCo C tipped it (36.5)',
     '`6788096`: `closed_loop_gpu/{slot,two-gaps,gate-mirror}_*.json`, '
     '`closed_loop_gpu/repeat/gate-mirror_*.json`, `closed_loop_trace_cpu/two-gaps_pachs*`; '
     '`b236397`: `physics/agreement_warp_convexbox_cpu.json`; `96d1e22`: '
     '`closed_loop_trace_cpu/{slot,gate-mirror,wall-right}_pachs*`; `eeeedd4`: '
     '`closed_loop_gpu/{gate,wall,detour,wall-right}_{pachs,parallel}.json`, '
     '`closed_loop_gpu/{gate,wall}_*-planner-world.json`, '
     '`closed_loop_gpu/repeat/wall_pachs.json`; `1f6c582`: '
     '`closed_loop_gpu/{slot,gate-mirror,detour}_parallel-q1.json` (the rollout at 1 s: 6%, '
     '1% and 0%)'),
    ('The closed loop through a server on blocks without a margin, K 64 (wall, one H200)',
     'PACHS 95% [91, 99] served, 90% [83, 96] in process; 5,654 edges per query and episode '
     'against 5,760: superseded by the default physics\' run with K 128',
     '`b5c3c48`: `serve_gpu/wall_pachs-served.json`'),
    ('The server at the task\'s budget with K 64 (one request of 30 PushT-Obs episodes, '
     '100,000 evaluations each, one H200)',
     '29.7 s, of which the search 29.7 s; 29 reached the goal: superseded by the server of '
     'K 128 (`--query-time 3`)', '`b5c3c48`: `serve_gpu/task_budget/bench_serve.json`'),
    ('Closed loop on blocks without a margin, wall in the planners\' own physics, K 64',
     'PACHS 99% (90% in MuJoCo C), rollout 72% (64%): superseded by the default physics\' '
     'runs', '`4304295`: `closed_loop_soft_gpu/wall_*-planner-world*`'),
    ('The server warming every bucket (1, 4, 16, 64, 256) before it was ready (one H200)',
     'start to ready 212 s; one client 2.08 s, its search 2.07 s: the server now answers once '
     'its largest bucket is warm and warms the others while idle',
     '`4304295`: `serve_gpu/gpus1_five_buckets/`'),
    ('A wider pop for a small request (toward the server\'s 0.5 s for one PushT-Obs episode '
     'at 10,000 evaluations): one search of 5 episodes, Warp, one H200',
     'K 1024: 1.73 s, 0 of 5 found; K 256: 2.31 s, 0 of 5 found; K 64: 3.90 s, 3 of 5 found: '
     'the time falls far less than the iterations (each costs more with K) and the wider '
     'searches find no goal; K stays the task\'s', '`ce9adf1`: `serve_gpu/lone_pop_size.json`'),
    ('A fill the check stopped, ended 2 actions sooner still (`closed_loop.py --fill-margin 2`), '
     'so that the next query starts further from the invalid edge: traced on a CPU, gate-mirror '
     '(8 episodes, 8,000 evaluations a query)',
     'the same episodes, steps and failures as the default\'s trace '
     '(`closed_loop_trace_cpu/gate-mirror_pachs.json`): the stopped fills before its empty '
     'answer stopped at 0 actions, the answer\'s own end being the state the policy tips the T '
     'from, which no margin on the fill reaches; the code left the tree',
     '`4d82a80`: the code (the run\'s file not kept: identical to the default\'s)'),
    ('The policy\'s fill not checked at 3 s per query (`closed_loop.py --fill-check 0`; default '
     'physics, one H200 per planner, the seven layouts, the same instances)',
     'in MuJoCo C 536 episodes solved against the check\'s 547 (44 solved only without the '
     'check, 55 only with it) and 66 Ts tipped over against 33 (gate 1 against 3, wall 5 '
     'against 2, detour 17 against 11, two-gaps 21 against 10, gate-mirror 15 against 3, '
     'wall-right 5 against 2, slot 2 against 2); in the planners\' own physics 550 solved '
     'against 569; edges per query 0.87-1.08x the rollout\'s against 0.85-1.03x. Traced on a '
     'CPU (8 instances, 8,000 evaluations a query, no clock) two-gaps solved 6/8 and '
     'gate-mirror 5/8 without the check (7/8 and 5/8 with it); of their 3 failed episodes, '
     'replayed from the world\'s states (`trace_replay.py`), 2 tipped the T alike in both '
     'engines on a policy step and 1 was an engine difference (a plan that kept the T within '
     '20 degrees in Warp, 30.3 in MuJoCo C): the check stays on at 3 s',
     '`1b7cee0`: `closed_loop_gpu/*_pachs-noguard.json`, '
     '`closed_loop_gpu/*_pachs-noguard-planner-world.json`; `b1ec95b`: '
     '`closed_loop_trace_cpu/*_pachs-noguard*`; `7a3f2fb`: '
     '`closed_loop_trace_cpu/two-gaps_pachs*` (the checked trace)'),
    ('The policy\'s fill checked at 1 s per query (`--fill-check 1`, K 64; default physics, '
     'one H200 per planner, the seven layouts, the same instances)',
     'in MuJoCo C 288 episodes solved against 329 unchecked (93 solved only with the check, '
     '134 only without: gate 62 against 78, wall 80 against 69, two-gaps 34 against 29, '
     'gate-mirror 25 against 36, wall-right 45 against 55, slot 41 against 56, detour 1 '
     'against 6) and 83 Ts tipped over against 169. Its follow took 84-126 ms of each query, '
     'the search 0.74-0.81 s against 0.88-0.92 s (edges per query 0.59-0.68x the rollout\'s '
     'against 0.73-0.83x), and the episodes it kept upright ran out of queries instead (empty '
     'answers on two-gaps 28 against 0); in its own physics gate 65% and wall 82%, drops of 3 '
     'and 2 points (the rollout\'s -9 and -2): the check runs in queries of 2 s or more '
     '(`TaskSpec.replan_fill_check_s`)',
     '`1b7cee0`: `closed_loop_gpu/*_pachs-guard-q1.json`, '
     '`closed_loop_gpu/{gate,wall}_pachs-guard-q1-planner-world.json`'),
    ('The policy\'s fill followed on the query\'s clock, after the choice (the default at 3 s '
     'until the follow moved to a thread after the answer; gate and wall-right, default '
     'physics, one H200 per run)',
     'the choice and follow took 16 and 50 ms a query against 6 ms now, the search 2.74 and '
     '2.82 s against 2.86 and 2.87 s; edges per query 0.91x and 0.88x the rollout\'s against '
     '0.87x and 0.88x, solved 98% and 93% against 98% and 95%: the gain in search time is '
     'within the runs\' spread of edges per query',
     '`1b7cee0`: `closed_loop_gpu/repeat/{gate,wall-right}_pachs.json`'),
    ('The policy\'s fill checked at 1 s per query with its follow after the answer (on the '
     'session\'s thread; the wait past the answer\'s own actions charged to the next query; '
     'K 64, default physics, one H200 per run, the seven layouts, the same instances)',
     'in MuJoCo C 316 episodes solved against 329 unchecked (115 solved only with the check, '
     '128 only without: gate 61 against 78, wall 77 against 69, two-gaps 33 against 29, '
     'gate-mirror 30 against 36, wall-right 63 against 55, slot 50 against 56, detour 2 '
     'against 6) and 88 Ts tipped over against 169, but 296 episodes out of queries against '
     '202. The choice took 6 ms, the wait for the fill 55-84 ms a query, of which 9-35 ms '
     'were charged; the search 0.83-0.87 s against 0.88-0.92 s (edges per query 0.66-0.78x '
     'the rollout\'s against 0.73-0.83x); empty answers 77 against 6. On the query\'s clock '
     'the same runs (`c365457`, not kept) solved 289: the follow off the clock won 27 '
     'episodes and the check still loses at 1 s',
     '`aaa0e99`: `closed_loop_gpu/*_pachs-guard-q1.json`'),
    ('The closed loop\'s first queries on the clock: an episode\'s first query searched 1 '
     'iteration (its programs\' first run, which loads MuJoCo Warp\'s kernel modules, on the '
     'clock) and the session\'s first follow and the choice\'s compile were charged to the '
     'next queries (the default at 3 s and 1 s, the rollout with its first run on the clock '
     'too; default physics, one H200 per run, 100 episodes a layout)',
     'PACHS at 3 s solved gate 97% (98% run again), wall 97%, two-gaps 80%, gate-mirror 86%, '
     'wall-right 94% (95% run again), slot 86% and detour 8%, against 98, 100, 86, 96, 97, 95 '
     'and 7% with 8-9 iterations in each of an episode\'s first three queries; the rollout 73, '
     '62, 20, 42, 59, 52 and 2% against 67, 74, 15, 49, 72, 57 and 4%; at 1 s PACHS gate 78%, '
     'wall 69% and two-gaps 29% against 87, 88 and 36%, the rollout 18, 31 and 0% against 15, '
     '32 and 2%',
     '`16cdef3`: `closed_loop_gpu/*_{pachs,parallel}.json`, '
     '`closed_loop_gpu/{gate,wall,two-gaps}_{pachs,parallel}-q1.json`, '
     '`closed_loop_gpu/repeat/`'),
    ('The rollout at 1 s per query with Python\'s garbage collector free to run during the '
     'clock (gate-mirror and wall-right, default physics, one H200 per run)',
     'an episode\'s third query searched 2 iterations, against 14-16 and 9-10 in the first '
     'two ([14, 10, 2] and [15, 9, 2]: a full collection, 0.4-0.65 s over a compiled '
     'process\'s million objects on a CPU core, in one query\'s clock); solved 5% and 22%. '
     'With the collector paused in the clocked loop: [16, 10, 10] and [16, 10, 11], the '
     'longest query 1.03 s against 1.09 and 1.13 s, solved 8% and 23%',
     '`d559736`: `closed_loop_gpu/{gate-mirror,wall-right}_parallel-q1.json`'),
)


def training_run(src: Sources, name: str) -> str:
  """A training run's best evaluation success and its env steps (training/runs.json)."""
  run = next(r for r in src.load('training/runs.json')['runs'] if r['name'] == name)
  return (f'best evaluation success {pct(run["eval_success_deterministic_best"])} after '
          f'{run["env_steps"] / 1e6:.1f} M env steps ("{name}" in the training runs)')


def ledger(src: Sources) -> str:
  """One row per variant or default that was measured and lost."""
  rows = [[what, result(src) if callable(result) else result, where]
          for what, result, where in LEDGER]
  return '\n\n'.join([
      'Variants and earlier defaults that were measured and lost, one row each. Where their '
      'result files left this tree, the row names the commit whose tree holds them under '
      '`experiments/results`; the report of commit `a51f31b` (`docs/results.md`) has their '
      'tables. The numbers here are computed from files in this tree:',
      table(['what changed', 'result', 'files'], rows)])


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
      'The candidates that chose the faithful physics, measured with the planar-physics '
      'model\'s pushes. MJX (float32, the GPU planners\' physics of then) against the MuJoCo C '
      'float64 world: the T\'s position (mm) / angle (degrees) error at the 90th '
      'percentile after 10 control steps, per layout (fields over the planar preset; "today": '
      'the planar preset itself; "free": the free T under gravity, friction 3; the faithful '
      'physics is "free mu3 2.5ms x20 stiff" at friction 1.65):',
      table(['physics'] + list(LAYOUTS), agree_rows),
      'The deepest T-block / stick-block penetration (mm) over policy rollouts in MuJoCo C:',
      table(['physics'] + list(LAYOUTS), deep_rows),
      warp_box_contacts(src)])


def warp_box_contacts(src: Sources) -> str:
  """The T's block contacts in MuJoCo Warp against MuJoCo C, by Warp's convex collider and by
  the box-box routine (physics/contacts_warp_cpu.json), the stick's contacts with the T
  (physics/contacts_stick_warp_cpu.json), and the Warp planners' agreement with
  the MuJoCo C world on the default physics (physics/agreement_warp_boxbox_cpu.json)."""
  contacts = src.load('physics/contacts_warp_cpu.json')
  bins = {}
  for r in contacts['rows']:
    cell = bins.setdefault(r['tilt_deg'], [0, 0, 0, 0.0, 0.0, 0.0])
    n = r['samples']
    cell[0] += n
    cell[1] += r['differ_convex']
    cell[2] += r['differ_box-box']
    cell[3] += n * r['mean_contacts_mujoco_c']
    cell[4] += n * r['mean_contacts_convex']
    cell[5] += n * r['mean_contacts_box-box']
  contact_rows = [[tilt, f'{n:,}', f'{c:,} ({pct(c / n)})', f'{b:,} ({pct(b / n)})',
                   ' / '.join(num(x / n, 2) for x in (mc, mx, mb))]
                  for tilt, (n, c, b, mc, mx, mb) in bins.items()]
  stick = src.load('physics/contacts_stick_warp_cpu.json')
  stick_rows = [[r['tilt_deg'], r['depth_mm'], f'{r["samples"]:,}',
                 f'{r["differ"]:,} ({pct(r["differ"] / max(r["samples"], 1))})',
                 f'{num(r["mean_contacts_mujoco_c"], 2)} / {num(r["mean_contacts_warp"], 2)}']
                for r in stick['rows']]
  agreement = src.load('physics/agreement_warp_boxbox_cpu.json')
  cells = {}
  for r in agreement['rows']:
    cells.setdefault(r['layout'], {})[r['horizon']] = (
        f'{num(r["position_mm_p90"], 2)} / {num(r["angle_deg_p90"], 2)}')
  horizons = sorted({h for c in cells.values() for h in c})
  agree_rows = [[layout] + [c.get(h, '-') for h in horizons] for layout, c in cells.items()]
  s = contacts['settings']
  return '\n\n'.join([
      'The T\'s contacts with the blocks, MuJoCo Warp (its CPU kernels) against MuJoCo C '
      f'(`physics_agreement.py contacts`, {contacts["provenance"]["device"]}): the T drawn '
      'near a block of each layout, lifted up to 2 cm, any yaw, tilted within the range; '
      f'{s["samples"]} poses per layout and range where either engine finds a T-block contact '
      '(MuJoCo C\'s at most 5 mm deep). Contacts differ where their number differs or one lies '
      'more than 0.5 mm from the other engine\'s. Warp collides box pairs by its general convex '
      'collider unless the model disables it (`nativeccd`); PushT\'s model does, so that Warp '
      'uses MuJoCo C\'s box-box routine:',
      table(['tilt (degrees)', 'poses', 'differ: convex collider', 'differ: box-box',
             'contacts per pose: MuJoCo C / convex / box-box'], contact_rows),
      'The stick\'s contacts with the T, the same comparison (`physics_agreement.py stick`, '
      f'{stick["provenance"]["device"]}): the arm at its home pose, the stick upright, the T '
      'drawn at any yaw, tilted within the range, and pressed against the stick by its bar or '
      'stem up to 12 mm deep (the stick\'s radius is 8 mm), by the deepest contact in MuJoCo '
      'C. Warp collides the capsule and the box by its port of MuJoCo C\'s routine; they part '
      'where the stick lies parallel to the T\'s face, a flat T against an upright stick:',
      table(['tilt (degrees)', 'depth (mm)', 'poses', 'differ',
             'contacts per pose: MuJoCo C / Warp'], stick_rows),
      'The Warp planners (box-box) against the MuJoCo C world on the default physics, the '
      'shipped policy\'s pushes as above (`physics_agreement.py agreement`, '
      f'{agreement["provenance"]["device"]}, {agreement["settings"]["instances"]} starts a '
      'layout): the T\'s position (mm) / angle (degrees) error at the 90th percentile after '
      'the control steps; with Warp\'s convex box contacts: '
      '[measured and not kept](#measured-and-not-kept):',
      table(['layout'] + [f'after {h} step{"s" if h != 1 else ""}' for h in horizons],
            agree_rows)])


PLAYGROUND_LOOP_PLANNERS = {'single': 'the policy alone', 'parallel': 'parallel rollout (256 copies)',
                            'pachs': "PACHS (the task's search, replanning session)"}


def playground(src: Sources) -> str:
  """MuJoCo Playground's reacher tasks: the policy, the parallel rollout and PACHS."""
  rows = []
  for name in ('playground_reachereasy.json', 'playground_reacherhard.json'):
    p = src.load(name)
    for s in p['summaries']:
      rows.append([p['task'].split(':')[-1], s['planner'], f'{s["solved"]}/{s["instances"]}',
                   num(s['mean_cost_solved']), num(s['mean_evaluated']), num(s['wall_s'])])
  loop, first = [], None
  protocol = ('instances', 'rounds', 'query_time', 'execute', 'max_queries', 'budget')
  for name in ('closed_loop_playground_cpu/reachereasy.json',
               'closed_loop_playground_cpu/reacherhard.json'):
    p = src.load(name)
    first = first or p
    differ = [k for k in protocol if p['settings'][k] != first['settings'][k]]
    if differ or p['provenance']['device'] != first['provenance']['device']:
      raise ValueError(f'{name}: its runs differ from the first Playground closed loop\'s in '
                       f'{", ".join(differ) or "device"}; the table states one protocol')
    for a in p['summary']:
      loop.append([p['task'].split(':')[-1],
                   PLAYGROUND_LOOP_PLANNERS.get(a['planner'], a['planner']),
                   episodes_solved(a), num(a['steps_to_success_mean']), num(a.get('queries_per_episode_mean')),
                   num(a.get('evaluations_per_query_mean')), num(a.get('query_time_s_mean'))])
  s, prov = first['settings'], first['provenance']
  return '\n\n'.join([
      'The shipped Playground models on their 30 canonical instances (budgets in the planner '
      'names):',
      table(['task', 'planner', 'solved', 'mean cost (solved)', 'mean evaluations', 'wall (s)'],
            rows),
      f'In closed loop (`closed_loop.py --task playground:NAME`, {prov["device"]}): MJX '
      'planners, each episode\'s world the task\'s MuJoCo model in MuJoCo C around the env\'s '
      f'own step (docs/closed_loop.md); {s["instances"]} instances x {s["rounds"]} rounds, '
      f'{s["query_time"]:g} s per query for all episodes together, {s["execute"]} actions '
      f'executed per query, at most {s["max_queries"]} queries '
      f'({s["max_queries"] * s["execute"]} steps), '
      f'{s["budget"]:,} evaluations per query and episode; '
      '95% intervals over the instances. Steps: world steps to the goal, the solved episodes\' '
      'mean (the policy alone: its steps):',
      table(['task', 'planner', 'solved', 'steps to the goal', 'queries per episode',
             'edges per query and episode', 'query (s)'], loop)])


def bench_serve_rows(data: Dict) -> List[List[str]]:
  """A bench_serve result's rows: clients, answers/s, speed-up, latency, search, overhead."""
  return [[str(c['clients']), num(c['answers_per_s']), f'{num(c["speedup_vs_alone"], 2)}x',
           num(c['latency_median_s']), num(c['search_median_s']), num(c['overhead_median_s']),
           num(c['mean_requests_per_batch'], 2)] for c in data['clients']]


def serving(src: Sources) -> str:
  """`pachs serve`: answers per second and latency of one client alone and of several at once,
  on a CPU and on one GPU."""
  data = src.load('serve_cpu/bench_serve.json')
  settings, server, big = data['settings'], data['server'], data['big_request'][0]
  header = ['clients', 'answers/s', 'vs alone', 'latency (s)', 'search (s)', 'overhead (s)',
            'requests per batch']
  gpu = src.load('serve_gpu/gpus1/bench_serve.json')
  g_settings, g_server = gpu['settings'], gpu['server']
  g_big = ' '.join(
      f'{b["instances"]} episodes at once ({b["requests"]} request(s) gathered into one '
      f'search): {num(b["latency_median_s"])} s, of which the search '
      f'{num(b["search_median_s"])} s.' for b in gpu['big_request'])
  task_budget = src.load('serve_gpu/task_budget/bench_serve.json')
  t_big = task_budget['big_request'][0]
  return '\n\n'.join([
      f'A resident server ([serving.md](serving.md)) on {settings["task"]} with '
      f'{server["physics"]} physics, {settings["budget"]:,} evaluations per request, batches '
      f'of at most {settings["max_batch"]} episodes ({settings["window_ms"]:g} ms gathering '
      f'window); each client sends {settings["requests"]} requests of one episode. Start to '
      f'ready: {num(server["start_to_ready_s"], 1)} s. One request of {big["instances"]} '
      f'instances: {num(big["latency_median_s"])} s, of which the search '
      f'{num(big["search_median_s"])} s.',
      table(header, bench_serve_rows(data)),
      'On a CPU the physics cost grows with the batch, so batching gains little.',
      f'The same benchmark on one GPU ({gpu["provenance"]["device"]}, revision '
      f'`{gpu["provenance"]["git_revision"]}`, `serve_gpu/gpus.sh 1`), {g_server["physics"]} '
      f'physics, {g_settings["budget"]:,} evaluations per request, each client '
      f'{g_settings["requests"]} requests, the server warming the buckets these requests use '
      f'({", ".join(map(str, g_server["buckets"]))} episodes): start to ready '
      f'{num(g_server["start_to_ready_s"], 1)} s, to every bucket warm '
      f'{num(g_server["start_to_every_bucket_warm_s"], 1)} s. {g_big}',
      table(header, bench_serve_rows(gpu)),
      f'At the task\'s budget ({task_budget["server"]["budget"]:,} evaluations per episode), '
      f'the server of `serve_gpu/run.sh` (K {served_pop_size(src)}, '
      f'{task_budget["provenance"]["device"]}): one request of {t_big["instances"]} episodes: '
      f'{num(t_big["latency_median_s"])} s, of which the search '
      f'{num(t_big["search_median_s"])} s; {num(t_big["reaching_goal_median"])} of them '
      'reached the goal.',
      serving_gpus(src),
      served_closed_loop(src)])


SERVE_GPU_RUN = re.compile(r'gpus(\d+)(-threads)?(-wait([\d.]+))?(-k(\d+))?$')


def serving_gpus(src: Sources) -> str:
  """The server's batches over 1, 2 and 4 GPUs of one host (each `gpus.sh` run in serve_gpu/:
  gpus<N>[-threads][-wait<ms>][-k<K>]): 150 episodes at once and 16 clients, against one
  GPU."""
  folder = os.path.join(src.root, RESULTS, 'serve_gpu')
  found = sorted((int(m.group(1)), bool(m.group(2)), float(m.group(4) or 0),
                  int(m.group(6) or 0), name)
                 for name in os.listdir(folder) for m in [SERVE_GPU_RUN.match(name)] if m)
  runs = {key[:4]: src.load(f'serve_gpu/{key[4]}/bench_serve.json') for key in found}
  big = {k: next((b for b in r['big_request'] if b['instances'] == 150), None)
         for k, r in runs.items()}  # None: the run ended before that phase
  many = {k: next(c for c in r['clients'] if c['clients'] == 16) for k, r in runs.items()}
  default = (1, False, 0.0, 0)
  one = runs[default]
  alone = next(c for c in one['clients'] if c['clients'] == 1)
  base = big[default]['latency_median_s']
  rows = [[str(key[0]), '-' if key[0] == 1 else 'threads' if key[1] else 'mesh',
           f'restarting, at most {key[2]:g} ms' if key[2] else
           f'{runs[key]["settings"]["window_ms"]:g} ms', str(key[3] or 'default'),
           runs[key]['provenance']['git_revision'],
           *([num(big[key]['latency_median_s']), f'{num(base / big[key]["latency_median_s"], 2)}x',
              num(big[key]['reaching_goal_median'])] if big[key] else ['not reached'] * 3),
           num(many[key]['answers_per_s']),
           num(many[key]['mean_requests_per_batch'], 2)] for key in runs]
  return '\n\n'.join([
      'The server on several GPUs of one H200 host (`pachs serve --devices N`, `serve_gpu/'
      'gpus.sh N`; split: `mesh`, one search sharded over the GPUs, or `threads`, a part per '
      'GPU from its own thread; `--max-wait-ms`: the gathering window restarts at each '
      'request), 10,000 evaluations per episode: 150 episodes asked at once (30 instances x 5 '
      f'seeds), and 16 clients of one episode each. At revision '
      f'`{one["provenance"]["git_revision"]}` the 1- and 2-GPU servers ran at once on GPUs 0 '
      'and 1-2 of one host, the 4-GPU server alone ("not reached": the device command\'s '
      'limit ended the run before that phase):',
      table(['GPUs', 'split', 'gathering window', 'K', 'revision', '150 episodes: latency (s)',
             'vs 1 GPU', 'reaching the goal', '16 clients: answers/s', 'requests per batch'],
            rows),
      f'On one GPU, one episode alone took {num(alone["search_median_s"])} s and 150 at once '
      f'{num(big[default]["search_median_s"])} s: 150 times the physics for '
      f'{num(big[default]["search_median_s"] / alone["search_median_s"], 2)} times the '
      'time. Most of an iteration\'s cost is a fixed cost per physics call (the kernels of 8 '
      'control steps of 20 physics steps each), which every GPU pays again when the episodes '
      'are split; only the part that grows with the worlds is divided.'])


def served_closed_loop(src: Sources) -> str:
  """The closed loop's protocol through a server against the same protocol in process."""
  served = summary_of(src.load('serve_gpu/wall_pachs-served.json'), 'pachs')
  # in process as served: the policy's fill not checked
  own = summary_of(src.load('closed_loop_gpu/wall_pachs-noguard.json'), 'pachs')
  prov = src.load('serve_gpu/wall_pachs-served.json')['provenance']
  return (f'The closed loop through a server (`serve_gpu/run.sh`: `pachs serve --query-time 3`, '
          f'K {served_pop_size(src)}, and `closed_loop.py --server`, {prov["device"]}; wall, the '
          'protocol of [the closed loop](#closed-loop-on-the-faithful-physics)): PACHS solved '
          f'{episodes_solved(served)} of its episodes, in process {episodes_solved(own)}; '
          f'{num(served["evaluations_per_query_mean"])} edges per query and episode against '
          f'{num(own["evaluations_per_query_mean"])}.')


def served_pop_size(src: Sources) -> str:
  """The K of the server that `serve_gpu/run.sh` started (its closed loop's config names
  it)."""
  config = summary_of(src.load('serve_gpu/wall_pachs-served.json'), 'pachs')['config']
  found = re.search(r'\bK (\d+)', str(config))
  return found.group(1) if found else '?'



def training(src: Sources) -> str:
  """SAC on the faithful PushT physics with MuJoCo Warp: throughput against MJX-JAX and the
  training runs, those of the shipped models among them."""
  bench = src.load('training/bench_training.json')
  speed_rows = [[r['engine'], f'{r["num_envs"]:,}', f'{r["physics_env_steps_per_s"]:,.0f}',
                 f'{r["training_env_steps_per_s"]:,.0f}', num(r['epoch_s']),
                 num(r['physics_compile_s'], 2)] for r in bench['rows']]
  ratio = bench['warp_over_mjx']
  runs = src.load('training/runs.json')['runs']
  run_rows = [[r['name'], f'{r["env_steps"] / 1e6:.1f} M', f'{r["env_steps_per_s_median"]:,.0f}',
               pct(r['success_rate_last_tenth']), pct(r['eval_success_deterministic_best']),
               num(r['episode_return_last_tenth'], 3), r['note'] or ''] for r in runs]
  return '\n\n'.join([
      f'Training throughput on the faithful preset ({bench["task"]}, one GPU, '
      f'`bench_training.py`): env steps/s of the physics alone and of whole training epochs '
      f'(env step, replay insert, {bench["sac_config"]["grad_updates_per_step"]} gradient '
      f'updates of batch {bench["sac_config"]["batch_size"]:,} per step). Warp over MJX-JAX: '
      f'{num(ratio["physics_env_steps_per_s"], 2)}x the physics, '
      f'{num(ratio["training_env_steps_per_s"], 2)}x the training.',
      table(['engine', 'envs', 'physics env steps/s', 'training env steps/s', 'epoch (s)',
             'physics compile (s)'], speed_rows),
      'Training runs on the faithful physics with Warp, 2,048 envs each (three of the first '
      'four beside another run on their GPU, the last four alone). Success: the training '
      'episodes\' over the last tenth of the epochs, and the best periodic evaluation (256 '
      'instances, deterministic policy); return: the training episodes\' mean. A tipped T ends an episode; charged '
      'nothing, it was the cheapest end (rewards are negative costs) and the policy tipped the '
      'T on purpose; charged 25, the policy left the T alone. Two changes made the task '
      'learnable: the failed end charged as absorbing (its step cost as if kept for ever, '
      '`SACConfig.absorbing_failure`), and a cost on the stick tip\'s height off the T\'s half '
      'height (`PushTConfig.w_height`; the planar model had learnt to push at the T\'s top '
      'edge, which tips a free T). The shipped PushT-Fixed model is the fine-tuned run, '
      'PushT-Rand\'s the scratch run, each after under 7 minutes of one H200:',
      table(['run', 'env steps', 'env steps/s', 'training success', 'evaluation success',
             'episode return', 'what'], run_rows),
      _learner_move(src)])


def _learner_move(src: Sources) -> str:
  """A run moved through its learner file against the same run trained straight."""
  data = src.load('training/learner_move.json')
  settings, summary = data['settings'], data['summary']
  rows = [[run, pct(summary[run]['success']), num(summary[run]['cost'], 3)]
          for run in ('straight', 'moved')]
  return '\n\n'.join([
      f'A run moved between machines through its learner file (`learner_move.py`, the '
      f'point-mass task on a CPU, {len(data["rows"])} seeds, {settings["steps"]:,} env steps, '
      f'moved at {settings["move_at"]:,}: the replay buffer refilled by the policy) against '
      'the same run trained straight; the final deterministic policy on 256 start nodes, mean '
      'over the seeds:',
      table(['run', 'success', 'cost'], rows)])


SECTIONS: Tuple[Tuple[str, Callable[[Sources], str]], ...] = (
    ('PushT on the faithful physics (the default)', faithful),
    ('The layouts: the policy alone', policy_per_layout),
    ('Open loop: Panda-Shelf', open_loop_tasks),
    ('Closed loop on the faithful physics', closed_loop_sessions),
    ('Speed and start-up', speed),
    ('Physics engines: MuJoCo Warp, MJX and MuJoCo C', engines),
    ('MuJoCo Playground', playground),
    ('Serving: a resident planner', serving),
    ('PushT physics: agreement and penetration', physics),
    ('Training on the faithful physics with Warp', training),
    ('Measured and not kept', ledger),
)


def anchor(title: str) -> str:
  """GitHub's anchor of a markdown heading."""
  return re.sub(r'[^a-z0-9 -]', '', title.lower()).replace(' ', '-')


def results_markdown(root: str = ROOT) -> Tuple[str, List[str]]:
  """docs/results.md and the result files it cites."""
  parts = ['# Results', '',
           'Generated by `python experiments/report.py` from the result files in '
           '`experiments/results/`; do not edit by hand. Each section lists its files by the device '
           'and revision of the runs in them; each file, and the `.md` beside it, holds the '
           'command of each run. The protocol is in '
           '[experiments.md](experiments.md).', '',
           'PushT\'s default physics is the faithful one (ManiSkill PushT-v1\'s free T, hard '
           'blocks), its results in the first section, its training in "Training on the '
           'faithful physics with Warp" and its CPU serving runs. The other PushT sections were '
           'measured on the planar preset (`physics=\'planar\'`: a T on joints, soft blocks) '
           'with the models trained on it, which commit `5476e47` holds; they stay as the '
           'measurements of the search\'s variants until the faithful physics repeats them.',
           '']
  cited = []
  for title, section in SECTIONS:
    src = Sources(root)
    body = read_section(title, section, src)
    parts += [f'## {title}', '', body, '', '**Sources**', '']
    parts += read_section(title, lambda _: provenance_lines(
        [(path, read_result(root, path)) for path in src.cited], 'docs'), src)
    cited += src.cited
    parts.append('')
  return '\n'.join(parts).rstrip() + '\n', cited


def headline_table(root: str = ROOT) -> Tuple[str, List[str]]:
  """The README's headline block (between the markers) and the files it cites."""
  src = Sources(root)
  rows = []
  for task, name in (('PushT-Fixed', 'faithful_gpu/pusht-fixed.json'),
                     ('PushT-Rand', 'faithful_gpu/pusht-rand.json')):
    p = src.load(name)
    rows.append((task, p, 'pachs', p))  # (runs, PACHS's default there, the policy alone's)
  for layout in FAITHFUL_LAYOUTS:
    rows.append((f'PushT-Obs, {layout}', src.load(f'faithful_gpu/{layout}.json'),
                 'pachs-improve', None))
  shelf = src.load('open_loop_shelf.json')
  rows.append(('Panda-Shelf', shelf, 'pachs', shelf))
  body = []
  for task, p, name, policy in rows:
    pachs, parallel = summary_of(p, name), summary_of(p, 'parallel')
    single = summary_of(policy, 'single') if policy else None
    rollout_10k = pct(curve_at(p, 'parallel', 10000)[1]) if parallel else '-'
    at_10k = f'{pct(curve_at(p, name, 10000)[1])} / {rollout_10k}'
    body.append([task, pct(pachs['success_rate']),
                 pct(parallel['success_rate']) if parallel else 'not run',
                 pct(single['success_rate']) if single else '-', at_10k,
                 num(pachs['evaluated_mean']), f'{num(pachs["batch_wall_s"], 2)} s',
                 cost_ratio(p, name, 'parallel') if parallel else '-'])
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
      f'{" or one ".join(devices)}, each task\'s default, PushT on its default (faithful) '
      f'physics with MuJoCo Warp planners (PushT-Obs: the first goal\'s path improved, a '
      f'quarter of the actions drawn uniformly'
      + (', the T-block contacts by Warp\'s convex collider, not yet as MuJoCo C does'
         if {box_contacts(r[1]) for r in rows if r[0].startswith('PushT-Obs')} == {'convex'}
         else '') + ', '
      f'[results](docs/results.md#pusht-on-the-faithful-physics-the-default)). Path '
      f'cost: mean ratio over the runs both solved. Start-up of `pachs plan --task pusht-obs` '
      f'(30 instances, one GPU, Warp, the planar physics; three machines, H200 and H100): '
      f'{span(cold)} cold, {span(warm)} warm. On a '
      f'2-core CPU: '
      f'{claims["job"]}. '
      f'Tests: {claims["suite"]}. Every table, its device, command and revision: '
      f'[docs/results.md](docs/results.md).',
      '',
      closed_loop_headline(src),
  ]
  return '\n'.join(lines), src.cited


def closed_loop_headline(src: Sources) -> str:
  """The README's closed-loop sentence: PACHS (today's default) against the rollout on each
  layout run, each planner's episodes pooled over its runs (first runs and repeats), at the
  original's 3 s per query and, where run, at 1 s."""
  folder, devices, repeated, convex = 'closed_loop_gpu', set(), [], []

  def pairs_at(clock: str) -> List[str]:
    pairs = []
    for layout in CLOSED_LOOP_LAYOUTS:
      names = [f'{folder}/{layout}_{variant}{clock}.json' for variant in ('pachs', 'parallel')]
      if not all(src.exists(n) for n in names):
        continue
      rates = []
      for n, planner in zip(names, ('pachs', 'parallel')):
        again = n.replace(f'{folder}/', f'{folder}/{CLOSED_LOOP_REPEATS}/')
        runs = [src.load(x) for x in (n, again) if src.exists(x)]
        devices.update(r['provenance']['device'].split(': ')[-1].replace(' x1', '')
                       for r in runs)
        summaries = [summary_of(r, planner) for r in runs]
        rates.append(sum(a['successes'] for a in summaries)
                     / sum(a['episodes'] for a in summaries))
        if len(runs) > 1:
          repeated.append(f'{layout}\'s {"PACHS" if planner == "pachs" else "rollout"}')
        if 'convex' in {box_contacts(r) for r in runs} and layout not in convex:
          convex.append(layout)
      pairs.append(f'{layout} {pct(rates[0])} / {pct(rates[1])}')
    return pairs

  pairs, quick = pairs_at(''), pairs_at('-q1')
  settings = src.load(next(n for n in (f'{folder}/{layout}_pachs.json'
                                       for layout in CLOSED_LOOP_LAYOUTS)
                           if src.exists(n)))['settings']
  return (f'Closed loop, the original\'s protocol (plan {settings["query_time"]:g} s, execute '
          f'{settings["execute"]} actions in a MuJoCo C world, replan; at most '
          f'{settings["max_queries"]} queries; {settings["instances"] * settings["rounds"]} '
          'episodes per layout and run, each planner alone on '
          f'one {" or one ".join(sorted(devices))}), PACHS / parallel rollout: '
          + ', '.join(pairs)
          + (f'; planning 1 s a query: {", ".join(quick)}' if quick else '')
          + ' (gate-mirror and wall-right held out'
          + (f'; {", ".join(repeated)} over two runs' if repeated else '')
          + (f'; {", ".join(convex)} measured while the Warp planners collided the T with the '
             'blocks by Warp\'s convex collider, not as MuJoCo C does' if convex else '')
          + '; [results](docs/results.md#closed-loop-on-the-faithful-physics)).')


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
