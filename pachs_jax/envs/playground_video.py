"""Frames of a Playground task's closed loop, rendered by MuJoCo's own renderer (OpenGL:
`MUJOCO_GL=egl` or `osmesa` without a display): the world's states, with the path that the plan
being executed gives the most-moving body drawn as a dashed line."""

from __future__ import annotations

from typing import Optional, Sequence

import mujoco
import numpy as np

from pachs_jax.envs import base, render

PLAN_RGBA = np.array([0.95, 0.35, 0.1, 1.0], np.float32)
PLAN_WIDTH = 0.006  # the drawn path's radius, as a fraction of the model's extent (`stat.extent`)


def _set_state(model: mujoco.MjModel, data: mujoco.MjData, node, i: int) -> None:
  """Puts state i of node's arrays (qpos [S, nq], and mocap fields where the node has them)
  into data and computes its positions (`mj_forward`)."""
  data.qpos[:] = np.asarray(node.qpos)[i]
  for field in ('mocap_pos', 'mocap_quat'):
    value = node.sim.get(field) if hasattr(node, 'sim') else None
    if value is not None and model.nmocap:
      getattr(data, field)[...] = np.asarray(value)[i].reshape(getattr(data, field).shape)
  mujoco.mj_forward(model, data)  # positions, cameras included


def body_positions(model: mujoco.MjModel, node) -> np.ndarray:
  """[S, nbody, 3] the bodies' world positions at each of node's S states."""
  data = mujoco.MjData(model)
  out = []
  for i in range(np.asarray(node.qpos).shape[0]):
    _set_state(model, data, node, i)
    out.append(data.xpos.copy())
  return np.stack(out)


def moving_body(positions: np.ndarray) -> int:
  """The body (not the world's) whose path through positions [S, nbody, 3] is longest."""
  travelled = np.linalg.norm(np.diff(positions, axis=0), axis=-1).sum(axis=0)
  return int(np.argmax(travelled[1:]) + 1) if travelled.shape[0] > 1 else 0


def _add_dashes(scene: mujoco.MjvScene, points: np.ndarray, width: float) -> None:
  """Every other segment of the polyline points [P, 3] as a capsule of radius width in scene (room
  permitting)."""
  for a, b in zip(points[:-1:2], points[1::2]):
    if scene.ngeom >= scene.maxgeom or np.allclose(a, b):
      continue
    geom = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(geom, mujoco.mjtGeom.mjGEOM_CAPSULE, np.zeros(3), np.zeros(3),
                        np.zeros(9), PLAN_RGBA)
    mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_CAPSULE, width,
                         np.asarray(a, np.float64), np.asarray(b, np.float64))
    scene.ngeom += 1


def loop_frames(env, states: base.NodeState, plans: Sequence[Optional[base.NodeState]],
                size_px=(320, 240), max_frames: int = render.MAX_FRAMES) -> np.ndarray:
  """frames [F, H, W, 3] uint8 of a Playground world's states NodeState [S + 1, ...]; plans:
  per state s, the planned states [L + 1, ...] being executed there (None: none), whose path
  of the most-moving body is drawn dashed. The model's first camera, else the free camera.
  Raises ValueError when MuJoCo cannot open an OpenGL context."""
  model = env.playground_env.mj_model
  width, height = size_px
  try:
    renderer = mujoco.Renderer(model, height, width)
  except Exception as err:  # pylint: disable=broad-except  (GL back ends fail in many ways)
    message = ' '.join(str(err).split())
    raise ValueError(f'MuJoCo could not render {env.name} ({type(err).__name__}: {message}); '
                     'without a display, MUJOCO_GL=egl or osmesa gives MuJoCo an OpenGL '
                     'context') from None
  try:
    body = moving_body(body_positions(model, states))
    paths = {id(p): body_positions(model, p)[:, body] for p in plans if p is not None}
    data = mujoco.MjData(model)
    camera = 0 if model.ncam else -1
    frames = []
    for i in render.frame_steps(np.asarray(states.qpos).shape[0], max_frames):
      _set_state(model, data, states, i)
      renderer.update_scene(data, camera=camera)
      if plans[i] is not None:
        _add_dashes(renderer.scene, paths[id(plans[i])], PLAN_WIDTH * model.stat.extent)
      frames.append(renderer.render().copy())
    return np.stack(frames)
  finally:
    renderer.close()
