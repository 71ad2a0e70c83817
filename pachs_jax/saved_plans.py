"""Each instance's plan of a `SearchResult` as actions, states and costs; its JSON form; and its
replay through the env's own transition."""

from __future__ import annotations

import dataclasses
from typing import Any, Dict, List, Optional

import jax
import jax.numpy as jnp
import numpy as np

from pachs_jax.envs import base, physics_presets
from pachs_jax.search.baselines import common

NODE_FIELDS = ('qpos', 'qvel', 'ctrl', 'qacc_warmstart', 't')  # the goal is stored once


@dataclasses.dataclass(frozen=True)
class Plan:
  """The plan of one instance, trimmed to its length L (numpy arrays, no batch axis).

  actions: [L, A] float32 env actions in [-1, 1]^A, one per transition (an edge of H
    transitions contributes its H actions: its own, then the actor's).
  states: NodeState [L + 1, ...] the states along the path, the start first.
  cost: path cost (sum of the transitions' costs, the env's cost units).
  found: the search reached a goal; ends_at_goal: the last state satisfies the goal rule.
  truncated: the path was longer than the search kept (`Capacities.max_path_length`); the
    plan holds its first L transitions.
  physics: the engine that made it (`base.Env.physics`: 'mjx', 'warp', 'mujoco-c', 'jax');
    None: not recorded.
  physics_settings: the settings of the physics model it simulated (`base.Env.physics_settings`,
    e.g. PushT's time step and contact parameters); None: none or not recorded.
  """

  actions: np.ndarray
  states: base.NodeState
  cost: float
  found: bool
  ends_at_goal: bool
  truncated: bool
  physics: Optional[str] = None
  physics_settings: Optional[Dict[str, Any]] = None

  @property
  def length(self) -> int:
    """L, the transitions in the plan."""
    return int(self.actions.shape[0])

  @property
  def start(self) -> base.NodeState:
    """The start state (no batch axis)."""
    return jax.tree.map(lambda x: x[0], self.states)


def from_result(result, physics: Optional[str] = None,
                physics_settings: Optional[Dict[str, Any]] = None) -> List[Plan]:
  """The plan of each instance of a SearchResult [I], in order; physics, physics_settings: the
  engine and model settings of the env that made it (`base.Env.physics`, `physics_settings`)."""
  r = jax.tree.map(np.asarray, result.replace(wall_time_s=None))
  kept = r.path_actions.shape[1]
  plans = []
  for i in range(r.found.shape[0]):
    length = int(min(r.path_length[i], kept))
    plans.append(Plan(
        actions=r.path_actions[i, :length], cost=float(r.cost[i]), found=bool(r.found[i]),
        states=jax.tree.map(lambda x, i=i, n=length: x[i, :n + 1], r.path_nodes),
        ends_at_goal=bool(r.path_is_goal[i]), truncated=bool(r.path_truncated[i]),
        physics=physics, physics_settings=physics_settings))
  return plans


def _floats(array: np.ndarray) -> list:
  """Nested lists of Python numbers; float32 values convert exactly (and back, see `from_json`)."""
  return np.asarray(array).tolist()


def _leaves(states) -> Dict[str, Any]:
  """{key path: leaf} of a node pytree (a task's own node type, e.g. a Playground node)."""
  flat, _ = jax.tree_util.tree_flatten_with_path(states)
  return {jax.tree_util.keystr(path): leaf for path, leaf in flat}


def to_json(plan: Plan) -> Dict[str, Any]:
  """A JSON-ready dict of a plan: length, cost, found, ends_at_goal, truncated, action_size A,
  actions [L][A] and the states [L + 1][...]: for a `base.NodeState`, goal [G] once and states
  {qpos, qvel, ctrl, qacc_warmstart, t}; for another node type, states {key path: leaf} and
  node_type. Floats keep their float32 values exactly (`from_json` restores them bit for bit)."""
  out = {'length': plan.length, 'cost': plan.cost, 'found': plan.found,
         'ends_at_goal': plan.ends_at_goal, 'truncated': plan.truncated, 'physics': plan.physics,
         'physics_settings': plan.physics_settings,
         'action_size': int(plan.actions.shape[1]), 'actions': _floats(plan.actions)}
  if isinstance(plan.states, base.NodeState):
    out['goal'] = _floats(plan.states.goal[0])
    out['states'] = {name: _floats(getattr(plan.states, name)) for name in NODE_FIELDS}
  else:
    out['node_type'] = type(plan.states).__qualname__
    out['states'] = {path: _floats(leaf) for path, leaf in _leaves(plan.states).items()}
  return out


def from_json(data: Dict[str, Any], like=None) -> Plan:
  """The Plan of a `to_json` dict (for example a row's 'plan' in `pachs plan --json`);
  like: a node of the task (any batch shape) for a plan of another node type than
  `base.NodeState`. ValueError naming what is missing or of the wrong shape."""
  try:
    actions = np.asarray(data['actions'], np.float32)
    if actions.size == 0:  # an empty plan: [0, A]
      actions = actions.reshape(0, int(data['action_size']))
    flags = {k: bool(data[k]) for k in ('found', 'ends_at_goal', 'truncated')}
    cost = float(data['cost'])
    physics = data.get('physics')
    if physics is not None and not isinstance(physics, str):
      raise TypeError(f"'physics' {physics!r}")
    settings = data.get('physics_settings')
    if settings is not None and not isinstance(settings, dict):
      raise TypeError(f"'physics_settings' {settings!r}")
    if 'node_type' in data:
      if like is None:
        raise ValueError(f'a plan of {data["node_type"]} nodes needs like= (a node of its task)')
      fields = {path: np.asarray(data['states'][path], leaf.dtype)
                for path, leaf in _leaves(like).items()}
    else:
      fields = {name: np.asarray(data['states'][name], np.int32 if name == 't' else np.float32)
                for name in NODE_FIELDS}
      goal = np.asarray(data['goal'], np.float32)
  except (KeyError, TypeError, AttributeError) as err:
    raise ValueError(f'not a plan: missing or malformed entry {err}') from None
  count = actions.shape[0] + 1 if actions.ndim == 2 else None
  wrong = [f'{k} {v.shape}' for k, v in fields.items() if v.shape[:1] != (count,)]
  if count is None or wrong:
    raise ValueError(f'a plan needs actions [L, A] and states of L + 1 rows, got actions '
                     f'{actions.shape} and {", ".join(wrong) or "no states"}')
  if 'node_type' in data:
    states = jax.tree_util.tree_unflatten(jax.tree.structure(like), list(fields.values()))
  else:
    states = base.NodeState(goal=np.broadcast_to(goal, (count,) + goal.shape).copy(), **fields)
  return Plan(actions=actions, states=states, cost=cost, physics=physics,
              physics_settings=settings, **flags)


@dataclasses.dataclass(frozen=True)
class Replay:
  """A plan replayed from its start (numpy arrays).

  states: NodeState [L + 1, ...] the states the env's transition reaches, the start first.
  step_costs: [L] float32 each transition's cost; cost: their sum (float32).
  valid: every transition was valid; is_goal: the last state satisfies the goal rule.
  """

  states: base.NodeState
  step_costs: np.ndarray
  cost: float
  valid: bool
  is_goal: bool


def make_env(task: str, physics: str, layout: Optional[str] = None,
             physics_settings: Optional[Dict[str, Any]] = None) -> base.Env:
  """The env of a task name (`envs.make`, layout for pusht-obs) simulated by `physics` with
  `physics_settings` (PushT: `pusht.PHYSICS_FIELDS`; None: the task's), the engine and model a
  plan records (`Plan.physics`, `Plan.physics_settings`), to replay it where it was made."""
  from pachs_jax import envs  # pylint: disable=import-outside-toplevel  (MuJoCo)
  from pachs_jax.envs import backends, pusht  # pylint: disable=import-outside-toplevel
  env = envs.make(task, layout=layout)
  differ = (physics_presets.differing_settings(physics_settings, env.physics_settings or {})
            if physics_settings is not None else [])
  if differ:
    unknown = sorted(set(physics_settings) - set(pusht.PHYSICS_FIELDS))
    if unknown or not isinstance(env, pusht.PushTEnv):
      raise ValueError(f'task {task!r} takes no physics settings '
                       f'{", ".join(unknown or sorted(physics_settings))}')
    missing = [k for k in differ if k not in physics_settings]
    if missing:
      raise ValueError(f'the physics settings record lacks {", ".join(missing)}, which task '
                       f'{task!r} simulates: the plan cannot be replayed where it was made')
    fields = {k: tuple(v) if isinstance(v, list) else v
              for k, v in physics_settings.items() if k in differ}
    env = pusht.PushTEnv(dataclasses.replace(env.config, **fields))
  if physics == env.physics:
    return env
  built = (backends.make_backend(env, physics)
           if physics in backends.BACKENDS and isinstance(env, pusht.PushTEnv) else env)
  if built.physics != physics:
    raise ValueError(f'task {task!r} simulates with {env.physics!r}, not {physics!r}')
  return built


def replay(env: base.Env, plan: Plan) -> Replay:
  """Applies the plan's actions from its start state through `env.evaluate` (the physics the
  search used, one world) and returns the states reached and their costs. ValueError when the
  plan records another engine than env's (`make_env` builds the plan's)."""
  if plan.physics is not None and plan.physics != env.physics:
    raise ValueError(f'this plan was made with {plan.physics} physics and env {env.name!r} '
                     f'simulates with {env.physics}, where it reaches other states: replay it '
                     f"on saved_plans.make_env(task, {plan.physics!r}, layout, settings)")
  differ = (physics_presets.differing_settings(plan.physics_settings, env.physics_settings or {})
            if plan.physics_settings is not None else [])
  if differ:
    raise ValueError(f'this plan was made with other physics settings than env {env.name!r} '
                     f'simulates ({", ".join(differ[:4])}), where it reaches other states: '
                     'replay it on saved_plans.make_env(task, physics, layout, '
                     'plan.physics_settings)')
  if plan.actions.ndim != 2 or plan.actions.shape[1] != env.action_size:
    raise ValueError(f'the plan\'s actions have shape {plan.actions.shape}; env {env.name!r} '
                     f'takes [L, {env.action_size}]')
  batch = lambda tree: jax.tree.map(lambda x: jnp.asarray(x)[None], tree)
  length = jnp.asarray([plan.length], jnp.int32)
  nodes, _, valid, is_goal = jax.jit(common.replay, static_argnums=0)(
      env, batch(plan.start), batch(plan.actions), length)
  states = jax.tree.map(lambda x: np.asarray(x)[0], nodes)
  if plan.length:  # each transition's cost, re-evaluated from the replayed state before it
    before = jax.tree.map(lambda x: jnp.asarray(x[:-1]), states)
    step_costs = np.asarray(jax.jit(env.evaluate)(before, jnp.asarray(plan.actions)).cost)
  else:
    step_costs = np.zeros((0,), np.float32)
  return Replay(states=states, step_costs=step_costs,
                cost=float(np.sum(step_costs, dtype=np.float32)),
                valid=bool(np.asarray(valid)[0]), is_goal=bool(np.asarray(is_goal)[0]))
