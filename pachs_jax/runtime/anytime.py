"""The host loop of the planners: advance in jitted chunks (sized to a fraction of a second)
until every instance has stopped, the next chunk and the result would end past the time limit,
or the caller asks to stop; `timed_result` also times the run and marks the instances the clock
or the request stopped."""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import math
import threading
import time
from typing import Any, Callable, Dict, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np
from pachs_jax.search.result import SearchResult, StopReason


@dataclasses.dataclass(frozen=True)
class ChunkSizes:
  """How many loop iterations each jitted chunk runs: `first`, then as many as took about
  `target_s` seconds at the last chunk's pace, at most `growth` times the last count and at most
  `most` (a traced count: no chunk size compiles anew)."""

  first: int = 2
  target_s: float = 0.3
  growth: float = 4.0
  most: int = 2**30

  @classmethod
  def fixed(cls, iterations: int) -> 'ChunkSizes':
    """Every chunk runs `iterations`."""
    return cls(first=iterations, target_s=math.inf, growth=1.0, most=iterations)

  def next(self, iterations: int, took_s: float) -> int:
    """The next chunk's iterations after one of `iterations` that took took_s seconds."""
    wanted = min(self.target_s * iterations / max(took_s, 1e-9), iterations * self.growth,
                 self.most)
    return max(1, int(round(wanted)))


class Run(NamedTuple):
  """What `run_until` ended with: the state, whether any instance is still active, and whether
  the caller's `stop` ended it."""

  state: Any
  active: bool
  stopped: bool


def run_until(advance: Callable[..., Any], state: Any, time_limit_s: Optional[float],
              start: Optional[float] = None, reserve_s: float = 0.0,
              stop: Optional[Callable[[], bool]] = None, sizes: Optional[ChunkSizes] = None,
              on_chunk: Optional[Callable[[Any, float], None]] = None) -> Run:
  """Calls state = advance(state) (a jitted chunk of a planner whose state has an [I] bool
  `active`; with `sizes`, advance(state, iterations)) until no instance is active, `stop()`
  turns True (checked before each chunk), or, with a time limit (s, counted from `start`, a
  `time.perf_counter()` value, default this call), until the next chunk, at the last one's
  pace, followed by reserve_s would end past it (then at least one chunk runs; with `sizes` the
  last chunk is cut to what fits). on_chunk(state, seconds since start) follows each chunk."""
  start = time.perf_counter() if start is None else start
  iterations = None if sizes is None else sizes.first
  while True:
    if stop is not None and stop():
      return Run(state, bool(np.asarray(state.active).any()), True)
    began = time.perf_counter()
    state = advance(state) if sizes is None else advance(state, iterations)
    active = bool(np.asarray(state.active).any())
    now = time.perf_counter()
    if on_chunk is not None:
      on_chunk(state, now - start)
    if not active:
      return Run(state, False, False)
    took = now - began
    left = math.inf if time_limit_s is None else time_limit_s - (now - start) - reserve_s
    if sizes is None:
      if took > left:
        return Run(state, True, False)
      continue
    upcoming = sizes.next(iterations, took)
    if left < math.inf:
      upcoming = int(min(upcoming, left * iterations / max(took, 1e-9)))  # (left may be huge)
      if upcoming < 1:
        return Run(state, True, False)
    iterations = upcoming


class CollectorPause:
  """A context in which Python's cyclic garbage collector is paused, for the clocked loops of
  all threads together (the last one out resumes it, unless it was off before the first came
  in). A full collection walks every object of the process, about a million once the programs
  are compiled: 0.4-0.65 s on a CPU core, a stall that takes most of a 1 s query's iterations;
  it runs after the clock instead."""

  def __init__(self):
    self._lock = threading.Lock()
    self._inside = 0  # the loops in the context now
    self._resume = False  # whether the collector was on when the first came in

  @contextlib.contextmanager
  def __call__(self):
    with self._lock:
      if not self._inside:
        self._resume = gc.isenabled()
        gc.disable()
      self._inside += 1
    try:
      yield
    finally:
      with self._lock:
        self._inside -= 1
        if not self._inside and self._resume:
          gc.enable()


collector_paused = CollectorPause()  # (one collector per process)


def timed_result(advance: Callable[..., Any], state: Any,
                 result: Callable[[Any], SearchResult], time_limit_s: Optional[float],
                 start: Optional[float] = None,
                 timing: Optional[Dict[str, float]] = None,
                 stop: Optional[Callable[[], bool]] = None, sizes: Optional[ChunkSizes] = None,
                 on_chunk: Optional[Callable[[Any, float], None]] = None) -> SearchResult:
  """result(state) after `run_until` (advance, stop, sizes and on_chunk as there), with
  wall_time_s (s from `start`, default this call, to the result; programs compiled beforehand),
  TIME_LIMIT for the instances still running when the clock stopped them and INTERRUPTED for
  those still running when `stop` did. The limit covers the result too: timing['result_s'], the
  last result's time (s; updated here), is held in reserve. With a limit, the garbage
  collector waits until the result is out (`collector_paused`)."""
  start = time.perf_counter() if start is None else start
  timing = {} if timing is None else timing
  with collector_paused() if time_limit_s is not None else contextlib.nullcontext():
    state, active, stopped = run_until(advance, state, time_limit_s, start,
                                       timing.get('result_s', 0.0), stop, sizes, on_chunk)
    finishing = time.perf_counter()
    out = jax.block_until_ready(result(state))
    now = time.perf_counter()
  timing['result_s'] = now - finishing
  if active:
    reason = StopReason.INTERRUPTED if stopped else StopReason.TIME_LIMIT
    out = out.replace(stop_reason=jnp.where(out.stop_reason == StopReason.RUNNING, reason,
                                            out.stop_reason))
  return out.replace(wall_time_s=np.float32(now - start))


def run_search(search: Any, start_nodes: Any, key: jax.Array, *init_args,
               time_limit_s: Optional[float] = None,
               timing: Optional[Dict[str, float]] = None,
               compiled: Optional[Dict[Any, Any]] = None) -> SearchResult:
  """The SearchResult [I] of a search given as jitted `init(start_nodes [I], key, *init_args)`,
  `step`, `run` and `result` (e.g. `search.baselines.Mppi`). time_limit_s None: `run` to the
  end in one call; otherwise one `step` per host step while the next one and the result, timed
  as their last runs (`timing`, see `timed_result`), would end within the limit (at least one);
  instances still running then report TIME_LIMIT. Compiled before the clock starts; compiled:
  a dict the caller keeps between calls, where the programs of each input shape are compiled
  once and, with a time limit, run once before their first clock (what a first run loads
  lazily, e.g. MuJoCo Warp's kernel modules, is on no clock)."""
  if time_limit_s is not None and not time_limit_s > 0:
    raise ValueError(f'time_limit_s must be > 0 or None, got {time_limit_s!r}')
  args = (start_nodes, key, *init_args)
  signature = (id(search), time_limit_s is None, jax.tree.structure(args),
               tuple((jnp.shape(x), jnp.result_type(x)) for x in jax.tree.leaves(args)))
  programs = {} if compiled is None else compiled
  if signature not in programs:
    shape = jax.eval_shape(search.init, *args)
    init = search.init.lower(*args).compile()
    loop = (search.run if time_limit_s is None else search.step).lower(shape).compile()
    result = search.result.lower(shape).compile()
    if compiled is not None and time_limit_s is not None:
      jax.block_until_ready(result(loop(init(*args))))
    programs[signature] = init, loop, result
  init, loop, result = programs[signature]
  return timed_result(loop, init(*args), result, time_limit_s, timing=timing)
