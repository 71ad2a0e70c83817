"""Panda-Shelf: a collision-free reach into the compartments of a bookshelf (after panda-gym),
with kinematic edges and exact signed distances in JAX (model: docs/tasks.md)."""

from __future__ import annotations

import dataclasses
from typing import Dict, Tuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from pachs_jax.envs import base, ik, kinematics, panda, warp_import

mjx = warp_import.quiet_mjx()  # mujoco.mjx, without its stdout line about a missing warp-lang

HOME_QPOS = (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785)
FAR_DISTANCE = 10.0  # m: the distance reported for a geom with no pair (never near the shelf)
_GOLDEN = 0.5 * (np.sqrt(5.0) - 1.0)
# Signs of a box's 8 corners, and for each of its 12 edges the signs of the two end corners.
_CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
                         np.float32)
_EDGE_SIGNS = np.array(
    [[np.insert([s1, s2], k, -1.0), np.insert([s1, s2], k, 1.0)]
     for k in range(3) for s1 in (-1, 1) for s2 in (-1, 1)], np.float32)  # [12, 2, 3]


@dataclasses.dataclass(frozen=True)
class ShelfConfig:
  """Shelf geometry, edge model, reward and instance generation of Panda-Shelf.

  Geometry (m): the shelf spans x in [front_x, front_x + depth], y in +-width / 2;
  `board_z` are the centre heights of the horizontal boards from the lowest (a plinth down to
  the floor) to the top one; `num_columns` columns split by vertical dividers; boards, sides,
  dividers and back are `thickness` thick. A floor slab lies below z = 0.
  Targets: uniform in a compartment's interior shrunk by `target_clearance` (and at least
  `target_min_inset` behind the open front), kept if IK finds a configuration with the tip on
  it and every pair at least `ik_clearance` apart.
  Edges: q' = q + action_scale * action (rad), `num_checks` collision checks per edge.
  Reward: `margin` (m) and `clearance_weight` shape the distance penalty (`dense_reward`);
  an invalid edge ends the episode with -(invalid_horizon * |tip - target| + invalid_penalty).
  """

  front_x: float = 0.45
  depth: float = 0.35
  width: float = 0.8
  board_z: Tuple[float, ...] = (0.12, 0.38, 0.64, 0.90)
  num_columns: int = 2
  thickness: float = 0.02
  collision_geoms: Tuple[str, ...] = ('link2', 'link3', 'link4', 'link6', 'palm',
                                      'finger_left', 'finger_right')
  home_qpos: Tuple[float, ...] = HOME_QPOS
  action_scale: float = 0.05
  num_checks: int = 5
  goal_tolerance: float = 0.05
  episode_length: int = 100
  lattice_resolution: float = 0.05
  margin: float = 0.05
  clearance_weight: float = 0.2
  invalid_horizon: float = 100.0
  invalid_penalty: float = 1.0
  target_clearance: float = 0.06
  target_min_inset: float = 0.05
  ik_clearance: float = 0.02
  ik_restarts: int = 4
  train_targets: int = 0
  train_seed: int = 12345
  golden_iterations: int = 24
  kinematics: str = 'chain'


# ---------------------------------------------------------------- shelf geometry (numpy)


def _shelf_boxes(config: ShelfConfig) -> Dict[str, Tuple[np.ndarray, np.ndarray]]:
  """Axis-aligned boxes of the scene: name -> (centre [3], half extents [3]) in metres."""
  c, t = config, config.thickness
  if len(c.board_z) < 2 or any(b <= a for a, b in zip(c.board_z, c.board_z[1:])):
    raise ValueError(f'board_z must hold at least 2 increasing heights, got {c.board_z}')
  if c.num_columns < 1:
    raise ValueError(f'num_columns must be >= 1, got {c.num_columns}')
  x0, x1, hw = c.front_x, c.front_x + c.depth, 0.5 * c.width
  top = c.board_z[-1] + 0.5 * t
  xc, hx = 0.5 * (x0 + x1), 0.5 * c.depth
  boxes = {'floor': (np.array([0.5 * (x0 + x1), 0.0, -0.025]), np.array([1.2, 1.2, 0.025]))}
  plinth_top = c.board_z[0] + 0.5 * t
  boxes['board0'] = (np.array([xc, 0.0, 0.5 * plinth_top]), np.array([hx, hw, 0.5 * plinth_top]))
  for i, z in enumerate(c.board_z[1:], start=1):
    boxes[f'board{i}'] = (np.array([xc, 0.0, z]), np.array([hx, hw, 0.5 * t]))
  for name, y in (('side_right', -hw + 0.5 * t), ('side_left', hw - 0.5 * t)):
    boxes[name] = (np.array([xc, y, 0.5 * top]), np.array([hx, 0.5 * t, 0.5 * top]))
  for j in range(1, c.num_columns):
    y = -hw + c.width * j / c.num_columns
    boxes[f'divider{j}'] = (np.array([xc, y, 0.5 * top]), np.array([hx, 0.5 * t, 0.5 * top]))
  boxes['back'] = (np.array([x1 - 0.5 * t, 0.0, 0.5 * top]), np.array([0.5 * t, hw, 0.5 * top]))
  return boxes


def compartments(config: ShelfConfig) -> np.ndarray:
  """[rows * columns, 2, 3] lower and upper corners (m) of each compartment's free interior.

  Ordered row-major from the bottom row, columns from -y to +y; x runs from the open front to
  the back panel.
  """
  c, t = config, config.thickness
  hw = 0.5 * c.width
  out = []
  for r in range(len(c.board_z) - 1):
    z0, z1 = c.board_z[r] + 0.5 * t, c.board_z[r + 1] - 0.5 * t
    for j in range(c.num_columns):
      y0 = -hw + c.width * j / c.num_columns + (t if j == 0 else 0.5 * t)
      y1 = -hw + c.width * (j + 1) / c.num_columns - (t if j == c.num_columns - 1 else 0.5 * t)
      out.append([[c.front_x, y0, z0], [c.front_x + c.depth - t, y1, z1]])
  return np.array(out)


def target_regions(config: ShelfConfig) -> np.ndarray:
  """[rows * columns, 2, 3] the boxes (m) targets are drawn from: compartments, shrunk."""
  comp = compartments(config).copy()
  cl = config.target_clearance
  comp[:, 0, :] += cl
  comp[:, 1, :] -= cl
  comp[:, 0, 0] = np.maximum(comp[:, 0, 0] - cl, config.front_x + config.target_min_inset)
  if np.any(comp[:, 1] <= comp[:, 0]):
    raise ValueError('target_clearance leaves no room for targets in the compartments')
  return comp


def _pairs(config: ShelfConfig, bare: mujoco.MjModel, boxes) -> list:
  """(arm geom, shelf box) names of the pairs that can touch, by a reach bound.

  The shoulder (body link2's origin, on joint 1's axis) does not move; an arm geom's points
  stay within (sum of body offsets from the shoulder along its chain) + |geom centre| +
  bounding radius of it. A box farther from the shoulder than that is left out.
  """
  data = mujoco.MjData(bare)
  mujoco.mj_kinematics(bare, data)
  shoulder = data.xpos[bare.body('link2').id]
  root = bare.body('link2').id
  out = []
  for g_name in config.collision_geoms:
    try:
      g = bare.geom(g_name)
    except KeyError as e:
      raise ValueError(f'unknown arm collision geom {g_name!r}') from e
    reach, b = np.linalg.norm(bare.geom_pos[g.id]) + bare.geom_rbound[g.id], bare.geom_bodyid[g.id]
    while b != root:
      if b == 0:
        raise ValueError(f'collision geom {g_name!r} is not on a moving link (link2 onwards)')
      reach += np.linalg.norm(bare.body_pos[b])
      b = bare.body_parentid[b]
    for b_name, (centre, half) in boxes.items():
      gap = np.linalg.norm(np.maximum(np.abs(shoulder - centre) - half, 0.0))
      if gap < reach:
        out.append((g_name, 'shelf_' + b_name))
  return out


def model_xml(config: ShelfConfig, with_pairs: bool = True) -> str:
  """MJCF of the arm (hand end effector, base at the origin) and the shelf boxes."""
  boxes = _shelf_boxes(config)
  geoms = ''.join(
      f'<geom name="shelf_{n}" type="box" pos="{c[0]:.6g} {c[1]:.6g} {c[2]:.6g}" '
      f'size="{h[0]:.6g} {h[1]:.6g} {h[2]:.6g}" class="shelf"/>' for n, (c, h) in boxes.items())
  pairs = ''
  if with_pairs:
    bare = mujoco.MjModel.from_xml_string(model_xml(config, with_pairs=False))
    pairs = ''.join(f'<pair geom1="{g}" geom2="{b}" margin="{config.margin}"/>'
                    for g, b in _pairs(config, bare, boxes))
  return f"""
<mujoco model="panda-shelf">
  <compiler angle="radian" autolimits="true"/>
  <default>
    {panda.arm_defaults_xml()}
    <default class="shelf"><geom contype="0" conaffinity="0" rgba="0.6 0.45 0.3 1"/></default>
  </default>
  <worldbody>
    <light pos="0 0 2" dir="0 0 -1" directional="true"/>
    {geoms}
    {panda.arm_body_xml('hand')}
  </worldbody>
  <contact>{pairs}</contact>
</mujoco>"""


# ---------------------------------------------------------------- signed distances (jax)


def _box_sdf(point: jax.Array, half: jax.Array) -> jax.Array:
  """[] signed distance (m) of a point [3] to an origin-centred axis-aligned box of half [3]."""
  q = jnp.abs(point) - half
  outside = jnp.sqrt(jnp.sum(jnp.square(jnp.maximum(q, 0.0))))
  return outside + jnp.minimum(jnp.max(q), 0.0)


def _segment_box_sdf(p0: jax.Array, p1: jax.Array, half: jax.Array,
                     iterations: int = 24) -> jax.Array:
  """[] min over the segment p0 [3] - p1 [3] of `_box_sdf` (box frame); golden-section search.

  Exact up to 0.618**iterations of the segment's length: the SDF of a convex set is convex.
  """
  f = lambda s: _box_sdf(p0 + s * (p1 - p0), half)

  def shrink(_, c):
    lo, hi, m1, m2, f1, f2 = c
    left = f1 <= f2  # a minimiser lies in [lo, m2]
    lo, hi = jnp.where(left, lo, m1), jnp.where(left, m2, hi)
    n1 = jnp.where(left, hi - _GOLDEN * (hi - lo), m2)
    n2 = jnp.where(left, m1, lo + _GOLDEN * (hi - lo))
    fn = f(jnp.where(left, n1, n2))
    return lo, hi, n1, n2, jnp.where(left, fn, f2), jnp.where(left, f1, fn)

  m1, m2 = 1.0 - _GOLDEN, _GOLDEN
  init = (jnp.float32(0.0), jnp.float32(1.0), jnp.float32(m1), jnp.float32(m2), f(m1), f(m2))
  _, _, _, _, f1, f2 = jax.lax.fori_loop(0, iterations, shrink, init)
  return jnp.minimum(jnp.minimum(f1, f2), jnp.minimum(f(0.0), f(1.0)))


def _box_box_distance(centre: jax.Array, rot: jax.Array, half_a: jax.Array, half_b: jax.Array,
                      iterations: int = 24) -> jax.Array:
  """[] signed distance (m) of box A (centre [3], rotation [3, 3] in B's frame, half_a [3]) to
  the origin-centred axis-aligned box B (half_b [3]); negative: penetration depth."""
  eye = jnp.eye(3, dtype=centre.dtype)
  axes_a = rot.T  # rows: A's axes in B's frame
  cross = jnp.cross(eye[:, None, :], axes_a[None, :, :]).reshape(9, 3)
  axes = jnp.concatenate([eye, axes_a, cross])
  norm = jnp.linalg.norm(axes, axis=1)
  ok = norm > 1e-6  # parallel edges give no axis
  u = axes / jnp.where(ok, norm, 1.0)[:, None]
  sep = (jnp.abs(u @ centre) - jnp.abs(u @ rot) @ half_a - jnp.abs(u) @ half_b)
  sat = jnp.max(jnp.where(ok, sep, -jnp.inf))
  ends = centre + (jnp.asarray(_EDGE_SIGNS) * half_a) @ rot.T  # [12, 2, 3] A's edges in B frame
  edge = jax.vmap(lambda e: _segment_box_sdf(e[0], e[1], half_b, iterations))(ends)
  corners_b = (jnp.asarray(_CORNER_SIGNS) * half_b - centre) @ rot  # B's corners in A's frame
  corner = jax.vmap(lambda p: _box_sdf(p, half_a))(corners_b)
  return jnp.where(sat > 0.0, jnp.minimum(jnp.min(edge), jnp.min(corner)), sat)


# ---------------------------------------------------------------- the task


class ShelfEnv(base.Env):
  """Panda-Shelf. qpos = 7 joint angles (rad); goal = target tip position [3] (m).

  Edge: q' = q + action_scale * action, valid within the joint limits and collision-free at
  `num_checks` points of the straight joint-space motion; cost |tip(q') - tip(q)| (m); goal: the
  tip within `goal_tolerance` of the target. `step` trains on the dense reward of
  `dense_reward`, not on -cost (docs/tasks.md).
  """

  goal_size = 3

  def __init__(self, config: ShelfConfig = ShelfConfig()):
    if config.kinematics not in ('chain', 'mjx'):
      raise ValueError(f"kinematics must be 'chain' or 'mjx', got {config.kinematics!r}")
    if config.num_checks < 1:
      raise ValueError(f'num_checks must be >= 1, got {config.num_checks}')
    if len(config.home_qpos) != panda.NUM_JOINTS:
      raise ValueError(f'home_qpos must have {panda.NUM_JOINTS} angles, got {config.home_qpos}')
    self.config = config
    self.name = 'shelf'
    self.episode_length = config.episode_length
    self.boxes = _shelf_boxes(config)
    self.compartments = compartments(config)
    self.target_regions = target_regions(config)
    self.mj_model = mujoco.MjModel.from_xml_string(model_xml(config))
    self.mjx_model = mjx.put_model(self.mj_model)
    self._data_template = mjx.make_data(self.mjx_model)
    self.chain = kinematics.ChainKinematics(self.mj_model)
    m = self.mj_model
    self.tip_site = m.site('tip').id
    self.geom_ids = np.array([m.geom(n).id for n in config.collision_geoms])
    box_names = list(self.boxes)
    pair_geom, pair_box = [], []
    for i in range(m.npair):
      g1, g2 = int(m.pair_geom1[i]), int(m.pair_geom2[i])
      if g1 not in self.geom_ids:
        g1, g2 = g2, g1
      pair_geom.append(int(np.flatnonzero(self.geom_ids == g1)[0]))
      pair_box.append(box_names.index(m.geom(g2).name[len('shelf_'):]))
    self.pair_geom = np.array(pair_geom, np.int32)  # [P] index into collision_geoms
    self.pair_box = np.array(pair_box, np.int32)  # [P] index into boxes
    types = m.geom_type[self.geom_ids[self.pair_geom]]
    supported = (mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_CAPSULE,
                 mujoco.mjtGeom.mjGEOM_BOX)
    if not np.all(np.isin(types, supported)):
      raise ValueError('collision geoms must be spheres, capsules or boxes')
    self._pair_kind = {k: np.flatnonzero(types == k) for k in supported}
    self._box_centre = np.array([c for c, _ in self.boxes.values()], np.float32)
    self._box_half = np.array([h for _, h in self.boxes.values()], np.float32)
    self._geom_size = m.geom_size.astype(np.float32)  # [ngeom, 3]
    self.home_qpos = np.array(config.home_qpos, np.float32)
    self._lower, self._upper = jax.device_put(
        [np.asarray(x, np.float32) for x in (panda.JOINT_LOWER, panda.JOINT_UPPER)])
    self._targets_cache: Dict[Tuple[int, int], Tuple[np.ndarray, np.ndarray]] = {}

  fingerprint = property(base.config_fingerprint)

  @property
  def action_size(self) -> int:
    return panda.NUM_JOINTS

  @property
  def default_lattice_resolution(self) -> jax.Array:
    return jnp.full((panda.NUM_JOINTS,), self.config.lattice_resolution, jnp.float32)

  @property
  def lattice_extent(self) -> np.ndarray:
    # the joint angles of valid states lie within the joint limits
    return np.maximum(np.abs(panda.JOINT_LOWER), np.abs(panda.JOINT_UPPER))

  # ---- geometry of one configuration ----

  def _poses(self, qpos: jax.Array, ids: np.ndarray):
    """(geom pos [G, 3], geom mat [G, 3, 3] of geoms `ids`, tip position [3]) at qpos [7]."""
    if self.config.kinematics == 'mjx':
      data = mjx.kinematics(self.mjx_model, self._data_template.replace(qpos=qpos))
      return data.geom_xpos[ids], data.geom_xmat[ids], data.site_xpos[self.tip_site]
    xpos, xmat = self.chain.bodies(qpos)
    pos, mat = self.chain.geoms(xpos, xmat, ids)
    return pos, mat, self.chain.site(xpos, xmat, self.tip_site)

  def geometry(self, qpos: jax.Array) -> Tuple[jax.Array, jax.Array]:
    """(tip position [3] (m), per-collision-geom min signed distance to the shelf [G] (m))."""
    it = self.config.golden_iterations
    centre, half = jnp.asarray(self._box_centre), jnp.asarray(self._box_half)
    gpos, gmat, tip = self._poses(qpos, self.geom_ids)
    size = jnp.asarray(self._geom_size[self.geom_ids])
    dists, owners = [], []
    for kind, idx in self._pair_kind.items():
      if idx.size == 0:
        continue
      g, b = self.pair_geom[idx], self.pair_box[idx]
      pos = gpos[g] - centre[b]  # arm geom centre in the (axis-aligned) box frame
      if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        d = jax.vmap(_box_sdf)(pos, half[b]) - size[g, 0]
      elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        seg = gmat[g][:, :, 2] * size[g, 1:2]
        d = jax.vmap(lambda p0, p1, h: _segment_box_sdf(p0, p1, h, it))(
            pos - seg, pos + seg, half[b]) - size[g, 0]
      else:
        d = jax.vmap(lambda c, r, ha, hb: _box_box_distance(c, r, ha, hb, it))(
            pos, gmat[g], size[g], half[b])
      dists.append(d)
      owners.append(self.pair_geom[idx])
    far = jnp.full((len(self.geom_ids),), FAR_DISTANCE, jnp.float32)
    if dists:
      far = far.at[np.concatenate(owners)].min(jnp.concatenate(dists))
    return tip, far

  def tip_position(self, qpos: jax.Array) -> jax.Array:
    """[3] tip position (m) of one configuration [7]."""
    return self._poses(qpos, self.geom_ids[:1])[2]

  # ---- instances ----

  def node_from(self, qpos: jax.Array, target: jax.Array) -> base.NodeState:
    """A node at configuration qpos [7] with target [3] and t = 0; no batch axis."""
    qpos = jnp.asarray(qpos, jnp.float32)
    zeros = jnp.zeros((panda.NUM_JOINTS,), jnp.float32)
    return base.NodeState(qpos=qpos, qvel=zeros, ctrl=qpos, qacc_warmstart=zeros,
                          goal=jnp.asarray(target, jnp.float32), t=jnp.zeros((), jnp.int32))

  def reachable_targets(self, num: int, seed: int) -> Tuple[np.ndarray, np.ndarray]:
    """(targets [num, 3] (m), IK goal configurations [num, 7] (rad)), fixed by seed.

    Each target is drawn uniformly from a random compartment's target region and kept if damped
    least-squares IK finds a configuration within the joint limits with the tip on the target
    (1 mm) and all pairs at least `ik_clearance` apart (MuJoCo C distances). Computed on the
    host with MuJoCo C, once per (num, seed) per environment.
    """
    if num < 1:
      raise ValueError(f'num must be >= 1, got {num}')
    key = (int(num), int(seed))
    if key not in self._targets_cache:
      self._targets_cache[key] = ik.reachable_targets(
          self.mj_model, self.target_regions, num, seed, home=self.home_qpos,
          clearance=self.config.ik_clearance, restarts=self.config.ik_restarts)
    return self._targets_cache[key]

  def canonical_instances(self, num: int = 100, seed: int = 0) -> base.NodeState:
    """NodeState [num]: the home start with IK-verified targets fixed by seed (benchmarks)."""
    targets, _ = self.reachable_targets(num, seed)
    return jax.vmap(lambda t: self.node_from(self.home_qpos, t))(jnp.asarray(targets))

  def sample_instance(self, key: jax.Array) -> base.NodeState:
    """The home start and a target: uniform in a uniformly chosen compartment's target region
    (not checked for reachability), or, with `train_targets` > 0, drawn from a pool of that
    many IK-verified targets (seed `train_seed`, computed on the host at the first call)."""
    c = self.config
    if c.train_targets > 0:
      pool, _ = self.reachable_targets(c.train_targets, c.train_seed)
      i = jax.random.randint(key, (), 0, pool.shape[0])
      return self.node_from(self.home_qpos, jnp.asarray(pool)[i])
    regions = jnp.asarray(self.target_regions, jnp.float32)
    k_region, k_point = jax.random.split(key)
    r = jax.random.randint(k_region, (), 0, regions.shape[0])
    target = jax.random.uniform(k_point, (3,), minval=regions[r, 0], maxval=regions[r, 1])
    return self.node_from(self.home_qpos, target)

  # ---- the edge ----

  def _sanitize(self, node: base.NodeState) -> Tuple[jax.Array, jax.Array, jax.Array]:
    """(qpos [7] with non-finite entries set to home, goal [3] finite, [] bool node finite)."""
    ok = base.finite_node(node) & jnp.all(jnp.isfinite(node.goal))
    qpos = jnp.where(jnp.isfinite(node.qpos), node.qpos, jnp.asarray(self.home_qpos))
    goal = jnp.where(jnp.isfinite(node.goal), node.goal, 0.0)
    return qpos, goal, ok

  def _motion(self, node: base.NodeState, delta: jax.Array, delta_ok: jax.Array,
              num_checks: int):
    """(EdgeOutcome, tip(q) [3], tip(q') [3], per-geom distances at q' [G]) of the straight
    joint-space motion q -> q + delta [7], collision-checked at `num_checks` points."""
    qpos, goal, node_ok = self._sanitize(node)
    q_next = qpos + delta
    in_limits = jnp.all((q_next >= self._lower) & (q_next <= self._upper))
    frac = jnp.arange(1, num_checks + 1, dtype=jnp.float32) / num_checks
    path = qpos[None, :] + frac[:, None] * delta[None, :]
    tips, dists = jax.vmap(self.geometry)(path)
    tip0 = self.tip_position(qpos)
    tip1, dist1 = tips[-1], dists[-1]
    free = jnp.all(dists >= 0.0)
    is_valid = delta_ok & node_ok & in_limits & free
    next_node = base.NodeState(
        qpos=q_next, qvel=jnp.zeros_like(q_next), ctrl=q_next,
        qacc_warmstart=jnp.zeros_like(q_next), goal=goal, t=node.t + 1)
    cost = jnp.linalg.norm(tip1 - tip0)
    is_goal = (jnp.linalg.norm(tip1 - goal) < self.config.goal_tolerance) & is_valid
    return base.EdgeOutcome(next_node, cost, is_goal, is_valid), tip0, tip1, dist1

  def _edge(self, node: base.NodeState, action: jax.Array):
    action, action_ok = base.sanitize_actions(action)
    return self._motion(node, self.config.action_scale * action, action_ok,
                        self.config.num_checks)

  def transition(self, node: base.NodeState, action: jax.Array) -> base.EdgeOutcome:
    """q' = q + action_scale * clip(action); cost = |tip(q') - tip(q)| (m); is_goal only for a
    valid edge. An invalid edge's next_node is the attempted (finite) configuration."""
    return self._edge(node, action)[0]

  def move(self, node: base.NodeState, delta: jax.Array,
           num_checks: int | None = None) -> base.EdgeOutcome:
    """The edge of an arbitrary joint displacement delta [7] (rad) of one node, with the same
    checks and cost as `transition` (for motion primitives larger than one action, e.g. the
    ePA*SE baseline's); `num_checks` (static) defaults to the config's."""
    delta = jnp.asarray(delta, jnp.float32)
    if delta.shape != (panda.NUM_JOINTS,):
      raise ValueError(f'delta must have shape [{panda.NUM_JOINTS}], got {delta.shape}')
    checks = self.config.num_checks if num_checks is None else int(num_checks)
    if checks < 1:
      raise ValueError(f'num_checks must be >= 1, got {checks}')
    ok = jnp.all(jnp.isfinite(delta))
    return self._motion(node, jnp.where(jnp.isfinite(delta), delta, 0.0), ok, checks)[0]

  # ---- what the networks and the search read ----

  def _observation(self, qpos, goal, tip, dists) -> jax.Array:
    span = self._upper - self._lower
    q = 2.0 * (qpos - self._lower) / span - 1.0
    clear = jnp.clip(dists, 0.0, self.config.margin) / self.config.margin
    return jnp.concatenate([q, tip, goal, goal - tip, clear]).astype(jnp.float32)

  def observation(self, node: base.NodeState) -> jax.Array:
    """[7 + 3 + 3 + 3 + G]: joint angles scaled to [-1, 1], tip, target, target - tip (m),
    per-collision-geom distance to the shelf clipped at `margin`, over `margin`."""
    qpos, goal, _ = self._sanitize(node)
    tip, dists = self.geometry(qpos)
    return self._observation(qpos, goal, tip, dists)

  def lattice_coords(self, node: base.NodeState, resolution: jax.Array) -> jax.Array:
    qpos, _, _ = self._sanitize(node)
    return jnp.floor(qpos / resolution).astype(jnp.int32)

  def goal_reached(self, node: base.NodeState) -> jax.Array:
    qpos, goal, ok = self._sanitize(node)
    return ok & (jnp.linalg.norm(self.tip_position(qpos) - goal) < self.config.goal_tolerance)

  # ---- training interface: the dense reward (overrides Env.step) ----

  def dense_reward(self, tip: jax.Array, goal: jax.Array, dists: jax.Array) -> jax.Array:
    """[] -|tip - goal| - clearance_weight * max(0, margin - min(dists)) / margin."""
    c = self.config
    near = jnp.maximum(c.margin - jnp.min(dists), 0.0) / c.margin
    return -jnp.linalg.norm(tip - goal) - c.clearance_weight * near

  def reset(self, key: jax.Array) -> base.State:
    node = self.sample_instance(key)
    zero = jnp.zeros((), jnp.float32)
    tip, dists = self.geometry(node.qpos)
    metrics = {'success': zero, 'cost': zero, 'target_distance': jnp.linalg.norm(tip - node.goal),
               'min_distance': jnp.min(dists)}
    return base.State(node, self._observation(node.qpos, node.goal, tip, dists), zero, zero,
                      metrics, {'truncation': zero})

  def step(self, state: base.State, action: jax.Array) -> base.State:
    """One control step with the dense reward (not -cost); done on success, invalid edge or
    time limit. After an invalid edge the (terminal) state is the attempted configuration."""
    base.check_actions(action, self.action_size, batched=False)
    c = self.config
    out, tip0, tip1, dists = self._edge(state.pipeline_state, action)
    node = out.next_node
    reward_bad = -(c.invalid_horizon * jnp.linalg.norm(tip0 - node.goal) + c.invalid_penalty)
    reward = jnp.where(out.is_valid, self.dense_reward(tip1, node.goal, dists), reward_bad)
    success = out.is_goal.astype(jnp.float32)
    invalid = 1.0 - out.is_valid.astype(jnp.float32)
    time_up = (node.t >= self.episode_length).astype(jnp.float32)
    done = jnp.maximum(jnp.maximum(success, invalid), time_up)
    # A truncation is a time limit without a terminal event (bootstrapping continues).
    truncation = time_up * (1.0 - jnp.maximum(success, invalid))
    metrics = {'success': success, 'cost': out.cost,
               'target_distance': jnp.linalg.norm(tip1 - node.goal), 'min_distance': jnp.min(dists)}
    obs = self._observation(node.qpos, node.goal, tip1, dists)
    return base.State(node, obs, reward.astype(jnp.float32), done, metrics,
                      dict(state.info, truncation=truncation))
