"""XLA CPU settings under which batched LAPACK calls (MJX's Cholesky factorizations under vmap)
cannot deadlock XLA's CPU thread pool; set them before JAX starts its CPU backend."""

from __future__ import annotations

import os
from typing import MutableMapping

# jaxlib 0.10 and 0.11.0 split a batched LAPACK call (Cholesky, triangular solve, ...) of
# batch x n^3 / 3 >= 2e5 flops into chunks on XLA's intra-op thread pool and block the calling
# pool thread until they are done. When as many such calls run at once as the pool has threads
# (2 on a 2-core machine; one MJX physics step of many worlds holds several), every thread
# waits for chunks that no thread is free to run. Single-threaded Eigen gives the calls no pool
# to split into, so each runs its batch itself.
LAPACK_SAFE_FLAG = '--xla_cpu_multi_thread_eigen=false'


def lapack_safe_flags(flags: str) -> str:
  """XLA_FLAGS text `flags` with LAPACK_SAFE_FLAG added, unless it already sets that flag."""
  if 'xla_cpu_multi_thread_eigen' in flags:
    return flags
  return f'{flags} {LAPACK_SAFE_FLAG}'.strip()


def configure(environ: MutableMapping[str, str]) -> None:
  """Adds LAPACK_SAFE_FLAG to environ['XLA_FLAGS'] (os.environ before JAX creates its CPU
  backend: XLA reads its flags once, at that moment); a flag already set is left as it is."""
  environ['XLA_FLAGS'] = lapack_safe_flags(environ.get('XLA_FLAGS', ''))


def is_configured(environ: MutableMapping[str, str] = os.environ) -> bool:
  """Whether environ's XLA_FLAGS carry LAPACK_SAFE_FLAG."""
  return LAPACK_SAFE_FLAG in environ.get('XLA_FLAGS', '').split()
