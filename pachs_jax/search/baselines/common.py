"""Pieces the baselines share: input checks, per-instance keys, path replay, timing."""

from __future__ import annotations

import time
from typing import Callable

import jax
import jax.numpy as jnp

from pachs_jax.envs import base
from pachs_jax.search import types
from pachs_jax.search.types import SearchResult


def node_spec(env: base.Env) -> base.NodeState:
  """The shapes of one node of env (no batch axis)."""
  return jax.eval_shape(env.sample_instance, jax.random.PRNGKey(0))


def check_start(start_nodes: base.NodeState, env: base.Env) -> int:
  """The number of instances I of start_nodes [I, ...]; ValueError when shapes do not fit."""
  return types.check_start_nodes(start_nodes, node_spec(env))


# [I, 2] uint32 per-instance keys from one key or per-instance keys (see `types`).
instance_keys = types.instance_keys


def check_actor_critic(actor_critic, names) -> None:
  for name in names:
    if not callable(getattr(actor_critic, name, None)):
      raise ValueError(f'actor_critic has no method {name}(...) (see search.types.ActorCritic)')


def positive_int(owner: str, name: str, value, allow_none: bool = False) -> None:
  if value is None and allow_none:
    return
  if isinstance(value, bool) or not isinstance(value, int) or value < 1:
    raise ValueError(f'{owner}.{name} must be a positive int, got {value!r}')


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
    node = jax.tree.map(lambda new, old: jnp.where(
        apply.reshape((-1,) + (1,) * (new.ndim - 1)), new, old), out.next_node, node)
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


def timed(fn: Callable[..., SearchResult], *args) -> SearchResult:
  """Runs a jitted planner fn(*args) after compiling it; sets wall_time_s (host seconds without
  compilation)."""
  compiled = fn.lower(*args).compile()
  start = time.perf_counter()
  out = jax.block_until_ready(compiled(*args))
  return out.replace(wall_time_s=jnp.float32(time.perf_counter() - start))


def zeros_i(num_instances: int) -> jax.Array:
  return jnp.zeros((num_instances,), jnp.int32)
