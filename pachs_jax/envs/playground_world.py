"""A MuJoCo C world (float64) for a MuJoCo Playground task: MuJoCo C simulates, the env's own
`step` supplies the control and the observation, reward and goal around it (how, and the
module-wide replacement of `mjx_env.step` while its programs compile: docs/closed_loop.md)."""

from __future__ import annotations

import contextlib
import copy
import dataclasses
from typing import Callable, List, Optional

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from pachs_jax.envs import base, playground


@contextlib.contextmanager
def _mjx_env_step_replaced(step: Callable):
  """Within the block, Playground's `mjx_env.step` (what its envs call to simulate) is step."""
  from mujoco_playground._src import mjx_env  # pylint: disable=import-outside-toplevel
  original = mjx_env.step
  mjx_env.step = step
  try:
    yield
  finally:
    mjx_env.step = original


@dataclasses.dataclass(frozen=True)
class _Call:
  """What the env's step asked of `mjx_env.step` while traced: its control [nu], the data it
  passed and n_substeps."""
  ctrl: jax.Array
  data: object
  n_substeps: int


# the integration-state fields an env's step may set before simulating, which the world then
# takes over (ctrl comes as the call's own argument; time is the world's)
EDITABLE_FIELDS = tuple(f for f in playground.STATE_FIELDS if f not in ('ctrl', 'time'))


class WorldSteps:
  """The two compiled halves of a Playground env's step around MuJoCo C physics, shared by
  the worlds of one env.

  env: the `playground.PlaygroundEnv` (MJX's JAX or Warp implementation).
  control(node, action [A]) -> (ctrl [nu] float32, edits): the control the env's step applies
    (to the action sanitized as the planner's edges do: `base.sanitize_actions`) and, per
    `EDITABLE_FIELDS` field of the env's Data, (the value the step passed to the physics, []
    bool whether the step changed it from the node's).
  finish(node, action [A], fields) -> the node after the step, where fields (dict of the
    public mjx.Data fields, `fields`; `fields_of` an MjData's) is the simulated data.
  n_substeps: physics steps per control step (the env's).
  Raises ValueError when the env's step does not call `mjx_env.step` exactly once.
  """

  def __init__(self, env: playground.PlaygroundEnv):
    self.env = env
    node = jax.eval_shape(env.sample_instance, jax.random.PRNGKey(0))
    action = jax.ShapeDtypeStruct((env.action_size,), jnp.float32)
    data = jax.eval_shape(env.state_from_node, node).data
    # every array field of mjx.Data but the implementation's private ones
    self.fields = tuple(f.name for f in dataclasses.fields(data)
                        if not f.name.startswith('_') and hasattr(getattr(data, f.name), 'shape'))
    self.field_specs = {f: getattr(data, f) for f in self.fields}
    calls: List[_Call] = []

    def control(node, action):
      def record(model, data, ctrl, n_substeps=1):
        del model
        calls.append(_Call(jnp.asarray(ctrl, jnp.float32), data, int(n_substeps)))
        return data
      state = env.state_from_node(node)
      with _mjx_env_step_replaced(record):
        env.playground_env.step(state, base.sanitize_actions(action)[0])
      if len(calls) != 1:
        raise ValueError(f'{env.name}: its step called mujoco_playground\'s mjx_env.step '
                         f'{len(calls)} times; a MuJoCo C world runs an env whose step calls '
                         'it once')
      passed = calls[0].data
      edits = {f: (getattr(passed, f), jnp.any(getattr(passed, f) != getattr(state.data, f)))
               for f in EDITABLE_FIELDS if f in self.fields}
      return calls[0].ctrl, edits

    self.control = jax.jit(control).lower(node, action).compile()
    self.n_substeps = calls[0].n_substeps
    finished = []

    def finish(node, action, fields):
      state = env.state_from_node(node)
      simulated = state.data.replace(**fields)

      def simulate(model, data, ctrl, n_substeps=1):
        del model, data, ctrl, n_substeps
        finished.append(True)
        return simulated
      with _mjx_env_step_replaced(simulate):
        stepped = env.playground_env.step(state, base.sanitize_actions(action)[0])
      return env.node_from_state(stepped, node.t + 1)

    self.finish = jax.jit(finish).lower(node, action, self.field_specs).compile()
    if len(finished) != 1:
      raise ValueError(f'{env.name}: its step called mjx_env.step {len(finished)} times')

  def fields_of(self, data: mujoco.MjData) -> dict:
    """The public mjx.Data fields of an MjData, in the shapes and dtypes of the env's Data."""
    return {f: np.asarray(getattr(data, f), spec.dtype).reshape(spec.shape)
            for f, spec in self.field_specs.items()}


class PlaygroundWorld:
  """One Playground episode's world in MuJoCo C (float64), with `world.World`'s interface.

  env: the `playground.PlaygroundEnv` whose MjModel the world simulates.
  steps: the env's `WorldSteps` (None: built here; pass one to share it between worlds).
  """

  def __init__(self, env: playground.PlaygroundEnv, steps: Optional[WorldSteps] = None):
    if not isinstance(env, playground.PlaygroundEnv):
      raise ValueError(f'PlaygroundWorld needs a Playground env, got {type(env).__name__}')
    self.env = env
    self.steps = steps if steps is not None else WorldSteps(env)
    self.model = copy.deepcopy(env.playground_env.mj_model)
    self.data = mujoco.MjData(self.model)
    self._node = None

  def reset(self, node: base.NodeState) -> base.NodeState:
    """Puts the world into a single node's state (its integration state,
    `playground.STATE_FIELDS`); returns the node. ValueError for a node with a batch axis."""
    if np.shape(node.qpos) != (self.model.nq,):
      raise ValueError(f'reset takes one node of {self.env.name} (qpos [{self.model.nq}]), got '
                       f'qpos of shape {np.shape(node.qpos)}')
    state = jax.tree.map(np.asarray, self.env.state_from_node(node).data)
    for field in playground.STATE_FIELDS:
      value = getattr(state, field, None)
      target = getattr(self.data, field, None)
      if value is None or target is None or np.size(value) != np.size(target) or not np.size(
          value):
        continue
      if np.ndim(target) == 0:
        setattr(self.data, field, float(value))
      else:
        target[...] = np.asarray(value).reshape(np.shape(target))
    mujoco.mj_forward(self.model, self.data)
    self._node = jax.tree.map(np.asarray, node)
    return self._node

  def observe(self) -> base.NodeState:
    """The node of the world's current state (float32, as the env's)."""
    return self._node

  def execute(self, actions) -> List[base.NodeState]:
    """Applies actions [T, A] (one control step each); returns the T observed nodes."""
    actions = np.asarray(actions, np.float32)
    if actions.ndim != 2 or actions.shape[1] != self.env.action_size:
      raise ValueError(f'actions must have shape [T, {self.env.action_size}], '
                       f'got {actions.shape}')
    nodes = []
    for action in actions:
      ctrl, edits = jax.tree.map(np.asarray, self.steps.control(self._node, action))
      for field, (value, changed) in edits.items():  # what the env's step set before simulating
        if changed:
          getattr(self.data, field)[...] = np.asarray(value).reshape(
              getattr(self.data, field).shape)
      self.data.ctrl[:] = ctrl.reshape(self.data.ctrl.shape)
      mujoco.mj_step(self.model, self.data, nstep=self.steps.n_substeps)
      self._node = jax.tree.map(np.asarray, self.steps.finish(
          self._node, action, self.steps.fields_of(self.data)))
      nodes.append(self._node)
    return nodes
