"""After the first goal: the incumbent goal of each instance, and the improvement phase that
spends an allowance of further evaluations on chains of the actor's edges restarted at nodes of
the incumbent's path, keeping any goal reached at a lower cost (anytime search, shortcuts by
re-simulation; docs/search_loop.md)."""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax.search import novelty
from pachs_jax.search import pool as pool_lib
from pachs_jax.search.phases import NO_NODE


@struct.dataclass
class Incumbent:
  """Per instance [I]: node int32 the cheapest goal node found (NO_NODE: none), cost float32 its
  g (inf: none); first_evaluated, first_iterations int32 the evaluations and iterations when the
  first goal was found, first_cost float32 that goal's g (-1, -1, inf before);
  evaluation_limit int32 the evaluations the instance may spend (the budget, then the first
  goal's evaluations plus the improvement allowance)."""

  node: jax.Array
  cost: jax.Array
  first_evaluated: jax.Array
  first_iterations: jax.Array
  first_cost: jax.Array
  evaluation_limit: jax.Array

  @property
  def found(self) -> jax.Array:
    return self.node != NO_NODE


def init(num_instances: int, budget: int) -> Incumbent:
  """No incumbent yet; every instance may spend the budget."""
  none = jnp.full((num_instances,), -1, jnp.int32)
  inf = jnp.full((num_instances,), jnp.inf, jnp.float32)
  return Incumbent(node=none, cost=inf, first_evaluated=none, first_iterations=none,
                   first_cost=inf, evaluation_limit=jnp.full((num_instances,), budget, jnp.int32))


def offer(incumbent: Incumbent, found: jax.Array, goal: jax.Array,
          cost: jax.Array) -> Incumbent:
  """incumbent with the goal nodes goal [I] of g cost [I] (where found [I]) that cost less
  than it."""
  better = found & (cost < incumbent.cost)
  return incumbent.replace(node=jnp.where(better, goal, incumbent.node).astype(jnp.int32),
                           cost=jnp.where(better, cost, incumbent.cost))


def cheapest(pool: pool_lib.NodePool, node: jax.Array, at_goal: jax.Array):
  """(found [I], goal [I], cost [I]): the cheapest of the goal nodes node [I, K] where at_goal
  [I, K], and its g."""
  cost = jnp.where(at_goal, pool_lib.gather(pool.g, node), jnp.inf)
  best = jnp.argmin(cost, axis=1)[:, None]
  return (jnp.any(at_goal, axis=1), jnp.take_along_axis(node, best, axis=1)[:, 0],
          jnp.take_along_axis(cost, best, axis=1)[:, 0])


def settle(incumbent: Incumbent, evaluated: jax.Array, iterations: jax.Array,
           allowance: float, budget: int) -> Incumbent:
  """incumbent with the first goal recorded where it was found this iteration (evaluated,
  iterations [I]: the counts after it) and the evaluation limit set to the first goal's
  evaluations times 1 + allowance, at most the budget (allowance inf: the budget)."""
  first = incumbent.found & (incumbent.first_evaluated < 0)
  extra = (jnp.full(evaluated.shape, float(budget)) if math.isinf(allowance) else
           jnp.minimum(evaluated.astype(jnp.float32) * (1.0 + allowance), float(budget)))
  return incumbent.replace(
      first_evaluated=jnp.where(first, evaluated, incumbent.first_evaluated),
      first_iterations=jnp.where(first, iterations, incumbent.first_iterations),
      first_cost=jnp.where(first, incumbent.cost, incumbent.first_cost),
      evaluation_limit=jnp.where(first, jnp.ceil(extra).astype(jnp.int32),
                                 incumbent.evaluation_limit))


def on_path(pool: pool_lib.NodePool, final: jax.Array) -> jax.Array:
  """[I, P] bool: the nodes of the path from the start to node final [I] (none where final is
  NO_NODE)."""
  rows = jnp.arange(final.shape[0])

  def body(carry):
    node, mask = carry
    live = node >= 0
    mask = mask.at[rows, jnp.where(live, node, pool.capacity)].set(True, mode='drop')
    return jnp.where(live, pool.parent[rows, jnp.maximum(node, 0)], NO_NODE), mask

  _, mask = jax.lax.while_loop(lambda carry: jnp.any(carry[0] >= 0), body,
                               (final.astype(jnp.int32), jnp.zeros(pool.g.shape, bool)))
  return mask


def path_restarts(pool: pool_lib.NodePool, incumbent: Incumbent, keys: jax.Array,
                  fits: jax.Array, num: int) -> jax.Array:
  """[I, num] int32 restart nodes on the incumbent's path (goals and nodes whose next edge
  would not fit, fits [I, P] False, left out), each drawn with weight incumbent cost - g (the
  most a shortcut from it can save: early nodes first); keys [I, 2]. Node 0 without an
  incumbent."""
  eligible = on_path(pool, incumbent.node) & fits & ~pool.is_goal
  saving = jnp.where(eligible, incumbent.cost[:, None] - pool.g, 0.0)
  share = saving / jnp.maximum(jnp.max(saving, axis=1, keepdims=True), 1e-30)
  scale = (2**31 - 1) // pool.capacity
  weight = jnp.where(eligible, jnp.maximum(jnp.floor(share * scale), 1.0), 0.0)
  return novelty.draw(weight.astype(jnp.int32), keys, num)


class AfterGoal(NamedTuple):
  """What an instance's search does once it holds a goal (`config.after_goal`), as functions of
  one loop iteration.

  working(active [I], found [I]) -> [I] the instances that expand and evaluate this iteration.
  prune(mask [I, K], parent_g [I, K], incumbent) -> mask of the edges worth evaluating.
  goal_lanes(chain_lane [I, K]) -> [I, K] the lanes whose generated goals are offered.
  restarts(pool, incumbent, keys [I, 2], fits [I, P], restarts [I, R]) -> the chains' restarts.
  done(incumbent, evaluated [I], stopping [I]) -> [I] the instances whose search ends with
    their goal (stopping: out of budget, OPEN empty, overflow or the iteration limit).
  """

  working: Callable
  prune: Callable
  goal_lanes: Callable
  restarts: Callable
  done: Callable


def stop_at_goal() -> AfterGoal:
  """'stop': the first goal (popped, or generated by a chain) ends the search."""
  return AfterGoal(working=lambda active, found: active & ~found,
                   prune=lambda mask, parent_g, incumbent: mask,
                   goal_lanes=lambda chain_lane: chain_lane,
                   restarts=lambda pool, incumbent, keys, fits, restarts: restarts,
                   done=lambda incumbent, evaluated, stopping: incumbent.found)


def improve_after_goal() -> AfterGoal:
  """'improve': after the first goal the search spends its allowance (`settle`) on edges that
  cost less than the incumbent, its chains restarting on the incumbent's path; any lane's goal
  that costs less replaces the incumbent."""

  def restarts(pool, incumbent, keys, fits, chosen):
    # the path walk and draw run only once some instance has a goal
    path_keys = jax.vmap(lambda key: jax.random.fold_in(key, 1))(keys)
    return jax.lax.cond(
        jnp.any(incumbent.found),
        lambda: jnp.where(incumbent.found[:, None], path_restarts(
            pool, incumbent, path_keys, fits, chosen.shape[1]), chosen),
        lambda: chosen)

  return AfterGoal(
      working=lambda active, found: active,
      prune=lambda mask, parent_g, incumbent: mask & (parent_g < incumbent.cost[:, None]),
      goal_lanes=lambda chain_lane: jnp.ones_like(chain_lane),
      restarts=restarts,
      done=lambda incumbent, evaluated, stopping: incumbent.found & (
          (evaluated >= incumbent.evaluation_limit) | stopping))
