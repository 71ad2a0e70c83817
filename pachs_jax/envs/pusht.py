"""PushT-Fixed / -Rand / -Obs: a Panda with a stick pushes a T-shaped block to a goal pose
(model and its choices: docs/tasks.md; PushT-Obs's obstacle layouts: layouts.py)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from pachs_jax.envs import (base, coverage, kinematics, layouts, panda, physics_presets,
                            warp_import)

mjx = warp_import.quiet_mjx()  # mujoco.mjx, without its stdout line about a missing warp-lang

BASE_POS = (-0.615, 0.0, 0.0)
FIXED_GOAL = (-0.156, -0.1, 5.0 * np.pi / 3.0)  # x (m), y (m), yaw (rad)
# PushT-Fixed / -Rand start distribution around the goal: x offset U[-0.1, 0.1], y offset
# U[-0.1, 0.2], yaw U[0, 2 pi] (PushT-Obs: its layout's start region, layouts.py).
START_OFFSET_LOW = (-0.1, -0.1)
START_OFFSET_HIGH = (0.1, 0.2)
T_MASS = 0.8  # kg
T_HALF_HEIGHT = 0.02  # m
# The arm's start configuration: stick vertical, tip 2 cm above the table at (-0.40, -0.32).
HOME_QPOS = (-1.0217, 0.3428, 0.0217, -2.7163, -0.0882, 3.0588, -0.1406)
ARM_ACTION_SCALE = 0.1  # rad per unit action per control step
# PushT-Obs obstacles and start regions: layouts.LAYOUTS (blocks 4 cm tall).
TABLE_HALF_EXTENT = 0.45  # m: the T must stay within this box around the goal region
TIP_START_XY = (-0.40, -0.32)  # m: the stick tip at HOME_QPOS
# A layout's start region must keep the T's origin this far inside the table box (m) and within
# this distance range of the robot base (m), where the stick can reach around the T.
START_TABLE_MARGIN = 0.05
START_REACH = (0.3, 0.7)
MIN_CLEAR_FRACTION = 0.25  # of poses drawn in a start region that must be valid starts


@dataclasses.dataclass(frozen=True)
class PushTConfig:
  """Task and physics parameters of PushT.

  variant: 'fixed', 'rand' or 'obs'.
  layout: the 'obs' variant's obstacle layout, a name in `layouts.LAYOUTS` (None: 'gate',
    `layouts.DEFAULT`); must be None for the other variants.
  physics_dt: s per physics step; substeps: physics steps per control step.
  solver_iterations / ls_iterations: MJX Newton solver and line-search iterations.
  table_friction: T-table Coulomb coefficient (planar: becomes joint friction loss).
  t_body: 'planar' (slide x, slide y, hinge yaw with joint friction, no gravity) or 'free' (a
    free joint under gravity with T-table contacts of friction `table_friction`; its node qpos
    is [14], qvel [13]; `t_pose` reads the planar pose of either).
  t_friction_radius: planar only: m, the yaw friction loss is the sliding one times this.
  t_damping, t_yaw_damping: planar only: T joint damping (N s / m, N m s / rad).
  solver: MuJoCo's constraint solver, 'Newton' or 'CG'.
  block_solref, block_solimp, block_margin: contact parameters of the T-block and stick-block
    pairs (None: MuJoCo's defaults; margin in m: the contacts act from that distance, so that
    the T and the stick stop at the block's face instead of sinking into it).
  w_angle, w_position, w_reach: cost weights of the three dense terms.
  w_height: free T only: cost weight (per m) of the stick tip's height off the T's half height,
    where a push slides the T; above the T's top it rides over the T and tips it.
  """

  variant: str = 'fixed'
  layout: str | None = None
  episode_length: int = 100
  physics_dt: float = 0.0025
  substeps: int = 20
  solver_iterations: int = 20
  ls_iterations: int = 20
  table_friction: float = 1.65
  pusher_friction: float = 0.8
  t_body: str = 'free'
  t_friction_radius: float = 0.05
  t_damping: float = 0.5
  t_yaw_damping: float = 0.01
  solver: str = 'Newton'
  block_solref: tuple | None = (0.005, 1.0)
  block_solimp: tuple | None = (0.99, 0.999, 0.001, 0.5, 2.0)
  block_margin: float = 0.003
  w_angle: float = 1.0
  w_position: float = 3.0
  w_reach: float = 0.5
  w_height: float = 4.0
  success_coverage: float = coverage.SUCCESS_THRESHOLD


def _box_xml(name: str, cx, cy, hx, hy, yaw, hz, z, rgba) -> str:
  return (f'<geom name="{name}" type="box" size="{hx} {hy} {hz}" pos="{cx} {cy} {z}" '
          f'euler="0 0 {yaw}" rgba="{rgba}" contype="0" conaffinity="0"/>')


def config_layout(config: PushTConfig) -> layouts.Layout | None:
  """The config's obstacle layout (None for 'fixed' and 'rand'); raises ValueError for an
  unknown name (listing the valid ones) or a layout given to another variant."""
  if config.variant != 'obs':
    if config.layout is not None:
      raise ValueError(f"layout applies to the 'obs' variant only, not {config.variant!r} "
                       f'(got layout={config.layout!r})')
    return None
  return layouts.layout(layouts.DEFAULT if config.layout is None else config.layout)


# Named physics settings (`physics_presets`: a light module, for the scripts' flags).
PHYSICS_PRESETS = physics_presets.PHYSICS_PRESETS
# The PushTConfig fields that make the physics model (`physics_settings`); the others make the task.
# BLOCK_FIELDS act only where a layout has blocks.
PHYSICS_FIELDS = ('physics_dt', 'substeps', 'solver_iterations', 'ls_iterations',
                  'table_friction', 'pusher_friction', 't_body', 't_friction_radius', 't_damping',
                  't_yaw_damping', 'solver', 'block_solref', 'block_solimp', 'block_margin')
BLOCK_FIELDS = physics_presets.BLOCK_FIELDS
T_BODIES = ('planar', 'free')
SOLVERS = ('Newton', 'CG')


def check_physics(config: PushTConfig) -> None:
  """Raises ValueError, one line naming the field, unless the config's physics fields are
  valid: positive time step, substeps and iterations, a known t_body and solver, and contact
  parameters of MuJoCo's shapes (solref 2 numbers, solimp 3 or 5, margin >= 0)."""
  c = config
  if not (np.isfinite(c.physics_dt) and c.physics_dt > 0):
    raise ValueError(f'PushTConfig.physics_dt must be a positive time step (s), got {c.physics_dt!r}')
  for name in ('substeps', 'solver_iterations', 'ls_iterations'):
    v = getattr(c, name)
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
      raise ValueError(f'PushTConfig.{name} must be a positive int, got {v!r}')
  if c.t_body not in T_BODIES:
    raise ValueError(f'PushTConfig.t_body must be one of {T_BODIES}, got {c.t_body!r}')
  if c.solver not in SOLVERS:
    raise ValueError(f'PushTConfig.solver must be one of {SOLVERS}, got {c.solver!r}')
  for name, sizes in (('block_solref', (2,)), ('block_solimp', (3, 5))):
    v = getattr(c, name)
    if v is not None and (np.shape(v) not in [(n,) for n in sizes]
                          or not np.all(np.isfinite(v))):
      raise ValueError(f'PushTConfig.{name} must be None or {" or ".join(map(str, sizes))} '
                       f'finite numbers, got {v!r}')
  if not (np.isfinite(c.block_margin) and c.block_margin >= 0):
    raise ValueError(f'PushTConfig.block_margin must be >= 0 (m), got {c.block_margin!r}')
  for name in ('table_friction', 'pusher_friction', 't_friction_radius', 't_damping',
               't_yaw_damping', 'w_angle', 'w_position', 'w_reach'):
    v = getattr(c, name)  # friction, damping and cost weights: physical only when >= 0
    if (isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating))
        or not np.isfinite(v) or v < 0):
      raise ValueError(f'PushTConfig.{name} must be a finite number >= 0, got {v!r}')
  if not 0 < c.success_coverage <= 1:
    raise ValueError(f'PushTConfig.success_coverage must be in (0, 1], got '
                     f'{c.success_coverage!r}')


def physics_settings(config: PushTConfig, blocks: bool = True) -> dict:
  """The config's `PHYSICS_FIELDS` as JSON values (tuples as lists); without `blocks` (a task
  without obstacles) less the `BLOCK_FIELDS`, which simulate nothing there."""
  value = lambda v: list(v) if isinstance(v, tuple) else v
  return {name: value(getattr(config, name)) for name in PHYSICS_FIELDS
          if blocks or name not in BLOCK_FIELDS}


def physics_preset(name: str, **fields) -> PushTConfig:
  """A PushTConfig with the named `PHYSICS_PRESETS` entry and the other given fields."""
  if name not in PHYSICS_PRESETS:
    raise ValueError(f'unknown physics preset {name!r}; valid: {sorted(PHYSICS_PRESETS)}')
  return PushTConfig(**{**PHYSICS_PRESETS[name], **fields})


def _block_pair_attributes(config: PushTConfig) -> str:
  """The contact attributes of a T-block or stick-block pair (leading space; '' for none)."""
  out = ''
  if config.block_solref is not None:
    out += ' solref="' + ' '.join(f'{x:g}' for x in config.block_solref) + '"'
  if config.block_solimp is not None:
    out += ' solimp="' + ' '.join(f'{x:g}' for x in config.block_solimp) + '"'
  if config.block_margin:
    out += f' margin="{config.block_margin:g}"'
  return out


def free_t_state(qpos, qvel):
  """(qpos [..., 14], qvel [..., 13]) of the free T model for planar states qpos [..., 10],
  qvel [..., 10]: the T resting on the table (centre at `T_HALF_HEIGHT`), yaw as a quaternion,
  its planar velocity as the free joint's linear x, y and angular z velocity."""
  qpos, qvel = np.asarray(qpos, np.float64), np.asarray(qvel, np.float64)
  yaw = qpos[..., 9]
  zero = np.zeros_like(yaw)
  t_qpos = np.stack([qpos[..., 7], qpos[..., 8], zero + T_HALF_HEIGHT, np.cos(yaw / 2), zero,
                     zero, np.sin(yaw / 2)], -1)
  t_qvel = np.stack([qvel[..., 7], qvel[..., 8], zero, zero, zero, qvel[..., 9]], -1)
  return (np.concatenate([qpos[..., :7], t_qpos], -1),
          np.concatenate([qvel[..., :7], t_qvel], -1))


def planar_t_state(qpos, qvel):
  """(qpos [..., 10], qvel [..., 10]) planar states of free T model states qpos [..., 14],
  qvel [..., 13]: the T's x, y and yaw (about the world z axis) and their rates."""
  qpos, qvel = np.asarray(qpos, np.float64), np.asarray(qvel, np.float64)
  w, x, y, z = (qpos[..., 10 + k] for k in range(4))
  yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
  t_qpos = np.stack([qpos[..., 7], qpos[..., 8], yaw], -1)
  t_qvel = np.stack([qvel[..., 7], qvel[..., 8], qvel[..., 12]], -1)
  return (np.concatenate([qpos[..., :7], t_qpos], -1),
          np.concatenate([qvel[..., :7], t_qvel], -1))


MAX_T_TILT = np.pi / 6  # rad: a free T tilted further has tipped over (its edge is invalid)


def t_pose(qpos: jax.Array) -> jax.Array:
  """[..., 3] the T's planar pose (x, y (m), yaw (rad) about the world z axis) of node qpos
  [..., 10] (planar T) or [..., 14] (free T: yaw of its quaternion)."""
  qpos = jnp.asarray(qpos)
  if qpos.shape[-1] == 10:
    return qpos[..., 7:10]
  w, x, y, z = (qpos[..., 10 + k] for k in range(4))
  yaw = jnp.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
  return jnp.stack([qpos[..., 7], qpos[..., 8], yaw], -1)


def perturb_t(nodes: base.NodeState, keys: jax.Array, position_m: float = 0.001,
              yaw_rad: float = 0.01) -> base.NodeState:
  """Nodes [B] with the T moved by N(0, position_m) along x and y and turned by N(0, yaw_rad)
  about the world z axis (planar or free T; one draw per node from keys [B, 2]): states near
  nodes, as another engine's T lies after a few steps (`replan.AnswerCheck`)."""
  noise = jax.vmap(lambda k: jax.random.normal(k, (3,)))(keys) * jnp.asarray(
      [position_m, position_m, yaw_rad], jnp.float32)
  qpos = nodes.qpos.at[:, 7:9].add(noise[:, :2].astype(nodes.qpos.dtype))
  if qpos.shape[-1] == 10:  # planar: the yaw joint
    qpos = qpos.at[:, 9].add(noise[:, 2].astype(qpos.dtype))
  else:  # free: the quaternion (w, x, y, z) turned about world z, q' = (c, 0, 0, s) q
    c, s = jnp.cos(noise[:, 2] / 2), jnp.sin(noise[:, 2] / 2)
    w, x, y, z = (qpos[:, 10 + k] for k in range(4))
    qpos = qpos.at[:, 10:14].set(jnp.stack([c * w - s * z, c * x - s * y, c * y + s * x,
                                            c * z + s * w], -1).astype(qpos.dtype))
  return nodes.replace(qpos=qpos)


def t_velocity(qvel: jax.Array) -> jax.Array:
  """[..., 3] the T's planar velocity (m/s, m/s, rad/s) of node qvel [..., 10] or [..., 13]."""
  qvel = jnp.asarray(qvel)
  if qvel.shape[-1] == 10:
    return qvel[..., 7:10]
  return jnp.stack([qvel[..., 7], qvel[..., 8], qvel[..., 12]], -1)


def t_tilt(qpos: jax.Array) -> jax.Array:
  """[...] rad the free T's tilt from upright (0 for a planar T) of node qpos [..., nq]."""
  qpos = jnp.asarray(qpos)
  if qpos.shape[-1] == 10:
    return jnp.zeros(qpos.shape[:-1], qpos.dtype)
  s = jnp.sqrt(jnp.clip(qpos[..., 11] ** 2 + qpos[..., 12] ** 2, 0.0, 1.0))
  return 2 * jnp.arcsin(s)


def box_excess(qpos: jax.Array) -> jax.Array:
  """[...] m how far the T of node qpos [..., nq] lies outside the square of half side
  TABLE_HALF_EXTENT around the fixed goal's position (0 inside)."""
  offset = jnp.abs(jnp.asarray(qpos)[..., 7:9] - jnp.asarray(FIXED_GOAL[:2]))
  return jnp.maximum(jnp.max(offset, axis=-1) - TABLE_HALF_EXTENT, 0.0)


TABLE_JITTER = 1e-4  # m: a free T resting outside the square may drift this far, still valid


def stays_on_table(qpos: jax.Array, next_qpos: jax.Array) -> jax.Array:
  """[...] bool an edge from qpos to next_qpos keeps the T on the table: inside the square of
  `box_excess`, or no farther outside than it was (a world can leave the T outside, and the
  way back must stay open)."""
  after = box_excess(next_qpos)
  return (after == 0.0) | (after <= box_excess(qpos) + TABLE_JITTER)


def model_xml(config: PushTConfig) -> str:
  """MJCF of the PushT scene for a config (obstacles only for the 'obs' variant)."""
  check_physics(config)
  g = 9.81
  fl_xy = config.table_friction * T_MASS * g
  fl_yaw = fl_xy * config.t_friction_radius  # effective radius of the contact patch (m)
  free = config.t_body == 'free'
  bar, stem = coverage.T_BOXES
  t_geoms = ''.join(
      f'<geom name="t_{n}" type="box" size="{b[2]} {b[3]} {T_HALF_HEIGHT}" '
      f'pos="{b[0]} {b[1]} 0" rgba="0.85 0.35 0.2 1" contype="0" conaffinity="0" '
      f'friction="{config.pusher_friction} 0.005 0.0001"/>'
      for n, b in (('bar', bar), ('stem', stem)))
  goal_geoms = ''.join(
      f'<geom name="goal_{n}" type="box" size="{b[2]} {b[3]} 0.0005" pos="{b[0]} {b[1]} 0" '
      f'rgba="0.2 0.8 0.3 0.5" contype="0" conaffinity="0" group="2"/>'
      for n, b in (('bar', bar), ('stem', stem)))
  layout = config_layout(config)
  obstacles = layout.blocks if layout is not None else ()
  obstacle_geoms = ''.join(
      _box_xml(f'obstacle{i}', *o, hz=0.02, z=0.02, rgba='0.4 0.4 0.45 1')
      for i, o in enumerate(obstacles))
  pairs = ['<pair geom1="stick" geom2="t_bar"/>', '<pair geom1="stick" geom2="t_stem"/>',
           '<pair geom1="stick" geom2="table"/>']
  block = _block_pair_attributes(config)
  for i in range(len(obstacles)):
    pairs += [f'<pair geom1="t_bar" geom2="obstacle{i}"{block}/>',
              f'<pair geom1="t_stem" geom2="obstacle{i}"{block}/>',
              f'<pair geom1="stick" geom2="obstacle{i}"{block}/>']
  if free:
    mu = config.table_friction
    pairs += [f'<pair geom1="t_{n}" geom2="table" condim="3" '
              f'friction="{mu} {mu} 0.005 0.0001 0.0001"/>' for n in ('bar', 'stem')]
    t_joints = '<freejoint name="t_free"/>'
  else:
    t_joints = (
        f'<joint name="t_x" type="slide" axis="1 0 0" frictionloss="{fl_xy}" '
        f'damping="{config.t_damping}"/>'
        f'<joint name="t_y" type="slide" axis="0 1 0" frictionloss="{fl_xy}" '
        f'damping="{config.t_damping}"/>'
        f'<joint name="t_yaw" type="hinge" axis="0 0 1" frictionloss="{fl_yaw}" '
        f'damping="{config.t_yaw_damping}"/>')
  gx, gy, gyaw = FIXED_GOAL
  # nativeccd="disable": MuJoCo Warp then collides box pairs (the T and the blocks) with the
  # box-box routine of MuJoCo C, not with its general convex one, whose contacts differ from
  # MuJoCo C's in about a third of the T's block contacts; MuJoCo C and MJX-JAX collide as before
  # (docs/tasks.md)
  return f"""
<mujoco model="pusht-{config.variant}{'-' + layout.name if layout else ''}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{config.physics_dt}" gravity="0 0 {-g if free else 0}"
          integrator="implicitfast" solver="{config.solver}"
          iterations="{config.solver_iterations}" ls_iterations="{config.ls_iterations}"
          cone="pyramidal">
    <flag eulerdamp="disable" nativeccd="disable"/>
  </option>
  <default>{panda.arm_defaults_xml()}</default>
  <worldbody>
    <light pos="0 0 1.5" dir="0 0 -1" directional="true"/>
    <camera name="overview" mode="targetbody" target="goal" pos="0.25 -0.95 0.85"/>
    <geom name="table" type="plane" size="1 1 0.01" rgba="0.8 0.75 0.65 1"
          contype="0" conaffinity="0"/>
    <body name="goal" pos="{gx} {gy} 0.0005" euler="0 0 {gyaw}">{goal_geoms}</body>
    {obstacle_geoms}
    {panda.arm_body_xml('stick', base_pos=BASE_POS, gravcomp=1.0 if free else 0.0)}
    <body name="tblock" pos="0 0 {T_HALF_HEIGHT}">
      <inertial pos="0 0 0" mass="{T_MASS}" diaginertia="0.0025 0.0025 0.0045"/>
      {t_joints}
      {t_geoms}
    </body>
  </worldbody>
  <contact>{''.join(pairs)}</contact>
  {panda.arm_actuators_xml()}
</mujoco>"""


def _box_points(box: np.ndarray, spacing: float = 0.0025) -> np.ndarray:
  """[P, 2] world points filling a box row (cx, cy, half_x, half_y, yaw) on a grid (m)."""
  cx, cy, hx, hy, yaw = box
  u = np.arange(-hx, hx + 1e-9, spacing)
  v = np.arange(-hy, hy + 1e-9, spacing)
  uu, vv = [a.ravel() for a in np.meshgrid(u, v)]
  c, s = np.cos(yaw), np.sin(yaw)
  return np.stack([cx + c * uu - s * vv, cy + s * uu + c * vv], -1).astype(np.float32)


def _t_points_in_box(poses: np.ndarray, box_points: np.ndarray) -> np.ndarray:
  """[N] bool: a corner of the T at poses [N, 3] lies inside the (axis-aligned) box sampled by
  box_points, i.e. within the points' bounding box."""
  lo, hi = box_points.min(0), box_points.max(0)
  c, s = np.cos(poses[:, 2:3]), np.sin(poses[:, 2:3])
  corners = coverage.T_OUTLINE[None]
  wx = poses[:, 0:1] + c * corners[..., 0] - s * corners[..., 1]
  wy = poses[:, 1:2] + s * corners[..., 0] + c * corners[..., 1]
  return np.any((wx >= lo[0]) & (wx <= hi[0]) & (wy >= lo[1]) & (wy <= hi[1]), axis=-1)


def _box_corners(box: np.ndarray) -> np.ndarray:
  """[4, 2] corners of a box row (cx, cy, half_x, half_y, yaw)."""
  cx, cy, hx, hy, yaw = np.asarray(box, np.float64)
  c, s = np.cos(yaw), np.sin(yaw)
  local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
  return np.stack([cx + c * local[:, 0] - s * local[:, 1],
                   cy + s * local[:, 0] + c * local[:, 1]], -1)


def start_clear(poses: np.ndarray, goals: np.ndarray, blocks: np.ndarray,
                success_coverage: float = coverage.SUCCESS_THRESHOLD) -> np.ndarray:
  """[N] bool: T poses [N, 3] that are valid starts for goals [N, 3] among blocks [M, 5].

  Rejected: the T already covers its goal (>= success_coverage), touches the stick's start
  position (a 6 cm square around `TIP_START_XY`) or overlaps a block grown by 5 mm.
  """
  poses = np.asarray(poses, np.float32)
  ok = coverage.coverage(poses, np.asarray(goals, np.float32), np) < success_coverage
  keep_out = [_box_points(np.array([TIP_START_XY[0], TIP_START_XY[1], 0.03, 0.03, 0.0]))]
  keep_out += [_box_points(np.asarray(o) + np.array([0, 0, 0.005, 0.005, 0]))
               for o in np.asarray(blocks).reshape(-1, 5)]
  for pts in keep_out:
    hit = coverage.points_in_t(np.broadcast_to(pts, (len(poses),) + pts.shape), poses, np)
    ok &= ~hit.any(axis=-1)
    ok &= ~_t_points_in_box(poses, pts)
  return ok


def check_layout(layout: layouts.Layout,
                 success_coverage: float = coverage.SUCCESS_THRESHOLD) -> None:
  """Raises ValueError, naming the layout and the fault, unless: every block has positive
  half sizes and clears the goal T (5 mm) and the stick's start; the start region's ranges are
  ordered, keep the T's origin `START_TABLE_MARGIN` inside the table box and within
  `START_REACH` of the robot base; and at least `MIN_CLEAR_FRACTION` of 512 poses drawn in it
  (seed 0) are valid starts (`start_clear`)."""
  where = f'PushT-Obs layout {layout.name!r}'
  blocks = layout.blocks_array()
  goal = np.asarray(FIXED_GOAL, np.float32)
  for i, block in enumerate(blocks):
    if not np.all(np.isfinite(block)) or block[2] <= 0 or block[3] <= 0:
      raise ValueError(f'{where}: block {i} {tuple(block.tolist())} needs finite values and '
                       'positive half sizes')
    grown = _box_points(block + np.array([0, 0, 0.005, 0.005, 0], np.float32))
    if (coverage.points_in_t(grown, goal, np).any()
        or _t_points_in_box(goal[None], grown)[0]):
      raise ValueError(f'{where}: block {i} {tuple(np.round(block, 4).tolist())} overlaps the '
                       f'goal T at {FIXED_GOAL[:2]} (or comes within 5 mm of it)')
    lo, hi = _box_corners(block).min(0), _box_corners(block).max(0)
    tip = np.asarray(TIP_START_XY)
    if np.all(lo <= tip + 0.02) and np.all(hi >= tip - 0.02):
      raise ValueError(f'{where}: block {i} covers the stick tip\'s start {TIP_START_XY}')
  ranges = {'start_x': layout.start_x, 'start_y': layout.start_y,
            'start_yaw': layout.start_yaw}
  for name, (lo, hi) in ranges.items():
    if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
      raise ValueError(f'{where}: {name} must be an ordered finite range, got {(lo, hi)}')
  limit = TABLE_HALF_EXTENT - START_TABLE_MARGIN
  for k, name in enumerate(('start_x', 'start_y')):
    lo, hi = ranges[name]
    if lo < goal[k] - limit or hi > goal[k] + limit:
      raise ValueError(f'{where}: {name} {(lo, hi)} leaves the table: the T must start within '
                       f'[{goal[k] - limit:.3f}, {goal[k] + limit:.3f}]')
  base_xy = np.asarray(BASE_POS[:2])
  near = np.clip(base_xy, [layout.start_x[0], layout.start_y[0]],
                 [layout.start_x[1], layout.start_y[1]])
  far = max(np.hypot(x - base_xy[0], y - base_xy[1])
            for x in layout.start_x for y in layout.start_y)
  if np.hypot(*(near - base_xy)) < START_REACH[0] or far > START_REACH[1]:
    raise ValueError(f'{where}: the start region x {layout.start_x}, y {layout.start_y} must '
                     f'lie {START_REACH[0]}-{START_REACH[1]} m from the robot base '
                     f'{tuple(base_xy)}, where the stick can reach around the T')
  rng = np.random.default_rng(0)
  num = 512
  poses = np.stack([rng.uniform(*layout.start_x, num), rng.uniform(*layout.start_y, num),
                    rng.uniform(*layout.start_yaw, num)], -1)
  clear = int(start_clear(poses, np.broadcast_to(goal, poses.shape), blocks,
                          success_coverage).sum())
  if clear < MIN_CLEAR_FRACTION * num:
    raise ValueError(f'{where} leaves too few valid starts: {clear} of {num} poses drawn in its '
                     f'start region (x {layout.start_x}, y {layout.start_y}) clear the blocks '
                     f'and the goal; at least {MIN_CLEAR_FRACTION:.0%} must')


def site_reach(model: mujoco.MjModel, site: int) -> float:
  """An upper bound (m) on the distance of a site from the world origin over all joint angles:
  the site's offset plus, up its body chain, each body's offset and twice its joints' anchor
  offsets (the triangle inequality; hinge joints)."""
  reach = float(np.linalg.norm(model.site_pos[site]))
  body = int(model.site_bodyid[site])
  while body != 0:
    joints = np.flatnonzero(model.jnt_bodyid == body)
    reach += float(np.linalg.norm(model.body_pos[body]))
    reach += 2.0 * float(sum(np.linalg.norm(model.jnt_pos[j]) for j in joints))
    body = int(model.body_parentid[body])
  return reach


def jacobian_action(model: mujoco.MjModel, data: mujoco.MjData, tip_goal: np.ndarray,
                    qpos: np.ndarray | None = None, max_step: float = 0.02) -> np.ndarray:
  """[7] float64 action in [-1, 1] moving the stick tip towards tip_goal [3] (m, world frame).

  One damped least-squares step on the tip's Jacobian towards a point at most max_step (m)
  away per axis. With `qpos` [10], data's kinematics are computed there first; without, data must hold
  the kinematics of its own qpos (e.g. after mj_forward). A scripted pusher for demos and tests.
  """
  if qpos is not None:
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
  site = model.site('tip').id
  jac = np.zeros((3, model.nv))
  mujoco.mj_jacSite(model, data, jac, None, site)
  jac = jac[:, :panda.NUM_JOINTS]
  dx = np.clip(tip_goal - data.site_xpos[site], -max_step, max_step)
  dq = jac.T @ np.linalg.solve(jac @ jac.T + 1e-4 * np.eye(3), dx)
  return np.clip(dq / ARM_ACTION_SCALE, -1.0, 1.0)


def _wrap_angle(a: jax.Array) -> jax.Array:
  """Angle wrapped into [-pi, pi)."""
  return (a + jnp.pi) % (2 * jnp.pi) - jnp.pi


class PushTEnv(base.Env):
  """PushT on MJX. qpos = [7 arm joints (rad), T x, T y (m), T yaw (rad)] (a free T: [7 arm
  joints, T x, y, z (m), quaternion w, x, y, z], qvel [13]); goal = [x, y, yaw].

  Action: [-1, 1]^7 scaled by ARM_ACTION_SCALE to a joint-position target offset from the
  current joint angles, held for `substeps` physics steps. Cost per step (= -reward):
  w_angle * |yaw error| / pi + w_position * position error (m) + w_reach * distance of the tip
  from the T's centre beyond 5 cm (m; in the plane for the planar T, in 3D for the free T)
  + w_height * |tip height - T half height| (m; free T only). Success: `coverage.coverage` >=
  `success_coverage`.
  """

  goal_size = 3
  physics = 'mjx'

  def __init__(self, config: PushTConfig = PushTConfig()):
    if config.variant not in ('fixed', 'rand', 'obs'):
      raise ValueError(f"PushT variant must be 'fixed', 'rand' or 'obs', got {config.variant!r}")
    check_physics(config)
    self.layout = config_layout(config)
    self.config = config
    self.name = f'pusht-{config.variant}'
    # Start region: offsets from the goal (x, y) and an absolute yaw range.
    low, high, self._start_yaw = START_OFFSET_LOW, START_OFFSET_HIGH, (0.0, 2 * jnp.pi)
    if self.layout is not None:
      check_layout(self.layout, config.success_coverage)
      if self.layout.name != layouts.DEFAULT:
        self.name += f':{self.layout.name}'
      gx, gy = FIXED_GOAL[:2]
      low = (self.layout.start_x[0] - gx, self.layout.start_y[0] - gy)
      high = (self.layout.start_x[1] - gx, self.layout.start_y[1] - gy)
      self._start_yaw = self.layout.start_yaw
    self._start_low = np.asarray(low, np.float32)
    self._start_high = np.asarray(high, np.float32)
    self.episode_length = config.episode_length
    self.mj_model = mujoco.MjModel.from_xml_string(model_xml(config))
    self.mjx_model = mjx.put_model(self.mj_model)
    self._data_template = mjx.make_data(self.mjx_model)
    self._tip_site = self.mj_model.site('tip').id
    self._tip_chain = kinematics.ChainKinematics(self.mj_model,
                                                 [self.mj_model.site_bodyid[self._tip_site]])
    self.obstacles = (self.layout.blocks_array() if self.layout is not None
                      else np.zeros((0, 5), np.float32))
    home = np.concatenate([HOME_QPOS, np.zeros(self.mj_model.nq - len(HOME_QPOS))])
    self._home_qpos, self._arm_lower, self._arm_upper = jax.device_put(
        [np.asarray(x, np.float32) for x in (home, panda.JOINT_LOWER, panda.JOINT_UPPER)])

  fingerprint = property(base.config_fingerprint)

  @property
  def physics_settings(self) -> dict:
    return physics_settings(self.config, blocks=self.layout is not None)

  @property
  def action_size(self) -> int:
    return panda.NUM_JOINTS

  @property
  def observation_size(self) -> int:
    """Length of `observation`: arm q and 0.1 qdot (14), tip (3), T x y, cos sin yaw, goal x y,
    cos sin goal yaw, T in the goal frame, cos sin yaw error, tip in the T frame (12), T
    velocity (3); declared, so that no process traces the kinematics to learn it."""
    return 34

  @property
  def default_lattice_resolution(self) -> jax.Array:
    # T x, T y (m), T yaw (rad), tip x, tip y (m).
    return jax.device_put(np.array([0.01, 0.01, 0.1, 0.02, 0.02], np.float32))

  @property
  def lattice_extent(self) -> np.ndarray:
    # a valid T stays on the table box around the goal; yaw in [0, 2 pi); the tip within the
    # arm's reach (`site_reach`)
    t_xy = np.abs(np.asarray(FIXED_GOAL[:2])) + TABLE_HALF_EXTENT
    reach = site_reach(self.mj_model, self.mj_model.site('tip').id)
    return np.array([t_xy[0], t_xy[1], 2 * np.pi, reach, reach])

  # ---- state construction ----

  def node_from_pose(self, t_pose: jax.Array, goal: jax.Array) -> base.NodeState:
    """A start node with the arm at home, T at t_pose [3] and goal [3]; no batch axis."""
    t_pose = jnp.asarray(t_pose, jnp.float32)
    if self.config.t_body == 'free':  # resting on the table, upright
      half = t_pose[2] / 2
      t_pose = jnp.stack([t_pose[0], t_pose[1], jnp.float32(T_HALF_HEIGHT), jnp.cos(half),
                          jnp.float32(0), jnp.float32(0), jnp.sin(half)])
    qpos = self._home_qpos.at[7:].set(t_pose)
    nv = self.mj_model.nv
    return base.NodeState(qpos=qpos, qvel=jnp.zeros(nv, jnp.float32),
                          ctrl=qpos[:7], qacc_warmstart=jnp.zeros(nv, jnp.float32),
                          goal=jnp.asarray(goal, jnp.float32), t=jnp.zeros((), jnp.int32))

  def sample_instance(self, key: jax.Array) -> base.NodeState:
    """Start and goal from the task's distribution (rejection-free; see `instances` for sets)."""
    k_goal, k_off, k_yaw = jax.random.split(key, 3)
    fixed = jnp.asarray(FIXED_GOAL, jnp.float32)
    if self.config.variant == 'rand':
      goal = jnp.array([
          jax.random.uniform(k_goal, (), minval=-0.22, maxval=-0.09),
          jax.random.uniform(jax.random.fold_in(k_goal, 1), (), minval=-0.15, maxval=0.05),
          jax.random.uniform(jax.random.fold_in(k_goal, 2), (), maxval=2 * jnp.pi)])
    else:
      goal = fixed
    off = jax.random.uniform(k_off, (2,), minval=jnp.asarray(self._start_low),
                             maxval=jnp.asarray(self._start_high))
    yaw = jax.random.uniform(k_yaw, (), minval=self._start_yaw[0], maxval=self._start_yaw[1])
    start = jnp.concatenate([goal[:2] + off, yaw[None]])
    return self.node_from_pose(start, goal)

  def canonical_instances(self, num: int = 30, seed: int = 0) -> base.NodeState:
    """[num] start nodes fixed by seed: the instance set every experiment uses.

    Candidates come from `sample_instance` (for PushT-Obs: uniform in the layout's start
    region); those already at the goal, touching the stick's start position or overlapping an
    obstacle (with 5 mm clearance) are rejected (`start_clear`).
    """
    if num <= 0:
      raise ValueError(f'num must be positive, got {num}')
    candidates = jax.jit(lambda key: self.initial_nodes(jax.random.split(key, 8 * num + 64)))
    nodes = jax.device_get(candidates(jax.random.PRNGKey(seed)))
    ok = start_clear(np.asarray(t_pose(nodes.qpos)), nodes.goal, self.obstacles,
                     self.config.success_coverage)
    index = np.flatnonzero(ok)[:num]
    if len(index) < num:
      raise RuntimeError(f'only {len(index)} of {num} instances passed the rejection tests')
    return jax.device_put(jax.tree.map(lambda x: x[index], nodes))

  # ---- physics: the only place where it happens ----

  def restore(self, node: base.NodeState, template: mjx.Data | None = None) -> mjx.Data:
    """An mjx.Data holding exactly the node's simulation state (derived fields recomputed):
    template (None: this env's MJX-JAX Data) with the node's qpos, qvel, ctrl, qacc_warmstart."""
    template = self._data_template if template is None else template
    return template.replace(qpos=node.qpos, qvel=node.qvel, ctrl=node.ctrl,
                                       qacc_warmstart=node.qacc_warmstart)

  def transition(self, node: base.NodeState, action: jax.Array) -> base.EdgeOutcome:
    data, action_ok = self._actuated(node, action)
    data = jax.lax.fori_loop(0, self.config.substeps,
                             lambda _, d: mjx.step(self.mjx_model, d), data)
    return self._outcome(node, data, action_ok)

  def evaluate(self, nodes: base.NodeState, actions: jax.Array) -> base.EdgeOutcome:
    """`transition` of B edges, nodes [B], actions [B, A]: the same physics with the batch
    inside the substep loop (the step is traced once under vmap, not batched as a loop body)."""
    base.check_actions(actions, self.action_size, batched=True)
    data, action_ok = jax.vmap(self._actuated)(nodes, actions)
    step = jax.vmap(lambda d: mjx.step(self.mjx_model, d))
    data = jax.lax.fori_loop(0, self.config.substeps, lambda _, d: step(d), data)
    return jax.vmap(self._outcome)(nodes, data, action_ok)

  def _actuated(self, node: base.NodeState, action: jax.Array,
                template: mjx.Data | None = None):
    """(mjx.Data of node, from template as in `restore`, with the action's joint targets as
    ctrl, [] bool action usable)."""
    action, action_ok = base.sanitize_actions(action)
    target = jnp.clip(node.qpos[:7] + ARM_ACTION_SCALE * action, self._arm_lower,
                      self._arm_upper)
    return self.restore(node, template).replace(ctrl=target), action_ok

  def _outcome(self, node: base.NodeState, data: mjx.Data, action_ok: jax.Array
               ) -> base.EdgeOutcome:
    """The EdgeOutcome of node's edge whose substeps ended in data."""
    next_node = base.NodeState(qpos=data.qpos, qvel=data.qvel, ctrl=data.ctrl,
                               qacc_warmstart=data.qacc_warmstart, goal=node.goal,
                               t=node.t + 1)
    finite = base.finite_node(next_node)
    on_table = stays_on_table(node.qpos, next_node.qpos)
    upright = t_tilt(next_node.qpos) < MAX_T_TILT
    is_valid = finite & action_ok & on_table & upright
    # Keep invalid successors finite: they are dropped by the search and end an episode.
    next_node = jax.tree.map(lambda new, old: jnp.where(finite, new, jnp.nan_to_num(old)),
                             next_node, node)
    next_node = next_node.replace(t=node.t + 1)
    tip = data.site_xpos[self._tip_site]
    cost = jnp.where(finite, self._cost(next_node, tip), self._invalid_cost())
    return base.EdgeOutcome(next_node, cost, self.goal_reached(next_node) & is_valid, is_valid)

  def tip_position(self, node: base.NodeState) -> jax.Array:
    """[3] world position of the stick tip (m) of one node, by forward kinematics of the arm's
    chain (`kinematics.ChainKinematics`; equal to mjx.kinematics' to float32 rounding)."""
    xpos, xmat = self._tip_chain.bodies(node.qpos)
    return self._tip_chain.site(xpos, xmat, self._tip_site)

  def _cost(self, node: base.NodeState, tip: jax.Array) -> jax.Array:
    """The step cost of node (no batch axis) with the stick tip at tip [3] (m)."""
    c = self.config
    pose, goal = t_pose(node.qpos), node.goal
    angle = jnp.abs(_wrap_angle(pose[2] - goal[2])) / jnp.pi
    position = jnp.linalg.norm(pose[:2] - goal[:2])
    # The tip's distance from the T's centre: in the plane for the planar T; in 3D for the free
    # T (as ManiSkill's PushT reward), which keeps the tip down at the T's half height, where a
    # push slides the T instead of tipping it over its top edge.
    offset = tip[:2] - pose[:2]
    height = 0.0
    if self.config.t_body == 'free':
      offset = jnp.append(offset, tip[2] - node.qpos[9])
      height = jnp.abs(tip[2] - T_HALF_HEIGHT)
    reach = jnp.maximum(jnp.linalg.norm(offset) - 0.05, 0.0)
    return (c.w_angle * angle + c.w_position * position + c.w_reach * reach
            + c.w_height * height)

  def _invalid_cost(self) -> jax.Array:
    c = self.config
    return jnp.asarray(c.w_angle + c.w_position * 2 * TABLE_HALF_EXTENT + c.w_reach, jnp.float32)

  # ---- what the networks and the search read ----

  def observation(self, node: base.NodeState) -> jax.Array:
    tip = self.tip_position(node)
    pose, goal = t_pose(node.qpos), node.goal
    c, s = jnp.cos(goal[2]), jnp.sin(goal[2])
    d = pose[:2] - goal[:2]
    rel = jnp.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])  # T in goal frame (m)
    dyaw = pose[2] - goal[2]
    ct, st = jnp.cos(pose[2]), jnp.sin(pose[2])
    dt = tip[:2] - pose[:2]
    tip_in_t = jnp.array([ct * dt[0] + st * dt[1], -st * dt[0] + ct * dt[1]])
    arm_q = node.qpos[:7]
    return jnp.concatenate([
        arm_q, 0.1 * node.qvel[:7], tip, pose[:2], jnp.array([ct, st]), goal[:2],
        jnp.array([c, s]), rel, jnp.array([jnp.cos(dyaw), jnp.sin(dyaw)]), tip_in_t,
        t_velocity(node.qvel)]).astype(jnp.float32)

  def lattice_coords(self, node: base.NodeState, resolution: jax.Array) -> jax.Array:
    pose = t_pose(node.qpos)
    tip = self.tip_position(node)
    yaw = pose[2] % (2 * jnp.pi)
    values = jnp.stack([pose[0], pose[1], yaw, tip[0], tip[1]])
    return jnp.floor(values / resolution).astype(jnp.int32)

  def goal_reached(self, node: base.NodeState) -> jax.Array:
    return coverage.coverage(t_pose(node.qpos), node.goal) >= self.config.success_coverage

  def is_failure(self, nodes: base.NodeState) -> jax.Array:
    """[B] bool the free T has tipped over: every edge from there is invalid."""
    return t_tilt(nodes.qpos) >= MAX_T_TILT
