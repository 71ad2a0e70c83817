"""Closed loop through a planning server: PushT episodes in MuJoCo C worlds (`episodes.Worlds`)
ask `pachs serve` for action chunks, execute them, observe, and ask again; the server keeps the
session's last answer, so each query also weighs the remainder of the last one.

  pachs serve --task pusht-obs --layout wall &        # prints 'ready on ws://127.0.0.1:8000'
  python examples/serve_closed_loop.py --url ws://127.0.0.1:8000 --instances 0,3

The worlds use the task's model (and --layout) locally; the planner runs in the server.
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

from pachs_jax import argtypes, client, envs, episodes, planner


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
  parser.add_argument('--url', default='ws://127.0.0.1:8000')
  parser.add_argument('--task', default='pusht-obs')
  parser.add_argument('--layout', default=None)
  parser.add_argument('--instances', default='0', help="canonical instances, e.g. '0,3'")
  parser.add_argument('--query-time', type=float, default=3.0, help='seconds per query')
  parser.add_argument('--execute', type=int, default=10, help='actions run per chunk')
  parser.add_argument('--max-queries', type=int, default=30)
  args = parser.parse_args()
  env = envs.make(args.task, layout=args.layout)
  instances = argtypes.instance_indices(args.instances, envs.spec(args.task).num_instances)
  starts = planner.canonical_instances(env, envs.spec(args.task).num_instances)
  worlds = episodes.Worlds(env, jax.tree.map(lambda x: np.asarray(x)[instances], starts))
  with client.Client(args.url, args.task) as asking:
    chunks = client.ActionChunks(asking, execute=args.execute, time_limit_s=args.query_time)
    for _ in range(args.max_queries):
      if not worlds.active.any():
        break
      actions, lengths = chunks.chunk(worlds.batch())
      # finished episodes stand still; the others run their chunk in their world
      running = worlds.active
      worlds.execute(actions, np.where(running, lengths, 0))
      chunks.executed = np.where(running, lengths, client.DIVERGED)
      print(f'query {chunks.queries}: answers {chunks.last.kind_names}, executed '
            f'{lengths.tolist()}, at the goal {worlds.success.tolist()}', flush=True)
  print(f'reached the goal in {int(worlds.success.sum())}/{worlds.num} episodes after '
        f'{chunks.queries} queries')


if __name__ == '__main__':
  main()
