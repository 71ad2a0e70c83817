"""PACHS: edge-based best-first search, K edges per iteration, I problem instances at once.

OPEN holds edges: a dummy edge (s, DUMMY) means "s is ready to be expanded", a real edge
(s, a_j) names the j-th action sampled at s. Each heap entry's value is node * (N + 1) + slot,
slot N for the dummy edge. Two loop bodies (`SearchConfig.loop`) share the phases below:

- goal check: a fresh popped dummy edge of a goal state ends the instance (path to it).
- expand the fresh dummy edges: one actor call samples N actions at each (I * K states), one
  critic call scores them; push (s, a_j) with f = g(s) + w q_j, q = max(-Q, 0); close s.
- evaluate popped real edges: one `env.evaluate` over all I * K slots (masked), at most the
  remaining budget per instance. Invalid edges are dropped.
- insert successors through the lattice: a new cell, or an open node with g(s) + c < g(s'),
  takes (state s', g, parent s, action) and gets a dummy edge g(s') + w max(q - c, 0).
  Closed nodes are never updated (no re-expansion): their children were generated from their
  stored state, so keeping it keeps every returned path replayable bit for bit.
- stop: goal, open list empty, capacity overflow, budget, iterations (in that precedence).

'split' (the default): OPEN is two heaps per instance, D (dummy edges, key g(s) + w h) and R
(real edges, key g(s) + w q_j). One iteration:
1. expansion phase: k_R = R's K-th best key (+inf when R holds fewer than K); pop up to K
   entries of D with key <= k_R; goal check; expand the fresh ones and push their N K real
   edges into R (one actor and one critic batch of I * K).
2. evaluation phase: pop the K best entries of R (the new children included) and evaluate all
   of them (one physics batch of I * K); insert the successors; push their dummy edges into D.
A popped real edge is never stale (its source is closed and never changes), so every
iteration in which R holds >= K entries after the expansion phase fills all K lanes.
'mixed': one heap holds both kinds; one iteration pops the K best entries, goal-checks and
expands the dummy edges among them and evaluates the real ones, then pushes all new entries
in one push. Popped dummy and stale entries leave their evaluation lanes empty.
`SearchResult.lane_utilization` reports evaluated / (K iterations) per instance. Measured
side by side (CPU, PushT-Fixed with the shipped model, 3 instances, K = 16, N = 8, w = 2,
all found): 'split' 0.72-0.81 of the lanes in 7-9 iterations, 'mixed' 0.50-0.66 in 13-17
(these searches are short: 'split' idles half its lanes in the first iteration, N < K, and
all in the last, the goal pop). On the grid-world tests (K = 8): 'split' fills every lane
except in the last iteration.

Why 'split' with K = 1, w = 1 stays optimal (as A* does, for a consistent cost-to-go estimate,
e.g. the grid world's critic): a dummy edge leaves D only when its key is <= min D (it is D's
best) and <= k_R = min R, i.e. when it is the minimum of OPEN = D u R, exactly as a pop of the
mixed loop. The real edge evaluated in the same iteration may come before OPEN's minimum
(a better dummy edge may remain in D): evaluating an edge early only generates or improves a
node earlier, it never closes one. The A* invariant is about expansions: when s is expanded
with the minimum key of OPEN, the first unfinished element of an optimal path to s (a real
edge in R out of an expanded node, or the dummy edge of its successor in D) has a key
<= f*(s) = g*(s) + h(s); key(s) is the minimum, so g(s) = g*(s), and no closed node would
ever need an update (optimal over the graph of sampled edges and lattice cells). A goal is
accepted only when its dummy edge is popped, i.e. at the minimum of OPEN, so its cost is
optimal; the same argument with keys g + w h gives weighted A*'s bound of w x optimal. Ties
between D and R go to D.
For K > 1 neither loop keeps a guarantee: 'mixed' expands dummy edges among the K best of
OPEN; 'split' those among the K best of D that are <= R's K-th best key, so among the 2K - 1
best of OPEN, and it evaluates the K best real edges after the expansion (mixed: the real
edges among the K best of OPEN, often fewer than K). Paths stay valid and replayable, costs
are those of the returned path; 'split' tends to expand more states per evaluated edge.
Even at K = 1 the two loops may evaluate different numbers of edges: 'split' evaluates one
real edge every iteration, also while a better dummy edge waits in D, and breaks D-R ties
toward D (on the grid-world tests: about as many evaluations in about half the iterations).

Lazy deletion: a popped dummy edge is stale (dropped) when its node is closed or its key is not
the node's latest dummy key (its g was improved since); a popped real edge is always evaluated.
Finished instances are masked and stop changing.

Per iteration of 'mixed': one heap pop (see `heap`: one top_k over the buffer for 'flat', two
small ones for 'segmented', O(K log C) sorts for 'blocked'), one push of K (N + 1) entries,
O(K^2) pairwise duplicate checks, a lattice probe of K keys, and O(K (N + 1)) gathers and
scatters into the pool, all batched over I. 'split' adds a k-th key look-up on R (about a pop)
and one more push ('blocked': a limited pop also pushes back up to K entries). Memory per
instance: pool (see `pool`), table 4 L + 5 bytes per slot, heaps 8 or 12 bytes per entry
('split': N * pool + budget + 1 entries, 'mixed': (N + 1) (budget + 1)). Measured search
overhead of 'mixed' (grid world, whose edges cost nothing, NVIDIA H200, I = 30, budget 100,000
each, 'segmented' heap): about 0.3 ms per iteration at K = 16..256 and N = 8 or 16, e.g.
0.58 s for all 3 million evaluations at K = 64, N = 16.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax.envs import base
from pachs_jax.search import anytime
from pachs_jax.search import compact
from pachs_jax.search import heap as heap_lib
from pachs_jax.search import lattice as lattice_lib
from pachs_jax.search import path as path_lib
from pachs_jax.search import pool as pool_lib
from pachs_jax.search import types
from pachs_jax.search.types import (ActorCritic, SearchConfig, SearchResult, StopReason,
                                     cost_to_go)

NO_NODE = -1


@struct.dataclass
class SearchState:
  """Everything the loop carries, leading axis I.

  heap: the OPEN list ('mixed') or the real-edge heap R ('split').
  dummy_heap: the dummy-edge heap D ('split'; None for 'mixed').
  pool: the nodes; table: lattice cell -> node index.
  rng: [I, 2] uint32 per-instance PRNG keys (folded with the iteration count).
  active: [I] bool, still searching; stop_reason: [I] int32 `StopReason`.
  goal_node: [I] int32 the popped goal node (NO_NODE if none).
  iterations, expanded, evaluated, invalid: [I] int32 counters.
  """

  heap: heap_lib.Heap
  dummy_heap: Optional[heap_lib.Heap]
  pool: pool_lib.NodePool
  table: lattice_lib.LatticeTable
  rng: jax.Array
  active: jax.Array
  stop_reason: jax.Array
  goal_node: jax.Array
  iterations: jax.Array
  expanded: jax.Array
  evaluated: jax.Array
  invalid: jax.Array


class _Popped(NamedTuple):
  """The K popped entries per instance, [I, K] each."""

  key: jax.Array  # float32 priority
  node: jax.Array  # int32 source node
  slot: jax.Array  # int32 action slot, N for the dummy edge
  mask: jax.Array  # bool, an entry was popped


@dataclasses.dataclass(frozen=True)
class Search:
  """PACHS bound to one environment, actor-critic and config (jitted functions).

  init(start_nodes [I], keys [I, 2]) -> SearchState with the start states' dummy edges in OPEN.
  run_chunk(state, num_iterations) -> state after at most num_iterations more iterations
    (the input state's buffers are donated).
  run(state) -> state when every instance has stopped.
  result(state) -> SearchResult; an instance that has not found a goal gets the path to the
    state of its best OPEN entry (the real-time answer; a real edge (s, a) names s), or with
    config.realtime_answer 'min_h' to its generated state of least estimated cost-to-go.
  """

  init: Callable[..., SearchState]
  run_chunk: Callable[..., SearchState]
  run: Callable[[SearchState], SearchState]
  result: Callable[[SearchState], SearchResult]
  config: SearchConfig


def _flat(tree, num):
  """Merges the leading two axes [I, K, ...] -> [I * K, ...]."""
  return jax.tree.map(lambda x: x.reshape((num,) + x.shape[2:]), tree)


def _unflat(tree, num_instances):
  return jax.tree.map(lambda x: x.reshape((num_instances, -1) + x.shape[1:]), tree)


def _first_of_node(node: jax.Array, mask: jax.Array) -> jax.Array:
  """[I, K] bool: mask and no earlier masked entry has the same node."""
  k = node.shape[1]
  earlier = jnp.arange(k)[None, :] < jnp.arange(k)[:, None]
  same = (node[:, :, None] == node[:, None, :]) & mask[:, None, :] & earlier
  return mask & ~jnp.any(same, axis=2)


def _check_config(env: base.Env, actor_critic: ActorCritic, config: SearchConfig):
  """Validates the pieces against each other; returns (lattice resolution, key size, action size)."""
  if not isinstance(config, SearchConfig):
    raise ValueError(f'config must be a SearchConfig, got {type(config).__name__}')
  for name in ('sample_actions', 'q_values'):
    if not callable(getattr(actor_critic, name, None)):
      raise ValueError(f'actor_critic has no method {name}(...) (see search.types.ActorCritic)')
  node = jax.eval_shape(env.sample_instance, jax.random.PRNGKey(0))
  resolution = types.env_lattice_resolution(env, config.lattice_resolution)
  key_size = jax.eval_shape(env.lattice_coords, node, resolution).shape
  num, actions = config.num_actions, env.action_size
  obs = jax.ShapeDtypeStruct((2, env.observation_size), jnp.float32)
  sampled = jax.eval_shape(lambda k, o: actor_critic.sample_actions(k, o, num),
                           jax.random.PRNGKey(0), obs)
  if sampled.shape != (2, num, actions):
    raise ValueError(f'actor_critic.sample_actions(key, obs[B, O], num) must return '
                     f'[B, num, A] = [2, {num}, {actions}], got {sampled.shape}')
  q = jax.eval_shape(actor_critic.q_values, obs, sampled)
  if q.shape != (2, num):
    raise ValueError(f'actor_critic.q_values(obs[B, O], actions[B, num, A]) must return '
                     f'[B, num] = [2, {num}], got {q.shape}')
  return resolution, int(key_size[0]), actions, node


def make_search(env: base.Env, actor_critic: ActorCritic, config: SearchConfig) -> Search:
  """Builds the jitted PACHS functions for env, actor_critic and config."""
  resolution, key_size, action_size, node_spec = _check_config(env, actor_critic, config)
  w, k, n = float(config.weight), config.pop_size, config.num_actions
  dummy = n  # the dummy edge's slot
  split = config.loop == 'split'
  count = lambda mask: jnp.sum(mask, axis=1, dtype=jnp.int32)

  def weighted(q):
    return q * w if w else jnp.zeros_like(q)  # w = 0: uniform cost (and no 0 * inf)

  # ---- the phases of one iteration ----

  def pop(heap, active, limit=None):
    heap, key, value, mask = heap_lib.pop(heap, k, active, limit)
    return heap, _Popped(key, value // (n + 1), value % (n + 1), mask)

  def goal_check(pool, popped):
    """(fresh dummy edges [I, K], found [I], goal node [I])."""
    fresh = (popped.mask & (popped.slot == dummy) & ~pool_lib.gather(pool.closed, popped.node)
             & (popped.key == pool_lib.gather(pool.open_key, popped.node)))
    fresh = _first_of_node(popped.node, fresh)
    at_goal = fresh & pool_lib.gather(pool.is_goal, popped.node)
    goal = jnp.take_along_axis(popped.node, jnp.argmax(at_goal, axis=1)[:, None], axis=1)[:, 0]
    return fresh & ~at_goal, jnp.any(at_goal, axis=1), goal

  def observe(sources):
    """[I, K, O] observations of the nodes sources [I, K]."""
    num_instances = jax.tree.leaves(sources)[0].shape[0]
    return _unflat(env.observe(_flat(sources, num_instances * k)), num_instances)

  def expand(state, pool, popped, obs, expand_mask):
    """Samples and scores N edges per expanded node; returns (pool, keys [I, K, N])."""
    num_instances = expand_mask.shape[0]
    rng = jax.vmap(jax.random.fold_in)(state.rng, state.iterations)  # per instance and step
    actions = jax.vmap(lambda key, o: actor_critic.sample_actions(key, o, n))(rng, obs)
    actions = jnp.clip(jnp.nan_to_num(actions.astype(jnp.float32)), -1.0, 1.0)
    q_value = actor_critic.q_values(_flat(obs, num_instances * k),
                                    _flat(actions, num_instances * k))
    q = cost_to_go(q_value).reshape(num_instances, k, n)
    f = pool_lib.gather(pool.g, popped.node)[:, :, None] + weighted(q)
    return pool_lib.close(pool, popped.node, expand_mask, actions, q), f

  def evaluate(state, pool, popped, sources, real):
    """Evaluates the popped real edges within budget; returns (outcome, mask, out of budget,
    action [I, K, A], q [I, K])."""
    num_instances = real.shape[0]
    left = config.max_evaluations - state.evaluated
    within = real & (jnp.cumsum(real, axis=1) <= left[:, None])
    slot = jnp.minimum(popped.slot, n - 1)
    rows = jnp.arange(num_instances)[:, None]
    action = pool.edge_actions[rows, popped.node, slot]
    q = pool.edge_q[rows, popped.node, slot]
    lanes = num_instances * k
    outcome = compact.evaluate_live(
        env.evaluate, _flat(sources, lanes), action.reshape(lanes, action_size),
        within.reshape(lanes), compact.batch_sizes(lanes, config.compact_fractions))
    outcome = _unflat(outcome, num_instances)
    return outcome, within, jnp.any(real & ~within, axis=1), action, q

  def insert(pool, table, popped, outcome, usable, action, q):
    """Successors into the lattice and pool; returns (pool, table, dummy keys, nodes, pushed)."""
    num_instances = usable.shape[0]
    g = pool_lib.gather(pool.g, popped.node) + outcome.cost
    cell = env.lattice_key(_flat(outcome.next_node, num_instances * k), resolution)
    cell = cell.reshape(num_instances, k, key_size)
    pool, table, node, write = pool_lib.merge_successors(pool, table, cell, g, usable)
    h = jnp.maximum(q - outcome.cost, 0.0)
    dummy_key = g + weighted(h)
    depth = pool_lib.gather(pool.depth, popped.node) + 1
    pool = pool_lib.set_nodes(pool, node, write, outcome.next_node, g, popped.node, action,
                              depth, outcome.is_goal, dummy_key)
    return pool, table, dummy_key, node, write

  def edge_entries(popped, edge_keys, expanding):
    """(keys, values, mask) [I, K N] of the real edges of the expanded nodes."""
    num_instances = expanding.shape[0]
    values = popped.node[:, :, None] * (n + 1) + jnp.arange(n)
    return (edge_keys.reshape(num_instances, -1), values.reshape(num_instances, -1),
            jnp.repeat(expanding, n, axis=1))

  def stop(state, heaps, pool, table, found, open_empty, out_of_budget, iterations):
    overflow = sum(heap_lib.overflow(h) for h in heaps) + pool.overflow + table.overflow
    reason = jnp.select(
        [found, open_empty, overflow > 0, out_of_budget, iterations >= config.iterations],
        [StopReason.GOAL, StopReason.OPEN_EMPTY, StopReason.CAPACITY, StopReason.BUDGET,
         StopReason.ITERATIONS], StopReason.RUNNING)
    reason = jnp.where(state.active, reason, state.stop_reason).astype(jnp.int32)
    return reason, state.active & (reason == StopReason.RUNNING)

  def finish(state, heap, dummy_heap, pool, table, found, goal, open_empty, out_of_budget,
             expanding, evaluated, usable):
    """The state after an iteration: stop reasons and counters."""
    iterations = state.iterations + state.active
    heaps = (heap,) if dummy_heap is None else (heap, dummy_heap)
    reason, active = stop(state, heaps, pool, table, found, open_empty, out_of_budget,
                          iterations)
    return state.replace(
        heap=heap, dummy_heap=dummy_heap, pool=pool, table=table, active=active,
        stop_reason=reason, goal_node=jnp.where(found & state.active, goal, state.goal_node),
        iterations=iterations, expanded=state.expanded + count(expanding),
        evaluated=state.evaluated + count(evaluated),
        invalid=state.invalid + count(evaluated & ~usable))

  # ---- one iteration ----

  def step_mixed(state: SearchState) -> SearchState:
    """Pops the K best entries of one OPEN heap; expands the dummy edges among them and
    evaluates the real ones."""
    heap, popped = pop(state.heap, state.active)
    open_empty = state.active & ~jnp.any(popped.mask, axis=1)
    fresh, found, goal = goal_check(state.pool, popped)
    working = (state.active & ~found)[:, None]
    sources = pool_lib.gather_nodes(state.pool, popped.node)
    expanding = fresh & working
    pool, edge_keys = expand(state, state.pool, popped, observe(sources), expanding)
    real = popped.mask & (popped.slot != dummy) & working
    outcome, evaluated, out_of_budget, action, q = evaluate(state, pool, popped, sources, real)
    usable = evaluated & outcome.is_valid & jnp.isfinite(outcome.cost)
    pool, table, dummy_keys, dummy_nodes, pushed = insert(
        pool, state.table, popped, outcome, usable, action, q)
    edges = edge_entries(popped, edge_keys, expanding)
    heap = heap_lib.push(heap, *(jnp.concatenate([e, d], axis=1) for e, d in zip(
        edges, (dummy_keys, dummy_nodes * (n + 1) + dummy, pushed))))
    return finish(state, heap, None, pool, table, found, goal, open_empty, out_of_budget,
                  expanding, evaluated, usable)

  def step_split(state: SearchState) -> SearchState:
    """Expansion phase on D (dummy edges before R's K-th key), then evaluation phase: the K
    best edges of R in one full physics batch."""
    # expand: one network batch
    limit = heap_lib.kth_key(state.heap, k)
    dummy_heap, popped = pop(state.dummy_heap, state.active, limit)
    fresh, found, goal = goal_check(state.pool, popped)
    working = state.active & ~found
    expanding = fresh & working[:, None]
    pool, edge_keys = expand(state, state.pool, popped, observe(
        pool_lib.gather_nodes(state.pool, popped.node)), expanding)
    heap = heap_lib.push(state.heap, *edge_entries(popped, edge_keys, expanding))
    # evaluate: one physics batch
    heap, edges = pop(heap, working)
    sources = pool_lib.gather_nodes(pool, edges.node)
    outcome, evaluated, out_of_budget, action, q = evaluate(state, pool, edges, sources,
                                                            edges.mask)
    usable = evaluated & outcome.is_valid & jnp.isfinite(outcome.cost)
    # insert: successors into the lattice, their dummy edges into D
    pool, table, dummy_keys, dummy_nodes, pushed = insert(
        pool, state.table, edges, outcome, usable, action, q)
    dummy_heap = heap_lib.push(dummy_heap, dummy_keys, dummy_nodes * (n + 1) + dummy, pushed)
    open_empty = state.active & ~jnp.any(popped.mask | edges.mask, axis=1)
    return finish(state, heap, dummy_heap, pool, table, found, goal, open_empty, out_of_budget,
                  expanding, evaluated, usable)

  step = step_split if split else step_mixed

  # ---- the public functions ----

  def init(start_nodes: base.NodeState, keys: jax.Array) -> SearchState:
    num_instances = types.check_start_nodes(start_nodes, node_spec)
    keys = types.instance_keys(keys, num_instances)
    start_goal = env.is_goal(start_nodes)
    pool = pool_lib.init(start_nodes, start_goal, config.pool, n, action_size)
    table = lattice_lib.init(num_instances, config.table, key_size)
    cell = env.lattice_key(start_nodes, resolution)[:, None]
    root = jnp.ones((num_instances, 1), bool)
    table, slot, _, _ = lattice_lib.insert(table, cell, root)
    table = lattice_lib.set_values(table, slot, jnp.zeros_like(slot), root)
    new_heap = lambda capacity: heap_lib.init(config.heap_kind, num_instances, capacity, k,
                                              config.segment_size)
    heap = new_heap(config.heap)
    dummy_heap = new_heap(config.dummy_heap) if split else None
    start_entry = (jnp.zeros((num_instances, 1), jnp.float32),
                   jnp.full((num_instances, 1), dummy, jnp.int32), root)
    if split:
      dummy_heap = heap_lib.push(dummy_heap, *start_entry)
    else:
      heap = heap_lib.push(heap, *start_entry)
    zeros = jnp.zeros((num_instances,), jnp.int32)
    return SearchState(
        heap=heap, dummy_heap=dummy_heap, pool=pool, table=table, rng=keys,
        active=jnp.ones((num_instances,), bool), stop_reason=zeros,
        goal_node=jnp.full((num_instances,), NO_NODE, jnp.int32),
        iterations=zeros, expanded=zeros, evaluated=zeros, invalid=zeros)

  def run_chunk(state: SearchState, num_iterations) -> SearchState:
    def cond(carry):
      state, done = carry
      return jnp.any(state.active) & (done < num_iterations)

    def body(carry):
      state, done = carry
      return step(state), done + 1

    state, _ = jax.lax.while_loop(cond, body, (state, jnp.zeros((), jnp.int32)))
    return state

  def best_open(state: SearchState):
    """(value [I], in OPEN [I]) of the best OPEN entry (of D and R: the smaller key, D on
    ties)."""
    key, value, in_open = heap_lib.peek(state.heap)
    if state.dummy_heap is not None:
      dummy_key, dummy_value, in_dummy = heap_lib.peek(state.dummy_heap)
      use_dummy = in_dummy & (~in_open | (dummy_key <= key))
      value = jnp.where(use_dummy, dummy_value, value)
      in_open = in_open | in_dummy
    return value, in_open

  def result(state: SearchState) -> SearchResult:
    value, in_open = best_open(state)  # the real-time answer: a real edge names its source
    if config.realtime_answer == 'min_h':
      h_value, has = path_lib.min_h_answer(state.pool, n + 1)
      value, in_open = jnp.where(has, h_value, value), has | in_open
    heap_overflow = heap_lib.overflow(state.heap)
    if state.dummy_heap is not None:
      heap_overflow = heap_overflow + heap_lib.overflow(state.dummy_heap)
    return path_lib.search_result(state, value, in_open, n + 1, k, heap_overflow,
                                  config.max_path_length)

  run_chunk_jit = jax.jit(run_chunk, donate_argnums=0)
  run_all = jnp.int32(jnp.iinfo(jnp.int32).max)
  return Search(init=jax.jit(init), run_chunk=run_chunk_jit,
                run=lambda state: run_chunk_jit(state, run_all), result=jax.jit(result),
                config=config)


# One key or per-instance keys -> [I, 2] uint32 (kept here as part of the search's API).
instance_keys = types.instance_keys


def plan(env: base.Env, actor_critic: ActorCritic, start_nodes: base.NodeState,
         config: SearchConfig, key: jax.Array, time_limit_s: Optional[float] = None,
         chunk_iterations: int = 32, search: Optional[Search] = None) -> SearchResult:
  """Plans from start_nodes [I]; returns the SearchResult with wall_time_s set.

  key: one PRNG key (split per instance) or per-instance keys [I, 2].
  time_limit_s: None runs to the end; otherwise jitted chunks of `chunk_iterations` run (at
    least one) while the next chunk, timed as the last, would end within the wall-clock limit,
    and instances still searching then report TIME_LIMIT with the path to their best open
    node. Compilation happens before the clock starts.
  search: a `make_search` result to reuse (its compiled functions); built here when None.
  """
  if time_limit_s is not None and not time_limit_s > 0:
    raise ValueError(f'time_limit_s must be > 0 or None, got {time_limit_s!r}')
  if chunk_iterations < 1:
    raise ValueError(f'chunk_iterations must be >= 1, got {chunk_iterations}')
  if search is None:
    search = make_search(env, actor_critic, config)
  elif search.config != config:
    raise ValueError('search was built with another config')
  num_instances = types.check_start_nodes(start_nodes, jax.eval_shape(env.sample_instance,
                                                           jax.random.PRNGKey(0)))
  keys = instance_keys(key, num_instances)
  init = search.init.lower(start_nodes, keys).compile()
  shape = jax.eval_shape(search.init, start_nodes, keys)
  steps = jnp.int32(chunk_iterations if time_limit_s is not None else jnp.iinfo(jnp.int32).max)
  chunk = search.run_chunk.lower(shape, steps).compile()
  result = search.result.lower(shape).compile()

  return anytime.timed_result(lambda s: chunk(s, steps), init(start_nodes, keys), result,
                              time_limit_s)
