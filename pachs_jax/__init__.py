"""PACHS in JAX: a trained SAC actor-critic turned into a batched best-first planner. Its entry
points (`Planner`, `Session`, `make_search`, `SearchConfig`, `SearchResult`, `envs`) load on
first use, so `import pachs_jax` stays light; README.md, "The package", says where each lives."""

import importlib

__version__ = '0.1.0'

_LAZY = {'Planner': 'pachs_jax.planner', 'Session': 'pachs_jax.replan',
         'make_search': 'pachs_jax.search', 'SearchConfig': 'pachs_jax.search',
         'SearchResult': 'pachs_jax.search', 'envs': None}

__all__ = sorted(_LAZY)


def __getattr__(name):
  if name not in _LAZY:
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
  if _LAZY[name] is None:
    return importlib.import_module(f'{__name__}.{name}')
  return getattr(importlib.import_module(_LAZY[name]), name)
