"""The search's result and the reasons an instance stops."""

from __future__ import annotations

from typing import Optional

import jax
import numpy as np
from flax import struct

from pachs_jax.envs import base


class StopReason:
  """Why a search instance stopped ([I] int32 codes in `SearchResult.stop_reason`)."""

  RUNNING = 0  # not stopped yet (a chunked run that was interrupted)
  GOAL = 1  # a dummy edge of a goal state was popped
  BUDGET = 2  # a popped edge needed an evaluation beyond `budget`
  ITERATIONS = 3  # `Capacities.max_iterations` loop iterations done
  OPEN_EMPTY = 4  # OPEN held no edge: every reachable lattice cell was expanded
  CAPACITY = 5  # the heap, node pool or lattice table overflowed (see the overflow counts)
  TIME_LIMIT = 6  # the host's wall-clock limit ran out between chunks (set by `plan`)
  INTERRUPTED = 7  # the caller asked the search to stop (a signal; set by `plan`)

  NAMES = ('running', 'goal', 'budget', 'iterations', 'open_empty', 'capacity', 'time_limit',
           'interrupted')

  @classmethod
  def name(cls, code: int) -> str:
    return cls.NAMES[int(code)]

  @classmethod
  def names(cls, codes) -> list:
    """The names of codes (an array of any shape, e.g. `SearchResult.stop_reason`), flat."""
    return [cls.NAMES[int(c)] for c in np.asarray(codes).reshape(-1)]


@struct.dataclass
class SearchResult:
  """The outcome of planning I problem instances (leading axis I everywhere).

  found: [I] bool, a goal state's dummy edge was popped; the path ends at that goal.
  stop_reason: [I] int32 `StopReason` code.
  path_actions: [I, max_path_length, A] actions from the start; rows >= path_length are 0.
  path_length: [I] int32 number of actions in the path (may exceed max_path_length, see
    path_truncated).
  path_nodes: NodeState [I, max_path_length + 1, ...] states along the path (start first).
  path_truncated: [I] bool, the path was longer than max_path_length (its prefix is kept).
  path_is_goal: [I] bool, the path's last state satisfies the goal rule.
  cost: [I] float32 path cost g of the last state (sum of edge costs, the env's cost units).
  expanded: [I] int32 states expanded (dummy edges popped and expanded).
  evaluated: [I] int32 edge evaluations: transitions simulated (env.evaluate calls counted per
    edge; an edge of `edge_steps` H counts H).
  invalid: [I] int32 evaluated edges that were invalid (dropped; edges, not transitions).
  generated: [I] int32 nodes in the pool.
  iterations: [I] int32 loop iterations.
  lane_utilization: [I] float32 evaluated / (K * H * iterations): the share of the instance's K
    evaluation lanes that held an edge while it searched (0 before the first iteration).
  heap_overflow, pool_overflow, table_overflow: [I] int32 entries dropped for lack of space.
  wall_time_s: [] float32 host wall-clock seconds of the planning call without compilation
    (set by `plan`; NaN from `Search.result`).
  first_goal_evaluated, first_goal_iterations: [I] int32 the evaluations and iterations when
    the first goal was found (-1: none); first_goal_cost: [I] float32 that goal's path cost
    (inf: none). None from a planner whose first goal is its answer (evaluated, iterations and
    cost say it).
  """

  found: jax.Array
  stop_reason: jax.Array
  path_actions: jax.Array
  path_length: jax.Array
  path_nodes: base.NodeState
  path_truncated: jax.Array
  path_is_goal: jax.Array
  cost: jax.Array
  expanded: jax.Array
  evaluated: jax.Array
  invalid: jax.Array
  generated: jax.Array
  iterations: jax.Array
  lane_utilization: jax.Array
  heap_overflow: jax.Array
  pool_overflow: jax.Array
  table_overflow: jax.Array
  wall_time_s: jax.Array
  first_goal_evaluated: Optional[jax.Array] = None
  first_goal_iterations: Optional[jax.Array] = None
  first_goal_cost: Optional[jax.Array] = None
