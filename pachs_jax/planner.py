"""`pachs plan` wiring: a task's tuned SearchConfig (from `envs.registry`; reasons in
docs/task_defaults.md), its shipped actor-critic, and a result table."""

from __future__ import annotations

import os
from typing import List, Optional, Sequence

import jax
import numpy as np

from pachs_jax import compile_cache, envs, programs
from pachs_jax.envs import mujoco_c, registry
from pachs_jax.sac import checkpoint as checkpoint_lib
from pachs_jax.search import pachs
from pachs_jax.search.config import SearchConfig
from pachs_jax.search.result import SearchResult, StopReason

CHECKPOINT_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'checkpoints')

# `pachs plan` on a CPU-only machine without a given budget: (instances, edge evaluations per
# instance) by physics backend, MuJoCo C ('mujoco-c') or MJX on the CPU ('other').
CPU_DEFAULTS = {'mujoco-c': ('all', 20_000), 'other': ('0', 2_000)}

# `pachs plan` on a GPU: SearchConfig.compact_fractions (docs/results.md, compaction):
# the command's one physics batch is the smallest of these that holds the live instances' lanes.
COMMAND_COMPACT_FRACTIONS = (0.125, 0.015625)


def default_config(task: Optional[str], algorithm: str = 'pachs',
                   **overrides) -> SearchConfig:
  """The task's SearchConfig for an algorithm of `registry.ALGORITHMS` ('pachs' or 'original';
  task None: a user's task, `registry.USER_SEARCH`) with fields replaced by the non-None
  `overrides`."""
  if task is None:  # a user's task: one-step edges either way
    registry.check_algorithm(algorithm)
    values = dict(registry.USER_SEARCH)
  else:
    values = dict(envs.spec(task).algorithm_defaults(algorithm))
  values.update({k: v for k, v in overrides.items() if v is not None})
  return SearchConfig(**values)


def command_config(task: Optional[str], on_cpu: bool, mujoco_c: bool,
                   budget: Optional[int] = None, algorithm: str = 'pachs',
                   **explicit) -> SearchConfig:
  """The SearchConfig of `pachs plan`.

  The task's defaults; on a CPU without a `budget`, the backend's CPU budget (`CPU_DEFAULTS`)
  and the task's `cpu_overrides`; on a GPU, `COMMAND_COMPACT_FRACTIONS`. Non-None `explicit`
  SearchConfig fields (weight, num_actions, ...) win over all of these.
  """
  settings = {} if on_cpu else {'compact_fractions': COMMAND_COMPACT_FRACTIONS}
  if on_cpu and budget is None:
    settings.update(envs.spec(task).cpu_overrides if task is not None else {})
    budget = CPU_DEFAULTS['mujoco-c' if mujoco_c else 'other'][1]
  settings.update({k: v for k, v in explicit.items() if v is not None})
  return default_config(task, algorithm, max_evaluations=budget, **settings)


def checkpoint_path(task: str) -> str:
  """Directory of the shipped actor-critic that plans `task` (':' in a name becomes '-':
  'playground:PointMass' -> checkpoints/playground-PointMass)."""
  return os.path.join(CHECKPOINT_DIR, envs.spec(task).model_task.replace(':', '-'))


def _make_env(task, backend: str, nthread: Optional[int], layout: Optional[str]):
  """The env of a task name with the chosen physics backend, or a user's Env (checked with
  `envs.check_task`; MJX physics only)."""
  if isinstance(task, envs.Env):
    if backend == 'mujoco-c':
      raise ValueError(f"backend 'mujoco-c' simulates the PushT tasks only; task {task.name!r} "
                       "runs its own transition (use backend 'mjx' or 'auto')")
    envs.check_task(task)
    return task
  if envs.is_playground(task) and backend == 'mujoco-c':
    raise ValueError(f"--backend mujoco-c simulates the PushT tasks only; {task} runs in MJX "
                     "(use --backend mjx or auto)")
  return mujoco_c.make_backend(envs.make(task, layout=layout), backend, nthread)


def load_model(task, path: Optional[str] = None, backend: str = 'mjx',
               nthread: Optional[int] = None, layout: Optional[str] = None):
  """(env, SacActorCritic) of a task: the shipped model unless `path`, checked against the env.

  task: a task name (`envs.TASKS`, or 'playground:NAME'), or a user's `envs.Env` (checked
  with `envs.check_task`; then `path` is required).
  backend: 'mjx', 'mujoco-c' (PushT edges simulated by MuJoCo C on CPU threads) or 'auto'
  (MuJoCo C when JAX has no accelerator). nthread: MuJoCo C threads (None: all CPUs).
  layout: pusht-obs's obstacle layout (`envs.layouts.LAYOUTS`; None: the default).
  Raises FileNotFoundError for a missing checkpoint, ValueError for one of another task or size.
  """
  env = _make_env(task, backend, nthread, layout)
  if isinstance(task, envs.Env):
    if path is None:
      raise ValueError(f'task {task.name!r} has no shipped model: give the checkpoint of a '
                       'model trained on it')
    model_task = task = task.name
  else:
    model_task = envs.spec(task).model_task
  path = path or checkpoint_path(task)
  if not os.path.exists(path):
    raise FileNotFoundError(f'no checkpoint at {path!r}; train one with experiments/train.py '
                            f'--task {model_task}')
  model = checkpoint_lib.load_actor_critic(path)
  allowed = {task, model_task}
  if model.config.task not in allowed:
    raise ValueError(f'{path!r} holds a model of task {model.config.task!r}; task {task!r} '
                     f'plans with a model of {" or ".join(sorted(allowed))}')
  if (model.config.observation_size, model.config.action_size) != (env.observation_size,
                                                                    env.action_size):
    raise ValueError(f'{path!r}: model sizes (observation {model.config.observation_size}, '
                     f'action {model.config.action_size}) do not fit task {task!r} '
                     f'({env.observation_size}, {env.action_size})')
  return env, model


def canonical_instances(env, num: int):
  """NodeState [num] of a task's canonical instances: `env.canonical_instances(num)`, or for
  an env without them the start nodes of keys split from PRNGKey(0)."""
  if hasattr(env, 'canonical_instances'):
    return env.canonical_instances(num)
  return jax.jit(env.initial_nodes)(jax.random.split(jax.random.PRNGKey(0), num))


class Planner:
  """Build once, plan many: a task's env, model and SearchConfig with its compiled programs
  kept warm between calls (compiled once per padded instance count and physics batch size,
  see `programs.plan`).

  task: a task name (`envs.TASKS`, 'playground:NAME') or a user's `envs.Env` (checked with
  `envs.check_task`); checkpoint: a model directory (None: the shipped one);
  backend: 'auto' (MuJoCo C physics on a CPU-only machine), 'mjx' or 'mujoco-c';
  budget and the SearchConfig fields in `overrides` as in `command_config`;
  cache: turn on the persistent compilation cache (`compile_cache.enable`);
  layout: pusht-obs's obstacle layout (None: the default).
  """

  def __init__(self, task: str, checkpoint: Optional[str] = None, backend: str = 'auto',
               budget: Optional[int] = None, cache: bool = True, layout: Optional[str] = None,
               **overrides):
    if cache:
      compile_cache.enable()
    self.env, self.model = load_model(task, checkpoint, backend, layout=layout)
    self.task = self.env.name if isinstance(task, envs.Env) else task
    on_cpu = jax.default_backend() == 'cpu'
    c_physics = type(self.env).__name__ == 'MujocoCEnv'
    if isinstance(task, envs.Env):  # a user's task: registry.USER_SEARCH
      self.config = command_config(None, on_cpu, c_physics, budget, **overrides)
      self._num_instances = 30
    else:
      self.config = command_config(task, on_cpu, c_physics, budget, **overrides)
      self._num_instances = envs.spec(task).num_instances
    self.search = programs.Programs(pachs.make_search(self.env, self.model, self.config))
    self._canonical = None

  def canonical(self, instances: Sequence[int]):
    """NodeState [len(instances)] of the task's canonical instances (generated once)."""
    if self._canonical is None:
      self._canonical = canonical_instances(self.env, self._num_instances)
    index = np.asarray(instances)
    return jax.tree.map(lambda x: x[index], self._canonical)

  def plan(self, instances: Optional[Sequence[int]] = None, start_nodes=None, seed: int = 0,
           time_limit_s: Optional[float] = None) -> SearchResult:
    """Plans the canonical `instances` (indices) or the given start_nodes [I]; returns the
    SearchResult [I] (wall_time_s without compilation)."""
    if (instances is None) == (start_nodes is None):
      raise ValueError('give either instances (canonical indices) or start_nodes')
    if start_nodes is None:
      start_nodes = self.canonical(instances)
    return programs.plan(self.env, self.model, start_nodes, self.config,
                         jax.random.PRNGKey(seed), time_limit_s=time_limit_s, search=self.search)


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


def result_rows(result: SearchResult, instances: Sequence[int]) -> List[dict]:
  """One dict per instance: found, cost, expansions, evaluations, stop reason."""
  r = jax.tree.map(np.asarray, result)
  rows = []
  for i, inst in enumerate(instances):
    rows.append({
        'instance': int(inst), 'found': bool(r.found[i]), 'cost': float(r.cost[i]),
        'path_length': int(r.path_length[i]), 'expanded': int(r.expanded[i]),
        'evaluated': int(r.evaluated[i]), 'iterations': int(r.iterations[i]),
        'stop': StopReason.name(r.stop_reason[i]),
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


def draw_result(env, result: SearchResult, instances: Sequence[int],
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
