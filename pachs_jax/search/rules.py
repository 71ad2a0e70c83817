"""The rules that tell PACHS's variants apart, as functions passed into one loop: how an edge is
simulated, where a chain of the actor's edges restarts, and which state an unfinished search
answers with (docs/search_loop.md)."""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax.numpy as jnp

from pachs_jax.search import novelty
from pachs_jax.search import path as path_lib
from pachs_jax.search import pool as pool_lib
from pachs_jax.search import segment
from pachs_jax.search.config import SearchConfig


class Edges(NamedTuple):
  """How an edge is simulated.

  steps: H, its transitions (the evaluations it costs).
  simulate(nodes [B], inputs) -> its outcome (`base.EdgeOutcome` or `segment.SegmentOutcome`).
  inputs(actions [I, K, A], keys [I, K, 2]) -> simulate's inputs per lane.
  h(q [I, K], outcome) -> [I, K] the successors' cost-to-go estimates.
  """

  steps: int
  simulate: Callable
  inputs: Callable
  h: Callable


def one_step_edges(env) -> Edges:
  """The original's edges: one transition of the sampled action, h = max(q - c, 0)."""
  return Edges(1, env.evaluate, lambda actions, keys: actions,
               lambda q, outcome: jnp.maximum(q - outcome.cost, 0.0))


def actor_edges(env, actor_critic, steps: int) -> Edges:
  """The sampled action, then steps - 1 actions the actor samples (`segment`); h the critic's
  at the successor."""
  return Edges(steps, segment.make_segment_fn(env, actor_critic, steps),
               lambda actions, keys: (actions, keys), lambda q, outcome: outcome.h)


class Restart(NamedTuple):
  """Where a chain of the actor's edges restarts.

  visits(start_cells [I, C]) -> the `novelty.Visits` the rule keeps.
  record(visits, nodes [I, K], new [I, K], cells [I, K, L]) -> visits with the new nodes.
  choose(pool, visits, keys [I, 2], fits [I, P] bool, num) -> [I, num] restart nodes (or one
    for all).
  """

  visits: Callable
  record: Callable
  choose: Callable


def restart_at_start(config: SearchConfig) -> Restart:
  """Chains restart at the start state: they are rollouts of the actor."""
  return Restart(
      lambda cells: novelty.init(novelty.coarse_cells(
          cells, config.novelty_coarsening, config.novelty_cells), 1, config.novelty_cells),
      lambda visits, *_: visits, lambda *_: pool_lib.ROOT_INDEX)


def restart_novel(config: SearchConfig) -> Restart:
  """Chains restart at a generated node drawn with weight 1 / the nodes in its coarse cell."""
  coarse = lambda cells: novelty.coarse_cells(cells, config.novelty_coarsening,
                                              config.novelty_cells)

  def choose(pool, visits, keys, fits, num):
    index = jnp.arange(pool.capacity)[None, :]
    eligible = (index < pool.size[:, None]) & ~pool.is_goal & fits
    return novelty.sample(visits, keys, eligible, num)

  return Restart(lambda cells: novelty.init(coarse(cells), config.pool_size, config.novelty_cells),
                 lambda visits, node, new, cells: novelty.add(visits, node, new, coarse(cells)),
                 choose)


def best_f_answer(pool, slots: int):
  """The best OPEN entry's state (the original's): no other choice, ([I] int32, [I] False)."""
  num_instances = pool.size.shape[0]
  return (jnp.zeros((num_instances,), jnp.int32), jnp.zeros((num_instances,), bool))


# answer(pool, slots) -> (heap value of the chosen state [I] int32, chosen [I] bool)
ANSWERS = {'best_f': best_f_answer, 'min_h': path_lib.min_h_answer,
           'min_cost': path_lib.min_cost_answer}


class Rules(NamedTuple):
  """The variant of PACHS a loop runs: its `Edges`, chain `Restart` and real-time answer."""

  edges: Edges
  restart: Restart
  answer: Callable


def from_config(env, actor_critic, config: SearchConfig) -> Rules:
  """The rules that config names: edge_steps, chain_restart and realtime_answer."""
  steps = config.edge_steps
  edges = one_step_edges(env) if steps == 1 else actor_edges(env, actor_critic, steps)
  novel = config.chain_restart == 'novel' and config.rollout_lanes > 0
  restart = restart_novel(config) if novel else restart_at_start(config)
  return Rules(edges, restart, ANSWERS[config.realtime_answer])
