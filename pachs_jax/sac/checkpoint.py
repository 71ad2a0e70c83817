"""Orbax checkpoints: the exported actor-critic the search loads, verified against SHA-256
digests of its parameters and of its metadata, and full training states (layouts and errors:
docs/sac.md)."""

from __future__ import annotations

import dataclasses
import errno
import gc
import hashlib
import inspect
import json
import logging
import os
import shutil
import sys
from typing import Any, Callable, Dict, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
import tensorstore as ts

from pachs_jax.runtime import files
from pachs_jax.envs import base, physics_presets
from pachs_jax.sac import config as config_lib
from pachs_jax.sac.actor_critic import ActorCriticParams, ModelConfig, SacActorCritic
from pachs_jax.sac.digest import params_hash

FORMAT = 'pachs_jax.actor_critic/1'
CONFIG_FILE = 'actor_critic.json'
PARAMS_DIR = 'params'
MODEL_SUBDIR = 'model'  # where a training run directory keeps its exported actor-critic
HASH_KEY = 'params_sha256'  # actor_critic.json entry: params_hash of the stored parameters
# actor_critic.json entry: meta_hash of every other entry (the model config, params_sha256, ...)
META_HASH_KEY = 'meta_sha256'
VERIFY_COMMAND = 'python -m pachs_jax.sac.verify --add-hash'
STATE_HASH_KEY = 'state_sha256'  # training checkpoint meta entry: params_hash of the state


class CheckpointError(ValueError):
  """A checkpoint that cannot be used: missing, incomplete, damaged or not what was asked for,
  or one that cannot be written. The message is one line and names the checkpoint."""


def meta_hash(meta: Dict[str, Any]) -> str:
  """SHA-256 (hex) of the canonical JSON (sorted keys, no spaces) of `meta` without its
  META_HASH_KEY entry: any change to the task, sizes or parameter hash changes it."""
  rest = {k: v for k, v in meta.items() if k != META_HASH_KEY}
  text = json.dumps(rest, sort_keys=True, separators=(',', ':'), ensure_ascii=True)
  return hashlib.sha256(text.encode()).hexdigest()


def _full_disk(reason: str) -> bool:
  """Whether an orbax / TensorStore failure reason says the disk is full (TensorStore reports
  ENOSPC as RESOURCE_EXHAUSTED)."""
  return any(k in reason for k in ('No space left', 'ENOSPC', 'RESOURCE_EXHAUSTED'))


def _save_failure(what: str, error: BaseException) -> CheckpointError:
  """The one-line CheckpointError of a failed write (a full disk names itself)."""
  reason = 'no space left on device' if getattr(error, 'errno', None) == errno.ENOSPC else (
      _reason(error))
  return CheckpointError(f'cannot save {what}: {reason}')


def _orbax_call(fn: Callable[[], Any]) -> Tuple[Any, Optional[str]]:
  """(fn(), None), or (None, a one-line reason) when orbax fails.

  A failed restore leaves orbax's other read coroutines with exceptions nobody retrieves;
  Python prints each (a page of TensorStore spec) when it collects them. They are collected
  here, with those reports dropped, so that the caller's one-line error is all the user sees.
  """
  old_hook = sys.unraisablehook

  def hook(unraisable):
    if not inspect.iscoroutine(unraisable.object):
      old_hook(unraisable)

  sys.unraisablehook = hook
  # absl's warnings and asyncio's reports of failed writes would add lines before the error
  loggers = [logging.getLogger(name) for name in ('absl', 'asyncio')]
  levels = [logger.level for logger in loggers]
  for logger in loggers:
    logger.setLevel(logging.CRITICAL)
  try:
    try:
      return fn(), None
    except Exception as e:  # pylint: disable=broad-except
      reason = _reason(e)
    gc.collect()  # the failed read coroutines, now unreferenced
    return None, reason
  finally:
    sys.unraisablehook = old_hook
    for logger, level in zip(loggers, levels):
      logger.setLevel(level)


def _reason(error: BaseException, limit: int = 200) -> str:
  """The first line of the innermost cause of `error` (orbax and TensorStore wrap the useful
  message in pages of specs), shortened to `limit` characters."""
  seen = set()
  while id(error) not in seen:
    seen.add(id(error))
    inner = error.__cause__ or error.__context__
    if inner is None:
      break
    error = inner
  lines = str(error).strip().splitlines()
  text = (lines[0] if lines else '') or type(error).__name__
  return text if len(text) <= limit else text[:limit - 3] + '...'


def _uncommitted(tree: Any) -> Any:
  """The tree's arrays as uncommitted device arrays (via the host), dtypes unchanged."""
  return jax.device_put(jax.tree.map(np.asarray, tree))


# ---------------------------------------------------------------- actor-critic export ----

def _params_tree(actor_critic: SacActorCritic) -> Dict[str, Any]:
  p = actor_critic.params
  return {'normalizer': dict(p.normalizer), 'policy': p.policy, 'q': p.q}


def save_actor_critic(path: str, actor_critic: SacActorCritic,
                      extra: Optional[Dict[str, Any]] = None) -> str:
  """Writes the actor-critic to directory `path` (replaced atomically if it exists).

  path/actor_critic.json holds {'format', 'model': ModelConfig dict} plus `extra`; path/params
  the orbax tree {'normalizer': {'mean', 'std'}, 'policy', 'q'}, whose `params_hash` goes into
  the JSON as 'params_sha256', and `meta_hash` of the JSON as 'meta_sha256'. Returns the
  absolute path. A failed write (a full disk) raises CheckpointError and leaves `path` as it was,
  with no temporary directory beside it.
  """
  path = os.path.abspath(path)
  remove_stale_exports(path)
  tmp = f'{path}.tmp-{os.getpid()}'
  tree = _params_tree(actor_critic)
  meta = {'format': FORMAT, 'model': config_lib.config_to_dict(actor_critic.config),
          HASH_KEY: params_hash(tree)}
  meta.update({k: v for k, v in (extra or {}).items() if k not in (*meta, META_HASH_KEY)})
  meta[META_HASH_KEY] = meta_hash(meta)
  old = f'{path}.old-{os.getpid()}'
  try:
    os.makedirs(tmp)
    checkpointer = ocp.StandardCheckpointer()
    _, failure = _orbax_call(lambda: _save_and_wait(checkpointer, os.path.join(tmp, PARAMS_DIR),
                                                    tree))
    if failure is not None:
      raise OSError(errno.ENOSPC if _full_disk(failure) else errno.EIO, failure)
    files.write_json(os.path.join(tmp, CONFIG_FILE), meta)
    if os.path.exists(path):
      os.rename(path, old)
    os.rename(tmp, path)
    files.fsync_directory(os.path.dirname(path))
  except OSError as e:
    shutil.rmtree(tmp, ignore_errors=True)
    if os.path.exists(old) and not os.path.exists(path):
      os.rename(old, path)
    raise _save_failure(f'the actor-critic in {path}', e) from None
  shutil.rmtree(old, ignore_errors=True)
  return path


def _save_and_wait(checkpointer: ocp.StandardCheckpointer, directory: str, tree: Any) -> None:
  checkpointer.save(directory, tree)
  checkpointer.wait_until_finished()


def remove_stale_exports(path: str) -> None:
  """Removes what an interrupted `save_actor_critic(path)` of a process no longer running left
  beside `path` (`path`.tmp-PID, `path`.old-PID; an .old- one is put back when `path` is
  missing)."""
  parent, name = os.path.split(os.path.abspath(path))
  if not os.path.isdir(parent):
    return
  for entry in sorted(os.listdir(parent)):
    for kind in ('.tmp-', '.old-'):
      pid = entry[len(name) + len(kind):] if entry.startswith(name + kind) else ''
      if not pid.isdigit() or _process_alive(int(pid)):
        continue
      stale = os.path.join(parent, entry)
      if kind == '.old-' and not os.path.exists(os.path.join(parent, name)):
        os.rename(stale, os.path.join(parent, name))
      else:
        shutil.rmtree(stale, ignore_errors=True)


def _process_alive(pid: int) -> bool:
  if pid == os.getpid():
    return False  # this process is not saving that path now
  try:
    os.kill(pid, 0)
  except ProcessLookupError:
    return False
  except PermissionError:
    return True
  return True


def _resolve_path(path: str) -> str:
  """The export directory at `path`, or inside a training run directory at `path`/model."""
  if not os.path.exists(path):
    raise CheckpointError(f'checkpoint {path}: no actor-critic checkpoint there (path does not '
                          'exist)')
  for candidate in (path, os.path.join(path, MODEL_SUBDIR)):
    if os.path.isfile(os.path.join(candidate, CONFIG_FILE)):
      return candidate
  raise CheckpointError(f'checkpoint {path}: not an actor-critic checkpoint (no {CONFIG_FILE} '
                        f'in it or in its {MODEL_SUBDIR}/ subdirectory)')


_REQUIRED_MODEL_FIELDS = tuple(f.name for f in dataclasses.fields(ModelConfig)
                               if f.default is dataclasses.MISSING)


def _read_model_config(path: str, require_hash: bool = True
                       ) -> Tuple[ModelConfig, Dict[str, Any]]:
  """(ModelConfig, whole metadata dict) of an actor-critic checkpoint; CheckpointError for a
  JSON that is unreadable or lacks a required entry (the hash only if `require_hash`)."""
  path = _resolve_path(path)
  where = f'checkpoint {path}: {CONFIG_FILE}'
  try:
    with open(os.path.join(path, CONFIG_FILE)) as f:
      meta = json.load(f)
  except (OSError, UnicodeDecodeError) as e:
    raise CheckpointError(f'{where} cannot be read ({_reason(e)})') from None
  except json.JSONDecodeError as e:
    raise CheckpointError(f'{where} is not valid JSON ({e}; file damaged?)') from None
  if not isinstance(meta, dict):
    raise CheckpointError(f'{where} holds a {type(meta).__name__}, not a JSON object')
  if meta.get('format') != FORMAT:
    raise CheckpointError(f'{where}: unknown checkpoint format {meta.get("format")!r}, '
                          f'expected {FORMAT!r}')
  model = meta.get('model')
  if not isinstance(model, dict):
    raise CheckpointError(f'{where} has no "model" object (the network config), so the '
                          'parameters cannot be interpreted')
  missing = [k for k in _REQUIRED_MODEL_FIELDS if k not in model]
  if missing:
    raise CheckpointError(f'{where}: "model" lacks required fields {missing}')
  try:
    config = config_lib.config_from_dict(ModelConfig, model, ignore_unknown=True)
    config.networks()  # an unknown activation or bad widths fail here, not at first use
  except (TypeError, ValueError, KeyError, AttributeError) as e:
    raise CheckpointError(f'{where}: invalid "model" config ({_reason(e)})') from None
  if require_hash:
    _check_meta_hash(path, where, config, meta)
  return config, meta


def _check_meta_hash(path: str, where: str, config: ModelConfig, meta: Dict[str, Any]) -> None:
  """CheckpointError unless meta records both hashes and its meta hash matches its entries."""
  missing = [k for k in (HASH_KEY, META_HASH_KEY) if not isinstance(meta.get(k), str)]
  if missing:
    before = 'metadata hashes' if missing == [META_HASH_KEY] else 'hashes'
    raise CheckpointError(f'{where} has no "{missing[0]}" (written before {before}, so its task '
                          f'and sizes are unverified); if you trust it, run: {VERIFY_COMMAND} '
                          f'{path}')
  if meta_hash(meta) != meta[META_HASH_KEY]:
    raise CheckpointError(f'{where} changed after it was written (meta hash mismatch; it now '
                          f'names task {config.task!r}); if that edit is intended, record it '
                          f'with: {VERIFY_COMMAND} {path}')


def _expected_params(config: ModelConfig) -> Dict[str, Any]:
  nets = config.networks()
  key = jax.ShapeDtypeStruct((2,), jnp.uint32)
  vec = jax.ShapeDtypeStruct((config.observation_size,), jnp.float32)
  return {'normalizer': {'mean': vec, 'std': vec},
          'policy': jax.eval_shape(nets.policy_init, key),
          'q': jax.eval_shape(nets.q_init, key)}


def _check_params(path: str, restored: Any, expected: Any) -> None:
  got = {jax.tree_util.keystr(k): v for k, v in jax.tree_util.tree_leaves_with_path(restored)}
  want = {jax.tree_util.keystr(k): v for k, v in jax.tree_util.tree_leaves_with_path(expected)}
  if set(got) != set(want):
    diff = sorted(set(got) ^ set(want))[:4]
    raise CheckpointError(f'checkpoint {path}: parameters do not match the network config in '
                          f'{CONFIG_FILE} (differing entries {diff})')
  for name, spec in want.items():
    if tuple(np.shape(got[name])) != tuple(spec.shape):
      raise CheckpointError(f'checkpoint {path}: parameter {name} has shape '
                            f'{tuple(np.shape(got[name]))}, the network config in {CONFIG_FILE} '
                            f'needs {tuple(spec.shape)}')


# Files orbax needs in params/ before it can even list the arrays (checked first: a missing one
# otherwise gives an orbax warning and an empty tree).
_PARAMS_FILES = ('_METADATA', 'manifest.ocdbt')


def _probe_ocdbt(params_path: str) -> Optional[str]:
  """None when every array of the OCDBT database in `params_path` reads back and decodes, else
  the first line of the error. Reads synchronously: orbax reads the same arrays from an asyncio
  loop and, after a failure, its abandoned reads print pages of tracebacks. Damage that still
  decodes (most of it: the arrays carry no checksums) is left to the hash."""
  if not os.path.isfile(os.path.join(params_path, 'manifest.ocdbt')):
    return None  # not an OCDBT checkpoint: left to orbax
  base = {'driver': 'ocdbt', 'base': f'file://{params_path}/'}
  try:
    keys = ts.KvStore.open(base).result().list().result()
    for key in keys:
      key = key.decode()
      if key.endswith('/.zarray'):
        array = ts.open({'driver': 'zarr', 'kvstore': dict(base, path=key[:-len('.zarray')])},
                        open=True).result()
        array.read().result()
  except Exception as e:  # pylint: disable=broad-except
    return _reason(e)
  return None


def _restore_params(path: str, config: ModelConfig) -> Dict[str, Any]:
  """The parameter tree of the export at `path` (resolved), restored onto the default device;
  CheckpointError for missing, unreadable or mismatching files (the hash is not checked)."""
  params_path = os.path.abspath(os.path.join(path, PARAMS_DIR))  # orbax needs it absolute
  if not os.path.isdir(params_path):
    raise CheckpointError(f'checkpoint {path}: missing {PARAMS_DIR}/ directory')
  for name in _PARAMS_FILES:
    if not os.path.isfile(os.path.join(params_path, name)):
      raise CheckpointError(f'checkpoint {path}: {PARAMS_DIR}/{name} is missing (incomplete '
                            'copy?)')
  failure = _probe_ocdbt(params_path)
  if failure is not None:
    raise CheckpointError(f'checkpoint {path}: cannot read {PARAMS_DIR}/ (file truncated, damaged '
                          f'or missing?): {failure}')
  expected = _expected_params(config)
  checkpointer = ocp.StandardCheckpointer()
  # Check names and shapes from the metadata first (a clear error instead of orbax's), then
  # restore onto this process's default device, whatever device the checkpoint was saved on.

  def shapes():
    stored = checkpointer.metadata(params_path)
    stored = getattr(stored, 'item_metadata', stored)
    stored = getattr(stored, 'tree', stored)
    return jax.tree.map(lambda m: np.zeros(m.shape, np.uint8), stored)

  stored, failure = _orbax_call(shapes)
  if failure is None and not jax.tree.leaves(stored):
    failure = 'no arrays listed'
  if failure is not None:
    raise CheckpointError(f'checkpoint {path}: cannot read {PARAMS_DIR}/ metadata (file damaged '
                          f'or missing?): {failure}')
  _check_params(path, stored, expected)
  device = jax.sharding.SingleDeviceSharding(jax.devices()[0])
  target = jax.tree.map(lambda s: jax.ShapeDtypeStruct(s.shape, s.dtype, sharding=device),
                        expected)
  restored, failure = _orbax_call(lambda: jax.tree.map(
      lambda x, s: np.asarray(x, s.dtype), checkpointer.restore(params_path, target), expected))
  if failure is not None:
    raise CheckpointError(f'checkpoint {path}: cannot read {PARAMS_DIR}/ (file truncated, damaged '
                          f'or missing?): {failure}')
  return restored


def params_sha256(path: str) -> str:
  """The parameter hash an export records (its metadata checked as on loading)."""
  _, meta = _read_model_config(path)
  return meta[HASH_KEY]


def physics_record(env: base.Env) -> Dict[str, Any]:
  """What an export records of the physics it was trained on: {'engine': `Env.physics`,
  'settings': `Env.physics_settings`}."""
  return {'engine': env.physics, 'settings': env.physics_settings}


def trained_physics(path: str) -> Optional[Dict[str, Any]]:
  """The `physics_record` of the env an export was trained on (None: not recorded); the
  metadata is checked as `load_actor_critic` checks it."""
  _, meta = _read_model_config(path)
  record = meta.get('physics')
  return record if isinstance(record, dict) else None


def physics_mismatch(path: str, env: base.Env) -> Optional[str]:
  """A line saying how env's physics model differs from the one the export at path was
  trained on (None: the same settings, or nothing recorded; `physics_presets.
  differing_settings`); engines that simulate the same settings (MJX, Warp, MuJoCo C) are not a
  mismatch."""
  record = trained_physics(path)
  if record is None:
    return None
  trained, now = record.get('settings') or {}, env.physics_settings or {}
  differ = physics_presets.differing_settings(trained, now)
  if not differ:
    return None
  shown = ', '.join(f'{k} {trained.get(k)!r} -> {now.get(k)!r}' for k in differ[:4])
  more = f' and {len(differ) - 4} more' if len(differ) > 4 else ''
  return (f'the model at {path} was trained on other physics than {env.name!r} simulates '
          f'({shown}{more}): its actor and critic may mislead the search')


def load_actor_critic(path: str, env: Optional[base.Env] = None,
                      task: Optional[str] = None) -> SacActorCritic:
  """Loads an exported actor-critic (or a run directory's latest export).

  With `env` (or `task`), checks that the checkpoint was trained on that task and, for `env`,
  that its observation and action sizes match. Any problem (also a parameter or metadata hash
  that does not match the one in actor_critic.json) raises CheckpointError, a ValueError.
  """
  path = _resolve_path(path)
  config, meta = _read_model_config(path)
  want_task = env.name if env is not None else task
  if want_task is not None and config.task != want_task:
    raise CheckpointError(f'checkpoint {path}: trained on task {config.task!r}, not '
                          f'{want_task!r}')
  if env is not None:
    if config.observation_size != env.observation_size:
      raise CheckpointError(f'checkpoint {path}: observation size {config.observation_size} != '
                            f'env {env.name!r} observation size {env.observation_size}')
    if config.action_size != env.action_size:
      raise CheckpointError(f'checkpoint {path}: action size {config.action_size} != env '
                            f'{env.name!r} action size {env.action_size}')
  restored = _restore_params(path, config)
  digest = params_hash(restored)
  if digest != meta[HASH_KEY]:
    raise CheckpointError(f'checkpoint {path}: params hash mismatch (file damaged?): '
                          f'{CONFIG_FILE} records {meta[HASH_KEY][:12]}..., the files hold '
                          f'{digest[:12]}...')
  restored = jax.device_put(restored)
  params = ActorCriticParams(normalizer=restored['normalizer'], policy=restored['policy'],
                             q=restored['q'])
  return SacActorCritic(params=params, config=config)


def add_hashes(path: str) -> str:
  """Records the parameter hash and the metadata hash of an export written before them, or
  whose actor_critic.json was edited on purpose (trusting its files as they are), and returns
  the metadata hash. A parameter hash already recorded must match the parameters (damaged
  weights are not blessed)."""
  path = _resolve_path(path)
  config, meta = _read_model_config(path, require_hash=False)
  digest = params_hash(_restore_params(path, config))
  if meta.get(HASH_KEY, digest) != digest:
    raise CheckpointError(f'checkpoint {path}: params hash mismatch (file damaged?); the '
                          'recorded hash is left as it is')
  head = {k: meta[k] for k in ('format', 'model')}
  rest = {k: v for k, v in meta.items() if k not in (*head, HASH_KEY, META_HASH_KEY)}
  meta = dict(head, **{HASH_KEY: digest}, **rest)
  meta[META_HASH_KEY] = meta_hash(meta)
  try:
    files.write_json(os.path.join(path, CONFIG_FILE), meta)
  except files.WriteError as e:
    raise CheckpointError(f'checkpoint {path}: {e}') from None
  return meta[META_HASH_KEY]


# ------------------------------------------------------------------ training states ----

class TrainingCheckpoints:
  """Full training states of one run, numbered by epoch; keeps the last `keep`. Opening it
  removes the temporary directories of a save that a kill interrupted."""

  def __init__(self, directory: str, keep: int = 3):
    if keep < 1:
      raise ValueError(f'keep must be >= 1, got {keep}')
    self.directory = os.path.abspath(directory)
    self._manager = ocp.CheckpointManager(
        self.directory,
        options=ocp.CheckpointManagerOptions(max_to_keep=keep, create=True,
                                             enable_async_checkpointing=False,
                                             cleanup_tmp_directories=True))
    self._remove_partial_saves()

  def _remove_partial_saves(self) -> None:
    """Removes orbax's temporary step directories (a save cut short by a kill or an error)."""
    for entry in os.listdir(self.directory):
      if '.orbax-checkpoint-tmp' in entry:
        shutil.rmtree(os.path.join(self.directory, entry), ignore_errors=True)

  def latest_epoch(self) -> Optional[int]:
    """The newest complete epoch saved, or None."""
    return self._manager.latest_step()

  def save(self, epoch: int, state: Any, meta: Dict[str, Any]) -> None:
    """Saves the state pytree and the JSON-ready meta dict, plus the state's `params_hash` as
    'state_sha256', as step `epoch` (blocking).

    A failed save (a full disk) raises a one-line CheckpointError and leaves no partial step
    behind; the earlier checkpoints stay."""
    meta = dict(meta, **{STATE_HASH_KEY: params_hash(state)})
    # a disk that cannot hold the state is named before orbax starts writing: a write that
    # fails midway leaves TensorStore's callbacks printing into a closed event loop
    need = sum(np.size(x) * np.dtype(x.dtype).itemsize if hasattr(x, 'dtype')  # no copy
               else np.asarray(x).nbytes for x in jax.tree.leaves(state))
    free = shutil.disk_usage(self.directory).free
    if free < need:
      raise CheckpointError(f'cannot save {self._where(epoch)}: no space left on device '
                            f'({free / 2**20:.1f} MiB free, the state needs about '
                            f'{need / 2**20:.1f} MiB)')

    def save():
      self._manager.save(int(epoch), args=ocp.args.Composite(
          state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta)), force=True)
      self._manager.wait_until_finished()

    _, failure = _orbax_call(save)
    if failure is not None:
      self._remove_partial_saves()
      raise CheckpointError(f'cannot save {self._where(epoch)}: '
                            + ('no space left on device' if _full_disk(failure) else failure))

  def _where(self, epoch: int) -> str:
    return f'training checkpoint {os.path.join(self.directory, str(int(epoch)))}'

  def read_meta(self, epoch: int) -> Dict[str, Any]:
    """The meta dict saved with `epoch`; CheckpointError when it cannot be read."""
    meta, failure = _orbax_call(lambda: self._manager.restore(
        int(epoch), args=ocp.args.Composite(meta=ocp.args.JsonRestore())).meta)
    if failure is not None:
      raise CheckpointError(f'{self._where(epoch)}: cannot read its meta (file damaged or '
                            f'missing?): {failure}')
    if not isinstance(meta, dict):
      raise CheckpointError(f'{self._where(epoch)}: its meta is not a JSON object')
    return meta

  def restore(self, epoch: int, like: Any) -> Any:
    """The state saved at `epoch`, with the structure, dtypes and shapes of `like`, as
    uncommitted arrays on the default device (as the jitted functions return them).

    CheckpointError when the files cannot be read or their hash differs from the recorded one
    (checkpoints from before state hashes are restored unverified)."""
    device = jax.sharding.SingleDeviceSharding(jax.devices()[0])
    abstract = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=device),
                            like)
    recorded = self.read_meta(epoch).get(STATE_HASH_KEY)
    failure = _probe_ocdbt(os.path.join(self.directory, str(int(epoch)), 'state'))
    if failure is not None:
      raise CheckpointError(f'{self._where(epoch)}: cannot read the training state (file '
                            f'truncated, damaged or missing?): {failure}')
    state, failure = _orbax_call(lambda: self._manager.restore(
        int(epoch), args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract))).state)
    if failure is not None:
      raise CheckpointError(f'{self._where(epoch)}: cannot read the training state (file '
                            f'truncated, damaged or missing?): {failure}')
    if recorded is not None and params_hash(state) != recorded:
      raise CheckpointError(f'{self._where(epoch)}: state hash mismatch (file damaged?)')
    return _uncommitted(state)

  def close(self) -> None:
    self._manager.close()

