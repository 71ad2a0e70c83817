"""The per-instance sizes of a search's arrays (node pool, lattice table, heaps, loop iterations,
kept path): derived from the budget so that they never overflow, or set smaller on purpose."""

from __future__ import annotations

import dataclasses
from typing import NamedTuple, Optional

from pachs_jax.search.config import next_pow2, normalize_numbers, positive_int

INT32_LIMIT = 2**31  # heap values, pool indices and table slots are int32


@dataclasses.dataclass(frozen=True)
class Capacities:
  """Per-instance capacities of a search; None derives one from the config's budget.

  max_iterations: loop iterations (None: no limit beyond the budget).
  heap: OPEN entries (None: every edge the budget can generate); PACHS bounds both its heaps.
  pool: nodes (None: one per edge the budget pays for, and the start).
  table: lattice-table slots, a power of two (None: the power of two >= 2 * pool).
  max_path_length: actions kept in a returned path (longer paths keep their first ones).
  replay: the most actions of a path the first chain lane can replay (`replay.Replay`; 0:
    none).
  """

  max_iterations: Optional[int] = None
  heap: Optional[int] = None
  pool: Optional[int] = None
  table: Optional[int] = None
  max_path_length: int = 1024
  replay: int = 0

  def __post_init__(self):
    normalize_numbers(self)
    positive_int('Capacities', 'max_path_length', self.max_path_length)
    if isinstance(self.replay, bool) or not isinstance(self.replay, int) or self.replay < 0:
      raise ValueError(f'Capacities.replay must be an int >= 0, got {self.replay!r}')
    for name in ('max_iterations', 'heap', 'pool', 'table'):
      positive_int('Capacities', name, getattr(self, name), allow_none=True)
    if self.table is not None and self.table & (self.table - 1):
      raise ValueError(f'Capacities.table must be a power of two, got {self.table}')


class Sizes(NamedTuple):
  """A search's per-instance array sizes: pool nodes, lattice-table slots, OPEN entries (heap:
  real edges, or every edge where one heap holds all; dummy_heap: PACHS's dummy edges),
  loop iterations, the actions kept in a returned path and those of a replayed path."""

  pool: int
  table: int
  heap: int
  dummy_heap: int
  iterations: int
  path: int
  replay: int = 0


def sizes(capacities: Optional[Capacities], budget: int, slots: int, edge_steps: int = 1,
          heap_per_node: Optional[int] = None) -> Sizes:
  """The Sizes of a search with an edge budget, `slots` heap entries per node (its edges and
  the dummy edge) and edges of edge_steps transitions; heap_per_node: real-edge entries per
  expanded node (None: one heap of every edge, `slots` per node paid for). ValueError, one
  line, when a size would overflow int32."""
  capacities = Capacities() if capacities is None else capacities
  if not isinstance(capacities, Capacities):
    raise ValueError(f'capacities must be a Capacities, got {type(capacities).__name__}')
  edges = budget // edge_steps + 1  # the edges the budget pays for, and the start's
  pool = capacities.pool or edges
  if pool * slots >= INT32_LIMIT:
    raise ValueError(f'the pool capacity * (edges per node + 1) must stay below 2**31 (heap '
                     f'entries store node * (edges + 1) + slot as int32); got {pool} nodes and '
                     f'{slots - 1} edges per node: lower the budget or Capacities.pool')
  table = capacities.table or next_pow2(2 * pool)
  if heap_per_node is None:
    heap, dummy_heap = capacities.heap or slots * (budget + 1), 0
  else:
    heap = capacities.heap or heap_per_node * pool
    dummy_heap = min(capacities.heap or edges, edges)
  if heap >= INT32_LIMIT or table >= INT32_LIMIT:
    raise ValueError(f'heap and table capacities must stay below 2**31 (got heap {heap}, '
                     f'table {table})')
  iterations = (capacities.max_iterations if capacities.max_iterations is not None
                else min(INT32_LIMIT - 1, slots * (budget + 1) + 1))
  return Sizes(pool, table, heap, dummy_heap, iterations, capacities.max_path_length,
               capacities.replay)
