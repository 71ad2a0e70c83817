"""Pieces the baselines share: input checks, per-instance keys, path replay, timing."""

from __future__ import annotations

import time
from typing import Callable

import jax
import jax.numpy as jnp

from pachs_jax.envs import base
from pachs_jax.search.types import SearchResult


def node_spec(env: base.Env) -> base.NodeState:
  """The shapes of one node of env (no batch axis)."""
  return jax.eval_shape(env.sample_instance, jax.random.PRNGKey(0))


def check_start(start_nodes: base.NodeState, env: base.Env) -> int:
  """The number of instances I of start_nodes [I, ...]; ValueError when shapes do not fit."""
  spec = node_spec(env)
  leaves, spec_leaves = jax.tree.leaves(start_nodes), jax.tree.leaves(spec)
  if (jax.tree.structure(start_nodes) != jax.tree.structure(spec)
      or any(jnp.ndim(x) != len(s.shape) + 1 or jnp.shape(x)[1:] != s.shape
             for x, s in zip(leaves, spec_leaves))):
    want = jax.tree.map(lambda s: ('I',) + s.shape, spec)
    got = jax.tree.map(jnp.shape, start_nodes)
    raise ValueError('start_nodes must be the environment\'s NodeState with a leading instance '
                     f'axis: want shapes {want}, got {got}')
  sizes = {jnp.shape(x)[0] for x in leaves}
  if len(sizes) != 1 or 0 in sizes:
    raise ValueError(f'start_nodes leaves must share one leading axis I >= 1, got {sizes}')
  return sizes.pop()


def instance_keys(key: jax.Array, num_instances: int) -> jax.Array:
  """[I, 2] uint32 per-instance keys: one key [2] (or typed []) is split, [I, 2] kept."""
  key = jnp.asarray(key)
  if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
    key = jax.random.key_data(key)
  if key.shape == (2,):
    key = jax.random.split(key, num_instances)
  if key.shape != (num_instances, 2):
    raise ValueError(f'key must be one PRNG key or [I, 2] keys with I = {num_instances}, '
                     f'got shape {key.shape}')
  return key.astype(jnp.uint32)


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
