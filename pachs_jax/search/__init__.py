"""PACHS: a batched best-first search over the edges that a trained actor-critic proposes."""

from pachs_jax.search.pachs import Search, SearchState, make_search, plan
from pachs_jax.search.types import (ActorCritic, SearchConfig, SearchResult, StopReason,
                                    instance_keys)

__all__ = ['ActorCritic', 'Search', 'SearchConfig', 'SearchResult', 'SearchState', 'StopReason',
           'instance_keys', 'make_search', 'plan']
