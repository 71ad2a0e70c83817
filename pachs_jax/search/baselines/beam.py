"""Parallel beam search: the actor samples, the critic keeps the beam; I instances at once
(docs/baselines.md)."""

from __future__ import annotations

import dataclasses
from typing import Callable, Optional, Tuple

import jax
import jax.numpy as jnp

from pachs_jax import trees
from pachs_jax.envs import base
from pachs_jax.search import lattice as lattice_lib
from pachs_jax.search.baselines import common
from pachs_jax.search.checks import (check_actor_critic, check_start_nodes, env_lattice_resolution,
                                     instance_keys)
from pachs_jax.search.config import (check_weight, lattice_resolution_tuple, normalize_numbers,
                                     positive_int)
from pachs_jax.search.model import ActorCritic, clean_actions, cost_to_go
from pachs_jax.search.result import SearchResult, StopReason

SCORES = ('edge', 'next')


@dataclasses.dataclass(frozen=True)
class BeamConfig:
  """beam_width: B states kept per step; num_actions: N actions sampled per beam state;
  budget: edge evaluations per instance; max_depth: steps (None: env.episode_length), also
  the path buffer length; weight: w on the critic's cost-to-go; score: 'edge' or 'next';
  dedup: merge candidates of one lattice cell; lattice_resolution: cell sizes (None: env's)."""

  beam_width: int = 64
  num_actions: int = 16
  budget: int = 100_000
  max_depth: Optional[int] = None
  weight: float = 1.0
  score: str = 'edge'
  dedup: bool = True
  lattice_resolution: Optional[Tuple[float, ...]] = None

  def __post_init__(self):
    normalize_numbers(self)
    for name in ('beam_width', 'num_actions', 'budget'):
      positive_int('BeamConfig', name, getattr(self, name))
    positive_int('BeamConfig', 'max_depth', self.max_depth, allow_none=True)
    check_weight('BeamConfig', self.weight)
    if self.score not in SCORES:
      raise ValueError(f'BeamConfig.score must be one of {SCORES}, got {self.score!r}')
    object.__setattr__(self, 'lattice_resolution',
                       lattice_resolution_tuple('BeamConfig', self.lattice_resolution))


def _first_in_cell(cells: jax.Array, score: jax.Array, ok: jax.Array) -> jax.Array:
  """[C] bool: ok and no better-ranked ok entry of one instance's cells [C, L] shares the cell
  (ranked by (score, position))."""
  h = lattice_lib.hash_keys(cells)
  order = jnp.lexsort((jnp.arange(score.shape[0]), score, h))  # by hash, then score, position
  c, okk, hh = cells[order], ok[order], h[order]
  dup = (hh[1:] == hh[:-1]) & jnp.all(c[1:] == c[:-1], axis=-1) & okk[:-1]
  dup = jnp.concatenate([jnp.zeros((1,), bool), dup])
  # a chain A, A, A marks all but the first: each later one repeats its ok predecessor
  return ok & ~jnp.zeros_like(ok).at[order].set(dup)


def _backtrack(parents, actions, depth, slot):
  """Actions [I, D, A] of the path to beam slot [I] at depth [I] (parents [I, D, B])."""
  num, max_depth = parents.shape[:2]
  rows = jnp.arange(num)
  out = jnp.zeros((num, max_depth, actions.shape[-1]), jnp.float32)

  def body(i, c):
    out, slot = c
    k = max_depth - 1 - i
    here = k < depth
    out = out.at[rows, k].set(jnp.where(here[:, None], actions[rows, k, slot], 0.0))
    slot = jnp.where(here, parents[rows, k, slot], slot)
    return out, slot

  out, _ = jax.lax.fori_loop(0, max_depth, body, (out, slot))
  return out


def make_beam_search(env: base.Env, actor_critic: ActorCritic, config: BeamConfig = BeamConfig()
                     ) -> Callable[..., SearchResult]:
  """A jitted fn(start_nodes [I], key) -> SearchResult (key: one PRNG key or [I, 2])."""
  if not isinstance(config, BeamConfig):
    raise ValueError(f'config must be a BeamConfig, got {type(config).__name__}')
  check_actor_critic(actor_critic, ('sample_actions', 'q_values'))
  b, n, budget = config.beam_width, config.num_actions, config.budget
  depth_limit = config.max_depth or env.episode_length
  w = float(config.weight)
  a_size = env.action_size
  resolution = env_lattice_resolution(env, config.lattice_resolution)
  weighted = (lambda q: q * w) if w else jnp.zeros_like

  def policy_q(key, obs):
    """[C] cost-to-go of one policy action at each of obs [C, O]."""
    if callable(getattr(actor_critic, 'deterministic_action', None)):
      act = actor_critic.deterministic_action(obs)[:, None]
    else:
      act = actor_critic.sample_actions(key, obs, 1)
    act = clean_actions(act)
    return cost_to_go(actor_critic.q_values(obs, act))[:, 0]

  def search(start_nodes: base.NodeState, key: jax.Array) -> SearchResult:
    num = check_start_nodes(start_nodes, env)
    keys = instance_keys(key, num)
    rows = jnp.arange(num)
    start_goal = env.is_goal(start_nodes)
    zeros = jnp.zeros((num,), jnp.int32)
    carry = dict(
        beam=jax.tree.map(lambda x: jnp.repeat(x[:, None], b, axis=1), start_nodes),
        g=jnp.zeros((num, b), jnp.float32),
        key=jnp.full((num, b), jnp.inf, jnp.float32).at[:, 0].set(0.0),
        valid=jnp.zeros((num, b), bool).at[:, 0].set(True),
        parents=jnp.zeros((num, depth_limit, b), jnp.int32),
        actions=jnp.zeros((num, depth_limit, b, a_size), jnp.float32),
        depth=zeros, t=jnp.zeros((), jnp.int32), active=~start_goal, found=start_goal,
        stop=jnp.where(start_goal, StopReason.GOAL, StopReason.RUNNING).astype(jnp.int32),
        expanded=zeros, evaluated=zeros, invalid=zeros, iterations=zeros,
        generated=jnp.ones((num,), jnp.int32))

    def cond(c):
      return jnp.any(c['active'])

    def body(c):
      active, t = c['active'], c['t']
      flat = jax.tree.map(lambda x: x.reshape((num * b,) + x.shape[2:]), c['beam'])
      obs = env.observe(flat)
      step_keys = jax.vmap(jax.random.fold_in)(keys, jnp.full((num,), t))
      k_sample = jax.vmap(lambda k: jax.random.split(k)[0])(step_keys)
      k_next = jax.vmap(lambda k: jax.random.split(k)[1])(step_keys)
      act = jax.vmap(lambda k, o: actor_critic.sample_actions(k, o, n))(
          k_sample, obs.reshape(num, b, -1))
      act = clean_actions(act)  # [I, B, N, A]
      sources = c['valid'] & active[:, None]
      cand = jnp.repeat(sources, n, axis=1)  # [I, B * N] in (slot, action) order
      left = budget - c['evaluated']
      within = cand & (jnp.cumsum(cand, axis=1) <= left[:, None])
      src = jax.tree.map(lambda x: jnp.repeat(x, n, axis=0), flat)
      out = env.evaluate(src, act.reshape(num * b * n, a_size))
      out = jax.tree.map(lambda x: x.reshape((num, b * n) + x.shape[1:]), out)
      ok = within & out.is_valid & jnp.isfinite(out.cost)
      g_src = jnp.repeat(c['g'], n, axis=1)
      g_next = g_src + out.cost
      if config.score == 'edge':
        q = cost_to_go(actor_critic.q_values(obs, act.reshape(num * b, n, a_size)))
        rank = g_src + weighted(q.reshape(num, b * n))
      else:
        next_flat = jax.tree.map(lambda x: x.reshape((num * b * n,) + x.shape[2:]),
                                 out.next_node)
        qn = policy_q(k_next[0], env.observe(next_flat)).reshape(num, b * n)
        rank = g_next + weighted(qn)
      rank = jnp.where(ok & ~jnp.isnan(rank), rank, jnp.inf)
      goal = ok & out.is_goal
      found_now = jnp.any(goal, axis=1)
      # the cheapest goal candidate goes first into the beam
      best_goal = jnp.argmin(jnp.where(goal, g_next, jnp.inf), axis=1)
      rank = jnp.where(found_now[:, None] & (jnp.arange(b * n)[None] == best_goal[:, None]),
                       -jnp.inf, rank)
      keep = ok
      if config.dedup:
        next_flat = jax.tree.map(lambda x: x.reshape((num * b * n,) + x.shape[2:]),
                                 out.next_node)
        cells = env.lattice_key(next_flat, resolution).reshape(num, b * n, -1)
        keep = jax.vmap(_first_in_cell)(cells, rank, ok)
      rank = jnp.where(keep, rank, jnp.inf)
      neg, idx = jax.lax.top_k(-rank, min(b, b * n))
      new_valid = neg > -jnp.inf
      advance = active & jnp.any(ok, axis=1)
      take = lambda x: jnp.take_along_axis(x, idx.reshape(idx.shape + (1,) * (x.ndim - 2)),
                                           axis=1)
      new_beam = jax.tree.map(take, out.next_node)
      new_actions = take(act.reshape(num, b * n, a_size))
      slot_t = jnp.where(advance, c['depth'], depth_limit)  # out of bounds: dropped
      parents = c['parents'].at[rows, slot_t].set(idx // n, mode='drop')
      actions = c['actions'].at[rows, slot_t].set(new_actions, mode='drop')
      depth = c['depth'] + advance
      evaluated = c['evaluated'] + jnp.sum(within, axis=1, dtype=jnp.int32)
      empty = active & ~jnp.any(ok, axis=1)
      out_of_budget = active & ~found_now & (evaluated >= budget)
      too_deep = active & ~found_now & (depth >= depth_limit)
      stop = jnp.select([active & found_now, empty, out_of_budget, too_deep],
                        [StopReason.GOAL, StopReason.OPEN_EMPTY, StopReason.BUDGET,
                         StopReason.ITERATIONS], c['stop'])
      adv = advance[:, None]
      return dict(
          beam=trees.where(adv, new_beam, c['beam']),
          g=jnp.where(adv, take(g_next), c['g']),
          key=jnp.where(adv, -neg, c['key']),
          valid=jnp.where(adv, new_valid, c['valid']),
          parents=parents, actions=actions, depth=depth, t=t + 1,
          active=active & (stop == StopReason.RUNNING), found=c['found'] | (active & found_now),
          stop=stop.astype(jnp.int32),
          expanded=c['expanded'] + jnp.sum(sources, axis=1, dtype=jnp.int32),
          evaluated=evaluated, iterations=c['iterations'] + active,
          invalid=c['invalid'] + jnp.sum(within & ~ok, axis=1, dtype=jnp.int32),
          generated=c['generated'] + jnp.sum(ok, axis=1, dtype=jnp.int32))

    c = jax.lax.while_loop(cond, body, carry)
    # a goal sits in slot 0 (ranked -inf); otherwise the best-ranked state of the last beam
    final = jnp.where(c['found'], 0, jnp.argmin(jnp.where(c['valid'], c['key'], jnp.inf),
                                                axis=1))
    path_actions = _backtrack(c['parents'], c['actions'], c['depth'], final)
    nodes, _, _, is_goal = common.replay(env, start_nodes, path_actions, c['depth'])
    iterations = c['iterations']
    lanes = b * n * iterations
    return SearchResult(
        found=c['found'], stop_reason=c['stop'], path_actions=path_actions,
        path_length=c['depth'], path_nodes=nodes, path_truncated=jnp.zeros_like(c['found']),
        path_is_goal=is_goal, cost=c['g'][rows, final], expanded=c['expanded'],
        evaluated=c['evaluated'], invalid=c['invalid'], generated=c['generated'],
        iterations=iterations,
        lane_utilization=jnp.where(lanes > 0, c['evaluated'] / jnp.maximum(lanes, 1),
                                   0.0).astype(jnp.float32),
        heap_overflow=zeros, pool_overflow=zeros, table_overflow=zeros,
        wall_time_s=jnp.float32(jnp.nan))

  return jax.jit(search)
