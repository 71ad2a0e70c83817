"""The wall-clock rule of the anytime planners: advance in jitted steps until every instance has
stopped or the next step and the result would end past the time limit; `timed_result` also times
the run and marks the instances the clock stopped."""

from __future__ import annotations

import time
from typing import Any, Callable, Dict, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np
from pachs_jax.search.result import SearchResult, StopReason



def run_until(advance: Callable[[Any], Any], state: Any, time_limit_s: Optional[float],
              start: Optional[float] = None, reserve_s: float = 0.0) -> Tuple[Any, bool]:
  """Calls state = advance(state) (a jitted chunk of a planner whose state has an [I] bool
  `active`) until no instance is active, or, with a time limit (s, counted from `start`, a
  `time.perf_counter()` value, default this call), until the next call, timed as the last one,
  followed by reserve_s would end past it; at least one call. Returns (state, any instance
  still active)."""
  start = time.perf_counter() if start is None else start
  while True:
    began = time.perf_counter()
    state = advance(state)
    active = bool(np.asarray(state.active).any())
    now = time.perf_counter()
    if (not active or time_limit_s is None
        or now - start + (now - began) + reserve_s > time_limit_s):
      return state, active


def timed_result(advance: Callable[[Any], Any], state: Any,
                 result: Callable[[Any], SearchResult], time_limit_s: Optional[float],
                 start: Optional[float] = None,
                 timing: Optional[Dict[str, float]] = None) -> SearchResult:
  """result(state) after `run_until`, with wall_time_s (s from `start`, default this call, to
  the result; programs compiled beforehand) and TIME_LIMIT for the instances still running when
  the clock stopped them. The limit covers the result too: timing['result_s'], the last
  result's time (s; updated here), is held in reserve."""
  start = time.perf_counter() if start is None else start
  timing = {} if timing is None else timing
  state, active = run_until(advance, state, time_limit_s, start, timing.get('result_s', 0.0))
  finishing = time.perf_counter()
  out = jax.block_until_ready(result(state))
  now = time.perf_counter()
  timing['result_s'] = now - finishing
  if active:
    out = out.replace(stop_reason=jnp.where(out.stop_reason == StopReason.RUNNING,
                                            StopReason.TIME_LIMIT, out.stop_reason))
  return out.replace(wall_time_s=np.float32(now - start))
