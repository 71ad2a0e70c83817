"""The task protocol checker: `check_task(env)` runs a few random nodes and actions through a
user's `base.Env` and raises a one-line `TaskError` naming what breaks the contract that the
trainer and the search rely on (docs/own_task.md)."""

from __future__ import annotations

import dataclasses
from typing import Any, List

import jax
import jax.numpy as jnp
import numpy as np

from pachs_jax import trees
from pachs_jax.envs import base


class TaskError(ValueError):
  """A task that does not follow the protocol; the message is one line naming the task and
  the broken rule."""


@dataclasses.dataclass(frozen=True)
class CheckConfig:
  """How hard `check_task` looks.

  num_nodes: random start nodes B (one batch of the batched interface).
  num_steps: random-action steps taken from them; every step's edges are checked.
  seed: PRNG seed of the start nodes and actions.
  """

  num_nodes: int = 4
  num_steps: int = 3
  seed: int = 0

  def __post_init__(self):
    for name in ('num_nodes', 'num_steps'):
      if getattr(self, name) < 1:
        raise ValueError(f'CheckConfig.{name} must be >= 1, got {getattr(self, name)}')


def _fail(env: Any, rule: str) -> TaskError:
  name = getattr(env, 'name', type(env).__name__)
  return TaskError(f'task {name!r} ({type(env).__name__}): {rule}')


def _shapes(tree: Any) -> Any:
  return jax.tree.map(lambda x: (tuple(jnp.shape(x)), str(jnp.result_type(x))), tree)


def _check_static(env: base.Env) -> None:
  """Attributes, sizes and the shapes of one node's functions (traced, nothing runs)."""
  if not isinstance(env, base.Env):
    raise _fail(env, 'is not a pachs_jax.envs.Env (subclass base.Env and implement '
                'sample_instance, transition, observation, lattice_coords, goal_reached, '
                'action_size, default_lattice_resolution)')
  if not isinstance(getattr(env, 'name', None), str) or not env.name:
    raise _fail(env, 'needs a non-empty str `name` (checkpoints record it)')
  for name in ('episode_length', 'action_size'):
    value = getattr(env, name, None)
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
      raise _fail(env, f'`{name}` must be a positive int, got {value!r}')
  try:
    node = env.node_spec
  except Exception as e:  # pylint: disable=broad-except
    raise _fail(env, f'sample_instance(key) fails: {type(e).__name__}: {e}') from None
  if not dataclasses.is_dataclass(node):
    raise _fail(env, f'sample_instance must return a flax struct.dataclass node (like '
                f'NodeState), got {type(node).__name__}')
  t = getattr(node, 't', None)
  if t is None or t.shape != () or t.dtype != jnp.int32:
    got = None if t is None else (t.shape, str(t.dtype))
    raise _fail(env, f'the node needs a field t: [] int32 control steps since the start '
                f'(the trainer and the episode limit use it), got {got}')
  obs = jax.eval_shape(env.observation, node)
  if obs.ndim != 1 or obs.dtype != jnp.float32:
    raise _fail(env, f'observation(node) must be [O] float32, got {obs.shape} {obs.dtype}')
  action = jax.ShapeDtypeStruct((env.action_size,), jnp.float32)
  try:
    out = jax.eval_shape(env.transition, node, action)
  except Exception as e:  # pylint: disable=broad-except
    raise _fail(env, f'transition(node, action [{env.action_size}]) fails: '
                f'{type(e).__name__}: {e}') from None
  if not isinstance(out, base.EdgeOutcome):
    raise _fail(env, f'transition must return an EdgeOutcome, got {type(out).__name__}')
  if jax.tree.structure(out.next_node) != jax.tree.structure(node) or any(
      a.shape != b.shape or a.dtype != b.dtype
      for a, b in zip(jax.tree.leaves(out.next_node), jax.tree.leaves(node))):
    raise _fail(env, f'transition changes the node\'s structure, shapes or dtypes: start '
                f'{_shapes(node)}, next {_shapes(out.next_node)}')
  for field, dtype in (('cost', jnp.float32), ('is_goal', jnp.bool_), ('is_valid', jnp.bool_)):
    x = getattr(out, field)
    if x.shape != () or x.dtype != dtype:
      raise _fail(env, f'transition\'s {field} must be [] {jnp.dtype(dtype).name} for one '
                  f'node, got {x.shape} {x.dtype}')
  goal = jax.eval_shape(env.goal_reached, node)
  if goal.shape != () or goal.dtype != jnp.bool_:
    raise _fail(env, f'goal_reached(node) must be [] bool, got {goal.shape} {goal.dtype}')
  resolution = jnp.asarray(env.default_lattice_resolution, jnp.float32)
  if resolution.ndim != 1 or resolution.shape[0] < 1:
    raise _fail(env, f'default_lattice_resolution must be [L] with L >= 1, got shape '
                f'{resolution.shape}')
  coords = jax.eval_shape(env.lattice_coords, node, resolution)
  if coords.shape != resolution.shape or coords.dtype != jnp.int32:
    raise _fail(env, f'lattice_coords(node, resolution [{resolution.shape[0]}]) must be '
                f'[{resolution.shape[0]}] int32, got {coords.shape} {coords.dtype}')


def _rollout_problems(env: base.Env, config: CheckConfig) -> List[str]:
  """The rules broken on a few random edges (values checked on the host)."""
  k_nodes, k_actions = jax.random.split(jax.random.PRNGKey(config.seed))
  actions = jax.random.uniform(k_actions, (config.num_steps, config.num_nodes, env.action_size),
                               jnp.float32, -1.0, 1.0)
  own_step = type(env).step is not base.Env.step  # else step is transition by construction

  def run(keys, actions):
    starts = env.initial_nodes(keys)

    def body(nodes, action):
      out = env.evaluate(nodes, action)
      seen = (nodes.t, out, env.observe(out.next_node), env.lattice_key(out.next_node),
              env.is_goal(out.next_node))
      return trees.where(out.is_valid, out.next_node, nodes), seen

    last, seen = jax.lax.scan(body, starts, actions)
    stepped = None
    if own_step:  # from the nodes after the random steps (moving, not at rest)
      zero = jnp.zeros(())
      stepped = (env.evaluate(last, actions[0]), jax.vmap(lambda n, a: env.step(
          base.State(n, env.observation(n), zero, zero, {'success': zero, 'cost': zero},
                     {'truncation': zero}), a))(last, actions[0]))
    return starts, env.observe(starts), seen, stepped

  starts, start_obs, seen, stepped = jax.jit(run)(jax.random.split(k_nodes, config.num_nodes),
                                                  actions)
  leaves = [np.asarray(x) for x in jax.tree.leaves(starts)]
  if any(np.issubdtype(x.dtype, np.inexact) and not np.isfinite(x).all() for x in leaves):
    return ['sample_instance gives non-finite start nodes']
  if not np.isfinite(np.asarray(start_obs)).all():
    return ['observation is not finite on the start nodes']
  if stepped is not None:
    first, stepped = stepped
    same_node = all(np.asarray(x).tobytes() == np.asarray(y).tobytes() for x, y in
                    zip(jax.tree.leaves(stepped.pipeline_state),
                        jax.tree.leaves(first.next_node)))
    if not (same_node and np.asarray(stepped.reward).tobytes()
            == np.asarray(-first.cost).tobytes()):
      return ['step (training) and transition (search) disagree: the trainer and the search '
              'must see one transition, bit for bit']
  t0, out, obs, cells, goal = jax.tree.map(np.asarray, seen)
  for step in range(config.num_steps):
    at = f'(step {step} of random actions)'
    cost, valid = out.cost[step], out.is_valid[step]
    if not np.isfinite(cost[valid]).all():
      return [f'edge cost is not finite on valid edges {at}']
    if (cost[valid] < 0).any():
      return [f'edge cost is negative ({cost[valid].min():.4g}) {at}: costs are -reward and '
              'must be >= 0 (shift the reward by an upper bound)']
    if not (out.next_node.t[step] == t0[step] + 1).all():
      return [f'transition must advance node.t by 1 (got {t0[step].tolist()} -> '
              f'{out.next_node.t[step].tolist()}) {at}']
    if not np.isfinite(obs[step][valid]).all():
      return [f'observation is not finite on valid next nodes {at}']
    if goal[step].tolist() != out.is_goal[step].tolist():
      return [f'goal_reached(next node) disagrees with the edge\'s is_goal {at}']
    if cells.dtype != np.int32:
      return [f'lattice_key must be int32, got {cells.dtype}']
  return []


def check_task(env: base.Env, config: CheckConfig = CheckConfig()) -> None:
  """Raises TaskError (one line) unless env follows the task protocol of docs/own_task.md.

  Checks, in order: the attributes (name, episode_length, action_size, lattice resolution);
  the shapes and dtypes of one node's functions (traced); then `config.num_steps` steps of
  random actions from `config.num_nodes` random start nodes: finite start nodes and
  observations, finite costs >= 0, t advancing by one, goal_reached agreeing with is_goal,
  and an overridden `step` (training) equal to `transition` (search) bit for bit. An env that
  wraps another simulator may define `restore_mismatches() -> list of str`: the fields where
  restoring a node and stepping differs from the simulator's own step; any raises too.
  """
  _check_static(env)
  problems = _rollout_problems(env, config)
  mismatches = getattr(env, 'restore_mismatches', None)
  if not problems and mismatches is not None:
    found = mismatches()
    if found:
      problems.append('a restored node stepped differs from the simulator\'s own step in '
                      f'{", ".join(found[:6])}: the node does not restore the simulation '
                      'exactly')
  if problems:
    raise _fail(env, problems[0])
