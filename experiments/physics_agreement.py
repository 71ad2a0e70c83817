"""PushT physics against references, measured over the shipped policy's pushes (issue 32).

  python experiments/physics_agreement.py reference    # planar T against the free T
  python experiments/physics_agreement.py penetration  # T-block and stick-block depth
  python experiments/physics_agreement.py agreement    # planners (MJX, ...) against the world
  python experiments/physics_agreement.py contacts     # Warp's T-block contacts against C's
  python experiments/physics_agreement.py stick        # Warp's stick-T contacts against C's

The stochastic pusht-fixed policy runs in a MuJoCo C float64 world of the reference physics
from the layouts' canonical starts; the candidates replay its actions from the world's states
every 10 steps; reported: the T's position (mm) and angle (deg) error percentiles after 1, 10
and 30 control steps, the deepest block penetrations, and each candidate's step cost on this
machine's CPU (MuJoCo C one thread; MJX a vmapped batch). `contacts` draws the T tilted near
a block instead and compares the T-block contacts of MuJoCo C with MuJoCo Warp's (CPU kernels),
colliding box pairs by its general convex collider and by the box-box routine (the model's).
`stick` presses the T against the stick (a capsule) instead and compares their contacts."""

from __future__ import annotations

import argparse
import copy
import dataclasses
import time
from typing import Dict, Tuple

import numpy as np

import common


def build_parser() -> argparse.ArgumentParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('part',
                      choices=['reference', 'penetration', 'agreement', 'gap', 'contacts',
                               'stick'])
  parser.add_argument('--layouts', default='gate,wall')
  parser.add_argument('--steps', type=int, default=40, help='world control steps per instance')
  parser.add_argument('--horizons', default='1,10,30')
  parser.add_argument('--planners', default='mjx,mujoco-c', help='agreement: planner physics')
  parser.add_argument('--candidates', default=None, help='agreement: names, comma separated')
  parser.add_argument('--bare-models', action='store_true',
                      help="agreement: replay on the config's bare models, not the envs")
  parser.add_argument('--samples', type=int, default=100,
                      help='contacts: T poses touching a block per layout and tilt range; '
                      'stick: T poses pressed against the stick per tilt range')
  parser.add_argument('--mjx-cost', action='store_true', help='also time MJX steps (slow)')
  parser.add_argument('--mjx-worlds', default='16', help='batch sizes of the MJX timing')
  common.add_common_args(parser, out=None, instances=8, seed=True)
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402

from pachs_jax import planner  # noqa: E402
import agreement  # noqa: E402
from pachs_jax.envs import pusht  # noqa: E402
# pylint: enable=wrong-import-position

P = pusht.PushTConfig
# Every named candidate below is PushTConfig physics fields over the 'planar' preset (the default
# when they were written); 'faithful' spells out the faithful physics with soft blocks (the
# 'soft-blocks' preset), 'faithful margin3mm' today's defaults.
BASE = pusht.PHYSICS_PRESETS['planar']
PLANAR = dict()  # the planar preset itself
FAITHFUL = {f: getattr(pusht.physics_preset('soft-blocks'), f) for f in pusht.PHYSICS_FIELDS}
MANISKILL_STEP = dict(physics_dt=0.01, substeps=5)
HARD = dict(block_solref=(0.005, 1.0), block_solimp=(0.99, 0.999, 0.0005, 0.5, 2))
# stiff blocks that hold: 2.5 ms steps, MuJoCo's solref clamp (2 dt) met, 20 solver iterations
STIFF = dict(physics_dt=0.0025, substeps=20, solver_iterations=20, ls_iterations=20,
             block_solref=(0.005, 1.0), block_solimp=(0.99, 0.999, 0.001, 0.5, 2))
FREE = dict(t_body='free', table_friction=3.0)
# the faithful physics at half its step, the blocks' solref at that step's 2-step limit
FINE = dict(FAITHFUL, physics_dt=0.00125, substeps=40, block_solref=(0.0025, 1.0))

# name -> PushTConfig physics fields
REFERENCE = {  # free T (world) and planar fits, ManiSkill's friction 3 and 100 Hz x 5 physics
    'free mu3': dict(t_body='free', table_friction=3.0, **MANISKILL_STEP),
}
PLANAR_FITS = {
    'planar mu3': dict(table_friction=3.0, **MANISKILL_STEP),
    'planar mu3 r0.03': dict(table_friction=3.0, t_friction_radius=0.03, **MANISKILL_STEP),
    'planar mu3 r0.07': dict(table_friction=3.0, t_friction_radius=0.07, **MANISKILL_STEP),
    'planar mu2.5': dict(table_friction=2.5, **MANISKILL_STEP),
    'planar mu3 damp0': dict(table_friction=3.0, t_damping=0.0, t_yaw_damping=0.0,
                             **MANISKILL_STEP),
}
PENETRATION = {
    'faithful': FAITHFUL,
    'faithful margin1mm': dict(FAITHFUL, block_margin=0.001),
    'faithful 1.25ms x40': FINE,
    'faithful 1.25ms x40 margin1mm': dict(FINE, block_margin=0.001),
    'faithful 1.25ms x40 margin2mm': dict(FINE, block_margin=0.002),
    'faithful margin2mm': dict(FAITHFUL, block_margin=0.002),
    'faithful margin3mm': dict(FAITHFUL, block_margin=0.003),
    'planar': PLANAR,
    '10ms x5': MANISKILL_STEP,
    '10ms x5 hard': dict(**MANISKILL_STEP, **HARD),
    '5ms x10 hard': dict(physics_dt=0.005, substeps=10, **HARD),
    '10ms x5 hard margin2mm': dict(**MANISKILL_STEP, **HARD, block_margin=0.002),
    '2.5ms x20 stiff': STIFF,
    'free mu3 10ms x5': dict(**FREE, **MANISKILL_STEP),
    'free mu3 2.5ms x20 stiff': dict(**FREE, **STIFF),
    'free mu3 5ms x10': dict(**FREE, physics_dt=0.005, substeps=10),
    'free mu3 5ms x10 stiff it20': dict(**FREE, physics_dt=0.005, substeps=10,
                                         solver_iterations=20, ls_iterations=20,
                                         block_solref=(0.01, 1.0),
                                         block_solimp=(0.99, 0.999, 0.001, 0.5, 2)),
}
AGREEMENT = {
    'faithful': FAITHFUL,
    **{name: PENETRATION[name] for name in PENETRATION
       if name.startswith('faithful') and name != 'faithful'},
    'planar': PLANAR,
    'newton 10/20': dict(solver_iterations=10, ls_iterations=20),
    '10ms x5': MANISKILL_STEP,
    '10ms x5 newton 10/20': dict(**MANISKILL_STEP, solver_iterations=10, ls_iterations=20),
    '5ms x10': dict(physics_dt=0.005, substeps=10),
    'planar mu3 10ms x5': dict(table_friction=3.0, **MANISKILL_STEP),
    'free mu3 5ms x10': dict(**FREE, physics_dt=0.005, substeps=10),
    'free mu3 2.5ms x20 stiff': dict(**FREE, **STIFF),
    'free mu3 5ms x10 stiff it20': dict(**FREE, physics_dt=0.005, substeps=10,
                                         solver_iterations=20, ls_iterations=20,
                                         block_solref=(0.01, 1.0),
                                         block_solimp=(0.99, 0.999, 0.001, 0.5, 2)),
    '2.5ms x20 stiff': STIFF,
    'free mu3 10ms x5': REFERENCE['free mu3'],
    'free mu3 10ms x5 newton 10/20': dict(**REFERENCE['free mu3'], solver_iterations=10,
                                          ls_iterations=20),
}


def config_of(layout: str, fields: dict) -> pusht.PushTConfig:
  """The PushT-Obs config of a layout with physics fields over the 'planar' preset."""
  return pusht.PushTConfig(variant='obs', layout=layout, **{**BASE, **fields})


def policy_of(model, env, seed: int) -> agreement.Policy:
  """The shipped model's stochastic policy on planar nodes (numpy in, numpy out)."""
  sample = jax.jit(lambda key, obs: model.sample_actions(key, obs, 1)[:, 0])
  key = jax.random.PRNGKey(seed)

  def policy(nodes, t):
    obs = env.observe(jax.tree.map(jnp.asarray, nodes))
    return np.asarray(sample(jax.random.fold_in(key, t), obs))
  return policy


def world_rollouts(config, starts, policy, steps):
  return agreement.CWorld(config).run(starts.qpos, starts.qvel, starts.goal, policy, steps)


def error_rows(replayed, truth, horizons, extra):
  rows = []
  for h in horizons:
    pos, ang = agreement.pose_errors(replayed[:, h], truth[:, h])
    rows.append({**extra, 'horizon': h, 'replays': int(pos.size),
                 **agreement.percentiles(pos, ang)})
    print(rows[-1], flush=True)
  return rows


def c_step_us(config, rollouts, repeats: int = 3) -> float:
  """Microseconds per physics step of MuJoCo C (one thread) from the rollouts' states."""
  world = agreement.CWorld(config)
  qpos, qvel = rollouts.qpos.reshape(-1, rollouts.qpos.shape[-1]), rollouts.qvel.reshape(
      -1, rollouts.qvel.shape[-1])
  qpos, qvel = world.state_of(qpos, qvel)
  pick = np.linspace(0, len(qpos) - 1, 32).astype(int)
  d, m = world.data, world.model
  best = np.inf
  for _ in range(repeats):
    t0 = time.perf_counter()
    for i in pick:
      d.qpos[:], d.qvel[:], d.ctrl[:] = qpos[i], qvel[i], qpos[i, :7]
      mujoco.mj_step(m, d, nstep=20)
    best = min(best, (time.perf_counter() - t0) / (20 * len(pick)))
  return 1e6 * best


def mjx_step_ms(config, rollouts, worlds: int = 16) -> float:
  """Milliseconds per control step of `worlds` vmapped MJX worlds (free or planar T)."""
  mjx = pusht.mjx
  model = mujoco.MjModel.from_xml_string(pusht.model_xml(config))
  mx = mjx.put_model(model)
  world = agreement.CWorld(config)
  qpos, qvel = world.state_of(rollouts.qpos.reshape(-1, rollouts.qpos.shape[-1]),
                              rollouts.qvel.reshape(-1, rollouts.qvel.shape[-1]))
  pick = np.linspace(0, len(qpos) - 1, worlds).astype(int)
  data = jax.vmap(lambda q, v: mjx.make_data(mx).replace(qpos=q, qvel=v, ctrl=q[:7]))(
      jnp.asarray(qpos[pick], jnp.float32), jnp.asarray(qvel[pick], jnp.float32))
  step = jax.jit(lambda d: jax.lax.fori_loop(
      0, config.substeps, lambda _, x: jax.vmap(lambda y: mjx.step(mx, y))(x), d))
  jax.block_until_ready(step(data))
  jax.block_until_ready(step(data))
  t0 = time.perf_counter()
  for _ in range(3):
    out = step(data)
  jax.block_until_ready(out)
  return 1e3 * (time.perf_counter() - t0) / 3


def run_reference(args, layouts, policies, starts_of):
  """Item 1: planar candidates against the free T, replayed in MuJoCo C float64."""
  rows, costs = [], []
  length = max(args.horizons)
  for layout in layouts:
    (ref_name, ref_fields), = REFERENCE.items()
    ref = config_of(layout, ref_fields)
    roll = world_rollouts(ref, starts_of[layout], policies[layout], args.steps)
    quat = roll.qpos[..., 10:14]
    tilt = np.degrees(2 * np.arcsin(np.sqrt(np.clip(quat[..., 1] ** 2 + quat[..., 2] ** 2,
                                                    0, 1))))
    costs.append({'physics': f'{ref_name} world on {layout}: T tilt',
                  'max_tilt_deg': float(tilt.max()),
                  'instances_tilted_over_5deg': int((tilt.max(1) > 5).sum()),
                  'instances': len(tilt),
                  'max_height_mm': float(1e3 * roll.qpos[..., 9].max())})
    print(costs[-1], flush=True)
    begins = agreement.replay_begins(args.steps, length)
    truth = agreement.truth_at(roll, begins, length)
    qpos, qvel = roll.planar()
    for name, fields in {ref_name + ' (float64 replay)': ref_fields, 'planar': PLANAR,
                         **PLANAR_FITS}.items():
      cfg = config_of(layout, fields)
      world = agreement.CWorld(cfg)
      src_q = roll.qpos if cfg.t_body == 'free' else qpos
      src_v = roll.qvel if cfg.t_body == 'free' else qvel
      rep = world.replay(np.concatenate([src_q[:, b] for b in begins]),
                         np.concatenate([src_v[:, b] for b in begins]), None,
                         np.concatenate([roll.actions[:, b:b + length] for b in begins]))
      rows += error_rows(rep, truth, args.horizons,
                         {'layout': layout, 'world': ref_name, 'physics': name})
      if layout == layouts[0]:
        costs.append({'physics': name, 'mujoco_c_us_per_physics_step': c_step_us(cfg, roll),
                      'physics_dt_ms': 1e3 * cfg.physics_dt, 'substeps': cfg.substeps})
        if args.mjx_cost and name in ('planar mu3', ref_name + ' (float64 replay)'):
          costs[-1]['mjx_ms_per_control_step_16_worlds'] = mjx_step_ms(cfg, roll)
        print(costs[-1], flush=True)
  return rows, costs


def gap_push(fields: dict, steps: int = 60) -> dict:
  """A flat T pushed hard into the 'slot' layout's 0.16 m gap, bar first (the bar is 0.2 m):
  the stick pushes on the stem's end straight down (-y) for `steps` control steps. Returns the
  lowest y of the T's origin (the gap spans y 0.03-0.07; the origin is 0.0625 m above the bar's
  edge, so below 0.0925 means the bar entered the blocks' band), its tilt and the deepest
  T-block penetration (mm)."""
  cfg = config_of('slot', fields)
  world = agreement.CWorld(cfg)
  # the policy sees planar nodes (`agreement.CWorld.run`): the arm's kinematics in a planar model
  model = mujoco.MjModel.from_xml_string(pusht.model_xml(P(t_body='planar')))
  data = mujoco.MjData(model)
  x0 = -0.155
  start = np.concatenate([pusht.HOME_QPOS, [x0, 0.165, 0.0]])

  def policy(nodes, t):
    q = np.asarray(nodes.qpos[0], np.float64)
    tip = ([x0, 0.33, 0.09] if t < 8 else [x0, 0.33, 0.02] if t < 11 else [x0, -0.2, 0.02])
    return pusht.jacobian_action(model, data, np.array(tip), q, max_step=0.05)[None]

  roll = world.run(start[None], np.zeros((1, 10)), np.asarray([pusht.FIXED_GOAL]), policy,
                   steps)
  qpos, _ = roll.planar()
  out = {'lowest_t_origin_y_mm': 1e3 * float(qpos[0, :, 8].min()),
         'bar_entered_block_band': bool(qpos[0, :, 8].min() < 0.0925 - 0.002),
         't_block_max_mm': 1e3 * float(roll.t_block.max())}
  if cfg.t_body == 'free':
    quat = roll.qpos[0, :, 10:14]
    out['max_tilt_deg'] = float(np.degrees(2 * np.arcsin(np.sqrt(np.clip(
        quat[:, 1] ** 2 + quat[:, 2] ** 2, 0, 1)))).max())
  print(out, flush=True)
  return out


def run_penetration(args, layouts, policies, starts_of):
  """Item 2: the deepest T-block and stick-block penetration of policy rollouts."""
  rows = []
  names = args.candidates.split(',') if args.candidates else list(PENETRATION)
  for name in names:
    fields = PENETRATION[name]
    for layout in layouts:
      cfg = config_of(layout, fields)
      roll = world_rollouts(cfg, starts_of[layout], policies[layout], args.steps)
      rows.append({'physics': name, 'layout': layout, 'instances': len(roll.t_block),
                   't_block_max_mm': 1e3 * float(roll.t_block.max()),
                   't_block_median_mm': 1e3 * float(np.median(roll.t_block)),
                   'stick_block_max_mm': 1e3 * float(roll.stick_block.max()),
                   'mujoco_c_us_per_physics_step': c_step_us(cfg, roll),
                   'physics_steps_per_control_step': cfg.substeps})
      print(rows[-1], flush=True)
  return rows, []


def run_gap(args, layouts, policies, starts_of):
  """A gap narrower than the T: `gap_push` for each penetration candidate."""
  del layouts, policies, starts_of
  names = args.candidates.split(',') if args.candidates else list(PENETRATION)
  return [{'name': name, **gap_push(PENETRATION[name])} for name in names], []


def run_agreement(args, layouts, policies, starts_of):
  """Item 3: the planners' physics (MJX float32, MuJoCo C float32 states) against the world of
  the same settings in MuJoCo C float64."""
  rows, costs = [], []
  length = max(args.horizons)
  names = (args.candidates.split(',') if args.candidates
           else [k for k in AGREEMENT if not k.startswith('free')])
  for name in names:
    fields = AGREEMENT[name]
    for layout in layouts:
      cfg = config_of(layout, fields)
      roll = world_rollouts(cfg, starts_of[layout], policies[layout], args.steps)
      begins = agreement.replay_begins(args.steps, length)
      truth = agreement.truth_at(roll, begins, length)
      for planner_name in args.planners.split(','):
        t0 = time.perf_counter()
        if cfg.t_body == 'free' or args.bare_models:
          rep = (agreement.c_replay(cfg, roll, begins, length) if planner_name == 'mujoco-c'
                 else agreement.model_replay(cfg, roll, begins, length,
                                             'warp' if planner_name == 'warp' else 'jax'))
        else:
          rep = agreement.replay_planner(agreement.planner_env(cfg, planner_name), roll,
                                         begins, length)
        seconds = time.perf_counter() - t0
        rows += error_rows(rep, truth, args.horizons,
                           {'physics': name, 'layout': layout, 'planner': planner_name,
                            'replay_s': round(seconds, 1)})
      if layout == layouts[0]:
        costs.append({'physics': name, 'mujoco_c_us_per_physics_step': c_step_us(cfg, roll),
                      'physics_dt_ms': 1e3 * cfg.physics_dt, 'substeps': cfg.substeps,
                      'iterations': cfg.solver_iterations,
                      'ls_iterations': cfg.ls_iterations})
        if args.mjx_cost:
          for w in args.mjx_worlds:
            costs[-1][f'mjx_ms_per_control_step_{w}_worlds'] = mjx_step_ms(cfg, roll, w)
        print(costs[-1], flush=True)
  return rows, costs


TILT_BINS_DEG = (0, 1, 3, 6, 12, 20, 30)  # contacts: the T's tilt ranges (degrees)


def _contact_set(pos, dist, geoms, pairs) -> list:
  """[(x, y, z, dist)] sorted: the contacts (positions [n, 3] m, distances [n], geom pairs
  [n, 2]) between the geom pairs in `pairs` (a set of frozensets)."""
  return sorted(tuple(float(v) for v in p) + (float(d),)
                for p, d, g in zip(pos, dist, geoms) if frozenset(int(x) for x in g) in pairs)


def _same_contacts(a: list, b: list, tol_m: float = 5e-4) -> bool:
  return len(a) == len(b) and all(np.allclose(x, y, atol=tol_m) for x, y in zip(a, b))


def convex_boxes(model: mujoco.MjModel) -> mujoco.MjModel:
  """A copy of a PushT model whose box pairs MuJoCo Warp collides by its general convex
  collider (`nativeccd` on, Warp's default), not by MuJoCo C's box-box routine."""
  out = copy.copy(model)
  out.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)
  return out


def warp_cpu_models(models: Dict[str, mujoco.MjModel]) -> Dict[str, object]:
  """{name: MuJoCo Warp model on the CPU} of {name: MjModel}."""
  from mujoco.mjx.third_party import mujoco_warp as mjw  # pylint: disable=g-import-not-at-top
  import warp as wp  # pylint: disable=g-import-not-at-top
  wp.config.quiet = True
  with wp.ScopedDevice('cpu'):
    return {name: mjw.put_model(m) for name, m in models.items()}


def t_block_contacts(model: mujoco.MjModel, warp_models: Dict[str, object],
                     qpos: np.ndarray) -> Tuple[list, Dict[str, list]]:
  """(MuJoCo C's, {name: each Warp model's}) contacts between the T and the blocks of a PushT
  model at qpos [nq], as `_contact_set` lists; warp_models from `warp_cpu_models`."""
  t_geoms = [model.geom(n).id for n in ('t_bar', 't_stem')]
  return pair_contacts(model, warp_models, qpos,
                       {frozenset((t, b)) for t in t_geoms for b in range(model.ngeom)
                        if model.geom(b).name.startswith('obstacle')})


def pair_contacts(model: mujoco.MjModel, warp_models: Dict[str, object], qpos: np.ndarray,
                  pairs: set) -> Tuple[list, Dict[str, list]]:
  """(MuJoCo C's, {name: each Warp model's}) contacts between the geom pairs (a set of
  frozensets of geom ids) of a model at qpos [nq], as `_contact_set` lists."""
  from mujoco.mjx.third_party import mujoco_warp as mjw  # pylint: disable=g-import-not-at-top
  import warp as wp  # pylint: disable=g-import-not-at-top
  data = mujoco.MjData(model)
  data.qpos[:] = qpos
  mujoco.mj_forward(model, data)
  c = _contact_set(data.contact.pos[:data.ncon], data.contact.dist[:data.ncon],
                   data.contact.geom[:data.ncon], pairs)
  found = {}
  with wp.ScopedDevice('cpu'):
    for name, warp_model in warp_models.items():
      warp_data = mjw.put_data(model, data, nconmax=64, njmax=320)
      mjw.kinematics(warp_model, warp_data)
      mjw.collision(warp_model, warp_data)
      n = int(warp_data.nacon.numpy()[0])
      found[name] = _contact_set(warp_data.contact.pos.numpy()[:n],
                                 warp_data.contact.dist.numpy()[:n],
                                 warp_data.contact.geom.numpy()[:n], pairs)
  return c, found


def _tilted_quat(rng, lo_deg: float, hi_deg: float) -> np.ndarray:
  """[4] a free body's orientation quaternion: any yaw, tilted lo_deg to hi_deg (drawn
  uniformly) about a horizontal axis of any azimuth."""
  tilt, azimuth, yaw = (np.radians(rng.uniform(lo_deg, hi_deg)), rng.uniform(0, 2 * np.pi),
                        rng.uniform(0, 2 * np.pi))
  q_tilt = np.array([np.cos(tilt / 2), np.sin(tilt / 2) * np.cos(azimuth),
                     np.sin(tilt / 2) * np.sin(azimuth), 0.0])
  q_yaw = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
  out = np.zeros(4)
  mujoco.mju_mulQuat(out, q_tilt, q_yaw)
  return out


def run_contacts(args, layouts, policies, starts_of):
  """The T's contacts with the blocks in MuJoCo C against MuJoCo Warp's (CPU kernels), the T
  drawn near a block (origin within 0.12 m of its side, lifted 0 to 2 cm, any yaw) tilted
  within each of TILT_BINS_DEG; kept where either engine finds a T-block contact and MuJoCo C's
  are at most 5 mm deep. Contacts agree where their number matches and each lies within 0.5 mm
  (position and distance) of the other engine's."""
  del policies, starts_of
  rng = np.random.default_rng(args.seed)
  rows = []
  for layout in layouts:
    m = mujoco.MjModel.from_xml_string(pusht.model_xml(
        pusht.PushTConfig(variant='obs', layout=layout)))
    blocks = [i for i in range(m.ngeom) if m.geom(i).name.startswith('obstacle')]
    warp_models = warp_cpu_models({'box-box': m, 'convex': convex_boxes(m)})
    for lo, hi in zip(TILT_BINS_DEG[:-1], TILT_BINS_DEG[1:]):
      kept, differ, counts = 0, {k: 0 for k in warp_models}, {'mujoco_c': 0}
      counts.update({k: 0 for k in warp_models})
      for _ in range(50 * args.samples):
        if kept == args.samples:
          break
        qpos = np.zeros(m.nq)
        qpos[:7] = pusht.HOME_QPOS
        b = rng.choice(blocks)
        reach = max(m.geom_size[b][:2]) + 0.12  # m: the block's half side and the T's
        qpos[7:9] = m.geom_pos[b][:2] + rng.uniform(-reach, reach, 2)
        qpos[9] = pusht.T_HALF_HEIGHT + rng.uniform(0.0, 0.02)
        qpos[10:14] = _tilted_quat(rng, lo, hi)
        c, found = t_block_contacts(m, warp_models, qpos)
        if (not c and not any(found.values())) or min(
            [x[3] for x in c] or [0.0]) < -0.005:  # none, or deeper than the blocks let
          continue
        kept += 1
        counts['mujoco_c'] += len(c)
        for name, w in found.items():
          counts[name] += len(w)
          differ[name] += not _same_contacts(c, w)
      row = {'layout': layout, 'tilt_deg': f'{lo}-{hi}', 'samples': kept,
             'mean_contacts_mujoco_c': round(counts['mujoco_c'] / max(kept, 1), 2)}
      for name in warp_models:
        row[f'differ_{name}'] = differ[name]
        row[f'mean_contacts_{name}'] = round(counts[name] / max(kept, 1), 2)
      print(row, flush=True)
      rows.append(row)
  return rows, []


STICK_TILT_BINS_DEG = ((0.0, 0.0), (0.0, 0.5), (0.5, 5.0))  # the T's tilt; (0, 0): flat
STICK_DEPTH_BINS_MM = (0.0, 4.0, 7.0, 9.0, 12.0)  # the stick's radius is 8 mm


def run_stick(args, layouts, policies, starts_of):
  """The stick's contacts with the T in MuJoCo C against MuJoCo Warp's (CPU kernels): the arm
  at its home pose (the stick upright), the T (any yaw, tilted within each of
  STICK_TILT_BINS_DEG) moved from 12 cm away against the stick until a drawn bar or stem
  presses it 0 to 12 mm deep; counted by the deepest contact in MuJoCo C
  (STICK_DEPTH_BINS_MM), args.samples poses per tilt range. Contacts agree as in
  `run_contacts`."""
  del layouts, policies, starts_of
  rng = np.random.default_rng(args.seed)
  m = mujoco.MjModel.from_xml_string(pusht.model_xml(pusht.PushTConfig(variant='obs')))
  warp_models = warp_cpu_models({'box-box': m})
  stick, t_geoms = m.geom('stick').id, [m.geom(n).id for n in ('t_bar', 't_stem')]
  pairs = {frozenset((stick, t)) for t in t_geoms}
  data, fromto = mujoco.MjData(m), np.zeros(6)
  data.qpos[:7] = pusht.HOME_QPOS
  mujoco.mj_forward(m, data)
  stick_xy = data.geom_xpos[stick][:2].copy()  # the upright stick at the arm's home pose
  rows = []
  for lo, hi in STICK_TILT_BINS_DEG:
    cells = {b: [0, 0, 0, 0] for b in range(len(STICK_DEPTH_BINS_MM) - 1)}
    kept = 0
    while kept < args.samples:
      qpos = np.zeros(m.nq)
      qpos[:7] = pusht.HOME_QPOS
      away = rng.uniform(0, 2 * np.pi)
      qpos[7:9] = stick_xy + 0.12 * np.array([np.cos(away), np.sin(away)])
      qpos[9] = pusht.T_HALF_HEIGHT
      qpos[10:14] = _tilted_quat(rng, lo, hi)
      data.qpos[:] = qpos
      mujoco.mj_forward(m, data)
      part = t_geoms[rng.integers(2)]
      gap = mujoco.mj_geomDistance(m, data, stick, part, 1.0, fromto)
      toward = fromto[:2] - fromto[3:5]  # from the T's nearest point to the stick's
      qpos[7:9] += toward / max(np.linalg.norm(toward), 1e-12) * (gap + rng.uniform(0, 0.012))
      c, found = pair_contacts(m, warp_models, qpos, pairs)
      depth = -1000 * min([x[3] for x in c] or [np.inf])
      b = next((i for i in cells if STICK_DEPTH_BINS_MM[i] <= depth
                < STICK_DEPTH_BINS_MM[i + 1]), None)
      if b is None:
        continue
      kept += 1
      w = found['box-box']
      cells[b][0] += 1
      cells[b][1] += not _same_contacts(c, w)
      cells[b][2] += len(c)
      cells[b][3] += len(w)
    for b, (n, differ, in_c, in_w) in cells.items():
      row = {'tilt_deg': f'{lo:g}-{hi:g}' if hi > lo else f'{lo:g} (flat)',
             'depth_mm': f'{STICK_DEPTH_BINS_MM[b]:g}-{STICK_DEPTH_BINS_MM[b + 1]:g}',
             'samples': n, 'differ': differ,
             'mean_contacts_mujoco_c': round(in_c / max(n, 1), 2),
             'mean_contacts_warp': round(in_w / max(n, 1), 2)}
      print(row, flush=True)
      rows.append(row)
  return rows, []


def main():
  args = build_parser().parse_args()
  args.horizons = [int(h) for h in args.horizons.split(',')]
  args.mjx_worlds = [int(w) for w in args.mjx_worlds.split(',')]
  layouts = args.layouts.split(',')
  out = args.out or f'experiments/results/physics/{args.part}.json'
  policies, starts_of = {}, {}
  for layout in (layouts if args.part not in ('gap', 'contacts', 'stick') else []):
    env, model = planner.load_model('pusht-obs', backend='mjx', layout=layout)
    policies[layout] = policy_of(model, env, args.seed)
    starts_of[layout] = jax.device_get(env.canonical_instances(args.instances))
  part = {'reference': run_reference, 'penetration': run_penetration,
          'agreement': run_agreement, 'gap': run_gap, 'contacts': run_contacts,
          'stick': run_stick}[args.part]
  rows, costs = part(args, layouts, policies, starts_of)
  settings = {k: v for k, v in vars(args).items()}
  tables = {'reference': REFERENCE | PLANAR_FITS, 'penetration': PENETRATION,
            'agreement': AGREEMENT, 'gap': PENETRATION, 'contacts': {},
            'stick': {}}[args.part]
  payload = {'provenance': common.provenance(), 'settings': settings,
             'physics': {k: {f: list(v) if isinstance(v, tuple) else v for f, v in d.items()}
                         for k, d in tables.items()},
             'rows': rows, 'costs': costs}
  columns = list(dict.fromkeys(k for r in rows for k in r))
  lines = common.markdown_header(
      f'PushT physics: {args.part}', payload['provenance'], f'Settings: {settings}',
      f'Physics (PushTConfig fields over the planar preset): {payload["physics"]}')
  lines.append(common.markdown_table([{k: r.get(k, '') for k in columns} for r in rows], columns))
  if costs:
    cols = sorted({k for c in costs for k in c}, key=lambda k: (k != 'physics', k))
    lines += ['', 'Step cost (MuJoCo C one thread; MJX a vmapped batch) and world facts:', '',
              common.markdown_table([{k: c.get(k, '') for k in cols} for c in costs], cols)]
  common.write_result(out, payload, lines)


if __name__ == '__main__':
  main()
