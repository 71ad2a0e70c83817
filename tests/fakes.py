"""Fakes for the host-side planning tests: a clock that moves only when a fake planner works,
and a search state and SearchResult with just the fields the wall-clock rule reads."""

import dataclasses

import numpy as np

from pachs_jax.runtime import anytime


class Clock:
  """A perf_counter that only moves when the fake planner works (now: seconds)."""

  def __init__(self, start: float = 0.0):
    self.now = start

  def __call__(self):
    return self.now


def patch_clock(monkeypatch, start: float = 0.0) -> Clock:
  """A Clock from start that `anytime` reads as time.perf_counter, with
  jax.block_until_ready a no-op."""
  clock = Clock(start)
  monkeypatch.setattr(anytime.time, 'perf_counter', clock)
  monkeypatch.setattr(anytime.jax, 'block_until_ready', lambda x: x)
  return clock


@dataclasses.dataclass
class State:
  """A search state: active [I] bool and the work done (chunks or iterations)."""

  active: np.ndarray
  done: int = 0


@dataclasses.dataclass
class Result:
  """stop_reason [I] and wall_time_s, replaced as a SearchResult's are."""

  stop_reason: np.ndarray
  wall_time_s: float = float('nan')

  def replace(self, **changes):
    return dataclasses.replace(self, **changes)
