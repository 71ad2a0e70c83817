"""Progress reporting of training runs: a progress bar, metrics.csv and TensorBoard."""

from __future__ import annotations

import csv
import math
import os
import time
from typing import Dict

import tqdm

from pachs_jax.runtime import files

CSV_COLUMNS = ('env_steps', 'epoch', 'walltime', 'sps', 'episode_return', 'success_rate',
               'episodes', 'reward_mean', 'critic_loss', 'actor_loss', 'alpha_loss', 'alpha',
               'buffer_size', 'eval_success_deterministic', 'eval_success_stochastic',
               'eval_cost_deterministic')


class RunReporter:
  """Writes run_dir/metrics.csv, TensorBoard events (if tensorboardX is installed) and a tqdm bar.

  metrics.csv gets one row per epoch (a header first when it is new or empty); a resumed run
  adds its rows after the earlier ones, once the rows past the checkpoint it resumes (those of
  a run killed before it saved them, or a row cut short) are dropped: each epoch has one row.

  progress: 'bar' (tqdm: env steps, env steps/s, episode return, success rate), 'lines' (a
    printed line at most every line_seconds and at every evaluation; for logs) or 'none'.
  tensorboard: write run_dir/tensorboard when tensorboardX can be imported.
  """

  def __init__(self, run_dir: str, progress: str = 'bar', tensorboard: bool = True,
               description: str = '', line_seconds: float = 30.0):
    if progress not in ('bar', 'lines', 'none'):
      raise ValueError(f"progress must be 'bar', 'lines' or 'none', got {progress!r}")
    self.run_dir = run_dir
    self.csv_path = os.path.join(run_dir, 'metrics.csv')
    self._progress = progress
    self._line_seconds = line_seconds
    self._last_line = -math.inf
    self._tensorboard = tensorboard
    self._description = description
    self._bar = None
    self._writer = None
    self._csv_file = None
    self._csv = None
    self._last = 0

  def start(self, env_steps: int, total_env_steps: int) -> None:
    """Opens the outputs of a run (re)starting at env_steps of total_env_steps."""
    os.makedirs(self.run_dir, exist_ok=True)
    new = not os.path.exists(self.csv_path) or os.path.getsize(self.csv_path) == 0
    if not new:
      _keep_rows_up_to(self.csv_path, env_steps)
    self._csv_file = open(self.csv_path, 'a', newline='')
    self._csv = csv.DictWriter(self._csv_file, fieldnames=CSV_COLUMNS, extrasaction='ignore')
    if new:
      self._csv.writeheader()
    if self._tensorboard:
      try:
        import tensorboardX  # pylint: disable=import-outside-toplevel
        self._writer = tensorboardX.SummaryWriter(os.path.join(self.run_dir, 'tensorboard'))
      except ImportError:
        self._writer = None
    if self._progress == 'bar':
      self._bar = tqdm.tqdm(total=total_env_steps, initial=env_steps, unit='step',
                            unit_scale=True, desc=self._description, dynamic_ncols=True)
    self._last = env_steps

  def report(self, env_steps: int, metrics: Dict[str, float]) -> None:
    row = {k: v for k, v in metrics.items() if not (isinstance(v, float) and math.isnan(v))}
    row['env_steps'] = env_steps
    self._csv.writerow(row)
    self._csv_file.flush()
    if self._writer is not None:
      for k, v in metrics.items():
        if k != 'epoch' and not math.isnan(v):
          self._writer.add_scalar(k, v, env_steps)
    if self._bar is not None:
      self._bar.update(env_steps - self._last)
      post = {'sps': f"{metrics.get('sps', 0.0):.3g}",
              'ret': f"{metrics.get('episode_return', math.nan):.3g}",
              'succ': f"{metrics.get('success_rate', math.nan):.2f}"}
      if 'eval_success_deterministic' in metrics:
        post['eval'] = f"{metrics['eval_success_deterministic']:.2f}"
      self._bar.set_postfix(post, refresh=False)
    elif self._progress == 'lines':
      now = time.time()
      if now - self._last_line >= self._line_seconds or 'eval_success_deterministic' in metrics:
        print(f'[{self._description}] ' + _summary_line(dict(metrics, env_steps=env_steps)),
              flush=True)
        self._last_line = now
    self._last = env_steps

  def note(self, line: str) -> None:
    """Prints a one-line note (above the bar when there is one; not with progress 'none')."""
    if self._bar is not None:
      self._bar.write(f'[{self._description}] {line}')
    elif self._progress != 'none':
      print(f'[{self._description}] {line}', flush=True)

  def close(self) -> None:
    if self._bar is not None:
      self._bar.close()
    if self._writer is not None:
      self._writer.close()
    if self._csv_file is not None:
      self._csv_file.close()
    self._bar = self._writer = self._csv_file = self._csv = None


def _keep_rows_up_to(csv_path: str, env_steps: int) -> None:
  """Rewrites csv_path (atomically) without the rows past env_steps and without rows cut short
  (fewer fields than the header, or no line end); a file without them is left untouched."""
  with open(csv_path, newline='') as f:
    text = f.read()
  lines = text.splitlines(keepends=True)
  if not lines:
    return
  width = len(next(csv.reader([lines[0]])))
  kept = [lines[0]]
  for line in lines[1:]:
    fields = next(csv.reader([line]), [])
    try:
      whole = line.endswith('\n') and len(fields) == width and float(fields[0]) <= env_steps
    except ValueError:
      whole = False
    if whole:
      kept.append(line)
  if len(kept) != len(lines):
    files.write_text(csv_path, ''.join(kept))


def _summary_line(metrics: Dict[str, float]) -> str:
  """One line of the main metrics (for logs of non-interactive runs)."""
  keys = ('env_steps', 'walltime', 'sps', 'episode_return', 'success_rate', 'critic_loss',
          'alpha', 'eval_success_deterministic', 'eval_success_stochastic')
  return ' '.join(f'{k}={metrics[k]:.4g}' for k in keys if k in metrics)
