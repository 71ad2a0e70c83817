"""Backtracking a path through the node pool's parent pointers, and the `SearchResult` of a
pool-based edge search (PACHS, ePA*SE)."""

from __future__ import annotations

from typing import Tuple

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax.envs import base
from pachs_jax.search import pool as pool_lib
from pachs_jax.search.result import SearchResult, StopReason


@struct.dataclass
class Path:
  """Paths from the start to a final node of I instances.

  actions: [I, max_len, A] float32 actions in order; rows >= length are 0.
  nodes: NodeState [I, max_len + 1, ...] states from the start; rows > length are 0.
  length: [I] int32 edges in the whole path.
  truncated: [I] bool, length > max_len (actions and nodes hold the path's first part).
  """

  actions: jax.Array
  nodes: base.NodeState
  length: jax.Array
  truncated: jax.Array


def extract(pool: pool_lib.NodePool, final: jax.Array, max_len: int) -> Path:
  """The path of each instance from the start to node final [I] (int32 pool indices)."""
  num_instances = final.shape[0]
  rows = jnp.arange(num_instances)
  length = pool.depth[rows, final]
  actions = jnp.zeros((num_instances, max_len, pool.action.shape[-1]), jnp.float32)
  nodes = jax.tree.map(lambda x: jnp.zeros((num_instances, max_len + 1) + x.shape[2:], x.dtype),
                       pool.nodes)

  def cond(carry):
    return jnp.any(carry[0] != pool_lib.NO_PARENT)

  def body(carry):
    node, actions, nodes = carry
    live = node != pool_lib.NO_PARENT
    at = jnp.maximum(node, 0)
    depth = pool.depth[rows, at]
    state_pos = jnp.where(live & (depth <= max_len), depth, max_len + 1)
    nodes = jax.tree.map(lambda out, x: out.at[rows, state_pos].set(x[rows, at], mode='drop'),
                         nodes, pool.nodes)
    parent = pool.parent[rows, at]
    first = jnp.where(parent >= 0, pool.depth[rows, jnp.maximum(parent, 0)], depth)
    action_pos = jnp.where(live & (depth >= 1) & (first < max_len), first, max_len)
    actions = actions.at[rows, action_pos].set(pool.action[rows, at], mode='drop')
    # a segment edge (`segment`): its inner actions and states at rows first + 1 .. depth - 1
    inner = jnp.arange(pool.segment_actions.shape[2])[None, :]
    pos = first[:, None] + 1 + inner
    inside = live[:, None] & (pos < depth[:, None])
    actions = actions.at[rows[:, None], jnp.where(inside, pos, max_len)].set(
        pool.segment_actions[rows, at], mode='drop')
    nodes = jax.tree.map(
        lambda out, x: out.at[rows[:, None], jnp.where(inside, pos, max_len + 1)].set(
            x[rows, at], mode='drop'), nodes, pool.segment_nodes)
    node = jnp.where(live, parent, pool_lib.NO_PARENT)
    return node, actions, nodes

  _, actions, nodes = jax.lax.while_loop(cond, body, (final.astype(jnp.int32), actions, nodes))
  return Path(actions=actions, nodes=nodes, length=length, truncated=length > max_len)


def _least_node(pool: pool_lib.NodePool, score: jax.Array, slots: int
                ) -> Tuple[jax.Array, jax.Array]:
  """(value [I], has [I]): the generated node, the start excluded, of least score [I, P] (ties
  go to the smaller g), as an entry value node * slots; has is False while the start is the
  only node."""
  index = jnp.arange(pool.capacity)[None, :]
  usable = (index < pool.size[:, None]) & (index != pool_lib.ROOT_INDEX)
  score = jnp.where(usable, score, jnp.inf)
  best = usable & (score == jnp.min(score, axis=1, keepdims=True))
  node = jnp.argmin(jnp.where(best, pool.g, jnp.inf), axis=1).astype(jnp.int32)
  return node * slots, jnp.any(usable, axis=1)


def min_h_answer(pool: pool_lib.NodePool, slots: int) -> Tuple[jax.Array, jax.Array]:
  """`_least_node` of the estimated cost-to-go (key of the node's latest dummy edge - g =
  w * h; ties, e.g. h clipped at 0, go to the smaller g)."""
  return _least_node(pool, pool.open_key - pool.g, slots)


def min_cost_answer(pool: pool_lib.NodePool, slots: int) -> Tuple[jax.Array, jax.Array]:
  """`_least_node` of the incoming edge's cost per transition ((g - parent's g) / transitions,
  the env's cost units). With one-step edges this is the cost of the last transition, the
  parallel rollout's rule (`ParallelRolloutConfig.fallback='last_cost'`)."""
  parent = jnp.maximum(pool.parent, 0)
  steps = jnp.maximum(pool.depth - pool_lib.gather(pool.depth, parent), 1)
  return _least_node(pool, (pool.g - pool_lib.gather(pool.g, parent)) / steps, slots)


def search_result(state, best_value: jax.Array, in_open: jax.Array, slots: int, pop_size: int,
                  heap_overflow: jax.Array, max_len: int, incumbent=None) -> SearchResult:
  """The SearchResult [I] of an edge search whose state has pool, table, stop_reason,
  goal_node, expanded, evaluated, invalid and iterations ([I] each).

  The path ends at the goal node when one was found, else at the real-time answer: the node of
  an entry value (best_value [I], node * slots + slot, where in_open [I]; the best OPEN entry's,
  `min_h_answer`'s or `min_cost_answer`'s),
  or with OPEN empty the node whose dummy edge had the smallest key. lane_utilization counts
  pop_size evaluations per iteration (K edges times their transitions). incumbent: the
  search's `improve.Incumbent` (None: the first goal ends a search): an instance stopped by
  another rule (a time limit) answers with its incumbent goal.
  """
  pool = state.pool
  found = state.stop_reason == StopReason.GOAL
  goal_node = state.goal_node
  first = {}
  if incumbent is not None:
    found, goal_node = found | incumbent.found, jnp.where(found, goal_node, incumbent.node)
    first = dict(first_goal_evaluated=incumbent.first_evaluated,
                 first_goal_iterations=incumbent.first_iterations,
                 first_goal_cost=incumbent.first_cost)
  exists = jnp.arange(pool.capacity)[None, :] < pool.size[:, None]
  best = jnp.where(in_open, best_value // slots,
                   jnp.argmin(jnp.where(exists, pool.open_key, jnp.inf), axis=1))
  final = jnp.where(found, goal_node, best).astype(jnp.int32)
  path = extract(pool, final, max_len)
  rows = jnp.arange(final.shape[0])
  lanes = pop_size * state.iterations
  return SearchResult(
      found=found, stop_reason=state.stop_reason, path_actions=path.actions,
      path_length=path.length, path_nodes=path.nodes, path_truncated=path.truncated,
      path_is_goal=pool.is_goal[rows, final], cost=pool.g[rows, final],
      expanded=state.expanded, evaluated=state.evaluated, invalid=state.invalid,
      generated=pool.size, iterations=state.iterations,
      lane_utilization=jnp.where(lanes > 0, state.evaluated / jnp.maximum(lanes, 1),
                                 0.0).astype(jnp.float32),
      heap_overflow=heap_overflow, pool_overflow=pool.overflow,
      table_overflow=state.table.overflow, wall_time_s=jnp.float32(jnp.nan), **first)
