"""SHA-256 digests of parameter pytrees: what checkpoints record and fingerprints name."""

from __future__ import annotations

import hashlib
from typing import Any

import jax
import numpy as np


def params_hash(tree: Any) -> str:
  """SHA-256 (hex) of a pytree's arrays: for each leaf in sorted key-path order its path,
  dtype and shape, then its bytes (little-endian, C order). Equal trees hash equally however
  they were built (dicts or FrozenDicts, device or host arrays)."""
  leaves = [(jax.tree_util.keystr(k), v) for k, v in jax.tree_util.tree_leaves_with_path(tree)]
  h = hashlib.sha256()
  for name, leaf in sorted(leaves, key=lambda kv: kv[0]):
    a = np.asarray(leaf)
    a = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder('<'))
    h.update(f'{name}|{a.dtype.str}|{a.shape}\n'.encode())
    h.update(a.tobytes())
  return h.hexdigest()
