"""The layer above the search core: PACHS's programs compiled (or loaded from the store) in
threads, instances padded to buckets, the model and memory checks, and the wall-clock rule of
`plan` (docs/startup_and_caching.md)."""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
import numbers
import time
from typing import Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from pachs_jax.runtime import anytime
from pachs_jax.runtime import compile_cache
from pachs_jax.runtime import signals
from pachs_jax.envs import base
from pachs_jax.search import memory
from pachs_jax.search.checks import (check_model_outputs, check_start_nodes, conform_start_nodes,
                                     instance_keys)
from pachs_jax.search.config import SearchConfig, next_pow2
from pachs_jax.search.model import ActorCritic, output_checks
from pachs_jax.search.pachs import Search, make_search
from pachs_jax.search.result import SearchResult


@functools.partial(jax.jit, static_argnums=1)
def pad_rows(tree, size: int):
  """The pytree's leaves [n, ...] as [size, ...] (size >= n), the new rows copies of row 0:
  one compiled program for the whole tree instead of a few per leaf."""
  return jax.tree.map(
      lambda x: jnp.concatenate([x, jnp.repeat(x[:1], size - x.shape[0], axis=0)]), tree)


@functools.partial(jax.jit, static_argnums=1)
def first_rows(tree, size: int):
  """The pytree's leaves with a leading axis cut to their first `size` rows (scalars kept), as
  one compiled program."""
  return jax.tree.map(lambda x: x[:size] if jnp.ndim(x) else x, tree)


def bucket_size(num_instances: int, minimum: int = 1) -> int:
  """The padded instance count that `plan` compiles for: the next power of two, at least
  minimum (so that nearby counts share one compiled program)."""
  return max(minimum, next_pow2(num_instances))


def program_fingerprint(env: base.Env, actor_critic: ActorCritic, search: Search):
  """What the search loop closes over (env, model, config and capacities), as a string; None
  when env or model cannot say."""
  parts = (getattr(env, 'fingerprint', None), getattr(actor_critic, 'fingerprint', None))
  return None if None in parts else repr(parts + (search.config, search.capacities))


@dataclasses.dataclass
class Programs:
  """A search with its compiled programs, kept warm between `plan` calls by their owner.

  search: a `make_search` result. prefetch: a command line's `compile_cache.Prefetch` (None:
    nothing loaded ahead).
  compiled: (padded instances, platform) -> the programs of `plan` (init, result, the loops of
    the sizes reached so far, the last result's 'timing', and 'ran': the names of the init programs
    and loop layouts whose warm-up run is done).
  model_checks: padded instances -> the compiled model check.
  """

  search: Search
  prefetch: Optional[compile_cache.Prefetch] = None
  compiled: dict = dataclasses.field(default_factory=dict)
  model_checks: dict = dataclasses.field(default_factory=dict)

  @property
  def config(self) -> SearchConfig:
    return self.search.config


def check_model(env: base.Env, actor_critic: ActorCritic, start_nodes: base.NodeState,
                num_actions: int, fingerprint: Optional[str] = None,
                programs: Optional[Programs] = None) -> None:
  """ValueError when the model's outputs on the start states [I] are not finite
  (`checks.check_model_outputs`): one small program on the start nodes padded to a power of
  two, stored under fingerprint, kept in programs.model_checks when given."""
  num = jax.tree.leaves(start_nodes)[0].shape[0]
  padded = next_pow2(num)
  if padded != num:
    start_nodes = pad_rows(start_nodes, padded)
  cache = {} if programs is None else programs.model_checks
  if padded not in cache:
    cache[padded] = compile_cache.compiled_program(
        jax.jit(output_checks(env, actor_critic, num_actions)),
        (start_nodes, jax.random.PRNGKey(0)), fingerprint,
        prefetch=programs and programs.prefetch)
  outputs = cache[padded](start_nodes, jax.random.PRNGKey(0))
  check_model_outputs(env.name, *(np.asarray(x)[:num] for x in outputs))


def check_memory(env: base.Env, actor_critic: ActorCritic, start_nodes: base.NodeState,
                 config: SearchConfig, search: Optional[Search] = None,
                 padded: Optional[int] = None, need: Optional[int] = None) -> int:
  """`memory.check_fits` of the search of start_nodes [I] padded to `plan`'s bucket (padded:
  that count when known), its state (need: its bytes when known, else traced without compiling)
  and one iteration's working set: ValueError before any work when they do not fit."""
  if padded is None:
    num = jax.tree.leaves(start_nodes)[0].shape[0]
    padded = bucket_size(num, 1 if jax.default_backend() == 'cpu' else 32)
  search = make_search(env, actor_critic, config) if search is None else search
  return memory.check_fits(functools.partial(make_search, env, actor_critic,
                                             capacities=search.capacities), search,
                           start_nodes, padded, need=need,
                           working=memory.iteration_bytes(env, config, padded))


def timed(fn: Callable[..., SearchResult], *args) -> SearchResult:
  """Runs a jitted planner fn(*args) (e.g. a baseline's plan) after compiling it; sets
  wall_time_s (host seconds without compilation)."""
  compiled = fn.lower(*args).compile()
  began = time.perf_counter()
  out = jax.block_until_ready(compiled(*args))
  return out.replace(wall_time_s=jnp.float32(time.perf_counter() - began))


def _loop_name(lanes) -> str:
  """The stored name of the loop program of a `pachs.Lanes` layout."""
  return f'loop size={lanes.size}'


def _ready(programs: dict, name, waiting: Optional[dict] = None):
  """programs[name], waiting for (and then storing) one still being compiled in a thread; the
  time waited (s) is added to waiting['s'] when given."""
  if isinstance(programs[name], concurrent.futures.Future):
    began = time.perf_counter()
    programs[name] = programs[name].result()
    if waiting is not None:
      waiting['s'] += time.perf_counter() - began
  return programs[name]


class Progress(NamedTuple):
  """Where a search stands after a chunk: instances finished of all, edge evaluations done
  (finished instances counted at their full budget) of the total budget, seconds searched;
  iterations: the loop iterations run so far (the batch runs them in lockstep);
  iterations_left: the most any running instance needs to spend its budget at its own pace so
  far (evaluations per iteration; 0 when none runs)."""

  finished: int
  instances: int
  evaluations: int
  budget: int
  elapsed_s: float
  iterations: int = 0
  iterations_left: int = 0


def _wait(future: concurrent.futures.Future, stop: Optional[Callable[[], bool]]):
  """future.result(), checking stop() every 0.1 s (`signals.StoppedBeforeSearch` once it turns
  True)."""
  while True:
    if stop is not None and stop():
      raise signals.StoppedBeforeSearch('stopped while the programs compiled')
    try:
      return future.result(timeout=None if stop is None else 0.1)
    except concurrent.futures.TimeoutError:
      continue


def _in_this_threads_device() -> Callable[[Callable], Callable]:
  """wrap(fn) -> fn run under this thread's `jax.default_device` (a thread starts without the
  one its creator set: a program compiled there would be for the default device)."""
  device = jax.config.jax_default_device

  def wrap(fn):
    if device is None:
      return fn

    @functools.wraps(fn)
    def run(*args, **kwargs):
      with jax.default_device(device):
        return fn(*args, **kwargs)
    return run
  return wrap


def plan(env: base.Env, actor_critic: ActorCritic, start_nodes: base.NodeState,
         config: SearchConfig, key: jax.Array, time_limit_s: Optional[float] = None,
         chunk_iterations: Optional[int] = None, search=None,
         min_bucket: Optional[int] = None, shrink: bool = True,
         stop: Optional[Callable[[], bool]] = None,
         progress: Optional[Callable[[Progress], None]] = None,
         started: Optional[Callable[[], object]] = None,
         compile_first: bool = False, replay=None, live=None) -> SearchResult:
  """Plans from start_nodes [I]; returns the SearchResult [I] with wall_time_s set.

  key: one PRNG key (split per instance) or per-instance keys [I, 2].
  The search runs in jitted chunks (`anytime.ChunkSizes`: about 0.3 s each; chunk_iterations:
    a fixed count per chunk instead), which leave the result unchanged.
  time_limit_s: None runs to the end; otherwise chunks run (at least one) while the next chunk
    and the result, timed as their last runs, would end within the limit (s), and instances
    still searching then report TIME_LIMIT with the path to their real-time answer.
  stop: checked between chunks (and while programs compile); once True, instances still
    searching report INTERRUPTED with their real-time answer
    (`signals.StoppedBeforeSearch` when the search has not begun). started: called once when
    the search begins (after compiling; e.g. `SignalGuard.keep`). progress: called with a
    `Progress` after each chunk.
    The programs are compiled or loaded concurrently, beside the model check, and wall_time_s
    leaves them out: init, result and the loop of the live instances' lane layout before the
    clock starts; the loops of the other layouts the search can reach also before it with a
    time limit or compile_first (a benchmark's search time: no compiling beside the search),
    else beside the search (time spent waiting for one is not counted). With a time limit or
    compile_first, a call whose init program has not run yet first runs it, one iteration and
    the result once, unclocked, so that what their first run loads lazily is not on the clock.
  search: a `Programs` to reuse (its compiled programs stay warm between calls), or a
    `make_search` result (compiled for this call only); None builds one.
  min_bucket: the smallest padded instance count (None: 32 on an accelerator, where idle lanes
    cost little, 1 on the CPU); I is padded to `bucket_size(I, min_bucket)` with stopped copies.
  shrink: move to the loops of other lane layouts (`pachs.Lanes`: smaller physics batches,
    wider pops) as instances stop (each one more program to compile or load); False runs the
    whole search in the loop of the live instances' layout
    (the one-shot `pachs plan`: a shorter start-up for a longer search).
  live: [I] bool the instances to search (None: all); the others stop at once (stop reason
    'running', no path).
  replay: paths from the starts (actions [I, T, A], length [I]) that the search's first chain
    lane replays (`search.replay`; a replanning query's last answer; None: none).
  """
  if time_limit_s is not None and (isinstance(time_limit_s, bool)
                                   or not isinstance(time_limit_s, numbers.Real)
                                   or not time_limit_s > 0):
    raise ValueError(f'time_limit_s must be a number of seconds > 0 or None, got '
                     f'{time_limit_s!r}')
  for name, fn in (('stop', stop), ('progress', progress), ('started', started)):
    if fn is not None and not callable(fn):
      raise ValueError(f'{name} must be a function or None, got {fn!r}')
  if chunk_iterations is not None and not (isinstance(chunk_iterations, int)
                                           and chunk_iterations >= 1):
    raise ValueError(f'chunk_iterations must be an int >= 1 or None, got {chunk_iterations!r}')
  if search is None:
    search = make_search(env, actor_critic, config)
  if not isinstance(search, Programs):
    search = Programs(search)
  if search.config != config:
    raise ValueError('search was built with another config')
  owner, search = search, search.search
  start_nodes = conform_start_nodes(start_nodes, env)
  num_instances = check_start_nodes(start_nodes, env)
  fingerprint = program_fingerprint(env, actor_critic, search)
  stored = lambda name: fingerprint and f'{fingerprint} {name}'
  compiled_program = functools.partial(compile_cache.compiled_program, prefetch=owner.prefetch)
  keys = instance_keys(key, num_instances)
  if min_bucket is None:
    min_bucket = 1 if jax.default_backend() == 'cpu' else 32
  padded = bucket_size(num_instances, min_bucket)
  sizes = (anytime.ChunkSizes() if chunk_iterations is None
           else anytime.ChunkSizes.fixed(chunk_iterations))
  # host values placed with device_put: jnp.asarray of a host scalar compiles a program of its own
  steps = jax.device_put(np.int32(sizes.first))  # (the loops take the count traced)
  # the loops of the lane layouts this search can reach (`pachs.Lanes`)
  reachable = search.reachable(num_instances, padded)
  first, reachable = reachable[0], reachable if shrink else reachable[:1]
  shrinking = jax.device_put(np.bool_(shrink))
  programs = owner.compiled.setdefault((padded, jax.default_backend()), {})
  # every program compiled (or loaded from the store) at once, beside the model check; without
  # a time limit or compile_first the smaller loops go on beside the search
  threads = concurrent.futures.ThreadPoolExecutor(len(reachable) + 2)
  here = _in_this_threads_device()  # the helper threads compile for the caller's device
  try:
    checked = threads.submit(here(check_model), env, actor_critic, start_nodes, config.num_actions,
                             stored('model check'), owner)
    if padded != num_instances:
      start_nodes, keys, replay = pad_rows((start_nodes, keys, replay), padded)
    searched = np.arange(padded) < num_instances
    if live is not None:
      searched[:num_instances] &= np.asarray(live, bool).reshape(num_instances)
    live = jax.device_put(searched)
    init_name, init_args = (('init', (start_nodes, keys, live)) if replay is None else
                            ('init replay', (start_nodes, keys, live, replay)))
    new = init_name not in programs
    if new:
      programs[init_name] = compiled_program(search.init, init_args, stored(init_name))
      # a budget that cannot fit is refused before the result and loops compile (traced only)
      check_memory(env, actor_critic, start_nodes, config, search, padded,
                   need=memory.tree_bytes((programs[init_name].out_shapes, jax.eval_shape(
                       search.result, programs[init_name].out_shapes))))
    if 'result' not in programs:
      programs['result'] = threads.submit(here(compiled_program), search.result,
                                          (programs[init_name].out_shapes,), stored('result'))
    for lanes in reachable:
      if ('loop', lanes) not in programs:
        programs[('loop', lanes)] = threads.submit(
            here(compiled_program),
            jax.jit(lambda state, n, shrink, lanes=lanes: search.loop(state, n, lanes, shrink),
                    donate_argnums=0),
            (programs[init_name].out_shapes, steps, shrinking), stored(_loop_name(lanes)),
            donate_argnums=(0,))
    _wait(checked, stop)  # a bad model's error before anything runs
    if isinstance(programs['result'], concurrent.futures.Future):
      programs['result'] = _wait(programs['result'], stop)
    for lanes in reachable[:1] if time_limit_s is None and not compile_first else reachable:
      if isinstance(programs[('loop', lanes)], concurrent.futures.Future):
        programs[('loop', lanes)] = _wait(programs[('loop', lanes)], stop)
    if stop is not None and stop():
      raise signals.StoppedBeforeSearch('stopped while the programs compiled')
    ran = programs.setdefault('ran', set())  # the programs whose warm-up run is done
    if (time_limit_s is not None or compile_first) and not {init_name, *reachable} <= ran:
      # each program's first run loads what it runs lazily (MuJoCo Warp's kernel modules, XLA's
      # kernels): one iteration of each reachable layout's loop (not stopped by its layout's
      # floor) from a throwaway init, and a result, so that no clock counts that load
      one, stay = jax.device_put(np.int32(1)), jax.device_put(np.bool_(False))
      for lanes in reachable:  # (each from a new init: its instances active)
        warm = programs[('loop', lanes)](programs[init_name](*init_args), one, stay)
      jax.block_until_ready(programs['result'](warm))
      del warm  # (its buffers freed before the search's own state is made)
      ran.update({init_name, *reachable})
    waiting = {'s': 0.0}  # for the smaller loops during the search
    state = programs[init_name](*init_args)
    if started is not None:
      started()

    def advance(state, iterations):
      """One chunk of at most `iterations` in the loop of the live instances' layout."""
      lanes = search.lanes_for(state) if shrink else first
      count = jax.device_put(np.int32(iterations))
      return _ready(programs, ('loop', lanes), waiting)(state, count, shrinking)

    def on_chunk(state, elapsed_s):
      active = np.asarray(state.active)[:num_instances]
      done = np.asarray(state.evaluated)[:num_instances]
      iterations = np.asarray(state.iterations)[:num_instances]
      budget = config.budget
      pace = np.maximum(done / np.maximum(iterations, 1), 1.0)  # evaluations per iteration
      left = np.where(active, np.ceil(np.maximum(budget - done, 0) / pace), 0)
      progress(Progress(int(np.sum(~active)), num_instances,
                        int(np.sum(np.where(active, np.minimum(done, budget), budget))),
                        budget * num_instances, elapsed_s, int(np.max(iterations, initial=0)),
                        int(np.max(left, initial=0))))

    out = anytime.timed_result(advance, state, programs['result'], time_limit_s,
                               timing=programs.setdefault('timing', {}), stop=stop,
                               sizes=sizes, on_chunk=progress and on_chunk)
    out = out.replace(wall_time_s=out.wall_time_s - np.float32(waiting['s']))
    if stop is None or not stop():  # nothing left compiling once plan returns (a stopped
      for lanes in reachable:       # plan returns at once; the next call waits for them)
        _ready(programs, ('loop', lanes), waiting)
  except BaseException:
    for name in [name for name, p in programs.items()
                 if isinstance(p, concurrent.futures.Future)]:
      programs.pop(name).cancel()
    raise
  finally:
    threads.shutdown(wait=False)
  return first_rows(out, num_instances)
