"""What the PACHS search is configured with, calls, and returns.

`SearchConfig` (static, hashable) sets the search; the actor-critic enters through the
`ActorCritic` protocol; `SearchResult` is what one planning call returns per problem instance;
`StopReason` names why an instance stopped.
"""

from __future__ import annotations

import dataclasses
import numbers
import math
from typing import Optional, Protocol, Tuple

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax.envs import base

HEAP_KINDS = ('flat', 'segmented', 'blocked')
LOOP_MODES = ('split', 'mixed')
REALTIME_ANSWERS = ('best_f', 'min_h')


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


def check_weight(owner: str, weight) -> None:
  """ValueError unless weight is a finite number >= 0."""
  if (isinstance(weight, bool) or not isinstance(weight, (int, float))
      or not math.isfinite(weight) or weight < 0):
    raise ValueError(f'{owner}.weight must be a finite number >= 0, got {weight!r}')


def check_heap_and_table(owner: str, heap_kind: str, table_capacity) -> None:
  """ValueError for an unknown heap kind or a table capacity that is not a power of two."""
  if heap_kind not in HEAP_KINDS:
    raise ValueError(f'{owner}.heap_kind must be one of {HEAP_KINDS}, got {heap_kind!r}')
  if table_capacity is not None and table_capacity & (table_capacity - 1):
    raise ValueError(f'{owner}.table_capacity must be a power of two, got {table_capacity}')


def lattice_resolution_tuple(owner: str, resolution):
  """None, or the resolution as a tuple of positive finite floats (ValueError otherwise)."""
  if resolution is None:
    return None
  res = tuple(resolution)
  if not res or not all(isinstance(r, (int, float)) and math.isfinite(r) and r > 0 for r in res):
    raise ValueError(f'{owner}.lattice_resolution must be a non-empty tuple of positive cell '
                     f'sizes, got {resolution!r}')
  return tuple(float(r) for r in res)


def env_lattice_resolution(env: base.Env, resolution) -> jax.Array:
  """[L] float32 cell sizes: `resolution`, or the env's default when None (ValueError when its
  length differs from the env's)."""
  default = jnp.asarray(env.default_lattice_resolution, jnp.float32)
  if resolution is None:
    return default
  resolution = jnp.asarray(resolution, jnp.float32)
  if resolution.shape != default.shape:
    raise ValueError(f'lattice_resolution has {resolution.shape[0]} entries, but the '
                     f'environment {env.name} uses {default.shape[0]}')
  return resolution


def check_start_nodes(start_nodes: base.NodeState, node_spec: base.NodeState) -> int:
  """The number of instances I of start_nodes [I, ...] (node_spec: one node's shapes);
  ValueError when the shapes do not fit."""
  leaves, spec_leaves = jax.tree.leaves(start_nodes), jax.tree.leaves(node_spec)
  if (jax.tree.structure(start_nodes) != jax.tree.structure(node_spec)
      or any(jnp.ndim(x) != len(s.shape) + 1 or jnp.shape(x)[1:] != s.shape
             for x, s in zip(leaves, spec_leaves))):
    want = jax.tree.map(lambda s: ('I',) + s.shape, node_spec)
    got = jax.tree.map(jnp.shape, start_nodes)
    raise ValueError(f'start_nodes must be the environment\'s NodeState with a leading '
                     f'instance axis: want shapes {want}, got {got}')
  sizes = {jnp.shape(x)[0] for x in leaves}
  if len(sizes) != 1 or 0 in sizes:
    raise ValueError(f'start_nodes leaves must share one leading axis I >= 1, got {sizes}')
  return sizes.pop()


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


def _next_pow2(n: int) -> int:
  return 1 << max(0, int(n - 1).bit_length())


@dataclasses.dataclass(frozen=True)
class SearchConfig:
  """PACHS parameters; capacities left as None are derived from the evaluation budget.

  weight: heuristic weight w >= 0 (f = g + w * q).
  num_actions: N actions sampled per expansion.
  pop_size: K edges popped per instance and loop iteration ('split': up to K dummy edges
    expanded and K real edges evaluated).
  max_evaluations: edge-evaluation budget per instance.
  max_iterations: loop-iteration limit per instance (None: no limit beyond the budget).
  lattice_resolution: [L] lattice cell sizes (None: the environment's default).
  heap_kind: 'flat' (one top_k over the buffer), 'segmented' (flat buffer with per-segment
    minima, two small top_k) or 'blocked' (binary heap of sorted blocks of K entries).
  heap_capacity: entries per instance of the OPEN heap ('mixed') or of the real-edge heap R
    ('split'); None: (N + 1) * (budget + 1) ('mixed') or N * pool ('split'), which never
    overflow. The dummy-edge heap D ('split') holds budget + 1 entries (at most heap_capacity).
  segment_size: entries per segment of the 'segmented' heaps (None: about sqrt(capacity)).
  pool_capacity: nodes per instance; None: budget + 1, which never overflows.
  table_capacity: lattice-table slots per instance, a power of two; None: >= 2 * pool.
  max_path_length: actions kept in a returned path (longer paths keep their first ones).
  loop: 'split' (two OPEN heaps, dummy edges D and real edges R: every iteration expands the
    dummy edges that come before R's K-th best key, then evaluates the K best real edges, so
    the physics batch stays full) or 'mixed' (one heap; the K popped entries are split between
    expansion and evaluation, which leaves evaluation lanes empty). See `pachs`.
  realtime_answer: the path returned when no goal was found: 'best_f' (the original's
    real-time variant: to the state of the best OPEN entry, often the start itself early in a
    search) or 'min_h' (to the generated state, the start excluded, with the smallest
    estimated cost-to-go h = (key of its latest dummy edge - g) / w; needs w > 0).
  compact_fractions: smaller physics batches, as fractions in (0, 1) of the I * K lanes: when
    the popped real edges of the instances still searching fit one, only they are simulated
    (`compact.evaluate_live`), which speeds up the tail of a batched search where most
    instances have stopped; () always simulates all I * K lanes. Each size adds a copy of the
    physics to the compiled program.
  """

  weight: float = 1.0
  num_actions: int = 16
  pop_size: int = 16
  max_evaluations: int = 100_000
  max_iterations: Optional[int] = None
  lattice_resolution: Optional[Tuple[float, ...]] = None
  heap_kind: str = 'segmented'
  heap_capacity: Optional[int] = None
  segment_size: Optional[int] = None
  pool_capacity: Optional[int] = None
  table_capacity: Optional[int] = None
  max_path_length: int = 1024
  loop: str = 'split'
  realtime_answer: str = 'best_f'
  compact_fractions: Tuple[float, ...] = ()

  def __post_init__(self):
    def positive_int(name, allow_none=False):
      v = getattr(self, name)
      if v is None and allow_none:
        return
      if isinstance(v, bool) or not isinstance(v, int) or v < 1:
        raise ValueError(f'SearchConfig.{name} must be a positive int, got {v!r}')

    check_weight('SearchConfig', self.weight)
    for name in ('num_actions', 'pop_size', 'max_evaluations', 'max_path_length'):
      positive_int(name)
    for name in ('max_iterations', 'heap_capacity', 'segment_size', 'pool_capacity',
                 'table_capacity'):
      positive_int(name, allow_none=True)
    if self.loop not in LOOP_MODES:
      raise ValueError(f'SearchConfig.loop must be one of {LOOP_MODES}, got {self.loop!r}')
    if self.realtime_answer not in REALTIME_ANSWERS:
      raise ValueError(f'SearchConfig.realtime_answer must be one of {REALTIME_ANSWERS}, got '
                       f'{self.realtime_answer!r}')
    fractions = (tuple(self.compact_fractions)
                 if isinstance(self.compact_fractions, (tuple, list)) else (None,))
    if not all(isinstance(f, numbers.Real) and not isinstance(f, bool) and 0 < f < 1
               for f in fractions):
      raise ValueError('SearchConfig.compact_fractions must be fractions in (0, 1), got '
                       f'{self.compact_fractions!r}')
    object.__setattr__(self, 'compact_fractions', tuple(float(f) for f in fractions))
    if self.realtime_answer == 'min_h' and not self.weight > 0:
      raise ValueError("SearchConfig.realtime_answer='min_h' reads h from the dummy-edge keys "
                       f'and needs weight > 0, got {self.weight!r}')
    check_heap_and_table('SearchConfig', self.heap_kind, self.table_capacity)
    object.__setattr__(self, 'lattice_resolution',
                       lattice_resolution_tuple('SearchConfig', self.lattice_resolution))
    if self.pool * (self.num_actions + 1) >= 2**31:
      raise ValueError('pool_capacity * (num_actions + 1) must stay below 2**31 (heap entries '
                       f'store node * (N + 1) + slot as int32); got {self.pool} nodes and '
                       f'N = {self.num_actions}')
    if self.heap >= 2**31 or self.table >= 2**31:
      raise ValueError('heap and table capacities must stay below 2**31 '
                       f'(got heap {self.heap}, table {self.table})')

  # ---- derived sizes ----

  @property
  def heap(self) -> int:
    """Capacity of the OPEN heap ('mixed') or the real-edge heap ('split'), entries per
    instance."""
    if self.heap_capacity is not None:
      return self.heap_capacity
    if self.loop == 'split':  # N edges per expansion, each node expanded at most once
      return self.num_actions * self.pool
    return (self.num_actions + 1) * (self.max_evaluations + 1)

  @property
  def dummy_heap(self) -> int:
    """Capacity of the dummy-edge heap of 'split' (entries per instance): the start's dummy
    edge plus at most one per evaluation."""
    if self.heap_capacity is None:
      return self.max_evaluations + 1
    return min(self.heap_capacity, self.max_evaluations + 1)

  @property
  def pool(self) -> int:
    """Node-pool capacity (nodes per instance)."""
    return self.pool_capacity if self.pool_capacity is not None else self.max_evaluations + 1

  @property
  def table(self) -> int:
    """Lattice-table capacity (slots per instance, a power of two)."""
    if self.table_capacity is not None:
      return self.table_capacity
    return _next_pow2(2 * self.pool)

  @property
  def iterations(self) -> int:
    """Loop-iteration limit per instance (the default can never be reached before the budget)."""
    if self.max_iterations is not None:
      return self.max_iterations
    return min(2**31 - 1, (self.num_actions + 1) * (self.max_evaluations + 1) + 1)


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
  evaluated: [I] int32 edges evaluated (env.evaluate calls counted per edge).
  invalid: [I] int32 evaluated edges that were invalid (dropped).
  generated: [I] int32 nodes in the pool.
  iterations: [I] int32 loop iterations.
  lane_utilization: [I] float32 evaluated / (K * iterations): the share of the instance's K
    evaluation lanes that held an edge while it searched (0 before the first iteration).
  heap_overflow, pool_overflow, table_overflow: [I] int32 entries dropped for lack of space
    (heap_overflow: both heaps of 'split').
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
