"""Single-rollout success of the shipped policies on the canonical instance sets.

The deterministic policy once (its runs would repeat), the stochastic one over `--seeds` seeds;
on the shelf an invalid edge (a collision) is a failure."""

from __future__ import annotations

import argparse
import os

import jax
import numpy as np

import common
import stats
from pachs_jax import envs, planner
from pachs_jax.sac import evaluator


def evaluate_task(task: str, seeds: int, layout=None) -> dict:
  env, model = planner.load_model(task, layout=layout if task == 'pusht-obs' else None)
  num = common.task_instances(task)
  nodes = env.canonical_instances(num)
  det = evaluator.make_rollout_fn(env, deterministic=True)(model, nodes, jax.random.PRNGKey(0))
  sto_fn = evaluator.make_rollout_fn(env, deterministic=False)
  sto = [sto_fn(model, nodes, jax.random.PRNGKey(s)) for s in range(seeds)]
  sto_success = np.stack([np.asarray(r.success) for r in sto])
  det_success = np.asarray(det.success)
  row = {
      'task': env.name, 'model': envs.spec(task).model_task, 'instances': num, 'seeds': seeds,
      'deterministic_success': float(det_success.mean()),
      'deterministic_invalid': float(np.asarray(det.invalid).mean()),
      'deterministic_mean_steps_success': stats.mean_where(det.steps, det_success),
      'deterministic_mean_cost_success': stats.mean_where(det.cost, det_success),
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
  common.add_common_args(parser, out='experiments/results/eval_policy.json', layout=True)
  args = parser.parse_args()
  rows = [evaluate_task(t, args.seeds, args.layout) for t in args.tasks.split(',')]
  common.write_json(args.out, {'provenance': common.provenance(), 'rows': rows})
  with open(os.path.splitext(args.out)[0] + '.md', 'w') as f:
    f.write(f"# Single-rollout policy success on the canonical instances\n\n"
            f"{common.provenance()}\n\n")
    f.write(common.markdown_table(rows, [
        'task', 'model', 'instances', 'deterministic_success', 'deterministic_invalid',
        'deterministic_mean_steps_success', 'stochastic_success', 'stochastic_runs']) + '\n')


if __name__ == '__main__':
  main()
