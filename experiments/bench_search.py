"""PACHS search throughput on the accelerator next to raw batched env steps, in one run.

For each (instances I, pop size K) the search runs to its evaluation budget and reports edges
evaluated per second (compile excluded); the raw throughput of `env.evaluate` at the same batch
I*K is measured in the same run. Also: bytes per node and per instance at the budget, and the
device's peak memory.

--run-to-budget makes every instance spend its whole budget (goals are never accepted; the
critic still steers toward the real goal): the worst case of the issue's time targets, and a
throughput figure not diluted by instances that finish early.

  python experiments/bench_search.py --task pusht-fixed --out experiments/results/bench_search.json
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

import bench_engines
import common
from pachs_jax import planner, programs
from pachs_jax.envs import mujoco_c
from pachs_jax.search import pachs
from pachs_jax.sac import actor_critic as ac_lib
from pachs_jax.search.checks import instance_keys


def untrained_model(env, hidden=(256, 256, 256), seed=0) -> ac_lib.SacActorCritic:
  """A randomly initialised actor-critic of the task's shapes (throughput only)."""
  config = ac_lib.ModelConfig(task=env.name, observation_size=env.observation_size,
                              action_size=env.action_size, actor_hidden=hidden,
                              critic_hidden=hidden, episode_length=env.episode_length)
  nets = config.networks()
  kp, kq = jax.random.split(jax.random.PRNGKey(seed))
  params = ac_lib.ActorCriticParams(
      normalizer={'mean': jnp.zeros(env.observation_size), 'std': jnp.ones(env.observation_size)},
      policy=nets.policy_init(kp), q=nets.q_init(kq))
  return ac_lib.SacActorCritic(params=params, config=config)


class NeverGoal:
  """env with the goal test switched off (every other method delegated): searches run to their
  budget."""

  def __init__(self, env):
    self._env = env

  def __getattr__(self, name):
    return getattr(self._env, name)

  def is_goal(self, nodes):
    return jnp.zeros(jax.tree.leaves(nodes)[0].shape[:1], bool)

  def evaluate(self, nodes, actions):
    out = self._env.evaluate(nodes, actions)
    return out.replace(is_goal=jnp.zeros_like(out.is_goal))


def peak_memory_bytes():
  """The device's peak bytes in use so far (None where the backend does not say)."""
  stats = jax.devices()[0].memory_stats() or {}
  return stats.get('peak_bytes_in_use')


def tree_bytes(tree) -> int:
  return int(sum(np.prod(x.shape) * x.dtype.itemsize for x in jax.tree.leaves(tree)))


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--task', default='pusht-fixed')
  parser.add_argument('--checkpoint', default=None, help='default: the shipped model, else '
                      'an untrained one')
  parser.add_argument('--instances', default='1,30')
  parser.add_argument('--pop-sizes', default='16,64,256')
  parser.add_argument('--num-actions', type=int, default=8)
  parser.add_argument('--budget', type=int, default=100_000)
  parser.add_argument('--weight', type=float, default=2.0)
  parser.add_argument('--backend', default='mjx', choices=mujoco_c.BACKENDS,
                      help='physics of the edges (mujoco-c: MuJoCo C on the CPU threads; warp: '
                      'MuJoCo Warp)')
  parser.add_argument('--raw-steps', type=int, default=20,
                      help='evaluate calls per raw-throughput measurement')
  parser.add_argument('--cpu-threads', type=int, default=None,
                      help='MuJoCo C threads of --backend mujoco-c (default: all CPUs)')
  parser.add_argument('--run-to-budget', action='store_true',
                      help='never accept a goal: every instance spends its whole budget')
  parser.add_argument('--out', default='experiments/results/bench_search.json')
  args = parser.parse_args()

  try:
    env, model = planner.load_model(args.task, args.checkpoint, args.backend,
                                    args.cpu_threads)
    model_name = args.checkpoint or planner.checkpoint_path(args.task)
  except FileNotFoundError:
    from pachs_jax import envs
    env = envs.make(args.task)
    model, model_name = untrained_model(env), 'untrained 3x256 (no checkpoint yet)'
  result = {'provenance': common.provenance(), 'task': args.task, 'model': model_name,
            'backend': type(env).__name__, 'run_to_budget': args.run_to_budget, 'rows': []}
  starts_all = env.canonical_instances(30)
  if args.run_to_budget:
    env = NeverGoal(env)
  for num_instances, k in [(i, k) for i in map(int, args.instances.split(','))
                           for k in map(int, args.pop_sizes.split(','))]:
    config = planner.default_config(args.task, pop_size=k, num_actions=args.num_actions,
                                    max_evaluations=args.budget, weight=args.weight)
    index = np.arange(num_instances) % 30
    starts = jax.tree.map(lambda x: x[index], starts_all)
    search = programs.Programs(pachs.make_search(env, model, config))
    t0 = time.perf_counter()
    out = programs.plan(env, model, starts, config, jax.random.PRNGKey(0), search=search)
    first = time.perf_counter() - t0  # wall_time_s excludes compilation; this includes it
    wall = float(out.wall_time_s)
    evaluated = int(np.sum(out.evaluated))
    iterations = int(np.max(out.iterations))
    raw = bench_engines.jax_throughput(env, num_instances * k, steps=args.raw_steps, repeats=3)
    state_shape = jax.eval_shape(search.search.init, starts, instance_keys(
        jax.random.PRNGKey(0), num_instances))
    row = {
        'instances': num_instances, 'K': k, 'N': args.num_actions,
        'budget': args.budget,
        'wall_s': wall, 'first_call_s_incl_compile': first, 'evaluated': evaluated,
        'iterations': iterations, 'found': int(np.sum(out.found)),
        'expanded': int(np.sum(out.expanded)),
        'edges_per_s': evaluated / wall,
        'evaluated_per_iteration_per_instance': evaluated / max(iterations, 1) / num_instances,
        'lane_utilization_mean': float(np.mean(out.lane_utilization)),
        'raw_env_steps_per_s_same_batch': raw['env_steps_per_s'],
        'search_over_raw': evaluated / wall / raw['env_steps_per_s'],
        'state_bytes_per_instance': tree_bytes(state_shape) // num_instances,
        'pool_bytes_per_node': tree_bytes(state_shape.pool) // (num_instances * config.pool_size),
        'stop_reasons': np.bincount(np.asarray(out.stop_reason), minlength=7).tolist(),
        'overflow': int(np.sum(out.heap_overflow + out.pool_overflow + out.table_overflow)),
        'device_peak_bytes_so_far': peak_memory_bytes(),
    }
    print(row, flush=True)
    result['rows'].append(row)
    common.write_json(args.out, result)
  md = [f"# PACHS search throughput ({args.task}, model: {model_name}, env: "
        f"{result['backend']}"
        f"{', run to budget (goals never accepted)' if args.run_to_budget else ''})\n\n"
        f"{result['provenance']}\n",
        common.markdown_table(result['rows'], [
            'instances', 'K', 'N', 'budget', 'wall_s', 'first_call_s_incl_compile',
            'evaluated', 'iterations', 'found', 'edges_per_s', 'raw_env_steps_per_s_same_batch', 'search_over_raw',
            'lane_utilization_mean', 'evaluated_per_iteration_per_instance',
            'state_bytes_per_instance', 'device_peak_bytes_so_far'])]
  with open(os.path.splitext(args.out)[0] + '.md', 'w') as f:
    f.write('\n'.join(md) + '\n')


if __name__ == '__main__':
  main()
