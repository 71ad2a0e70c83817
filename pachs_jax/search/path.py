"""Backtracking a path through the node pool's parent pointers."""

from __future__ import annotations


import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax.envs import base
from pachs_jax.search import pool as pool_lib


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
    action_pos = jnp.where(live & (depth >= 1) & (depth <= max_len), depth - 1, max_len)
    actions = actions.at[rows, action_pos].set(pool.action[rows, at], mode='drop')
    node = jnp.where(live, pool.parent[rows, at], pool_lib.NO_PARENT)
    return node, actions, nodes

  _, actions, nodes = jax.lax.while_loop(cond, body, (final.astype(jnp.int32), actions, nodes))
  return Path(actions=actions, nodes=nodes, length=length, truncated=length > max_len)
