"""A one-line progress report of a running search on a stream (stderr): rewritten in place on a
terminal, printed now and then elsewhere (a log keeps a few lines, stdout stays clean)."""

from __future__ import annotations

import collections
import sys
from typing import Optional, TextIO


def describe(finished: int, instances: int, evaluations: int, budget: int,
             elapsed_s: float, left_s: Optional[float] = None) -> str:
  """'searching: 3/30 instances finished, 1,200,000/3,000,000 evaluations, 12 s, at most
  about 18 s left' (left_s None: no estimate yet)."""
  text = (f'searching: {finished}/{instances} instances finished, '
          f'{evaluations:,}/{budget:,} evaluations, {elapsed_s:.0f} s')
  if left_s is not None:
    text += f', at most about {left_s:.0f} s left'
  return text


class Pace:
  """Seconds per loop iteration over the last window_s seconds of `programs.Progress` reports,
  and the time left: the iterations the slowest running instance needs to spend its budget at
  its own pace, at that rate (an upper bound: a goal ends an instance sooner)."""

  def __init__(self, window_s: float = 5.0):
    self.window_s = window_s
    self._samples = collections.deque()  # (elapsed_s, iterations)

  def left_s(self, progress) -> Optional[float]:
    """The estimate after this report (None until two reports span an iteration)."""
    self._samples.append((progress.elapsed_s, progress.iterations))
    while len(self._samples) > 2 and progress.elapsed_s - self._samples[1][0] >= self.window_s:
      self._samples.popleft()
    (t0, i0), (t1, i1) = self._samples[0], self._samples[-1]
    if i1 <= i0:
      return None
    return progress.iterations_left * (t1 - t0) / (i1 - i0)


class ProgressLine:
  """Reports `programs.Progress` values (call it with one) once the search has run after_s
  seconds: on a terminal one line rewritten at each report (`close` clears it), elsewhere (a
  log) a line then and one every every_s seconds after. stream: where (default stderr); tty:
  whether it is a terminal (None: asks the stream)."""

  def __init__(self, stream: Optional[TextIO] = None, after_s: float = 2.0,
               every_s: float = 10.0, tty: Optional[bool] = None):
    self.stream = sys.stderr if stream is None else stream
    self.tty = bool(getattr(self.stream, 'isatty', lambda: False)()) if tty is None else tty
    self.after_s = after_s
    self.every_s = every_s
    self._shown = False
    self._last_s = -float('inf')
    self._pace = Pace()

  def __call__(self, progress) -> None:
    elapsed = progress.elapsed_s
    left_s = self._pace.left_s(progress)
    if elapsed < self.after_s:
      return
    text = describe(progress.finished, progress.instances, progress.evaluations,
                    progress.budget, elapsed, left_s)
    if self.tty:
      self.stream.write('\r\033[K' + text)
      self._shown = True
    elif elapsed - self._last_s >= self.every_s:
      self.stream.write(text + '\n')
      self._last_s = elapsed
    self.stream.flush()

  def close(self) -> None:
    """Clears the terminal line (the table that follows starts on a clean line)."""
    if self._shown:
      self.stream.write('\r\033[K')
      self.stream.flush()
      self._shown = False
