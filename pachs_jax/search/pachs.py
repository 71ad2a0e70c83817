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
from pachs_jax.search import model as model_lib
from pachs_jax.search import novelty
from pachs_jax.search import path as path_lib
from pachs_jax.search import phases
from pachs_jax.search import pool as pool_lib
from pachs_jax.search import rules as rules_lib
from pachs_jax.search import replay as replay_lib
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
  lanes_offered: [I] int32 the edges the iterations so far could have evaluated (K each).
  incumbent: the cheapest goal found, the first goal's counts, the evaluation limit.
  replay: the path the first chain lane replays (`replay.Replay`; length 0: none).
  """

  edge_heap: heap_lib.Heap
  dummy_heap: heap_lib.Heap
  rng: jax.Array
  chain: jax.Array
  visits: novelty.Visits
  lanes_offered: jax.Array
  incumbent: improve.Incumbent
  replay: replay_lib.Replay


class Lanes(NamedTuple):
  """How one loop program lays out an iteration's edges: the physics simulates `size` lanes
  gathered from the I * K (None: all of them)."""

  size: Optional[int] = None


@dataclasses.dataclass(frozen=True)
class Search:
  """PACHS bound to one environment, actor-critic and config (jitted functions).

  init(start_nodes [I], keys [I, 2], live [I] bool, replay=None) -> SearchState with the start
    states' dummy edges in OPEN; instances that are not live (padding) start stopped; replay:
    paths from the starts (actions [I, T, A], length [I]) that the first chain lane replays
    (`replay`; T at most capacities.replay).
  loop(state, num_iterations, lanes, shrink=True) -> state after at most num_iterations more
    iterations laid out as `lanes` (a `Lanes`; None: Lanes()), with shrink (a traced bool)
    stopping early once another layout applies to the active instances (the input state's
    buffers are donated; `lanes` is static: one program per layout).
  lanes_of(num_active, I) -> the `Lanes` whose loop applies to num_active of I instances: the
    smallest of config.compact_fractions of I * K (each at least K) that holds their edges;
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
  sizes = compact.batch_sizes(full, config.compact_fractions, minimum=k)
  return Lanes(next((s for s in sizes if s >= num_active * k), None))


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


@dataclasses.dataclass(frozen=True)
class Parts:
  """What one PACHS loop is built from: env, actor_critic, config, its `rules.Rules`, the
  lattice resolution [L] and the arrays' sizes (`capacity.Sizes`)."""

  env: base.Env
  actor_critic: ActorCritic
  config: SearchConfig
  rules: rules_lib.Rules
  resolution: jax.Array
  sizes: capacity_lib.Sizes

  @property
  def slots(self) -> int:
    """Heap slots per node: its N real edges, then its dummy edge (slot N)."""
    return self.config.num_actions + 1


@struct.dataclass
class Expansion:
  """An iteration after its expansion: popped the dummy edges popped [I, K], expanding [I, K]
  the nodes expanded, working [I] the instances that expand and evaluate, and the heaps, pool
  and incumbent after it."""

  popped: phases.Popped
  expanding: jax.Array
  working: jax.Array
  edge_heap: heap_lib.Heap
  dummy_heap: heap_lib.Heap
  pool: pool_lib.NodePool
  incumbent: improve.Incumbent


@struct.dataclass
class Evaluation:
  """An iteration's K edges [I, K] after their evaluation (the last R lanes extend chains):
  parent node, action [I, K, A], q, mask (lanes that hold an edge worth evaluating), outcome,
  within the budget (evaluated), usable (valid with finite cost), out_of_budget [I], and OPEN's
  real edges after the pop."""

  parent: jax.Array
  action: jax.Array
  q: jax.Array
  mask: jax.Array
  outcome: object
  within: jax.Array
  usable: jax.Array
  out_of_budget: jax.Array
  edge_heap: heap_lib.Heap


def lane_keys(state: SearchState, stream: int, count: int) -> jax.Array:
  """[I, count, 2] per-lane keys of this iteration's samples of one stream (1: inside the
  segments, 2: the chains, 3: the chains' restarts), apart from the expansion's."""
  keys = jax.vmap(jax.random.fold_in)(state.rng, state.iterations)
  keys = jax.vmap(jax.random.fold_in, (0, None))(keys, stream)
  return jax.vmap(lambda key: jax.random.split(key, count))(keys)


def expand(parts: Parts, state: SearchState) -> Expansion:
  """Pops the dummy edges up to the K-th real edge's key, offers the popped goals, and samples
  and scores N edges at each node expanded (one network batch) into OPEN."""
  config, after_goal = parts.config, parts.rules.after_goal
  k, r, n = config.pop_size, config.rollout_lanes, config.num_actions
  limit = heap_lib.kth_key(state.edge_heap, k - r)
  dummy_heap, popped = phases.pop(state.dummy_heap, k, parts.slots, state.active, limit)
  fresh, found, goal = phases.goal_check(state.pool, popped, n)
  # the popped nodes' g, read once: the goal's cost and the edges' f (a read of g that the
  # insert's in-place write of g does not depend on would make XLA copy g every iteration)
  popped_g = pool_lib.gather(state.pool.g, popped.node)
  goal_g = jnp.max(jnp.where(popped.node == goal[:, None], popped_g, -jnp.inf), axis=1)
  incumbent = improve.offer(state.incumbent, found, goal, goal_g)
  working = after_goal.working(state.active, found)
  expanding = fresh & working[:, None]
  num_instances = expanding.shape[0]
  sources = pool_lib.gather_nodes(state.pool, popped.node)
  obs = phases.unflat(parts.env.observe(phases.flat(sources, num_instances * k)), num_instances)
  rng = jax.vmap(jax.random.fold_in)(state.rng, state.iterations)
  actions = clean_actions(jax.vmap(
      lambda key, o: parts.actor_critic.sample_actions(key, o, n))(rng, obs))
  q = cost_to_go(parts.actor_critic.q_values(phases.flat(obs, num_instances * k),
                                             phases.flat(actions, num_instances * k)))
  q = q.reshape(num_instances, k, n)
  pool = pool_lib.close(state.pool, popped.node, expanding, actions, q)
  f = popped_g[:, :, None] + phases.weighted(q, config.weight)
  values = popped.node[:, :, None] * parts.slots + jnp.arange(n)
  edge_heap = heap_lib.push(state.edge_heap, f.reshape(num_instances, -1),
                            values.reshape(num_instances, -1), jnp.repeat(expanding, n, axis=1))
  return Expansion(popped, expanding, working, edge_heap, dummy_heap, pool, incumbent)


def evaluate(parts: Parts, state: SearchState, expansion: Expansion, lanes: Lanes) -> Evaluation:
  """Pops the K - R best real edges and takes the actor's edge at each of the R chains' tips,
  then simulates those within the budget (one physics batch of `lanes.size`)."""
  config, rules, env = parts.config, parts.rules, parts.env
  k, r, n = config.pop_size, config.rollout_lanes, config.num_actions
  pool, working = expansion.pool, expansion.working
  edge_heap, edges = phases.pop(expansion.edge_heap, k - r, parts.slots, working)
  rows = jnp.arange(edges.node.shape[0])[:, None]
  action = pool.edge_actions[rows, edges.node, jnp.minimum(edges.slot, n - 1)]
  q = pool.edge_q[rows, edges.node, jnp.minimum(edges.slot, n - 1)]
  parent, mask = edges.node, edges.mask
  num_instances = parent.shape[0]
  # a search built with room for a replay (static): its first chain lane's next replayed edge
  replay_edge = (replay_lib.next_edge(state.replay, rules.edges.steps)
                 if r and parts.sizes.replay else None)
  if r:  # rollout lanes: the actor's edge at each chain's tip, after the K - R best edges
    tips = state.chain
    obs = env.observe(phases.flat(pool_lib.gather_nodes(pool, tips), num_instances * r))
    tip_action = segment.actor_samples(parts.actor_critic,
                                       lane_keys(state, 2, r).reshape(-1, 2), obs)
    if replay_edge is not None:
      tip_action = replay_lib.with_first_actions(tip_action, replay_edge, r)
    tip_q = cost_to_go(parts.actor_critic.q_values(obs, tip_action[:, None]))
    parent, action, q = (jnp.concatenate(x, axis=1) for x in (
        (parent, tips), (action, tip_action.reshape(num_instances, r, -1)),
        (q, tip_q.reshape(num_instances, r))))
    mask = jnp.concatenate([mask, jnp.broadcast_to(working[:, None], tips.shape)], axis=1)
  mask = rules.after_goal.prune(mask, pool_lib.gather(pool.g, parent), expansion.incumbent)
  replayed = () if replay_edge is None else replay_lib.lane_inputs(replay_edge, k - r, k)
  outcome, within, usable, out_of_budget = phases.evaluate(
      rules.edges.simulate, pool_lib.gather_nodes(pool, parent),
      rules.edges.inputs(action, lane_keys(state, 1, k), replayed), mask, state.evaluated,
      expansion.incumbent.evaluation_limit, lanes.size, rules.edges.steps)
  return Evaluation(parent, action, q, mask, outcome, within, usable, out_of_budget, edge_heap)


def next_chains(parts: Parts, pool, visits, incumbent, keys, tip, written, is_goal):
  """[I, R] the nodes the chains extend next, after the rollout lanes' successors tip [I, R]
  (nodes of their own, not merged in the lattice): a chain goes on from its successor and
  restarts (config.chain_restart; after the first goal, as `rules.after_goal` says) after an
  unusable edge, a goal, a g at the incumbent's cost or where its next edge would pass an
  episode's length."""
  r, steps, rules = parts.config.rollout_lanes, parts.rules.edges.steps, parts.rules
  if not r:
    return tip
  fits = lambda depth: depth + steps <= parts.env.episode_length
  tip_g = pool_lib.gather(pool.g, tip)
  go_on = (written & ~is_goal & fits(pool_lib.gather(pool.depth, tip))
           & (tip_g < incumbent.cost[:, None]))
  restarts = jnp.broadcast_to(rules.restart.choose(pool, visits, keys, fits(pool.depth), r),
                              tip.shape).astype(jnp.int32)
  restarts = rules.after_goal.restarts(pool, incumbent, keys, fits(pool.depth), restarts)
  return jnp.where(go_on, tip, restarts).astype(jnp.int32)


def insert(parts: Parts, state: SearchState, expansion: Expansion,
           evaluation: Evaluation) -> SearchState:
  """Puts the successors into the lattice and pool and their dummy edges into OPEN, moves the
  chains on, offers the goals generated and settles each instance's stop."""
  config, rules, env = parts.config, parts.rules, parts.env
  k, r, steps = config.pop_size, config.rollout_lanes, rules.edges.steps
  outcome, usable, incumbent = evaluation.outcome, evaluation.usable, expansion.incumbent
  h = rules.edges.h(evaluation.q, outcome)
  chain_lane = jnp.broadcast_to(jnp.arange(k) >= k - r, usable.shape)
  num_instances = usable.shape[0]
  cells = phases.unflat(env.lattice_key(phases.flat(outcome.next_node, num_instances * k),
                                        parts.resolution), num_instances)
  size = expansion.pool.size[:, None]
  pool, table, dummy_key, node, write = phases.insert(
      expansion.pool, state.table, cells, evaluation.parent, outcome, usable,
      evaluation.action, h, config.weight, unmerged=chain_lane if r else None)
  new = write & (node >= size)  # not an open node whose g improved
  visits = rules.restart.record(state.visits, node, new, cells)
  chain = next_chains(parts, pool, visits, incumbent, lane_keys(state, 3, 1)[:, 0],
                      node[:, k - r:], write[:, k - r:], outcome.is_goal[:, k - r:])
  replay = state.replay
  if r and parts.sizes.replay:  # the replay goes on while its chain goes on from its successor
    taken = outcome.length[:, k - r] if steps > 1 else jnp.ones_like(replay.done)
    replay = replay_lib.advance(replay, taken, write[:, k - r] & (chain[:, 0] == node[:, k - r]))
  incumbent = improve.offer(incumbent, *improve.cheapest(
      pool, node, write & outcome.is_goal & rules.after_goal.goal_lanes(chain_lane)))
  dummy_heap = heap_lib.push(expansion.dummy_heap, dummy_key,
                             node * parts.slots + config.num_actions, write)
  overflow = (evaluation.edge_heap.overflow + dummy_heap.overflow + pool.overflow
              + table.overflow)
  open_empty = state.active & ~jnp.any(expansion.popped.mask | evaluation.mask, axis=1)
  evaluated = state.evaluated + phases.count(evaluation.within) * steps
  incumbent = improve.settle(incumbent, evaluated, state.iterations + 1,
                             config.improve_allowance, config.budget)
  stopping = (evaluation.out_of_budget | open_empty | (overflow > 0)
              | (state.iterations + 1 >= parts.sizes.iterations))
  done = rules.after_goal.done(incumbent, evaluated, stopping)
  return phases.finish(state, done, incumbent.node, open_empty, evaluation.out_of_budget,
                       overflow, parts.sizes.iterations, expansion.expanding,
                       evaluation.within, usable, steps, edge_heap=evaluation.edge_heap,
                       dummy_heap=dummy_heap, pool=pool, table=table, chain=chain,
                       visits=visits, incumbent=incumbent, replay=replay,
                       lanes_offered=state.lanes_offered + k * state.active)


def step(parts: Parts, state: SearchState, lanes: Lanes) -> SearchState:
  """One iteration of every instance: expansion, evaluation, insertion."""
  expansion = expand(parts, state)
  evaluation = evaluate(parts, state, expansion, lanes)
  return insert(parts, state, expansion, evaluation)


def make_search(env: base.Env, actor_critic: ActorCritic, config: SearchConfig,
                rules: Optional[rules_lib.Rules] = None,
                capacities: Optional[capacity_lib.Capacities] = None) -> Search:
  """Builds the jitted PACHS functions for env, actor_critic and config; rules: the variant's
  edge, chain-restart, real-time answer and after-goal functions (None: those config names,
  `rules.from_config`); capacities: the arrays' sizes (None: derived from the budget)."""
  resolution = _check(env, actor_critic, config)
  actor_critic = model_lib.with_uniform_actions(actor_critic, config.uniform_share)
  capacities = capacity_lib.Capacities() if capacities is None else capacities
  sizes = capacity_lib.sizes(capacities, config.budget, config.num_actions + 1,
                             config.edge_steps, heap_per_node=config.num_actions)
  rules = rules_lib.from_config(env, actor_critic, config) if rules is None else rules
  parts = Parts(env, actor_critic, config, rules, resolution, sizes)
  k, n, r, steps = config.pop_size, config.num_actions, config.rollout_lanes, rules.edges.steps
  slots, dummy = parts.slots, n  # edge slots per node; the dummy edge's slot

  def init(start_nodes: base.NodeState, keys: jax.Array, live=None,
           replay=None) -> SearchState:
    num_instances = check_start_nodes(start_nodes, env)
    start_cells = env.lattice_key(start_nodes, resolution)
    pool, table = phases.start(start_nodes, env.is_goal(start_nodes), start_cells,
                               sizes.pool, sizes.table, n, env.action_size, steps)
    dummy_heap = heap_lib.init(num_instances, sizes.dummy_heap, k)
    return SearchState(edge_heap=heap_lib.init(num_instances, sizes.heap, k),
                       dummy_heap=phases.push_start(dummy_heap, dummy),
                       rng=instance_keys(keys, num_instances),
                       chain=jnp.zeros((num_instances, r), jnp.int32),
                       visits=rules.restart.visits(start_cells, sizes.pool),
                       lanes_offered=jnp.zeros((num_instances,), jnp.int32),
                       incumbent=improve.init(num_instances, config.budget),
                       replay=replay_lib.init(num_instances, sizes.replay, env.action_size,
                                              replay),
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
      return step(parts, state, lanes), done + 1

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
