"""Orbax checkpoints: the exported actor-critic the search loads, and full training states
(layouts: docs/sac.md)."""

from __future__ import annotations

import json
import os
import shutil
from typing import Any, Dict, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from pachs_jax.envs import base
from pachs_jax.sac import config as config_lib
from pachs_jax.sac.actor_critic import ActorCriticParams, ModelConfig, SacActorCritic

FORMAT = 'pachs_jax.actor_critic/1'
CONFIG_FILE = 'actor_critic.json'
PARAMS_DIR = 'params'
MODEL_SUBDIR = 'model'  # where a training run directory keeps its exported actor-critic


def _uncommitted(tree: Any) -> Any:
  """The tree's arrays as uncommitted device arrays (via the host), dtypes unchanged."""
  return jax.tree.map(lambda x: jnp.asarray(np.asarray(x)), tree)


# ---------------------------------------------------------------- actor-critic export ----

def _params_tree(actor_critic: SacActorCritic) -> Dict[str, Any]:
  p = actor_critic.params
  return {'normalizer': dict(p.normalizer), 'policy': p.policy, 'q': p.q}


def save_actor_critic(path: str, actor_critic: SacActorCritic,
                      extra: Optional[Dict[str, Any]] = None) -> str:
  """Writes the actor-critic to directory `path` (replaced atomically if it exists).

  path/actor_critic.json holds {'format', 'model': ModelConfig dict} plus `extra`; path/params
  the orbax tree {'normalizer': {'mean', 'std'}, 'policy', 'q'}. Returns the absolute path.
  """
  path = os.path.abspath(path)
  tmp = f'{path}.tmp-{os.getpid()}'
  shutil.rmtree(tmp, ignore_errors=True)
  os.makedirs(tmp)
  checkpointer = ocp.StandardCheckpointer()
  checkpointer.save(os.path.join(tmp, PARAMS_DIR), _params_tree(actor_critic))
  checkpointer.wait_until_finished()
  meta = {'format': FORMAT, 'model': config_lib.config_to_dict(actor_critic.config)}
  meta.update(extra or {})
  with open(os.path.join(tmp, CONFIG_FILE), 'w') as f:
    json.dump(meta, f, indent=2)
  old = f'{path}.old-{os.getpid()}'
  if os.path.exists(path):
    os.rename(path, old)
  os.rename(tmp, path)
  shutil.rmtree(old, ignore_errors=True)
  return path


def _resolve_path(path: str) -> str:
  """The export directory at `path`, or inside a training run directory at `path`/model."""
  if not os.path.exists(path):
    raise ValueError(f'no actor-critic checkpoint: path {path!r} does not exist')
  for candidate in (path, os.path.join(path, MODEL_SUBDIR)):
    if os.path.isfile(os.path.join(candidate, CONFIG_FILE)):
      return candidate
  raise ValueError(f'{path!r} is not an actor-critic checkpoint (no {CONFIG_FILE} in it or in '
                   f'its {MODEL_SUBDIR}/ subdirectory)')


def _read_model_config(path: str) -> Tuple[ModelConfig, Dict[str, Any]]:
  """(ModelConfig, whole metadata dict) of an actor-critic checkpoint."""
  path = _resolve_path(path)
  with open(os.path.join(path, CONFIG_FILE)) as f:
    try:
      meta = json.load(f)
    except json.JSONDecodeError as e:
      raise ValueError(f'{path!r}: {CONFIG_FILE} is not valid JSON ({e})') from None
  if meta.get('format') != FORMAT:
    raise ValueError(f'{path!r}: unknown checkpoint format {meta.get("format")!r}, expected '
                     f'{FORMAT!r}')
  return config_lib.config_from_dict(ModelConfig, meta['model'], ignore_unknown=True), meta


def _expected_params(config: ModelConfig) -> Dict[str, Any]:
  nets = config.networks()
  key = jax.random.PRNGKey(0)
  vec = jax.ShapeDtypeStruct((config.observation_size,), jnp.float32)
  return {'normalizer': {'mean': vec, 'std': vec},
          'policy': jax.eval_shape(nets.policy_init, key),
          'q': jax.eval_shape(nets.q_init, key)}


def _check_params(path: str, restored: Any, expected: Any) -> None:
  got = {jax.tree_util.keystr(k): v for k, v in jax.tree_util.tree_leaves_with_path(restored)}
  want = {jax.tree_util.keystr(k): v for k, v in jax.tree_util.tree_leaves_with_path(expected)}
  if set(got) != set(want):
    diff = sorted(set(got) ^ set(want))[:4]
    raise ValueError(f'{path!r}: parameters do not match the network config in {CONFIG_FILE} '
                     f'(differing entries {diff})')
  for name, spec in want.items():
    if tuple(np.shape(got[name])) != tuple(spec.shape):
      raise ValueError(f'{path!r}: parameter {name} has shape {tuple(np.shape(got[name]))}, the '
                       f'network config in {CONFIG_FILE} needs {tuple(spec.shape)}')


def load_actor_critic(path: str, env: Optional[base.Env] = None,
                      task: Optional[str] = None) -> SacActorCritic:
  """Loads an exported actor-critic (or a run directory's latest export).

  With `env` (or `task`), checks that the checkpoint was trained on that task and, for `env`,
  that its observation and action sizes match; any mismatch raises ValueError.
  """
  path = _resolve_path(path)
  config, _ = _read_model_config(path)
  want_task = env.name if env is not None else task
  if want_task is not None and config.task != want_task:
    raise ValueError(f'{path!r} was trained on task {config.task!r}, not {want_task!r}')
  if env is not None:
    if config.observation_size != env.observation_size:
      raise ValueError(f'{path!r}: observation size {config.observation_size} != env '
                       f'{env.name!r} observation size {env.observation_size}')
    if config.action_size != env.action_size:
      raise ValueError(f'{path!r}: action size {config.action_size} != env {env.name!r} action '
                       f'size {env.action_size}')
  params_path = os.path.join(path, PARAMS_DIR)
  if not os.path.isdir(params_path):
    raise ValueError(f'{path!r}: missing {PARAMS_DIR}/ directory')
  expected = _expected_params(config)
  checkpointer = ocp.StandardCheckpointer()
  # Check names and shapes from the metadata first (a clear error instead of orbax's), then
  # restore onto this process's default device, whatever device the checkpoint was saved on.
  stored = checkpointer.metadata(params_path)
  stored = getattr(stored, 'item_metadata', stored)
  stored = getattr(stored, 'tree', stored)
  _check_params(path, jax.tree.map(lambda m: np.zeros(m.shape, np.uint8), stored), expected)
  device = jax.sharding.SingleDeviceSharding(jax.devices()[0])
  target = jax.tree.map(lambda s: jax.ShapeDtypeStruct(s.shape, s.dtype, sharding=device),
                        expected)
  restored = checkpointer.restore(params_path, target)
  restored = jax.tree.map(lambda x, s: jnp.asarray(np.asarray(x), s.dtype), restored, expected)
  params = ActorCriticParams(normalizer=restored['normalizer'], policy=restored['policy'],
                             q=restored['q'])
  return SacActorCritic(params=params, config=config)


# ------------------------------------------------------------------ training states ----

class TrainingCheckpoints:
  """Full training states of one run, numbered by epoch; keeps the last `keep`."""

  def __init__(self, directory: str, keep: int = 3):
    if keep < 1:
      raise ValueError(f'keep must be >= 1, got {keep}')
    self.directory = os.path.abspath(directory)
    self._manager = ocp.CheckpointManager(
        self.directory,
        options=ocp.CheckpointManagerOptions(max_to_keep=keep, create=True,
                                             enable_async_checkpointing=False))

  def latest_epoch(self) -> Optional[int]:
    """The newest complete epoch saved, or None."""
    return self._manager.latest_step()

  def save(self, epoch: int, state: Any, meta: Dict[str, Any]) -> None:
    """Saves the state pytree and the JSON-ready meta dict as step `epoch` (blocking)."""
    self._manager.save(int(epoch), args=ocp.args.Composite(
        state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta)), force=True)
    self._manager.wait_until_finished()

  def read_meta(self, epoch: int) -> Dict[str, Any]:
    """The meta dict saved with `epoch`."""
    return self._manager.restore(
        int(epoch), args=ocp.args.Composite(meta=ocp.args.JsonRestore())).meta

  def restore(self, epoch: int, like: Any) -> Any:
    """The state saved at `epoch`, with the structure, dtypes and shapes of `like`, as
    uncommitted arrays on the default device (as the jitted functions return them)."""
    device = jax.sharding.SingleDeviceSharding(jax.devices()[0])
    abstract = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=device),
                            like)
    state = self._manager.restore(
        int(epoch), args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract))).state
    return _uncommitted(state)

  def close(self) -> None:
    self._manager.close()
