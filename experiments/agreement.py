"""Planner-world agreement of PushT physics: pushes run in a MuJoCo C float64 world are replayed
from the world's states in a planner's physics (MJX float32, MuJoCo Warp, MuJoCo C with float32
states); the T's pose error after `HORIZON` control steps is checked against tolerances.

  python experiments/agreement.py --layout wall --physics-dt 0.025 --substeps 2 \
      --world-physics-dt 0.0125 --world-substeps 4   # exit status 1: does not agree"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import Callable, Optional

import numpy as np

HORIZON = 10  # control steps: the closed loop replans every 10
POSITION_TOLERANCE_MM = 5.0  # T position error at the 90th percentile
ANGLE_TOLERANCE_DEG = 2.0  # T angle error at the 90th percentile
PLANNERS = ('mjx', 'mujoco-c', 'warp')
# PushTConfig fields with a flag each besides --t-body and --table-friction, and their types
# (an unset flag: PushTConfig's default)
PHYSICS_FLAGS = {'physics_dt': float, 'substeps': int, 'solver_iterations': int,
                 'ls_iterations': int, 'solver': str}
T_BODIES = ('planar', 'free')  # pusht.T_BODIES, spelled out: pusht loads MuJoCo


def build_parser() -> argparse.ArgumentParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--variant', default='obs', choices=['fixed', 'rand', 'obs'])
  parser.add_argument('--layout', default=None, help="the 'obs' variant's layout")
  parser.add_argument('--planner', default='mjx', choices=PLANNERS)
  parser.add_argument('--instances', type=int, default=4)
  parser.add_argument('--steps', type=int, default=20)
  parser.add_argument('--seed', type=int, default=0)
  for name, kind in PHYSICS_FLAGS.items():
    parser.add_argument('--' + name.replace('_', '-'), type=kind, default=None)
  parser.add_argument('--t-body', default=None, choices=T_BODIES)
  parser.add_argument('--table-friction', type=float, default=None)
  parser.add_argument('--world-physics-dt', type=float, default=None,
                      help="the world's time step (default: the planner's)")
  parser.add_argument('--world-substeps', type=int, default=None)
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402

from pachs_jax.envs import base, pusht  # noqa: E402
# pylint: enable=wrong-import-position

# A policy: (planar nodes NodeState [N] with numpy leaves, control step t) -> actions [N, 7].
Policy = Callable[[base.NodeState, int], np.ndarray]


@dataclasses.dataclass(frozen=True)
class Rollouts:
  """Trajectories of N instances in a MuJoCo C world, T control steps.

  qpos [N, T + 1, nq], qvel, warmstart [N, T + 1, nv] float64 (the world model's own state);
  actions [N, T, 7] float32 in [-1, 1]; goal [N, 3];
  t_block, stick_block: [N] m, the deepest penetration of a T-block / stick-block contact over
  all physics steps (0 without contact).
  """

  qpos: np.ndarray
  qvel: np.ndarray
  warmstart: np.ndarray
  actions: np.ndarray
  goal: np.ndarray
  t_block: np.ndarray
  stick_block: np.ndarray

  def planar(self) -> tuple:
    """(qpos [N, T + 1, 10], qvel [N, T + 1, 10]) planar states of the trajectories."""
    if self.qpos.shape[-1] == 10:
      return self.qpos, self.qvel
    return pusht.planar_t_state(self.qpos, self.qvel)


class CWorld:
  """A MuJoCo C (float64) PushT world of a config (planar or free T), stepping instances one
  control step at a time with `PushTEnv`'s control rule."""

  def __init__(self, config: pusht.PushTConfig):
    self.config = config
    self.model = mujoco.MjModel.from_xml_string(pusht.model_xml(config))
    self.data = mujoco.MjData(self.model)
    self.free = config.t_body == 'free'
    names = lambda prefix: {self.model.geom(i).id for i in range(self.model.ngeom)
                            if self.model.geom(i).name.startswith(prefix)}
    self._blocks = names('obstacle')
    self._t_geoms = names('t_')
    self._stick = {self.model.geom('stick').id}
    self._lower = np.asarray(pusht.panda.JOINT_LOWER, np.float64)
    self._upper = np.asarray(pusht.panda.JOINT_UPPER, np.float64)

  def state_of(self, qpos, qvel) -> tuple:
    """This model's (qpos, qvel) [..., nq / nv] of planar or own-model states."""
    qpos, qvel = np.asarray(qpos, np.float64), np.asarray(qvel, np.float64)
    if self.free and qpos.shape[-1] == 10:
      return pusht.free_t_state(qpos, qvel)
    if not self.free and qpos.shape[-1] == 14:
      return pusht.planar_t_state(qpos, qvel)
    return qpos, qvel

  def _penetration(self) -> tuple:
    """(T-block, stick-block) deepest penetration (m, >= 0) among the current contacts."""
    t_block = stick_block = 0.0
    for c in self.data.contact[:self.data.ncon]:
      pair = {int(c.geom1), int(c.geom2)}
      if not pair & self._blocks:
        continue
      if pair & self._t_geoms:
        t_block = max(t_block, -float(c.dist))
      elif pair & self._stick:
        stick_block = max(stick_block, -float(c.dist))
    return t_block, stick_block

  def _control_step(self, action: np.ndarray) -> tuple:
    d = self.data
    d.ctrl[:] = np.clip(d.qpos[:7] + pusht.ARM_ACTION_SCALE * action, self._lower, self._upper)
    deepest = np.zeros(2)
    for _ in range(self.config.substeps):
      mujoco.mj_step(self.model, d)
      deepest = np.maximum(deepest, self._penetration())
    return deepest

  def _reset(self, qpos, qvel, warm) -> None:
    d = self.data
    mujoco.mj_resetData(self.model, d)
    d.qpos[:], d.qvel[:] = qpos, qvel
    d.ctrl[:] = qpos[:7]
    d.qacc_warmstart[:] = 0.0 if warm is None else warm
    mujoco.mj_forward(self.model, d)

  def run(self, qpos, qvel, goal, policy: Policy, steps: int) -> Rollouts:
    """Rollouts of `steps` control steps from states qpos [N, nq or 10], qvel [N, ...] with goal
    [N, 3]; the policy sees planar nodes (float32) of the world's states."""
    qpos, qvel = self.state_of(qpos, qvel)
    n, m = len(qpos), self.model
    out_q = np.zeros((n, steps + 1, m.nq))
    out_v = np.zeros((n, steps + 1, m.nv))
    out_w = np.zeros((n, steps + 1, m.nv))
    actions = np.zeros((n, steps, pusht.panda.NUM_JOINTS), np.float32)
    deepest = np.zeros((n, 2))
    out_q[:, 0], out_v[:, 0] = qpos, qvel
    for t in range(steps):
      pq, pv = pusht.planar_t_state(out_q[:, t], out_v[:, t]) if self.free else (
          out_q[:, t], out_v[:, t])
      nodes = _planar_nodes(pq, pv, goal, t)
      act = np.clip(np.nan_to_num(np.asarray(policy(nodes, t), np.float32)), -1, 1)
      actions[:, t] = act
      for i in range(n):
        self._reset(out_q[i, t], out_v[i, t], out_w[i, t])
        deepest[i] = np.maximum(deepest[i], self._control_step(act[i].astype(np.float64)))
        out_q[i, t + 1], out_v[i, t + 1] = self.data.qpos, self.data.qvel
        out_w[i, t + 1] = self.data.qacc_warmstart
    return Rollouts(out_q, out_v, out_w, actions, np.asarray(goal, np.float32),
                    deepest[:, 0], deepest[:, 1])

  def replay(self, qpos, qvel, warm, actions, float32_states: bool = False) -> np.ndarray:
    """[N, H + 1, 10] planar qpos along actions [N, H, 7] from states qpos, qvel [N, ...]
    (planar or this model's) with warm starts warm [N, nv] (None: zero). float32_states: round
    the state to float32 between control steps, as the MuJoCo C edge backend's nodes are."""
    qpos, qvel = self.state_of(qpos, qvel)
    if warm is not None and np.shape(warm)[-1] != self.model.nv:
      warm = None
    n, h = actions.shape[:2]
    out = np.zeros((n, h + 1, self.model.nq))
    out[:, 0] = qpos
    for i in range(n):
      self._reset(qpos[i], qvel[i], None if warm is None else warm[i])
      for t in range(h):
        self._control_step(np.asarray(actions[i, t], np.float64))
        out[i, t + 1] = self.data.qpos
        if float32_states:
          d = self.data
          for field in (d.qpos, d.qvel, d.qacc_warmstart):
            field[:] = field.astype(np.float32)
    if self.free:
      return pusht.planar_t_state(out, np.zeros(out.shape[:-1] + (self.model.nv,)))[0]
    return out


def _planar_nodes(qpos, qvel, goal, t) -> base.NodeState:
  """NodeState [N] (numpy float32 leaves) of planar states."""
  qpos = np.asarray(qpos, np.float32)
  return base.NodeState(qpos=qpos, qvel=np.asarray(qvel, np.float32), ctrl=qpos[:, :7].copy(),
                        qacc_warmstart=np.zeros_like(qvel, np.float32),
                        goal=np.asarray(goal, np.float32),
                        t=np.full((len(qpos),), t, np.int32))


def pushing_policy(seed: int = 0, noise: float = 0.2) -> Policy:
  """A scripted pusher (no model needed): per instance a random push direction u; the tip goes
  behind the T (12 cm against u) 9 cm above the table for 7 steps, down to 2 cm for 3, then
  pushes towards 15 cm past the T's centre along u (`pusht.jacobian_action`, 5 cm a step),
  with Gaussian action noise."""
  config = pusht.physics_preset('planar')  # the arm's kinematics at the planar nodes it sees
  model = mujoco.MjModel.from_xml_string(pusht.model_xml(config))
  data = mujoco.MjData(model)
  rng = np.random.default_rng(seed)
  directions = {}

  def policy(nodes: base.NodeState, t: int) -> np.ndarray:
    n = len(nodes.qpos)
    if n not in directions:
      angle = rng.uniform(0, 2 * np.pi, n)
      directions[n] = np.stack([np.cos(angle), np.sin(angle)], -1)
    u = directions[n]
    out = np.zeros((n, pusht.panda.NUM_JOINTS))
    for i in range(n):
      centre = np.asarray(nodes.qpos[i, 7:9], np.float64)
      target = centre + (-0.12 if t < 10 else 0.15) * u[i]
      height = 0.09 if t < 7 else 0.02
      out[i] = pusht.jacobian_action(model, data, np.array([*target, height]),
                                     np.asarray(nodes.qpos[i], np.float64), max_step=0.05)
    return np.clip(out + noise * rng.standard_normal(out.shape), -1, 1).astype(np.float32)

  return policy


def pose_errors(a, b) -> tuple:
  """(position error mm, angle error degrees) of the T between planar qpos a and b [..., 10]."""
  d = np.asarray(a, np.float64)[..., 7:10] - np.asarray(b, np.float64)[..., 7:10]
  angle = np.abs((d[..., 2] + np.pi) % (2 * np.pi) - np.pi)
  return 1000 * np.linalg.norm(d[..., :2], axis=-1), np.degrees(angle)


def replay_begins(steps: int, length: int, every: int = HORIZON) -> list:
  """World steps (multiples of `every`) from which `length` recorded actions follow."""
  return list(range(0, steps - length + 1, every))


def planner_env(config: pusht.PushTConfig, planner: str) -> base.Env:
  """The env whose `evaluate` is the named planner physics of config ('mjx', 'mujoco-c',
  'warp')."""
  from pachs_jax.envs import backends  # pylint: disable=import-outside-toplevel
  if planner not in PLANNERS:
    raise ValueError(f'planner must be one of {PLANNERS}, got {planner!r}')
  return backends.make_backend(pusht.PushTEnv(config), planner, nthread=1)


def c_replay(config: pusht.PushTConfig, rollouts: Rollouts, begins, length: int,
             float32_states: bool = True) -> np.ndarray:
  """As `replay_planner`, in a MuJoCo C model of the config (any t_body) from the world's own
  states; float32_states as in `CWorld.replay` (True: the MuJoCo C edge backend's nodes)."""
  return CWorld(config).replay(
      np.concatenate([rollouts.qpos[:, b] for b in begins]),
      np.concatenate([rollouts.qvel[:, b] for b in begins]),
      np.concatenate([rollouts.warmstart[:, b] for b in begins]),
      np.concatenate([rollouts.actions[:, b:b + length] for b in begins]), float32_states)


def replay_planner(env: base.Env, rollouts: Rollouts, begins, length: int) -> np.ndarray:
  """[len(begins) * N, length + 1, 10] planar qpos of the planner env's replays of the world's
  actions from its (planar, float32) states at the begins; rows begin-major."""
  from pachs_jax.search.baselines import common as replay_lib  # pylint: disable=import-outside-toplevel
  qpos, qvel = rollouts.planar()
  n = len(qpos)
  start = base.NodeState(
      qpos=np.concatenate([qpos[:, b] for b in begins]).astype(np.float32),
      qvel=np.concatenate([qvel[:, b] for b in begins]).astype(np.float32),
      ctrl=np.concatenate([qpos[:, b, :7] for b in begins]).astype(np.float32),
      qacc_warmstart=np.concatenate(
          [rollouts.warmstart[:, b] if rollouts.warmstart.shape[-1] == 10
           else np.zeros((n, 10)) for b in begins]).astype(np.float32),
      goal=np.concatenate([rollouts.goal] * len(begins)),
      t=np.zeros((n * len(begins),), np.int32))
  actions = np.concatenate([rollouts.actions[:, b:b + length] for b in begins])
  run = jax.jit(lambda s, a: replay_lib.replay(env, s, a, jnp.full((len(a),), length,
                                                                   jnp.int32))[0].qpos)
  return np.asarray(run(jax.tree.map(jnp.asarray, start), jnp.asarray(actions)), np.float64)


def model_replay(config: pusht.PushTConfig, rollouts: Rollouts, begins, length: int,
                 impl: str = 'jax') -> np.ndarray:
  """As `replay_planner`, for any t_body, on the config's bare MJX model (impl 'jax' or 'warp';
  float32): the world's own states (free or planar) at the begins, the env's control rule."""
  mjx = pusht.mjx
  model = mujoco.MjModel.from_xml_string(pusht.model_xml(config))
  mx = mjx.put_model(model, impl=impl)
  qpos = np.concatenate([rollouts.qpos[:, b] for b in begins])
  qvel = np.concatenate([rollouts.qvel[:, b] for b in begins])
  warm = np.concatenate([rollouts.warmstart[:, b] for b in begins])
  if qpos.shape[-1] != model.nq:  # the world's other T model: its state converted, no warm start
    qpos, qvel = CWorld(config).state_of(qpos, qvel)
    warm = np.zeros_like(qvel)
  qpos, qvel, warm = (x.astype(np.float32) for x in (qpos, qvel, warm))
  actions = np.concatenate([rollouts.actions[:, b:b + length] for b in begins])
  if impl == 'warp':
    template = mjx.make_data(model, impl=impl, naconmax=48 * len(qpos), njmax=256)
  else:
    template = mjx.make_data(mx)
  path = _mjx_replay(mx, template, jnp.asarray(config.substeps), qpos, qvel, warm,
                     jnp.asarray(actions))
  path = np.asarray(path, np.float64)
  if config.t_body == 'free':
    return pusht.planar_t_state(path, np.zeros(path.shape[:-1] + (model.nv,)))[0]
  return path


@jax.jit
def _mjx_replay(mx, template, substeps, qpos, qvel, warm, actions):
  """[B, H + 1, nq] qpos of MJX replays of actions [B, H, 7] (model and step count traced, so
  configs that differ only in time step and substeps share one compiled program)."""
  mjx = pusht.mjx
  lower = jnp.asarray(pusht.panda.JOINT_LOWER, jnp.float32)
  upper = jnp.asarray(pusht.panda.JOINT_UPPER, jnp.float32)
  data = jax.vmap(lambda q, v, w: template.replace(qpos=q, qvel=v, qacc_warmstart=w,
                                                   ctrl=q[:7]))(qpos, qvel, warm)

  def control(d, act):
    d = d.replace(ctrl=jnp.clip(d.qpos[:, :7] + pusht.ARM_ACTION_SCALE * act, lower, upper))
    d = jax.lax.fori_loop(0, substeps, lambda _, x: jax.vmap(lambda y: mjx.step(mx, y))(x), d)
    return d, d.qpos

  _, path = jax.lax.scan(control, data, jnp.swapaxes(actions, 0, 1))
  return jnp.concatenate([qpos[None], path]).swapaxes(0, 1)


def truth_at(rollouts: Rollouts, begins, length: int) -> np.ndarray:
  """[len(begins) * N, length + 1, 10] planar qpos of the world along the same windows."""
  qpos, _ = rollouts.planar()
  return np.concatenate([qpos[:, b:b + length + 1] for b in begins])


def percentiles(pos, ang, prefix: str = '') -> dict:
  """p50 / p90 / p99 of position (mm) and angle (degrees) errors, as a flat dict."""
  out = {}
  for q in (50, 90, 99):
    out[f'{prefix}position_mm_p{q}'] = float(np.percentile(pos, q))
  for q in (50, 90, 99):
    out[f'{prefix}angle_deg_p{q}'] = float(np.percentile(ang, q))
  return out


@dataclasses.dataclass(frozen=True)
class AgreementReport:
  """A config's planner-world agreement: the planner's T pose errors against the MuJoCo C
  float64 world after `horizon` control steps over `replays` windows of contact-rich pushes.

  position_mm_p90, angle_deg_p90: the 90th percentiles (mm, degrees); position_tolerance_mm,
  angle_tolerance_deg: what they must not exceed; passed: both within.
  """

  planner: str
  horizon: int
  replays: int
  position_mm_p90: float
  angle_deg_p90: float
  position_tolerance_mm: float
  angle_tolerance_deg: float
  config: pusht.PushTConfig

  @property
  def passed(self) -> bool:
    return (self.position_mm_p90 <= self.position_tolerance_mm
            and self.angle_deg_p90 <= self.angle_tolerance_deg)

  def message(self) -> str:
    """One line: the verdict, the numbers and the physics settings."""
    c = self.config
    verdict = 'agrees with' if self.passed else 'DOES NOT agree with'
    return (f'{self.planner} physics {verdict} the MuJoCo C world after {self.horizon} control '
            f'steps: T position error p90 {self.position_mm_p90:.2f} mm (tolerance '
            f'{self.position_tolerance_mm:g}), angle p90 {self.angle_deg_p90:.2f} deg (tolerance '
            f'{self.angle_tolerance_deg:g}) over {self.replays} replays; physics_dt '
            f'{c.physics_dt:g} s x {c.substeps} substeps, {c.solver} {c.solver_iterations} '
            f'iterations, {c.ls_iterations} line-search')


def check_agreement(config: pusht.PushTConfig, planner: str = 'mjx', instances: int = 4,
                    steps: int = 20, horizon: int = HORIZON, seed: int = 0,
                    policy: Optional[Policy] = None,
                    world_config: Optional[pusht.PushTConfig] = None,
                    position_tolerance_mm: float = POSITION_TOLERANCE_MM,
                    angle_tolerance_deg: float = ANGLE_TOLERANCE_DEG) -> AgreementReport:
  """The planner's agreement with a MuJoCo C float64 world of world_config (None: the same
  config; e.g. the task's physics, to check a user's planner settings against it).

  The world runs `policy` (None: `pushing_policy(seed)`) from the config's first `instances`
  canonical starts for `steps` control steps; the planner replays each `horizon`-step window
  that starts at a multiple of `horizon` from the world's state there. A planar config's planner
  is its env's `evaluate` (`planner_env`); a free T's, the config's bare model.
  """
  if instances < 1 or steps < horizon or horizon < 1:
    raise ValueError(f'need instances >= 1 and steps >= horizon >= 1, got instances '
                     f'{instances}, steps {steps}, horizon {horizon}')
  if planner not in PLANNERS:
    raise ValueError(f'planner must be one of {PLANNERS}, got {planner!r}')
  world_config = config if world_config is None else world_config
  pusht.check_physics(world_config)
  planar = dataclasses.replace(world_config, t_body='planar')
  starts = jax.device_get(pusht.PushTEnv(planar).canonical_instances(instances))
  world = CWorld(world_config)
  rollouts = world.run(starts.qpos, starts.qvel, starts.goal,
                       policy or pushing_policy(seed), steps)
  begins = replay_begins(steps, horizon)
  if config.t_body == 'free':  # the config's bare model (the env's physics, no env needed)
    replayed = (c_replay(config, rollouts, begins, horizon) if planner == 'mujoco-c' else
                model_replay(config, rollouts, begins, horizon,
                             'warp' if planner == 'warp' else 'jax'))
  else:
    replayed = replay_planner(planner_env(config, planner), rollouts, begins, horizon)
  pos, ang = pose_errors(replayed[:, -1], truth_at(rollouts, begins, horizon)[:, -1])
  return AgreementReport(planner, horizon, int(pos.size), float(np.percentile(pos, 90)),
                         float(np.percentile(ang, 90)), position_tolerance_mm,
                         angle_tolerance_deg, config)


def main(argv=None) -> int:
  assert T_BODIES == pusht.T_BODIES, pusht.T_BODIES
  parser = build_parser()
  args = parser.parse_args(argv)
  physics = {name: getattr(args, name) for name in [*PHYSICS_FLAGS, 't_body', 'table_friction']
             if getattr(args, name) is not None}
  try:
    config = pusht.PushTConfig(variant=args.variant, layout=args.layout, **physics)
    world = dataclasses.replace(
        config, physics_dt=args.world_physics_dt or config.physics_dt,
        substeps=args.world_substeps or config.substeps)
    report = check_agreement(config, args.planner, args.instances, args.steps, seed=args.seed,
                             world_config=world)
  except ValueError as e:
    parser.error(str(e))
  print(report.message())
  return 0 if report.passed else 1


if __name__ == '__main__':
  sys.exit(main())
