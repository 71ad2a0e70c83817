"""`pachs plan` wiring: a task's tuned SearchConfig (from `envs.registry`; reasons in
docs/task_defaults.md), its shipped actor-critic, and a result table."""

from __future__ import annotations

import dataclasses
import importlib.util
import os
import warnings
from typing import Callable, List, Optional, Sequence

import jax
import numpy as np

from pachs_jax import envs, replan
from pachs_jax.runtime import compile_cache, programs, sharding, signals
from pachs_jax.envs import backends, playground, pusht, registry
from pachs_jax.sac import checkpoint as checkpoint_lib
from pachs_jax.search import capacity, pachs
from pachs_jax.search.checks import check_seconds
from pachs_jax.search.config import SearchConfig
from pachs_jax.search.result import SearchResult, StopReason

CHECKPOINT_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'checkpoints')

def accelerator_settings(on_cpu: bool) -> dict:
  """The SearchConfig fields that `pachs plan`, `Planner` and the benchmarks set on an
  accelerator (none on a CPU)."""
  return {} if on_cpu else dict(registry.ACCELERATOR_SEARCH)


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


def replan_pop_size(task: str, query_time_s: Optional[float], physics: str) -> Optional[int]:
  """The K of a task's replanning with queries of query_time_s seconds where its edges are
  simulated with `physics` (an `Env.physics` or a backend name): the task's for that query time
  on an accelerator (`TaskSpec.replan_pop_size`); None (the search defaults') on a CPU-only
  machine and with MuJoCo C physics, whose CPU threads pay for a wider pop in time."""
  if jax.default_backend() == 'cpu' or physics == 'mujoco-c':
    return None
  return envs.spec(task).replan_pop_size(query_time_s)


def replan_fill_check(task: str, query_time_s: Optional[float], physics: str) -> bool:
  """Whether a task's replanning with queries of query_time_s seconds, its edges simulated with
  `physics` (as in `replan_pop_size`), checks the policy's fill of its short answers
  (`replan.Session.fill_steps`): on an accelerator from the task's query time
  (`TaskSpec.replan_fill_check`); always on a CPU-only machine, with MuJoCo C physics (whose
  fill is a few CPU physics steps of each episode, not a chain of latency-bound GPU calls) and
  for a task outside the registry."""
  if jax.default_backend() == 'cpu' or physics == 'mujoco-c' or task not in envs.TASKS:
    return True
  return envs.spec(task).replan_fill_check(query_time_s)


def command_config(task: Optional[str], on_cpu: bool, mujoco_c: bool,
                   budget: Optional[int] = None, algorithm: str = 'pachs',
                   **explicit) -> SearchConfig:
  """The SearchConfig of `pachs plan`.

  The task's defaults; on a CPU without a `budget`, the physics' CPU budget
  (`registry.CPU_PLANNING`) and the task's `cpu_overrides`; on a GPU, `accelerator_settings`. Non-None `explicit`
  SearchConfig fields (weight, num_actions, ...) win over all of these.
  """
  settings = accelerator_settings(on_cpu)
  if on_cpu and budget is None:
    settings.update(envs.spec(task).cpu_overrides if task is not None else {})
    budget = registry.cpu_planning('mujoco-c' if mujoco_c else 'other').budget
  settings.update({k: v for k, v in explicit.items() if v is not None})
  return default_config(task, algorithm, budget=budget, **settings)


def checkpoint_path(task: str) -> str:
  """Directory of the shipped actor-critic that plans `task` (':' in a name becomes '-':
  'playground:PointMass' -> checkpoints/playground-PointMass)."""
  return os.path.join(CHECKPOINT_DIR, envs.spec(task).model_task.replace(':', '-'))


def _check_backend(task, backend: str) -> None:
  """ValueError when the MuJoCo C backend is asked of a task it does not simulate."""
  if isinstance(task, envs.Env) and backend == 'mujoco-c':
    raise ValueError(f"backend 'mujoco-c' simulates the PushT tasks only; task {task.name!r} "
                     "runs its own transition (use backend 'mjx' or 'auto')")
  if envs.is_playground(task) and backend == 'mujoco-c':
    raise ValueError(f"--backend mujoco-c simulates the PushT tasks only; {task} runs in MJX "
                     "(use --backend mjx or auto)")


def _make_env(task, backend: str, nthread: Optional[int], layout: Optional[str],
              physics: Optional[str] = None):
  """The env of a task name with the chosen physics backend (and PushT physics preset), or a
  user's Env (checked with `envs.check_task`; MJX physics only)."""
  _check_backend(task, backend)
  if isinstance(task, envs.Env):
    envs.check_task(task)
    return task
  return backends.make_backend(envs.make(task, layout=layout, physics=physics), backend, nthread)


def load_model(task, path: Optional[str] = None, backend: str = 'mjx',
               nthread: Optional[int] = None, layout: Optional[str] = None,
               physics: Optional[str] = None):
  """(env, SacActorCritic) of a task: the shipped model unless `path`, checked against the env.

  task: a task name (`envs.TASKS`, or 'playground:NAME'), or a user's `envs.Env` (checked
  with `envs.check_task`; then `path` is required).
  backend: 'mjx', 'mujoco-c' (PushT edges simulated by MuJoCo C on CPU threads) or 'auto'
  (MuJoCo C when JAX has no accelerator). nthread: MuJoCo C threads (None: all CPUs).
  layout: pusht-obs's obstacle layout (`envs.layouts.LAYOUTS`; None: the default).
  physics: a PushT task's physics preset (`envs.physics_presets.PHYSICS_PRESETS`; None: the
    default).
  Raises FileNotFoundError for a missing checkpoint, ValueError for one of another task or size.
  """
  if path is not None and not (isinstance(path, (str, os.PathLike)) and os.fspath(path)):
    raise ValueError(f'checkpoint must name a model directory, got {path!r}')
  _check_backend(task, backend)
  if isinstance(task, envs.Env):
    if path is None:
      raise ValueError(f'task {task.name!r} has no shipped model: give the checkpoint of a '
                       'model trained on it')
    model_task = task.name
  else:
    model_task = envs.spec(task).model_task
  if envs.is_playground(model_task) and importlib.util.find_spec('mujoco_playground') is None:
    playground.require_playground()  # the install command first: nothing runs without it
  if envs.is_playground(model_task) and path is None:  # the env's name before its checkpoint
    playground.check_name(model_task[len(registry.PLAYGROUND_PREFIX):])
  # the checkpoint before the env (a Playground env takes long to build)
  path = path or checkpoint_path(model_task if isinstance(task, envs.Env) else task)
  if not os.path.exists(path):
    flag = '--env' if envs.is_playground(model_task) else '--task'
    raise FileNotFoundError(f'no checkpoint at {path!r}; train one with experiments/train.py '
                            f'{flag} {model_task}')
  name = task.name if isinstance(task, envs.Env) else task
  model = checkpoint_lib.load_actor_critic(path)  # a model of another task: refused at once
  allowed = {name, model_task}
  if model.config.task not in allowed:
    raise ValueError(f'{path!r} holds a model of task {model.config.task!r}; task {name!r} '
                     f'plans with a model of {" or ".join(sorted(allowed))}')
  env = _make_env(task, backend, nthread, layout, physics)
  task = name
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
  see `programs.plan`). Instance counts are padded to the next power of two, at least 32 on an
  accelerator but 1 on a CPU, where padded instances cost their full physics: there a new
  bucket (1, 2, 4, ...) compiles once (docs/startup_and_caching.md has the measured trade-off).

  task: a task name (`envs.TASKS`, 'playground:NAME') or a user's `envs.Env` (checked with
  `envs.check_task`); checkpoint: a model directory (None: the shipped one);
  backend: 'auto' (MuJoCo C physics on a CPU-only machine), 'mjx' or 'mujoco-c';
  budget and the SearchConfig fields in `overrides` as in `command_config`;
  cache: turn on the persistent compilation cache (`compile_cache.enable`);
  layout: pusht-obs's obstacle layout (None: the default);
  prefetch: a command line's `compile_cache.Prefetch` (None: nothing loaded ahead).
  physics_note: a line when the model was trained on other physics settings than the env
  simulates (`checkpoint.physics_mismatch`; also issued as a UserWarning), else None.
  """

  def __init__(self, task: str, checkpoint: Optional[str] = None, backend: str = 'auto',
               budget: Optional[int] = None, cache: bool = True, layout: Optional[str] = None,
               prefetch: Optional[compile_cache.Prefetch] = None, **overrides):
    if cache:
      compile_cache.enable()
    self.env, self.model = load_model(task, checkpoint, backend, layout=layout)
    self.task = self.env.name if isinstance(task, envs.Env) else task
    self.physics_note = checkpoint_lib.physics_mismatch(
        checkpoint or checkpoint_path(self.task), self.env)
    if self.physics_note is not None:
      warnings.warn(self.physics_note, stacklevel=2)
    on_cpu = jax.default_backend() == 'cpu'
    c_physics = self.env.physics == 'mujoco-c'
    if isinstance(task, envs.Env):  # a user's task: registry.USER_SEARCH
      self.config = command_config(None, on_cpu, c_physics, budget, **overrides)
      self._num_instances = 30
    else:
      self.config = command_config(task, on_cpu, c_physics, budget, **overrides)
      self._num_instances = envs.spec(task).num_instances
    # the task whose K for the query time a session takes (None: a user's task, or a given K)
    self._replan_task = (None if isinstance(task, envs.Env)
                         or overrides.get('pop_size') is not None else task)
    self.search = programs.Programs(pachs.make_search(self.env, self.model, self.config),
                                    prefetch=prefetch)
    self._canonical = None
    self._replaying = {}  # (replayed actions, K) -> the sessions' search (0: no chain lanes)

  @property
  def num_instances(self) -> int:
    """The size of the task's canonical instance set."""
    return self._num_instances

  def canonical(self, instances: Sequence[int]):
    """NodeState [len(instances)] of the task's canonical instances (generated once);
    ValueError unless instances are indices in 0..available - 1 (`check_indices`)."""
    index = check_indices(instances, self._num_instances)
    if self._canonical is None:
      self._canonical = canonical_instances(self.env, self._num_instances)
    return jax.tree.map(lambda x: x[index], self._canonical)

  def plan(self, instances: Optional[Sequence[int]] = None, start_nodes=None, seed: int = 0,
           time_limit_s: Optional[float] = None, stop: Optional[Callable[[], bool]] = None,
           progress: Optional[Callable[[programs.Progress], None]] = None,
           started: Optional[Callable[[], object]] = None, shrink: bool = True,
           devices: Optional[Sequence] = None) -> SearchResult:
    """Plans the canonical `instances` (indices) or the given start_nodes [I]; returns the
    SearchResult [I] (wall_time_s without compilation).

    seed: an integer in -2**63 .. 2**63 - 1. stop: checked between chunks of the search
    (about 0.3 s each); once it returns True, the instances still searching report
    'interrupted' with their real-time answer. Ctrl-C (SIGINT in the main thread) during the
    search does the same; before the search (while compiling) and a second Ctrl-C raise
    KeyboardInterrupt as usual. progress: called with a `programs.Progress` after each chunk;
    started: called once when the search begins (after compiling). shrink: as in
    `programs.plan` (False: a one-shot search, no further loop to compile).
    devices: shard the instances over these devices (`sharding.plan_sharded`: no time limit
    or progress; on one host stop and Ctrl-C work as above).
    """
    if (instances is None) == (start_nodes is None):
      raise ValueError('give either instances (canonical indices) or start_nodes')
    for name, fn in (('stop', stop), ('progress', progress), ('started', started)):
      if fn is not None and not callable(fn):  # before the signal handlers
        raise ValueError(f'{name} must be a function or None, got {fn!r}')
    key = jax.random.PRNGKey(check_seed(seed))
    if not isinstance(shrink, (bool, np.bool_)):
      raise ValueError(f'shrink must be True or False, got {shrink!r}')
    if devices is not None and (isinstance(devices, (str, bytes)) or not all(
        isinstance(d, jax.Device) for d in np.ravel(np.asarray(devices, object)))):
      raise ValueError(f'devices must be a sequence of jax devices (jax.devices()), got '
                       f'{devices!r}')
    if start_nodes is None:
      start_nodes = self.canonical(instances)
    if devices is not None and time_limit_s is not None:
      raise ValueError('a time limit (anytime mode) is not supported with sharding: plan on '
                       'one device, or run every instance to completion')
    with signals.interrupt_requests() as interrupted:
      asked = interrupted if stop is None else (lambda: interrupted() or bool(stop()))
      if devices is not None:
        return sharding.plan_sharded(self.env, self.model, start_nodes, self.config, key,
                                     mesh=sharding.instance_mesh(devices), stop=asked,
                                     started=started)
      try:
        return programs.plan(self.env, self.model, start_nodes, self.config, key,
                             time_limit_s=time_limit_s, search=self.search, stop=asked,
                             progress=progress, started=started, shrink=shrink)
      except signals.StoppedBeforeSearch:
        if interrupted():
          raise KeyboardInterrupt from None
        raise

  def session(self, horizon: Optional[int] = None,
              candidates: Sequence[str] = replan.DEFAULT_CANDIDATES,
              check: Optional[replan.AnswerCheck] = None,
              query_time_s: Optional[float] = None, fill_steps: int = 0) -> replan.Session:
    """A `replan.Session` that replans many episodes from their new states with this planner's
    env, model and config, keeping its last answer between queries (horizon, candidates, check
    and fill_steps as there). query_time_s: the seconds its queries will last, which on an
    accelerator choose its K (`TaskSpec.replan_pop_size`) unless the planner was given one.
    Where the config has chain lanes the session's search replays the last answer's remainder
    and is built apart from `plan`'s, with room for it (once per horizon and K, shared by the
    sessions that have them); otherwise it shares `plan`'s where the K is the same."""
    if horizon is not None and (isinstance(horizon, bool) or not isinstance(horizon, int)
                                or horizon < 1):  # before a search is built for it
      raise ValueError(f'horizon must be a positive int, got {horizon!r}')
    config = self.replan_config(query_time_s)
    rows = int(self.env.episode_length) if horizon is None else horizon
    rows = rows if config.rollout_lanes else 0
    search = self.search
    if rows or config != self.config:
      if (rows, config.pop_size) not in self._replaying:
        self._replaying[rows, config.pop_size] = programs.Programs(pachs.make_search(
            self.env, self.model, config, capacities=capacity.Capacities(replay=rows)))
      search = self._replaying[rows, config.pop_size]
    return replan.Session(self.env, self.model, config, search, horizon, candidates,
                          check=check, fill_steps=fill_steps)

  def replan_config(self, query_time_s: Optional[float]) -> SearchConfig:
    """The SearchConfig of a replanning session whose queries last query_time_s seconds: this
    planner's, with the task's K for that query time (`TaskSpec.replan_pop_size`; on an
    accelerator, when the planner was given no K); ValueError unless query_time_s is None or
    a finite number of seconds > 0."""
    check_seconds(query_time_s, 'query_time_s')
    pop_size = (None if self._replan_task is None
                else replan_pop_size(self._replan_task, query_time_s, self.env.physics))
    return self.config if pop_size is None else dataclasses.replace(self.config,
                                                                    pop_size=pop_size)

  def replan_fill_check(self, query_time_s: Optional[float]) -> bool:
    """Whether a replanning session with queries of query_time_s seconds should check the
    policy's fill of its short answers (`replan_fill_check`; a user's or a Playground task:
    always); ValueError as `replan_config`'s."""
    check_seconds(query_time_s, 'query_time_s')
    return replan_fill_check(self.task, query_time_s, self.env.physics)


def check_indices(instances, available: int) -> np.ndarray:
  """[I] int64 canonical indices; ValueError unless instances is a non-empty sequence of
  distinct integers in 0..available - 1 (no wrap-around of negative indices)."""
  shown = repr(instances) if len(repr(instances)) < 60 else repr(instances)[:56] + ' ...'
  try:
    values = np.asarray(instances)
  except Exception:  # pylint: disable=broad-except  (ragged or odd objects)
    values = np.asarray([], dtype=object)
  if values.ndim != 1 or values.size == 0:
    raise ValueError(f'instances must be a non-empty list of canonical indices in '
                     f'0..{available - 1}, got {shown}')
  if values.dtype == bool or not np.issubdtype(values.dtype, np.integer):
    raise ValueError(f'instances must be integers (canonical indices in 0..{available - 1}), '
                     f'got {shown}')
  bad = values[(values < 0) | (values >= available)]
  if bad.size:
    raise ValueError(f'instances must lie in 0..{available - 1}, got {int(bad[0])} in {shown}')
  unique, counts = np.unique(values, return_counts=True)
  if np.any(counts > 1):
    raise ValueError(f'instances must not repeat: {int(unique[counts > 1][0])} is listed '
                     f'{int(counts.max())} times in {shown} (plan it again with another seed)')
  return values.astype(np.int64)


def check_seed(seed) -> int:
  """seed as an int; ValueError unless it is an integer in -2**63 .. 2**63 - 1 (a PRNG key's
  64 bits)."""
  if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
    raise ValueError(f'seed must be an integer, got {seed!r}')
  if not -2**63 <= int(seed) < 2**63:
    raise ValueError(f'seed must fit in 64 bits (-2**63 .. 2**63 - 1), got {seed}')
  return int(seed)


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
  from pachs_jax.envs import render  # start-up path: matplotlib only where a plan is drawn
  if not env.name.startswith('pusht'):
    raise ValueError(f'drawing a path is implemented for the PushT tasks, not {env.name!r}')
  length = int(min(result.path_length[0], result.path_actions.shape[1]))
  nodes = jax.tree.map(lambda x: x[0, :length + 1], result.path_nodes)
  tips = np.asarray(jax.jit(jax.vmap(env.tip_position))(nodes))[:, :2]
  found = 'reached the goal' if bool(result.found[0]) else 'partial path'
  render.save_pusht_figure(path, np.asarray(pusht.t_pose(nodes.qpos)), np.asarray(nodes.goal[0]),
                           pusher_xy=tips, obstacles=env.obstacles if len(env.obstacles) else None,
                           every=max(1, length // 12),
                           title=f'{env.name} instance {instances[0]}: PACHS path of {length} '
                                 f'steps\ncost {float(result.cost[0]):.2f}, {found}')
  return path
