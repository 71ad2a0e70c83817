"""Tasks: `make(name)` returns an `Env` with the training and the search interface."""

from pachs_jax.envs.base import EdgeOutcome, Env, NodeState, State
from pachs_jax.envs.registry import SPECS, TASKS, TaskSpec, make, spec

__all__ = ['EdgeOutcome', 'Env', 'NodeState', 'SPECS', 'State', 'TASKS', 'TaskSpec', 'make',
           'spec']
