"""JAX's persistent compilation cache, on by default in the user's cache directory, so that a
second run of a command skips XLA compilation."""

from __future__ import annotations

import os
from typing import Optional

import jax

ENV_VAR = 'PACHS_COMPILATION_CACHE'  # a directory, or 0 / off / false to disable


def default_dir() -> Optional[str]:
  """The cache directory: $PACHS_COMPILATION_CACHE, else $XDG_CACHE_HOME/pachs_jax/jax (default
  ~/.cache); None when the variable disables it."""
  value = os.environ.get(ENV_VAR, '').strip()
  if value.lower() in ('0', 'off', 'false', 'no'):
    return None
  if value:
    return value
  base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
  return os.path.join(base, 'pachs_jax', 'jax')


def enable(path: Optional[str] = None) -> Optional[str]:
  """Points JAX's persistent compilation cache at path (None: `default_dir()`), caching every
  program however quick its compilation; returns the directory, or None when disabled or not
  writable (the command then runs without the cache)."""
  path = path or default_dir()
  if path is None:
    return None
  try:
    os.makedirs(path, exist_ok=True)
  except OSError:
    return None
  if not os.access(path, os.W_OK):
    return None
  jax.config.update('jax_compilation_cache_dir', path)
  jax.config.update('jax_persistent_cache_min_compile_time_secs', 0.0)
  jax.config.update('jax_persistent_cache_min_entry_size_bytes', 0)
  return path
