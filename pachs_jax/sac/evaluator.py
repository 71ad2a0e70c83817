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


def make_rollout_fn(env: base.Env, deterministic: bool = True, num_steps: Optional[int] = None
                    ) -> Callable[[SacActorCritic, base.NodeState, jax.Array], RolloutResult]:
  """A jitted fn(actor_critic, nodes [B], key) -> RolloutResult of the (stochastic) policy."""
  horizon = env.episode_length if num_steps is None else int(num_steps)
  if horizon < 1:
    raise ValueError(f'num_steps must be >= 1, got {horizon}')

  def rollout(actor_critic: SacActorCritic, nodes: base.NodeState, key: jax.Array
              ) -> RolloutResult:
    if actor_critic.config.action_size != env.action_size:
      raise ValueError(f'actor-critic action size {actor_critic.config.action_size} != env '
                       f'{env.name!r} action size {env.action_size}')
    success = env.is_goal(nodes)
    batch = success.shape[0]
    zeros_i = jnp.zeros((batch,), jnp.int32)
    init = (nodes, ~success, success, jnp.zeros((batch,), bool), zeros_i,
            jnp.zeros((batch,), jnp.float32))

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

    carry, _ = jax.lax.scan(step, init, jax.random.split(key, horizon))
    node, _, success, invalid, steps, cost = carry
    return RolloutResult(success=success, invalid=invalid, steps=steps, cost=cost,
                         final_node=node)

  return jax.jit(rollout)


def success_rates(env: base.Env, actor_critic: SacActorCritic, nodes: base.NodeState,
                  key: jax.Array) -> Dict[str, float]:
  """{'deterministic': rate, 'stochastic': rate} single-rollout success over nodes [B]."""
  det = make_rollout_fn(env, deterministic=True)(actor_critic, nodes, key)
  sto = make_rollout_fn(env, deterministic=False)(actor_critic, nodes, key)
  return {'deterministic': float(jnp.mean(det.success)),
          'stochastic': float(jnp.mean(sto.success))}
