"""Forward kinematics of a MuJoCo model's hinge chains in a few dozen array operations, for the
poses the search reads at every node (a tip position, a few geoms) instead of the full
`mjx.kinematics` of every body."""

from __future__ import annotations

from typing import Optional, Sequence, Tuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np


def _quat_to_mat(quat: np.ndarray) -> np.ndarray:
  """[3, 3] rotation of a unit quaternion (w, x, y, z)."""
  w, x, y, z = np.asarray(quat, np.float64) / np.linalg.norm(quat)
  return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                   [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                   [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _axis_angle(axis: np.ndarray, angle: jax.Array) -> jax.Array:
  """[3, 3] rotation by angle (rad) about the unit axis [3] (Rodrigues)."""
  k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]],
               np.float32)
  return jnp.eye(3, dtype=jnp.float32) + jnp.sin(angle) * k + (1.0 - jnp.cos(angle)) * (k @ k)


class ChainKinematics:
  """Forward kinematics of the bodies of an MjModel read from its arrays, MuJoCo's composition:
  body = parent * (body_pos, body_quat), then each hinge turns the body about its axis through
  its anchor by qpos - qpos0.

  bodies: the bodies to pose (None: all), with their ancestors; their joints must be hinges.
  """

  def __init__(self, model: mujoco.MjModel, bodies: Optional[Sequence[int]] = None):
    wanted = set(range(model.nbody)) if bodies is None else set(int(b) for b in bodies)
    self.chain = set()
    for b in wanted:
      while b > 0 and b not in self.chain:
        self.chain.add(b)
        b = int(model.body_parentid[b])
    hinge = int(mujoco.mjtJoint.mjJNT_HINGE)
    if any(model.jnt_type[j] != hinge for j in range(model.njnt)
           if model.jnt_bodyid[j] in self.chain):
      raise ValueError('ChainKinematics supports hinge joints only')
    self.nbody = model.nbody
    self.parent = model.body_parentid.copy()
    self.body_pos = model.body_pos.astype(np.float32)
    self.body_mat = np.array([_quat_to_mat(q) for q in model.body_quat], np.float32)
    self.joints = [[(model.jnt_axis[j].astype(np.float32), model.jnt_pos[j].astype(np.float32),
                     int(model.jnt_qposadr[j]), float(model.qpos0[model.jnt_qposadr[j]]))
                    for j in range(model.njnt) if model.jnt_bodyid[j] == b]
                   for b in range(model.nbody)]
    self.geom_body = model.geom_bodyid.copy()
    self.geom_pos = model.geom_pos.astype(np.float32)
    self.geom_mat = np.array([_quat_to_mat(q) for q in model.geom_quat], np.float32)
    self.site_body = model.site_bodyid.copy()
    self.site_pos = model.site_pos.astype(np.float32)

  def bodies(self, qpos: jax.Array) -> Tuple[jax.Array, jax.Array]:
    """(xpos [nbody, 3] (m), xmat [nbody, 3, 3]) of configuration qpos [nq]; bodies outside
    the chain stay at the origin."""
    xpos, xmat = [jnp.zeros(3, jnp.float32)], [jnp.eye(3, dtype=jnp.float32)]
    for b in range(1, self.nbody):
      if b not in self.chain:  # parents come first in MuJoCo's body order
        xpos.append(xpos[0])
        xmat.append(xmat[0])
        continue
      p = self.parent[b]
      pos = xpos[p] + xmat[p] @ self.body_pos[b]
      mat = xmat[p] @ self.body_mat[b]
      for axis, jpos, adr, q0 in self.joints[b]:
        anchor = pos + mat @ jpos
        mat = mat @ _axis_angle(axis, qpos[adr] - q0)
        pos = anchor - mat @ jpos
      xpos.append(pos)
      xmat.append(mat)
    return jnp.stack(xpos), jnp.stack(xmat)

  def geoms(self, xpos: jax.Array, xmat: jax.Array, ids: np.ndarray):
    """(pos [G, 3], mat [G, 3, 3]) of the geoms `ids` [G] from the body poses."""
    b = self.geom_body[ids]
    pos = xpos[b] + jnp.einsum('gij,gj->gi', xmat[b], self.geom_pos[ids])
    return pos, jnp.einsum('gij,gjk->gik', xmat[b], self.geom_mat[ids])

  def site(self, xpos: jax.Array, xmat: jax.Array, site: int) -> jax.Array:
    """[3] position (m) of one site."""
    return xpos[self.site_body[site]] + xmat[self.site_body[site]] @ self.site_pos[site]
