"""Soft actor-critic that keeps its critic: Brax-style jitted training and checkpoints of the
actor and twin critic that the search loads (`load_actor_critic`)."""

from pachs_jax.sac.actor_critic import ModelConfig, SacActorCritic
from pachs_jax.sac.checkpoint import load_actor_critic, save_actor_critic
from pachs_jax.sac.config import SACConfig
from pachs_jax.sac.presets import PRESETS, preset

__all__ = ['SacActorCritic', 'ModelConfig', 'SACConfig', 'PRESETS', 'preset', 'load_actor_critic',
           'save_actor_critic']
