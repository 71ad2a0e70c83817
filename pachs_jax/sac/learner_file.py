"""A training run's learner in one .npz file: what a run needs to move between machines
(networks, optimiser states, temperature, normaliser, PRNG key, counters), without its replay
buffer and environment states, which the receiving machine refills with the learner's own
policy (`Trainer.refill`). PushT-Fixed's learner is about 7 MB, PushT-Rand's about 25 MB; a full
training checkpoint with its 1 M-transition buffer is about 300 MB."""

from __future__ import annotations

import io
import json
import zipfile
from typing import Any, Dict, Tuple

import jax
import numpy as np

from pachs_jax.runtime import files
from pachs_jax.sac import digest
from pachs_jax.sac.trainer import TrainingState

FORMAT = 'pachs_jax.sac_learner/1'
# The TrainingState fields a learner file holds; the others (env_state, episode_return,
# buffer_state) are refilled where it is read.
LEARNER_FIELDS = ('policy_params', 'policy_optimizer_state', 'q_params', 'target_q_params',
                  'q_optimizer_state', 'log_alpha', 'alpha_optimizer_state', 'normalizer',
                  'key', 'epoch', 'gradient_steps')


class LearnerFileError(ValueError):
  """A learner file that is missing, damaged or of another run's shapes (one line)."""


def learner(state: TrainingState) -> Dict[str, Any]:
  """The `LEARNER_FIELDS` of a training state, by name."""
  return {name: getattr(state, name) for name in LEARNER_FIELDS}


def save(path: str, state: TrainingState, meta: Dict[str, Any]) -> None:
  """Writes the learner of `state` and the JSON-able `meta` (task, config, epoch, env steps,
  physics) to `path` in one atomic write; meta gains 'format' and 'learner_sha256'."""
  tree = jax.device_get(learner(state))
  leaves = jax.tree_util.tree_leaves(tree)
  meta = dict(meta, format=FORMAT, learner_sha256=digest.params_hash(tree))
  buffer = io.BytesIO()
  np.savez(buffer, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8),
           **{f'leaf{i:04d}': np.asarray(x) for i, x in enumerate(leaves)})
  files.write_bytes(path, buffer.getvalue())


def load(path: str, template: TrainingState) -> Tuple[Dict[str, Any], Dict[str, Any]]:
  """(learner fields, meta) of the file at `path`, shaped as `template`'s (a TrainingState or
  its `jax.eval_shape`); LearnerFileError, one line, for a missing or damaged file or other
  shapes (another task, network or optimiser)."""
  want = learner(template)
  structure = jax.tree_util.tree_structure(want)
  specs = jax.tree_util.tree_leaves(want)
  try:
    with np.load(path, allow_pickle=False) as data:
      meta = json.loads(bytes(data['meta']).decode())
      leaves = [data[f'leaf{i:04d}'] for i in range(len(specs))]
      extra = len(data.files) - 1 - len(specs)
  except FileNotFoundError:
    raise LearnerFileError(f'learner file {path} does not exist') from None
  except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
    raise LearnerFileError(f'learner file {path} is not a complete learner file ({e})') from None
  if meta.get('format') != FORMAT:
    raise LearnerFileError(f'learner file {path}: format {meta.get("format")!r}, expected '
                           f'{FORMAT!r}')
  if extra:
    raise LearnerFileError(f'learner file {path} holds {len(specs) + extra} arrays, this run '
                           f'{len(specs)}: another network or optimiser')
  for i, (leaf, spec) in enumerate(zip(leaves, specs)):
    if leaf.shape != tuple(spec.shape) or leaf.dtype != spec.dtype:
      raise LearnerFileError(
          f'learner file {path}: array {i} is {leaf.dtype}{list(leaf.shape)}, this run needs '
          f'{spec.dtype}{list(spec.shape)} (another task or network size)')
  tree = jax.tree_util.tree_unflatten(structure, leaves)
  if digest.params_hash(tree) != meta.get('learner_sha256'):
    raise LearnerFileError(f'learner file {path}: its arrays do not match their hash (damaged)')
  return tree, meta
