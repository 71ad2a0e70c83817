"""MuJoCo C (float64, CPU threads) for PushT: NodeState <-> MuJoCo C state conversion and the
`MujocoCEnv` search backend (`envs.backends` chooses among the engines; `envs.world` executes
plans in closed loop); docs/tasks.md."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import threading
from typing import Optional

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout

from pachs_jax.envs import base, host_call, pusht

FULLPHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS


# ---- one node <-> one MjData ----

def node_to_mjdata(env: pusht.PushTEnv, node: base.NodeState, data: mujoco.MjData) -> None:
  """Writes a single node's simulation state (qpos, qvel, ctrl, qacc_warmstart) into data.

  time is set to 0; derived quantities are not recomputed (call mj_forward if needed).
  """
  _check_single(env, node)
  data.time = 0.0
  data.qpos[:] = np.asarray(node.qpos, np.float64)
  data.qvel[:] = np.asarray(node.qvel, np.float64)
  data.ctrl[:] = np.asarray(node.ctrl, np.float64)
  data.qacc_warmstart[:] = np.asarray(node.qacc_warmstart, np.float64)


def mjdata_to_node(env: pusht.PushTEnv, data: mujoco.MjData, goal, t) -> base.NodeState:
  """The float32 node of data's state with goal [G] and step count t (numpy leaves)."""
  del env
  return base.NodeState(qpos=np.asarray(data.qpos, np.float32).copy(),
                        qvel=np.asarray(data.qvel, np.float32).copy(),
                        ctrl=np.asarray(data.ctrl, np.float32).copy(),
                        qacc_warmstart=np.asarray(data.qacc_warmstart, np.float32).copy(),
                        goal=np.asarray(goal, np.float32).copy(),
                        t=np.asarray(t, np.int32).copy())


def _check_single(env: pusht.PushTEnv, node: base.NodeState) -> None:
  m = env.mj_model
  for name, size in (('qpos', m.nq), ('qvel', m.nv), ('ctrl', m.nu), ('qacc_warmstart', m.nv)):
    shape = np.shape(getattr(node, name))
    if shape != (size,):
      raise ValueError(f'node.{name} must have shape ({size},) for {env.name}, got {shape}')


# ---- batches <-> full-physics state vectors ----

@dataclasses.dataclass(frozen=True)
class _StateLayout:
  """Where qpos, qvel and time sit in a model's mjSTATE_FULLPHYSICS vector.

  size: entries per state vector; time, qpos, qvel: offsets; nq, nv: sizes.
  template: [size] float64 the state of a freshly reset MjData (mocap, eq_active, ... defaults).
  """

  size: int
  time: int
  qpos: int
  qvel: int
  nq: int
  nv: int
  template: np.ndarray


def _state_layout(model: mujoco.MjModel) -> _StateLayout:
  """The layout of the full-physics state: its components in increasing mjtState bit order."""
  offsets, offset = {}, 0
  for bit in range(int(mujoco.mjtState.mjNSTATE)):
    component = 1 << bit
    if int(FULLPHYSICS) & component:
      offsets[component] = offset
      offset += mujoco.mj_stateSize(model, component)
  size = mujoco.mj_stateSize(model, FULLPHYSICS)
  if offset != size:
    raise RuntimeError(f'full-physics state layout mismatch: {offset} != {size}')
  data = mujoco.MjData(model)
  template = np.zeros(size)
  mujoco.mj_getState(model, data, template, FULLPHYSICS)
  s = mujoco.mjtState
  return _StateLayout(size, offsets[int(s.mjSTATE_TIME)], offsets[int(s.mjSTATE_QPOS)],
                     offsets[int(s.mjSTATE_QVEL)], model.nq, model.nv, template)


def _nodes_to_states(layout: _StateLayout, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
  """[B, size] float64 full-physics states (time 0) of qpos [B, nq] and qvel [B, nv]."""
  state = np.tile(layout.template, (qpos.shape[0], 1))
  state[:, layout.time] = 0.0
  state[:, layout.qpos:layout.qpos + layout.nq] = qpos
  state[:, layout.qvel:layout.qvel + layout.nv] = qvel
  return state


def _states_to_qpos_qvel(layout: _StateLayout, state: np.ndarray) -> tuple:
  """(qpos [..., nq], qvel [..., nv], time [...]) float64 of states [..., size]."""
  qpos = state[..., layout.qpos:layout.qpos + layout.nq]
  qvel = state[..., layout.qvel:layout.qvel + layout.nv]
  return qpos, qvel, state[..., layout.time]


def batch_to_rollout(env: pusht.PushTEnv, nodes: base.NodeState) -> tuple:
  """(initial_state [B, size], initial_warmstart [B, nv], ctrl [B, nu]) float64 of nodes [B]."""
  layout = _state_layout(env.mj_model)
  qpos = np.asarray(nodes.qpos, np.float64)
  if qpos.ndim != 2 or qpos.shape[1] != layout.nq:
    raise ValueError(f'nodes.qpos must have shape [B, {layout.nq}], got {qpos.shape}')
  state = _nodes_to_states(layout, qpos, np.asarray(nodes.qvel, np.float64))
  return (state, np.asarray(nodes.qacc_warmstart, np.float64),
          np.asarray(nodes.ctrl, np.float64))


def rollout_to_batch(env: pusht.PushTEnv, state: np.ndarray, warmstart: np.ndarray,
                     ctrl: np.ndarray, goal, t) -> base.NodeState:
  """Float32 nodes [B] of full-physics states [B, size], warm starts [B, nv], ctrl [B, nu]."""
  layout = _state_layout(env.mj_model)
  qpos, qvel, _ = _states_to_qpos_qvel(layout, np.asarray(state))
  return base.NodeState(qpos=qpos.astype(np.float32), qvel=qvel.astype(np.float32),
                        ctrl=np.asarray(ctrl, np.float32),
                        qacc_warmstart=np.asarray(warmstart, np.float32),
                        goal=np.asarray(goal, np.float32), t=np.asarray(t, np.int32))


# ---- the batched physics: one rollout call per batch ----

class _Simulator:
  """A persistent `mujoco.rollout.Rollout` over one model: held ctrl, `substeps` steps.
  `close()` stops its threads; a later call starts them again (the custom call of a program
  compiled for an env that was closed reaches an equal simulator: `host_call`)."""

  def __init__(self, model: mujoco.MjModel, substeps: int, nthread: int):
    self.model = model
    self.substeps = substeps
    self.layout = _state_layout(model)
    self.nthread = nthread
    self._runner = rollout.Rollout(nthread=nthread)
    self._datas = [mujoco.MjData(model) for _ in range(max(nthread, 1))]
    self._scratch = mujoco.MjData(model)
    self._lock = threading.Lock()

  def site_position(self, site: int, qpos):
    """[..., 3] float32 world position of a site at qpos [..., nq] (float64 mj_kinematics)."""
    lead = np.shape(qpos)[:-1]
    qpos = np.asarray(qpos, np.float64).reshape(-1, self.model.nq)
    out = np.zeros((qpos.shape[0], 3), np.float32)
    with self._lock:
      d = self._scratch
      for i, q in enumerate(qpos):
        d.qpos[:] = q
        mujoco.mj_kinematics(self.model, d)
        out[i] = d.site_xpos[site]
    return out.reshape(lead + (3,))

  def close(self):
    with self._lock:
      if self._runner is not None:
        self._runner.close()
        self._runner = None

  def __call__(self, qpos, qvel, warmstart, ctrl):
    """float32 (qpos [..., nq], qvel [..., nv], qacc_warmstart [..., nv], ok [...] bool) after
    `substeps` physics steps from qpos, qvel, warmstart with ctrl [..., nu] held.

    ok is False where the input or output is not finite or MuJoCo reset the data (divergence).
    """
    lead = np.shape(qpos)[:-1]
    m, lay = self.model, self.layout
    qpos = np.asarray(qpos, np.float64).reshape(-1, m.nq)
    qvel = np.asarray(qvel, np.float64).reshape(-1, m.nv)
    warm = np.asarray(warmstart, np.float64).reshape(-1, m.nv)
    ctrl = np.asarray(ctrl, np.float64).reshape(-1, m.nu)
    num = qpos.shape[0]
    ok_in = (np.isfinite(qpos).all(1) & np.isfinite(qvel).all(1) & np.isfinite(warm).all(1)
             & np.isfinite(ctrl).all(1))
    # Non-finite rows run from the model's reference state (their result is discarded).
    qpos = np.where(ok_in[:, None], qpos, lay.template[lay.qpos:lay.qpos + m.nq])
    qvel = np.where(ok_in[:, None], qvel, 0.0)
    warm = np.where(ok_in[:, None], warm, 0.0)
    ctrl = np.where(ok_in[:, None], ctrl, qpos[:, :m.nu])
    out_qpos = np.zeros((num, m.nq), np.float32)
    out_qvel = np.zeros((num, m.nv), np.float32)
    out_warm = np.zeros((num, m.nv), np.float32)
    ok = np.zeros((num,), bool)
    if num:
      state = _nodes_to_states(lay, qpos, qvel)
      with self._lock:
        if self._runner is None:
          self._runner = rollout.Rollout(nthread=self.nthread)
        traj, _ = self._runner.rollout([m] * num, self._datas[:max(self.nthread, 1)], state,
                                       ctrl[:, None, :], nstep=self.substeps,
                                       initial_warmstart=warm)
      q, v, time = _states_to_qpos_qvel(lay, traj)
      prev_v = v[:, -2] if self.substeps > 1 else qvel
      acc = (v[:, -1] - prev_v) / m.opt.timestep
      # mj_step resets the data (time back to 0) when the state diverges.
      expected = self.substeps * m.opt.timestep
      reset = np.abs(time[:, -1] - expected) > 1e-6 * max(expected, 1.0)
      big = np.finfo(np.float32).max
      finite = (np.all(np.abs(q[:, -1]) < big, 1) & np.all(np.abs(v[:, -1]) < big, 1)
                & np.all(np.abs(acc) < big, 1))
      ok = ok_in & ~reset & finite
      out_qpos = q[:, -1].astype(np.float32)
      out_qvel = v[:, -1].astype(np.float32)
      out_warm = acc.astype(np.float32)
    return (out_qpos.reshape(lead + (m.nq,)), out_qvel.reshape(lead + (m.nv,)),
            out_warm.reshape(lead + (m.nv,)), ok.reshape(lead))


def _model_digest(model: mujoco.MjModel) -> str:
  """16 hex digits of the SHA-256 of the model's binary (MJB) form."""
  buffer = np.empty(mujoco.mj_sizeModel(model), np.uint8)
  mujoco.mj_saveModel(model, None, buffer)
  return hashlib.sha256(buffer.tobytes()).hexdigest()[:16]


# ---- the search / training backend ----

class MujocoCEnv(base.Env):
  """A PushT env whose physics runs in MuJoCo C on CPU threads; all else is the wrapped env's.

  env: the `PushTEnv` to wrap (its `mj_model`, config and JAX scoring code are used).
  nthread: rollout threads (None: os.cpu_count()).
  """

  def __init__(self, env: pusht.PushTEnv, nthread: Optional[int] = None):
    if not isinstance(env, pusht.PushTEnv):
      raise ValueError(f'MujocoCEnv wraps a PushTEnv, got {type(env).__name__}')
    nthread = (os.cpu_count() or 1) if nthread is None else nthread
    if isinstance(nthread, bool) or not isinstance(nthread, int) or nthread < 1:
      raise ValueError(f'nthread must be a positive int or None, got {nthread!r}')
    self.env = env
    self.name = env.name
    self.episode_length = env.episode_length
    self.goal_size = env.goal_size
    self.nthread = nthread
    self._sim = _Simulator(env.mj_model, env.config.substeps, nthread)
    self._lower = jnp.asarray(env._arm_lower)
    self._upper = jnp.asarray(env._arm_upper)
    # the programs call the simulator as XLA custom calls named by what they compute (the
    # model's bytes, the substeps, the site), so that JAX's persistent cache stores them
    digest = _model_digest(env.mj_model)
    self._step_target = f'pachs_mujoco_c_step_{digest}_{env.config.substeps}'
    self._tip_target = f'pachs_mujoco_c_site_{digest}_{env._tip_site}'
    host_call.register(self._step_target, self._sim)
    host_call.register(self._tip_target, functools.partial(self._sim.site_position,
                                                           env._tip_site))

  physics = 'mujoco-c'

  @property
  def physics_settings(self) -> dict:
    return self.env.physics_settings

  def __getattr__(self, name):
    # Only reached for attributes this wrapper lacks (config, mj_model, node_from_pose, ...).
    if name in ('env', '_sim'):
      raise AttributeError(name)
    return getattr(self.env, name)

  def close(self):
    """Stops the rollout threads."""
    self._sim.close()

  # ---- delegated single-node functions ----

  def sample_instance(self, key):
    return self.env.sample_instance(key)

  # observation and lattice coordinates run PushTEnv's own code with this wrapper as `self`,
  # so that their tip position comes from MuJoCo C (mjx.kinematics costs ~15 ms a node on CPU).

  def observation(self, node):
    return pusht.PushTEnv.observation(self, node)

  def lattice_coords(self, node, resolution):
    return pusht.PushTEnv.lattice_coords(self, node, resolution)

  def tip_position(self, node: base.NodeState) -> jax.Array:
    """[3] world position of the stick tip (m), by MuJoCo C forward kinematics (any leading
    batch shape of node.qpos; one simulator call per call, also under vmap)."""
    qpos = jnp.asarray(node.qpos, jnp.float32)
    spec = jax.ShapeDtypeStruct(qpos.shape[:-1] + (3,), jnp.float32)
    return host_call.call(self._tip_target, (spec,), qpos)[0]

  def goal_reached(self, node):
    return self.env.goal_reached(node)

  @property
  def default_lattice_resolution(self):
    return self.env.default_lattice_resolution

  @property
  def lattice_extent(self):
    return self.env.lattice_extent

  @property
  def action_size(self) -> int:
    return self.env.action_size

  @property
  def observation_size(self) -> int:
    return self.env.observation_size

  # ---- physics ----

  def simulate(self, qpos, qvel, qacc_warmstart, ctrl):
    """(qpos, qvel, qacc_warmstart, ok) after `substeps` MuJoCo C steps with ctrl held.

    Any leading batch shape; one rollout call per call (also under vmap).
    """
    m = self.env.mj_model
    lead = jnp.shape(qpos)[:-1]
    f32 = lambda n: jax.ShapeDtypeStruct(lead + (n,), jnp.float32)
    spec = (f32(m.nq), f32(m.nv), f32(m.nv), jax.ShapeDtypeStruct(lead, jnp.bool_))
    args = [jnp.asarray(x, jnp.float32) for x in (qpos, qvel, qacc_warmstart, ctrl)]
    return tuple(host_call.call(self._step_target, spec, *args))

  def evaluate(self, nodes: base.NodeState, actions: jax.Array) -> base.EdgeOutcome:
    """Evaluates B edges in MuJoCo C: nodes [B], actions [B, action_size] in [-1, 1]."""
    shape = jnp.shape(actions)
    if len(shape) != 2 or shape[-1] != self.action_size:
      raise ValueError(f'actions must have shape [B, {self.action_size}], got {tuple(shape)}')
    if jnp.shape(nodes.qpos)[:1] != shape[:1]:
      raise ValueError(f'nodes and actions must share the batch size, got nodes.qpos '
                       f'{jnp.shape(nodes.qpos)} and actions {tuple(shape)}')
    action, action_ok = jax.vmap(base.sanitize_actions)(actions)
    target = jnp.clip(nodes.qpos[:, :7] + pusht.ARM_ACTION_SCALE * action, self._lower,
                      self._upper)
    qpos, qvel, warm, ok = self.simulate(nodes.qpos, nodes.qvel, nodes.qacc_warmstart, target)
    stepped = base.NodeState(qpos=qpos, qvel=qvel, ctrl=target, qacc_warmstart=warm,
                             goal=nodes.goal, t=nodes.t + 1)
    return jax.vmap(self._score)(nodes, stepped, ok, action_ok)

  def _score(self, node, next_node, ok, action_ok) -> base.EdgeOutcome:
    """The MJX transition's validity, cost and success rule for one simulated edge."""
    env = self.env
    finite = ok & base.finite_node(next_node)
    on_table = pusht.stays_on_table(node.qpos, next_node.qpos)
    upright = pusht.t_tilt(next_node.qpos) < pusht.MAX_T_TILT
    is_valid = finite & action_ok & on_table & upright
    next_node = jax.tree.map(lambda new, old: jnp.where(finite, new, jnp.nan_to_num(old)),
                             next_node, node)
    next_node = next_node.replace(t=node.t + 1)
    tip = self.tip_position(next_node)
    cost = jnp.where(finite, env._cost(next_node, tip), env._invalid_cost())
    return base.EdgeOutcome(next_node, cost, env.goal_reached(next_node) & is_valid, is_valid)

  def transition(self, node: base.NodeState, action: jax.Array) -> base.EdgeOutcome:
    """One edge of a single node (the batched path with B = 1)."""
    out = self.evaluate(jax.tree.map(lambda x: jnp.asarray(x)[None], node),
                        jnp.asarray(action)[None])
    return jax.tree.map(lambda x: x[0], out)
