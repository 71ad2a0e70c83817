"""Tasks: `make(name)` returns an `Env` with the training and the search interface;
`from_playground(env)` wraps a MuJoCo Playground env, `check_task(env)` checks a user's task
(docs/own_task.md)."""

from pachs_jax.envs.base import EdgeOutcome, Env, NodeState, State
from pachs_jax.envs.protocol import TaskError, check_task
from pachs_jax.envs.registry import (SPECS, TASKS, TaskSpec, is_playground, make, spec)


def from_playground(env, is_goal=None, lattice=None, **options):
  """A MuJoCo Playground env (an MjxEnv, or a registry name) as a PACHS task; see
  `envs.playground.from_playground` (needs pip install -e '.[playground]')."""
  from pachs_jax.envs import playground  # start-up path: lazy (loads PushT and MJX)
  return playground.from_playground(env, is_goal=is_goal, lattice=lattice, **options)


__all__ = ['EdgeOutcome', 'Env', 'NodeState', 'SPECS', 'State', 'TASKS', 'TaskError',
           'TaskSpec', 'check_task', 'from_playground', 'is_playground', 'make', 'spec']
