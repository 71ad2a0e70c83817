"""SIGINT and SIGTERM during a command: stop at the next safe point and keep what is done."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from typing import Callable, Iterator, Optional

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(BaseException):
  """A signal arrived before there was anything to keep (raised in the main thread; a
  BaseException, as KeyboardInterrupt, so that no `except Exception` swallows it)."""

  def __init__(self, signum: int):
    super().__init__(f'interrupted by {signal.Signals(signum).name}')
    self.signum = signum

  @property
  def exit_code(self) -> int:
    """128 + the signal number (130 for SIGINT, 143 for SIGTERM), as a shell reports it."""
    return 128 + self.signum


def interrupted_by(err: BaseException) -> Optional[Interrupted]:
  """The `Interrupted` that err is or that led to it (a signal during the initialization of a
  C extension module surfaces as the ImportError that it caused); None otherwise."""
  seen = set()
  while err is not None and id(err) not in seen:
    if isinstance(err, Interrupted):
      return err
    seen.add(id(err))
    err = err.__cause__ or err.__context__
  return None


class StoppedBeforeSearch(Exception):
  """A `stop` callable turned True before the work began (e.g. while its programs compiled):
  there is nothing to keep."""


class SignalGuard:
  """Routes SIGINT and SIGTERM for one command, as a context manager (main thread only; in
  another thread it installs nothing and `requested` stays None).

  Until `keep()`, a signal raises `Interrupted` in the main thread (nothing to keep yet; where
  Python drops that exception, as inside a garbage-collector callback, it prints nothing about
  it and the next `stop()` or `keep()` raises it again). From
  then on, the first signal only records itself in `requested` (the work checks `stop()` at its
  next chunk and returns what it has, which is then written) and prints `notice`; a second one
  ends the process at once.
  """

  def __init__(self, prog: str, notice: str = 'stopping after the current chunk; '
               'a second signal exits at once'):
    self.prog = prog
    self.notice = notice
    self.requested: Optional[int] = None
    self.phase: Optional[str] = None  # what runs now, for the line of a signal that stops it
    self._keeping = False
    self._early: Optional[int] = None  # a signal before keep(), in case its raise is dropped
    self._previous = {}
    self._previous_unraisablehook = None

  def __enter__(self) -> 'SignalGuard':
    if threading.current_thread() is threading.main_thread():
      for signum in SIGNALS:
        self._previous[signum] = signal.signal(signum, self._handle)
      self._previous_unraisablehook = sys.unraisablehook
      sys.unraisablehook = self._unraisable
    return self

  def __exit__(self, *exc) -> None:
    for signum, handler in self._previous.items():
      signal.signal(signum, handler)
    self._previous.clear()
    if self._previous_unraisablehook is not None:
      sys.unraisablehook = self._previous_unraisablehook
      self._previous_unraisablehook = None

  def _unraisable(self, unraisable) -> None:
    """sys.unraisablehook: an `Interrupted` that Python dropped is raised again later (see
    `_raise_early`), so it prints no "Exception ignored" traceback; others go on as before."""
    if not (unraisable.exc_type is Interrupted and self._early is not None):
      self._previous_unraisablehook(unraisable)

  def _handle(self, signum, frame) -> None:
    del frame
    if not self._keeping:
      self._early = signum
      raise Interrupted(signum)
    if self.requested is not None:  # the second signal: no waiting
      sys.stdout.flush()
      print(f'{self.prog}: {signal.Signals(signum).name} again: exiting now', file=sys.stderr,
            flush=True)
      os._exit(128 + signum)
    self.requested = signum
    print(f'{self.prog}: {signal.Signals(signum).name}: {self.notice}', file=sys.stderr,
          flush=True)

  def keep(self) -> Callable[[], bool]:
    """From now on, signals ask the work to stop instead of raising; returns `stop`."""
    self._raise_early()
    self._keeping = True
    return self.stop

  def stop(self) -> bool:
    """Whether a signal asked the work to stop (a `stop` callable for `plan`)."""
    self._raise_early()
    return self.requested is not None

  def _raise_early(self) -> None:
    """Raises `Interrupted` for a signal that arrived before keep() (in the main thread)."""
    if (self._early is not None and not self._keeping
        and threading.current_thread() is threading.main_thread()):
      raise Interrupted(self._early)

  @property
  def early(self) -> Optional[int]:
    """The signal that arrived before keep(), if any: an error raised after it may be its
    consequence (a library that turned the `Interrupted` into its own error)."""
    return None if self._keeping else self._early

  @property
  def exit_code(self) -> int:
    """0 without a signal, else 128 + its number."""
    return 0 if self.requested is None else 128 + self.requested


@contextlib.contextmanager
def interrupt_requests() -> Iterator[Callable[[], bool]]:
  """Ctrl-C as a request inside a Python call (`Planner.plan`): yields `stop`, which turns True
  at the first SIGINT in the block; a second SIGINT raises KeyboardInterrupt as usual. Only in
  the main thread and where SIGINT has Python's default handler (elsewhere stop stays False and
  nothing is installed); the handler is restored on leaving."""
  requested = []

  def handle(signum, frame):
    del signum, frame
    if requested:
      raise KeyboardInterrupt
    requested.append(True)

  install = (threading.current_thread() is threading.main_thread()
             and signal.getsignal(signal.SIGINT) is signal.default_int_handler)
  previous = signal.signal(signal.SIGINT, handle) if install else None
  try:
    yield lambda: bool(requested)
  finally:
    if install:
      signal.signal(signal.SIGINT, previous)
