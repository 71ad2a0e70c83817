"""Pieces the baselines share: the sampling planners' state and path replay."""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax import trees
from pachs_jax.envs import base
from pachs_jax.search.result import StopReason


@struct.dataclass
class SamplingState:
  """What the sampling planners (parallel rollout, MPPI) carry per instance, leading axis I:
  start: NodeState [I]; rng: [I, 2] uint32; active, found: [I] bool; stop_reason: [I] int32
  `StopReason`; evaluated, invalid, iterations: [I] int32 counters."""

  start: base.NodeState
  rng: jax.Array
  active: jax.Array
  found: jax.Array
  stop_reason: jax.Array
  evaluated: jax.Array
  invalid: jax.Array
  iterations: jax.Array


def sampling_start(start_nodes: base.NodeState, keys: jax.Array, start_is_goal: jax.Array) -> dict:
  """The SamplingState fields before the first iteration, as keyword arguments."""
  zeros = jnp.zeros(start_is_goal.shape, jnp.int32)
  return dict(start=start_nodes, rng=keys, active=~start_is_goal, found=start_is_goal,
              stop_reason=jnp.where(start_is_goal, StopReason.GOAL,
                                    StopReason.RUNNING).astype(jnp.int32),
              evaluated=zeros, invalid=zeros, iterations=zeros)


def replay(env: base.Env, start: base.NodeState, actions: jax.Array, length: jax.Array,
           edge_fn: Callable | None = None):
  """States along paths, re-evaluated from the start.

  start: NodeState [I]; actions: [I, L, A]; length: [I] int32 (rows >= length are not applied).
  edge_fn(nodes [B], actions [B, A]) -> EdgeOutcome (default env.evaluate).
  Returns (nodes NodeState [I, L + 1, ...] (rows > length repeat the last state), cost [I]
  float32 sum of the applied edges' costs, valid [I] bool every applied edge was valid,
  is_goal [I] bool the last state satisfies the goal rule).
  """
  edge_fn = env.evaluate if edge_fn is None else edge_fn
  num_instances, steps = actions.shape[:2]
  if steps == 0:  # no edge to apply
    return (jax.tree.map(lambda s: s[:, None], start), jnp.zeros((num_instances,), jnp.float32),
            jnp.ones((num_instances,), bool), env.is_goal(start))
  length = jnp.minimum(length, steps)
  # as many sequential edges as the longest path, not L: a path cut by a clock is short
  last_row = jnp.max(length, initial=0)

  def body(carry):
    t, node, cost, valid, rows = carry
    out = edge_fn(node, actions[:, t])
    apply = t < length
    node = trees.where(apply, out.next_node, node)
    cost = cost + jnp.where(apply, out.cost, 0.0)
    valid = valid & (out.is_valid | ~apply)
    rows = jax.tree.map(lambda r, n: r.at[t + 1].set(n), rows, node)
    return t + 1, node, cost, valid, rows

  rows = jax.tree.map(lambda s: jnp.broadcast_to(s, (steps + 1,) + s.shape), start)
  init = (jnp.int32(0), start, jnp.zeros((num_instances,), jnp.float32),
          jnp.ones((num_instances,), bool), rows)
  _, last, cost, valid, rows = jax.lax.while_loop(lambda c: c[0] < last_row, body, init)
  # rows past the longest path repeat each path's last state, as the shorter paths' rows do
  beyond = jnp.arange(steps + 1) > last_row
  rows = jax.tree.map(
      lambda r, n: jnp.where(beyond.reshape((-1,) + (1,) * n.ndim), n[None], r), rows, last)
  nodes = jax.tree.map(lambda r: jnp.swapaxes(r, 0, 1), rows)
  return nodes, cost, valid, env.is_goal(last)

