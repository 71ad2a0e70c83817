"""Coarse-cell visit counts over the search's nodes, and restart nodes drawn by novelty: a cell
of n generated nodes weighs 1 / sqrt(n), shared by those of its nodes that may restart a chain
(Go-Explore's count-based return to rarely visited cells)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax.search import lattice as lattice_lib

NO_CELL = -1  # node_cell of a pool entry that holds no node


@struct.dataclass
class Visits:
  """Per instance [I]: nodes_per_cell [I, C] int32 the nodes generated (new pool entries) in
  each of C hashed coarse cells; node_cell [I, P] int32 the hashed cell of each pool node
  (NO_CELL: unused)."""

  nodes_per_cell: jax.Array
  node_cell: jax.Array


def coarse_cells(cells: jax.Array, coarsening: int, num_cells: int) -> jax.Array:
  """[...] int32 hashed coarse cell (in [0, num_cells), a power of two) of lattice keys
  cells [..., L]: each coordinate floor-divided by coarsening."""
  coarse = jnp.floor_divide(cells, coarsening)
  return (lattice_lib.hash_keys(coarse) & jnp.uint32(num_cells - 1)).astype(jnp.int32)


def init(start_cell: jax.Array, pool_size: int, num_cells: int) -> Visits:
  """Visits of pools of pool_size nodes and num_cells (a power of two) hashed cells, holding
  each instance's start node (pool index 0) in its cell start_cell [I]."""
  if num_cells < 1 or num_cells & (num_cells - 1):
    raise ValueError(f'num_cells must be a power of two, got {num_cells}')
  num_instances = start_cell.shape[0]
  rows = jnp.arange(num_instances)
  nodes_per_cell = jnp.zeros((num_instances, num_cells), jnp.int32).at[rows, start_cell].add(1)
  node_cell = jnp.full((num_instances, pool_size), NO_CELL, jnp.int32).at[:, 0].set(start_cell)
  return Visits(nodes_per_cell=nodes_per_cell, node_cell=node_cell)


def add(visits: Visits, node: jax.Array, new: jax.Array, cell: jax.Array) -> Visits:
  """Visits after the new pool nodes node [I, K] (where new [I, K]) in cells cell [I, K]."""
  rows = jnp.arange(node.shape[0])[:, None]
  nodes_per_cell = visits.nodes_per_cell.at[rows, cell].add(new.astype(jnp.int32))
  pool_size = visits.node_cell.shape[1]
  node_cell = visits.node_cell.at[rows, jnp.where(new, node, pool_size)].set(
      cell, mode='drop')
  return Visits(nodes_per_cell=nodes_per_cell, node_cell=node_cell)


def sample(visits: Visits, keys: jax.Array, eligible: jax.Array, num: int) -> jax.Array:
  """[I, num] int32 pool nodes drawn with replacement among eligible [I, P] nodes, each with
  weight n ** -1.5 for the n nodes generated in its cell, so that a cell weighs 1 / sqrt(n)
  (`draw`, the weights scaled to sum to about 2**30); keys [I, 2]. An instance with no eligible
  node draws node 0."""
  in_cell = jnp.take_along_axis(visits.nodes_per_cell, jnp.maximum(visits.node_cell, 0), axis=1)
  eligible = eligible & (visits.node_cell != NO_CELL)
  weight = jnp.where(eligible, jnp.maximum(in_cell, 1).astype(jnp.float32) ** -1.5, 0.0)
  share = weight / jnp.maximum(jnp.sum(weight, axis=1, keepdims=True), 1e-30)
  return draw(jnp.where(eligible, jnp.maximum(jnp.floor(share * 2.0**30), 1.0), 0.0)
              .astype(jnp.int32), keys, num)


def below(key: jax.Array, bound: jax.Array, num: int) -> jax.Array:
  """[num] int32 integers drawn uniformly from [0, bound), 1 <= bound < 2**31: the high word of
  32 random bits times bound, so that every value has floor or ceil(2**32 / bound) of the 2**32
  bit patterns, spread evenly over the range (`jax.random.randint` of jax 0.10 reduces one word
  modulo bounds above 2**16, which favours the values below 2**32 mod bound, up to 3 / 2 as
  likely)."""
  bits = jax.random.bits(key, (num,), jnp.uint32)
  bound = jnp.asarray(bound).astype(jnp.uint32)
  lo16 = jnp.uint32(0xFFFF)
  b_hi, b_lo, t_hi, t_lo = bits >> 16, bits & lo16, bound >> 16, bound & lo16
  cross_a, cross_b = b_hi * t_lo, b_lo * t_hi  # each below 2**32
  carry = ((b_lo * t_lo) >> 16) + (cross_a & lo16) + (cross_b & lo16)
  high = b_hi * t_hi + (cross_a >> 16) + (cross_b >> 16) + (carry >> 16)
  return high.astype(jnp.int32)


def draw(weight: jax.Array, keys: jax.Array, num: int) -> jax.Array:
  """[I, num] int32 indices drawn with replacement with integer weights weight [I, P] >= 0
  (summing below 2**31, so that the draw never picks an index of weight 0, `below`); keys
  [I, 2]. An instance whose weights are all 0 draws index 0."""
  pool_size = weight.shape[1]
  cdf = jnp.cumsum(weight, axis=1, dtype=jnp.int32)
  total = cdf[:, -1]
  u = jax.vmap(lambda key, t: below(key, jnp.maximum(t, 1), num))(keys, total)
  index = jax.vmap(lambda c, x: jnp.searchsorted(c, x, side='right'))(cdf, u)
  index = jnp.minimum(index, pool_size - 1)
  drawn = (jnp.take_along_axis(weight, index, axis=1) > 0) & (total[:, None] > 0)
  return jnp.where(drawn, index, 0).astype(jnp.int32)
