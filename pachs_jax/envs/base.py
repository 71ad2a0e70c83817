"""The environment interface shared by SAC training (Brax-style `reset`, `step`, `State`) and
the search (batched `evaluate`, `observe`, `lattice_key`, `is_goal` on compact `NodeState`s)."""

from __future__ import annotations

import abc
import functools
from typing import Any, Dict

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class NodeState:
  """Everything that restores a simulation exactly; a leading batch axis is optional.

  qpos: [..., nq] generalised positions (m, rad).
  qvel: [..., nv] generalised velocities (m/s, rad/s).
  ctrl: [..., nu] actuator targets (joint position targets, rad).
  qacc_warmstart: [..., nv] the constraint solver's warm start (m/s^2, rad/s^2).
  goal: [..., G] the task's goal parameters (PushT: x, y, yaw; shelf: target x, y, z).
  t: [...] int32 control steps taken since the episode start.
  """

  qpos: jax.Array
  qvel: jax.Array
  ctrl: jax.Array
  qacc_warmstart: jax.Array
  goal: jax.Array
  t: jax.Array


@struct.dataclass
class EdgeOutcome:
  """The result of evaluating a batch of edges (s, a).

  next_node: NodeState [B, ...] the successor states s'.
  cost: [B] float32 edge cost c(s, a) = -r(s, a) >= 0.
  is_goal: [B] bool, s' satisfies the task's success rule.
  is_valid: [B] bool, the edge is usable (no collision, within limits, finite state).
  """

  next_node: NodeState
  cost: jax.Array
  is_goal: jax.Array
  is_valid: jax.Array


@struct.dataclass
class State:
  """Brax-style training state (the same fields as `brax.envs.State`).

  pipeline_state: NodeState [...] the compact simulation state.
  obs: [..., observation_size] float32.
  reward: [...] float32, non-positive.
  done: [...] float32, 1.0 on success or at the time limit.
  metrics: dict of [...] float32 (includes 'success').
  info: dict of auxiliary arrays (includes 'truncation').
  """

  pipeline_state: NodeState
  obs: jax.Array
  reward: jax.Array
  done: jax.Array
  metrics: Dict[str, jax.Array] = struct.field(default_factory=dict)
  info: Dict[str, Any] = struct.field(default_factory=dict)


class Env(abc.ABC):
  """A task with a training interface and a search interface over the same transition.

  `step` goes through `transition` on the compact node state, so a node restored from a
  training state and stepped reproduces the training transition bit for bit.
  """

  name: str
  episode_length: int
  goal_size: int

  # ---- search interface: single-node functions, vmapped by the batched wrappers ----

  @abc.abstractmethod
  def sample_instance(self, key: jax.Array) -> NodeState:
    """A random start node (start state and goal) of the task's distribution; no batch axis."""

  @abc.abstractmethod
  def transition(self, node: NodeState, action: jax.Array) -> EdgeOutcome:
    """One edge (s, a) -> s' for a single node; the only place where physics happens."""

  @abc.abstractmethod
  def observation(self, node: NodeState) -> jax.Array:
    """[observation_size] float32 network input of one node."""

  @abc.abstractmethod
  def lattice_coords(self, node: NodeState, resolution: jax.Array) -> jax.Array:
    """[L] int32 lattice coordinates of one node; `resolution` [L] cell sizes."""

  @abc.abstractmethod
  def goal_reached(self, node: NodeState) -> jax.Array:
    """[] bool success rule of one node."""

  @property
  @abc.abstractmethod
  def default_lattice_resolution(self) -> jax.Array:
    """[L] float32 default cell sizes of `lattice_coords` (units of the lattice coordinates)."""

  @property
  def lattice_extent(self):
    """[L] the largest |value| (units of `default_lattice_resolution`) of each coordinate that
    `lattice_coords` divides by the cell size, over the task's valid states; None: unknown.
    The search refuses cell sizes below lattice_extent / 2**30, which would overflow the int32
    lattice coordinates (`search.checks.env_lattice_resolution`)."""
    return None

  # The engine that simulates the env's edges ('jax': its own JAX transition; 'mjx', 'warp',
  # 'mujoco-c': MuJoCo's): plans made in one engine replay to other states in another.
  physics: str = 'jax'

  @property
  def physics_settings(self) -> dict | None:
    """The settings of the physics model its engine simulates (PushT: time step, substeps,
    solver, T body, friction and contact parameters), as JSON values: what a model trained on
    it and a plan made in it record. None: nothing beyond the task itself."""
    return None

  @property
  def fingerprint(self) -> str | None:
    """A string that, with the package sources, fixes everything the env's functions close
    over, so that a traced search program of it may be stored and reused across processes
    (`compile_cache.compiled_program`); None (the default): never stored."""
    return None

  # ---- batched search interface: leading batch axis B ----

  def evaluate(self, nodes: NodeState, actions: jax.Array) -> EdgeOutcome:
    """Evaluates B edges: nodes [B], actions [B, action_size] in [-1, 1]."""
    check_actions(actions, self.action_size, batched=True)
    return jax.vmap(self.transition)(nodes, actions)

  def observe(self, nodes: NodeState) -> jax.Array:
    """[B, observation_size] observations of a batch of nodes."""
    return jax.vmap(self.observation)(nodes)

  def lattice_key(self, nodes: NodeState, resolution: jax.Array | None = None) -> jax.Array:
    """[B, L] int32 lattice coordinates of a batch of nodes."""
    res = self.default_lattice_resolution if resolution is None else jnp.asarray(resolution)
    return jax.vmap(lambda n: self.lattice_coords(n, res))(nodes)

  def is_goal(self, nodes: NodeState) -> jax.Array:
    """[B] bool success rule of a batch of nodes."""
    return jax.vmap(self.goal_reached)(nodes)

  def is_failure(self, nodes: NodeState) -> jax.Array:
    """[B] bool states no edge can leave validly (an episode there has failed; PushT: the
    free T tipped over). Default: none."""
    return jnp.zeros(jax.tree.leaves(nodes)[0].shape[:1], bool)

  def initial_nodes(self, keys: jax.Array) -> NodeState:
    """[B] random start nodes, one per key in keys [B, 2]."""
    return jax.vmap(self.sample_instance)(keys)

  # ---- training interface (Brax style), on a single environment ----

  @functools.cached_property
  def node_spec(self) -> NodeState:
    """The shapes and dtypes of one node, no batch axis (`sample_instance` traced once)."""
    return jax.eval_shape(self.sample_instance, jax.ShapeDtypeStruct((2,), jnp.uint32))

  @functools.cached_property
  def observation_size(self) -> int:
    """Length O of `observation` (traced once, not computed)."""
    return int(jax.eval_shape(self.observation, self.node_spec).shape[-1])

  @property
  @abc.abstractmethod
  def action_size(self) -> int:
    """Number of action dimensions; actions live in [-1, 1]^action_size."""

  def reset(self, key: jax.Array) -> State:
    """A fresh episode from the task's start distribution (no batch axis)."""
    node = self.sample_instance(key)
    zero = jnp.zeros((), jnp.float32)
    metrics = {'success': zero, 'cost': zero}
    info = {'truncation': zero}
    return State(node, self.observation(node), zero, zero, metrics, info)

  def step(self, state: State, action: jax.Array) -> State:
    """One control step; reward = -cost, done on success, invalid edge or time limit."""
    check_actions(action, self.action_size, batched=False)
    return _stepped(self, state, self.transition(state.pipeline_state, action))

  def step_batch(self, states: State, actions: jax.Array) -> State:
    """`step` of B environments, states [B] and actions [B, action_size], whose physics is one
    `evaluate` call (one Warp or MuJoCo C call for the batch, not B of them)."""
    check_actions(actions, self.action_size, batched=True)
    outcomes = self.evaluate(states.pipeline_state, actions)
    return jax.vmap(lambda s, o: _stepped(self, s, o))(states, outcomes)


def _stepped(env: Env, state: State, out: EdgeOutcome) -> State:
  """The State after `state`'s edge with outcome `out` (one environment, no batch axis)."""
  node = out.next_node
  success = out.is_goal.astype(jnp.float32)
  invalid = 1.0 - out.is_valid.astype(jnp.float32)
  time_up = (node.t >= env.episode_length).astype(jnp.float32)
  done = jnp.maximum(jnp.maximum(success, invalid), time_up)
  # A truncation is a time limit without a terminal event (bootstrapping continues).
  truncation = time_up * (1.0 - jnp.maximum(success, invalid))
  metrics = {'success': success, 'cost': out.cost}
  info = dict(state.info, truncation=truncation)
  return State(node, env.observation(node), -out.cost, done, metrics, info)


def check_actions(actions: jax.Array, action_size: int, batched: bool) -> None:
  """Raises a clear error for a wrong action shape (shapes are static under jit)."""
  shape = jnp.shape(actions)
  want = 2 if batched else 1
  if len(shape) != want or shape[-1] != action_size:
    expected = '[B, %d]' % action_size if batched else '[%d]' % action_size
    raise ValueError(f'actions must have shape {expected}, got {tuple(shape)}')


def finite_node(node: NodeState) -> jax.Array:
  """[] bool: every float of a single node is finite."""
  leaves = [node.qpos, node.qvel, node.ctrl, node.qacc_warmstart]
  return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves]))


def sanitize_actions(action: jax.Array) -> tuple[jax.Array, jax.Array]:
  """(clipped action with non-finite entries zeroed, [] bool all entries finite)."""
  ok = jnp.all(jnp.isfinite(action))
  clean = jnp.where(jnp.isfinite(action), action, 0.0)
  return jnp.clip(clean, -1.0, 1.0), ok


def config_fingerprint(env: Env) -> str:
  """`Env.fingerprint` of an env that its class and its frozen `config` fix."""
  return f'{type(env).__qualname__}({env.config!r})'
