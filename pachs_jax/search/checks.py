"""Checks of the search's inputs against the environment and the model, each a one-line
ValueError before any work starts, and the per-instance PRNG keys."""

from __future__ import annotations

import dataclasses
import math
import numbers

import jax
import jax.numpy as jnp
import numpy as np

from pachs_jax.envs import base


def check_seconds(value, name: str) -> None:
  """ValueError naming `name` unless value is None or a finite number of seconds > 0."""
  if value is not None and (isinstance(value, bool) or not isinstance(value, numbers.Real)
                            or not math.isfinite(value) or value <= 0):
    raise ValueError(f'{name} must be a number of seconds > 0 or None, got {value!r}')


def check_actor_critic(actor_critic, names) -> None:
  """ValueError unless actor_critic has each of the named methods."""
  for name in names:
    if not callable(getattr(actor_critic, name, None)):
      raise ValueError(f'actor_critic has no method {name}(...) (see search.model.ActorCritic)')


# Lattice coordinates are int32; a cell size is allowed when the coordinates of the env's
# states stay within +-2**30 (half the int32 range, a margin for float32 rounding).
LATTICE_COORD_LIMIT = 2.0**30


def _ceil_2(x: float) -> float:
  """x rounded up to 2 significant digits (so that the printed bound is itself allowed)."""
  if x <= 0:
    return 0.0
  scale = 10.0**(math.floor(math.log10(x)) - 1)
  return math.ceil(x / scale * (1 - 1e-12)) * scale


def _format_sizes(values) -> str:
  return '(' + ', '.join(f'{v:.2g}' for v in values) + ')'


def min_lattice_resolution(env: base.Env):
  """[L] float64 smallest cell sizes that keep env's int32 lattice coordinates from
  overflowing (`Env.lattice_extent` / 2**30), or None when the env does not bound them."""
  extent = getattr(env, 'lattice_extent', None)
  if extent is None:
    return None
  return np.abs(np.asarray(extent, np.float64)) / LATTICE_COORD_LIMIT


def env_lattice_resolution(env: base.Env, resolution) -> jax.Array:
  """[L] float32 cell sizes: `resolution`, or the env's default when None.

  ValueError when its length differs from the env's, or when a cell is so small that the
  int32 lattice coordinates of the env's states overflow (they saturate, and every state falls
  into one cell); the message names the smallest allowed size per coordinate.
  """
  default = np.asarray(env.default_lattice_resolution, np.float32)
  if resolution is None:
    return jax.device_put(default)
  given = _format_sizes(np.asarray(resolution, np.float64).ravel())
  resolution = np.asarray(resolution, np.float32)
  if resolution.shape != default.shape:
    raise ValueError(f'lattice_resolution has {resolution.shape[0]} entries, but the '
                     f'environment {env.name} uses {default.shape[0]}')
  res = np.asarray(resolution, np.float64)
  smallest = min_lattice_resolution(env)
  if smallest is not None and np.shape(smallest) != res.shape:
    raise ValueError(f'{type(env).__name__}.lattice_extent has shape {np.shape(smallest)}, but '
                     f'its lattice coordinates have {res.shape}')
  allowed = np.array([_ceil_2(float(x)) for x in smallest]) if smallest is not None else None
  too_fine = ~(res > 0) | ~np.isfinite(res)
  if smallest is not None:
    too_fine |= res < smallest
  if too_fine.any():
    bad = [int(i) for i in np.flatnonzero(too_fine)]
    if allowed is None:
      raise ValueError(f'lattice_resolution {given} of {env.name}: cells {bad} become 0 or inf '
                       'in float32')
    raise ValueError(f'lattice_resolution {given} overflows the int32 lattice coordinates of '
                     f'{env.name} (coordinate{"s" * (len(bad) > 1)} {", ".join(map(str, bad))}): '
                     f'cell sizes must be at least {_format_sizes(allowed)}')
  return jax.device_put(resolution)


def check_start_nodes(start_nodes: base.NodeState, env: base.Env) -> int:
  """The number of instances I of start_nodes [I, ...]; ValueError when the shapes do not fit
  env's NodeState."""
  spec = env.node_spec
  leaves, spec_leaves = jax.tree.leaves(start_nodes), jax.tree.leaves(spec)
  if (jax.tree.structure(start_nodes) != jax.tree.structure(spec)
      or any(jnp.ndim(x) != len(s.shape) + 1 or jnp.shape(x)[1:] != s.shape
             for x, s in zip(leaves, spec_leaves))):
    want = jax.tree.map(lambda s: ('I',) + s.shape, spec)
    got = jax.tree.map(jnp.shape, start_nodes)
    raise ValueError(f'start_nodes must be the environment\'s NodeState with a leading '
                     f'instance axis: want shapes {want}, got {got}')
  sizes = {jnp.shape(x)[0] for x in leaves}
  if len(sizes) != 1 or 0 in sizes:
    raise ValueError(f'start_nodes leaves must share one leading axis I >= 1, got {sizes}')
  check_finite_start_nodes(start_nodes)
  return sizes.pop()


def conform_start_nodes(start_nodes: base.NodeState, env: base.Env) -> base.NodeState:
  """start_nodes with each field cast to the dtype of env's NodeState where that keeps its
  kind (int32 qpos -> float32, float64 -> float32); ValueError naming the field and both
  dtypes otherwise (e.g. float t). Fields of the right dtype are returned as given."""
  spec = env.node_spec
  if not dataclasses.is_dataclass(start_nodes) or type(start_nodes) is not type(spec):
    return start_nodes  # check_start_nodes names the mismatch
  changes = {}
  for field in dataclasses.fields(spec):
    want, x = getattr(spec, field.name), getattr(start_nodes, field.name)
    if not hasattr(want, 'dtype') or not hasattr(x, 'dtype'):
      continue  # a field that is itself a pytree (a Playground env's info): left as given
    want, have = np.dtype(want.dtype), np.dtype(x.dtype)
    if have == want:
      continue
    safe = (np.can_cast(have, want, 'same_kind')
            or (np.issubdtype(have, np.integer) and np.issubdtype(want, np.floating)))
    if not safe:
      raise ValueError(f'start_nodes.{field.name} has dtype {have}, but the environment '
                       f'{env.name} uses {want}: give {want} values')
    changes[field.name] = jnp.asarray(x).astype(want)
  return start_nodes.replace(**changes) if changes else start_nodes


# The largest magnitude a start state's positions, controls and goal (m, rad) and velocities
# (m/s, rad/s) may have: far beyond any task's workspace and any robot's speed; larger values
# are no physical state (velocities of 1e5 and more overflow MuJoCo's accelerations).
START_STATE_LIMITS = {'qpos': 1e6, 'ctrl': 1e6, 'goal': 1e6, 'qvel': 1e3}


def check_finite_start_nodes(start_nodes: base.NodeState) -> None:
  """ValueError naming the instances whose start state or goal holds a NaN or inf, or whose
  qpos, qvel, ctrl or goal exceed `START_STATE_LIMITS` in magnitude (host-side; does nothing
  for traced or non-addressable arrays, e.g. under jit)."""
  fields = [(f.name, getattr(start_nodes, f.name)) for f in dataclasses.fields(start_nodes)]
  if any(isinstance(x, jax.core.Tracer) or not getattr(x, 'is_fully_addressable', True)
         for _, x in fields):
    return
  bad, names = None, []
  for name, x in fields:
    x = np.asarray(x)
    if not np.issubdtype(x.dtype, np.inexact):
      continue
    ok = np.isfinite(x.reshape(x.shape[0], -1)).all(axis=1)
    if not ok.all():
      names.append(name)
      bad = ~ok if bad is None else bad | ~ok
  if names:
    index = np.flatnonzero(bad).tolist()
    raise ValueError(f'start_nodes of instance{"s" * (len(index) > 1)} {_list(index)} are not '
                     f'finite (NaN or inf in {", ".join(names)}): the search needs finite start '
                     'states and goals')
  for name, x in fields:
    x = np.asarray(x)
    if name not in START_STATE_LIMITS or not np.issubdtype(x.dtype, np.number):
      continue
    limit = START_STATE_LIMITS[name]
    over = (np.abs(x.reshape(x.shape[0], -1)) > limit).any(axis=1)
    if over.any():
      index = np.flatnonzero(over).tolist()
      raise ValueError(f'start_nodes.{name} of instance{"s" * (len(index) > 1)} '
                       f'{_list(index)} exceeds {limit:.0e} in magnitude: no physical start '
                       'state (positions in m or rad, velocities per second)')


def _list(index, most: int = 10) -> str:
  """'[0, 3, 7]', or the first `most` and a count."""
  if len(index) <= most:
    return str(list(index))
  return f'[{", ".join(map(str, index[:most]))}, ...] ({len(index)} in all)'


def instance_keys(key: jax.Array, num_instances: int) -> jax.Array:
  """[I, 2] uint32 per-instance keys: one key ([2] raw or [] typed) is split, per-instance keys
  ([I, 2] raw or [I] typed) are kept; ValueError for other shapes."""
  key = jnp.asarray(key)
  if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
    key = jax.random.key_data(key)
  if key.shape == (2,):
    key = jax.random.split(key, num_instances)
  if key.shape != (num_instances, 2):
    raise ValueError(f'key must be one PRNG key or [I, 2] keys with I = {num_instances}, '
                     f'got shape {key.shape}')
  return key.astype(jnp.uint32)


def check_model_outputs(env_name: str, obs_ok, actions_ok, q_ok) -> None:
  """ValueError when the actor-critic's sampled actions or critic Q on the start states are
  not finite (a damaged model, or one of another task: the search would drop every edge and
  report OPEN empty), or the observations are not; arguments: [I] bool host arrays of
  `model.output_checks`."""
  for ok, what in ((obs_ok, f'{env_name} gives non-finite observations of the start states'),
                   (actions_ok, 'actor-critic samples non-finite actions on the start states'),
                   (q_ok, 'actor-critic returns non-finite Q on the start states')):
    if not np.all(ok):
      index = np.flatnonzero(~np.asarray(ok)).tolist()
      cause = ('the start states lie outside the task' if ok is obs_ok else
               'the model is damaged or does not fit the task')
      raise ValueError(f'{what} (instance{"s" * (len(index) > 1)} {_list(index)}): {cause}')
