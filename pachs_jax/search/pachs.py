"""PACHS: edge-based best-first search, K edges per iteration, I problem instances at once
(docs/search_loop.md)."""

from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pachs_jax.envs import base
from pachs_jax.search import capacity as capacity_lib
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
  chain: [I, R * W] int32 the node each rollout lane extends next (config.rollout_lanes R; W
    the widest of config.widen_factors, 1 without; a step widened m times uses the first m R).
  visits: the nodes per coarse cell, where chains restart with chain_restart 'novel' (a pool
    of one node otherwise).
  lanes_offered: [I] int32 the edges the iterations so far could have evaluated (K each, m K
    when widened).
  incumbent: the cheapest goal found, the first goal's counts, the evaluation limit.
  """

  edge_heap: heap_lib.Heap
  dummy_heap: heap_lib.Heap
  rng: jax.Array
  chain: jax.Array
  visits: novelty.Visits
  lanes_offered: jax.Array
  incumbent: improve.Incumbent


class Lanes(NamedTuple):
  """How one loop program lays out an iteration's edges: each instance pops widen * K edges
  (widen * R of them extend chains), and the physics simulates `size` lanes gathered from
  the I * widen * K (None: all of them, only with widen 1)."""

  size: Optional[int] = None
  widen: int = 1


@dataclasses.dataclass(frozen=True)
class Search:
  """PACHS bound to one environment, actor-critic and config (jitted functions).

  init(start_nodes [I], keys [I, 2], live [I] bool) -> SearchState with the start states'
    dummy edges in OPEN; instances that are not live (padding) start stopped.
  loop(state, num_iterations, lanes, shrink=True) -> state after at most num_iterations more
    iterations laid out as `lanes` (a `Lanes`; None: Lanes()), with shrink (a traced bool)
    stopping early once another layout applies to the active instances (the input state's
    buffers are donated; `lanes` is static: one program per layout).
  lanes_of(num_active, I) -> the `Lanes` whose loop applies to num_active of I instances: the
    widest of config.widen_factors whose edges fit the I * K lanes (1 when none does), then
    the smallest of config.compact_fractions of I * K (each at least K) that holds them;
    lanes_for(state) -> the one that applies to state now (host; reads state.active).
  reachable(num_active, I) -> the layouts, in order, of a search that starts with num_active
    of I instances active.
  run_chunk(state, num_iterations) -> loop(state, num_iterations, lanes_for(state)).
  run(state) -> state when every instance has stopped (one program: every layout's loop).
  result(state) -> SearchResult; an instance that has not found a goal gets the path to its
    real-time answer (config.realtime_answer).
  capacities: the `capacity.Capacities` it was built with (sizes: what they resolve to).
  """

  init: Callable[..., SearchState]
  loop: Callable[..., SearchState]
  run: Callable[[SearchState], SearchState]
  result: Callable[[SearchState], SearchResult]
  config: SearchConfig
  capacities: capacity_lib.Capacities
  sizes: capacity_lib.Sizes

  def lanes_of(self, num_active: int, num_instances: int) -> Lanes:
    return lanes_of(self.config, num_active, num_instances)

  def lanes_for(self, state: SearchState) -> Lanes:
    return self.lanes_of(int(np.sum(np.asarray(state.active))), state.active.shape[0])

  def reachable(self, num_active: int, num_instances: int) -> Tuple[Lanes, ...]:
    return reachable(self.config, num_active, num_instances)

  def run_chunk(self, state: SearchState, num_iterations) -> SearchState:
    return self.loop(state, num_iterations, self.lanes_for(state))


def lanes_of(config: SearchConfig, num_active: int, num_instances: int) -> Lanes:
  """The `Lanes` of `Search.lanes_of` for config."""
  k, full = config.pop_size, num_instances * config.pop_size
  widen = max((m for m in config.widen_factors if num_active * k * m <= full), default=1)
  edges = num_active * k * widen
  sizes = compact.batch_sizes(full, config.compact_fractions, minimum=k)
  size = next((s for s in sizes if s >= edges), None if widen == 1 else full)
  return Lanes(size, widen)


def reachable(config: SearchConfig, num_active: int, num_instances: int) -> Tuple[Lanes, ...]:
  """The `Lanes` of `Search.reachable` for config."""
  layouts = [lanes_of(config, a, num_instances) for a in range(num_active, 0, -1)]
  return tuple(dict.fromkeys(layouts or [Lanes()]))


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
                rules: Optional[rules_lib.Rules] = None,
                capacities: Optional[capacity_lib.Capacities] = None) -> Search:
  """Builds the jitted PACHS functions for env, actor_critic and config; rules: the variant's
  edge, chain-restart and real-time answer functions (None: those config names,
  `rules.from_config`); capacities: the arrays' sizes (None: derived from the budget)."""
  resolution = _check(env, actor_critic, config)
  capacities = capacity_lib.Capacities() if capacities is None else capacities
  sizes = capacity_lib.sizes(capacities, config.budget, config.num_actions + 1,
                             config.edge_steps, heap_per_node=config.num_actions)
  rules = rules_lib.from_config(env, actor_critic, config) if rules is None else rules
  edge_rule, restart = rules.edges, rules.restart
  w, k, n = float(config.weight), config.pop_size, config.num_actions
  slots, dummy = n + 1, n  # edge slots per node; the dummy edge's slot
  steps, r = edge_rule.steps, config.rollout_lanes
  widest = max(config.widen_factors, default=1)
  improving = config.after_goal == 'improve'

  def lattice_cells(nodes):
    """[I, K, L] int32 lattice keys of nodes [I, K]."""
    num_instances, lanes = jax.tree.leaves(nodes)[0].shape[:2]
    return phases.unflat(env.lattice_key(phases.flat(nodes, num_instances * lanes),
                                         resolution), num_instances)

  def expand(state, popped, expanding):
    """Samples and scores N edges at each expanded node; returns (pool, edge entries)."""
    num_instances, k = expanding.shape
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

  def chain_edges(state, pool, r):
    """(tips [I, R], actions [I, R, A], q [I, R]): the actor's edge at each of the first R
    rollout lanes' tip."""
    tips = state.chain[:, :r]
    num_instances = tips.shape[0]
    obs = env.observe(phases.flat(pool_lib.gather_nodes(pool, tips), num_instances * r))
    actions = segment.actor_samples(actor_critic, lane_keys(state, 2, r).reshape(-1, 2), obs)
    q = cost_to_go(actor_critic.q_values(obs, actions[:, None]))
    return tips, actions.reshape(num_instances, r, -1), q.reshape(num_instances, r)

  def next_chains(pool, visits, incumbent, keys, tip, written, is_goal, r):
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
    restarts = jnp.broadcast_to(restart.choose(pool, visits, keys, fits(pool.depth), r),
                                tip.shape).astype(jnp.int32)
    if improving:  # the path walk and draw run only once some instance has a goal
      path_keys = jax.vmap(lambda key: jax.random.fold_in(key, 1))(keys)
      restarts = jax.lax.cond(
          jnp.any(incumbent.found),
          lambda: jnp.where(incumbent.found[:, None], improve.path_restarts(
              pool, incumbent, path_keys, fits(pool.depth), r), restarts),
          lambda: restarts)
    return jnp.where(go_on, tip, restarts).astype(jnp.int32)

  def step(state: SearchState, lanes: Lanes) -> SearchState:
    k, r = lanes.widen * config.pop_size, lanes.widen * config.rollout_lanes
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
      tips, tip_action, tip_q = chain_edges(state, pool, r)
      parent, action, q = (jnp.concatenate(x, axis=1) for x in
                           ((parent, tips), (action, tip_action), (q, tip_q)))
      mask = jnp.concatenate([mask, jnp.broadcast_to(working[:, None], tips.shape)], axis=1)
    if improving:  # prune the edges from nodes that cost as much as the incumbent
      mask = mask & (pool_lib.gather(pool.g, parent) < incumbent.cost[:, None])
    outcome, within, usable, out_of_budget = phases.evaluate(
        edge_rule.simulate, pool_lib.gather_nodes(pool, parent),
        edge_rule.inputs(action, lane_keys(state, 1, k)), mask, state.evaluated,
        incumbent.evaluation_limit, lanes.size, steps)
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
                        node[:, k - r:], write[:, k - r:], outcome.is_goal[:, k - r:], r)
    # goals at generation: the chains' (as a rollout's), after the first goal every lane's
    incumbent = improve.offer(incumbent, pool, *improve.cheapest(
        pool, node, write & outcome.is_goal & (chain_lane | improving)))
    dummy_heap = heap_lib.push(dummy_heap, dummy_key, node * slots + dummy, write)
    overflow = edge_heap.overflow + dummy_heap.overflow + pool.overflow + table.overflow
    open_empty = state.active & ~jnp.any(popped.mask | mask, axis=1)
    evaluated = state.evaluated + phases.count(within) * steps
    incumbent = improve.settle(incumbent, evaluated, state.iterations + 1,
                               config.improve_allowance, config.budget)
    done = incumbent.found  # the first goal, or (improving) the end of the allowance
    if improving:
      done = done & ((evaluated >= incumbent.evaluation_limit) | out_of_budget | open_empty | (overflow > 0)
                     | (state.iterations + 1 >= sizes.iterations))
    return phases.finish(state, done, incumbent.node, open_empty, out_of_budget, overflow,
                         sizes.iterations, expanding, within, usable, steps,
                         edge_heap=edge_heap, dummy_heap=dummy_heap, pool=pool, table=table,
                         chain=state.chain.at[:, :r].set(chain), visits=visits,
                         incumbent=incumbent, lanes_offered=state.lanes_offered + k * state.active)

  def init(start_nodes: base.NodeState, keys: jax.Array, live=None) -> SearchState:
    num_instances = check_start_nodes(start_nodes, env)
    start_cells = env.lattice_key(start_nodes, resolution)
    pool, table = phases.start(start_nodes, env.is_goal(start_nodes), start_cells,
                               sizes.pool, sizes.table, n, env.action_size, steps)
    dummy_heap = heap_lib.init(num_instances, sizes.dummy_heap, k)
    return SearchState(edge_heap=heap_lib.init(num_instances, sizes.heap, k),
                       dummy_heap=phases.push_start(dummy_heap, dummy),
                       rng=instance_keys(keys, num_instances),
                       chain=jnp.zeros((num_instances, r * widest), jnp.int32),
                       visits=restart.visits(start_cells, sizes.pool),
                       lanes_offered=jnp.zeros((num_instances,), jnp.int32),
                       incumbent=improve.init(num_instances, config.budget),
                       **phases.start_state(pool, table, live))

  def loop(state: SearchState, num_iterations, lanes: Optional[Lanes] = None,
           shrink=True) -> SearchState:
    lanes, num_instances = lanes or Lanes(), state.active.shape[0]
    # the active instances at and below which another layout takes over
    floor = min((a for a in range(1, num_instances + 1)
                 if lanes_of(config, a, num_instances) == lanes), default=1) - 1

    def cond(carry):
      state, done = carry
      active = jnp.sum(state.active, dtype=jnp.int32)
      return (active > jnp.where(shrink, floor, 0)) & (done < num_iterations)

    def body(carry):
      state, done = carry
      return step(state, lanes), done + 1

    state, _ = jax.lax.while_loop(cond, body, (state, jnp.zeros((), jnp.int32)))
    return state

  def run(state: SearchState) -> SearchState:
    num_instances = state.active.shape[0]
    for lanes in reachable(config, num_instances, num_instances):
      state = loop(state, jnp.iinfo(jnp.int32).max, lanes)
    return state

  def result(state: SearchState) -> SearchResult:
    # the best OPEN entry (dummy edges win ties); a real edge (s, a) names s
    key, value, in_open = heap_lib.peek(state.edge_heap)
    dummy_key, dummy_value, in_dummy = heap_lib.peek(state.dummy_heap)
    use_dummy = in_dummy & (~in_open | (dummy_key <= key))
    value, in_open = jnp.where(use_dummy, dummy_value, value), in_open | in_dummy
    chosen, has = rules.answer(state.pool, slots)  # the real-time answer, where it chooses
    value, in_open = jnp.where(has, chosen, value), has | in_open
    out = path_lib.search_result(state, value, in_open, slots, k * steps,
                                 state.edge_heap.overflow + state.dummy_heap.overflow,
                                 sizes.path, state.incumbent)
    offered = state.lanes_offered * steps
    return out.replace(lane_utilization=jnp.where(
        offered > 0, state.evaluated / jnp.maximum(offered, 1), 0.0).astype(jnp.float32))

  return Search(init=jax.jit(init), loop=jax.jit(loop, static_argnames='lanes', donate_argnums=0),
                run=jax.jit(run), result=jax.jit(result), config=config,
                capacities=capacities, sizes=sizes)
