"""One results JSON of SAC training runs made elsewhere (a GPU command): per run, what it
trained on (task, physics, failure cost, a fine-tuned model) from its exported model, and how
it learnt (env steps, throughput, training and evaluation success, episode return) from its
metrics.csv, with the device, revision and command that made it, which the caller names.

  python experiments/training_summary.py --out experiments/results/training/runs.json \\
    --run NAME=RUN_DIR --device 'gpu: NVIDIA H200 x1' --revision REV --command '...' [--run ...]
Flags --device, --revision, --command and --note apply to the --run flags after them.
"""

from __future__ import annotations

import csv
import json
import math
import os
import sys
from typing import Dict, List

import common
from pachs_jax import argtypes


def _float(text: str) -> float:
  return float(text) if text not in ('', None) else math.nan


def summarize(name: str, run_dir: str) -> Dict:
  """The summary row of the run directory `run_dir` (train.py --out)."""
  with open(os.path.join(run_dir, 'metrics.csv')) as f:
    rows = [{k: _float(v) for k, v in r.items()} for r in csv.DictReader(f)]
  with open(os.path.join(run_dir, 'model', 'actor_critic.json')) as f:
    model = json.load(f)
  config = model['sac_config']
  evals = [r for r in rows if not math.isnan(r.get('eval_success_deterministic', math.nan))]
  last = rows[-1]
  tail = rows[-max(1, len(rows) // 10):]  # the last tenth of the epochs
  finite = lambda xs: [x for x in xs if not math.isnan(x)]
  mean = lambda xs: sum(finite(xs)) / max(1, len(finite(xs)))
  curve_every = max(1, len(rows) // 20)
  return {
      'name': name, 'task': model['model']['task'], 'physics': model['physics'],
      'failure_cost': config.get('failure_cost', 0.0),
      'absorbing_failure': config.get('absorbing_failure', False), 'num_envs': config['num_envs'],
      'env_steps': int(last['env_steps']), 'epochs': int(last['epoch']),
      'walltime_s': last['walltime'],
      'env_steps_per_s_median': sorted(r['sps'] for r in rows)[len(rows) // 2],
      'success_rate_last_tenth': mean([r['success_rate'] for r in tail]),
      'episode_return_last_tenth': mean([r['episode_return'] for r in tail]),
      'eval_success_deterministic_best': max((r['eval_success_deterministic'] for r in evals),
                                             default=None),
      'eval_success_deterministic_last': evals[-1]['eval_success_deterministic'] if evals
                                         else None,
      'alpha_last': last['alpha'],
      'curve': [{k: r[k] for k in ('env_steps', 'success_rate', 'episode_return', 'alpha')}
                for r in rows[::curve_every]],
  }


def main(argv: List[str]) -> int:
  parser = argtypes.OneLineParser(description=__doc__.split('\n')[0])
  parser.add_argument('--out', required=True)
  parser.add_argument('--device', action='append', default=[])
  parser.add_argument('--revision', action='append', default=[])
  parser.add_argument('--command', action='append', default=[])
  parser.add_argument('--note', action='append', default=[])
  parser.add_argument('--run', action='append', default=[], metavar='NAME=RUN_DIR')
  args = parser.parse_args(argv)  # checks the flags; their order is read below
  current = {'device': None, 'revision': None, 'command': None, 'note': None}
  runs = []
  it = iter(argv)
  for flag in it:
    value = next(it)
    key = flag.lstrip('-')
    if key in current:
      current[key] = value
    elif key == 'run':
      name, _, run_dir = value.partition('=')
      if not run_dir or not os.path.isdir(run_dir):
        parser.error(f'--run {value!r}: NAME=RUN_DIR with an existing directory')
      if None in (current['device'], current['revision'], current['command']):
        parser.error(f'--run {name}: give --device, --revision and --command before it')
      runs.append(dict(summarize(name, run_dir), device=current['device'],
                       git_revision=current['revision'], run_command=current['command'],
                       note=current['note']))
  merged = [{'device': r['device'], 'git_revision': r['git_revision'],
             'command': r['run_command']} for r in runs]
  payload = {'provenance': common.merged_provenance(merged, command=common.command_line(),
                                                   git_revision=common.git_revision()),
             'runs': runs}
  common.write_json(args.out, payload)
  return 0


if __name__ == '__main__':
  sys.exit(main(sys.argv[1:]))
