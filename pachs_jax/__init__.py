"""PACHS in JAX: a trained SAC actor-critic turned into a batched best-first planner over MuJoCo
MJX tasks.

Entry points (imported on first use, so that `import pachs_jax` stays light):
  Planner: a task's env, model and tuned search with its compiled programs (`planner.py`).
  Session: replanning many episodes from their new states, keeping the last answer
    (`replan.py`; `Planner.session()`).
  make_search, SearchConfig, SearchResult: the search core (`search/`), for your own loop.
  envs: the tasks (`envs.make(name)`, `envs.from_playground(env)`, `envs.check_task(env)`).
"""

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
