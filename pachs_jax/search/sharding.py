"""PACHS with the problem-instance axis sharded across devices.

Instances are independent, so each device runs the whole search on its own block of instances:
init, the while_loop to completion and the result all run inside one `shard_map` over a mesh
axis named 'instances', with no communication in the loop. A device stops as soon as its own
instances have finished. Per-instance keys are made on the host before sharding, so every
instance's result equals that of the unsharded `pachs.plan`.

Multi-host: after `jax.distributed.initialize()`, `jax.devices()` lists the devices of every
host, so the default mesh spans hosts. Every host calls `plan_sharded` with the same global
start nodes and key; the returned arrays are then global (not fully addressable on one host):
gather them with `jax.experimental.multihost_utils.process_allgather` before reading them.
"""

from __future__ import annotations

import functools
import inspect
import time
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from pachs_jax.envs import base
from pachs_jax.search import pachs
from pachs_jax.search.types import ActorCritic, SearchConfig, SearchResult

AXIS = 'instances'


def _shard_map(fn, mesh: Mesh, in_specs, out_specs):
  """`jax.shard_map` (jax >= 0.7) or `jax.experimental.shard_map.shard_map` (older), with the
  replication check off: the per-shard search has no collectives, and its inner loops start
  from constants that the check would demand be cast to 'varying'."""
  if hasattr(jax, 'shard_map'):
    shard_map, check = jax.shard_map, 'check_vma'
  else:
    from jax.experimental.shard_map import shard_map  # pylint: disable=g-import-not-at-top
    check = 'check_rep'
  if check not in inspect.signature(shard_map).parameters:
    check = 'check_rep' if check == 'check_vma' else 'check_vma'
  return shard_map(fn, mesh=mesh, in_specs=in_specs, out_specs=out_specs, **{check: False})


def instance_mesh(devices=None) -> Mesh:
  """A one-axis mesh named 'instances' over devices (default: all of `jax.devices()`)."""
  devices = jax.devices() if devices is None else list(devices)
  if not devices:
    raise ValueError('instance_mesh needs at least one device')
  return Mesh(np.asarray(devices), (AXIS,))


def _pad(tree, num: int):
  """Pads every leaf's leading axis to num rows by repeating the last row."""
  def pad(x):
    extra = num - x.shape[0]
    if extra == 0:
      return x
    return jnp.concatenate([x, jnp.repeat(x[-1:], extra, axis=0)], axis=0)
  return jax.tree.map(pad, tree)


def make_sharded_search(search: pachs.Search, mesh: Mesh):
  """The jitted sharded search: (start_nodes [P], keys [P, 2]) -> SearchResult [P], P a multiple
  of the mesh size, wall_time_s [P] NaN (every leaf keeps the leading instance axis)."""
  def per_shard(start_nodes, keys):
    state = search.run(search.init(start_nodes, keys))
    out = search.result(state)
    local = keys.shape[0]
    return out.replace(wall_time_s=jnp.full((local,), jnp.nan, jnp.float32))

  spec = PartitionSpec(AXIS)
  return jax.jit(_shard_map(per_shard, mesh, (spec, spec), spec))


@functools.lru_cache(maxsize=32)
def _cached_sharded(search: pachs.Search, mesh: Mesh):
  return make_sharded_search(search, mesh)


def plan_sharded(env: base.Env, actor_critic: ActorCritic, start_nodes: base.NodeState,
                 config: SearchConfig, key: jax.Array, mesh: Optional[Mesh] = None,
                 search: Optional[pachs.Search] = None) -> SearchResult:
  """Plans from start_nodes [I] with the instances split over mesh; returns SearchResult [I].

  key: one PRNG key (split per instance, as in `pachs.plan`) or per-instance keys [I, 2].
  mesh: a `jax.sharding.Mesh` with the single axis 'instances' (default: all `jax.devices()`).
    I need not divide the device count: the last instance is repeated up to a multiple of it,
    and the extra rows are dropped from the result.
  search: a `make_search` result to reuse; built here when None.
  Runs every instance to completion (no time limit; use `pachs.plan` for anytime chunks).
  wall_time_s: host seconds of the call without compilation and input transfer.
  """
  if mesh is None:
    mesh = instance_mesh()
  if not isinstance(mesh, Mesh):
    raise ValueError(f'mesh must be a jax.sharding.Mesh, got {type(mesh).__name__}')
  if tuple(mesh.axis_names) != (AXIS,):
    raise ValueError(f"mesh must have the single axis '{AXIS}', got axes {mesh.axis_names}")
  if search is None:
    search = pachs.make_search(env, actor_critic, config)
  elif search.config != config:
    raise ValueError('search was built with another config')
  num_instances = pachs._check_start(  # pylint: disable=protected-access
      start_nodes, jax.eval_shape(env.sample_instance, jax.random.PRNGKey(0)))
  keys = pachs._raw_keys(  # pylint: disable=protected-access
      pachs.instance_keys(key, num_instances), num_instances)

  devices = mesh.devices.size
  padded = -(-num_instances // devices) * devices
  sharding = NamedSharding(mesh, PartitionSpec(AXIS))
  start_nodes = jax.device_put(_pad(start_nodes, padded), sharding)
  keys = jax.device_put(_pad(keys, padded), sharding)
  run = _cached_sharded(search, mesh).lower(start_nodes, keys).compile()

  start = time.perf_counter()
  out = jax.block_until_ready(run(start_nodes, keys))
  wall = time.perf_counter() - start
  out = jax.tree.map(lambda x: x[:num_instances], out)
  return out.replace(wall_time_s=jnp.float32(wall))
