"""Planning with the shipped models: per-task defaults, checkpoint lookup, a result table.

The search itself lives in `pachs_jax.search`; this module only wires a task, its trained
actor-critic and tuned parameters together for the `pachs plan` command and the experiments.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Dict, List, Optional, Sequence

import jax
import numpy as np

from pachs_jax import envs
from pachs_jax.search import types as search_types

CHECKPOINT_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'checkpoints')

# The model each task plans with (PushT-Obs uses the PushT-Fixed model, as in the original).
MODEL_FOR_TASK: Dict[str, str] = {
    'pusht-fixed': 'pusht-fixed',
    'pusht-rand': 'pusht-rand',
    'pusht-obs': 'pusht-fixed',
    'shelf': 'shelf',
}

# Tuned search parameters per task (w, N, K; lattice resolution: the env's default when None;
# the sweep: experiments/tune.py).
TASK_DEFAULTS: Dict[str, search_types.SearchConfig] = {
    'pusht-fixed': search_types.SearchConfig(weight=2.0, num_actions=8, pop_size=64,
                                             max_evaluations=100_000),
    'pusht-rand': search_types.SearchConfig(weight=2.0, num_actions=8, pop_size=64,
                                            max_evaluations=100_000),
    # PushT-Obs: K = 256 and half the default lattice cells (experiments/results/tune_pusht-obs.md:
    # each alone lifts 27/30 to 29/30; together 144/150 against 137/150 with K 64, default cells).
    'pusht-obs': search_types.SearchConfig(weight=2.0, num_actions=8, pop_size=256,
                                           max_evaluations=100_000,
                                           lattice_resolution=(0.005, 0.005, 0.05, 0.01, 0.01)),
    'shelf': search_types.SearchConfig(weight=2.0, num_actions=8, pop_size=16,
                                       max_evaluations=20_000),
}


# Defaults (instances, budget) on a CPU-only machine: with MuJoCo C physics (PushT, backend
# 'auto'), all instances at a fifth of the paper's budget (about a minute on 2 cores); with MJX on
# the CPU, which costs milliseconds per world and step, one instance and a small budget.
CPU_DEFAULTS = {'mujoco-c': ('all', 20_000), 'other': ('0', 2_000)}
# Settings that are better at the CPU's smaller budget (CPU, 2 cores, 30 instances, 20,000
# evaluations, MuJoCo C: PushT-Obs finds 28/30 in 43 s of search with these, 25/30 in 43 s with
# the GPU defaults, whose finer lattice pays off only with a larger budget).
CPU_TASK_OVERRIDES = {
    'pusht-obs': {'pop_size': 64, 'lattice_resolution': (0.01, 0.01, 0.1, 0.02, 0.02)},
}


# On a GPU `pachs plan` simulates only the live edges once they fit an eighth (or a 64th) of the
# I x K lanes (SearchConfig.compact_fractions): the 150-run PushT-Obs benchmark took 11.4 s
# instead of 32.0 s on one H200 (experiments/results/bench_compact.md). On the CPU the search's
# own work dominates and compaction did not pay (30 PushT-Obs instances, 2 cores: 45.9 s without,
# 46.9-49.3 s with). The experiment scripts keep the tuned configs as recorded.
COMMAND_COMPACT_FRACTIONS = (0.125, 0.015625)


def default_config(task: str, **overrides) -> search_types.SearchConfig:
  """The tuned SearchConfig of a task with fields replaced by the non-None overrides."""
  if task not in TASK_DEFAULTS:
    raise ValueError(f'unknown task {task!r}; valid tasks: {", ".join(TASK_DEFAULTS)}')
  kept = {k: v for k, v in overrides.items() if v is not None}
  return dataclasses.replace(TASK_DEFAULTS[task], **kept)


def command_config(task: str, on_cpu: bool, mujoco_c: bool, budget: Optional[int] = None,
                   **explicit) -> search_types.SearchConfig:
  """The SearchConfig of `pachs plan`: the task's defaults; on a CPU-only machine without a
  given budget, the CPU budget (`CPU_DEFAULTS`, by physics backend) and `CPU_TASK_OVERRIDES`;
  on a GPU compaction (`COMMAND_COMPACT_FRACTIONS`); explicit non-None values (weight,
  num_actions, ...) win over all of these."""
  settings = {} if on_cpu else {'compact_fractions': COMMAND_COMPACT_FRACTIONS}
  if on_cpu and budget is None:
    settings.update(CPU_TASK_OVERRIDES.get(task, {}))
    budget = CPU_DEFAULTS['mujoco-c' if mujoco_c else 'other'][1]
  settings.update({k: v for k, v in explicit.items() if v is not None})
  return default_config(task, max_evaluations=budget, **settings)


def checkpoint_path(task: str) -> str:
  """Directory of the shipped actor-critic that plans `task`."""
  if task not in MODEL_FOR_TASK:
    raise ValueError(f'unknown task {task!r}; valid tasks: {", ".join(MODEL_FOR_TASK)}')
  return os.path.join(CHECKPOINT_DIR, MODEL_FOR_TASK[task])


def load_model(task: str, path: Optional[str] = None, backend: str = 'mjx',
               nthread: Optional[int] = None):
  """(env, actor-critic) for a task: the shipped model unless `path`, checked against the env.

  backend: 'mjx', 'mujoco-c' (PushT edges simulated by MuJoCo C on all CPU threads) or 'auto'
  (MuJoCo C when JAX has no accelerator). nthread: MuJoCo C threads (None: all CPUs).
  """
  from pachs_jax.envs import mujoco_c
  from pachs_jax.sac import checkpoint
  env = mujoco_c.make_backend(envs.make(task), backend, nthread)
  path = path or checkpoint_path(task)
  if not os.path.exists(path):
    raise FileNotFoundError(f'no checkpoint at {path!r}; train one with experiments/train.py '
                            f'--task {MODEL_FOR_TASK.get(task, task)}')
  model = checkpoint.load_actor_critic(path)
  allowed = {task, MODEL_FOR_TASK[task]}
  if model.config.task not in allowed:
    raise ValueError(f'{path!r} holds a model of task {model.config.task!r}; task {task!r} '
                     f'plans with a model of {" or ".join(sorted(allowed))}')
  if (model.config.observation_size, model.config.action_size) != (env.observation_size,
                                                                    env.action_size):
    raise ValueError(f'{path!r}: model sizes (observation {model.config.observation_size}, '
                     f'action {model.config.action_size}) do not fit task {task!r} '
                     f'({env.observation_size}, {env.action_size})')
  return env, model


def parse_instances(text: str, available: int) -> List[int]:
  """'0-29' or '0,3,5' or '7' -> sorted instance indices, checked against `available`."""
  out = set()
  try:
    for part in text.split(','):
      if '-' in part:
        lo, hi = (int(x) for x in part.split('-'))
        out.update(range(lo, hi + 1))
      else:
        out.add(int(part))
  except ValueError:
    raise ValueError(f"instances must look like '0-29' or '0,3,5', got {text!r}") from None
  bad = [i for i in out if not 0 <= i < available]
  if not out or bad:
    raise ValueError(f'instances must lie in 0..{available - 1}, got {text!r}')
  return sorted(out)


def result_rows(result: search_types.SearchResult, instances: Sequence[int]) -> List[dict]:
  """One dict per instance: found, cost, expansions, evaluations, stop reason."""
  r = jax.tree.map(np.asarray, result)
  rows = []
  for i, inst in enumerate(instances):
    rows.append({
        'instance': int(inst), 'found': bool(r.found[i]), 'cost': float(r.cost[i]),
        'path_length': int(r.path_length[i]), 'expanded': int(r.expanded[i]),
        'evaluated': int(r.evaluated[i]), 'iterations': int(r.iterations[i]),
        'stop': search_types.StopReason.name(r.stop_reason[i]),
        'overflow': int(r.heap_overflow[i] + r.pool_overflow[i] + r.table_overflow[i])})
  return rows


def format_table(rows: List[dict], columns: Sequence[str]) -> str:
  """A plain-text table of the given columns."""
  def fmt(v):
    return f'{v:.3f}' if isinstance(v, float) else str(v)
  cells = [[c for c in columns]] + [[fmt(r[c]) for c in columns] for r in rows]
  widths = [max(len(row[i]) for row in cells) for i in range(len(columns))]
  lines = ['  '.join(x.rjust(w) for x, w in zip(row, widths)) for row in cells]
  lines.insert(1, '  '.join('-' * w for w in widths))
  return '\n'.join(lines)


def draw_result(env, result: search_types.SearchResult, instances: Sequence[int],
                path: str) -> str:
  """Draws the first instance's path (PushT: T poses, goal, obstacles, pusher trace)."""
  from pachs_jax.envs import render
  if not env.name.startswith('pusht'):
    raise ValueError(f'drawing a path is implemented for the PushT tasks, not {env.name!r}')
  length = int(min(result.path_length[0], result.path_actions.shape[1]))
  nodes = jax.tree.map(lambda x: x[0, :length + 1], result.path_nodes)
  tips = np.asarray(jax.jit(jax.vmap(env.tip_position))(nodes))[:, :2]
  found = 'reached the goal' if bool(result.found[0]) else 'partial path'
  render.save_pusht_figure(path, np.asarray(nodes.qpos[:, 7:10]), np.asarray(nodes.goal[0]),
                           pusher_xy=tips, obstacles=env.obstacles if len(env.obstacles) else None,
                           every=max(1, length // 12),
                           title=f'{env.name} instance {instances[0]}: PACHS path of {length} '
                                 f'steps\ncost {float(result.cost[0]):.2f}, {found}')
  return path
