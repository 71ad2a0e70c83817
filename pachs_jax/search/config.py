"""The search's configuration: the settings PACHS and ePA*SE share, PACHS's own, and the checks
of their numbers."""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from pachs_jax.flags import AFTER_GOALS, CHAIN_RESTARTS, REALTIME_ANSWERS


def plain_number(value):
  """value as a Python int or float when it is an integer or real number of any kind (a numpy
  or JAX scalar, a 0-d array); anything else, bools included, unchanged."""
  if isinstance(value, (bool, np.bool_)) or isinstance(value, jax.core.Tracer):
    return value
  if isinstance(value, numbers.Integral):
    return int(value)
  if isinstance(value, numbers.Real):
    return float(value)
  dtype = getattr(value, 'dtype', None)
  if getattr(value, 'shape', None) == () and dtype is not None:
    if jnp.issubdtype(dtype, jnp.integer):
      return int(value)
    if jnp.issubdtype(dtype, jnp.floating):
      return float(value)
  return value


def normalize_numbers(config) -> None:
  """Replaces the numpy / JAX scalar fields of a frozen dataclass config by Python ints and
  floats (so that equal configs hash and compare equal); call first in __post_init__."""
  for field in dataclasses.fields(config):
    value = getattr(config, field.name)
    plain = plain_number(value)
    if plain is not value:
      object.__setattr__(config, field.name, plain)


def positive_int(owner: str, name: str, value, allow_none: bool = False):
  """value as a Python int >= 1 (numpy and JAX integers accepted; None when allow_none);
  ValueError otherwise (bools included)."""
  if value is None and allow_none:
    return None
  value = plain_number(value)
  if isinstance(value, bool) or not isinstance(value, int) or value < 1:
    raise ValueError(f'{owner}.{name} must be a positive int, got {value!r}')
  return value


def check_weight(owner: str, weight) -> float:
  """weight as a Python float, finite and >= 0 (numpy and JAX numbers accepted); ValueError
  otherwise."""
  weight = plain_number(weight)
  if (isinstance(weight, bool) or not isinstance(weight, (int, float))
      or not math.isfinite(weight) or weight < 0):
    raise ValueError(f'{owner}.weight must be a finite number >= 0, got {weight!r}')
  return float(weight)


def lattice_resolution_tuple(owner: str, resolution):
  """None, or the resolution as a tuple of positive finite floats (numpy and JAX numbers
  accepted); ValueError otherwise."""
  if resolution is None:
    return None
  try:
    res = tuple(plain_number(r) for r in resolution)
  except TypeError:
    res = ()
  if not res or not all(isinstance(r, (int, float)) and not isinstance(r, bool)
                        and math.isfinite(r) and r > 0 for r in res):
    raise ValueError(f'{owner}.lattice_resolution must be a non-empty tuple of positive cell '
                     f'sizes, got {resolution!r}')
  return tuple(float(r) for r in res)


def next_pow2(n: int) -> int:
  """The smallest power of two >= n (1 for n <= 1)."""
  return 1 << max(0, int(n - 1).bit_length())


@dataclasses.dataclass(frozen=True)
class EdgeSearchConfig:
  """The settings that PACHS and ePA*SE share (the arrays' capacities follow from the budget,
  `capacity.Capacities`).

  weight: heuristic weight w >= 0 (keys g + w h).
  pop_size: K: per instance and iteration, the edges popped (PACHS: up to K states expanded
    and K edges evaluated).
  budget: edge-evaluation budget per instance.
  lattice_resolution: [L] lattice cell sizes (None: the environment's default).
  """

  weight: float = 1.0
  pop_size: int = 16
  budget: int = 100_000
  lattice_resolution: Optional[Tuple[float, ...]] = None

  def __post_init__(self):
    owner = type(self).__name__
    normalize_numbers(self)
    object.__setattr__(self, 'weight', check_weight(owner, self.weight))
    for name in ('pop_size', 'budget'):
      positive_int(owner, name, getattr(self, name))
    object.__setattr__(self, 'lattice_resolution',
                       lattice_resolution_tuple(owner, self.lattice_resolution))


@dataclasses.dataclass(frozen=True)
class SearchConfig(EdgeSearchConfig):
  """PACHS parameters: those of `EdgeSearchConfig` and

  num_actions: N actions sampled per expansion.
  realtime_answer: the path returned when no goal was found: 'best_f' (to the state of the
    best OPEN entry, the original's), 'min_h' (to the generated state, the start excluded,
    of least estimated cost-to-go; needs w > 0) or 'min_cost' (to the generated state whose
    incoming edge has the least cost per transition, `path.min_cost_answer`).
  compact_fractions: smaller physics batches as fractions in (0, 1) of the I * K lanes
    (`compact.evaluate_live`); () always simulates all lanes.
  edge_steps: H, the transitions of one edge: its sampled action, then H - 1 actions that the
    actor samples along the way (`segment`); an edge costs H evaluations, and a successor's h
    is the critic's at its state. 1: the original's one-step edges, h = q - c.
  rollout_share: the share of the K evaluation lanes, R = floor(share K) (`rollout_lanes`), that
    extend chains of the actor's edges (each from its chain's last successor, restarting as
    chain_restart says after an unusable edge or an episode's length) instead of popping OPEN's
    best edges; their successors join the search, and a chain's goal ends the instance at once.
  chain_restart: where a chain restarts: 'start' (the start state, so that chains are rollouts
    of the actor) or 'novel' (a generated node of a rarely visited coarse cell, a cell of n
    nodes drawn with weight 1 / sqrt(n), `rules.restart_novel`; nodes whose next edge would
    pass an episode's length are left out); no effect without rollout lanes.
  after_goal: what the first goal does: 'stop' (it ends the instance, the original's) or
    'improve' (`improve`: the instance goes on, its chains restarting on the cheapest goal's
    path and edges from nodes that cost as much as that goal pruned, and returns the cheapest
    goal found).
  improve_allowance: with 'improve', the evaluations spent after the first goal, as a multiple
    of those spent up to it (inf: until the budget ends).
  uniform_share: the probability that an action the search draws from the actor (an
    expansion's N, the steps along an edge, a chain's) is drawn uniformly from [-1, 1]^A
    instead (`model.with_uniform_actions`): moves the actor never proposes, such as lifting a
    stick blocked by an obstacle the actor never saw.
  """

  num_actions: int = 16
  realtime_answer: str = 'best_f'
  compact_fractions: Tuple[float, ...] = ()
  edge_steps: int = 1
  rollout_share: float = 0.0
  chain_restart: str = 'start'
  after_goal: str = 'stop'
  improve_allowance: float = math.inf
  uniform_share: float = 0.0

  def __post_init__(self):
    super().__post_init__()
    positive_int('SearchConfig', 'num_actions', self.num_actions)
    share = self.uniform_share
    if (isinstance(share, bool) or not isinstance(share, (int, float)) or not 0 <= share <= 1):
      raise ValueError(f'SearchConfig.uniform_share must be a number in [0, 1], got {share!r}')
    object.__setattr__(self, 'uniform_share', float(share))
    if self.chain_restart not in CHAIN_RESTARTS:
      raise ValueError(f'SearchConfig.chain_restart must be one of {CHAIN_RESTARTS}, got '
                       f'{self.chain_restart!r}')
    positive_int('SearchConfig', 'edge_steps', self.edge_steps)
    share = self.rollout_share
    if (isinstance(share, bool) or not isinstance(share, (int, float)) or not 0 <= share < 1):
      raise ValueError(f'SearchConfig.rollout_share must be a number in [0, 1), got {share!r}')
    object.__setattr__(self, 'rollout_share', float(share))
    if self.pop_size * self.edge_steps >= 2**31:
      raise ValueError(f'SearchConfig.pop_size * edge_steps must stay below 2**31 (int32 '
                       f'evaluation counts), got {self.pop_size} * {self.edge_steps}')
    if self.edge_steps > self.budget:
      raise ValueError(f'SearchConfig.edge_steps ({self.edge_steps}) exceeds budget '
                       f'({self.budget}): no edge would fit the budget')
    if self.after_goal not in AFTER_GOALS:
      raise ValueError(f'SearchConfig.after_goal must be one of {AFTER_GOALS}, got '
                       f'{self.after_goal!r}')
    allowance = self.improve_allowance
    if (isinstance(allowance, bool) or not isinstance(allowance, (int, float))
        or math.isnan(allowance) or allowance < 0):
      raise ValueError('SearchConfig.improve_allowance must be a number >= 0 (inf: the whole '
                       f'budget), got {allowance!r}')
    object.__setattr__(self, 'improve_allowance', float(allowance))
    if self.realtime_answer not in REALTIME_ANSWERS:
      raise ValueError(f'SearchConfig.realtime_answer must be one of {REALTIME_ANSWERS}, got '
                       f'{self.realtime_answer!r}')
    fractions = (tuple(plain_number(f) for f in self.compact_fractions)
                 if isinstance(self.compact_fractions, (tuple, list)) else (None,))
    if not all(isinstance(f, numbers.Real) and not isinstance(f, bool) and 0 < f < 1
               for f in fractions):
      raise ValueError('SearchConfig.compact_fractions must be fractions in (0, 1), got '
                       f'{self.compact_fractions!r}')
    object.__setattr__(self, 'compact_fractions', tuple(float(f) for f in fractions))
    if self.realtime_answer == 'min_h' and not self.weight > 0:
      raise ValueError("SearchConfig.realtime_answer='min_h' reads h from the dummy-edge keys "
                       f'and needs weight > 0, got {self.weight!r}')

  @property
  def rollout_lanes(self) -> int:
    """R, the lanes of the K that extend chains of the actor's edges."""
    return int(self.rollout_share * self.pop_size)
