"""Single-rollout success of the shipped policies on the canonical instance sets.

Each PushT task: 30 canonical instances x 5 seeds (150 runs; the deterministic policy and the
task are deterministic, so its 5 seeds agree and are reported once), up to the episode length.
The shelf: its 100 canonical targets (invalid edges, i.e. collisions, count as failures).

  python experiments/eval_policy.py --tasks pusht-fixed,pusht-rand,pusht-obs \
      --out experiments/results/eval_policy.json
"""

from __future__ import annotations

import argparse
import os

import jax
import numpy as np

import common
from pachs_jax import planner
from pachs_jax.sac import evaluator


def evaluate_task(task: str, seeds: int) -> dict:
  env, model = planner.load_model(task)
  num = 100 if task == 'shelf' else 30
  nodes = env.canonical_instances(num)
  det = evaluator.make_rollout_fn(env, deterministic=True)(model, nodes, jax.random.PRNGKey(0))
  sto_fn = evaluator.make_rollout_fn(env, deterministic=False)
  sto = [sto_fn(model, nodes, jax.random.PRNGKey(s)) for s in range(seeds)]
  sto_success = np.stack([np.asarray(r.success) for r in sto])
  det_success = np.asarray(det.success)
  row = {
      'task': task, 'model': planner.MODEL_FOR_TASK[task], 'instances': num, 'seeds': seeds,
      'deterministic_success': float(det_success.mean()),
      'deterministic_invalid': float(np.asarray(det.invalid).mean()),
      'deterministic_mean_steps_success': float(np.asarray(det.steps)[det_success].mean())
      if det_success.any() else None,
      'deterministic_mean_cost_success': float(np.asarray(det.cost)[det_success].mean())
      if det_success.any() else None,
      'stochastic_success': float(sto_success.mean()),
      'stochastic_runs': int(sto_success.size),
      'failed_instances_deterministic': np.flatnonzero(~det_success).tolist(),
  }
  print(row, flush=True)
  return row


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--tasks', default='pusht-fixed,pusht-rand,pusht-obs')
  parser.add_argument('--seeds', type=int, default=5)
  parser.add_argument('--out', default='experiments/results/eval_policy.json')
  args = parser.parse_args()
  rows = [evaluate_task(t, args.seeds) for t in args.tasks.split(',')]
  common.write_json(args.out, {'provenance': common.provenance(), 'rows': rows})
  with open(os.path.splitext(args.out)[0] + '.md', 'w') as f:
    f.write(f"# Single-rollout policy success on the canonical instances\n\n"
            f"{common.provenance()}\n\n")
    f.write(common.markdown_table(rows, [
        'task', 'model', 'instances', 'deterministic_success', 'deterministic_invalid',
        'deterministic_mean_steps_success', 'stochastic_success', 'stochastic_runs']) + '\n')


if __name__ == '__main__':
  main()
