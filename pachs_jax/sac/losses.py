"""Soft actor-critic losses with automatic entropy tuning (Haarnoja et al. 2018,
arXiv:1812.05905), as pure functions of explicit parameters."""

from __future__ import annotations

from typing import Any, Callable, Tuple

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax.sac import networks as sac_networks


@struct.dataclass
class Transition:
  """A batch of transitions, leading axes [...].

  observation: [..., O] float32 observation before the step.
  action: [..., A] float32 action in [-1, 1].
  reward: [...] float32 environment reward (non-positive, unscaled).
  discount: [...] float32 1.0 to bootstrap from next_observation, 0.0 at a terminal state
    (success or invalid edge; a time-limit truncation still bootstraps).
  next_observation: [..., O] float32 observation after the step (before any auto-reset).
  """

  observation: jax.Array
  action: jax.Array
  reward: jax.Array
  discount: jax.Array
  next_observation: jax.Array


def make_losses(networks: sac_networks.SACNetworks, reward_scaling: float, discount: float,
                target_entropy: float) -> Tuple[Callable[..., jax.Array], ...]:
  """(alpha_loss, critic_loss, actor_loss) for the given networks and hyperparameters."""
  dist = networks.distribution

  def _sample_with_log_prob(normalizer, policy_params, obs, key):
    params = networks.policy_apply(normalizer, policy_params, obs)
    raw = dist.sample_no_postprocessing(params, key)
    return dist.postprocess(raw), dist.log_prob(params, raw)

  def alpha_loss(log_alpha: jax.Array, policy_params: Any, normalizer: Any,
                 transitions: Transition, key: jax.Array) -> jax.Array:
    """Temperature loss: pushes the policy entropy toward target_entropy (eq. 18)."""
    _, log_prob = _sample_with_log_prob(normalizer, policy_params, transitions.observation, key)
    alpha = jnp.exp(log_alpha)
    return jnp.mean(alpha * jax.lax.stop_gradient(-log_prob - target_entropy))

  def critic_loss(q_params: Any, policy_params: Any, normalizer: Any, target_q_params: Any,
                  alpha: jax.Array, transitions: Transition, key: jax.Array) -> jax.Array:
    """Soft Bellman residual of both critics against the clipped double-Q target."""
    q_old = networks.q_apply(normalizer, q_params, transitions.observation, transitions.action)
    next_action, next_log_prob = _sample_with_log_prob(
        normalizer, policy_params, transitions.next_observation, key)
    next_q = networks.q_apply(normalizer, target_q_params, transitions.next_observation,
                              next_action)
    next_v = jnp.min(next_q, axis=-1) - alpha * next_log_prob
    target = jax.lax.stop_gradient(transitions.reward * reward_scaling
                                   + transitions.discount * discount * next_v)
    return 0.5 * jnp.mean(jnp.square(q_old - target[..., None]))

  def actor_loss(policy_params: Any, normalizer: Any, q_params: Any, alpha: jax.Array,
                 transitions: Transition, key: jax.Array) -> jax.Array:
    """Entropy-regularised policy loss: alpha * log pi(a|s) - min_i Q_i(s, a)."""
    action, log_prob = _sample_with_log_prob(normalizer, policy_params,
                                             transitions.observation, key)
    q = networks.q_apply(normalizer, q_params, transitions.observation, action)
    return jnp.mean(alpha * log_prob - jnp.min(q, axis=-1))

  return alpha_loss, critic_loss, actor_loss
