"""A MuJoCo C world (float64) that executes plans' actions in closed loop, independent of the
planner's physics, optionally perturbed; docs/closed_loop.md."""

from __future__ import annotations

import copy
import dataclasses
from typing import List, Optional, Sequence

import jax
import mujoco
import numpy as np

from pachs_jax.envs import base, pusht
from pachs_jax.envs.mujoco_c import MujocoCEnv, mjdata_to_node, node_to_mjdata


@dataclasses.dataclass(frozen=True)
class Perturbation:
  """Scale factors applied to a copy of the world's MjModel (1.0 leaves a field unchanged).

  friction: T-table friction: `dof_frictionloss` of the T's joints t_x, t_y, t_yaw (a free T:
    the T-table pairs' `pair_friction`).
  contact_friction: the friction of every other contact pair (stick-T, T-obstacle, stick-table;
    `pair_friction`, and `geom_friction` alike).
  t_mass: the T's `body_mass` and `body_inertia`.
  actuator_gain: the arm servos' stiffness kp (`actuator_gainprm[:, 0]`, `actuator_biasprm[:, 1]`).
  actuator_damping: the arm servos' damping kv (`actuator_biasprm[:, 2]`).
  """

  friction: float = 1.0
  contact_friction: float = 1.0
  t_mass: float = 1.0
  actuator_gain: float = 1.0
  actuator_damping: float = 1.0

  def __post_init__(self):
    for f in dataclasses.fields(self):
      v = getattr(self, f.name)
      if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v <= 0:
        raise ValueError(f'Perturbation.{f.name} must be a finite number > 0, got {v!r}')

  def apply(self, model: mujoco.MjModel) -> mujoco.MjModel:
    """A perturbed copy of a PushT model (model itself is unchanged)."""
    m = _copy_model(model)
    t_body = m.body('tblock').id
    t_table = np.array([_is_t_table_pair(m, p) for p in range(m.npair)], bool)
    # every contact of the scene is an explicit pair, whose friction MuJoCo fixes at compile
    # time (pair_friction): geom_friction no longer reaches it
    m.pair_friction[~t_table] *= self.contact_friction
    if env_is_free(m):  # the T-table pairs' sliding, torsional and rolling friction
      m.pair_friction[t_table] *= self.friction
    else:
      for name in ('t_x', 't_y', 't_yaw'):
        m.dof_frictionloss[m.jnt_dofadr[m.joint(name).id]] *= self.friction
    m.geom_friction[:] *= self.contact_friction
    m.body_mass[t_body] *= self.t_mass
    m.body_inertia[t_body] *= self.t_mass
    m.actuator_gainprm[:, 0] *= self.actuator_gain
    m.actuator_biasprm[:, 1] *= self.actuator_gain
    m.actuator_biasprm[:, 2] *= self.actuator_damping
    return m


def _is_t_table_pair(model: mujoco.MjModel, pair: int) -> bool:
  """Whether contact pair `pair` is the T's bar or stem against the table (MuJoCo may store a
  pair's geoms in either order)."""
  names = {model.geom(model.pair_geom1[pair]).name, model.geom(model.pair_geom2[pair]).name}
  return 'table' in names and bool(names & {'t_bar', 't_stem'})


def env_is_free(model: mujoco.MjModel) -> bool:
  """Whether a PushT model's T is the free body (`pusht.PushTConfig.t_body` 'free')."""
  return model.nq == 14


def _copy_model(model: mujoco.MjModel) -> mujoco.MjModel:
  return copy.deepcopy(model)


class World:
  """The 'real' PushT world in MuJoCo C (float64) that executes plans closed loop.

  env: the PushTEnv (or MujocoCEnv) whose model and control rule are used.
  perturbation: optional `Perturbation` of the world's model copy (None: the env's model).
  """

  def __init__(self, env: base.Env, perturbation: Optional[Perturbation] = None):
    if isinstance(env, MujocoCEnv):
      env = env.env
    if not isinstance(env, pusht.PushTEnv):
      raise ValueError(f'World needs a PushT env, got {type(env).__name__}')
    if perturbation is not None and not isinstance(perturbation, Perturbation):
      raise ValueError(f'perturbation must be a Perturbation or None, got '
                       f'{type(perturbation).__name__}')
    self.env = env
    self.perturbation = perturbation
    self.model = (perturbation.apply(env.mj_model) if perturbation is not None
                  else _copy_model(env.mj_model))
    self.data = mujoco.MjData(self.model)
    self._goal = np.asarray(pusht.FIXED_GOAL, np.float32)
    self._t = 0
    self._lower, self._upper = np.asarray(env._arm_lower, np.float64), np.asarray(
        env._arm_upper, np.float64)

  def reset(self, node: base.NodeState) -> base.NodeState:
    """Puts the world into a single node's state; returns the observed node."""
    node_to_mjdata(self.env, node, self.data)
    mujoco.mj_forward(self.model, self.data)
    self._goal = np.asarray(node.goal, np.float32)
    self._t = int(np.asarray(node.t))
    return self.observe()

  def observe(self) -> base.NodeState:
    """The float32 node of the world's current state."""
    return mjdata_to_node(self.env, self.data, self._goal, self._t)

  def execute(self, actions) -> List[base.NodeState]:
    """Applies actions [T, A] (one control step each); returns the T observed nodes.

    Non-finite action entries are zeroed and actions clipped to [-1, 1], as in the env.
    """
    actions = np.asarray(actions, np.float64)
    if actions.ndim != 2 or actions.shape[1] != self.env.action_size:
      raise ValueError(f'actions must have shape [T, {self.env.action_size}], '
                       f'got {actions.shape}')
    actions = np.clip(np.where(np.isfinite(actions), actions, 0.0), -1.0, 1.0)
    nodes = []
    for a in actions:
      self.data.ctrl[:] = np.clip(self.data.qpos[:7] + pusht.ARM_ACTION_SCALE * a,
                                  self._lower, self._upper)
      mujoco.mj_step(self.model, self.data, nstep=self.env.config.substeps)
      self._t += 1
      nodes.append(self.observe())
    return nodes


def stack_nodes(nodes: Sequence[base.NodeState]) -> base.NodeState:
  """[T] nodes stacked from a list of single nodes."""
  return jax.tree.map(lambda *x: np.stack(x), *nodes)
