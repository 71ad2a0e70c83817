"""The trained model as the search sees it: the actor-critic protocol, the cost-to-go of its
critic, its actions made safe to simulate, the check of its outputs on the start states, and
the actor mixed with uniform actions."""

from __future__ import annotations

import dataclasses
from typing import Protocol

import jax
import jax.numpy as jnp


class ActorCritic(Protocol):
  """The trained model as the search sees it; both functions are pure and jittable.

  `sample_actions(key, obs[B, O], num) -> [B, num, A]` actions in [-1, 1] (the actor's
  proposals for the outgoing edges of B states).
  `q_values(obs[B, O], actions[B, num, A]) -> [B, num]` float32 critic Q, a reward sum in the
  environment's reward units; the search uses the cost-to-go q = max(-Q, 0).
  """

  def sample_actions(self, key: jax.Array, obs: jax.Array, num: int) -> jax.Array:
    ...

  def q_values(self, obs: jax.Array, actions: jax.Array) -> jax.Array:
    ...


def cost_to_go(q_value: jax.Array) -> jax.Array:
  """The critic's cost-to-go q = max(-Q, 0), with NaN as +inf (such an edge is never chosen)."""
  q = jnp.maximum(-q_value.astype(jnp.float32), 0.0)
  return jnp.where(jnp.isnan(q), jnp.inf, q)


def clean_actions(actions: jax.Array) -> jax.Array:
  """Actions [..., A] as the search simulates and scores them: float32, non-finite entries
  zeroed, clipped to [-1, 1]."""
  return jnp.clip(jnp.nan_to_num(actions.astype(jnp.float32)), -1.0, 1.0)


def output_checks(env, actor_critic: ActorCritic, num_actions: int):
  """(nodes [B], key) -> ([B] bool finite observations, [B] finite sampled actions, [B] finite
  critic Q on the cleaned actions): a pure function to jit."""

  def outputs(nodes, key):
    finite = lambda x: jnp.all(jnp.isfinite(x.reshape(x.shape[0], -1)), axis=1)
    obs = env.observe(nodes)
    actions = actor_critic.sample_actions(key, obs, num_actions)
    q = actor_critic.q_values(obs, clean_actions(actions))
    return finite(obs), finite(actions), finite(q)

  return outputs


@dataclasses.dataclass(frozen=True)
class UniformMix:
  """An ActorCritic whose `sample_actions` draws each action uniformly from [-1, 1]^A with
  probability `share`, else from `actor_critic`; `q_values` is actor_critic's."""

  actor_critic: ActorCritic
  share: float

  def sample_actions(self, key: jax.Array, obs: jax.Array, num: int) -> jax.Array:
    k_actor, k_uniform, k_pick = jax.random.split(key, 3)
    actions = self.actor_critic.sample_actions(k_actor, obs, num)
    uniform = jax.random.uniform(k_uniform, actions.shape, actions.dtype, -1.0, 1.0)
    pick = jax.random.uniform(k_pick, actions.shape[:-1] + (1,)) < self.share
    return jnp.where(pick, uniform, actions)

  def q_values(self, obs: jax.Array, actions: jax.Array) -> jax.Array:
    return self.actor_critic.q_values(obs, actions)


def with_uniform_actions(actor_critic: ActorCritic, share: float) -> ActorCritic:
  """actor_critic, or `UniformMix` of it where share > 0 (`SearchConfig.uniform_share`)."""
  return UniformMix(actor_critic, share) if share > 0 else actor_critic
