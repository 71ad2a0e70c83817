"""Rollout baselines: the policy alone and many stochastic copies of it, batched over I
problem instances (docs/baselines.md)."""

from __future__ import annotations

import dataclasses
from typing import Callable, Optional

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax import trees
from pachs_jax.envs import base
from pachs_jax.search import compact
from pachs_jax.search.baselines import common
from pachs_jax.search.checks import check_actor_critic, check_start_nodes, instance_keys
from pachs_jax.search.config import normalize_numbers, positive_int
from pachs_jax.search.model import ActorCritic, clean_actions
from pachs_jax.search.result import SearchResult, StopReason

FALLBACKS = ('last_cost', 'total_cost')


def _flat(tree, num):
  return jax.tree.map(lambda x: x.reshape((num,) + x.shape[2:]), tree)


def _unflat(tree, num_instances):
  return jax.tree.map(lambda x: x.reshape((num_instances, -1) + x.shape[1:]), tree)


def _result(found, stop_reason, actions, length, nodes, is_goal, cost, evaluated, invalid,
            generated, iterations, lanes):
  zeros = jnp.zeros_like(evaluated)
  return SearchResult(
      found=found, stop_reason=stop_reason.astype(jnp.int32), path_actions=actions,
      path_length=length, path_nodes=nodes, path_truncated=jnp.zeros_like(found),
      path_is_goal=is_goal, cost=cost, expanded=evaluated, evaluated=evaluated,
      invalid=invalid, generated=generated, iterations=iterations,
      lane_utilization=jnp.where(lanes > 0, evaluated / jnp.maximum(lanes, 1),
                                 0.0).astype(jnp.float32),
      heap_overflow=zeros, pool_overflow=zeros, table_overflow=zeros,
      wall_time_s=jnp.float32(jnp.nan))


# ---------------------------------------------------------------- single rollout


@dataclasses.dataclass(frozen=True)
class SingleRolloutConfig:
  """max_steps: edges per rollout (None: env.episode_length); also the path buffer length."""

  max_steps: Optional[int] = None

  def __post_init__(self):
    normalize_numbers(self)
    positive_int('SingleRolloutConfig', 'max_steps', self.max_steps, allow_none=True)


def make_single_rollout(env: base.Env, actor_critic, config: SingleRolloutConfig = SingleRolloutConfig()
                        ) -> Callable[[base.NodeState], SearchResult]:
  """A jitted fn(start_nodes [I]) -> SearchResult of the deterministic policy.

  path_actions [I, T, A] with T = max_steps; cost = sum of the applied edges' costs.
  expanded = evaluated = policy steps taken; invalid = 1 where the rollout ended on an invalid
  edge (that edge is not in the path).
  """
  if not isinstance(config, SingleRolloutConfig):
    raise ValueError(f'config must be a SingleRolloutConfig, got {type(config).__name__}')
  check_actor_critic(actor_critic, ('deterministic_action',))
  steps = config.max_steps or env.episode_length
  action_size = env.action_size

  def rollout(start_nodes: base.NodeState) -> SearchResult:
    num = check_start_nodes(start_nodes, env)
    start_goal = env.is_goal(start_nodes)
    nodes = jax.tree.map(lambda x: jnp.repeat(x[:, None], steps + 1, axis=1), start_nodes)
    rows = jnp.arange(num)
    carry = dict(
        node=start_nodes, t=jnp.zeros((), jnp.int32), active=~start_goal, found=start_goal,
        stop=jnp.where(start_goal, StopReason.GOAL, StopReason.RUNNING).astype(jnp.int32),
        actions=jnp.zeros((num, steps, action_size), jnp.float32), nodes=nodes,
        length=jnp.zeros((num,), jnp.int32), cost=jnp.zeros((num,), jnp.float32),
        evaluated=jnp.zeros((num,), jnp.int32), invalid=jnp.zeros((num,), jnp.int32))

    def cond(c):
      return jnp.any(c['active']) & (c['t'] < steps)

    def body(c):
      active, t = c['active'], c['t']
      action = actor_critic.deterministic_action(env.observe(c['node']))
      action = clean_actions(action)
      out = env.evaluate(c['node'], action)
      ok = active & out.is_valid & jnp.isfinite(out.cost)
      goal = ok & out.is_goal
      bad = active & ~ok
      time_up = ok & ~goal & (t + 1 >= steps)
      stop = jnp.select([goal, bad, time_up],
                        [StopReason.GOAL, StopReason.OPEN_EMPTY, StopReason.BUDGET], c['stop'])
      pos = jnp.where(ok, t, steps)  # out of bounds: dropped
      node_pos = jnp.where(ok, t + 1, steps + 1)
      return dict(
          node=trees.where(ok, out.next_node, c['node']), t=t + 1,
          active=ok & ~goal & ~time_up, found=c['found'] | goal, stop=stop.astype(jnp.int32),
          actions=c['actions'].at[rows, pos].set(action, mode='drop'),
          nodes=jax.tree.map(lambda buf, x: buf.at[rows, node_pos].set(x, mode='drop'),
                             c['nodes'], out.next_node),
          length=c['length'] + ok, cost=c['cost'] + jnp.where(ok, out.cost, 0.0),
          evaluated=c['evaluated'] + active, invalid=c['invalid'] + bad)

    c = jax.lax.while_loop(cond, body, carry)
    # rows after the path's end repeat its last state
    after = jnp.arange(steps + 1)[None, :] > c['length'][:, None]
    last = jax.tree.map(lambda buf: buf[rows, c['length']], c['nodes'])
    path_nodes = trees.where(after, jax.tree.map(lambda x: x[:, None], last), c['nodes'])
    return _result(c['found'], c['stop'], c['actions'], c['length'], path_nodes,
                   env.is_goal(last), c['cost'], c['evaluated'], c['invalid'],
                   c['length'] + 1, c['evaluated'], c['evaluated'])

  return jax.jit(rollout)


# ---------------------------------------------------------------- parallel rollout


@dataclasses.dataclass(frozen=True)
class ParallelRolloutConfig:
  """num_copies: M policy copies per instance; budget: edge evaluations per instance;
  episode_length: steps before a copy restarts (None: env.episode_length); fallback: which
  rollout to return without a goal, 'last_cost' or 'total_cost' (see the module docstring)."""

  num_copies: int = 256
  budget: int = 100_000
  episode_length: Optional[int] = None
  fallback: str = 'last_cost'

  def __post_init__(self):
    normalize_numbers(self)
    for name in ('num_copies', 'budget'):
      positive_int('ParallelRolloutConfig', name, getattr(self, name))
    positive_int('ParallelRolloutConfig', 'episode_length', self.episode_length,
                        allow_none=True)
    if self.fallback not in FALLBACKS:
      raise ValueError(f'ParallelRolloutConfig.fallback must be one of {FALLBACKS}, '
                       f'got {self.fallback!r}')


@struct.dataclass
class RolloutState(common.SamplingState):
  """The parallel rollout's loop state, leading axis I (copies M): the fields of
  `common.SamplingState` and

  node: NodeState [I, M] the copies' states.
  episode_step: [I, M] int32 edges applied since the copy's (re)start.
  episode_cost: [I, M] float32 their summed cost; last_cost: [I, M] cost of the last applied
    edge (+inf before the first); episode_actions: [I, M, T, A] the applied actions.
  best_actions: [I, T, A], best_length [I], best_score [I], best_cost [I]: the returned rollout.
  restarts: [I] int32 copies restarted.
  """

  node: base.NodeState
  episode_step: jax.Array
  episode_cost: jax.Array
  last_cost: jax.Array
  episode_actions: jax.Array
  best_actions: jax.Array
  best_length: jax.Array
  best_score: jax.Array
  best_cost: jax.Array
  restarts: jax.Array


@dataclasses.dataclass(frozen=True)
class ParallelRollout:
  """Jitted functions: init(start_nodes [I], key) -> RolloutState; step(state, size=None) ->
  state after one loop step (size, static: simulate only the active instances' copies gathered
  into that many lanes, at least their count, `compact.evaluate_live`; None: all I * M);
  run(state) -> state when all instances stopped; stop(state) -> state with the
  active instances ended now (TIME_LIMIT; for a caller's wall-clock limit between steps);
  result(state) -> SearchResult; plan(start_nodes, key) = result(run(init(...)))."""

  init: Callable[..., RolloutState]
  step: Callable[[RolloutState], RolloutState]
  run: Callable[[RolloutState], RolloutState]
  stop: Callable[[RolloutState], RolloutState]
  result: Callable[[RolloutState], SearchResult]
  plan: Callable[..., SearchResult]
  config: ParallelRolloutConfig


def make_parallel_rollout(env: base.Env, actor_critic: ActorCritic,
                          config: ParallelRolloutConfig = ParallelRolloutConfig()
                          ) -> ParallelRollout:
  """Builds the jitted parallel rollout for env, actor_critic and config."""
  if not isinstance(config, ParallelRolloutConfig):
    raise ValueError(f'config must be a ParallelRolloutConfig, got {type(config).__name__}')
  check_actor_critic(actor_critic, ('sample_actions',))
  m, budget = config.num_copies, config.budget
  steps = config.episode_length or env.episode_length
  action_size = env.action_size

  def init(start_nodes: base.NodeState, key: jax.Array) -> RolloutState:
    num = check_start_nodes(start_nodes, env)
    keys = instance_keys(key, num)
    start_goal = env.is_goal(start_nodes)
    node = jax.tree.map(lambda x: jnp.repeat(x[:, None], m, axis=1), start_nodes)
    zeros = jnp.zeros((num,), jnp.int32)
    return RolloutState(
        node=node, episode_step=jnp.zeros((num, m), jnp.int32),
        episode_cost=jnp.zeros((num, m), jnp.float32),
        last_cost=jnp.full((num, m), jnp.inf, jnp.float32),
        episode_actions=jnp.zeros((num, m, steps, action_size), jnp.float32),
        best_actions=jnp.zeros((num, steps, action_size), jnp.float32), best_length=zeros,
        best_score=jnp.full((num,), jnp.inf, jnp.float32),
        best_cost=jnp.zeros((num,), jnp.float32), restarts=zeros,
        **common.sampling_start(start_nodes, keys, start_goal))

  def pick(state, best, candidates, score, length, cost):
    """Takes each instance's candidate copy with the lowest score if it beats best."""
    score = jnp.where(candidates, score, jnp.inf)
    j = jnp.argmin(score, axis=1)
    rows = jnp.arange(j.shape[0])
    take = jnp.any(candidates, axis=1) & (score[rows, j] < best)
    return (take, jnp.where(take[:, None, None], state.episode_actions[rows, j],
                            state.best_actions),
            jnp.where(take, length[rows, j], state.best_length),
            jnp.where(take, score[rows, j], state.best_score),
            jnp.where(take, cost[rows, j], state.best_cost))

  def step(state: RolloutState, size: Optional[int] = None) -> RolloutState:
    num = state.active.shape[0]
    left = budget - state.evaluated
    lane = state.active[:, None] & (jnp.arange(m)[None, :] < left[:, None])
    flat_node = _flat(state.node, num * m)
    obs = env.observe(flat_node).reshape(num, m, -1)
    keys = jax.vmap(jax.random.fold_in)(state.rng, state.iterations)
    action = jax.vmap(lambda k, o: actor_critic.sample_actions(k, o, 1)[:, 0])(keys, obs)
    action = clean_actions(action)
    out = _unflat(compact.evaluate_live(env.evaluate, flat_node,
                                        action.reshape(num * m, action_size),
                                        lane.reshape(num * m), size), num)
    ok = lane & out.is_valid & jnp.isfinite(out.cost)
    bad = lane & ~ok
    rows = jnp.arange(num)[:, None]
    cols = jnp.arange(m)[None, :]
    pos = jnp.where(ok, state.episode_step, steps)  # out of bounds: dropped
    episode_actions = state.episode_actions.at[rows, cols, pos].set(action, mode='drop')
    episode_step = state.episode_step + ok
    episode_cost = state.episode_cost + jnp.where(ok, out.cost, 0.0)
    last_cost = jnp.where(ok, out.cost, state.last_cost)
    state = state.replace(episode_actions=episode_actions)
    goal = ok & out.is_goal
    found_now = jnp.any(goal, axis=1)
    evaluated = state.evaluated + jnp.sum(lane, axis=1, dtype=jnp.int32)
    out_of_budget = state.active & ~found_now & (evaluated >= budget)
    finished = bad | (ok & (episode_step >= steps))
    # a goal copy: the cheapest one wins outright
    take_goal, g_actions, g_length, g_score, g_cost = pick(
        state, jnp.full((num,), jnp.inf), goal, episode_cost, episode_step, episode_cost)
    # otherwise the best-reward rollout among the finished copies (all copies at the end)
    score = last_cost if config.fallback == 'last_cost' else episode_cost
    candidates = (finished | out_of_budget[:, None]) & (episode_step >= 1) & ~found_now[:, None]
    _, f_actions, f_length, f_score, f_cost = pick(state, state.best_score, candidates, score,
                                                   episode_step, episode_cost)
    best_actions = jnp.where(take_goal[:, None, None], g_actions, f_actions)
    best_length = jnp.where(take_goal, g_length, f_length)
    best_score = jnp.where(take_goal, g_score, f_score)
    best_cost = jnp.where(take_goal, g_cost, f_cost)
    # restart the finished copies from the start state
    restart = finished & ~found_now[:, None]
    start = jax.tree.map(lambda x: jnp.repeat(x[:, None], m, axis=1), state.start)
    node = trees.where(ok, out.next_node, state.node)
    node = trees.where(restart, start, node)
    stop = jnp.select([state.active & found_now, out_of_budget],
                      [StopReason.GOAL, StopReason.BUDGET], state.stop_reason)
    return state.replace(
        node=node, episode_step=jnp.where(restart, 0, episode_step),
        episode_cost=jnp.where(restart, 0.0, episode_cost),
        last_cost=jnp.where(restart, jnp.inf, last_cost),
        episode_actions=jnp.where(restart[:, :, None, None], 0.0, episode_actions),
        best_actions=best_actions, best_length=best_length, best_score=best_score,
        best_cost=best_cost, active=state.active & ~found_now & ~out_of_budget,
        found=state.found | found_now, stop_reason=stop.astype(jnp.int32), evaluated=evaluated,
        invalid=state.invalid + jnp.sum(bad, axis=1, dtype=jnp.int32),
        iterations=state.iterations + state.active,
        restarts=state.restarts + jnp.sum(restart, axis=1, dtype=jnp.int32))

  def run(state: RolloutState) -> RolloutState:
    return jax.lax.while_loop(lambda s: jnp.any(s.active), step, state)

  def stop(state: RolloutState) -> RolloutState:
    """Ends the still-active instances now (e.g. at a wall-clock limit) with TIME_LIMIT: their
    unfinished copies (at least one step) compete for the returned rollout, as at the budget."""
    score = state.last_cost if config.fallback == 'last_cost' else state.episode_cost
    candidates = state.active[:, None] & (state.episode_step >= 1)
    _, actions, length, best_score, cost = pick(state, state.best_score, candidates, score,
                                                state.episode_step, state.episode_cost)
    return state.replace(
        best_actions=actions, best_length=length, best_score=best_score, best_cost=cost,
        active=jnp.zeros_like(state.active),
        stop_reason=jnp.where(state.active, StopReason.TIME_LIMIT,
                              state.stop_reason).astype(jnp.int32))

  def result(state: RolloutState) -> SearchResult:
    nodes, _, _, is_goal = common.replay(env, state.start, state.best_actions, state.best_length)
    return _result(state.found, state.stop_reason, state.best_actions, state.best_length, nodes,
                   is_goal, state.best_cost, state.evaluated, state.invalid,
                   state.evaluated - state.invalid + 1, state.iterations, m * state.iterations)

  def plan(start_nodes: base.NodeState, key: jax.Array) -> SearchResult:
    return result(run(init(start_nodes, key)))

  return ParallelRollout(init=jax.jit(init), step=jax.jit(step, static_argnames='size'),
                         run=jax.jit(run),
                         stop=jax.jit(stop), result=jax.jit(result), plan=jax.jit(plan),
                         config=config)
