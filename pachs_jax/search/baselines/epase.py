"""ePA*SE (edge-based parallel A* for slow evaluations) with motion primitives, batched over I
problem instances: the search baseline of the Panda-Shelf experiment."""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pachs_jax.envs import base
from pachs_jax.search import capacity as capacity_lib
from pachs_jax.search import heap as heap_lib
from pachs_jax.search import path as path_lib
from pachs_jax.search import phases
from pachs_jax.search import pool as pool_lib
from pachs_jax.search.checks import check_start_nodes, env_lattice_resolution
from pachs_jax.search.config import EdgeSearchConfig
from pachs_jax.search.result import SearchResult


@dataclasses.dataclass(frozen=True)
class Heuristic:
  """init(start_nodes [I]) -> data (pytree, leading axis I, e.g. a BFS distance grid from the
  goal); value(data, nodes [I, K]) -> [I, K] float32 cost-to-go estimates h >= 0."""

  init: Callable[[base.NodeState], Any]
  value: Callable[[Any, base.NodeState], jax.Array]


@dataclasses.dataclass(frozen=True)
class EpaseConfig(EdgeSearchConfig):
  """ePA*SE parameters, those of `EdgeSearchConfig` (its one heap holds (P + 1)(budget + 1)
  entries for P motion primitives unless `capacity.Capacities` says fewer)."""


@struct.dataclass
class EpaseState(phases.EdgeSearchState):
  """The fields of `phases.EdgeSearchState`, heap: OPEN, heuristic: the Heuristic's data."""

  heap: heap_lib.Heap
  heuristic: Any


@dataclasses.dataclass(frozen=True)
class Epase:
  """Jitted functions: init(start_nodes [I]) -> EpaseState; run(state) -> state when every
  instance stopped; result(state) -> SearchResult (without a goal: the path to the best OPEN
  entry's state); plan(start_nodes) = result(run(init(start_nodes))); capacities and sizes:
  as in `pachs.Search`."""

  init: Callable[[base.NodeState], EpaseState]
  run: Callable[[EpaseState], EpaseState]
  result: Callable[[EpaseState], SearchResult]
  plan: Callable[[base.NodeState], SearchResult]
  config: EpaseConfig
  capacities: capacity_lib.Capacities
  sizes: capacity_lib.Sizes


def make_epase(env: base.Env, motion_primitives, heuristic: Heuristic,
               config: EpaseConfig = EpaseConfig(), edge_fn: Optional[Callable] = None,
               capacities: Optional[capacity_lib.Capacities] = None) -> Epase:
  """Builds the jitted ePA*SE for env, motion primitives [P, D], heuristic and config.

  One OPEN heap: expanding a state pushes its P real edges with the state's own key
  g + w h; the real edges among the K popped entries are evaluated in one batch by
  edge_fn(nodes [B], primitives [B, D]) -> EdgeOutcome (default env.evaluate, primitives being
  actions). path_actions of the result hold the primitives of the path. capacities: the
  arrays' sizes (None: derived from the budget).
  """
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
  resolution = env_lattice_resolution(env, config.lattice_resolution)
  capacities = capacity_lib.Capacities() if capacities is None else capacities
  sizes = capacity_lib.sizes(capacities, config.budget, num_prims + 1)
  w, k, slots, dummy = float(config.weight), config.pop_size, num_prims + 1, num_prims

  def init(start_nodes: base.NodeState) -> EpaseState:
    num = check_start_nodes(start_nodes, env)
    pool, table = phases.start(start_nodes, env.is_goal(start_nodes),
                               env.lattice_key(start_nodes, resolution), sizes.pool,
                               sizes.table, 1, dim)
    heap = heap_lib.init(num, sizes.heap, k)
    return EpaseState(heap=phases.push_start(heap, dummy), heuristic=heuristic.init(start_nodes),
                      **phases.start_state(pool, table))

  def step(state: EpaseState) -> EpaseState:
    num = state.active.shape[0]
    heap, popped = phases.pop(state.heap, k, slots, state.active)
    fresh, found, goal = phases.goal_check(state.pool, popped, dummy)
    working = (state.active & ~found)[:, None]
    # expand: the P primitives of each fresh state, all with the state's own key
    expanding = fresh & working
    pool = pool_lib.close(state.pool, popped.node, expanding,
                          jnp.zeros((num, k, 1, dim), jnp.float32),
                          jnp.zeros((num, k, 1), jnp.float32))
    edge_keys = jnp.repeat(popped.key, num_prims, axis=1)
    edge_values = (popped.node[:, :, None] * slots + jnp.arange(num_prims)).reshape(num, -1)
    # evaluate the popped real edges within the budget (one batch of I * K)
    prim = primitives[jnp.minimum(popped.slot, num_prims - 1)]  # [I, K, D]
    outcome, within, usable, out_of_budget = phases.evaluate(
        edge_fn, pool_lib.gather_nodes(pool, popped.node), prim,
        popped.mask & (popped.slot != dummy) & working, state.evaluated,
        config.budget)
    # insert the successors
    cells = phases.unflat(env.lattice_key(phases.flat(outcome.next_node, num * k), resolution),
                          num)
    h = heuristic.value(state.heuristic, outcome.next_node).astype(jnp.float32)
    h = jnp.where(jnp.isnan(h), jnp.inf, jnp.maximum(h, 0.0))
    pool, table, dummy_key, node, write = phases.insert(
        pool, state.table, cells, popped.node, outcome, usable, prim, h, w)
    heap = heap_lib.push(heap, jnp.concatenate([edge_keys, dummy_key], axis=1),
                         jnp.concatenate([edge_values, node * slots + dummy], axis=1),
                         jnp.concatenate([jnp.repeat(expanding, num_prims, axis=1), write],
                                         axis=1))
    open_empty = state.active & ~jnp.any(popped.mask, axis=1)
    return phases.finish(state, found, goal, open_empty, out_of_budget,
                         heap.overflow + pool.overflow + table.overflow,
                         sizes.iterations, expanding, within, usable,
                         heap=heap, pool=pool, table=table)

  def run(state: EpaseState) -> EpaseState:
    return jax.lax.while_loop(lambda s: jnp.any(s.active), step, state)

  def result(state: EpaseState) -> SearchResult:
    _, value, in_open = heap_lib.peek(state.heap)
    return path_lib.search_result(state, value, in_open, slots, k, state.heap.overflow,
                                  sizes.path)

  def plan(start_nodes: base.NodeState) -> SearchResult:
    return result(run(init(start_nodes)))

  return Epase(init=jax.jit(init), run=jax.jit(run), result=jax.jit(result),
               plan=jax.jit(plan), config=config,
               capacities=capacities, sizes=sizes)
