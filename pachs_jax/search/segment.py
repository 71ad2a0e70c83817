"""Policy-segment edges: an edge (s, a) takes its action a and then follows the actor for H - 1
more steps, so that one edge covers H transitions (SearchConfig.edge_steps = H)."""

from __future__ import annotations

from typing import Callable, Tuple

import jax
import jax.numpy as jnp
from flax import struct

from pachs_jax import trees
from pachs_jax.envs import base
from pachs_jax.search.model import ActorCritic, clean_actions, cost_to_go


@struct.dataclass
class SegmentOutcome(base.EdgeOutcome):
  """The `EdgeOutcome` of a batch of H-step edges [B] and what the path needs of their inside.

  next_node: the segment's last state; cost: the sum of its step costs; is_goal: the last
    state satisfies the goal rule; is_valid: the first step was valid.
  actions: [B, H - 1, A] float32 the actor's actions after the edge's own (0 past length).
  nodes: NodeState [B, H - 1, ...] the states after steps 1 .. H - 1 (the last state repeats
    past length).
  length: [B] int32 transitions applied, 1 .. H: a segment stops early at a goal state, and
    before a step that is invalid.
  h: [B] float32 the critic's cost-to-go max(-Q, 0) at the last state, for the actor's action.
  """

  actions: jax.Array
  nodes: base.NodeState
  length: jax.Array
  h: jax.Array


def actor_samples(actor_critic: ActorCritic, keys: jax.Array, obs: jax.Array) -> jax.Array:
  """[B, A] float32 one actor sample per lane, drawn with the lane's own key (so that a lane's
  sample does not depend on the batch it is in); keys [B, 2], obs [B, O]. Non-finite entries
  become 0, and actions are clipped to [-1, 1]."""
  sample = jax.vmap(lambda key, o: actor_critic.sample_actions(key, o[None], 1)[0, 0])
  return clean_actions(sample(keys, obs))


def make_segment_fn(env: base.Env, actor_critic: ActorCritic, edge_steps: int
                    ) -> Callable[[base.NodeState, Tuple[jax.Array, jax.Array]], SegmentOutcome]:
  """segment(nodes [B], (actions [B, A], keys [B, 2] uint32[, forced [B, H - 1, A],
  forced_steps [B] int32])) -> SegmentOutcome [B].

  Step 1 applies the edge's action; steps 2 .. H apply the actor's sample at the current state
  (`actor_samples` with the lane's key folded with the step), or in a lane with forced_steps
  m >= 1 (a replayed path, `replay`) the forced actions, the segment ending after m steps.
  Every lane simulates all H steps (a stopped lane repeats its last state).
  """

  def segment(nodes: base.NodeState, inputs) -> SegmentOutcome:
    first_action, keys, replayed = inputs[0], inputs[1], inputs[2:]
    batch = first_action.shape[0]

    def body(carry, step):
      node, action, _, cost, length, is_goal, done = carry
      out = env.evaluate(node, action)
      take = ~done & out.is_valid & jnp.isfinite(out.cost)
      node = trees.where(take, out.next_node, node)
      cost = cost + jnp.where(take, out.cost, 0.0)
      is_goal = jnp.where(take, out.is_goal, is_goal)
      done = done | ~take | is_goal
      obs = env.observe(node)
      step_keys = jax.vmap(jax.random.fold_in, (0, None))(keys, step)
      next_action = actor_samples(actor_critic, step_keys, obs)
      if replayed:  # (static) the replaying lanes' forced actions, and their end
        forced, forced_steps = replayed
        done = done | ((forced_steps > 0) & (step + 1 >= forced_steps))
        given = forced[:, jnp.minimum(step, forced.shape[1] - 1)]
        next_action = jnp.where((step + 1 < forced_steps)[:, None], given, next_action)
      carry = (node, next_action, obs, cost, length + take, is_goal, done)
      return carry, (jnp.where(take[:, None], action, 0.0), node)

    carry = (nodes, first_action.astype(jnp.float32),
             jnp.zeros((batch, env.observation_size), jnp.float32),
             jnp.zeros((batch,), jnp.float32), jnp.zeros((batch,), jnp.int32),
             jnp.zeros((batch,), bool), jnp.zeros((batch,), bool))
    (last, action, obs, cost, length, is_goal, _), (actions, states) = jax.lax.scan(
        body, carry, jnp.arange(edge_steps))
    # h: the critic at the last state, for the actor's sample there (drawn in the last step)
    h = cost_to_go(actor_critic.q_values(obs, action[:, None]))[:, 0]
    to_lanes = lambda x: jnp.swapaxes(x, 0, 1)  # [H, B, ...] -> [B, H, ...]
    return SegmentOutcome(
        next_node=last, cost=cost, is_goal=is_goal, is_valid=length >= 1,
        actions=to_lanes(actions)[:, 1:], nodes=jax.tree.map(lambda x: to_lanes(x)[:, :-1], states),
        length=length, h=h)

  return segment
