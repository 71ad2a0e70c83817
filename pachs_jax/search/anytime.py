"""The wall-clock rule of the anytime planners: advance in jitted steps until every instance has
stopped or the next step would end past the time limit."""

from __future__ import annotations

import time
from typing import Any, Callable, Optional, Tuple

import jax.numpy as jnp


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
    active = bool(jnp.any(state.active))
    now = time.perf_counter()
    if not active or time_limit_s is None or now - start + (now - began) > time_limit_s:
      return state, active
