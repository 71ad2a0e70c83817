"""Single-rollout evaluation of a trained policy from a batch of start nodes."""

from __future__ import annotations

from typing import Callable, Dict, Optional

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax import trees
from pachs_jax.envs import base
from pachs_jax.sac.actor_critic import SacActorCritic


@struct.dataclass
class RolloutResult:
  """Outcome of one rollout per start node, leading axis B.

  success: [B] bool the rollout reached the goal (a start node that is a goal counts).
  invalid: [B] bool the rollout ended on an invalid edge.
  steps: [B] int32 edges evaluated until success, invalid edge (counted) or the step limit.
  cost: [B] float32 summed cost of the valid edges taken.
  final_node: NodeState [B] the last state reached (the goal state on success; the state
    before the invalid edge when one ended the rollout).
  """

  success: jax.Array
  invalid: jax.Array
  steps: jax.Array
  cost: jax.Array
  final_node: base.NodeState


def make_rollout_fn(env: base.Env, deterministic: bool = True, num_steps: Optional[int] = None,
                    chunk_steps: Optional[int] = None
                    ) -> Callable[..., Optional[RolloutResult]]:
  """fn(actor_critic, nodes [B], key, stop=None) -> RolloutResult of the (stochastic) policy.

  The rollout runs in jitted chunks of chunk_steps steps (None: all in one call), which leave
  its result unchanged; stop (fn() -> bool) is checked after each chunk, and once it returns
  True the rollout ends early and fn returns None.
  """
  horizon = env.episode_length if num_steps is None else int(num_steps)
  if horizon < 1:
    raise ValueError(f'num_steps must be >= 1, got {horizon}')
  chunk = horizon if chunk_steps is None else max(1, min(int(chunk_steps), horizon))

  def start(actor_critic: SacActorCritic, nodes: base.NodeState):
    if actor_critic.config.action_size != env.action_size:
      raise ValueError(f'actor-critic action size {actor_critic.config.action_size} != env '
                       f'{env.name!r} action size {env.action_size}')
    success = env.is_goal(nodes)
    batch = success.shape[0]
    zeros_i = jnp.zeros((batch,), jnp.int32)
    return (nodes, ~success, success, jnp.zeros((batch,), bool), zeros_i,
            jnp.zeros((batch,), jnp.float32))

  def advance(actor_critic: SacActorCritic, carry, step_keys: jax.Array):
    """carry after one step per key of step_keys [S, 2]."""
    def step(carry, step_key):
      node, active, success, invalid, steps, cost = carry
      obs = env.observe(node)
      if deterministic:
        action = actor_critic.deterministic_action(obs)
      else:
        action = actor_critic.sample_actions(step_key, obs, 1)[:, 0]
      out = env.evaluate(node, action)
      take = active & out.is_valid
      node = trees.where(take, out.next_node, node)
      cost = cost + jnp.where(take, out.cost, 0.0)
      steps = steps + active.astype(jnp.int32)
      success = success | (active & out.is_goal)
      invalid = invalid | (active & ~out.is_valid)
      active = active & out.is_valid & ~out.is_goal
      return (node, active, success, invalid, steps, cost), None

    return jax.lax.scan(step, carry, step_keys)[0]

  start_jit, advance_jit = jax.jit(start), jax.jit(advance)

  def rollout(actor_critic: SacActorCritic, nodes: base.NodeState, key: jax.Array,
              stop: Optional[Callable[[], bool]] = None) -> Optional[RolloutResult]:
    carry = start_jit(actor_critic, nodes)
    keys = jax.random.split(key, horizon)
    for first in range(0, horizon, chunk):
      carry = advance_jit(actor_critic, carry, keys[first:first + chunk])
      if stop is not None and first + chunk < horizon:
        jax.block_until_ready(carry)
        if stop():
          return None
    node, _, success, invalid, steps, cost = carry
    return RolloutResult(success=success, invalid=invalid, steps=steps, cost=cost,
                         final_node=node)

  return rollout


def success_rates(env: base.Env, actor_critic: SacActorCritic, nodes: base.NodeState,
                  key: jax.Array) -> Dict[str, float]:
  """{'deterministic': rate, 'stochastic': rate} single-rollout success over nodes [B]."""
  det = make_rollout_fn(env, deterministic=True)(actor_critic, nodes, key)
  sto = make_rollout_fn(env, deterministic=False)(actor_critic, nodes, key)
  return {'deterministic': float(jnp.mean(det.success)),
          'stochastic': float(jnp.mean(sto.success))}
