"""Evaluating only the live lanes of a batch of edges: at the tail of a batched search, when
the instances still searching hold few lanes, their popped edges are gathered into a smaller
static batch, so that a small physics call runs instead of a full one. Each size is its own
loop (`pachs.make_search`); `programs.plan` compiles those a search can reach, concurrently."""

from __future__ import annotations

import math
from typing import Any, Callable, Optional, Sequence, Tuple

import jax
import jax.numpy as jnp

from pachs_jax.envs import base


def batch_sizes(total: int, fractions: Sequence[float], minimum: int = 1) -> Tuple[int, ...]:
  """The compacted batch sizes (ascending, each in [minimum, total)) for fractions of a total
  lanes."""
  return tuple(sorted({max(1, math.ceil(f * total)) for f in fractions
                      if minimum <= max(1, math.ceil(f * total)) < total}))


def evaluate_live(evaluate: Callable[[base.NodeState, Any], base.EdgeOutcome],
                  nodes: base.NodeState, actions: Any, live: jax.Array,
                  size: Optional[int] = None) -> base.EdgeOutcome:
  """evaluate(nodes [B], actions [B, A]) where it matters: live [B] bool lanes (actions may be
  any pytree of [B, ...] arrays, e.g. actions and keys).

  size None simulates all B lanes. Otherwise the live lanes, at most `size` of them (the
  caller's guarantee), are gathered into `size` lanes and only those are simulated; the other
  lanes' outcomes are zeros (is_valid False). The live lanes' outcomes are the same either way
  (up to the physics' own dependence on the batch shape).
  """
  if size is None:
    return evaluate(nodes, actions)
  total = live.shape[0]
  lane = jnp.nonzero(live, size=size, fill_value=total)[0]  # [size]; padding: total
  source = jnp.minimum(lane, total - 1)
  out = evaluate(*jax.tree.map(lambda x: x[source], (nodes, actions)))
  return jax.tree.map(
      lambda o: jnp.zeros((total,) + o.shape[1:], o.dtype).at[lane].set(o, mode='drop'), out)
