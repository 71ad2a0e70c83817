"""The trained SAC actor-critic as the search uses it: parameters as pytree leaves, the
hashable `ModelConfig` as static data, so it can be passed into a jitted function."""

from __future__ import annotations

import dataclasses
from typing import Any, Dict, Tuple

import jax
import jax.numpy as jnp
from brax.training.acme import running_statistics
from flax import struct

from pachs_jax.sac import digest
from pachs_jax.sac import networks as sac_networks


@dataclasses.dataclass(frozen=True)
class ModelConfig:
  """What a checkpoint must say about its networks and task.

  task: environment name (`Env.name`).
  observation_size / action_size: network input and action dimensions.
  actor_hidden / critic_hidden: hidden layer widths.
  activation: hidden activation name; normalize_observations: inputs are mean/std normalised.
  discount: the critic's per-step discount.
  reward_scaling: the critic was trained on reward * reward_scaling (divided out by q_values).
  episode_length: the task's episode length at training time (control steps).
  """

  task: str
  observation_size: int
  action_size: int
  actor_hidden: Tuple[int, ...]
  critic_hidden: Tuple[int, ...]
  activation: str = 'relu'
  normalize_observations: bool = True
  discount: float = 0.97
  reward_scaling: float = 1.0
  episode_length: int = 0

  def __post_init__(self):
    object.__setattr__(self, 'actor_hidden', tuple(int(h) for h in self.actor_hidden))
    object.__setattr__(self, 'critic_hidden', tuple(int(h) for h in self.critic_hidden))

  def networks(self) -> sac_networks.SACNetworks:
    """The pure network functions of this config."""
    return sac_networks.make_sac_networks(
        self.observation_size, self.action_size, self.actor_hidden, self.critic_hidden,
        self.activation, self.normalize_observations)


@struct.dataclass
class ActorCriticParams:
  """normalizer: {'mean': [O], 'std': [O]}; policy / q: flax parameter trees."""

  normalizer: Dict[str, jax.Array]
  policy: Any
  q: Any


@struct.dataclass
class SacActorCritic:
  """A trained tanh-Gaussian actor and twin critic (implements `search.model.ActorCritic`).

  sample_actions(key, obs[B, O], num) -> [B, num, A] stochastic actions in [-1, 1].
  q_values(obs[B, O], actions[B, num, A]) -> [B, num] min of the twin critics in the
    environment's reward units (so -Q is a cost-to-go estimate).
  deterministic_action(obs[B, O]) -> [B, A] the policy mean squashed by tanh.
  """

  params: ActorCriticParams
  config: ModelConfig = struct.field(pytree_node=False)

  @property
  def fingerprint(self) -> str:
    """The config and a digest of the parameters: they fix what the networks compute."""
    return f'{self.config!r}:{digest.params_hash(self.params)}'

  def _normalizer(self) -> running_statistics.NestedMeanStd:
    return running_statistics.NestedMeanStd(mean=self.params.normalizer['mean'],
                                            std=self.params.normalizer['std'])

  def _check_obs(self, obs: jax.Array) -> None:
    shape = jnp.shape(obs)
    if len(shape) != 2 or shape[1] != self.config.observation_size:
      raise ValueError(f'obs must have shape [B, {self.config.observation_size}] for task '
                       f'{self.config.task!r}, got {tuple(shape)}')

  def sample_actions(self, key: jax.Array, obs: jax.Array, num: int) -> jax.Array:
    """[B, num, A] actions sampled from the policy at each of obs [B, O]."""
    self._check_obs(obs)
    if not isinstance(num, int) or num < 1:
      raise ValueError(f'num must be a positive Python int, got {num!r}')
    nets = self.config.networks()
    dist_params = nets.policy_apply(self._normalizer(), self.params.policy, obs)
    dist_params = jnp.broadcast_to(dist_params[:, None, :],
                                   (obs.shape[0], num, dist_params.shape[-1]))
    return nets.distribution.sample(dist_params, key)

  def deterministic_action(self, obs: jax.Array) -> jax.Array:
    """[B, A] the tanh of the policy mean at obs [B, O]."""
    self._check_obs(obs)
    nets = self.config.networks()
    return nets.distribution.mode(nets.policy_apply(self._normalizer(), self.params.policy, obs))

  def q_values(self, obs: jax.Array, actions: jax.Array) -> jax.Array:
    """[B, num] float32 min twin Q (reward units) of actions [B, num, A] at obs [B, O]."""
    self._check_obs(obs)
    a_shape = jnp.shape(actions)
    if (len(a_shape) != 3 or a_shape[0] != obs.shape[0]
        or a_shape[2] != self.config.action_size):
      raise ValueError(f'actions must have shape [{obs.shape[0]}, num, '
                       f'{self.config.action_size}], got {tuple(a_shape)}')
    nets = self.config.networks()
    obs_b = jnp.broadcast_to(obs[:, None, :], (a_shape[0], a_shape[1], obs.shape[1]))
    q = nets.q_apply(self._normalizer(), self.params.q, obs_b, actions)
    return (jnp.min(q, axis=-1) / self.config.reward_scaling).astype(jnp.float32)
