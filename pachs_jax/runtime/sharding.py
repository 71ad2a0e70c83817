"""Planners with the problem-instance axis sharded across devices and hosts (docs/sharding.md)."""

from __future__ import annotations

import functools
import inspect
import os
import time
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from pachs_jax.envs import base
from pachs_jax.runtime import anytime
from pachs_jax.runtime.programs import check_model
from pachs_jax.search import memory, pachs
from pachs_jax.search.checks import check_start_nodes, instance_keys
from pachs_jax.search.config import SearchConfig
from pachs_jax.search.model import ActorCritic
from pachs_jax.search.result import SearchResult

AXIS = 'instances'

# fn(start_nodes [P], keys [P, 2] uint32) -> SearchResult [P]: one device's planner.
ShardFn = Callable[[base.NodeState, jax.Array], SearchResult]


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


# ---- devices and hosts ----

def initialize_multihost(**kwargs) -> bool:
  """Joins a multi-process JAX job when the environment describes one; True if it did.

  Call it on every host before any other JAX call. It calls `jax.distributed.initialize`
  - with JAX_COORDINATOR_ADDRESS ('host:port' of process 0), JAX_NUM_PROCESSES and
    JAX_PROCESS_ID when JAX_COORDINATOR_ADDRESS is set (the two others may be left to JAX's
    cluster detection);
  - with JAX's own cluster detection under SLURM (SLURM_NTASKS > 1) or Open MPI's mpirun
    (OMPI_COMM_WORLD_SIZE > 1).
  Otherwise, or when already initialized, it does nothing. kwargs go to
  `jax.distributed.initialize` (e.g. local_device_ids).
  """
  if jax.distributed.is_initialized():
    return False
  env = os.environ

  def count(name):
    try:
      return int(env.get(name, '1'))
    except ValueError:
      return 1

  if env.get('JAX_COORDINATOR_ADDRESS'):
    for arg, name in (('num_processes', 'JAX_NUM_PROCESSES'), ('process_id', 'JAX_PROCESS_ID')):
      if env.get(name) and arg not in kwargs:
        try:
          kwargs[arg] = int(env[name])
        except ValueError:
          raise ValueError(f'{name} must be an integer, got {env[name]!r}') from None
    kwargs.setdefault('coordinator_address', env['JAX_COORDINATOR_ADDRESS'])
  elif not ((count('SLURM_NTASKS') > 1 and 'SLURM_PROCID' in env)
            or (count('OMPI_COMM_WORLD_SIZE') > 1 and 'OMPI_MCA_orte_hnp_uri' in env)):
    return False
  jax.distributed.initialize(**kwargs)
  return True


def instance_mesh(devices=None) -> Mesh:
  """A one-axis mesh named 'instances' over devices (default: all of `jax.devices()`)."""
  devices = jax.devices() if devices is None else list(devices)
  if not devices:
    raise ValueError('instance_mesh needs at least one device')
  return Mesh(np.asarray(devices), (AXIS,))


def check_mesh(mesh: Optional[Mesh]) -> Mesh:
  """mesh (default: `instance_mesh()`), checked to be a Mesh with the single axis 'instances'."""
  if mesh is None:
    return instance_mesh()
  if not isinstance(mesh, Mesh):
    raise ValueError(f'mesh must be a jax.sharding.Mesh, got {type(mesh).__name__}')
  if tuple(mesh.axis_names) != (AXIS,):
    raise ValueError(f"mesh must have the single axis '{AXIS}', got axes {mesh.axis_names}")
  return mesh


def to_host(tree):
  """tree's arrays whole on every host: `process_allgather` of the global arrays when there are
  several processes (numpy arrays then), the tree unchanged with one."""
  if jax.process_count() > 1:
    return multihost_utils.process_allgather(tree, tiled=True)
  return tree


# ---- the generic sharded planner ----

def _pad(tree, num: int):
  """Pads every leaf's leading axis to num rows by repeating the last row."""
  def pad(x):
    extra = num - x.shape[0]
    if extra == 0:
      return x
    return jnp.concatenate([x, jnp.repeat(x[-1:], extra, axis=0)], axis=0)
  return jax.tree.map(pad, tree)


def _num_instances(start_nodes) -> int:
  sizes = {jnp.shape(x)[0] if jnp.ndim(x) else 0 for x in jax.tree.leaves(start_nodes)}
  if len(sizes) != 1 or 0 in sizes:
    raise ValueError(f'start_nodes leaves must share one leading axis I >= 1, got {sizes}')
  return sizes.pop()


def _put_global(x, sharding: NamedSharding) -> jax.Array:
  """The global array of host value x (the same on every host) split by sharding."""
  host = np.asarray(x)
  return jax.make_array_from_callback(host.shape, sharding, lambda index: host[index])


@functools.lru_cache(maxsize=32)
def keyless(fn: Callable[[base.NodeState], SearchResult]) -> ShardFn:
  """A per-shard fn(start_nodes, keys) of a planner without keys (ePA*SE, single rollout)."""
  def run(start_nodes, keys):
    del keys
    return fn(start_nodes)
  return run


@functools.lru_cache(maxsize=32)
def shard_planner(fn: ShardFn, mesh: Mesh):
  """The jitted sharded planner: (start_nodes [P], keys [P, 2]) -> SearchResult [P], P a
  multiple of the mesh size, each device running fn on its P / devices rows; wall_time_s [P]
  NaN (every leaf keeps the leading instance axis). Cached per (fn, mesh)."""
  def per_shard(start_nodes, keys):
    out = fn(start_nodes, keys)
    return out.replace(wall_time_s=jnp.full((keys.shape[0],), jnp.nan, jnp.float32))

  spec = PartitionSpec(AXIS)
  return jax.jit(_shard_map(per_shard, mesh, (spec, spec), spec))


def plan_sharded_fn(fn: ShardFn, start_nodes: base.NodeState, key: jax.Array,
                    mesh: Optional[Mesh] = None) -> SearchResult:
  """Runs the per-shard planner fn on start_nodes [I] split over mesh; SearchResult [I].

  fn(start_nodes [P], keys [P, 2] uint32) -> SearchResult [P]: pure and jittable, each
    instance's result depending only on its own row (see the module docstring).
  key: one PRNG key (split per instance, as the planners do) or per-instance keys [I, 2] / [I].
  mesh: a `jax.sharding.Mesh` with the single axis 'instances' (default: all `jax.devices()`).
    I need not divide the device count: the last instance is repeated up to a multiple of it,
    and the extra rows are dropped from the result.
  Returns the whole result on every host; wall_time_s: host seconds of the planning call
  (compilation, input transfer and the gather across hosts excluded).
  """
  mesh = check_mesh(mesh)
  num_instances = _num_instances(start_nodes)
  keys = instance_keys(key, num_instances)
  devices = mesh.devices.size
  padded = -(-num_instances // devices) * devices
  sharding = NamedSharding(mesh, PartitionSpec(AXIS))
  start_nodes = jax.tree.map(lambda x: _put_global(x, sharding), _pad(start_nodes, padded))
  keys = _put_global(_pad(keys, padded), sharding)
  run = shard_planner(fn, mesh).lower(start_nodes, keys).compile()

  start = time.perf_counter()
  out = jax.block_until_ready(run(start_nodes, keys))
  wall = time.perf_counter() - start
  out = jax.tree.map(lambda x: x[:num_instances], to_host(out))
  return out.replace(wall_time_s=jnp.float32(wall))


# ---- PACHS ----

@functools.lru_cache(maxsize=32)
def pachs_shard_fn(search: pachs.Search) -> ShardFn:
  """PACHS as a per-shard planner: init, the loop to completion and the result."""
  def run(start_nodes, keys):
    return search.result(search.run(search.init(start_nodes, keys)))
  return run


@functools.lru_cache(maxsize=32)
def pachs_shard_programs(search: pachs.Search, mesh: Mesh):
  """PACHS's jitted programs sharded over mesh, for a search in chunks: init(start_nodes [P],
  keys [P, 2], replay) -> state, replay None or the paths its first chain lanes replay
  ((actions [P, T, A], length [P]), `search.replay`); loop(state, iterations) -> state after at
  most that many more iterations (every lane simulated; state donated); result(state) ->
  SearchResult [P] (its wall_time_s [P] NaN). Cached per (search, mesh)."""
  spec = PartitionSpec(AXIS)
  init = jax.jit(_shard_map(lambda nodes, keys, replay: search.init(nodes, keys, None, replay),
                            mesh, (spec, spec, spec), spec))
  loop = jax.jit(_shard_map(lambda state, count: search.loop(state, count, None, False), mesh,
                            (spec, PartitionSpec()), spec), donate_argnums=0)

  def result(state):
    out = search.result(state)
    return out.replace(wall_time_s=jnp.full(state.active.shape, jnp.nan, jnp.float32))

  return init, loop, jax.jit(_shard_map(result, mesh, (spec,), spec))


class ShardedSearch:
  """PACHS over a mesh's devices for repeated calls (a server's queries): each padded instance
  count's programs are compiled on first use and kept.

  search: a `make_search` result; mesh: as in `plan_sharded` (one host).
  """

  def __init__(self, search: pachs.Search, mesh: Optional[Mesh] = None):
    self.search, self.mesh = search, check_mesh(mesh)
    self._compiled = {}  # padded instances -> (init, loop, result)
    self.timing = {}  # the last result's time, held in reserve under a time limit

  def padded(self, num_instances: int, min_bucket: Optional[int] = None) -> int:
    """The instance count a call of num_instances runs: at least min_bucket, a multiple of the
    device count."""
    devices = self.mesh.devices.size
    return -(-max(num_instances, min_bucket or 0) // devices) * devices

  def plan(self, start_nodes: base.NodeState, key: jax.Array,
           time_limit_s: Optional[float] = None, stop: Optional[Callable[[], bool]] = None,
           started: Optional[Callable[[], object]] = None,
           min_bucket: Optional[int] = None, replay=None) -> SearchResult:
    """SearchResult [I] from start_nodes [I] in jitted chunks (`anytime.ChunkSizes`); wall_time_s
    leaves compiling out. time_limit_s: the instances still searching when it would pass report
    TIME_LIMIT; stop: checked between chunks (INTERRUPTED); started: called as the chunks
    begin; key: one PRNG key or per-instance keys [I, 2]; replay: paths from the starts
    (actions [I, T, A], length [I]) that the first chain lanes replay (a search built with
    room for them, `Capacities.replay`; None: none)."""
    num_instances = _num_instances(start_nodes)
    keys = instance_keys(key, num_instances)
    padded = self.padded(num_instances, min_bucket)
    sharding = NamedSharding(self.mesh, PartitionSpec(AXIS))
    start_nodes = jax.tree.map(lambda x: _put_global(x, sharding), _pad(start_nodes, padded))
    keys = _put_global(_pad(keys, padded), sharding)
    if replay is not None:
      replay = jax.tree.map(lambda x: _put_global(x, sharding),
                            _pad(tuple(jnp.asarray(x) for x in replay), padded))
    compiled_key = (padded, None if replay is None else replay[0].shape[1:])
    if compiled_key not in self._compiled:
      init_jit, loop_jit, result_jit = pachs_shard_programs(self.search, self.mesh)
      shape = jax.eval_shape(init_jit, start_nodes, keys, replay)
      self._compiled[compiled_key] = (
          init_jit.lower(start_nodes, keys, replay).compile(),
          loop_jit.lower(shape, jax.device_put(np.int32(1))).compile(),
          result_jit.lower(shape).compile())
    init, loop, result = self._compiled[compiled_key]
    begin = time.perf_counter()
    state = init(start_nodes, keys, replay)
    if started is not None:
      started()
    out = anytime.timed_result(lambda s, n: loop(s, jax.device_put(np.int32(n))), state, result,
                               time_limit_s, start=begin, timing=self.timing, stop=stop,
                               sizes=anytime.ChunkSizes())
    wall = time.perf_counter() - begin
    out = jax.tree.map(lambda x: x[:num_instances], out.replace(wall_time_s=None))
    return out.replace(wall_time_s=jnp.float32(wall))


def plan_sharded(env: base.Env, actor_critic: ActorCritic, start_nodes: base.NodeState,
                 config: SearchConfig, key: jax.Array, mesh: Optional[Mesh] = None,
                 search: Optional[pachs.Search] = None,
                 stop: Optional[Callable[[], bool]] = None,
                 started: Optional[Callable[[], object]] = None) -> SearchResult:
  """Plans from start_nodes [I] with the instances split over mesh; returns SearchResult [I].

  key: one PRNG key (split per instance, as in `programs.plan`) or per-instance keys [I, 2].
  mesh: a `jax.sharding.Mesh` with the single axis 'instances' (default: all `jax.devices()`).
  search: a `make_search` result to reuse; built here when None.
  Runs every instance to completion (no time limit; use `programs.plan` for anytime chunks).
  stop (one host): the search runs in chunks and stop() is checked between them; once True,
  the instances still searching report INTERRUPTED with their real-time answer. started:
  called once the programs are compiled and the chunks begin (one host with stop only).
  See `plan_sharded_fn` for padding, the result across hosts and wall_time_s.
  """
  mesh = check_mesh(mesh)
  if search is None:
    search = pachs.make_search(env, actor_critic, config)
  elif search.config != config:
    raise ValueError('search was built with another config')
  num_instances = check_start_nodes(start_nodes, env)
  check_model(env, actor_critic, start_nodes, config.num_actions)
  memory.check_fits(functools.partial(pachs.make_search, env, actor_critic,
                                      capacities=search.capacities), search,
                    start_nodes, -(-num_instances // mesh.devices.size),
                    device=mesh.local_devices[0])
  if stop is not None and jax.process_count() == 1:
    return ShardedSearch(search, mesh).plan(start_nodes, key, stop=stop, started=started)
  return plan_sharded_fn(pachs_shard_fn(search), start_nodes, key, mesh)
