"""SAC hyperparameters as one validated frozen dataclass, and the JSON round trip of configs."""

from __future__ import annotations

import dataclasses
from typing import Any, Dict, Mapping, Tuple, Type, TypeVar

_Config = TypeVar('_Config')
SEED_LIMIT = 2**32  # seeds are in [0, SEED_LIMIT)


def config_to_dict(config: Any) -> Dict[str, Any]:
  """A JSON-ready dict of a frozen config dataclass's fields (tuples become lists)."""
  return {k: list(v) if isinstance(v, tuple) else v
          for k, v in dataclasses.asdict(config).items()}


def config_from_dict(cls: Type[_Config], values: Mapping[str, Any],
                     ignore_unknown: bool = False) -> _Config:
  """The `cls` instance of a dict written by `config_to_dict`.

  Raises ValueError for a missing field without default and, unless `ignore_unknown`, for a
  key that is no field of `cls`.
  """
  fields = dataclasses.fields(cls)
  known = {f.name for f in fields}
  unknown = sorted(set(values) - known)
  if unknown and not ignore_unknown:
    raise ValueError(f'unknown {cls.__name__} fields {unknown}')
  missing = sorted(f.name for f in fields if f.name not in values
                   and f.default is dataclasses.MISSING
                   and f.default_factory is dataclasses.MISSING)
  if missing:
    raise ValueError(f'{cls.__name__} lacks fields {missing}')
  return cls(**{k: v for k, v in values.items() if k in known})


@dataclasses.dataclass(frozen=True)
class SACConfig:
  """Hyperparameters of one SAC run.

  num_envs: environments stepped in parallel (one vmapped env step per training step).
  batch_size: transitions per gradient update.
  grad_updates_per_step: gradient updates per training step (per num_envs env steps).
  steps_per_epoch: training steps in one jitted epoch (the unit of logging and checkpoints).
  actor/critic/alpha_learning_rate: Adam step sizes.
  discount: per-step discount of the soft Bellman target.
  reward_scaling: the critic learns Q of reward * reward_scaling.
  tau: Polyak averaging rate of the target critic.
  replay_capacity: transitions kept in the device replay buffer (FIFO).
  min_replay_size: transitions collected with uniform random actions before learning.
  actor_hidden / critic_hidden: hidden layer widths of the actor and of each twin critic.
  activation: 'relu', 'swish', 'tanh' or 'elu'.
  normalize_observations: feed running-mean/std normalised observations to both networks.
  init_alpha: initial entropy temperature.
  target_entropy_per_action: target entropy = this * action_size (SAC's default is -1).
  max_grad_norm: global gradient-norm clip of every update (0 disables it).
  desync_episodes: start each environment's first episode at a random step count t in
    [0, episode_length) so that episode ends (and resets) are spread over time, not in lockstep.
  seed: PRNG seed of the whole run, in [0, 2**32) (jax.random.PRNGKey keeps 32 bits of it
    without x64, so larger seeds would repeat smaller ones).
  eval_instances: start nodes of the periodic single-rollout evaluation (0 disables it).
  failure_cost: subtracted from the reward of a step that ends its episode in failure (an
    invalid edge: a tipped T, the T off the table). Where rewards are negative costs and
    nothing is charged, failing early is the cheapest episode; a large charge teaches the
    policy to avoid what might fail (on PushT: the T itself).
  absorbing_failure: a step that ends its episode in failure is charged its reward as if the
    failed state were kept for ever (reward / (1 - discount)), before failure_cost: failing then
    costs what staying put costs, no more (needs discount < 1).
  """

  num_envs: int = 128
  batch_size: int = 256
  grad_updates_per_step: int = 1
  steps_per_epoch: int = 50
  actor_learning_rate: float = 3e-4
  critic_learning_rate: float = 3e-4
  alpha_learning_rate: float = 3e-4
  discount: float = 0.97
  reward_scaling: float = 1.0
  tau: float = 0.005
  replay_capacity: int = 1_000_000
  min_replay_size: int = 8192
  actor_hidden: Tuple[int, ...] = (256, 256)
  critic_hidden: Tuple[int, ...] = (256, 256)
  activation: str = 'relu'
  normalize_observations: bool = True
  init_alpha: float = 1.0
  target_entropy_per_action: float = -1.0
  max_grad_norm: float = 0.0
  desync_episodes: bool = True
  seed: int = 0
  eval_instances: int = 128
  failure_cost: float = 0.0
  absorbing_failure: bool = False

  def __post_init__(self):
    object.__setattr__(self, 'actor_hidden', tuple(int(h) for h in self.actor_hidden))
    object.__setattr__(self, 'critic_hidden', tuple(int(h) for h in self.critic_hidden))
    positive = ('num_envs', 'batch_size', 'grad_updates_per_step', 'steps_per_epoch',
                'replay_capacity', 'actor_learning_rate', 'critic_learning_rate',
                'alpha_learning_rate', 'reward_scaling', 'init_alpha')
    for name in positive:
      if not getattr(self, name) > 0:
        raise ValueError(f'SACConfig.{name} must be > 0, got {getattr(self, name)}')
    if not 0.0 <= self.discount <= 1.0:
      raise ValueError(f'SACConfig.discount must be in [0, 1], got {self.discount}')
    if not 0.0 < self.tau <= 1.0:
      raise ValueError(f'SACConfig.tau must be in (0, 1], got {self.tau}')
    if not (self.failure_cost >= 0 and self.failure_cost < float('inf')):
      raise ValueError(f'SACConfig.failure_cost must be a finite number >= 0, got '
                       f'{self.failure_cost}')
    if self.absorbing_failure and not self.discount < 1.0:
      raise ValueError(f'SACConfig.absorbing_failure needs discount < 1, got {self.discount}')
    if self.min_replay_size < 0 or self.max_grad_norm < 0 or self.eval_instances < 0:
      raise ValueError('SACConfig.min_replay_size, max_grad_norm and eval_instances must be '
                       f'>= 0, got {self.min_replay_size}, {self.max_grad_norm}, '
                       f'{self.eval_instances}')
    if self.replay_capacity < max(self.num_envs, self.min_replay_size):
      raise ValueError(f'SACConfig.replay_capacity ({self.replay_capacity}) must hold at least '
                       f'num_envs ({self.num_envs}) and min_replay_size ({self.min_replay_size})')
    if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not (
        0 <= self.seed < SEED_LIMIT):
      raise ValueError(f'SACConfig.seed must be an integer in [0, 2**32), got {self.seed!r}')
    for name in ('actor_hidden', 'critic_hidden'):
      widths = getattr(self, name)
      if not widths or min(widths) < 1:
        raise ValueError(f'SACConfig.{name} must be non-empty positive widths, got {widths}')

  def differences(self, other: 'SACConfig') -> Dict[str, Tuple[Any, Any]]:
    """{field: (self value, other value)} of the fields that differ."""
    return {f.name: (getattr(self, f.name), getattr(other, f.name))
            for f in dataclasses.fields(self)
            if getattr(self, f.name) != getattr(other, f.name)}
