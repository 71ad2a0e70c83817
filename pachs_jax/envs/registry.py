"""The task registry: each task's constructor, planning model, instance count and search defaults.

Measured reasons for the defaults: docs/task_defaults.md.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Dict, Mapping, Optional, Tuple

from pachs_jax.envs import base


@dataclasses.dataclass(frozen=True)
class TaskSpec:
  """One task.

  name: the task name (`Env.name`; pusht-obs with a layout other than the default is
    named 'pusht-obs:LAYOUT').
  make: (**options) -> Env, a new environment of the task.
  model_task: the task whose shipped actor-critic plans this one.
  num_instances: size of the canonical instance set (`Env.canonical_instances`).
  search_defaults: SearchConfig field values of PACHS, chosen at the paper's budget (on a GPU).
  original_search: those of the original algorithm ('original' in `ALGORITHMS`: one-step
    edges, as published; None: search_defaults with edge_steps 1).
  cpu_overrides: SearchConfig field values that replace either at the CPU budget of `pachs plan`.
  options: the keyword options `make` takes (pusht-obs: 'layout', `layouts.LAYOUTS`; PushT:
    'physics', a name of `pusht.PHYSICS_PRESETS`).
  replan_pop_sizes: (seconds, K) pairs, longest first: on an accelerator, a replanning session
    whose queries last at least that many seconds pops K edges per iteration (`replan_pop_size`;
    none: search_defaults' K at every query time).
  replan_fill_check_s: on an accelerator, a replanning session whose queries last at least that
    many seconds checks the policy's fill of its short answers (`replan_fill_check`; 0: at
    every query time).
  """

  name: str
  make: Callable[..., base.Env]
  model_task: str
  num_instances: int
  search_defaults: Mapping[str, Any]
  original_search: Optional[Mapping[str, Any]] = None
  cpu_overrides: Mapping[str, Any] = dataclasses.field(default_factory=dict)
  options: Tuple[str, ...] = ()
  replan_pop_sizes: Tuple[Tuple[float, int], ...] = ()
  replan_fill_check_s: float = 0.0

  def algorithm_defaults(self, algorithm: str = 'pachs') -> Mapping[str, Any]:
    """The SearchConfig field values of an algorithm of `ALGORITHMS`; ValueError naming them."""
    if check_algorithm(algorithm) == 'pachs':
      return self.search_defaults
    return self.original_search or dict(self.search_defaults, edge_steps=1, rollout_share=0.0,
                                        uniform_share=0.0)

  def replan_pop_size(self, query_time_s: Optional[float]) -> Optional[int]:
    """K of PACHS replanning on an accelerator with queries of query_time_s seconds
    (`replan_pop_sizes`); None: the search defaults' (below every threshold, and without a
    clock). `planner.replan_pop_size` adds where the edges are simulated."""
    if query_time_s is None:
      return None
    return next((k for seconds, k in self.replan_pop_sizes if query_time_s >= seconds), None)

  def replan_fill_check(self, query_time_s: Optional[float]) -> bool:
    """Whether replanning on an accelerator with queries of query_time_s seconds (None: no
    clock) follows each short answer's policy fill in the planner's physics and stops it
    before the first invalid edge (`replan.Session.fill_steps`; `replan_fill_check_s`)."""
    return query_time_s is None or query_time_s >= self.replan_fill_check_s


def _pusht(variant: str) -> Callable[..., base.Env]:
  def build(physics: str | None = None, **options) -> base.Env:
    from pachs_jax.envs import pusht  # lazy: a task's physics loads when it is made
    if physics is None:
      return pusht.PushTEnv(pusht.PushTConfig(variant=variant, **options))
    return pusht.PushTEnv(pusht.physics_preset(physics, variant=variant, **options))
  return build


def _shelf() -> base.Env:
  from pachs_jax.envs import shelf  # lazy: a task's physics loads when it is made
  return shelf.ShelfEnv()


# The search algorithms by name: 'pachs', the default (edges of `edge_steps` transitions that
# follow the actor after their sampled action), and 'original', the published one-step edges.
ALGORITHMS = ('pachs', 'original')


def check_algorithm(algorithm: str) -> str:
  """algorithm, when it names one of `ALGORITHMS`; ValueError listing them otherwise."""
  if algorithm not in ALGORITHMS:
    raise ValueError(f'unknown algorithm {algorithm!r}; valid: {", ".join(ALGORITHMS)}')
  return algorithm


# Weight w, actions per expansion N, edges popped per iteration K, edge evaluations per instance.
_SEARCH = {'weight': 2.0, 'num_actions': 8, 'pop_size': 64, 'budget': 100_000}
# PushT: edges of 8 transitions, and without a goal in time the path to the state whose
# incoming edge costs least per transition; PushT-Obs also extends chains of the actor's edges
# in 56 of its K = 64 lanes, restarting them at nodes of rarely visited coarse cells, and after
# its first goal spends up to 3x the evaluations that goal took on chains restarted on the
# cheapest goal's path (docs/task_defaults.md).
_PUSHT = dict(_SEARCH, edge_steps=8, realtime_answer='min_cost')
_PUSHT_OBS = dict(_PUSHT, rollout_share=0.875, chain_restart='novel', after_goal='improve',
                  improve_allowance=3.0, uniform_share=0.25)
# PushT-Obs replanning on a GPU: queries of 2 s or more pop K = 128 (at 3 s, 10-17 iterations a
# query and 0.86-1.2x the rollout's edges; K 64: 0.60-0.77x); shorter ones keep 64 (at 1 s K 128
# gets 3-5 iterations, too shallow). docs/task_defaults.md.
_PUSHT_OBS_REPLAN_POP_SIZES = ((2.0, 128),)
# ... and check the policy's fill in queries of 2 s or more: at 3 s the check halved the Ts
# tipped over and solved as many episodes; at 1 s its stopped fills left more episodes out of
# queries and it solved fewer (docs/task_defaults.md).
_PUSHT_OBS_REPLAN_FILL_CHECK_S = 2.0

SPECS: Dict[str, TaskSpec] = {s.name: s for s in (
    TaskSpec('pusht-fixed', _pusht('fixed'), 'pusht-fixed', 30, _PUSHT, _SEARCH,
             options=('physics',)),
    TaskSpec('pusht-rand', _pusht('rand'), 'pusht-rand', 30, _PUSHT, _SEARCH,
             options=('physics',)),
    TaskSpec('pusht-obs', _pusht('obs'), 'pusht-fixed', 30, _PUSHT_OBS,
             dict(_SEARCH, pop_size=256, lattice_resolution=(0.005, 0.005, 0.05, 0.01, 0.01)),
             cpu_overrides={'pop_size': 64,
                            'lattice_resolution': (0.01, 0.01, 0.1, 0.02, 0.02)},
             options=('layout', 'physics'), replan_pop_sizes=_PUSHT_OBS_REPLAN_POP_SIZES,
             replan_fill_check_s=_PUSHT_OBS_REPLAN_FILL_CHECK_S),
    TaskSpec('shelf', _shelf, 'shelf', 100,
             dict(_SEARCH, pop_size=16, budget=20_000)),
)}

TASKS = tuple(SPECS)

@dataclasses.dataclass(frozen=True)
class CpuPlanning:
  """What `pachs plan` and `Planner` plan on a CPU-only machine when no budget is given:
  instances ('all' or a `argtypes.instance_indices` text; `pachs plan` only) and budget (edge
  evaluations per instance)."""

  instances: str
  budget: int


# By physics: MuJoCo C on all CPU threads ('mujoco-c'), or MJX on the CPU ('other'; milliseconds
# per world and step). docs/task_defaults.md.
CPU_PLANNING = {'mujoco-c': CpuPlanning('all', 20_000), 'other': CpuPlanning('0', 2_000)}


def cpu_planning(physics: str) -> CpuPlanning:
  """`CPU_PLANNING` of an env's physics (`Env.physics`)."""
  return CPU_PLANNING['mujoco-c' if physics == 'mujoco-c' else 'other']


# On an accelerator, where a physics call costs about the same from a few to thousands of
# worlds: SearchConfig.compact_fractions, the smallest batch that holds the live instances'
# lanes, in halving sizes down to an eighth, then a 64th (docs/results.md, "Keeping the GPU
# full"). None applies on a CPU.
ACCELERATOR_SEARCH = {'compact_fractions': (0.5, 0.25, 0.125, 0.015625)}

# The physics backends of PushT edges (`backends.make_backend`): named here, where a command
# line reads them without importing MuJoCo.
BACKENDS = ('auto', 'mjx', 'mujoco-c', 'warp')

PLAYGROUND_PREFIX = 'playground:'  # 'playground:NAME': Playground's env NAME (envs/playground.py)

# The search defaults of a Playground task or a user's task (not tuned): the same w and N, a
# smaller K (a few edges per iteration suit a single instance on a CPU) and a budget of 20,000.
USER_SEARCH = dict(_SEARCH, pop_size=16, budget=20_000)


def _playground_spec(name: str) -> TaskSpec:
  """The TaskSpec of 'playground:NAME' (NAME is checked when the env is made)."""
  if name == PLAYGROUND_PREFIX:
    raise ValueError(f"give the Playground env's name: {PLAYGROUND_PREFIX}NAME, e.g. "
                     f'{PLAYGROUND_PREFIX}PointMass')

  def build(**options) -> base.Env:
    from pachs_jax.envs import playground  # lazy: a task's physics loads when it is made
    return playground.make(name, **options)

  return TaskSpec(name, build, name, 30, USER_SEARCH,
                  options=('check', 'is_goal', 'goal_threshold', 'reward_max',
                           'termination_cost', 'episode_length', 'lattice',
                           'lattice_resolution'))


def is_playground(name: str) -> bool:
  """Whether a task name names a MuJoCo Playground env ('playground:NAME')."""
  return isinstance(name, str) and name.startswith(PLAYGROUND_PREFIX)


def spec(name: str) -> TaskSpec:
  """The TaskSpec of a task name ('playground:NAME' for a MuJoCo Playground env); raises
  ValueError listing the valid names."""
  if is_playground(name):
    return _playground_spec(name)
  if name not in SPECS:
    raise ValueError(f'unknown task {name!r}; valid tasks: {", ".join(TASKS)}, or '
                     f'{PLAYGROUND_PREFIX}NAME (a MuJoCo Playground env)')
  return SPECS[name]


def make(name: str, **options) -> base.Env:
  """A new environment of the named task; raises ValueError listing the valid names.

  options: the task's keyword options (`TaskSpec.options`; None values are dropped), e.g.
  make('pusht-obs', layout='legacy'); one the task does not take raises ValueError.
  """
  task = spec(name)
  options = {k: v for k, v in options.items() if v is not None}
  unknown = sorted(set(options) - set(task.options))
  if unknown:
    takes = (f'it takes {", ".join(task.options)}' if task.options else 'it takes none')
    raise ValueError(f'task {name!r} has no option {", ".join(unknown)}; {takes}')
  return task.make(**options)
