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

  def step(carry, xs):
    node, cost, valid = carry
    action, t = xs
    out = edge_fn(node, action)
    apply = t < length
    node = trees.where(apply, out.next_node, node)
    cost = cost + jnp.where(apply, out.cost, 0.0)
    valid = valid & (out.is_valid | ~apply)
    return (node, cost, valid), node

  num_instances, steps = actions.shape[:2]
  init = (start, jnp.zeros((num_instances,), jnp.float32), jnp.ones((num_instances,), bool))
  xs = (jnp.swapaxes(actions, 0, 1), jnp.arange(steps, dtype=jnp.int32))
  (last, cost, valid), nodes = jax.lax.scan(step, init, xs)
  nodes = jax.tree.map(lambda s, n: jnp.concatenate([s[:, None], jnp.swapaxes(n, 0, 1)], axis=1),
                       start, nodes)
  return nodes, cost, valid, env.is_goal(last)

