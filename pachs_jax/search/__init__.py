"""PACHS search: fixed-capacity edge heap, node pool, lattice table and the batched loop."""

from pachs_jax.search.pachs import Search, SearchState, instance_keys, make_search, plan
from pachs_jax.search.types import ActorCritic, SearchConfig, SearchResult, StopReason

__all__ = ['ActorCritic', 'Search', 'SearchConfig', 'SearchResult', 'SearchState', 'StopReason',
           'instance_keys', 'make_search', 'plan']
