"""Evaluating only the live lanes of a batch of edges: the popped real edges of the instances
still searching are gathered into the smallest of a few static batch sizes that holds them, so
a batch whose instances mostly finished (the tail of a batched search) runs a small physics
call instead of a full one. All sizes are compiled into one program (`lax.switch`)."""

from __future__ import annotations

import math
from typing import Callable, Sequence, Tuple

import jax
import jax.numpy as jnp

from pachs_jax.envs import base


def batch_sizes(total: int, fractions: Sequence[float]) -> Tuple[int, ...]:
  """The compacted batch sizes (ascending, each < total) for fractions of a total lanes."""
  return tuple(sorted({max(1, math.ceil(f * total)) for f in fractions
                      if math.ceil(f * total) < total}))


def evaluate_live(evaluate: Callable[[base.NodeState, jax.Array], base.EdgeOutcome],
                  nodes: base.NodeState, actions: jax.Array, live: jax.Array,
                  sizes: Tuple[int, ...]) -> base.EdgeOutcome:
  """evaluate(nodes [B], actions [B, A]) where it matters: live [B] bool lanes.

  With sizes (ascending, each < B) the live lanes are gathered into the smallest size that
  holds them and only those are simulated; the other lanes' outcomes are zeros (is_valid
  False). When more than sizes[-1] lanes are live, or sizes is empty, all B lanes are
  simulated. The live lanes' outcomes are the same either way (up to the physics' own
  dependence on the batch shape).
  """
  if not sizes:
    return evaluate(nodes, actions)
  total = live.shape[0]

  def compacted(size):
    def run(_):
      lane = jnp.nonzero(live, size=size, fill_value=total)[0]  # [size]; padding: total
      source = jnp.minimum(lane, total - 1)
      out = evaluate(jax.tree.map(lambda x: x[source], nodes), actions[source])
      return jax.tree.map(
          lambda o: jnp.zeros((total,) + o.shape[1:], o.dtype).at[lane].set(o, mode='drop'),
          out)
    return run

  branches = [compacted(size) for size in sizes] + [lambda _: evaluate(nodes, actions)]
  index = jnp.searchsorted(jnp.asarray(sizes), jnp.sum(live, dtype=jnp.int32))
  return jax.lax.switch(index, branches, None)
