"""Where the wall time of one `pachs plan` process goes: imports, Warp's start and kernel module
loads, the model, the env's physics, each search program (stored, JAX cache or compiled), the
search itself and the output; one JSON line per run.

  python experiments/profile_plan_startup.py --out phases.json -- plan --task pusht-obs
"""

from __future__ import annotations

import time

_BEGAN = time.perf_counter()

# pylint: disable=g-import-not-at-top,wrong-import-position
import argparse
import collections
import contextlib
import functools
import json
import os
import sys

TIMES = collections.defaultdict(float)  # phase -> seconds (summed over its calls)
COUNTS = collections.Counter()


@contextlib.contextmanager
def phase(name: str):
  began = time.perf_counter()
  try:
    yield
  finally:
    TIMES[name] += time.perf_counter() - began
    COUNTS[name] += 1


def timed(owner, attribute: str, name: str):
  """Wraps owner.attribute so that its calls add to phase `name`."""
  inner = getattr(owner, attribute)

  @functools.wraps(inner)
  def wrapper(*args, **kwargs):
    with phase(name):
      return inner(*args, **kwargs)
  setattr(owner, attribute, wrapper)


def main() -> int:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--out', required=True, help='JSON file the phases are appended to')
  parser.add_argument('--label', default='', help='a name for this run in the JSON')
  parser.add_argument('--widen-backend', action='store_true',
                      help="let the CLI's --backend take every envs backend ('warp' too)")
  parser.add_argument('words', nargs='+', help="the `pachs` command's words, after '--'")
  args = parser.parse_args()
  if args.widen_backend:
    add_argument = argparse._ActionsContainer.add_argument  # pylint: disable=protected-access

    def widened(self, *names, **kwargs):
      if names[:1] == ('--backend',) and 'choices' in kwargs:
        from pachs_jax.envs import mujoco_c
        kwargs['choices'] = list(mujoco_c.BACKENDS)
      return add_argument(self, *names, **kwargs)
    argparse._ActionsContainer.add_argument = widened  # pylint: disable=protected-access

  with phase('import jax'):
    import jax
    jax.devices()
  with phase('import mujoco, mjx (warp part)'):
    from pachs_jax.envs import warp_import
  warp_ok = warp_import.available()
  if warp_ok:
    with phase('import warp, warp.init'):
      import warp
      warp.init()
    from warp._src import context as warp_context
    timed(warp_context.Module, 'load', 'warp module loads')
    timed(warp_context.Module, 'hash_module', 'warp module hashing (inside loads)')
  with phase('import pachs_jax'):
    from pachs_jax import cli, compile_cache, planner
    from pachs_jax.envs import mujoco_c
    from pachs_jax.sac import checkpoint
    from pachs_jax import programs
  timed(planner, 'load_model', 'load_model (env + physics + checkpoint)')
  physics = []
  inner_backend = mujoco_c.make_backend

  def make_backend(*a, **k):
    with phase('make_backend (physics backend, put_model)'):
      env = inner_backend(*a, **k)
    physics.append(type(env).__name__)
    return env
  mujoco_c.make_backend = make_backend
  timed(checkpoint, 'load_actor_critic', 'checkpoint load')
  timed(planner, 'canonical_instances', 'canonical instances')
  timed(programs, 'check_model_outputs', 'model check (thread)')
  timed(programs, 'plan', 'programs.plan (programs + search)')
  stores = collections.Counter()
  inner_compiled = compile_cache.compiled_program

  def compiled_program(jitted, call_args, fingerprint, donate_argnums=(), prefetch=None):
    name = (fingerprint or '').rsplit(' ', 2)[-1] if fingerprint else 'unnamed'
    directory = jax.config.jax_compilation_cache_dir
    before = set(os.listdir(os.path.join(directory, compile_cache.TRACES))) if directory and \
        os.path.isdir(os.path.join(directory, compile_cache.TRACES)) else set()
    with phase(f'program {name} (thread time)'):
      out = inner_compiled(jitted, call_args, fingerprint, donate_argnums, prefetch)
    after = set(os.listdir(os.path.join(directory, compile_cache.TRACES))) if directory and \
        os.path.isdir(os.path.join(directory, compile_cache.TRACES)) else set()
    new = sorted(after - before)
    stores[name] = ','.join(n.rsplit('.', 1)[-1] for n in new) or 'loaded or traced'
    return out
  compile_cache.compiled_program = compiled_program
  inner_compile = compile_cache._compile  # pylint: disable=protected-access

  def _compile(jitted, call_args):
    with phase('trace+lower+XLA compile/JAX-cache load (not stored)'):
      return inner_compile(jitted, call_args)
  compile_cache._compile = _compile  # pylint: disable=protected-access

  log = {'compiled': [], 'cache_hits': [], 'cache_misses': []}

  import logging

  class Record(logging.Handler):
    def emit(self, record):
      message = record.getMessage()
      if message.startswith('Compiling '):
        log['compiled'].append(message.split(' ')[1])
      elif 'cache hit' in message.lower():
        log['cache_hits'].append(message[:120])
      elif 'cache miss' in message.lower() or 'not found in the persistent' in message.lower():
        log['cache_misses'].append(message[:120])
  logger = logging.getLogger('jax')
  logger.addHandler(Record())
  logger.setLevel(logging.DEBUG)
  for handler in logging.getLogger().handlers:
    handler.setLevel(logging.WARNING)
  jax.config.update('jax_log_compiles', True)
  logging.getLogger('jax').propagate = False

  printed = []
  real_print = print

  def spy_print(*a, **k):
    text = ' '.join(str(x) for x in a)
    printed.append(text)
    if text.startswith('found '):
      TIMES['search run (result.wall_time_s, in pachs.plan)'] = float(
          text.split('search time ')[1].split(' s')[0])
    real_print(*a, **k)
  import builtins
  builtins.print = spy_print
  with phase('cli.main (all of the command)'):
    code = cli.main(args.words)
  builtins.print = real_print
  total = time.perf_counter() - _BEGAN
  record = {
      'label': args.label, 'words': args.words, 'rc': code, 'warp': warp_ok,
      'physics': physics,
      'device': str(jax.devices()[0].device_kind), 'backend': jax.default_backend(),
      'seconds_in_script': round(total, 3),
      'phases': {k: round(v, 3) for k, v in TIMES.items()},
      'calls': dict(COUNTS), 'programs': dict(stores),
      'xla_compiled': log['compiled'], 'jax_cache_hits': len(log['cache_hits']),
      'jax_cache_messages': log['cache_hits'][:5] + log['cache_misses'][:5],
      'last_lines': printed[-2:],
  }
  with open(args.out, 'a') as f:
    f.write(json.dumps(record) + '\n')
  real_print(json.dumps(record, indent=1), file=sys.stderr)
  return code


if __name__ == '__main__':
  sys.exit(main())
