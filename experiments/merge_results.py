"""Merges result files of one task (e.g. planners run on separate GPUs) into one JSON, markdown
table and plot, keeping every source's provenance; the sources' protocol settings must agree."""

from __future__ import annotations

import argparse
import json
import os
from typing import Dict, List


def build_parser() -> argparse.ArgumentParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('kind', choices=['closed', 'open'])
  parser.add_argument('sources', nargs='+',
                      help="result JSON files of one task; PATH#OLD=NEW renames that source's "
                      "planner OLD (e.g. a PACHS variant kept beside a new default)")
  parser.add_argument('--out', required=True)
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import closed_loop  # noqa: E402
import common  # noqa: E402
import open_loop  # noqa: E402
import stats  # noqa: E402
# pylint: enable=wrong-import-position

PROTOCOL = ('task', 'instances', 'rounds', 'query_time', 'execute', 'max_queries',
            'fill_with_policy', 'perturb', 'seed')


def label(planner: str, settings: Dict) -> str:
  """The planner's name; PACHS run with an explicit `--realtime-answer A` is 'pachs-A'
  (best_f, the original's rule, keeps the plain name)."""
  answer = settings.get('realtime_answer')
  if planner == 'pachs' and answer not in (None, 'best_f'):
    return f'pachs-{answer}'
  return planner


def merge_closed(payloads: List[Dict]) -> Dict:
  """One closed-loop payload holding every source's planners (in order)."""
  first = payloads[0]
  for p in payloads[1:]:
    for name in PROTOCOL:
      if p['settings'].get(name) != first['settings'].get(name):
        raise ValueError(f'the sources disagree on {name}: {first["settings"].get(name)!r} '
                         f'vs {p["settings"].get(name)!r}')
    if p['perturbation'] != first['perturbation']:
      raise ValueError('the sources ran different world perturbations')
  merged = {'provenance': common.merged_provenance([p['provenance'] for p in payloads]),
            'task': first['task'],
            'settings': {name: first['settings'].get(name) for name in PROTOCOL},
            'settings_per_source': [p['settings'] for p in payloads],
            'perturbation': first['perturbation'], 'summary': [], 'episodes': {}}
  for p in payloads:
    for row in p['summary']:
      name = label(row['planner'], p['settings'])
      if name in merged['episodes']:
        raise ValueError(f'planner {name!r} appears in two sources')
      merged['summary'].append(dict(row, planner=name))
      merged['episodes'][name] = p['episodes'][row['planner']]
  return merged


OPEN_PROTOCOL = ('instances', 'rounds', 'instance_seed', 'budget', 'time_limit_s')


def _setting(payload: Dict, name: str):
  """An open-loop protocol setting of payload; files from before --instance-seed used set 0."""
  return payload['settings'].get(name, 0 if name == 'instance_seed' else None)


def merge_open(payloads: List[Dict]) -> Dict:
  """One open-loop payload; a planner of a later payload replaces the same planner before, and
  the pairwise cost ratios are recomputed."""
  first = payloads[0]
  for p in payloads[1:]:
    if p['task'] != first['task'] or p['curve_budgets'] != first['curve_budgets']:
      raise ValueError('the sources are of different tasks or success-curve budgets')
    for name in OPEN_PROTOCOL:
      if _setting(p, name) != _setting(first, name):
        raise ValueError(f'the sources disagree on {name}: {_setting(first, name)!r} '
                         f'vs {_setting(p, name)!r}')
  sources = []
  for p in payloads:
    source = {k: v for k, v in p['provenance'].items() if k != 'renamed'}
    if 'merged_from' not in source:
      source['planners'] = [s['planner'] for s in p['summary']]
    sources.append(source)
  merged = {'provenance': common.merged_provenance(sources), 'task': first['task'],
            'model': first['model'],
            'settings': {name: _setting(first, name) for name in OPEN_PROTOCOL},
            'settings_per_planner': {}, 'configs': {}, 'summary': [], 'runs': {},
            'curve_budgets': first['curve_budgets'], 'success_curve': {}}
  summary = {}
  for p in payloads:
    if p['provenance'].get('renamed'):
      merged['provenance'].setdefault('renamed', {}).update(p['provenance']['renamed'])
    for row in p['summary']:
      name = row['planner']
      summary[name] = row
      merged['settings_per_planner'][name] = p.get('settings_per_planner', {}).get(
          name, p['settings'])
      merged['configs'][name] = p['configs'][name]
      merged['runs'][name] = p['runs'][name]
      merged['success_curve'][name] = p['success_curve'][name]
  merged['summary'] = list(summary.values())
  merged['cost_ratios'] = stats.cost_ratios(merged['runs'])
  return merged


def load_source(source: str) -> Dict:
  """The payload of 'PATH' or 'PATH#OLD=NEW' (planner OLD renamed NEW in every table)."""
  path, _, rename = source.partition('#')
  with open(path) as f:
    payload = json.load(f)
  if not rename:
    return payload
  old, sep, new = rename.partition('=')
  names = [s['planner'] for s in payload['summary']]
  if not sep or old not in names or new in names:
    raise ValueError(f'{source!r}: rename as PATH#OLD=NEW, OLD one of {names}, NEW a new name')
  for row in payload['summary']:
    if row['planner'] == old:
      row['planner'] = new
  for table in ('runs', 'episodes', 'configs', 'success_curve', 'settings_per_planner'):
    if old in payload.get(table, {}):
      payload[table][new] = payload[table].pop(old)
  payload.setdefault('provenance', {})['renamed'] = {old: new}
  return payload


def main():
  args = build_parser().parse_args()
  payloads = [load_source(source) for source in args.sources]
  stem = os.path.splitext(args.out)[0]
  if args.kind == 'closed':
    merged = merge_closed(payloads)
    common.write_result(args.out, merged, closed_loop.markdown(merged))
    closed_loop.plot(merged, stem + '.png')
  else:
    merged = merge_open(payloads)
    common.write_result(args.out, merged, open_loop.markdown(merged['task'], merged))
    open_loop.plot(merged['task'], merged, stem + '.png')
  with open(stem + '.md') as f:
    print(f.read())


if __name__ == '__main__':
  main()
