"""Pytrees of arrays that share leading batch axes."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp


def where(mask: jax.Array, new: Any, old: Any) -> Any:
  """new where mask else old, leaf by leaf: mask [B] (or [B, M]) covers the leaves' leading
  axes and is broadcast over the rest."""
  return jax.tree.map(lambda a, b: jnp.where(
      jnp.reshape(mask, mask.shape + (1,) * (jnp.ndim(a) - mask.ndim)), a, b), new, old)
