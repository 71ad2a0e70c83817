"""Shared helpers of the experiment scripts: flags, provenance, timing, result files. Light to
import (JAX loads where a helper needs it), so that a script can check its flags first."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import subprocess
import sys
import time
from typing import Any, Callable, Dict, List, Optional, Sequence, Union

import numpy as np

from pachs_jax import argtypes, cli, envs
from pachs_jax.envs import layouts, physics_presets, registry


def add_common_args(parser: argparse.ArgumentParser, out: Optional[str],
                    instances: Union[bool, None, int] = False, backend: bool = False,
                    seed: bool = False, layout: bool = False, physics: bool = False) -> None:
  """Adds the flags the experiments share.

  --out: the results JSON (markdown and pictures go next to it); default `out`, or where None,
    a path the script derives from its other flags.
  --instances N (unless `instances` is False): the first N canonical instances of the task
    (0..N-1), its one meaning in every experiment; default `instances`, None: the task's whole
    canonical set (30 PushT, 100 shelf; `task_instances`).
  --backend (if `backend`): the planners' edge physics, `planner.load_model`'s backend.
  --seed (if `seed`): the runs' PRNG seed, default 0.
  --layout NAME (if `layout`): pusht-obs's obstacle layout (`layouts.LAYOUTS`; default
    `layouts.DEFAULT`); check it against the task with `check_layout`.
  --physics NAME (if `physics`): a PushT task's physics preset
    (`physics_presets.PHYSICS_PRESETS`; default: the task's); check it against the task with
    `check_physics`.
  """
  if instances is not False:
    parser.add_argument('--instances', type=argtypes.positive_int, default=instances,
                        metavar='N',
                        help='the first N canonical instances, 0..N-1 (default: '
                        f'{instances or "the task set: 30 PushT, 100 shelf"})')
  if backend:
    parser.add_argument('--backend', default='mjx', choices=registry.BACKENDS,
                        help="edge physics (mujoco-c: MuJoCo C on the CPU threads; warp: MuJoCo "
                        "Warp; auto: warp or mjx on an accelerator, mujoco-c without one)")
  if seed:
    parser.add_argument('--seed', type=argtypes.seed, default=0)
  if layout:
    parser.add_argument('--layout', default=None, choices=layouts.NAMES,
                        help=f"pusht-obs only: the obstacle layout (default: {layouts.DEFAULT}; "
                        "'legacy': PushT-Obs of the results recorded before the layouts)")
  if physics:
    parser.add_argument('--physics', default=None, choices=physics_presets.NAMES,
                        help='PushT only: the physics preset of the planners and the worlds '
                        '(default: the task\'s, faithful)')
  parser.add_argument('--out', default=out, type=argtypes.path('a file'),
                      help='results JSON, other outputs next to it '
                      f'(default: {out or "in experiments/results/, named after the flags"})')


def check_layout(parser: argparse.ArgumentParser, task: str, layout: Optional[str]) -> None:
  """parser.error unless --layout is unset or the task is pusht-obs."""
  if layout is not None and task != 'pusht-obs':
    parser.error(f'--layout applies to --task pusht-obs only, not {task!r}')


def check_physics(parser: argparse.ArgumentParser, task: str, physics: Optional[str]) -> None:
  """--physics applies to the PushT tasks only."""
  if physics is not None and not task.startswith('pusht'):
    parser.error(f'--physics applies to the PushT tasks, not {task}')


def task_label(task: str, layout: Optional[str] = None, physics: Optional[str] = None) -> str:
  """The name a task's result files carry: the task, or 'pusht-obs-NAME' for a layout other than
  the default, and '_PRESET' for a physics preset given."""
  label = task if layout in (None, layouts.DEFAULT) else f'{task}-{layout}'
  return label + (f'_{physics}' if physics else '')


def task_instances(task: str, instances: Optional[int] = None,
                   parser: Optional[argparse.ArgumentParser] = None) -> int:
  """`instances`, or where None the size of the task's canonical set; parser.error (ValueError
  without a parser) for more than that set holds."""
  available = envs.spec(task).num_instances
  if instances is not None and instances > available:
    message = (f'--instances {instances} exceeds the {available} canonical instances of '
               f'{task} (0..{available - 1})')
    if parser is None:
      raise ValueError(message)
    parser.error(message)
  return instances or available


def check_out(parser: argparse.ArgumentParser, path: Optional[str]) -> None:
  """parser.error unless a results JSON can be written at path (`cli.check_output_path`; a
  .json name, since its .md and plots are written beside it; None: the script's default, under
  experiments/results/), before any work."""
  if path is not None:
    if not path.endswith('.json'):
      parser.error(f'--out {path!r}: a .json file (the .md and plots go beside it)')
    try:
      cli.check_output_path('--out', path)
    except ValueError as err:
      parser.error(str(err))


def check_out_folder(parser: argparse.ArgumentParser, path: str) -> None:
  """parser.error unless path is, or can be made, a folder this process writes to (made now,
  before any work)."""
  try:
    os.makedirs(path, exist_ok=True)
    if not os.access(path, os.W_OK):
      raise OSError('not writable')
  except OSError as err:
    parser.error(f'--out {path!r}: not a folder that can be written ({err})')


def checked(parser: argparse.ArgumentParser, build: Callable[[], Any]) -> Any:
  """build(), with a ValueError it raises (a bad setting) turned into parser.error."""
  try:
    return build()
  except ValueError as err:
    parser.error(str(err))


def git_revision(root: Optional[str] = None) -> str:
  """PACHS_GIT_REVISION when set (the GPU machine's copy of the tree), else the commit of the
  checkout at root (None: this one), with '+dirty' when files differ, or 'unknown'."""
  if os.environ.get('PACHS_GIT_REVISION'):
    return os.environ['PACHS_GIT_REVISION']
  root = root or os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
  try:
    rev = subprocess.run(['git', 'rev-parse', 'HEAD'], cwd=root, capture_output=True, text=True,
                         check=True).stdout.strip()
    dirty = subprocess.run(['git', 'status', '--porcelain', '--untracked-files=no'], cwd=root,
                           capture_output=True, text=True).stdout.strip()
    return rev + ('+dirty' if dirty else '')
  except (OSError, subprocess.CalledProcessError):
    return 'unknown'


def command_line() -> str:
  """The command that started this process as typed (a wrapper such as heldout_layouts.py
  included), the interpreter by its base name."""
  argv = list(getattr(sys, 'orig_argv', None) or [sys.executable] + sys.argv)
  return ' '.join([os.path.basename(argv[0])] + argv[1:])


def provenance(device: Optional[str] = None) -> Dict[str, Any]:
  """Device, command, revision and versions for a results file. device: the planner's device
  where it is not this process's (a server's, from its health answer)."""
  import jax  # pylint: disable=import-outside-toplevel
  dev = jax.devices()[0]
  device = device or f'{dev.platform}: {getattr(dev, "device_kind", str(dev))} x{jax.device_count()}'
  return {
      'command': command_line(),
      'git_revision': git_revision(),
      'device': device,
      'host_cpus': os.cpu_count(),
      'jax': jax.__version__,
      'python': platform.python_version(),
      'date_utc': time.strftime('%Y-%m-%d %H:%M:%S', time.gmtime()),
  }


def merged_provenance(sources: Sequence[Dict[str, Any]], **fields: Any) -> Dict[str, Any]:
  """The provenance of a result merged from others: fields (such as the merging command) and
  'merged_from', the sources' provenance records in order, an earlier merge's own sources in
  its place (one flat list)."""
  runs: List[Dict[str, Any]] = []
  for source in sources:
    runs.extend(source.get('merged_from') or [source])
  return dict(fields, merged_from=runs)


def time_call(fn: Callable[[], Any], repeats: int = 3, warmup: int = 1) -> Dict[str, float]:
  """Median and min wall time (s) of fn() with its outputs blocked on; compile excluded."""
  import jax  # pylint: disable=import-outside-toplevel
  for _ in range(warmup):
    jax.block_until_ready(fn())
  times: List[float] = []
  for _ in range(repeats):
    start = time.perf_counter()
    jax.block_until_ready(fn())
    times.append(time.perf_counter() - start)
  return {'median_s': float(np.median(times)), 'min_s': float(np.min(times))}


def env_throughput(env, worlds: int, steps: int, repeats: int, nodes=None) -> dict:
  """Env steps/s of a JAX env: `steps` `env.evaluate` calls of `worlds` edges (uniform random
  actions) in one jitted scan, from nodes [worlds] (None: the env's initial nodes); the compile
  time, the median and min wall time (s) of `repeats` timed scans, the invalid edges."""
  import jax  # pylint: disable=import-outside-toplevel
  import jax.numpy as jnp  # pylint: disable=import-outside-toplevel
  from pachs_jax import trees  # pylint: disable=import-outside-toplevel
  if nodes is None:
    nodes = env.initial_nodes(jax.random.split(jax.random.PRNGKey(0), worlds))

  @jax.jit
  def run(nodes, key):
    def body(nodes, k):
      actions = jax.random.uniform(k, (worlds, env.action_size), minval=-1.0, maxval=1.0)
      out = env.evaluate(nodes, actions)
      return trees.where(out.is_valid, out.next_node, nodes), jnp.sum(~out.is_valid)
    return jax.lax.scan(body, nodes, jax.random.split(key, steps))

  start = time.perf_counter()
  _, invalid = jax.block_until_ready(run(nodes, jax.random.PRNGKey(1)))
  compile_s = time.perf_counter() - start
  t = time_call(lambda: run(nodes, jax.random.PRNGKey(2)), repeats=repeats, warmup=0)
  return {'worlds': worlds, 'steps': steps, 'compile_s': compile_s, **t,
          'invalid_edges': int(np.sum(invalid)),
          'env_steps_per_s': worlds * steps / t['median_s'],
          'ms_per_env_step': 1e3 * t['median_s'] / steps}


def config_record(config: Any) -> Any:
  """A planner's config as a result file keeps it: a dataclass as {'type': its class name,
  **its fields}, anything else as its repr."""
  if dataclasses.is_dataclass(config) and not isinstance(config, type):
    return {'type': type(config).__name__, **dataclasses.asdict(config)}
  return repr(config)


def write_json(path: str, payload: Dict[str, Any]) -> None:
  """Writes payload as indented JSON at path (its folder made; numpy scalars as floats)."""
  os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
  with open(path, 'w') as f:
    json.dump(payload, f, indent=1, default=float)


def markdown_header(title: str, provenance: Dict[str, Any], *paragraphs: str) -> List[str]:
  """The first lines of a result's markdown: '# title', the provenance record as Python prints
  it, then paragraphs (such as 'Settings: ...'), each followed by a blank line."""
  lines = []
  for block in (f'# {title}', str(provenance)) + paragraphs:
    lines += [block, '']
  return lines


def write_result(path: str, document: Dict[str, Any], markdown: Sequence[str]) -> None:
  """Writes a result: document as the JSON at path (a .json name) and the markdown lines,
  joined by newlines and ending in one, beside it (path with .md for .json)."""
  write_json(path, document)
  with open(os.path.splitext(path)[0] + '.md', 'w') as f:
    f.write('\n'.join(markdown) + '\n')


def markdown_table(rows: List[Dict[str, Any]], columns: List[str]) -> str:
  """A markdown table of the given columns of rows (floats with 4 significant digits)."""
  def fmt(v):
    if isinstance(v, float):
      return f'{v:.4g}'
    return str(v)
  lines = ['| ' + ' | '.join(columns) + ' |', '|' + '---|' * len(columns)]
  lines += ['| ' + ' | '.join(fmt(r.get(c, '')) for c in columns) + ' |' for r in rows]
  return '\n'.join(lines)
