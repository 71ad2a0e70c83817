"""`pachs demo`: a scripted Jacobian pusher rolled out through a PushT task and drawn, with no
learning involved."""

from __future__ import annotations

import os
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from pachs_jax.envs import coverage, pusht, render


def scripted_push(env: pusht.PushTEnv, node, num_steps: int = 60):
  """Rolls a scripted pusher out of a single node for num_steps (T) control steps.

  The tip goes behind the T (lifted 6 cm when it must pass it), then pushes through the T's
  centre towards the goal. Returns (qpos [T+1, 10], tip xy [T+1, 2] (m), coverage [T+1]).
  """
  transition = jax.jit(env.transition)
  tip_fn = jax.jit(env.tip_position)
  data = mujoco.MjData(env.mj_model)
  qposes, tips = [np.asarray(node.qpos)], [np.asarray(tip_fn(node))[:2]]
  goal = np.asarray(node.goal)
  for _ in range(num_steps):
    q = np.asarray(node.qpos)
    t_xy, tip = q[7:9], tips[-1]
    direction = goal[:2] - t_xy
    dist = np.linalg.norm(direction)
    direction = direction / max(dist, 1e-6)
    behind = t_xy - 0.13 * direction  # a point behind the T, on the line to the goal
    lateral = np.linalg.norm((tip - t_xy) - np.dot(tip - t_xy, direction) * direction)
    ahead = np.dot(tip - t_xy, direction) > -0.1
    if lateral > 0.03 or ahead:  # go around: lift to 6 cm and move behind the T
      target = np.array([behind[0], behind[1], 0.06 if ahead else 0.015])
    else:  # push through the T's centre towards the goal
      target = np.array([*(t_xy + 0.05 * direction), 0.015])
    action = pusht.jacobian_action(env.mj_model, data, target, qpos=q)
    node = transition(node, jnp.asarray(action, jnp.float32)).next_node
    qposes.append(np.asarray(node.qpos))
    tips.append(np.asarray(tip_fn(node))[:2])
  qposes = np.array(qposes)
  cov = np.asarray(coverage.coverage(qposes[:, 7:10], goal[None]))
  return qposes, np.array(tips), cov


def run_demo(task: str, instance: int, out: str, num_steps: int, gif: str | None) -> dict:
  """Runs `scripted_push` on a canonical instance of a PushT task, draws it to the PNG `out`
  (and, with `gif`, renders a MuJoCo GIF); returns a JSON-ready summary."""
  from pachs_jax import envs
  if isinstance(num_steps, bool) or not isinstance(num_steps, int) or num_steps < 1:
    raise ValueError(f'num_steps must be a positive int, got {num_steps!r}')
  env = envs.make(task)
  if not isinstance(env, pusht.PushTEnv):
    raise ValueError(f'the scripted demo drives PushT tasks; got {task!r}')
  node = jax.tree.map(lambda x: x[instance], env.canonical_instances(instance + 1))
  start = time.perf_counter()
  qposes, tips, cov = scripted_push(env, node, num_steps)
  elapsed = time.perf_counter() - start
  render.save_pusht_figure(out, qposes[:, 7:10], np.asarray(node.goal), pusher_xy=tips,
                           obstacles=env.obstacles if len(env.obstacles) else None, every=5,
                           title=f'{task} instance {instance}: scripted pusher, '
                                 f'final coverage {cov[-1]:.2f}')
  summary = {'task': task, 'instance': instance, 'steps': num_steps, 'final_coverage':
             float(cov[-1]), 'best_coverage': float(cov.max()), 'seconds': elapsed, 'figure': out}
  if gif:
    try:
      frames = render.render_mujoco_frames(env.mj_model, qposes, 480, 360, camera='overview')
      summary['gif'] = render.save_gif(gif, frames, fps=20)
    except RuntimeError as err:
      summary['gif_error'] = str(err)
  return summary


if __name__ == '__main__':
  os.environ.setdefault('MUJOCO_GL', 'egl')
  print(run_demo('pusht-obs', 0, 'demo.png', 60, None))
