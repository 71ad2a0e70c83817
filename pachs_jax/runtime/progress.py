"""A one-line progress report of a running search on a stream (stderr): rewritten in place on a
terminal, printed now and then elsewhere (a log keeps a few lines, stdout stays clean)."""

from __future__ import annotations

import sys
from typing import Optional, TextIO


def describe(finished: int, instances: int, evaluations: int, budget: int,
             elapsed_s: float) -> str:
  """'searching: 3/30 instances finished, 1,200,000/3,000,000 evaluations, 12 s, about 18 s
  left' (the time left at the pace so far; no estimate before the first evaluation)."""
  text = (f'searching: {finished}/{instances} instances finished, '
          f'{evaluations:,}/{budget:,} evaluations, {elapsed_s:.0f} s')
  if evaluations > 0:
    text += f', about {elapsed_s * (budget - evaluations) / evaluations:.0f} s left'
  return text


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

  def __call__(self, progress) -> None:
    elapsed = progress.elapsed_s
    if elapsed < self.after_s:
      return
    text = describe(progress.finished, progress.instances, progress.evaluations,
                    progress.budget, elapsed)
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
