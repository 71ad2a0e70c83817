"""Tasks: `make(name)` returns an `Env` with the training and the search interface."""

from __future__ import annotations

from typing import Callable, Dict

from pachs_jax.envs.base import EdgeOutcome, Env, NodeState, State


def _pusht(variant: str) -> Callable[[], Env]:
  def build() -> Env:
    from pachs_jax.envs import pusht
    return pusht.PushTEnv(pusht.PushTConfig(variant=variant))
  return build


def _shelf() -> Env:
  from pachs_jax.envs import shelf
  return shelf.ShelfEnv()


_REGISTRY: Dict[str, Callable[[], Env]] = {
    'pusht-fixed': _pusht('fixed'),
    'pusht-rand': _pusht('rand'),
    'pusht-obs': _pusht('obs'),
    'shelf': _shelf,
}

TASKS = tuple(_REGISTRY)


def make(name: str) -> Env:
  """A new environment of the named task; raises ValueError listing the valid names."""
  if name not in _REGISTRY:
    raise ValueError(f'unknown task {name!r}; valid tasks: {", ".join(TASKS)}')
  return _REGISTRY[name]()


__all__ = ['EdgeOutcome', 'Env', 'NodeState', 'State', 'TASKS', 'make']
