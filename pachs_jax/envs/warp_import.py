"""Imports MJX with its optional MuJoCo Warp part quietly and says whether Warp can run.

MJX prints `Failed to import warp` to stdout on every import where warp-lang is not installed;
here that expected line is dropped, and any other import message goes to stderr."""

from __future__ import annotations

import contextlib
import functools
import io
import os
import sys

# what MJX prints where warp-lang is not installed (or blocked with sys.modules['warp'] = None)
_EXPECTED = tuple(f'Failed to import {part}: {why}' for part in ('warp', 'mujoco_warp')
                  for why in ("No module named 'warp'",
                              'import of warp halted; None in sys.modules'))
INSTALL_HINT = "pip install -e '.[cuda]' (it brings warp-lang)"


@functools.cache
def import_message() -> str:
  """Imports `mujoco.mjx` (once) with its stdout caught: the lines that only say warp-lang is
  not installed are dropped, any other line goes to stderr and is returned ('' for none)."""
  printed = io.StringIO()
  with contextlib.redirect_stdout(printed):
    import mujoco.mjx  # pylint: disable=g-import-not-at-top,unused-import
    import mujoco.mjx.warp  # pylint: disable=g-import-not-at-top,unused-import
  rest = [line for line in printed.getvalue().splitlines()
          if line.strip() and line.strip() not in _EXPECTED]
  if rest:
    print('\n'.join(rest), file=sys.stderr)
  return '\n'.join(rest)


def quiet_mjx():
  """`mujoco.mjx`, imported through `import_message` (no stdout line about warp)."""
  import_message()
  return sys.modules['mujoco.mjx']


def available() -> bool:
  """Whether MJX's Warp implementation (warp-lang and MJX's bundled MuJoCo Warp) imported."""
  quiet_mjx()
  from mujoco.mjx import warp as mjx_warp  # pylint: disable=g-import-not-at-top
  return bool(mjx_warp.WARP_INSTALLED) and mjx_warp.mujoco_warp is not None


def require(what: str = "backend 'warp'") -> None:
  """Raises ImportError, one line naming the extra to install, unless `available()`."""
  if not available():
    message = import_message()
    detail = f' (import said: {message.splitlines()[0]})' if message else ''
    raise ImportError(f'{what} needs MuJoCo Warp, which is not installed: {INSTALL_HINT}'
                      f'{detail}')


def announce_kernel_compile() -> None:
  """Keeps Warp's per-module load lines and start-up banner off stdout (its log level goes
  from info to warning), and prints one line to stderr when Warp's kernel cache holds no
  MuJoCo Warp step kernels yet, i.e. when this machine compiles them (once; cached after)."""
  import warp  # pylint: disable=g-import-not-at-top
  if warp.config.log_level == warp.LOG_INFO:
    warp.config.log_level = warp.LOG_WARNING
  cache = warp.config.kernel_cache_dir or os.path.join(
      os.path.expanduser('~'), '.cache', 'warp', warp.config.version)
  names = os.listdir(cache) if os.path.isdir(cache) else []
  if not any(n.startswith('wp__next_time') for n in names):
    print(f'MuJoCo Warp: compiling its kernels for this machine, once (a minute or two); '
          f'they are cached in {cache}', file=sys.stderr, flush=True)
