"""MPPI (model-predictive path integral control), batched over I problem instances
(docs/baselines.md)."""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Optional

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax import trees
from pachs_jax.envs import base
from pachs_jax.search.baselines import common
from pachs_jax.search.checks import check_actor_critic, check_start_nodes, instance_keys
from pachs_jax.search.config import normalize_numbers, positive_int
from pachs_jax.search.model import ActorCritic, clean_actions, cost_to_go
from pachs_jax.search.result import SearchResult, StopReason

FALLBACKS = ('nominal', 'best')


def _finite_number(owner: str, name: str, value, positive: bool) -> None:
  """ValueError unless value is a finite number > 0 (positive) or >= 0."""
  ok = (not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
        and (value > 0 if positive else value >= 0))
  if not ok:
    bound = '> 0' if positive else '>= 0'
    raise ValueError(f'{owner}.{name} must be a finite number {bound}, got {value!r}')


@dataclasses.dataclass(frozen=True)
class MppiConfig:
  """MPPI parameters (per instance).

  num_samples: S action sequences per iteration; horizon: H edges per sequence (also the
  returned path's buffer length); temperature: lambda > 0 of the softmax weights, in cost
  units; noise_std: std of the Gaussian perturbation, in action units ([-1, 1]);
  max_iterations: iterations per plan; budget: edge evaluations (an iteration costs S * H);
  policy_prior_samples: P of the S sequences drawn from the stochastic policy (None: S // 8);
  terminal_weight: weight >= 0 of the critic's cost-to-go at a rollout's last state;
  invalid_penalty: cost >= 0 charged per edge from a rollout's first invalid edge to the
  horizon's end; fallback: the path returned without a goal, 'nominal' (the final nominal)
  or 'best' (the lowest-score sampled sequence).
  """

  num_samples: int = 256
  horizon: int = 16
  temperature: float = 1.0
  noise_std: float = 0.3
  max_iterations: int = 8
  budget: int = 100_000
  policy_prior_samples: Optional[int] = None
  terminal_weight: float = 1.0
  invalid_penalty: float = 10.0
  fallback: str = 'nominal'

  def __post_init__(self):
    normalize_numbers(self)
    for name in ('num_samples', 'horizon', 'max_iterations', 'budget'):
      positive_int('MppiConfig', name, getattr(self, name))
    _finite_number('MppiConfig', 'temperature', self.temperature, positive=True)
    for name in ('noise_std', 'terminal_weight', 'invalid_penalty'):
      _finite_number('MppiConfig', name, getattr(self, name), positive=False)
    p = self.policy_prior_samples
    if p is not None and (isinstance(p, bool) or not isinstance(p, int)
                          or not 0 <= p <= self.num_samples):
      raise ValueError('MppiConfig.policy_prior_samples must be None or an int in '
                       f'[0, num_samples = {self.num_samples}], got {p!r}')
    if self.evaluations_per_iteration > self.budget:
      raise ValueError('MppiConfig.budget must cover one iteration of num_samples * '
                       f'horizon = {self.evaluations_per_iteration} evaluations, got '
                       f'{self.budget}')
    if self.fallback not in FALLBACKS:
      raise ValueError(f'MppiConfig.fallback must be one of {FALLBACKS}, got {self.fallback!r}')

  @property
  def num_policy_samples(self) -> int:
    """P: sequences per iteration drawn from the stochastic policy."""
    if self.policy_prior_samples is None:
      return self.num_samples // 8
    return self.policy_prior_samples

  @property
  def evaluations_per_iteration(self) -> int:
    """S * H edges evaluated per instance and iteration."""
    return self.num_samples * self.horizon


@struct.dataclass
class MppiState(common.SamplingState):
  """MPPI's state between iterations, leading axis I: the fields of `common.SamplingState` and

  nominal: [I, H, A] float32 nominal actions in [-1, 1].
  best_actions: [I, H, A] the lowest-score sampled sequence so far; best_score: [I] its score
    (+inf before the first iteration).
  nominal_score: [I] score of the last iteration's noise-free nominal sample (+inf if none).
  goal_actions: [I, H, A] the cheapest goal-reaching sampled rollout's actions up to its goal
    (rows >= goal_length are 0); goal_length: [I] int32; goal_cost: [I] its summed edge cost.
  live: [I] int32 edges evaluated (S * H per iteration) on rollouts that had not ended (no
    goal, no invalid edge yet), of which `invalid` were invalid (each ends its rollout) and
    applied: [I] int32 moved it.
  """

  nominal: jax.Array
  best_actions: jax.Array
  best_score: jax.Array
  nominal_score: jax.Array
  goal_actions: jax.Array
  goal_length: jax.Array
  goal_cost: jax.Array
  live: jax.Array
  applied: jax.Array


@dataclasses.dataclass(frozen=True)
class Mppi:
  """Jitted functions: init(start_nodes [I], key, nominal [I, H, A] | None) -> MppiState;
  step(state) -> state after one iteration (stopped instances unchanged); run(state) -> state
  when all instances stopped; result(state) -> SearchResult. `runtime.anytime.run_search`
  runs them to the end or under a wall clock."""

  init: Callable[..., MppiState]
  step: Callable[[MppiState], MppiState]
  run: Callable[[MppiState], MppiState]
  result: Callable[[MppiState], SearchResult]
  config: MppiConfig


def shift_plan(actions: jax.Array, num_steps: int) -> jax.Array:
  """actions [I, H, A] without their first num_steps rows, padded by repeating the last row:
  the warm start of the next MPC query after executing num_steps actions."""
  horizon = actions.shape[1]
  index = jnp.minimum(jnp.arange(horizon) + num_steps, horizon - 1)
  return actions[:, index]


def make_mppi(env: base.Env, actor_critic: ActorCritic, config: MppiConfig = MppiConfig()
              ) -> Mppi:
  """Builds the jitted MPPI planner for env, actor_critic and config.

  The actor-critic needs deterministic_action(obs [B, O]) -> [B, A] (warm start, terminal
  cost), sample_actions when P > 0 and q_values when terminal_weight > 0.
  """
  if not isinstance(config, MppiConfig):
    raise ValueError(f'config must be an MppiConfig, got {type(config).__name__}')
  needed = ['deterministic_action']
  if config.num_policy_samples:
    needed.append('sample_actions')
  if config.terminal_weight:
    needed.append('q_values')
  check_actor_critic(actor_critic, needed)
  s, h, p = config.num_samples, config.horizon, config.num_policy_samples
  per_iteration, budget = config.evaluations_per_iteration, config.budget
  a_size = env.action_size
  penalty = float(config.invalid_penalty)
  weight = float(config.terminal_weight)

  def policy_rollout(start_nodes, steps):
    """[I, steps, A] deterministic policy actions from start_nodes [I] (an invalid edge leaves
    the state unchanged)."""
    def body(node, _):
      action = clean_actions(actor_critic.deterministic_action(env.observe(node)))
      out = env.evaluate(node, action)
      ok = out.is_valid & jnp.isfinite(out.cost)
      return trees.where(ok, out.next_node, node), action

    _, actions = jax.lax.scan(body, start_nodes, None, length=steps)
    return jnp.swapaxes(actions, 0, 1)

  def init(start_nodes: base.NodeState, key: jax.Array,
           nominal: Optional[jax.Array] = None) -> MppiState:
    num = check_start_nodes(start_nodes, env)
    keys = instance_keys(key, num)
    if nominal is None:
      nominal = policy_rollout(start_nodes, h)
    elif jnp.shape(nominal) != (num, h, a_size):
      raise ValueError(f'nominal must have shape [I, H, A] = {(num, h, a_size)}, '
                       f'got {jnp.shape(nominal)}')
    nominal = clean_actions(jnp.asarray(nominal))
    start_goal = env.is_goal(start_nodes)
    zeros = jnp.zeros((num,), jnp.int32)
    inf = jnp.full((num,), jnp.inf, jnp.float32)
    return MppiState(
        nominal=nominal, best_actions=nominal, best_score=inf,
        nominal_score=inf, goal_actions=jnp.zeros((num, h, a_size), jnp.float32),
        goal_length=zeros, goal_cost=jnp.zeros((num,), jnp.float32), live=zeros, applied=zeros,
        **common.sampling_start(start_nodes, keys, start_goal))

  def sample(state: MppiState):
    """Rolls S sequences per instance. Returns (actions [I, S, H, A], score [I, S], cost [I, S]
    summed edge cost up to the goal or end, goal_length [I, S] int32 (0: no goal), and the
    [I] int32 edge counts invalid, live, applied)."""
    num = state.active.shape[0]
    keys = jax.vmap(jax.random.fold_in)(state.rng, state.iterations)
    keys = jax.vmap(lambda k: jax.random.split(k, h + 1))(keys)  # [I, H + 1, 2]
    noise = config.noise_std * jax.vmap(
        lambda k: jax.random.normal(k, (s - p, h, a_size), jnp.float32))(keys[:, 0])
    noise = noise.at[:, :1].set(0.0)  # the nominal itself (no-op when s == p)
    planned = jnp.clip(state.nominal[:, None] + noise, -1.0, 1.0)  # [I, S - P, H, A]
    step_keys = jnp.swapaxes(keys[:, 1:], 0, 1)  # [H, I, 2] keys of the policy samples

    def body(c, xs):
      node, alive, cost, extra, goal_length, t = c
      planned_t, key_t = xs  # [I, S - P, A], [I, 2]
      if p:
        obs = env.observe(jax.tree.map(lambda x: x.reshape((num, s) + x.shape[1:])[:, :p]
                                       .reshape((num * p,) + x.shape[1:]), node))
        obs = obs.reshape(num, p, -1)
        prior = jax.vmap(lambda k, o: actor_critic.sample_actions(k, o, 1)[:, 0])(key_t, obs)
        action = jnp.concatenate([clean_actions(prior), planned_t], axis=1)
      else:
        action = planned_t
      out = env.evaluate(node, action.reshape(num * s, a_size))
      ok = out.is_valid & jnp.isfinite(out.cost)
      applied = alive & ok
      reached = applied & out.is_goal
      extra = extra + jnp.where(alive & ~ok, penalty * (h - t), 0.0)
      c = (trees.where(applied, out.next_node, node), applied & ~out.is_goal,
           cost + jnp.where(applied, out.cost, 0.0), extra,
           jnp.where(reached, t + 1, goal_length), t + 1)
      counts = tuple(jnp.sum(x.reshape(num, s), axis=1, dtype=jnp.int32)
                     for x in (alive & ~ok, alive, applied))
      return c, (action, counts)

    start = jax.tree.map(lambda x: jnp.repeat(x, s, axis=0), state.start)  # [I * S]
    zeros_f = jnp.zeros((num * s,), jnp.float32)
    carry = (start, jnp.ones((num * s,), bool), zeros_f, zeros_f,
             jnp.zeros((num * s,), jnp.int32), jnp.zeros((), jnp.int32))
    xs = (jnp.moveaxis(planned, 2, 0), step_keys)
    (last, _, cost, extra, goal_length, _), (actions, counts) = jax.lax.scan(body, carry, xs)
    score = cost + extra
    if weight:
      obs = env.observe(last)
      q = actor_critic.q_values(
          obs, clean_actions(actor_critic.deterministic_action(obs))[:, None])
      score = score + jnp.where(goal_length > 0, 0.0, weight * cost_to_go(q)[:, 0])
    actions = jnp.moveaxis(actions, 0, 2)  # [I, S, H, A]
    return (actions, score.reshape(num, s), cost.reshape(num, s), goal_length.reshape(num, s),
            *(jnp.sum(x, axis=0) for x in counts))

  def step(state: MppiState) -> MppiState:
    num = state.active.shape[0]
    rows = jnp.arange(num)
    actions, score, cost, goal_length, invalid, live, applied = sample(state)
    score = jnp.where(jnp.isnan(score), jnp.inf, score)
    # softmax weights over the finite scores; without any, the nominal stays
    low = jnp.min(score, axis=1, keepdims=True)
    finite = jnp.isfinite(score)
    w = jnp.where(finite, jnp.exp(-(score - jnp.where(jnp.isfinite(low), low, 0.0))
                                  / config.temperature), 0.0)
    total = jnp.sum(w, axis=1, keepdims=True)
    mean = jnp.einsum('is,isha->iha', w / jnp.maximum(total, 1e-30), actions)
    nominal = jnp.where(total[:, :, None] > 0, clean_actions(mean), state.nominal)
    # lowest score so far
    j = jnp.argmin(score, axis=1)
    better = score[rows, j] < state.best_score
    best_actions = jnp.where(better[:, None, None], actions[rows, j], state.best_actions)
    best_score = jnp.where(better, score[rows, j], state.best_score)
    # the cheapest goal-reaching rollout (ties: the lowest sample index)
    goal_cost = jnp.where(goal_length > 0, cost, jnp.inf)
    g = jnp.argmin(goal_cost, axis=1)
    found_now = jnp.any(goal_length > 0, axis=1)
    length = goal_length[rows, g]
    prefix = jnp.where((jnp.arange(h)[None, :] < length[:, None])[:, :, None],
                       actions[rows, g], 0.0)
    nominal_score = score[:, p] if p < s else jnp.full((num,), jnp.inf, jnp.float32)
    # stopping
    active = state.active
    iterations = state.iterations + 1
    evaluated = state.evaluated + per_iteration
    out_of_iterations = iterations >= config.max_iterations
    out_of_budget = evaluated + per_iteration > budget
    stop = jnp.select([found_now, out_of_iterations, out_of_budget],
                      [StopReason.GOAL, StopReason.ITERATIONS, StopReason.BUDGET],
                      StopReason.RUNNING)
    new = state.replace(
        nominal=nominal, best_actions=best_actions, best_score=best_score,
        nominal_score=nominal_score,
        goal_actions=jnp.where(found_now[:, None, None], prefix, state.goal_actions),
        goal_length=jnp.where(found_now, length, state.goal_length),
        goal_cost=jnp.where(found_now, goal_cost[rows, g], state.goal_cost),
        active=stop == StopReason.RUNNING, found=state.found | found_now,
        stop_reason=stop.astype(jnp.int32), evaluated=evaluated,
        invalid=state.invalid + invalid, live=state.live + live,
        applied=state.applied + applied, iterations=iterations)
    return trees.where(active, new, state)

  def run(state: MppiState) -> MppiState:
    return jax.lax.while_loop(lambda st: jnp.any(st.active), step, state)

  def executable_length(start, actions):
    """[I] int32: edges of actions [I, H, A] before the first invalid one, through the first
    goal state."""
    def body(c, action):
      node, length, going = c
      out = env.evaluate(node, action)
      ok = going & out.is_valid & jnp.isfinite(out.cost)
      return (trees.where(ok, out.next_node, node), length + ok, ok & ~out.is_goal), None

    num = actions.shape[0]
    carry = (start, jnp.zeros((num,), jnp.int32), ~env.is_goal(start))
    (_, length, _), _ = jax.lax.scan(body, carry, jnp.swapaxes(actions, 0, 1))
    return length

  def result(state: MppiState) -> SearchResult:
    fallback = state.nominal if config.fallback == 'nominal' else state.best_actions
    fallback_length = executable_length(state.start, fallback)
    actions = jnp.where(state.found[:, None, None], state.goal_actions,
                        jnp.where((jnp.arange(h)[None, :] < fallback_length[:, None])[:, :, None],
                                  fallback, 0.0))
    length = jnp.where(state.found, state.goal_length, fallback_length)
    nodes, cost, _, is_goal = common.replay(env, state.start, actions, length)
    evaluated = state.evaluated
    zeros = jnp.zeros_like(evaluated)
    return SearchResult(
        found=state.found, stop_reason=state.stop_reason, path_actions=actions,
        path_length=length, path_nodes=nodes, path_truncated=jnp.zeros_like(state.found),
        path_is_goal=is_goal, cost=cost, expanded=evaluated, evaluated=evaluated,
        invalid=state.invalid, generated=state.applied + 1,
        iterations=state.iterations,
        lane_utilization=jnp.where(evaluated > 0, state.live / jnp.maximum(evaluated, 1),
                                   0.0).astype(jnp.float32),
        heap_overflow=zeros, pool_overflow=zeros, table_overflow=zeros,
        wall_time_s=jnp.float32(jnp.nan))

  return Mppi(init=jax.jit(init), step=jax.jit(step), run=jax.jit(run),
              result=jax.jit(result), config=config)
