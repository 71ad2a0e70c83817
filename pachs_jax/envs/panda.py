"""A Franka Panda arm written from the public modified-DH table, as MJCF built in code
(conventions: docs/tasks.md)."""

from __future__ import annotations

import dataclasses

import numpy as np

# Modified DH parameters (metres, radians), joints 1..7.
DH_A = (0.0, 0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088)
DH_D = (0.333, 0.0, 0.316, 0.0, 0.384, 0.0, 0.107)
DH_ALPHA = (0.0, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2)

JOINT_LOWER = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
JOINT_UPPER = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
VELOCITY_LIMIT = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])  # rad/s
TORQUE_LIMIT = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0])  # N m

# Link masses (kg), after Franka's published dynamic parameters, rounded.
LINK_MASS = (4.97, 0.65, 3.23, 3.59, 1.23, 1.67, 0.74)

# Collision capsule radius of each link (m).
LINK_RADIUS = (0.065, 0.065, 0.06, 0.06, 0.055, 0.05, 0.045)

NUM_JOINTS = 7


@dataclasses.dataclass(frozen=True)
class ArmConfig:
  """Actuation of the arm: position servos on every joint (gains: docs/tasks.md).

  kp: [7] position gains (N m / rad); kv: [7] velocity gains (N m s / rad).
  armature: [7] reflected rotor inertia (kg m^2); damping: [7] joint damping (N m s / rad).
  """

  kp: tuple = (2500.0, 2500.0, 750.0, 1000.0, 300.0, 300.0, 225.0)
  kv: tuple = (80.0, 80.0, 24.0, 32.0, 9.6, 9.6, 7.2)
  armature: tuple = (0.1,) * 7
  damping: tuple = (0.5,) * 7


def _link_offset(i: int) -> tuple[np.ndarray, np.ndarray]:
  """Position [3] (m) and quaternion [4] (w, x, y, z) of body i+1 (0-based i) in its parent."""
  a, d, alpha = DH_A[i], DH_D[i], DH_ALPHA[i]
  pos = np.array([a, -np.sin(alpha) * d, np.cos(alpha) * d])
  quat = np.array([np.cos(alpha / 2), np.sin(alpha / 2), 0.0, 0.0])
  return pos, quat


def _fmt(v) -> str:
  return ' '.join('%.6g' % float(x) for x in np.ravel(v))


def _link_geoms(i: int, prefix: str) -> str:
  """Collision geoms of body i+1: a capsule to the next joint, or a sphere if it coincides."""
  r = LINK_RADIUS[i]
  if i + 1 < NUM_JOINTS:
    nxt, _ = _link_offset(i + 1)
  else:
    nxt = np.zeros(3)
  geoms = [f'<geom name="{prefix}link{i + 1}_joint" type="sphere" size="{r}" class="arm"/>']
  if np.linalg.norm(nxt) > 1e-6:
    geoms.append(f'<geom name="{prefix}link{i + 1}" type="capsule" size="{r}" '
                 f'fromto="0 0 0 {_fmt(nxt)}" class="arm"/>')
  return '\n'.join(geoms)


def _end_effector(kind: str, prefix: str) -> str:
  """Geoms of the end effector, attached at the flange (origin of body 7, pointing along +z)."""
  if kind == 'stick':
    # A 0.1 m stick of radius 8 mm below the flange; the pusher tip is its far end.
    return (f'<geom name="{prefix}stick" type="capsule" size="0.008" fromto="0 0 0.01 0 0 0.1" '
            f'rgba="0.9 0.9 0.9 1" mass="0.05" contype="0" conaffinity="0"/>\n'
            f'<site name="{prefix}tip" pos="0 0 0.1" size="0.005"/>')
  if kind == 'hand':
    # A simple parallel-jaw hand, rotated -45 deg about the flange axis like the real one.
    return (f'<body name="{prefix}hand" pos="0 0 0" quat="0.92388 0 0 -0.382683">'
            f'<geom name="{prefix}palm" type="box" size="0.03 0.1 0.03" pos="0 0 0.035" '
            f'mass="0.6" class="arm"/>'
            f'<geom name="{prefix}finger_left" type="box" size="0.01 0.012 0.025" '
            f'pos="0 0.04 0.09" mass="0.02" class="arm"/>'
            f'<geom name="{prefix}finger_right" type="box" size="0.01 0.012 0.025" '
            f'pos="0 -0.04 0.09" mass="0.02" class="arm"/>'
            f'<site name="{prefix}tip" pos="0 0 0.105" size="0.005"/></body>')
  raise ValueError(f"unknown end effector {kind!r}; valid: 'stick', 'hand'")


def arm_body_xml(end_effector: str = 'stick', base_pos=(0.0, 0.0, 0.0), prefix: str = '',
                 config: ArmConfig = ArmConfig(), gravcomp: float = 0.0) -> str:
  """MJCF <body> of the arm with joints 'joint1'..'joint7' and sites 'flange' and 'tip';
  gravcomp: the links' gravity compensation (1: the arm ignores gravity in a scene with it)."""
  close = []
  parts = [f'<body name="{prefix}link0" pos="{_fmt(base_pos)}">',
           f'<geom name="{prefix}link0" type="capsule" size="0.07" fromto="0 0 0.05 0 0 0.25" '
           f'class="arm"/>']
  for i in range(NUM_JOINTS):
    pos, quat = _link_offset(i)
    lo, hi = JOINT_LOWER[i], JOINT_UPPER[i]
    comp = f' gravcomp="{gravcomp:g}"' if gravcomp else ''
    parts.append(f'<body name="{prefix}link{i + 1}" pos="{_fmt(pos)}" quat="{_fmt(quat)}"'
                 f'{comp}>')
    parts.append(f'<inertial pos="0 0 0" mass="{LINK_MASS[i]}" '
                 f'diaginertia="{_fmt(np.full(3, 0.004 + 0.006 * LINK_MASS[i]))}"/>')
    parts.append(f'<joint name="{prefix}joint{i + 1}" range="{lo:.4f} {hi:.4f}" class="arm" '
                 f'armature="{config.armature[i]}" damping="{config.damping[i]}"/>')
    parts.append(_link_geoms(i, prefix))
    close.append('</body>')
  parts.append(f'<site name="{prefix}flange" pos="0 0 0" size="0.01"/>')
  parts.append(_end_effector(end_effector, prefix))
  parts.extend(close)
  parts.append('</body>')
  return '\n'.join(parts)


def arm_defaults_xml() -> str:
  """The <default> class 'arm' shared by joints and collision geoms."""
  return ('<default class="arm">'
          '<joint type="hinge" axis="0 0 1" limited="true"/>'
          '<geom contype="0" conaffinity="0" rgba="0.95 0.95 0.95 1" group="1"/>'
          '</default>')


def arm_actuators_xml(config: ArmConfig = ArmConfig(), prefix: str = '') -> str:
  """Position servos on joints 1..7, force-limited to the Panda's torque limits."""
  rows = []
  for i in range(NUM_JOINTS):
    lo, hi = JOINT_LOWER[i], JOINT_UPPER[i]
    rows.append(f'<position name="{prefix}act{i + 1}" joint="{prefix}joint{i + 1}" '
                f'kp="{config.kp[i]}" kv="{config.kv[i]}" ctrlrange="{lo:.4f} {hi:.4f}" '
                f'forcerange="{-TORQUE_LIMIT[i]} {TORQUE_LIMIT[i]}"/>')
  return '<actuator>' + '\n'.join(rows) + '</actuator>'
