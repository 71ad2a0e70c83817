"""The phases of a batched edge search that PACHS and ePA*SE share: start, pop, goal check,
budgeted evaluation, successor insertion and stop."""

from __future__ import annotations

from typing import Any, Callable, NamedTuple, Optional, Tuple

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax.envs import base
from pachs_jax.search import compact
from pachs_jax.search import heap as heap_lib
from pachs_jax.search import lattice as lattice_lib
from pachs_jax.search import pool as pool_lib
from pachs_jax.search import segment
from pachs_jax.search.result import StopReason

NO_NODE = -1  # goal_node of an instance that has found no goal


@struct.dataclass
class EdgeSearchState:
  """What every edge search carries, leading axis I (subclasses add their OPEN lists).

  pool: the nodes; table: lattice cell -> node index.
  active: [I] bool, still searching; stop_reason: [I] int32 `StopReason`.
  goal_node: [I] int32 the popped goal node (NO_NODE if none).
  iterations, expanded, evaluated, invalid: [I] int32 counters.
  """

  pool: pool_lib.NodePool
  table: lattice_lib.LatticeTable
  active: jax.Array
  stop_reason: jax.Array
  goal_node: jax.Array
  iterations: jax.Array
  expanded: jax.Array
  evaluated: jax.Array
  invalid: jax.Array


def start_state(pool: pool_lib.NodePool, table: lattice_lib.LatticeTable,
                live: Optional[jax.Array] = None) -> dict:
  """The EdgeSearchState fields of a search that has not begun, as keyword arguments; live: [I]
  bool instances that search (None: all)."""
  num_instances = pool.size.shape[0]
  zeros = jnp.zeros((num_instances,), jnp.int32)
  active = jnp.ones((num_instances,), bool) if live is None else jnp.asarray(live, bool)
  return dict(pool=pool, table=table, active=active,
              stop_reason=zeros, goal_node=jnp.full((num_instances,), NO_NODE, jnp.int32),
              iterations=zeros, expanded=zeros, evaluated=zeros, invalid=zeros)


class Popped(NamedTuple):
  """The popped entries of I instances, [I, K] each."""

  key: jax.Array  # float32 priority
  node: jax.Array  # int32 source node
  slot: jax.Array  # int32 edge slot of the node, the last one for the dummy edge
  mask: jax.Array  # bool, an entry was popped


def flat(tree, num: int):
  """[I, K, ...] -> [num = I * K, ...] on every leaf."""
  return jax.tree.map(lambda x: x.reshape((num,) + x.shape[2:]), tree)


def unflat(tree, num_instances: int):
  """[I * K, ...] -> [I, K, ...] on every leaf."""
  return jax.tree.map(lambda x: x.reshape((num_instances, -1) + x.shape[1:]), tree)


def weighted(value: jax.Array, weight: float) -> jax.Array:
  """weight * value, with weight 0 giving zeros (uniform cost, and no 0 * inf)."""
  return value * weight if weight else jnp.zeros_like(value)


def count(mask: jax.Array) -> jax.Array:
  """[I] int32 true entries of mask [I, K]."""
  return jnp.sum(mask, axis=1, dtype=jnp.int32)


def start(start_nodes: base.NodeState, start_is_goal: jax.Array, start_cell: jax.Array,
          pool_size: int, table_size: int, num_edges: int, action_size: int,
          edge_steps: int = 1) -> Tuple[pool_lib.NodePool, lattice_lib.LatticeTable]:
  """(pool, table) holding the start nodes [I] (cells start_cell [I, L]) as node 0."""
  num_instances = start_is_goal.shape[0]
  pool = pool_lib.init(start_nodes, start_is_goal, pool_size, num_edges, action_size,
                       edge_steps)
  table = lattice_lib.init(num_instances, table_size, start_cell.shape[-1])
  root = jnp.ones((num_instances, 1), bool)
  table, slot, _, _ = lattice_lib.insert(table, start_cell[:, None], root)
  return pool, lattice_lib.set_values(table, slot, jnp.zeros_like(slot), root)


def push_start(heap: heap_lib.Heap, dummy_slot: int) -> heap_lib.Heap:
  """heap with the start's dummy edge (node 0, key 0) pushed."""
  num_instances = heap.keys.shape[0]
  return heap_lib.push(heap, jnp.zeros((num_instances, 1), jnp.float32),
                       jnp.full((num_instances, 1), dummy_slot, jnp.int32),
                       jnp.ones((num_instances, 1), bool))


def pop(heap: heap_lib.Heap, k: int, slots: int, active: jax.Array,
        limit=None) -> Tuple[heap_lib.Heap, Popped]:
  """The k best entries (value node * slots + slot) of the active instances [I]."""
  heap, key, value, mask = heap_lib.pop(heap, k, active, limit)
  return heap, Popped(key, value // slots, value % slots, mask)


def _first_of_node(node: jax.Array, mask: jax.Array) -> jax.Array:
  """[I, K] bool: mask and no earlier masked entry has the same node."""
  k = node.shape[1]
  earlier = jnp.arange(k)[None, :] < jnp.arange(k)[:, None]
  same = (node[:, :, None] == node[:, None, :]) & mask[:, None, :] & earlier
  return mask & ~jnp.any(same, axis=2)


def goal_check(pool: pool_lib.NodePool, popped: Popped,
               dummy_slot: int) -> Tuple[jax.Array, jax.Array, jax.Array]:
  """(to expand [I, K], found [I], goal node [I]) from the popped entries.

  A dummy edge is fresh when its node is open and the key is the node's latest (lazy
  deletion), and only its first copy in the batch counts; a fresh goal ends the instance.
  """
  fresh = (popped.mask & (popped.slot == dummy_slot)
           & ~pool_lib.gather(pool.closed, popped.node)
           & (popped.key == pool_lib.gather(pool.open_key, popped.node)))
  fresh = _first_of_node(popped.node, fresh)
  at_goal = fresh & pool_lib.gather(pool.is_goal, popped.node)
  goal = jnp.take_along_axis(popped.node, jnp.argmax(at_goal, axis=1)[:, None], axis=1)[:, 0]
  return fresh & ~at_goal, jnp.any(at_goal, axis=1), goal


def evaluate(edge_fn: Callable[[base.NodeState, Any], base.EdgeOutcome],
             sources: base.NodeState, actions: Any, real: jax.Array,
             evaluated: jax.Array, budget: int, batch_size: Optional[int] = None,
             edge_evaluations: int = 1):
  """Evaluates the real edges [I, K] that fit each instance's remaining budget.

  sources: NodeState [I, K]; actions: [I, K, D] (or a pytree of [I, K, ...] edge inputs);
  evaluated: [I] int32 evaluations so far; edge_evaluations: the evaluations one edge costs
  (its transitions). Returns (outcome EdgeOutcome [I, K], within [I, K] evaluated, usable
  [I, K] valid with finite cost, out_of_budget [I] an edge was left unevaluated). batch_size:
  the physics lanes (`compact.evaluate_live`; None: all I * K).
  """
  num_instances, k = real.shape
  within = real & (jnp.cumsum(real, axis=1) * edge_evaluations
                   <= (budget - evaluated)[:, None])
  lanes = num_instances * k
  outcome = compact.evaluate_live(edge_fn, flat(sources, lanes), flat(actions, lanes),
                                  within.reshape(lanes), batch_size)
  outcome = unflat(outcome, num_instances)
  usable = within & outcome.is_valid & jnp.isfinite(outcome.cost)
  return outcome, within, usable, jnp.any(real & ~within, axis=1)


def insert(pool: pool_lib.NodePool, table: lattice_lib.LatticeTable, cells: jax.Array,
           parent: jax.Array, outcome: base.EdgeOutcome, usable: jax.Array, action: jax.Array,
           h: jax.Array, weight: float, unmerged=None):
  """Successors of the edges [I, K] from parent into the lattice and pool.

  cells: [I, K, L] int32 lattice keys of outcome.next_node; h: [I, K] float32 cost-to-go
  estimates of the successors. A new cell, or an open node whose g improves, takes the
  successor (see `pool.merge_successors`; `unmerged` [I, K] lanes always take a new node); a
  `segment.SegmentOutcome` also stores the
  segment's inside. Returns (pool, table, dummy keys g + w h [I, K], nodes [I, K] int32,
  written [I, K] bool).
  """
  g = pool_lib.gather(pool.g, parent) + outcome.cost
  pool, table, node, write = pool_lib.merge_successors(pool, table, cells, g, usable, unmerged)
  dummy_key = g + weighted(h, weight)
  is_segment = isinstance(outcome, segment.SegmentOutcome)
  depth = pool_lib.gather(pool.depth, parent) + (outcome.length if is_segment else 1)
  pool = pool_lib.set_nodes(pool, node, write, outcome.next_node, g, parent, action, depth,
                            outcome.is_goal, dummy_key)
  if is_segment:
    pool = pool_lib.set_segments(pool, node, write, outcome.actions, outcome.nodes)
  return pool, table, dummy_key, node, write


def finish(state, found: jax.Array, goal: jax.Array, open_empty: jax.Array,
           out_of_budget: jax.Array, overflow: jax.Array, iteration_limit: int,
           expanded: jax.Array, within: jax.Array, usable: jax.Array,
           edge_evaluations: int = 1, **fields):
  """state.replace(**fields) with its stop reasons and counters updated after an iteration.

  state has [I] fields active, stop_reason, goal_node, iterations, expanded, evaluated and
  invalid; found, open_empty, out_of_budget: [I] bool; overflow: [I] int32 entries dropped;
  expanded, within, usable: [I, K] bool; edge_evaluations: the evaluations one edge costs (an
  invalid edge counts once in invalid). Stop reasons in precedence: goal, open list empty,
  capacity, budget, iterations.
  """
  iterations = state.iterations + state.active
  reason = jnp.select(
      [found, open_empty, overflow > 0, out_of_budget, iterations >= iteration_limit],
      [StopReason.GOAL, StopReason.OPEN_EMPTY, StopReason.CAPACITY, StopReason.BUDGET,
       StopReason.ITERATIONS], StopReason.RUNNING)
  reason = jnp.where(state.active, reason, state.stop_reason).astype(jnp.int32)
  return state.replace(
      active=state.active & (reason == StopReason.RUNNING), stop_reason=reason,
      goal_node=jnp.where(found & state.active, goal, state.goal_node), iterations=iterations,
      expanded=state.expanded + count(expanded),
      evaluated=state.evaluated + count(within) * edge_evaluations,
      invalid=state.invalid + count(within & ~usable), **fields)
