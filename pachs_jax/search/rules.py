"""The rules that tell PACHS's variants apart, as functions passed into one loop: how an edge is
simulated, where a chain of the actor's edges restarts, which state an unfinished search
answers with and what a search does after its first goal (docs/search_loop.md)."""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax.numpy as jnp

from pachs_jax.search import improve
from pachs_jax.search import novelty
from pachs_jax.search import path as path_lib
from pachs_jax.search import pool as pool_lib
from pachs_jax.search import segment
from pachs_jax.search.config import SearchConfig, next_pow2, positive_int


class Edges(NamedTuple):
  """How an edge is simulated.

  steps: H, its transitions (the evaluations it costs).
  simulate(nodes [B], inputs) -> its outcome (`base.EdgeOutcome` or `segment.SegmentOutcome`).
  inputs(actions [I, K, A], keys [I, K, 2], replayed) -> simulate's inputs per lane; replayed:
    (forced [I, K, H - 1, A], forced_steps [I, K]) the lanes that replay a path (`replay`).
  h(q [I, K], outcome) -> [I, K] the successors' cost-to-go estimates.
  """

  steps: int
  simulate: Callable
  inputs: Callable
  h: Callable


def one_step_edges(env) -> Edges:
  """The original's edges: one transition of the sampled action, h = max(q - c, 0)."""
  return Edges(1, env.evaluate, lambda actions, keys, replayed: actions,
               lambda q, outcome: jnp.maximum(q - outcome.cost, 0.0))


def actor_edges(env, actor_critic, steps: int) -> Edges:
  """The sampled action, then steps - 1 actions the actor samples (`segment`); h the critic's
  at the successor."""
  return Edges(steps, segment.make_segment_fn(env, actor_critic, steps),
               lambda actions, keys, replayed: (actions, keys) + replayed,
               lambda q, outcome: outcome.h)


class Restart(NamedTuple):
  """Where a chain of the actor's edges restarts.

  visits(start_cells [I, L], pool_size) -> the `novelty.Visits` the rule keeps.
  record(visits, nodes [I, K], new [I, K], cells [I, K, L]) -> visits with the new nodes.
  choose(pool, visits, keys [I, 2], fits [I, P] bool, num) -> [I, num] restart nodes (or one
    for all).
  """

  visits: Callable
  record: Callable
  choose: Callable


def restart_at_start() -> Restart:
  """Chains restart at the start state: they are rollouts of the actor (visits: one cell and
  one node, never read)."""
  return Restart(
      lambda cells, pool_size: novelty.init(jnp.zeros(cells.shape[:1], jnp.int32), 1, 1),
      lambda visits, *_: visits, lambda *_: pool_lib.ROOT_INDEX)


def restart_novel(coarsening: int = 4) -> Restart:
  """Chains restart at a generated node of a rarely visited coarse cell, a cell of n nodes drawn
  with weight 1 / sqrt(n) (`novelty.sample`): lattice cells merged `coarsening` to a side,
  hashed into the power of two >= 2 * pool size cells."""
  coarsening = positive_int('restart_novel', 'coarsening', coarsening)
  coarse = lambda cells, num_cells: novelty.coarse_cells(cells, coarsening, num_cells)

  def visits(cells, pool_size):
    num_cells = next_pow2(2 * pool_size)
    return novelty.init(coarse(cells, num_cells), pool_size, num_cells)

  def record(visits, node, new, cells):
    return novelty.add(visits, node, new, coarse(cells, visits.nodes_per_cell.shape[1]))

  def choose(pool, visits, keys, fits, num):
    index = jnp.arange(pool.capacity)[None, :]
    eligible = (index < pool.size[:, None]) & ~pool.is_goal & fits
    return novelty.sample(visits, keys, eligible, num)

  return Restart(visits, record, choose)


def best_f_answer(pool, slots: int):
  """The best OPEN entry's state (the original's): no other choice, ([I] int32, [I] False)."""
  num_instances = pool.size.shape[0]
  return (jnp.zeros((num_instances,), jnp.int32), jnp.zeros((num_instances,), bool))


# answer(pool, slots) -> (heap value of the chosen state [I] int32, chosen [I] bool)
ANSWERS = {'best_f': best_f_answer, 'min_h': path_lib.min_h_answer,
           'min_cost': path_lib.min_cost_answer}


class Rules(NamedTuple):
  """The variant of PACHS a loop runs: its `Edges`, chain `Restart`, real-time answer and
  `improve.AfterGoal`."""

  edges: Edges
  restart: Restart
  answer: Callable
  after_goal: improve.AfterGoal = improve.stop_at_goal()


def from_config(env, actor_critic, config: SearchConfig) -> Rules:
  """The rules that config names: edge_steps, chain_restart, realtime_answer and after_goal."""
  steps = config.edge_steps
  edges = one_step_edges(env) if steps == 1 else actor_edges(env, actor_critic, steps)
  lanes = config.rollout_lanes
  restart = (restart_novel() if config.chain_restart == 'novel' and lanes > 0
             else restart_at_start())
  after_goal = (improve.improve_after_goal() if config.after_goal == 'improve'
                else improve.stop_at_goal())
  return Rules(edges, restart, ANSWERS[config.realtime_answer], after_goal)
