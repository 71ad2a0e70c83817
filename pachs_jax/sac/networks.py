"""SAC networks from Brax's factories: a tanh-Gaussian actor and a twin Q critic over
normalised observations, as pure functions of explicit parameters."""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
from brax.training import distribution
from brax.training import networks as brax_networks
from brax.training import types as brax_types
from brax.training.acme import running_statistics
from flax import linen

NORMALIZER_VARIANCE_EPS = 1e-6

ACTIVATIONS = {'relu': linen.relu, 'swish': linen.swish, 'tanh': linen.tanh, 'elu': linen.elu}


@dataclasses.dataclass(frozen=True)
class SACNetworks:
  """Pure functions of the actor and the critic.

  policy_apply(normalizer, policy_params, obs[..., O]) -> [..., 2A] distribution parameters.
  q_apply(normalizer, q_params, obs[..., O], action[..., A]) -> [..., 2] twin Q values
    (scaled reward units).
  policy_init(key) / q_init(key) -> parameters.
  distribution: the tanh-Gaussian over actions in [-1, 1]^A.
  """

  policy_apply: Callable[..., jax.Array]
  q_apply: Callable[..., jax.Array]
  policy_init: Callable[[jax.Array], Any]
  q_init: Callable[[jax.Array], Any]
  distribution: distribution.NormalTanhDistribution
  observation_size: int
  action_size: int


def make_sac_networks(observation_size: int, action_size: int,
                      actor_hidden: Sequence[int] = (256, 256),
                      critic_hidden: Sequence[int] = (256, 256),
                      activation: str = 'relu',
                      normalize_observations: bool = True) -> SACNetworks:
  """Actor and twin critic MLPs with the given hidden layer widths."""
  if activation not in ACTIVATIONS:
    raise ValueError(f'activation must be one of {sorted(ACTIVATIONS)}, got {activation!r}')
  for label, hidden in (('actor_hidden', actor_hidden), ('critic_hidden', critic_hidden)):
    if len(hidden) == 0 or any(int(h) < 1 for h in hidden):
      raise ValueError(f'{label} must be a non-empty sequence of positive widths, got {hidden}')
  if observation_size < 1 or action_size < 1:
    raise ValueError(f'observation_size and action_size must be >= 1, got {observation_size}, '
                     f'{action_size}')
  preprocess = running_statistics.normalize if normalize_observations else (lambda x, _: x)
  act = ACTIVATIONS[activation]
  dist = distribution.NormalTanhDistribution(event_size=action_size)
  policy = brax_networks.make_policy_network(
      dist.param_size, observation_size, preprocess_observations_fn=preprocess,
      hidden_layer_sizes=tuple(int(h) for h in actor_hidden), activation=act)
  q = brax_networks.make_q_network(
      observation_size, action_size, preprocess_observations_fn=preprocess,
      hidden_layer_sizes=tuple(int(h) for h in critic_hidden), activation=act, n_critics=2)
  return SACNetworks(policy_apply=policy.apply, q_apply=q.apply, policy_init=policy.init,
                     q_init=q.init, distribution=dist, observation_size=observation_size,
                     action_size=action_size)


def init_normalizer(observation_size: int) -> running_statistics.RunningStatisticsState:
  """Running mean/std of observations [O], starting at mean 0 and std 1, with a variance floor
  of NORMALIZER_VARIANCE_EPS (a std of at least 1e-3)."""
  zeros = jnp.zeros((observation_size,), jnp.float32)
  return running_statistics.RunningStatisticsState(
      count=brax_types.UInt64(hi=0, lo=0), mean=zeros, summed_variance=zeros,
      std=jnp.ones((observation_size,), jnp.float32),
      std_eps=jnp.asarray(NORMALIZER_VARIANCE_EPS, jnp.float32))


def update_normalizer(state: running_statistics.RunningStatisticsState,
                      observations: jax.Array) -> running_statistics.RunningStatisticsState:
  """Adds a batch of observations [N, O] to the running statistics."""
  return running_statistics.update(state, observations)


def sample_actions(networks: SACNetworks, normalizer: Any, policy_params: Any, key: jax.Array,
                   obs: jax.Array) -> jax.Array:
  """[..., A] stochastic actions in [-1, 1] for observations [..., O]."""
  params = networks.policy_apply(normalizer, policy_params, obs)
  return networks.distribution.sample(params, key)

