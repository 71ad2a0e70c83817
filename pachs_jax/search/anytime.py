"""The wall-clock rule of the anytime planners: advance in jitted steps until every instance has
stopped or the next step would end past the time limit; `timed_result` also times the run and
marks the instances the clock stopped."""

from __future__ import annotations

import time
from typing import Any, Callable, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from pachs_jax.search.types import SearchResult, StopReason


def run_until(advance: Callable[[Any], Any], state: Any,
              time_limit_s: Optional[float]) -> Tuple[Any, bool]:
  """Calls state = advance(state) (a jitted chunk of a planner whose state has an [I] bool
  `active`) until no instance is active, or, with a time limit (s, from this call on), until
  the next call, timed as the last one, would end past it; at least one call. Returns (state,
  any instance still active)."""
  start = time.perf_counter()
  while True:
    began = time.perf_counter()
    state = advance(state)
    active = bool(np.asarray(state.active).any())
    now = time.perf_counter()
    if not active or time_limit_s is None or now - start + (now - began) > time_limit_s:
      return state, active


def timed_result(advance: Callable[[Any], Any], state: Any,
                 result: Callable[[Any], SearchResult],
                 time_limit_s: Optional[float]) -> SearchResult:
  """result(state) after `run_until`, with wall_time_s (s: the run and the result, compiled
  beforehand) and TIME_LIMIT for the instances still running when the clock stopped them."""
  start = time.perf_counter()
  state, active = run_until(advance, state, time_limit_s)
  out = jax.block_until_ready(result(state))
  wall = time.perf_counter() - start
  if active:
    out = out.replace(stop_reason=jnp.where(out.stop_reason == StopReason.RUNNING,
                                            StopReason.TIME_LIMIT, out.stop_reason))
  return out.replace(wall_time_s=np.float32(wall))
