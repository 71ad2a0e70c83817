"""Why a traced closed loop's T tipped: each failed episode's last query replayed from the world's
state, its executed actions again in MuJoCo C and in the planner's physics.

  python experiments/trace_replay.py experiments/results/closed_loop_trace_gpu/two-gaps_pachs.json

Reads `<run>.pachs.trace.npz` beside a `closed_loop.py --trace 1` result. Per failed episode
(`episodes.trace`): the world state at which its last query asked; from there, step by step,
the T's tilt in the world, in a MuJoCo C replay, in a replay in the planner's physics
(`--planner`) and in the plan; the T's height, the stick tip's and the T's contacts in MuJoCo
C. An episode whose planner replay tips the T too failed on the executed actions (the plan's
or the policy's); one whose planner replay keeps the T flat where MuJoCo C tips it, on the
engines' difference; one whose plan itself tilted the T near 30 degrees, on a plan at the
limit (`report.replay_sentence`)."""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

import common
from pachs_jax import argtypes


def build_parser() -> argtypes.OneLineParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argtypes.OneLineParser(description=__doc__.splitlines()[0])
  parser.add_argument('result', help="a closed_loop.py --trace 1 result (.json) of pusht-obs")
  parser.add_argument('--planner', default='warp', choices=['warp', 'mjx'],
                      help="the planner's physics to replay in (default: warp)")
  parser.add_argument('--out', default=None,
                      help='the result (default: <result stem>.replay.json beside it)')
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from pachs_jax import planner  # noqa: E402
from pachs_jax.envs import backends, base, pusht, world as world_lib  # noqa: E402
# pylint: enable=wrong-import-position


def last_query(trace: dict, e: int) -> int:
  """The world state at which episode e's last query asked (before its last step)."""
  return int(max(a for a in trace['asked_at'][:, e] if 0 <= a < int(trace['steps'][e])))


def replay(env, edges, trace: dict, e: int) -> list:
  """Rows per world step of episode e from its last query to its failure (module docstring)."""
  degrees = lambda q: float(np.degrees(np.asarray(pusht.t_tilt(jnp.asarray(q, jnp.float32)))))
  start, steps = last_query(trace, e), int(trace['steps'][e])
  node = base.NodeState(**{f: trace['world_' + f][e, start].astype(np.float32)
                           for f in ('qpos', 'qvel', 'ctrl', 'qacc_warmstart')},
                        goal=trace['goal'][e].astype(np.float32), t=np.int32(start))
  world = world_lib.World(env)
  world.reset(node)
  model, tip = env.mj_model, env.mj_model.site('tip').id
  step = jax.jit(edges.evaluate)
  rows = []
  for s in range(start, steps):
    action = trace['actions'][e, s]
    out = step(jax.tree.map(lambda x: jnp.asarray(x)[None], node),
               jnp.asarray(action[None], jnp.float32))
    node = jax.tree.map(lambda x: np.asarray(x)[0], out.next_node)
    world.execute(action[None])
    data = world.data
    contacts = sorted({' / '.join(sorted((model.geom(c.geom1).name, model.geom(c.geom2).name)))
                       for c in data.contact[:data.ncon]})
    planned = trace['planned_qpos'][e, s + 1]
    rows.append({'step': s + 1, 'by_policy': bool(trace['by_policy'][e, s]),
                 'tilt_world': degrees(trace['world_qpos'][e, s + 1]),
                 'tilt_c_replay': degrees(data.qpos), 'tilt_planner_replay': degrees(node.qpos),
                 'tilt_plan': None if np.isnan(planned[0]) else degrees(planned),
                 't_height_m': float(data.qpos[9]),
                 'tip_height_m': float(data.site_xpos[tip][2]),
                 't_contacts': [c for c in contacts if 't_' in c and 'table' not in c]})
  return rows


def main() -> int:
  parser = build_parser()
  args = parser.parse_args()
  traced = os.path.splitext(args.result)[0] + '.pachs.trace.npz'
  if not os.path.exists(traced):
    parser.error(f'{args.result}: no trace beside it ({traced}; closed_loop.py --trace 1 '
                 'writes one)')
  with open(args.result) as f:
    result = json.load(f)
  trace = dict(np.load(traced))
  layout = result['env'].split(':')[-1]
  env, _ = planner.load_model('pusht-obs', backend='mjx', layout=layout,
                              physics=result['settings'].get('physics'))
  edges = backends.make_backend(env, args.planner)
  episodes = []
  for e in np.flatnonzero(trace['failed']):
    rows = replay(env, edges, trace, int(e))
    last = rows[-1]
    episodes.append({'episode': int(e), 'query_at': rows[0]['step'] - 1,
                     'failed_at': last['step'], 'on_policy_step': last['by_policy'],
                     'planner_replay_tilt_at_failure': last['tilt_planner_replay'],
                     'plan_max_tilt': max((r['tilt_plan'] for r in rows
                                           if r['tilt_plan'] is not None), default=None),
                     'rows': rows})
  out = args.out or os.path.splitext(args.result)[0] + '.replay.json'
  payload = {'provenance': common.provenance(), 'source': args.result, 'env': result['env'],
             'planner_physics': args.planner, 'episodes': episodes}
  lines = common.markdown_header(f'Failed episodes replayed, {result["env"]}',
                                 payload['provenance'], f'Source: {args.result}')
  for ep in episodes:
    lines += [f'Episode {ep["episode"]}: query at step {ep["query_at"]}, failed at '
              f'{ep["failed_at"]}', '',
              common.markdown_table(ep['rows'], ['step', 'by_policy', 'tilt_world',
                                                 'tilt_c_replay', 'tilt_planner_replay',
                                                 'tilt_plan', 't_height_m', 'tip_height_m',
                                                 't_contacts']), '']
  common.write_result(out, payload, lines)
  print(f'wrote {out}: {len(episodes)} failed episodes replayed')
  return 0


if __name__ == '__main__':
  sys.exit(main())
