"""The files `pachs plan` writes of a result: JSON rows with each instance's plan, a still and an
animation of one instance's plan; output paths checked up front, each file written atomically."""

from __future__ import annotations

import json
import os
from typing import Callable, Dict, Optional, Sequence

import numpy as np

from pachs_jax import saved_plans
from pachs_jax.runtime import files

def check_distinct(paths: Dict[str, Optional[str]]) -> None:
  """ValueError naming both flags when two of flag -> path (None: not given) name one file."""
  seen = {}
  for flag, path in paths.items():
    if not path:
      continue
    real = os.path.realpath(path)
    if real in seen:
      raise ValueError(f'{seen[real]} and {flag} name the same file {path!r}: give each its own')
    seen[real] = flag


def check_show_instance(instance: Optional[int], planned: Sequence[int]) -> int:
  """The instance a still or an animation shows: `instance` (None: the first planned), which
  must be one of the planned ones; ValueError otherwise."""
  if instance is None:
    return int(planned[0])
  if instance not in planned:
    shown = ', '.join(map(str, planned[:8])) + (', ...' if len(planned) > 8 else '')
    raise ValueError(f'--show-instance {instance} is not among the planned instances ({shown})')
  return int(instance)


def write_atomically(path: str, write: Callable) -> str:
  """Calls write(binary file) through `files.atomic_open`, so that path holds the old file or
  the whole new one; a path that is not a regular file (a device such as /dev/stdout) is
  written in place. Errors (a full disk) raise OSError."""
  path = os.fspath(path)
  if os.path.exists(path) and not os.path.isfile(path):
    with open(path, 'wb') as f:
      write(f)
    return path
  with files.atomic_open(path, 'wb') as f:
    write(f)
  return path


def json_document(saved: dict, result, instances: Sequence[int],
                  physics: Optional[str] = None, physics_settings: Optional[dict] = None) -> dict:
  """saved (the rows and settings) with each row given its instance's plan (`saved_plans.to_json`)
  under 'plan', made with `physics` and `physics_settings` (`base.Env`'s); the rows keep their
  other keys."""
  found = saved_plans.from_result(result, physics, physics_settings)
  rows = [dict(row, plan=saved_plans.to_json(p)) for row, p in zip(saved['rows'], found)]
  return dict(saved, rows=rows)


def write_json(path: str, document: dict) -> str:
  """Writes a JSON document atomically."""
  text = json.dumps(document, indent=1).encode()
  return write_atomically(path, lambda f: f.write(text))


def _title(env, plan: saved_plans.Plan, instance: int) -> str:
  outcome = 'reached the goal' if plan.ends_at_goal else 'partial path (no goal)'
  return (f'{env.name} instance {instance}: {plan.length} steps, cost {plan.cost:.2f}\n'
          f'{outcome}')


def _instance_plan(result, instances: Sequence[int], instance: int) -> saved_plans.Plan:
  return saved_plans.from_result(result)[list(instances).index(instance)]


def write_still(path: str, env, result, instances: Sequence[int], instance: int) -> str:
  """Draws the plan of `instance` (one of `instances`, the result's rows) to an image file
  whose extension names the format (none: PNG)."""
  from pachs_jax.envs import render  # start-up path: matplotlib only where a plan is drawn
  plan = _instance_plan(result, instances, instance)
  fig = render.plan_figure(env, plan.states, _title(env, plan, instance))
  ext = os.path.splitext(path)[1].lower().lstrip('.') or 'png'
  return write_atomically(path, lambda f: fig.savefig(f, format=ext))


def write_animation(path: str, env, result, instances: Sequence[int], instance: int,
                    arm: Optional[bool] = None) -> tuple[str, Optional[str]]:
  """Writes a GIF of the plan of `instance` executing (`render.animation_frames`: the
  drawing, with the MuJoCo rendering of the arm beside it with `arm`; None: where the user
  chose an OpenGL backend with MUJOCO_GL, since creating a context without one can abort the
  process); returns (path, note: why the rendering is left out, or None)."""
  from pachs_jax.envs import render  # start-up path: matplotlib only where a plan is drawn
  plan = _instance_plan(result, instances, instance)
  if arm is None:
    arm = bool(os.environ.get('MUJOCO_GL'))
  frames, note = render.animation_frames(env, plan.states, _title(env, plan, instance), arm=arm)
  if not arm:
    note = ('the arm is drawn from its kinematics; set MUJOCO_GL=egl (or osmesa) for '
            "MuJoCo's rendering beside it")
  return write_gif(path, env, frames, plan.length + 1), note


def write_gif(path: str, env, frames: np.ndarray, num_states: int) -> str:
  """Writes frames [F, H, W, 3] of num_states states (`render.frame_steps` of them shown) as a
  GIF that plays at the env's control rate (`control_hz`), atomically; returns path."""
  from pachs_jax.envs import render  # start-up path: matplotlib only where a plan is drawn
  shown = render.frame_steps(num_states)
  stride = float(np.mean(np.diff(shown))) if len(shown) > 1 else 1.0
  return write_atomically(path, lambda f: render.save_gif(f, frames,
                                                          fps=control_hz(env) / stride))


def control_hz(env) -> float:
  """Transitions per second of simulated time (PushT: 1 / (physics_dt * substeps); a Playground
  task: 1 / its env's dt); 10 for an env without a duration (the shelf's kinematic edges). An
  animation plays at this speed."""
  config = getattr(env, 'config', None)
  if hasattr(config, 'physics_dt') and hasattr(config, 'substeps'):
    return 1.0 / (config.physics_dt * config.substeps)
  dt = getattr(getattr(env, 'playground_env', None), 'dt', None)
  if dt:
    return 1.0 / float(dt)
  return 10.0


def check_plan_outputs(task: str, paths: Dict[str, Optional[str]]) -> None:
  """Before any work: ValueError when two flags of flag -> path name one file, when --render or
  --animate is given for a task without a drawing (PushT tasks and the shelf have one), or when
  --animate names no .gif file. Whether each path can be written is `cli.check_output_path`'s."""
  check_distinct(paths)
  drawable = task.startswith('pusht') or task == 'shelf'
  for flag in ('--render', '--animate'):
    if paths.get(flag) and not drawable:
      raise ValueError(f'{flag} draws the PushT tasks and the shelf; task {task!r} has no '
                       'drawing')
  animate = paths.get('--animate')
  if animate and os.path.splitext(animate)[1].lower() != '.gif':
    raise ValueError(f'--animate {animate}: animations are written as GIF; name a .gif file')
