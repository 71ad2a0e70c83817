"""Command-line parsing shared by `pachs` and experiments/train.py: one-line errors and the
argument types they share (no JAX import, so bad input is refused before JAX starts)."""

from __future__ import annotations

import argparse
import math
from typing import Callable, List, Optional


class OneLineParser(argparse.ArgumentParser):
  """An ArgumentParser whose errors are one line, 'PROG: error: ... (see --help)' (exit 2)."""

  def error(self, message):
    self.exit(2, f'{self.prog}: error: {message} (see --help)\n')


def positive_float(text: str) -> float:
  """An argument type: a finite number > 0."""
  try:
    value = float(text)
  except ValueError:
    value = math.nan
  if not (math.isfinite(value) and value > 0):
    raise argparse.ArgumentTypeError(f'must be a positive number, got {text!r}')
  return value


def number(low: float = -math.inf, high: float = math.inf, high_open: bool = False,
           allow_inf: bool = False) -> Callable[[str], float]:
  """An argument type: a number in [low, high] ([low, high) with high_open), finite unless
  allow_inf."""
  if math.isinf(high):
    words = f'a number >= {low:g}' + (" ('inf' allowed)" if allow_inf else ', finite')
  else:
    words = f'a number in [{low:g}, {high:g}' + (')' if high_open else ']')

  def parse(text: str) -> float:
    try:
      value = float(text)
    except ValueError:
      value = math.nan
    inside = low <= value and (value < high if high_open else value <= high)
    if math.isnan(value) or not inside or (math.isinf(value) and not allow_inf):
      raise argparse.ArgumentTypeError(f'must be {words}, got {text!r}')
    return value

  return parse


def numbers(text: str, what: str) -> tuple:
  """A comma-separated list of numbers ('' gives ()); what names them in the error."""
  if not text.strip():
    return ()
  try:
    return tuple(float(x) for x in text.split(','))
  except ValueError:
    raise argparse.ArgumentTypeError(f'must be {what}, comma separated, got {text!r}') from None


def integer(low: Optional[int] = None, high: Optional[int] = None,
            bounds: Optional[str] = None, quoted: bool = False) -> Callable[[str], int]:
  """An argument type: an integer in [low, high) (None: no bound); bounds: the words of the
  error for one outside them (default 'must be >= low' / 'must be < high'), which quotes the
  text given when quoted."""
  if bounds is None:
    bounds = ' and '.join(part for part in (low is not None and f'must be >= {low}',
                                            high is not None and f'must be < {high}') if part)

  def parse(text: str) -> int:
    try:
      value = int(text)
    except ValueError:
      raise argparse.ArgumentTypeError(f'must be an integer, got {text!r}') from None
    if (low is not None and value < low) or (high is not None and value >= high):
      shown = repr(text) if quoted else value
      raise argparse.ArgumentTypeError(f'{bounds}, got {shown}')
    return value

  return parse


positive_int = integer(1, bounds='must be a positive integer', quoted=True)
seed = integer(-2**63, 2**63, 'must fit in 64 bits (-2**63 .. 2**63 - 1)')  # a PRNG key's


def path(what: str) -> Callable[[str], str]:
  """An argument type: a path that is not empty (an empty one would silently mean 'none');
  what names the thing it names in the error ('a file', 'a directory')."""

  def parse(text: str) -> str:
    if not text.strip():
      raise argparse.ArgumentTypeError(f'must name {what}, got an empty string')
    return text

  return parse


def instance_indices(text: str, available: int) -> List[int]:
  """'0-29' or '0,3,5' or '7' -> sorted instance indices, checked against `available`."""
  ranges = []
  try:
    for part in text.split(','):
      if '-' in part:
        lo, hi = (int(x) for x in part.split('-'))
      else:
        lo = hi = int(part)
      ranges.append((lo, hi))
  except ValueError:
    raise ValueError(f"instances must look like '0-29' or '0,3,5', got {text!r}") from None
  # bounds first: no range is built beyond the available instances
  if not ranges or any(not 0 <= lo < available or not 0 <= hi < available
                       for lo, hi in ranges):
    raise ValueError(f'instances must lie in 0..{available - 1}, got {text!r}')
  empty = [f'{lo}-{hi}' for lo, hi in ranges if lo > hi]
  if empty:
    raise ValueError(f'instances: the range {empty[0]} is empty (write low-high), got {text!r}')
  return sorted({i for lo, hi in ranges for i in range(lo, hi + 1)})
