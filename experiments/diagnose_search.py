"""Where PACHS spends its budget on a PushT-Obs layout (issue 14's diagnosis): depth, the
heuristic along found paths against the path's remaining cost, expansions in front of the
blocks, lattice merges and the spread of the sampled actions.

  python experiments/diagnose_search.py --layout gate      # CPU: pachs plan's CPU settings

Writes `diagnose_<layout>_<device>.json` and `.md` in experiments/results/ (or --out).
"""

from __future__ import annotations

import argparse
import dataclasses
import os

import jax
import numpy as np

import common
from pachs_jax import flags, planner
from pachs_jax.envs import layouts
from pachs_jax.search import pachs
from pachs_jax.search.checks import instance_keys

TASK = 'pusht-obs'


def path_indices(parent: np.ndarray, node: int) -> list:
  """Pool indices from the start to node, following parent links."""
  chain = []
  while node >= 0:
    chain.append(node)
    node = int(parent[node])
  return chain[::-1]


def instance_rows(state, result, blocks_y: tuple, edge_steps: int = 1) -> list:
  """One dict of diagnostics per instance (numpy over the final search state); edge_steps:
  the evaluations one edge costs."""
  pool = jax.tree.map(np.asarray, state.pool)
  rows = []
  low, high = blocks_y
  for i in range(pool.g.shape[0]):
    size = int(pool.size[i])
    closed = pool.closed[i, :size]
    y = pool.nodes.qpos[i, :size, 8]  # the T's y (m)
    q = pool.edge_q[i, :size]  # [P, N] cost-to-go estimates of the sampled edges
    h = np.where(closed, q.min(axis=1), np.nan)  # the best sampled edge's estimate
    actions = pool.edge_actions[i, :size][closed]  # [E, N, A]
    row = dict(
        instance=i, found=bool(result.found[i]), cost=float(result.cost[i]),
        path_length=int(result.path_length[i]), expanded=int(closed.sum()),
        evaluated=int(result.evaluated[i]), invalid=int(result.invalid[i]),
        generated=size,
        merged_share=1.0 - (size - 1) / max(
            1, int(result.evaluated[i]) // edge_steps - int(result.invalid[i])),
        depth_max=int(pool.depth[i, :size].max()),
        depth_expanded_mean=float(pool.depth[i, :size][closed].mean()) if closed.any() else 0.0,
        before_blocks=float((y[closed] > high).mean()) if closed.any() else 0.0,
        in_gap=float(((y[closed] <= high) & (y[closed] >= low)).mean()) if closed.any() else 0.0,
        past_blocks=float((y[closed] < low).mean()) if closed.any() else 0.0,
        t_moved_share=float((np.abs(y - y[0]) > 0.01).mean()),
        h_max=float(np.nanmax(h)) if closed.any() else 0.0,
        action_std=float(actions.std(axis=1).mean()) if len(actions) else 0.0,
        start_h=float(h[0]) if closed[0] else float('nan'))
    goal = int(state.goal_node[i])
    if row['found'] and goal >= 0:
      chain = path_indices(pool.parent[i], goal)
      remaining = pool.g[i, goal] - pool.g[i, chain]
      estimate = h[chain]
      use = closed[chain] & (remaining > 0)
      row['h_over_remaining'] = float(np.nanmean(estimate[use] / remaining[use]))
      row['h_over_remaining_start'] = float(estimate[0] / remaining[0]) if use[0] else float('nan')
      row['remaining_start'] = float(remaining[0])
    rows.append(row)
  return rows


def summary(rows: list, config, discount: float) -> dict:
  """Means over instances (and over solved / unsolved ones where it matters)."""
  def mean(key, which=None):
    values = [r[key] for r in rows if key in r and (which is None or r['found'] == which)]
    values = [v for v in values if v == v]
    return float(np.mean(values)) if values else float('nan')
  return {
      'found': sum(r['found'] for r in rows), 'instances': len(rows),
      'discount': discount, 'discount_horizon_steps': 1.0 / (1.0 - discount),
      'h_max_seen': max(r['h_max'] for r in rows),
      'h_over_remaining_on_found_paths': mean('h_over_remaining'),
      'h_over_remaining_at_start': mean('h_over_remaining_start'),
      'remaining_cost_at_start': mean('remaining_start'),
      'path_length_found': mean('path_length', True),
      'cost_per_step_found': float(np.mean([r['cost'] / r['path_length'] for r in rows
                                            if r['found'] and r['path_length']] or [np.nan])),
      'depth_max_unsolved': mean('depth_max', False),
      'depth_max_solved': mean('depth_max', True),
      'expanded_unsolved': mean('expanded', False),
      'before_blocks_unsolved': mean('before_blocks', False),
      'before_blocks_solved': mean('before_blocks', True),
      'in_gap_unsolved': mean('in_gap', False),
      'past_blocks_unsolved': mean('past_blocks', False),
      'merged_share': mean('merged_share'),
      'invalid_share': float(np.mean([r['invalid'] / max(1, r['evaluated']) for r in rows])),
      'action_std': mean('action_std'),
      'uniform_action_std': 1.0 / np.sqrt(3.0),
      'num_actions': config.num_actions, 'weight': config.weight,
      'budget': config.max_evaluations,
  }


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument('--budget', type=int, default=None, help="None: pachs plan's default")
  flags.add_search_flags(parser, ['weight', 'num_actions', 'edge_steps', 'rollout_share'])
  parser.add_argument('--lattice-scale', type=float, default=1.0,
                      help='lattice cell sizes = this x the default')
  common.add_common_args(parser, out=None, instances=None, backend=True, seed=True, layout=True)
  args = parser.parse_args()
  args.layout = args.layout or layouts.DEFAULT
  env, model = planner.load_model(TASK, None, args.backend, layout=args.layout)
  on_cpu = jax.default_backend() == 'cpu'
  overrides = flags.search_overrides(args)

  config = planner.command_config(TASK, on_cpu, type(env).__name__ == 'MujocoCEnv',
                                  args.budget, **overrides)
  if args.lattice_scale != 1.0:
    base = config.lattice_resolution or np.asarray(env.default_lattice_resolution).tolist()
    config = dataclasses.replace(config, lattice_resolution=tuple(
        float(x) * args.lattice_scale for x in base))
  count = common.task_instances(TASK, args.instances)
  starts = env.canonical_instances(count)
  search = pachs.make_search(env, model, config)
  keys = instance_keys(jax.random.PRNGKey(args.seed), count)
  state = search.run(search.init(starts, keys))
  result = jax.tree.map(np.asarray, search.result(state))
  blocks = np.asarray(layouts.layout(args.layout).blocks)
  blocks_y = (float((blocks[:, 1] - blocks[:, 3]).min()), float((blocks[:, 1] + blocks[:, 3]).max()))
  discount = float(model.config.discount)
  rows = instance_rows(state, result, blocks_y, config.edge_steps)
  payload = {'provenance': common.provenance(), 'layout': args.layout,
             'config': repr(config), 'blocks_y': blocks_y,
             'summary': summary(rows, config, discount), 'instances': rows}
  device = 'cpu' if on_cpu else 'gpu'
  out = args.out or os.path.join(os.path.dirname(__file__), 'results',
                                 f'diagnose_{args.layout}_{device}.json')
  common.write_json(out, payload)
  with open(os.path.splitext(out)[0] + '.md', 'w') as f:
    f.write(f'# PACHS diagnostics, pusht-obs layout {args.layout}\n\n{payload["provenance"]}\n\n'
            f'{config}\n\n' + common.markdown_table(
                [{'quantity': k, 'value': v} for k, v in payload['summary'].items()],
                ['quantity', 'value']) + '\n\nPer instance:\n\n'
            + common.markdown_table(rows, list(rows[0])) + '\n')
  print(payload['summary'])


if __name__ == '__main__':
  main()
