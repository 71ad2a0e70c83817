"""A known path that a search replays in its first chain lane: a replanning query's last
answer, without its executed actions, simulated from the new start edge by edge inside the
search's own physics batches, so that the search goes on from where the last one got
(`pachs.evaluate`, `pachs.insert`)."""

from __future__ import annotations

from typing import Optional, Tuple

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Replay:
  """Per instance [I]: actions [I, T, A] float32 the path's actions, length [I] int32 its
  transitions (0: none), done [I] int32 the transitions replayed so far (the replay ends, done
  set to length, at the path's end, at an edge that is not kept, or when its chain stops)."""

  actions: jax.Array
  length: jax.Array
  done: jax.Array

  @property
  def active(self) -> jax.Array:
    """[I] bool the instances whose next chain-lane edge replays the path."""
    return self.done < self.length


def init(num_instances: int, horizon: int, action_size: int,
         path: Optional[Tuple[jax.Array, jax.Array]] = None) -> Replay:
  """The Replay of paths (actions [I, T, A], length [I]) padded to `horizon` (at least 1 row);
  None: nothing to replay. ValueError, one line, for a path longer than horizon."""
  rows = max(horizon, 1)
  if path is None:
    return Replay(actions=jnp.zeros((num_instances, rows, action_size), jnp.float32),
                  length=jnp.zeros((num_instances,), jnp.int32),
                  done=jnp.zeros((num_instances,), jnp.int32))
  actions, length = path
  if actions.ndim != 3 or actions.shape[0] != num_instances or actions.shape[2] != action_size:
    raise ValueError(f'replay actions must be [{num_instances}, T, {action_size}], got '
                     f'{tuple(actions.shape)}')
  if actions.shape[1] > horizon:
    raise ValueError(f'replay paths of {actions.shape[1]} actions exceed the search\'s replay '
                     f'horizon {horizon} (Capacities.replay)')
  pad = rows - actions.shape[1]
  actions = jnp.pad(jnp.asarray(actions, jnp.float32), ((0, 0), (0, pad), (0, 0)))
  length = jnp.clip(jnp.asarray(length, jnp.int32), 0, actions.shape[1] - pad)
  return Replay(actions=actions, length=length, done=jnp.zeros((num_instances,), jnp.int32))


def next_edge(replay: Replay, edge_steps: int):
  """The next edge of each path: (first action [I, A], the actions after it [I, H - 1, A],
  transitions [I] int32: min(H, length - done), 0 where the replay has ended)."""
  rows = jnp.arange(replay.done.shape[0])[:, None]
  horizon = replay.actions.shape[1]
  index = jnp.minimum(replay.done[:, None] + jnp.arange(edge_steps)[None], horizon - 1)
  actions = replay.actions[rows, index]  # [I, H, A]
  steps = jnp.where(replay.active, jnp.minimum(edge_steps, replay.length - replay.done), 0)
  return actions[:, 0], actions[:, 1:], steps.astype(jnp.int32)


def with_first_actions(tip_action: jax.Array, edge, num_chains: int) -> jax.Array:
  """The chains' actions tip_action [I * R, A] with each instance's first chain lane taking
  its replayed edge's first action (`next_edge`'s edge) while its replay lasts."""
  first, _, steps = edge
  lane = (jnp.arange(tip_action.shape[0]) % num_chains == 0) & jnp.repeat(steps > 0, num_chains)
  return jnp.where(lane[:, None], jnp.repeat(first, num_chains, axis=0), tip_action)


def lane_inputs(edge, lane: int, num_lanes: int):
  """(forced [I, K, H - 1, A], forced_steps [I, K]): `next_edge`'s edge in lane `lane` of the
  K, nothing forced in the others (the segment's replay inputs, `segment.make_segment_fn`)."""
  _, forced, steps = edge
  at = jnp.arange(num_lanes) == lane
  return (jnp.where(at[None, :, None, None], forced[:, None], 0.0),
          jnp.where(at[None], steps[:, None], 0))


def advance(replay: Replay, steps: jax.Array, goes_on: jax.Array) -> Replay:
  """replay after its lane's edge: steps [I] int32 the transitions the edge applied, goes_on
  [I] bool the chain goes on from the edge's successor; otherwise the replay ends."""
  done = replay.done + steps
  keep = replay.active & goes_on & (done < replay.length)
  return replay.replace(done=jnp.where(replay.active, jnp.where(keep, done, replay.length),
                                       replay.done).astype(jnp.int32))
