"""How far the planners' physics drifts from the closed-loop world: action sequences run in the
MuJoCo C world (float64) are replayed from the same states in MJX (float32, the GPU planners'
physics), in the MuJoCo C edge backend (float32 states between steps, the CPU planners') and,
where installed, in MuJoCo Warp (float32, MJX impl='warp'), which is also compared with MJX.

  python experiments/physics_mismatch.py --layout wall --instances 8

The actions are the stochastic policy's in the world (pushing contact included). Reported: the T's
position (mm) and angle (degrees) error percentiles against the world after `--horizons` steps,
from the start and from world states every 10 steps along the way (the closed loop replans
every 10)."""

from __future__ import annotations

import argparse
import os

import jax
import jax.numpy as jnp
import numpy as np

import common
from pachs_jax import planner
from pachs_jax.envs import backends, warp_import, world as world_lib
from pachs_jax.search.baselines import common as replay_lib


def world_trajectories(env, model, starts, steps: int, seed: int):
  """(actions [I, T, A], world nodes NodeState [I, T + 1]) of the stochastic policy run in one
  MuJoCo C world per instance."""
  sample = jax.jit(lambda key, obs: model.sample_actions(key, obs, 1)[:, 0])
  num = jax.tree.leaves(starts)[0].shape[0]
  worlds = [world_lib.World(env) for _ in range(num)]
  nodes = [[w.reset(jax.tree.map(lambda x, i=i: np.asarray(x[i]), starts))]
           for i, w in enumerate(worlds)]
  actions = np.zeros((num, steps, env.action_size), np.float32)
  key = jax.random.PRNGKey(seed)
  for t in range(steps):
    batch = jax.tree.map(jnp.asarray, world_lib.stack_nodes([n[-1] for n in nodes]))
    act = np.clip(np.asarray(sample(jax.random.fold_in(key, t), env.observe(batch))), -1, 1)
    actions[:, t] = act
    for i, w in enumerate(worlds):
      nodes[i].append(w.execute(act[i:i + 1])[-1])
  stacked = [world_lib.stack_nodes(n) for n in nodes]  # per instance [T + 1]
  return actions, jax.tree.map(lambda *x: np.stack(x), *stacked)


def pose_error(a, b):
  """(position error mm, angle error degrees) of the T between node states a and b [..., nq]."""
  d = np.asarray(a)[..., 7:10] - np.asarray(b)[..., 7:10]
  angle = np.abs((d[..., 2] + np.pi) % (2 * np.pi) - np.pi)
  return 1000 * np.linalg.norm(d[..., :2], axis=-1), np.degrees(angle)


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--task', default='pusht-obs', choices=['pusht-fixed', 'pusht-obs'])
  parser.add_argument('--steps', type=int, default=80, help='world steps per instance')
  parser.add_argument('--horizons', default='1,10,30', help='replay lengths, comma separated')
  common.add_common_args(parser, out=None, instances=8, seed=True, layout=True)
  args = parser.parse_args()
  common.check_layout(parser, args.task, args.layout)
  label = common.task_label(args.task, args.layout)
  out = args.out or f'experiments/results/physics_mismatch_{label}.json'
  horizons = [int(h) for h in args.horizons.split(',') if int(h) <= args.steps]

  env, model = planner.load_model(args.task, backend='mjx', layout=args.layout)
  physics = {'mjx': env, 'mujoco-c backend': backends.make_backend(env, 'mujoco-c', None)}
  if warp_import.available():
    physics['warp'] = backends.make_backend(env, 'warp')
  else:
    print(f'no warp row: {warp_import.INSTALL_HINT}', flush=True)
  starts = env.canonical_instances(args.instances)
  actions, world = world_trajectories(env, model, starts, args.steps, args.seed)
  rows, ends = [], {}
  for h in horizons:
    # from every world state at a multiple of 10 steps whose next h actions exist
    begins = [t for t in range(0, args.steps - h + 1, 10)]
    truth = jax.tree.map(lambda x: np.concatenate([x[:, t0 + h] for t0 in begins]), world)
    for name, sim in physics.items():
      replay = jax.jit(lambda s, a, n, sim=sim: replay_lib.replay(sim, s, a, n)[0])
      end = []
      for t0 in begins:
        start = jax.tree.map(lambda x: jnp.asarray(x[:, t0]), world)
        nodes = replay(start, jnp.asarray(actions[:, t0:t0 + h]),
                       jnp.full((args.instances,), h, jnp.int32))
        end.append(jax.tree.map(lambda x: np.asarray(x[:, h]), nodes))
      ends[name, h] = jax.tree.map(lambda *x: np.concatenate(x), *end)
    pairs = [(name, 'world', truth) for name in physics]
    if 'warp' in physics:
      pairs.append(('warp', 'mjx', ends['mjx', h]))
    for name, against, other in pairs:
      end = ends[name, h]
      pos, ang = pose_error(end.qpos, other.qpos)
      agree = (np.asarray(env.is_goal(jax.tree.map(jnp.asarray, end)))
               == np.asarray(env.is_goal(jax.tree.map(jnp.asarray, other))))
      rows.append({'physics': name, 'against': against, 'horizon': h, 'replays': int(pos.size),
                   **{f'position_error_mm_p{q}': float(np.percentile(pos, q))
                      for q in (50, 90, 99)},
                   **{f'angle_error_deg_p{q}': float(np.percentile(ang, q))
                      for q in (50, 90, 99)},
                   'goal_agreement': float(np.mean(agree))})
      print(rows[-1], flush=True)
  payload = {'provenance': common.provenance(), 'settings': vars(args), 'rows': rows}
  common.write_json(out, payload)
  with open(os.path.splitext(out)[0] + '.md', 'w') as f:
    f.write(f'# Physics mismatch against the MuJoCo C world, {label}\n\n'
            f'{payload["provenance"]}\n\nSettings: {payload["settings"]}\n\n')
    f.write(common.markdown_table(rows, list(rows[0])) + '\n')


if __name__ == '__main__':
  main()
