"""ePA*SE (edge-based parallel A* for slow evaluations) with motion primitives, batched over I
problem instances: the search baseline of the Panda-Shelf experiment.

OPEN holds edges, as in PACHS, but the actions are a fixed set of P motion primitives (no
actor) and the priorities carry no action information (no critic): expanding a state s (popping
its dummy edge) pushes its P real edges (s, p) all with s's own key g(s) + w h(s), ties in
primitive order; evaluating (s, p) (one batch of up to K edges per instance and iteration, the
parallel edge evaluation of ePA*SE) gives s' and c, and a new or improved s' gets the dummy edge
g(s') + w h(s'). Duplicates, lazy deletion and closed nodes work as in `pachs` (no re-expansion
of closed nodes); one OPEN heap ('mixed' loop): the K popped entries are split between
expansion and evaluation.

The task enters through three things:
- motion_primitives [P, D]: the primitives, passed to `edge_fn`;
- edge_fn(nodes [B], primitives [B, D]) -> EdgeOutcome (default `env.evaluate`, primitives
  then being actions in [-1, 1]); for the shelf `shelf_setup` uses `ShelfEnv.move` with joint
  displacements in radians;
- a `Heuristic`: init(start_nodes [I]) -> per-instance data (a pytree, leading axis I, computed
  once per call, e.g. a BFS distance grid from the goal) and value(data, nodes [I, K]) -> [I, K]
  float32 h >= 0 in cost units.
path_actions hold the primitives of the path (for the shelf: joint displacements in rad).
Stop reasons: GOAL, OPEN_EMPTY, CAPACITY, BUDGET, ITERATIONS (in that precedence).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pachs_jax.envs import base
from pachs_jax.search import heap as heap_lib
from pachs_jax.search import lattice as lattice_lib
from pachs_jax.search import path as path_lib
from pachs_jax.search import pool as pool_lib
from pachs_jax.search.baselines import common
from pachs_jax.search import types
from pachs_jax.search.types import SearchResult, StopReason

NO_NODE = -1


@dataclasses.dataclass(frozen=True)
class Heuristic:
  """init(start_nodes [I]) -> data (pytree, leading axis I); value(data, nodes [I, K]) ->
  [I, K] float32 cost-to-go estimates."""

  init: Callable[[base.NodeState], Any]
  value: Callable[[Any, base.NodeState], jax.Array]


@dataclasses.dataclass(frozen=True)
class EpaseConfig:
  """weight: w (key g + w h); pop_size: K entries popped per iteration; max_evaluations: edge
  budget per instance; max_iterations: None = no limit beyond the budget;
  lattice_resolution: cell sizes of env.lattice_key (None: env's default); heap_kind and the
  capacities as in `SearchConfig` (None: heap (P + 1)(budget + 1), pool budget + 1, table the
  next power of two >= 2 pool, none of which can overflow); max_path_length: actions kept."""

  weight: float = 1.0
  pop_size: int = 16
  max_evaluations: int = 100_000
  max_iterations: Optional[int] = None
  lattice_resolution: Optional[Tuple[float, ...]] = None
  heap_kind: str = 'segmented'
  heap_capacity: Optional[int] = None
  pool_capacity: Optional[int] = None
  table_capacity: Optional[int] = None
  max_path_length: int = 1024

  def __post_init__(self):
    types.check_weight('EpaseConfig', self.weight)
    for name in ('pop_size', 'max_evaluations', 'max_path_length'):
      common.positive_int('EpaseConfig', name, getattr(self, name))
    for name in ('max_iterations', 'heap_capacity', 'pool_capacity', 'table_capacity'):
      common.positive_int('EpaseConfig', name, getattr(self, name), allow_none=True)
    types.check_heap_and_table('EpaseConfig', self.heap_kind, self.table_capacity)
    object.__setattr__(self, 'lattice_resolution',
                       types.lattice_resolution_tuple('EpaseConfig', self.lattice_resolution))

  def pool(self) -> int:
    return self.pool_capacity or self.max_evaluations + 1

  def heap(self, num_primitives: int) -> int:
    return self.heap_capacity or (num_primitives + 1) * (self.max_evaluations + 1)

  def table(self) -> int:
    return self.table_capacity or 1 << max(0, int(2 * self.pool() - 1).bit_length())

  def iterations(self, num_primitives: int) -> int:
    if self.max_iterations is not None:
      return self.max_iterations
    return min(2**31 - 1, (num_primitives + 1) * (self.max_evaluations + 1) + 1)


@struct.dataclass
class EpaseState:
  """heap: OPEN; pool: nodes; table: lattice cell -> node; heuristic: the Heuristic's data;
  active [I]; stop_reason [I]; goal_node [I]; iterations, expanded, evaluated, invalid [I]."""

  heap: heap_lib.Heap
  pool: pool_lib.NodePool
  table: lattice_lib.LatticeTable
  heuristic: Any
  active: jax.Array
  stop_reason: jax.Array
  goal_node: jax.Array
  iterations: jax.Array
  expanded: jax.Array
  evaluated: jax.Array
  invalid: jax.Array


@dataclasses.dataclass(frozen=True)
class Epase:
  """Jitted functions: init(start_nodes [I]) -> EpaseState; run(state) -> state when every
  instance stopped; result(state) -> SearchResult (without a goal: the path to the best OPEN
  entry's state); plan(start_nodes) = result(run(init(start_nodes)))."""

  init: Callable[[base.NodeState], EpaseState]
  run: Callable[[EpaseState], EpaseState]
  result: Callable[[EpaseState], SearchResult]
  plan: Callable[[base.NodeState], SearchResult]
  config: EpaseConfig


def _first_of_node(node, mask):
  k = node.shape[1]
  earlier = jnp.arange(k)[None, :] < jnp.arange(k)[:, None]
  same = (node[:, :, None] == node[:, None, :]) & mask[:, None, :] & earlier
  return mask & ~jnp.any(same, axis=2)


def make_epase(env: base.Env, motion_primitives, heuristic: Heuristic,
               config: EpaseConfig = EpaseConfig(), edge_fn: Optional[Callable] = None) -> Epase:
  """Builds the jitted ePA*SE for env, primitives [P, D], heuristic and config."""
  if not isinstance(config, EpaseConfig):
    raise ValueError(f'config must be an EpaseConfig, got {type(config).__name__}')
  if not isinstance(heuristic, Heuristic):
    raise ValueError(f'heuristic must be a Heuristic, got {type(heuristic).__name__}')
  prims = np.asarray(motion_primitives, np.float32)
  if prims.ndim != 2 or prims.shape[0] < 1 or not np.all(np.isfinite(prims)):
    raise ValueError(f'motion_primitives must be a finite [P, D] array with P >= 1, got shape '
                     f'{prims.shape}')
  num_prims, dim = prims.shape
  if edge_fn is None:
    if dim != env.action_size:
      raise ValueError(f'motion_primitives have {dim} columns, but env.evaluate takes actions '
                       f'of {env.action_size}; pass an edge_fn for other primitives')
    edge_fn = env.evaluate
  primitives = jnp.asarray(prims)
  resolution = types.env_lattice_resolution(env, config.lattice_resolution)
  spec = common.node_spec(env)
  key_size = int(jax.eval_shape(env.lattice_coords, spec, resolution).shape[0])
  if config.pool() * (num_prims + 1) >= 2**31:
    raise ValueError('pool_capacity * (P + 1) must stay below 2**31')
  w, k, dummy = float(config.weight), config.pop_size, num_prims
  weighted = (lambda h: h * w) if w else jnp.zeros_like
  count = lambda mask: jnp.sum(mask, axis=1, dtype=jnp.int32)
  max_iterations = config.iterations(num_prims)

  def flat(tree, num):
    return jax.tree.map(lambda x: x.reshape((num,) + x.shape[2:]), tree)

  def unflat(tree, num):
    return jax.tree.map(lambda x: x.reshape((num, -1) + x.shape[1:]), tree)

  def h_value(data, nodes):
    h = heuristic.value(data, nodes).astype(jnp.float32)
    return jnp.where(jnp.isnan(h), jnp.inf, jnp.maximum(h, 0.0))

  def init(start_nodes: base.NodeState) -> EpaseState:
    num = common.check_start(start_nodes, env)
    data = heuristic.init(start_nodes)
    start_goal = env.is_goal(start_nodes)
    pool = pool_lib.init(start_nodes, start_goal, config.pool(), 1, dim)
    table = lattice_lib.init(num, config.table(), key_size)
    root = jnp.ones((num, 1), bool)
    cell = env.lattice_key(start_nodes, resolution)[:, None]
    table, slot, _, _ = lattice_lib.insert(table, cell, root)
    table = lattice_lib.set_values(table, slot, jnp.zeros_like(slot), root)
    heap = heap_lib.init(config.heap_kind, num, config.heap(num_prims), k)
    # the start's dummy edge with key 0 (the pool's open_key of the root), whatever h is
    heap = heap_lib.push(heap, jnp.zeros((num, 1), jnp.float32),
                         jnp.full((num, 1), dummy, jnp.int32), root)
    zeros = common.zeros_i(num)
    return EpaseState(heap=heap, pool=pool, table=table, heuristic=data,
                      active=jnp.ones((num,), bool), stop_reason=zeros,
                      goal_node=jnp.full((num,), NO_NODE, jnp.int32), iterations=zeros,
                      expanded=zeros, evaluated=zeros, invalid=zeros)

  def step(state: EpaseState) -> EpaseState:
    pool, table = state.pool, state.table
    num = state.active.shape[0]
    heap, key, value, mask = heap_lib.pop(state.heap, k, state.active)
    node, slot = value // (num_prims + 1), value % (num_prims + 1)
    open_empty = state.active & ~jnp.any(mask, axis=1)
    # goal check on the fresh dummy edges
    fresh = (mask & (slot == dummy) & ~pool_lib.gather(pool.closed, node)
             & (key == pool_lib.gather(pool.open_key, node)))
    fresh = _first_of_node(node, fresh)
    at_goal = fresh & pool_lib.gather(pool.is_goal, node)
    found = jnp.any(at_goal, axis=1)
    goal = jnp.take_along_axis(node, jnp.argmax(at_goal, axis=1)[:, None], axis=1)[:, 0]
    working = (state.active & ~found)[:, None]
    # expand: the P primitives of each fresh state, all with the state's own key
    expanding = fresh & ~at_goal & working
    pool = pool_lib.close(pool, node, expanding, jnp.zeros((num, k, 1, dim), jnp.float32),
                          jnp.zeros((num, k, 1), jnp.float32))
    edge_keys = jnp.broadcast_to(key[:, :, None], (num, k, num_prims)).reshape(num, -1)
    edge_values = (node[:, :, None] * (num_prims + 1) + jnp.arange(num_prims)).reshape(num, -1)
    edge_mask = jnp.broadcast_to(expanding[:, :, None], (num, k, num_prims)).reshape(num, -1)
    # evaluate the popped real edges within the budget (one batch of I * K)
    real = mask & (slot != dummy) & working
    left = config.max_evaluations - state.evaluated
    evaluated = real & (jnp.cumsum(real, axis=1) <= left[:, None])
    out_of_budget = jnp.any(real & ~evaluated, axis=1)
    prim = primitives[jnp.minimum(slot, num_prims - 1)]  # [I, K, D]
    sources = pool_lib.gather_nodes(pool, node)
    outcome = unflat(edge_fn(flat(sources, num * k), prim.reshape(num * k, dim)), num)
    usable = evaluated & outcome.is_valid & jnp.isfinite(outcome.cost)
    # insert the successors
    g = pool_lib.gather(pool.g, node) + outcome.cost
    cell = env.lattice_key(flat(outcome.next_node, num * k), resolution).reshape(num, k, -1)
    pool, table, target, write = pool_lib.merge_successors(pool, table, cell, g, usable)
    h = h_value(state.heuristic, outcome.next_node)
    dummy_key = g + weighted(h)
    pool = pool_lib.set_nodes(pool, target, write, outcome.next_node, g, node, prim,
                              pool_lib.gather(pool.depth, node) + 1, outcome.is_goal, dummy_key)
    heap = heap_lib.push(
        heap, jnp.concatenate([edge_keys, dummy_key], axis=1),
        jnp.concatenate([edge_values, target * (num_prims + 1) + dummy], axis=1),
        jnp.concatenate([edge_mask, write], axis=1))
    # stop
    iterations = state.iterations + state.active
    overflow = heap_lib.overflow(heap) + pool.overflow + table.overflow
    reason = jnp.select(
        [found, open_empty, overflow > 0, out_of_budget, iterations >= max_iterations],
        [StopReason.GOAL, StopReason.OPEN_EMPTY, StopReason.CAPACITY, StopReason.BUDGET,
         StopReason.ITERATIONS], StopReason.RUNNING)
    reason = jnp.where(state.active, reason, state.stop_reason).astype(jnp.int32)
    return state.replace(
        heap=heap, pool=pool, table=table, active=state.active & (reason == StopReason.RUNNING),
        stop_reason=reason, goal_node=jnp.where(found & state.active, goal, state.goal_node),
        iterations=iterations, expanded=state.expanded + count(expanding),
        evaluated=state.evaluated + count(evaluated),
        invalid=state.invalid + count(evaluated & ~usable))

  def run(state: EpaseState) -> EpaseState:
    return jax.lax.while_loop(lambda s: jnp.any(s.active), step, state)

  def result(state: EpaseState) -> SearchResult:
    _, value, in_open = heap_lib.peek(state.heap)
    return path_lib.search_result(state, value, in_open, num_prims + 1, k,
                                  heap_lib.overflow(state.heap), config.max_path_length)

  def plan(start_nodes: base.NodeState) -> SearchResult:
    return result(run(init(start_nodes)))

  return Epase(init=jax.jit(init), run=jax.jit(run), result=jax.jit(result),
               plan=jax.jit(plan), config=config)
