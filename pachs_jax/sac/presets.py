"""Per-task SAC hyperparameters for a single H100/H200, and smaller ones for a CPU (reasons:
docs/sac.md)."""

from __future__ import annotations

import dataclasses
from typing import Dict

from pachs_jax.sac.config import SACConfig

_PUSHT = SACConfig(
    num_envs=2048, batch_size=4096, grad_updates_per_step=8, steps_per_epoch=25,
    actor_learning_rate=3e-4, critic_learning_rate=3e-4, alpha_learning_rate=3e-4,
    discount=0.8, reward_scaling=1.0, tau=0.005, replay_capacity=1_000_000,
    min_replay_size=65_536, actor_hidden=(256, 256, 256), critic_hidden=(256, 256, 256),
    init_alpha=0.2, eval_instances=256,
    # a tipped T ends an episode: charged as if kept for ever, no more (reasons: docs/sac.md)
    absorbing_failure=True)

_PLAYGROUND_CPU = SACConfig(
    num_envs=32, batch_size=256, grad_updates_per_step=4, steps_per_epoch=50,
    actor_learning_rate=1e-3, critic_learning_rate=1e-3, alpha_learning_rate=1e-3,
    discount=0.98, replay_capacity=200_000, min_replay_size=4096, actor_hidden=(64, 64),
    critic_hidden=(64, 64), init_alpha=0.1, eval_instances=32)

PRESETS: Dict[str, SACConfig] = {
    # Small enough to learn in seconds on a CPU (used by the tests).
    'point-mass': SACConfig(
        num_envs=16, batch_size=128, grad_updates_per_step=8, steps_per_epoch=25,
        actor_learning_rate=1e-3, critic_learning_rate=1e-3, alpha_learning_rate=1e-3,
        discount=0.9, replay_capacity=20_000, min_replay_size=256, actor_hidden=(32, 32),
        critic_hidden=(32, 32), init_alpha=0.1, eval_instances=64),
    'pusht-fixed': _PUSHT,
    # The Obs task is normally solved with the Fixed model; this trains one of its own.
    'pusht-obs': _PUSHT,
    'pusht-rand': dataclasses.replace(_PUSHT, actor_hidden=(512, 512, 512),
                                      critic_hidden=(512, 512, 512)),
    'shelf': SACConfig(
        num_envs=1024, batch_size=2048, grad_updates_per_step=4, steps_per_epoch=50,
        discount=0.97, replay_capacity=1_000_000, min_replay_size=32_768,
        actor_hidden=(256, 256, 256), critic_hidden=(256, 256, 256), init_alpha=0.2,
        eval_instances=256),
    # MuJoCo Playground tasks (envs/playground.py), small enough to train on a CPU in minutes.
    'playground:PointMass': _PLAYGROUND_CPU,
    'playground:ReacherEasy': _PLAYGROUND_CPU,
    'playground:ReacherHard': _PLAYGROUND_CPU,
}


# On a CPU (a few cores; PushT physics in MuJoCo C): epochs of seconds and evaluations of a few
# rollouts, so that a run of a few minutes saves checkpoints and evaluates.
_CPU_SIZES = dict(num_envs=64, batch_size=256, grad_updates_per_step=1, steps_per_epoch=10,
                  replay_capacity=200_000, min_replay_size=1024, eval_instances=16)
CPU_PRESETS: Dict[str, SACConfig] = {
    task: dataclasses.replace(PRESETS[task], **_CPU_SIZES)
    for task in ('pusht-fixed', 'pusht-obs', 'pusht-rand', 'shelf')}


def preset(task: str, platform: str = 'gpu') -> SACConfig:
  """The preset SACConfig of a task name for `platform` ('cpu': CPU_PRESETS where the task has
  one; any other platform: PRESETS)."""
  if task not in PRESETS:
    raise ValueError(f'no SAC preset for task {task!r}; known: {sorted(PRESETS)}')
  if platform == 'cpu':
    return CPU_PRESETS.get(task, PRESETS[task])
  return PRESETS[task]
