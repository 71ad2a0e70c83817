"""PACHS: a batched best-first search over the edges that a trained actor-critic proposes."""

from pachs_jax.search.pachs import Search, SearchState, make_search
from pachs_jax.search.capacity import Capacities
from pachs_jax.search.checks import instance_keys
from pachs_jax.search.config import SearchConfig
from pachs_jax.search.model import ActorCritic
from pachs_jax.search.result import SearchResult, StopReason

__all__ = ['ActorCritic', 'Capacities', 'Search', 'SearchConfig', 'SearchResult', 'SearchState',
           'StopReason', 'instance_keys', 'make_search']

