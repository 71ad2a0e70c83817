"""Inverse kinematics of a site position (MuJoCo C, damped least squares, with collision
clearance) and sets of IK-reachable targets; method: docs/tasks.md."""

from __future__ import annotations

from typing import Optional, Tuple

import mujoco
import numpy as np

_APPROACH_X = np.array([1.0, 0.0, 0.0])  # the hand pointing into the shelf (+x)


def _site_ik(model: mujoco.MjModel, data: mujoco.MjData, site: int, target: np.ndarray,
             q0: np.ndarray, approach: Optional[np.ndarray] = None, approach_weight: float = 0.3,
             clearance: Optional[float] = None, iterations: int = 150, damping: float = 0.05,
             max_step: float = 0.2, tolerance: float = 1e-3) -> Tuple[np.ndarray, float, float]:
  """(configuration [nq], position error (m), pair clearance (m)) putting `site` at target [3].

  q0 [nq]: the start (the model's joints: all hinges, all limited). approach [3] or None: a
  wanted direction of the site's z axis, a soft task dropped for the second half of the
  iterations. clearance (m) or None: pairs closer than `clearance + 0.03` get a row pushing them
  apart along their closest points' direction, and the iteration stops only once all pairs are
  at least `clearance` apart (the reported clearance is capped at `clearance + 0.03`; +inf when
  clearance is None). Gives up early when the site is still 2 cm off after a third of the
  iterations.
  """
  lower, upper = model.jnt_range[:, 0], model.jnt_range[:, 1]
  q = np.clip(np.array(q0, np.float64), lower, upper)
  jacp = np.zeros((3, model.nv))
  jacr = np.zeros((3, model.nv))
  for it in range(iterations):
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    e_pos = target - data.site_xpos[site]
    err = float(np.linalg.norm(e_pos))
    if it >= iterations // 3 and err > 0.02:
      break
    mujoco.mj_jacSite(model, data, jacp, jacr, site)
    rows, residuals = [jacp], [e_pos]
    gap = np.inf
    if clearance is not None:
      gap, avoid_rows, avoid_res = _avoidance(model, data, clearance + 0.03)
      rows += avoid_rows
      residuals += avoid_res
    if err < tolerance and gap >= (-np.inf if clearance is None else clearance):
      break
    if approach is not None and it < iterations // 2:
      z = data.site_xmat[site].reshape(3, 3)[:, 2]
      rows.append(approach_weight * jacr)
      residuals.append(approach_weight * np.cross(z, approach))  # turns z towards approach
    jac, e = np.vstack(rows), np.concatenate(residuals)
    dq = jac.T @ np.linalg.solve(jac @ jac.T + damping**2 * np.eye(jac.shape[0]), e)
    step = np.max(np.abs(dq))
    if step > max_step:
      dq *= max_step / step
    q = np.clip(q + dq, lower, upper)
  data.qpos[:] = q
  mujoco.mj_kinematics(model, data)
  err = float(np.linalg.norm(target - data.site_xpos[site]))
  gap = np.inf if clearance is None else _pair_clearance(model, data, q, clearance + 0.03)
  return q, err, gap


def _avoidance(model: mujoco.MjModel, data: mujoco.MjData, activation: float):
  """(min pair distance capped at activation, rows [1, nv] list, residuals [1] list).

  For each pair closer than `activation`: the rate of change of its distance with q (the arm
  point's Jacobian projected on the direction from the other point to the arm point; the other
  geom is the one on the world body) and the distance still missing to `activation`.
  """
  fromto = np.zeros(6)
  jacp = np.zeros((3, model.nv))
  gap, rows, residuals = activation, [], []
  for i in range(model.npair):
    g1, g2 = model.pair_geom1[i], model.pair_geom2[i]
    dist = mujoco.mj_geomDistance(model, data, g1, g2, activation, fromto)
    gap = min(gap, dist)
    if dist >= activation:
      continue
    p1, p2 = fromto[:3].copy(), fromto[3:].copy()
    arm_body = model.geom_bodyid[g1]
    p_arm, p_other = p1, p2
    if arm_body == 0:
      arm_body, p_arm, p_other = model.geom_bodyid[g2], p2, p1
    v = p_arm - p_other
    norm = np.linalg.norm(v)
    if norm < 1e-9:
      continue
    normal = v / norm * (1.0 if dist >= 0 else -1.0)
    mujoco.mj_jac(model, data, jacp, None, p_arm, arm_body)
    rows.append((normal @ jacp)[None, :])
    residuals.append(np.array([activation - dist]))
  return gap, rows, residuals


def _pair_clearance(model: mujoco.MjModel, data: mujoco.MjData, q: np.ndarray,
                    distmax: float = 1.0) -> float:
  """Smallest signed distance (m) over the model's contact pairs at configuration q [nq],
  capped at distmax."""
  data.qpos[:] = q
  mujoco.mj_kinematics(model, data)
  best = distmax
  for i in range(model.npair):
    best = min(best, mujoco.mj_geomDistance(model, data, model.pair_geom1[i],
                                            model.pair_geom2[i], distmax, None))
  return best


def _solve_reachable(model: mujoco.MjModel, data: mujoco.MjData, site: int, target: np.ndarray,
                     starts: list, clearance: float,
                     tolerance: float = 1e-3) -> Optional[np.ndarray]:
  """A configuration [nq] with the site on target and pair clearance >= `clearance`, or None.

  Tries each start [nq] in order, first without an orientation preference and then with the
  hand approaching along +x.
  """
  for q0 in starts:
    for approach in (None, _APPROACH_X):
      q, err, gap = _site_ik(model, data, site, target, q0, approach=approach,
                             clearance=clearance)
      if err < tolerance and gap >= clearance:
        return q
  return None


def reachable_targets(model: mujoco.MjModel, regions: np.ndarray, num: int, seed: int,
                      home: np.ndarray, clearance: float, restarts: int, site: str = 'tip',
                      neighbours: int = 2, max_tries: int = 50) -> Tuple[np.ndarray, np.ndarray]:
  """(targets [num, 3], configurations [num, nq]) drawn in regions [R, 2, 3] (m), fixed by seed.

  A target is drawn uniformly in a uniformly chosen region and kept when `_solve_reachable`
  finds a configuration for it from these starts: home turned towards the target (joint 1),
  home, the solutions of the `neighbours` nearest targets kept so far, and `restarts` uniform
  random configurations. Raises ValueError when `max_tries * num` draws do not suffice.
  """
  rng = np.random.default_rng(seed)
  data = mujoco.MjData(model)
  site_id = model.site(site).id
  lower, upper = model.jnt_range[:, 0], model.jnt_range[:, 1]
  home = np.asarray(home, np.float64)
  targets, configs = [], []
  for _ in range(max_tries * num):
    if len(targets) == num:
      break
    lo, hi = regions[rng.integers(len(regions))]
    target = rng.uniform(lo, hi)
    facing = home.copy()
    facing[0] = np.clip(np.arctan2(target[1], target[0]), lower[0], upper[0])
    starts = [facing, home]
    if targets:
      near = np.argsort(np.linalg.norm(np.array(targets) - target, axis=1))[:neighbours]
      starts += [configs[i] for i in near]
    starts += [rng.uniform(lower, upper) for _ in range(restarts)]
    q = _solve_reachable(model, data, site_id, target, starts, clearance)
    if q is not None:
      targets.append(target)
      configs.append(q)
  if len(targets) < num:
    raise ValueError(f'found only {len(targets)} of {num} reachable targets; '
                     'the target regions may be out of reach')
  return np.array(targets, np.float32), np.array(configs, np.float32)
