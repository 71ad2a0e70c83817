"""The physics engines a task can plan with, chosen in one place: MJX's JAX implementation,
MJX's Warp implementation and MuJoCo C (each env says which it uses: `Env.physics`)."""

from __future__ import annotations

from typing import Optional

import jax

from pachs_jax.envs import base, mujoco_c, pusht, warp_import, warp_physics
from pachs_jax.envs.registry import BACKENDS


def make_backend(env: base.Env, backend: str = 'auto', nthread: Optional[int] = None) -> base.Env:
  """env with the chosen physics backend.

  'mjx': MJX's JAX implementation (env as built); 'mujoco-c': `MujocoCEnv` (PushT only);
  'warp': `warp_physics.WarpPushTEnv` (PushT only; needs the 'cuda' extra); 'auto': for PushT,
  Warp when JAX runs on an accelerator and Warp is installed, MuJoCo C when JAX runs on the
  CPU, else MJX; other envs unchanged (e.g. the kinematic shelf env).
  """
  if backend not in BACKENDS:
    raise ValueError(f'backend must be one of {BACKENDS}, got {backend!r}')
  if isinstance(env, mujoco_c.MujocoCEnv):
    env = env.env
  is_pusht = isinstance(env, pusht.PushTEnv)
  if backend in ('mujoco-c', 'warp') and not is_pusht:
    raise ValueError(f'backend {backend!r} needs a PushT env, got {type(env).__name__}')
  if backend == 'auto':
    if not is_pusht:
      return env
    if jax.default_backend() == 'cpu':
      backend = 'mujoco-c'
    else:
      backend = 'warp' if warp_import.available() else 'mjx'
  if backend == 'warp':
    warp_import.require()
    return (env if isinstance(env, warp_physics.WarpPushTEnv)
            else warp_physics.WarpPushTEnv(env.config))
  if isinstance(env, warp_physics.WarpPushTEnv):
    env = pusht.PushTEnv(env.config)
  if backend == 'mujoco-c':
    return mujoco_c.MujocoCEnv(env, nthread)
  return env
