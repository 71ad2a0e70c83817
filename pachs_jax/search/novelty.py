"""Coarse-cell visit counts over the search's nodes, and restart nodes drawn by novelty: each
node weighs 1 / (nodes generated in its coarse cell), so every cell found so far is about as
likely to be drawn (Go-Explore's return to rarely visited cells)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax.search import lattice as lattice_lib

NO_CELL = -1  # node_cell of a pool entry that holds no node


@struct.dataclass
class Visits:
  """Per instance [I]: counts [I, C] int32 nodes generated in each of C hashed coarse cells;
  node_cell [I, P] int32 the hashed cell of each pool node (NO_CELL: unused)."""

  counts: jax.Array
  node_cell: jax.Array


def coarse_cells(cells: jax.Array, coarsening: int, num_cells: int) -> jax.Array:
  """[...] int32 hashed coarse cell (in [0, num_cells), a power of two) of lattice keys
  cells [..., L]: each coordinate floor-divided by coarsening."""
  coarse = jnp.floor_divide(cells, coarsening)
  return (lattice_lib.hash_keys(coarse) & jnp.uint32(num_cells - 1)).astype(jnp.int32)


def init(start_cell: jax.Array, pool_size: int, num_cells: int) -> Visits:
  """Visits with each instance's start node (pool index 0) in its cell start_cell [I]."""
  num_instances = start_cell.shape[0]
  rows = jnp.arange(num_instances)
  counts = jnp.zeros((num_instances, num_cells), jnp.int32).at[rows, start_cell].add(1)
  node_cell = jnp.full((num_instances, pool_size), NO_CELL, jnp.int32).at[:, 0].set(start_cell)
  return Visits(counts=counts, node_cell=node_cell)


def add(visits: Visits, node: jax.Array, written: jax.Array, cell: jax.Array) -> Visits:
  """Visits after the nodes node [I, K] (where written [I, K]) were set in cells cell [I, K]."""
  rows = jnp.arange(node.shape[0])[:, None]
  counts = visits.counts.at[rows, cell].add(written.astype(jnp.int32))
  pool_size = visits.node_cell.shape[1]
  node_cell = visits.node_cell.at[rows, jnp.where(written, node, pool_size)].set(
      cell, mode='drop')
  return Visits(counts=counts, node_cell=node_cell)


def sample(visits: Visits, keys: jax.Array, eligible: jax.Array, num: int) -> jax.Array:
  """[I, num] int32 pool nodes drawn with replacement among eligible [I, P] nodes, each with
  weight 1 / counts[its cell]; keys [I, 2]. An instance with no eligible node draws node 0."""
  count = jnp.take_along_axis(visits.counts, jnp.maximum(visits.node_cell, 0), axis=1)
  weight = jnp.where(eligible & (visits.node_cell >= 0),
                     1.0 / jnp.maximum(count, 1).astype(jnp.float32), 0.0)
  cdf = jnp.cumsum(weight, axis=1)
  u = jax.vmap(lambda key: jax.random.uniform(key, (num,)))(keys) * cdf[:, -1:]
  index = jax.vmap(lambda c, x: jnp.searchsorted(c, x, side='right'))(cdf, u)
  index = jnp.minimum(index, eligible.shape[1] - 1)
  return jnp.where(cdf[:, -1:] > 0, index, 0).astype(jnp.int32)
