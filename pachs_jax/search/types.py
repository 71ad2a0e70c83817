"""The search's configuration, result, stop reasons and actor-critic protocol, and the checks
of its inputs."""

from __future__ import annotations

import collections
import dataclasses
import functools
import numbers
import math
from typing import Optional, Protocol, Tuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pachs_jax import compile_cache
from pachs_jax.envs import base

REALTIME_ANSWERS = ('best_f', 'min_h', 'min_cost')
CHAIN_RESTARTS = ('start', 'novel')


class StopReason:
  """Why a search instance stopped ([I] int32 codes in `SearchResult.stop_reason`)."""

  RUNNING = 0  # not stopped yet (a chunked run that was interrupted)
  GOAL = 1  # a dummy edge of a goal state was popped
  BUDGET = 2  # a popped edge needed an evaluation beyond `max_evaluations`
  ITERATIONS = 3  # `max_iterations` loop iterations done
  OPEN_EMPTY = 4  # OPEN held no edge: every reachable lattice cell was expanded
  CAPACITY = 5  # the heap, node pool or lattice table overflowed (see the overflow counts)
  TIME_LIMIT = 6  # the host's wall-clock limit ran out between chunks (set by `plan`)

  NAMES = ('running', 'goal', 'budget', 'iterations', 'open_empty', 'capacity', 'time_limit')

  @classmethod
  def name(cls, code: int) -> str:
    return cls.NAMES[int(code)]


class ActorCritic(Protocol):
  """The trained model as the search sees it; both functions are pure and jittable.

  `sample_actions(key, obs[B, O], num) -> [B, num, A]` actions in [-1, 1] (the actor's
  proposals for the outgoing edges of B states).
  `q_values(obs[B, O], actions[B, num, A]) -> [B, num]` float32 critic Q, a reward sum in the
  environment's reward units; the search uses the cost-to-go q = max(-Q, 0).
  """

  def sample_actions(self, key: jax.Array, obs: jax.Array, num: int) -> jax.Array:
    ...

  def q_values(self, obs: jax.Array, actions: jax.Array) -> jax.Array:
    ...


def plain_number(value):
  """value as a Python int or float when it is an integer or real number of any kind (a numpy
  or JAX scalar, a 0-d array); anything else, bools included, unchanged."""
  if isinstance(value, (bool, np.bool_)) or isinstance(value, jax.core.Tracer):
    return value
  if isinstance(value, numbers.Integral):
    return int(value)
  if isinstance(value, numbers.Real):
    return float(value)
  dtype = getattr(value, 'dtype', None)
  if getattr(value, 'shape', None) == () and dtype is not None:
    if jnp.issubdtype(dtype, jnp.integer):
      return int(value)
    if jnp.issubdtype(dtype, jnp.floating):
      return float(value)
  return value


def normalize_numbers(config) -> None:
  """Replaces the numpy / JAX scalar fields of a frozen dataclass config by Python ints and
  floats (so that equal configs hash and compare equal); call first in __post_init__."""
  for field in dataclasses.fields(config):
    value = getattr(config, field.name)
    plain = plain_number(value)
    if plain is not value:
      object.__setattr__(config, field.name, plain)


def positive_int(owner: str, name: str, value, allow_none: bool = False):
  """value as a Python int >= 1 (numpy and JAX integers accepted; None when allow_none);
  ValueError otherwise (bools included)."""
  if value is None and allow_none:
    return None
  value = plain_number(value)
  if isinstance(value, bool) or not isinstance(value, int) or value < 1:
    raise ValueError(f'{owner}.{name} must be a positive int, got {value!r}')
  return value


def check_weight(owner: str, weight) -> float:
  """weight as a Python float, finite and >= 0 (numpy and JAX numbers accepted); ValueError
  otherwise."""
  weight = plain_number(weight)
  if (isinstance(weight, bool) or not isinstance(weight, (int, float))
      or not math.isfinite(weight) or weight < 0):
    raise ValueError(f'{owner}.weight must be a finite number >= 0, got {weight!r}')
  return float(weight)


def check_table_capacity(owner: str, table_capacity) -> None:
  """ValueError for a lattice-table capacity that is not a power of two."""
  if table_capacity is not None and table_capacity & (table_capacity - 1):
    raise ValueError(f'{owner}.table_capacity must be a power of two, got {table_capacity}')


def check_actor_critic(actor_critic, names) -> None:
  """ValueError unless actor_critic has each of the named methods."""
  for name in names:
    if not callable(getattr(actor_critic, name, None)):
      raise ValueError(f'actor_critic has no method {name}(...) (see search.types.ActorCritic)')


def lattice_resolution_tuple(owner: str, resolution):
  """None, or the resolution as a tuple of positive finite floats (numpy and JAX numbers
  accepted); ValueError otherwise."""
  if resolution is None:
    return None
  try:
    res = tuple(plain_number(r) for r in resolution)
  except TypeError:
    res = ()
  if not res or not all(isinstance(r, (int, float)) and not isinstance(r, bool)
                        and math.isfinite(r) and r > 0 for r in res):
    raise ValueError(f'{owner}.lattice_resolution must be a non-empty tuple of positive cell '
                     f'sizes, got {resolution!r}')
  return tuple(float(r) for r in res)


# Lattice coordinates are int32; a cell size is allowed when the coordinates of the env's
# states stay within +-2**30 (half the int32 range, a margin for float32 rounding).
LATTICE_COORD_LIMIT = 2.0**30


def _ceil_2(x: float) -> float:
  """x rounded up to 2 significant digits (so that the printed bound is itself allowed)."""
  if x <= 0:
    return 0.0
  scale = 10.0**(math.floor(math.log10(x)) - 1)
  return math.ceil(x / scale * (1 - 1e-12)) * scale


def _format_sizes(values) -> str:
  return '(' + ', '.join(f'{v:.2g}' for v in values) + ')'


def min_lattice_resolution(env: base.Env):
  """[L] float64 smallest cell sizes that keep env's int32 lattice coordinates from
  overflowing (`Env.lattice_extent` / 2**30), or None when the env does not bound them."""
  extent = getattr(env, 'lattice_extent', None)
  if extent is None:
    return None
  return np.abs(np.asarray(extent, np.float64)) / LATTICE_COORD_LIMIT


def env_lattice_resolution(env: base.Env, resolution) -> jax.Array:
  """[L] float32 cell sizes: `resolution`, or the env's default when None.

  ValueError when its length differs from the env's, or when a cell is so small that the
  int32 lattice coordinates of the env's states overflow (they saturate, and every state falls
  into one cell); the message names the smallest allowed size per coordinate.
  """
  default = np.asarray(env.default_lattice_resolution, np.float32)
  if resolution is None:
    return jax.device_put(default)
  given = _format_sizes(np.asarray(resolution, np.float64).ravel())
  resolution = np.asarray(resolution, np.float32)
  if resolution.shape != default.shape:
    raise ValueError(f'lattice_resolution has {resolution.shape[0]} entries, but the '
                     f'environment {env.name} uses {default.shape[0]}')
  res = np.asarray(resolution, np.float64)
  smallest = min_lattice_resolution(env)
  if smallest is not None and np.shape(smallest) != res.shape:
    raise ValueError(f'{type(env).__name__}.lattice_extent has shape {np.shape(smallest)}, but '
                     f'its lattice coordinates have {res.shape}')
  allowed = np.array([_ceil_2(float(x)) for x in smallest]) if smallest is not None else None
  too_fine = ~(res > 0) | ~np.isfinite(res)
  if smallest is not None:
    too_fine |= res < smallest
  if too_fine.any():
    bad = [int(i) for i in np.flatnonzero(too_fine)]
    if allowed is None:
      raise ValueError(f'lattice_resolution {given} of {env.name}: cells {bad} become 0 or inf '
                       'in float32')
    raise ValueError(f'lattice_resolution {given} overflows the int32 lattice coordinates of '
                     f'{env.name} (coordinate{"s" * (len(bad) > 1)} {", ".join(map(str, bad))}): '
                     f'cell sizes must be at least {_format_sizes(allowed)}')
  return jax.device_put(resolution)


def node_spec(env: base.Env) -> base.NodeState:
  """The shapes of one node of env (no batch axis)."""
  return jax.eval_shape(env.sample_instance, jax.ShapeDtypeStruct((2,), jnp.uint32))


def check_start_nodes(start_nodes: base.NodeState, env: base.Env) -> int:
  """The number of instances I of start_nodes [I, ...]; ValueError when the shapes do not fit
  env's NodeState."""
  spec = node_spec(env)
  leaves, spec_leaves = jax.tree.leaves(start_nodes), jax.tree.leaves(spec)
  if (jax.tree.structure(start_nodes) != jax.tree.structure(spec)
      or any(jnp.ndim(x) != len(s.shape) + 1 or jnp.shape(x)[1:] != s.shape
             for x, s in zip(leaves, spec_leaves))):
    want = jax.tree.map(lambda s: ('I',) + s.shape, spec)
    got = jax.tree.map(jnp.shape, start_nodes)
    raise ValueError(f'start_nodes must be the environment\'s NodeState with a leading '
                     f'instance axis: want shapes {want}, got {got}')
  sizes = {jnp.shape(x)[0] for x in leaves}
  if len(sizes) != 1 or 0 in sizes:
    raise ValueError(f'start_nodes leaves must share one leading axis I >= 1, got {sizes}')
  check_finite_start_nodes(start_nodes)
  return sizes.pop()


def check_finite_start_nodes(start_nodes: base.NodeState) -> None:
  """ValueError naming the instances whose start state or goal holds a NaN or inf (host-side;
  does nothing for traced or non-addressable arrays, e.g. under jit)."""
  fields = [(f.name, getattr(start_nodes, f.name)) for f in dataclasses.fields(start_nodes)]
  if any(isinstance(x, jax.core.Tracer) or not getattr(x, 'is_fully_addressable', True)
         for _, x in fields):
    return
  bad, names = None, []
  for name, x in fields:
    x = np.asarray(x)
    if not np.issubdtype(x.dtype, np.inexact):
      continue
    ok = np.isfinite(x.reshape(x.shape[0], -1)).all(axis=1)
    if not ok.all():
      names.append(name)
      bad = ~ok if bad is None else bad | ~ok
  if names:
    index = np.flatnonzero(bad).tolist()
    raise ValueError(f'start_nodes of instance{"s" * (len(index) > 1)} {_list(index)} are not '
                     f'finite (NaN or inf in {", ".join(names)}): the search needs finite start '
                     'states and goals')


def _list(index, most: int = 10) -> str:
  """'[0, 3, 7]', or the first `most` and a count."""
  if len(index) <= most:
    return str(list(index))
  return f'[{", ".join(map(str, index[:most]))}, ...] ({len(index)} in all)'


_MODEL_CHECKS: collections.OrderedDict = collections.OrderedDict()


def _model_outputs_program(env: base.Env, actor_critic, num_actions: int, nodes: base.NodeState,
                           fingerprint: Optional[str]):
  """The compiled (nodes [B], key) -> ([B] bool finite observations, [B] finite actions, [B]
  finite Q) for nodes shaped like `nodes` (stored under fingerprint,
  `compile_cache.compiled_program`), cached per (env, actor_critic, num_actions) object and
  batch size (the last 8, held so ids stay unique)."""
  batch = jax.tree.leaves(nodes)[0].shape[0]
  cache_key = (id(env), id(actor_critic), num_actions, batch)
  hit = _MODEL_CHECKS.get(cache_key)
  if hit is not None and hit[0] is env and hit[1] is actor_critic:
    _MODEL_CHECKS.move_to_end(cache_key)
    return hit[2]

  def outputs(nodes, key):
    finite = lambda x: jnp.all(jnp.isfinite(x.reshape(x.shape[0], -1)), axis=1)
    obs = env.observe(nodes)
    actions = actor_critic.sample_actions(key, obs, num_actions)
    # the actions as the search scores them (non-finite entries zeroed, clipped)
    clean = jnp.clip(jnp.nan_to_num(actions.astype(jnp.float32)), -1.0, 1.0)
    q = actor_critic.q_values(obs, clean)
    return finite(obs), finite(actions), finite(q)

  program = compile_cache.compiled_program(jax.jit(outputs), (nodes, jax.random.PRNGKey(0)),
                                           fingerprint)
  _MODEL_CHECKS[cache_key] = (env, actor_critic, program)
  while len(_MODEL_CHECKS) > 8:
    _MODEL_CHECKS.popitem(last=False)
  return program


def check_model_outputs(env: base.Env, actor_critic: ActorCritic, start_nodes: base.NodeState,
                        num_actions: int, fingerprint: Optional[str] = None) -> None:
  """ValueError when the actor-critic's sampled actions or critic Q on the start states are
  not finite (a damaged model, or one of another task): the search would drop every edge and
  report OPEN empty, as if the task had been searched exhaustively.

  One small jitted call on the start nodes [I] (padded to a power of two, so that nearby
  instance counts share its compilation; stored under fingerprint, see
  `compile_cache.compiled_program`); also ValueError for non-finite observations.
  """
  num = jax.tree.leaves(start_nodes)[0].shape[0]
  padded = next_pow2(num)
  if padded != num:
    start_nodes = pad_rows(start_nodes, padded)
  program = _model_outputs_program(env, actor_critic, num_actions, start_nodes, fingerprint)
  obs_ok, actions_ok, q_ok = (np.asarray(x)[:num]
                              for x in program(start_nodes, jax.random.PRNGKey(0)))
  for ok, what in ((obs_ok, f'{env.name} gives non-finite observations of the start states'),
                   (actions_ok, 'actor-critic samples non-finite actions on the start states'),
                   (q_ok, 'actor-critic returns non-finite Q on the start states')):
    if not ok.all():
      index = np.flatnonzero(~ok).tolist()
      cause = ('the start states lie outside the task' if ok is obs_ok else
               'the model is damaged or does not fit the task')
      raise ValueError(f'{what} (instance{"s" * (len(index) > 1)} {_list(index)}): {cause}')


def instance_keys(key: jax.Array, num_instances: int) -> jax.Array:
  """[I, 2] uint32 per-instance keys: one key ([2] raw or [] typed) is split, per-instance keys
  ([I, 2] raw or [I] typed) are kept; ValueError for other shapes."""
  key = jnp.asarray(key)
  if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
    key = jax.random.key_data(key)
  if key.shape == (2,):
    key = jax.random.split(key, num_instances)
  if key.shape != (num_instances, 2):
    raise ValueError(f'key must be one PRNG key or [I, 2] keys with I = {num_instances}, '
                     f'got shape {key.shape}')
  return key.astype(jnp.uint32)


def cost_to_go(q_value: jax.Array) -> jax.Array:
  """The critic's cost-to-go q = max(-Q, 0), with NaN as +inf (such an edge is never chosen)."""
  q = jnp.maximum(-q_value.astype(jnp.float32), 0.0)
  return jnp.where(jnp.isnan(q), jnp.inf, q)


def next_pow2(n: int) -> int:
  """The smallest power of two >= n (1 for n <= 1)."""
  return 1 << max(0, int(n - 1).bit_length())


@functools.partial(jax.jit, static_argnums=1)
def pad_rows(tree, size: int):
  """The pytree's leaves [n, ...] as [size, ...] (size >= n), the new rows copies of row 0:
  one compiled program for the whole tree instead of a few per leaf."""
  return jax.tree.map(
      lambda x: jnp.concatenate([x, jnp.repeat(x[:1], size - x.shape[0], axis=0)]), tree)


@functools.partial(jax.jit, static_argnums=1)
def first_rows(tree, size: int):
  """The pytree's leaves with a leading axis cut to their first `size` rows (scalars kept), as
  one compiled program."""
  return jax.tree.map(lambda x: x[:size] if jnp.ndim(x) else x, tree)


@dataclasses.dataclass(frozen=True)
class EdgeSearchConfig:
  """The settings that PACHS and ePA*SE share; capacities left as None are derived from the
  evaluation budget and never overflow.

  weight: heuristic weight w >= 0 (keys g + w h).
  pop_size: K: per instance and iteration, the edges popped (PACHS: up to K states expanded
    and K edges evaluated).
  max_evaluations: edge-evaluation budget per instance.
  max_iterations: loop-iteration limit per instance (None: no limit beyond the budget).
  lattice_resolution: [L] lattice cell sizes (None: the environment's default).
  heap_capacity: OPEN entries per instance (None: every edge the budget can generate).
  pool_capacity: nodes per instance (None: budget + 1).
  table_capacity: lattice-table slots per instance, a power of two (None: >= 2 * pool).
  max_path_length: actions kept in a returned path (longer paths keep their first ones).
  """

  weight: float = 1.0
  pop_size: int = 16
  max_evaluations: int = 100_000
  max_iterations: Optional[int] = None
  lattice_resolution: Optional[Tuple[float, ...]] = None
  heap_capacity: Optional[int] = None
  pool_capacity: Optional[int] = None
  table_capacity: Optional[int] = None
  max_path_length: int = 1024

  def __post_init__(self):
    owner = type(self).__name__
    normalize_numbers(self)
    object.__setattr__(self, 'weight', check_weight(owner, self.weight))
    for name in ('pop_size', 'max_evaluations', 'max_path_length'):
      positive_int(owner, name, getattr(self, name))
    for name in ('max_iterations', 'heap_capacity', 'pool_capacity', 'table_capacity'):
      positive_int(owner, name, getattr(self, name), allow_none=True)
    check_table_capacity(owner, self.table_capacity)
    object.__setattr__(self, 'lattice_resolution',
                       lattice_resolution_tuple(owner, self.lattice_resolution))

  @property
  def pool_size(self) -> int:
    """Nodes per instance."""
    return self.pool_capacity or self.max_evaluations + 1

  @property
  def table_size(self) -> int:
    """Lattice-table slots per instance (a power of two)."""
    return self.table_capacity or next_pow2(2 * self.pool_size)

  def check_slots(self, slots: int) -> None:
    """ValueError when heap entries node * slots + slot would overflow int32."""
    if self.pool_size * slots >= 2**31:
      raise ValueError(f'{type(self).__name__}: pool_capacity * (edges per node + 1) must stay '
                       f'below 2**31 (heap entries store node * (edges + 1) + slot as int32); '
                       f'got {self.pool_size} nodes and {slots - 1} edges per node')

  def iteration_limit_for(self, slots: int) -> int:
    """Loop iterations per instance with `slots` heap entries per node (the default is never
    reached before the budget)."""
    if self.max_iterations is not None:
      return self.max_iterations
    return min(2**31 - 1, slots * (self.max_evaluations + 1) + 1)


@dataclasses.dataclass(frozen=True)
class SearchConfig(EdgeSearchConfig):
  """PACHS parameters: those of `EdgeSearchConfig` and

  num_actions: N actions sampled per expansion.
  realtime_answer: the path returned when no goal was found: 'best_f' (to the state of the
    best OPEN entry, the original's), 'min_h' (to the generated state, the start excluded,
    of least estimated cost-to-go; needs w > 0) or 'min_cost' (to the generated state whose
    incoming edge has the least cost per transition, `path.min_cost_answer`).
  compact_fractions: smaller physics batches as fractions in (0, 1) of the I * K lanes
    (`compact.evaluate_live`); () always simulates all lanes.
  edge_steps: H, the transitions of one edge: its sampled action, then H - 1 actions that the
    actor samples along the way (`segment`); an edge costs H evaluations, and a successor's h
    is the critic's at its state. 1: the original's one-step edges, h = q - c.
  rollout_share: the share of the K evaluation lanes, R = floor(share K) (`rollout_lanes`), that
    extend chains of the actor's edges (each from its chain's last successor, restarting as
    chain_restart says after an unusable edge or an episode's length) instead of popping OPEN's
    best edges; their successors join the search, and a chain's goal ends the instance at once.
  chain_restart: where a chain restarts: 'start' (the start state, so that chains are rollouts
    of the actor) or 'novel' (a generated node drawn with weight 1 / the nodes in its coarse
    cell, `novelty`; nodes whose next edge would pass an episode's length are left out); no
    effect without rollout lanes.
  novelty_coarsening: the coarse cells of 'novel': lattice cells merged this many to a side.
  heap_capacity bounds both heaps: the real-edge heap (None: N * pool) and the dummy-edge heap
  (None: pool). pool_capacity None: budget // H + 1.
  """

  num_actions: int = 16
  realtime_answer: str = 'best_f'
  compact_fractions: Tuple[float, ...] = ()
  edge_steps: int = 1
  rollout_share: float = 0.0
  chain_restart: str = 'start'
  novelty_coarsening: int = 4

  def __post_init__(self):
    super().__post_init__()
    positive_int('SearchConfig', 'num_actions', self.num_actions)
    positive_int('SearchConfig', 'novelty_coarsening', self.novelty_coarsening)
    if self.chain_restart not in CHAIN_RESTARTS:
      raise ValueError(f'SearchConfig.chain_restart must be one of {CHAIN_RESTARTS}, got '
                       f'{self.chain_restart!r}')
    positive_int('SearchConfig', 'edge_steps', self.edge_steps)
    share = self.rollout_share
    if (isinstance(share, bool) or not isinstance(share, (int, float)) or not 0 <= share < 1):
      raise ValueError(f'SearchConfig.rollout_share must be a number in [0, 1), got {share!r}')
    object.__setattr__(self, 'rollout_share', float(share))
    if self.edge_steps > self.max_evaluations:
      raise ValueError(f'SearchConfig.edge_steps ({self.edge_steps}) exceeds max_evaluations '
                       f'({self.max_evaluations}): no edge would fit the budget')
    if self.realtime_answer not in REALTIME_ANSWERS:
      raise ValueError(f'SearchConfig.realtime_answer must be one of {REALTIME_ANSWERS}, got '
                       f'{self.realtime_answer!r}')
    fractions = (tuple(plain_number(f) for f in self.compact_fractions)
                 if isinstance(self.compact_fractions, (tuple, list)) else (None,))
    if not all(isinstance(f, numbers.Real) and not isinstance(f, bool) and 0 < f < 1
               for f in fractions):
      raise ValueError('SearchConfig.compact_fractions must be fractions in (0, 1), got '
                       f'{self.compact_fractions!r}')
    object.__setattr__(self, 'compact_fractions', tuple(float(f) for f in fractions))
    if self.realtime_answer == 'min_h' and not self.weight > 0:
      raise ValueError("SearchConfig.realtime_answer='min_h' reads h from the dummy-edge keys "
                       f'and needs weight > 0, got {self.weight!r}')
    self.check_slots(self.num_actions + 1)
    if self.edge_heap_size >= 2**31 or self.table_size >= 2**31:
      raise ValueError('heap and table capacities must stay below 2**31 '
                       f'(got heap {self.edge_heap_size}, table {self.table_size})')

  @property
  def rollout_lanes(self) -> int:
    """R, the lanes of the K that extend chains of the actor's edges."""
    return int(self.rollout_share * self.pop_size)

  @property
  def pool_size(self) -> int:
    """Nodes per instance (one per edge the budget pays for, and the start)."""
    return self.pool_capacity or self.max_evaluations // self.edge_steps + 1

  @property
  def novelty_cells(self) -> int:
    """Hashed coarse cells per instance of chain_restart 'novel' (1 otherwise)."""
    return (next_pow2(2 * self.pool_size) if self.chain_restart == 'novel' and self.rollout_lanes
            else 1)

  @property
  def edge_heap_size(self) -> int:
    """Entries per instance of the real-edge heap: N per expanded node."""
    return self.heap_capacity or self.num_actions * self.pool_size

  @property
  def dummy_heap_size(self) -> int:
    """Entries per instance of the dummy-edge heap: the start's plus one per edge."""
    edges = self.max_evaluations // self.edge_steps + 1
    return min(self.heap_capacity or edges, edges)

  @property
  def iteration_limit(self) -> int:
    """Loop iterations per instance (the default is never reached before the budget)."""
    return self.iteration_limit_for(self.num_actions + 1)


@struct.dataclass
class SearchResult:
  """The outcome of planning I problem instances (leading axis I everywhere).

  found: [I] bool, a goal state's dummy edge was popped; the path ends at that goal.
  stop_reason: [I] int32 `StopReason` code.
  path_actions: [I, max_path_length, A] actions from the start; rows >= path_length are 0.
  path_length: [I] int32 number of actions in the path (may exceed max_path_length, see
    path_truncated).
  path_nodes: NodeState [I, max_path_length + 1, ...] states along the path (start first).
  path_truncated: [I] bool, the path was longer than max_path_length (its prefix is kept).
  path_is_goal: [I] bool, the path's last state satisfies the goal rule.
  cost: [I] float32 path cost g of the last state (sum of edge costs, the env's cost units).
  expanded: [I] int32 states expanded (dummy edges popped and expanded).
  evaluated: [I] int32 edge evaluations: transitions simulated (env.evaluate calls counted per
    edge; an edge of `edge_steps` H counts H).
  invalid: [I] int32 evaluated edges that were invalid (dropped; edges, not transitions).
  generated: [I] int32 nodes in the pool.
  iterations: [I] int32 loop iterations.
  lane_utilization: [I] float32 evaluated / (K * H * iterations): the share of the instance's K
    evaluation lanes that held an edge while it searched (0 before the first iteration).
  heap_overflow, pool_overflow, table_overflow: [I] int32 entries dropped for lack of space.
  wall_time_s: [] float32 host wall-clock seconds of the planning call without compilation
    (set by `plan`; NaN from `Search.result`).
  """

  found: jax.Array
  stop_reason: jax.Array
  path_actions: jax.Array
  path_length: jax.Array
  path_nodes: base.NodeState
  path_truncated: jax.Array
  path_is_goal: jax.Array
  cost: jax.Array
  expanded: jax.Array
  evaluated: jax.Array
  invalid: jax.Array
  generated: jax.Array
  iterations: jax.Array
  lane_utilization: jax.Array
  heap_overflow: jax.Array
  pool_overflow: jax.Array
  table_overflow: jax.Array
  wall_time_s: jax.Array
