"""Command-line parsing shared by `pachs` and experiments/train.py: one-line errors and the
argument types they share (no JAX import, so bad input is refused before JAX starts)."""

from __future__ import annotations

import argparse
import math


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


def numbers(text: str, what: str) -> tuple:
  """A comma-separated list of numbers ('' gives ()); what names them in the error."""
  try:
    return tuple(float(x) for x in text.split(',') if x.strip())
  except ValueError:
    raise argparse.ArgumentTypeError(f'must be {what}, comma separated, got {text!r}') from None
