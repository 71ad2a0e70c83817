"""PACHS: edge-based best-first search, K edges per iteration, I problem instances at once
(docs/search_loop.md)."""

from __future__ import annotations

import dataclasses
from typing import Callable, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pachs_jax.envs import base
from pachs_jax.search import compact
from pachs_jax.search import heap as heap_lib
from pachs_jax.search import improve
from pachs_jax.search import novelty
from pachs_jax.search import path as path_lib
from pachs_jax.search import phases
from pachs_jax.search import pool as pool_lib
from pachs_jax.search import rules as rules_lib
from pachs_jax.search import segment
from pachs_jax.search.checks import (check_actor_critic, check_start_nodes, env_lattice_resolution,
                                     instance_keys)
from pachs_jax.search.config import SearchConfig
from pachs_jax.search.model import ActorCritic, clean_actions, cost_to_go
from pachs_jax.search.result import SearchResult


@struct.dataclass
class SearchState(phases.EdgeSearchState):
  """Everything the loop carries, leading axis I: the fields of `phases.EdgeSearchState` and

  edge_heap: OPEN's real edges (s, a_j), key g(s) + w q_j.
  dummy_heap: OPEN's dummy edges (s, DUMMY), key g(s) + w h(s).
  rng: [I, 2] uint32 per-instance PRNG keys (folded with the iteration count).
  chain: [I, R] int32 the node each rollout lane extends next (config.rollout_lanes R).
  visits: the nodes per coarse cell, where chains restart with chain_restart 'novel' (a pool
    of one node otherwise).
  incumbent: the cheapest goal found, the first goal's counts, the evaluation limit.
  """

  edge_heap: heap_lib.Heap
  dummy_heap: heap_lib.Heap
  rng: jax.Array
  chain: jax.Array
  visits: novelty.Visits
  incumbent: improve.Incumbent


@dataclasses.dataclass(frozen=True)
class Search:
  """PACHS bound to one environment, actor-critic and config (jitted functions).

  init(start_nodes [I], keys [I, 2], live [I] bool) -> SearchState with the start states'
    dummy edges in OPEN; instances that are not live (padding) start stopped.
  loop(state, num_iterations, size, shrink=True) -> state after at most num_iterations more
    iterations whose edges are simulated in `size` physics lanes (None: all I * K), with
    shrink (a traced bool) stopping early once the active instances' lanes fit the next
    smaller of `lane_sizes(I)` (the input state's buffers are donated; `size` is static: one
    program per size).
  lane_sizes(I) -> the compacted lane counts (ascending; config.compact_fractions of I * K,
    each at least K).
  size_of(num_active, I) -> the `size` whose loop applies to num_active of I instances;
    size_for(state) -> the one that applies to state now (host; reads state.active).
  run_chunk(state, num_iterations) -> loop(state, num_iterations, size_for(state)).
  run(state) -> state when every instance has stopped (one program: the loops of every size).
  result(state) -> SearchResult; an instance that has not found a goal gets the path to its
    real-time answer (config.realtime_answer).
  """

  init: Callable[..., SearchState]
  loop: Callable[..., SearchState]
  lane_sizes: Callable[[int], Tuple[int, ...]]
  run: Callable[[SearchState], SearchState]
  result: Callable[[SearchState], SearchResult]
  config: SearchConfig

  def size_of(self, num_active: int, num_instances: int) -> Optional[int]:
    lanes = num_active * self.config.pop_size
    return next((size for size in self.lane_sizes(num_instances) if size >= lanes), None)

  def size_for(self, state: SearchState) -> Optional[int]:
    return self.size_of(int(np.sum(np.asarray(state.active))), state.active.shape[0])

  def run_chunk(self, state: SearchState, num_iterations) -> SearchState:
    return self.loop(state, num_iterations, size=self.size_for(state))


def _check(env: base.Env, actor_critic: ActorCritic, config: SearchConfig):
  """Validates the pieces against each other; returns the lattice resolution [L]."""
  if not isinstance(config, SearchConfig):
    raise ValueError(f'config must be a SearchConfig, got {type(config).__name__}')
  check_actor_critic(actor_critic, ('sample_actions', 'q_values'))
  resolution = env_lattice_resolution(env, config.lattice_resolution)
  num = config.num_actions
  obs = jax.ShapeDtypeStruct((2, env.observation_size), jnp.float32)
  sampled = jax.eval_shape(lambda k, o: actor_critic.sample_actions(k, o, num),
                           jax.random.PRNGKey(0), obs)
  if sampled.shape != (2, num, env.action_size):
    raise ValueError(f'actor_critic.sample_actions(key, obs[B, O], num) must return '
                     f'[B, num, A] = [2, {num}, {env.action_size}], got {sampled.shape}')
  q = jax.eval_shape(actor_critic.q_values, obs, sampled)
  if q.shape != (2, num):
    raise ValueError(f'actor_critic.q_values(obs[B, O], actions[B, num, A]) must return '
                     f'[B, num] = [2, {num}], got {q.shape}')
  return resolution


def make_search(env: base.Env, actor_critic: ActorCritic, config: SearchConfig,
                rules: Optional[rules_lib.Rules] = None) -> Search:
  """Builds the jitted PACHS functions for env, actor_critic and config; rules: the variant's
  edge, chain-restart and real-time answer functions (None: those config names,
  `rules.from_config`)."""
  resolution = _check(env, actor_critic, config)
  rules = rules_lib.from_config(env, actor_critic, config) if rules is None else rules
  edge_rule, restart = rules.edges, rules.restart
  w, k, n = float(config.weight), config.pop_size, config.num_actions
  slots, dummy = n + 1, n  # edge slots per node; the dummy edge's slot
  steps, r = edge_rule.steps, config.rollout_lanes
  improving = config.after_goal == 'improve'
  lane_sizes = lambda num_instances: compact.batch_sizes(num_instances * k,
                                                        config.compact_fractions, minimum=k)

  def lattice_cells(nodes):
    """[I, K, L] int32 lattice keys of nodes [I, K]."""
    num_instances = jax.tree.leaves(nodes)[0].shape[0]
    return phases.unflat(env.lattice_key(phases.flat(nodes, num_instances * k), resolution),
                         num_instances)

  def expand(state, popped, expanding):
    """Samples and scores N edges at each expanded node; returns (pool, edge entries)."""
    num_instances = expanding.shape[0]
    sources = pool_lib.gather_nodes(state.pool, popped.node)
    obs = phases.unflat(env.observe(phases.flat(sources, num_instances * k)), num_instances)
    rng = jax.vmap(jax.random.fold_in)(state.rng, state.iterations)
    actions = jax.vmap(lambda key, o: actor_critic.sample_actions(key, o, n))(rng, obs)
    actions = clean_actions(actions)
    q = cost_to_go(actor_critic.q_values(phases.flat(obs, num_instances * k),
                                               phases.flat(actions, num_instances * k)))
    q = q.reshape(num_instances, k, n)
    pool = pool_lib.close(state.pool, popped.node, expanding, actions, q)
    f = pool_lib.gather(state.pool.g, popped.node)[:, :, None] + phases.weighted(q, w)
    values = popped.node[:, :, None] * slots + jnp.arange(n)
    return pool, (f.reshape(num_instances, -1), values.reshape(num_instances, -1),
                  jnp.repeat(expanding, n, axis=1))

  def lane_keys(state, stream: int, count: int):
    """[I, count, 2] per-lane keys of this iteration's samples of one stream (1: inside the
    segments, 2: the chains, 3: the chains' restarts), apart from expand's."""
    keys = jax.vmap(jax.random.fold_in)(state.rng, state.iterations)
    keys = jax.vmap(jax.random.fold_in, (0, None))(keys, stream)
    return jax.vmap(lambda key: jax.random.split(key, count))(keys)

  def chain_edges(state, pool):
    """(tips [I, R], actions [I, R, A], q [I, R]): the actor's edge at each rollout lane's tip."""
    tips = state.chain
    num_instances = tips.shape[0]
    obs = env.observe(phases.flat(pool_lib.gather_nodes(pool, tips), num_instances * r))
    actions = segment.actor_samples(actor_critic, lane_keys(state, 2, r).reshape(-1, 2), obs)
    q = cost_to_go(actor_critic.q_values(obs, actions[:, None]))
    return tips, actions.reshape(num_instances, r, -1), q.reshape(num_instances, r)

  def next_chains(pool, visits, incumbent, keys, tip, written, is_goal):
    """[I, R] the nodes the chains extend next, after the rollout lanes' successors tip [I, R]
    (nodes of their own, not merged in the lattice): a chain goes on from its successor and
    restarts (config.chain_restart; after the first goal with after_goal 'improve', on the
    incumbent's path) after an unusable edge, a goal, a g at the incumbent's cost or where its
    next edge would pass an episode's length."""
    if not r:
      return tip
    fits = lambda depth: depth + steps <= env.episode_length
    tip_g = pool_lib.gather(pool.g, tip)
    go_on = (written & ~is_goal & fits(pool_lib.gather(pool.depth, tip))
             & (tip_g < incumbent.cost[:, None]))
    restarts = restart.choose(pool, visits, keys, fits(pool.depth))
    if improving:
      path_keys = jax.vmap(lambda key: jax.random.fold_in(key, 1))(keys)
      restarts = jnp.where(incumbent.found[:, None], improve.path_restarts(
          pool, incumbent, path_keys, fits(pool.depth), r), restarts)
    return jnp.where(go_on, tip, restarts).astype(jnp.int32)

  def step(state: SearchState, size: Optional[int]) -> SearchState:
    # expansion: the dummy edges up to the K-th real-edge key, one network batch
    limit = heap_lib.kth_key(state.edge_heap, k - r)
    dummy_heap, popped = phases.pop(state.dummy_heap, k, slots, state.active, limit)
    fresh, found, goal = phases.goal_check(state.pool, popped, dummy)
    incumbent = improve.offer(state.incumbent, state.pool, found, goal)
    working = state.active if improving else state.active & ~found
    expanding = fresh & working[:, None]
    pool, new_edges = expand(state, popped, expanding)
    edge_heap = heap_lib.push(state.edge_heap, *new_edges)
    # evaluation: the K best real edges, one physics batch
    edge_heap, edges = phases.pop(edge_heap, k - r, slots, working)
    rows = jnp.arange(edges.node.shape[0])[:, None]
    action = pool.edge_actions[rows, edges.node, jnp.minimum(edges.slot, n - 1)]
    q = pool.edge_q[rows, edges.node, jnp.minimum(edges.slot, n - 1)]
    parent, mask = edges.node, edges.mask
    if r:  # rollout lanes: the actor's edge at each chain's tip, after the K - R best edges
      tips, tip_action, tip_q = chain_edges(state, pool)
      parent, action, q = (jnp.concatenate(x, axis=1) for x in
                           ((parent, tips), (action, tip_action), (q, tip_q)))
      mask = jnp.concatenate([mask, jnp.broadcast_to(working[:, None], tips.shape)], axis=1)
    if improving:  # prune the edges from nodes that cost as much as the incumbent
      mask = mask & (pool_lib.gather(pool.g, parent) < incumbent.cost[:, None])
    outcome, within, usable, out_of_budget = phases.evaluate(
        edge_rule.simulate, pool_lib.gather_nodes(pool, parent),
        edge_rule.inputs(action, lane_keys(state, 1, k)), mask, state.evaluated,
        incumbent.limit, size, steps)
    # insertion: successors into the lattice and pool, their dummy edges into OPEN
    h = edge_rule.h(q, outcome)
    chain_lane = jnp.broadcast_to(jnp.arange(k) >= k - r, usable.shape)
    cells, size = lattice_cells(outcome.next_node), pool.size[:, None]
    pool, table, dummy_key, node, write = phases.insert(
        pool, state.table, cells, parent, outcome, usable, action, h, w,
        unmerged=chain_lane if r else None)
    new = write & (node >= size)  # not an open node whose g improved
    visits = restart.record(state.visits, node, new, cells)
    chain = next_chains(pool, visits, incumbent, lane_keys(state, 3, 1)[:, 0],
                        node[:, k - r:], write[:, k - r:], outcome.is_goal[:, k - r:])
    # goals at generation: the chains' (as a rollout's), after the first goal every lane's
    incumbent = improve.offer(incumbent, pool, *improve.cheapest(
        pool, node, write & outcome.is_goal & (chain_lane | improving)))
    dummy_heap = heap_lib.push(dummy_heap, dummy_key, node * slots + dummy, write)
    overflow = edge_heap.overflow + dummy_heap.overflow + pool.overflow + table.overflow
    open_empty = state.active & ~jnp.any(popped.mask | mask, axis=1)
    evaluated = state.evaluated + phases.count(within) * steps
    incumbent = improve.settle(incumbent, evaluated, state.iterations + 1,
                               config.improve_allowance, config.max_evaluations)
    done = incumbent.found  # the first goal, or (improving) the end of the allowance
    if improving:
      done = done & ((evaluated >= incumbent.limit) | out_of_budget | open_empty | (overflow > 0)
                     | (state.iterations + 1 >= config.iteration_limit))
    return phases.finish(state, done, incumbent.node, open_empty, out_of_budget, overflow,
                         config.iteration_limit, expanding, within, usable, steps,
                         edge_heap=edge_heap, dummy_heap=dummy_heap, pool=pool, table=table,
                         chain=chain, visits=visits, incumbent=incumbent)

  def init(start_nodes: base.NodeState, keys: jax.Array, live=None) -> SearchState:
    num_instances = check_start_nodes(start_nodes, env)
    start_cells = env.lattice_key(start_nodes, resolution)
    pool, table = phases.start(start_nodes, env.is_goal(start_nodes), start_cells,
                               config.pool_size, config.table_size, n, env.action_size, steps)
    dummy_heap = heap_lib.init(num_instances, config.dummy_heap_size, k)
    return SearchState(edge_heap=heap_lib.init(num_instances, config.edge_heap_size, k),
                       dummy_heap=phases.push_start(dummy_heap, dummy),
                       rng=instance_keys(keys, num_instances),
                       chain=jnp.zeros((num_instances, r), jnp.int32),
                       visits=restart.visits(start_cells),
                       incumbent=improve.init(num_instances, config.max_evaluations),
                       **phases.start_state(pool, table, live))

  def loop(state: SearchState, num_iterations, size: Optional[int] = None,
           shrink=True) -> SearchState:
    smaller = [s for s in lane_sizes(state.active.shape[0]) if size is None or s < size]
    floor = max(smaller, default=0)  # lanes at which the next smaller size takes over

    def cond(carry):
      state, done = carry
      lanes = jnp.sum(state.active, dtype=jnp.int32) * k
      return (lanes > jnp.where(shrink, floor, 0)) & (done < num_iterations)

    def body(carry):
      state, done = carry
      return step(state, size), done + 1

    state, _ = jax.lax.while_loop(cond, body, (state, jnp.zeros((), jnp.int32)))
    return state

  def run(state: SearchState) -> SearchState:
    for size in (None,) + tuple(reversed(lane_sizes(state.active.shape[0]))):
      state = loop(state, jnp.iinfo(jnp.int32).max, size)
    return state

  def result(state: SearchState) -> SearchResult:
    # the best OPEN entry (dummy edges win ties); a real edge (s, a) names s
    key, value, in_open = heap_lib.peek(state.edge_heap)
    dummy_key, dummy_value, in_dummy = heap_lib.peek(state.dummy_heap)
    use_dummy = in_dummy & (~in_open | (dummy_key <= key))
    value, in_open = jnp.where(use_dummy, dummy_value, value), in_open | in_dummy
    chosen, has = rules.answer(state.pool, slots)  # the real-time answer, where it chooses
    value, in_open = jnp.where(has, chosen, value), has | in_open
    return path_lib.search_result(state, value, in_open, slots, k * steps,
                                  state.edge_heap.overflow + state.dummy_heap.overflow,
                                  config.max_path_length, state.incumbent)

  return Search(init=jax.jit(init), loop=jax.jit(loop, static_argnames='size', donate_argnums=0),
                lane_sizes=lane_sizes, run=jax.jit(run), result=jax.jit(result), config=config)
