"""Batched env-step throughput: MJX on the accelerator against MuJoCo C on all CPU threads.

Per task and batch size: `env.evaluate` steps in one jitted scan, `mujoco.rollout` on the same
model; for PushT a sweep of physics settings, timed and checked against a 1 ms reference."""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout

import common
from pachs_jax import envs, trees
from pachs_jax.envs import panda, pusht


def mjx_throughput(env, worlds: int, steps: int, repeats: int) -> dict:
  """Env steps/s of `steps` evaluate calls on `worlds` worlds in one jit."""
  nodes = env.initial_nodes(jax.random.split(jax.random.PRNGKey(0), worlds))

  @jax.jit
  def run(nodes, key):
    def body(carry, k):
      nodes = carry
      actions = jax.random.uniform(k, (worlds, env.action_size), minval=-1.0, maxval=1.0)
      out = env.evaluate(nodes, actions)
      valid = out.is_valid
      nodes = trees.where(valid, out.next_node, nodes)
      return nodes, out.cost.sum()
    return jax.lax.scan(body, nodes, jax.random.split(key, steps))

  start = time.perf_counter()
  jax.block_until_ready(run(nodes, jax.random.PRNGKey(1)))
  compile_s = time.perf_counter() - start
  t = common.time_call(lambda: run(nodes, jax.random.PRNGKey(2)), repeats=repeats, warmup=0)
  return {'worlds': worlds, 'steps': steps, 'compile_s': compile_s, **t,
          'env_steps_per_s': worlds * steps / t['median_s'],
          'ms_per_env_step': 1e3 * t['median_s'] / steps}


def mujoco_c_throughput(env, worlds: int, steps: int, nthread: int) -> dict:
  """Env steps/s of MuJoCo C (`mujoco.rollout`, nthread threads) on the same model."""
  m = env.mj_model
  substeps = env.config.substeps
  datas = [mujoco.MjData(m) for _ in range(nthread)]
  nodes = env.initial_nodes(jax.random.split(jax.random.PRNGKey(0), worlds))
  state = np.zeros((worlds, mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS)))
  for i in range(worlds):
    datas[0].qpos[:] = np.asarray(nodes.qpos[i])
    datas[0].qvel[:] = 0
    mujoco.mj_getState(m, datas[0], state[i], mujoco.mjtState.mjSTATE_FULLPHYSICS)
  rng = np.random.default_rng(0)
  targets = np.asarray(nodes.qpos[:, None, :7]) + np.cumsum(
      0.1 * rng.uniform(-1, 1, (worlds, steps, 7)), axis=1)
  targets = np.clip(targets, panda.JOINT_LOWER, panda.JOINT_UPPER)
  control = np.repeat(targets, substeps, axis=1)
  with rollout.Rollout(nthread=nthread) as runner:
    runner.rollout([m] * worlds, datas, state, control)  # warm up
    times = []
    for _ in range(3):
      start = time.perf_counter()
      runner.rollout([m] * worlds, datas, state, control)
      times.append(time.perf_counter() - start)
  t = float(np.median(times))
  return {'worlds': worlds, 'steps': steps, 'threads': nthread, 'median_s': t,
          'env_steps_per_s': worlds * steps / t}


def pushing_actions(config: pusht.PushTConfig, num_steps: int = 40) -> tuple:
  """A closed-loop Jacobian push in MuJoCo C: (start qpos [10], actions [num_steps, 7])."""
  m = mujoco.MjModel.from_xml_string(pusht.model_xml(config))
  d = mujoco.MjData(m)
  d.qpos[:7] = pusht.HOME_QPOS
  d.qpos[7:] = [-0.25, -0.15, 0.3]
  d.ctrl[:] = d.qpos[:7]
  start = d.qpos.copy()
  actions = []
  for k in range(num_steps):
    mujoco.mj_forward(m, d)
    goal = np.array([-0.25, -0.32, 0.015]) if k < 10 else np.array([-0.22, 0.05, 0.015])
    a = pusht.jacobian_action(m, d, goal)
    actions.append(a)
    d.ctrl[:] = np.clip(d.qpos[:7] + 0.1 * a, panda.JOINT_LOWER, panda.JOINT_UPPER)
    for _ in range(config.substeps):
      mujoco.mj_step(m, d)
  return start, np.array(actions)


def mujoco_c_replay(config: pusht.PushTConfig, start, actions) -> np.ndarray:
  """[T, 10] qpos of MuJoCo C (float64) replaying delta-joint actions under a config."""
  m = mujoco.MjModel.from_xml_string(pusht.model_xml(config))
  d = mujoco.MjData(m)
  d.qpos[:] = start
  d.ctrl[:] = start[:7]
  out = []
  for a in actions:
    d.ctrl[:] = np.clip(d.qpos[:7] + 0.1 * a, panda.JOINT_LOWER, panda.JOINT_UPPER)
    for _ in range(config.substeps):
      mujoco.mj_step(m, d)
    out.append(d.qpos.copy())
  return np.array(out)


def mjx_replay(env, start, actions) -> np.ndarray:
  node = env.node_from_pose(jnp.asarray(start[7:]), jnp.asarray(pusht.FIXED_GOAL))
  node = node.replace(qpos=jnp.asarray(start, jnp.float32))

  def body(n, a):
    out = env.transition(n, a)
    return out.next_node, out.next_node.qpos
  return np.asarray(jax.jit(lambda n, a: jax.lax.scan(body, n, a)[1])(
      node, jnp.asarray(actions, jnp.float32)))


PHYSICS_VARIANTS = {
    '4x12.5ms/newton4': dict(physics_dt=0.0125, substeps=4, solver_iterations=4, ls_iterations=8),
    '5x10ms/newton4': dict(physics_dt=0.01, substeps=5, solver_iterations=4, ls_iterations=8),
    '4x12.5ms/newton2': dict(physics_dt=0.0125, substeps=4, solver_iterations=2, ls_iterations=4),
    '3x16.7ms/newton4': dict(physics_dt=0.05 / 3, substeps=3, solver_iterations=4,
                             ls_iterations=8),
}


def physics_sweep(worlds: int, steps: int, repeats: int) -> list:
  """Speed and accuracy of PushT physics settings against a 1 ms MuJoCo C reference."""
  base_cfg = pusht.PushTConfig()
  start, actions = pushing_actions(base_cfg)
  reference = mujoco_c_replay(dataclasses.replace(base_cfg, physics_dt=0.001, substeps=50,
                                                  solver_iterations=100, ls_iterations=50),
                              start, actions)
  rows = []
  for name, kw in PHYSICS_VARIANTS.items():
    cfg = dataclasses.replace(base_cfg, **kw)
    env = pusht.PushTEnv(cfg)
    traj = mjx_replay(env, start, actions)
    c_traj = mujoco_c_replay(cfg, start, actions)
    speed = mjx_throughput(env, worlds, steps, repeats)
    rows.append({
        'variant': name, 'worlds': worlds, 'env_steps_per_s': speed['env_steps_per_s'],
        'ms_per_env_step': speed['ms_per_env_step'],
        'T_displacement_m': float(np.linalg.norm(reference[-1, 7:9] - start[7:9])),
        'T_pos_err_vs_1ms_ref_m': float(np.linalg.norm(traj[-1, 7:9] - reference[-1, 7:9])),
        'T_yaw_err_vs_1ms_ref_rad': float(abs(traj[-1, 9] - reference[-1, 9])),
        'mjx_vs_mujoco_c_same_settings_m': float(np.abs(traj[:, 7:9] - c_traj[:, 7:9]).max()),
        'arm_err_vs_ref_rad': float(np.abs(traj[:, :7] - reference[:, :7]).max()),
    })
    print(rows[-1], flush=True)
  return rows


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--tasks', default='pusht-fixed,pusht-obs,shelf')
  parser.add_argument('--worlds', default='1,256,1024,4096,16384')
  parser.add_argument('--steps', type=int, default=20, help='control steps per timed call')
  parser.add_argument('--repeats', type=int, default=3)
  parser.add_argument('--cpu-worlds', default='1024,4096')
  parser.add_argument('--sweep-worlds', type=int, default=4096)
  parser.add_argument('--no-sweep', action='store_true')
  common.add_common_args(parser, out='experiments/results/bench_env.json')
  args = parser.parse_args()
  worlds = [int(w) for w in args.worlds.split(',')]
  cpu_worlds = [int(w) for w in args.cpu_worlds.split(',') if w]
  nthread = os.cpu_count()
  result = {'provenance': common.provenance(), 'mjx': [], 'mujoco_c': [], 'sweep': []}
  for task in args.tasks.split(','):
    env = envs.make(task)
    for w in worlds:
      row = {'task': task, **mjx_throughput(env, w, args.steps, args.repeats)}
      print(row, flush=True)
      result['mjx'].append(row)
      common.write_json(args.out, result)
    if task.startswith('pusht'):
      for w in cpu_worlds:
        for threads in (nthread, 1):
          row = {'task': task, **mujoco_c_throughput(env, w, args.steps, threads)}
          print(row, flush=True)
          result['mujoco_c'].append(row)
      common.write_json(args.out, result)
  if not args.no_sweep:
    result['sweep'] = physics_sweep(args.sweep_worlds, args.steps, args.repeats)
  # Ratios measured side by side in this run: MJX over MuJoCo C (all threads), same task and W.
  ratios = []
  for c in result['mujoco_c']:
    if c['threads'] != nthread:
      continue
    for g in result['mjx']:
      if g['task'] == c['task'] and g['worlds'] == c['worlds']:
        ratios.append({'task': c['task'], 'worlds': c['worlds'],
                       'mjx_over_mujoco_c': g['env_steps_per_s'] / c['env_steps_per_s']})
  result['ratios'] = ratios
  common.write_json(args.out, result)
  md = [f"# Env-step throughput\n\n{result['provenance']}\n",
        common.markdown_table(result['mjx'], ['task', 'worlds', 'ms_per_env_step',
                                              'env_steps_per_s', 'compile_s']),
        '\n## MuJoCo C (mujoco.rollout)\n',
        common.markdown_table(result['mujoco_c'], ['task', 'worlds', 'threads',
                                                   'env_steps_per_s']),
        '\n## MJX / MuJoCo C (all threads), same run\n',
        common.markdown_table(ratios, ['task', 'worlds', 'mjx_over_mujoco_c']),
        '\n## PushT physics settings\n',
        common.markdown_table(result['sweep'], [
            'variant', 'worlds', 'env_steps_per_s', 'T_displacement_m', 'T_pos_err_vs_1ms_ref_m',
            'T_yaw_err_vs_1ms_ref_rad', 'mjx_vs_mujoco_c_same_settings_m'])]
  with open(os.path.splitext(args.out)[0] + '.md', 'w') as f:
    f.write('\n'.join(md) + '\n')


if __name__ == '__main__':
  main()
