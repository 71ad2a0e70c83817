"""Where a `pachs plan` process spends its time: imports, model load, instance generation,
checks + tracing + compilation, search and output, and the XLA programs compiled, cold and
with a warm persistent compilation cache, for one instance and for the 30-instance main job.
`--commands 30` times the real command; `--test-suite` times `python -m pytest` instead;
`profile` runs one command in this process and times its phases (Warp's kernel loads included):

  python experiments/bench_startup.py profile --out phases.json -- plan --task pusht-obs
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import functools
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time

T_START = time.perf_counter()  # before the other imports: `profile` times them


def child(task: str, instances: int, budget, backend: str) -> dict:
  """One process's phases (s), as `pachs plan` runs them (with its prefetch of the executables
  this child used last time, in a thread from the start), and the XLA programs it compiled."""
  import logging
  reads = []  # (file, thread, began, ended): s from this process's start

  class Reads(logging.Handler):
    def emit(self, record):
      name, _, began, ended, thread = record.args
      reads.append((name[:12], thread, round(began - T_START, 3), round(ended - T_START, 3)))

  store_log = logging.getLogger('pachs_jax.runtime.compile_cache')
  store_log.addHandler(Reads())
  store_log.setLevel(logging.DEBUG)
  times, ends = {}, {}
  mark = time.perf_counter()

  def phase(name):
    nonlocal mark
    now = time.perf_counter()
    times[name], ends[name] = now - mark, round(now - T_START, 3)
    mark = now

  from pachs_jax.runtime import compile_cache
  with compile_cache.prefetching(sys.argv[1:]) as prefetch:  # as `pachs plan` (cli.main) does
    import jax
    from pachs_jax import planner
    from pachs_jax.runtime import programs
    from pachs_jax.search import pachs
    from pachs_jax.search.checks import instance_keys
    phase('imports')
    with compile_cache.compile_log() as log:
      cache = compile_cache.enable()
      on_cpu = jax.default_backend() == 'cpu'
      jax.devices()
      phase('backend_init')
      env, model = planner.load_model(task, None, backend)
      config = planner.command_config(task, on_cpu, env.physics == 'mujoco-c', budget)
      phase('model_load')
      starts = env.canonical_instances(instances)
      jax.block_until_ready(starts)
      phase('instance_generation')
      search = programs.Programs(pachs.make_search(env, model, config), prefetch=prefetch)
      keys = instance_keys(jax.random.PRNGKey(0), instances)
      phase('make_search')
      # as `pachs plan` runs it: checks, tracing and compilation (or loading the stored programs;
      # the loops of the reachable physics sizes concurrently), search
      began = time.perf_counter()
      out = jax.block_until_ready(programs.plan(env, model, starts, config, keys, search=search))
      times['search'] = float(out.wall_time_s)
      times['checks_trace_compile'] = time.perf_counter() - began - times['search']
      ends['plan'] = round(time.perf_counter() - T_START, 3)
      mark = time.perf_counter()
      loops = sorted(str(key[1]) for compiled in search.compiled.values() for key in compiled
                     if isinstance(key, tuple))
      rows = planner.result_rows(out, list(range(instances)))
      print(planner.format_table(rows, ['instance', 'found', 'cost', 'evaluated', 'stop']),
            file=sys.stderr)
      phase('output')
  return {'phases_s': times, 'phase_ends_s': ends, 'executable_reads': reads,
          'programs_compiled': len(log.compiled),
          'persistent_cache_hits': len(log.cache_hits),
          'program_names': sorted(set(log.compiled)), 'found': sum(r['found'] for r in rows),
          'loop_sizes_compiled': loops,
          'device': str(jax.devices()[0]), 'cache_dir': cache,
          'in_process_s': time.perf_counter() - T_START}


def cold_then_warm(command: list, warm_variants: dict = None, repeats: int = 1):
  """Runs command cold and then warm `repeats` times (each warm variant, label -> command, in
  turn) with one fresh persistent cache: yields (run, process wall s, stdout), run 'cold',
  'warm' or a variant's label; a failing run ends the benchmark with its stderr."""
  warm = [('warm', command)] + list((warm_variants or {}).items())
  runs = [('cold', command)] + warm * repeats
  with tempfile.TemporaryDirectory() as cache:
    for run, argv in runs:
      began = time.perf_counter()
      done = subprocess.run(argv, capture_output=True, text=True,
                            env=dict(os.environ, PACHS_COMPILATION_CACHE=cache))
      wall = time.perf_counter() - began
      if done.returncode:
        raise SystemExit(done.stderr[-3000:])
      yield run, wall, done.stdout


def main():
  if sys.argv[1:2] == ['profile']:
    sys.exit(profile(sys.argv[2:]))
  parser = argparse.ArgumentParser(description=__doc__)
  parser.add_argument('--task', default='pusht-obs')
  parser.add_argument('--instances', default='1,30', help='instance counts, comma separated')
  parser.add_argument('--budget', type=int, default=None, help='None: the command default')
  parser.add_argument('--backend', default='auto', choices=['auto', 'mjx', 'mujoco-c'])
  parser.add_argument('--commands', default='',
                      help='instance counts of the real `pachs plan` processes to time too, '
                      'cold and warm, comma separated')
  parser.add_argument('--plan-args', default='',
                      help="more `pachs plan` options for the real commands, given as "
                      "--plan-args='--compact-fractions=' (with '=': they begin with --)")
  parser.add_argument('--repeats', type=int, default=1,
                      help='warm runs of each real command (and as many of each variant: '
                      'without prefetch, with the teardown)')
  parser.add_argument('--out', default='experiments/results/bench_startup.json')
  parser.add_argument('--child', action='store_true', help=argparse.SUPPRESS)
  parser.add_argument('--test-suite', action='store_true',
                      help='time the test suite instead (`python -m pytest` with the options '
                      'of pyproject.toml: two worker processes)')
  parser.add_argument('--merge', default='',
                      help='comma-separated result files of earlier runs to merge into --out '
                      '(runs nothing)')
  args = parser.parse_args()
  if args.merge:
    merge(args.merge.split(','), args.out)
    return
  if args.child:
    print(json.dumps(child(args.task, int(args.instances), args.budget, args.backend)))
    return
  import common
  if args.test_suite:
    note = ('the JAX compilation cache empty at the start (a new folder, as on a fresh machine '
            'or CI)')
    common.write_json(args.out, dict(provenance=dict(common.provenance(), note=note),
                                     **test_suite()))
    return
  rows = []
  budget = ['--budget', str(args.budget)] if args.budget else []
  for count in map(int, filter(None, args.instances.split(','))):
    command = [sys.executable, __file__, '--child', '--task', args.task, '--instances',
               str(count), '--backend', args.backend] + budget
    for run, wall, stdout in cold_then_warm(command):
      row = json.loads(stdout.strip().splitlines()[-1])
      row.update(instances=count, run=run, process_wall_s=wall)
      rows.append(row)
      print(json.dumps({k: v for k, v in row.items() if k != 'program_names'}), flush=True)
  commands = []
  for count in map(int, filter(None, args.commands.split(','))):
    spec = '0' if count == 1 else f'0-{count - 1}'
    words = (['plan', '--task', args.task, '--instances', spec, '--backend', args.backend]
             + budget + shlex.split(args.plan_args))
    command = [sys.executable, '-m', 'pachs_jax.cli'] + words
    # the command without `cli.main`'s prefetch of the executables it used last time, and
    # without `cli.run`'s immediate exit (the interpreter's and JAX's teardown)
    variants = {
        'warm, no prefetch': [sys.executable, '-c', 'import os, sys; from pachs_jax import cli; '
                              'code = cli._main(sys.argv[1:]); sys.stdout.flush(); '
                              'os._exit(code)'] + words,
        'warm, teardown': [sys.executable, '-c', 'import sys; from pachs_jax import cli; '
                           'sys.exit(cli.main(sys.argv[1:]))'] + words}
    for run, wall, stdout in cold_then_warm(command, variants, args.repeats):
      summary = [l for l in stdout.splitlines() if l.startswith('found ')][-1]
      commands.append(dict(command=' '.join(['pachs'] + words), instances=count,
                           run=run, process_wall_s=wall, summary=summary))
      print(json.dumps(commands[-1]), flush=True)
  result = {'provenance': common.provenance(), 'task': args.task, 'rows': rows,
             'commands': commands}
  common.write_result(args.out, result, markdown(result))


def test_suite() -> dict:
  """Process wall (s), pytest's summary line, exit status and failed tests of `python -m pytest`
  run from the repository root with an empty compilation cache (a new temporary folder, removed
  after)."""
  import shutil
  import tempfile
  root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
  cache = tempfile.mkdtemp(prefix='pachs_suite_cache_')
  began = time.perf_counter()
  try:
    done = subprocess.run([sys.executable, '-m', 'pytest'], cwd=root, capture_output=True,
                          text=True, env=dict(os.environ, PACHS_COMPILATION_CACHE=cache))
  finally:
    shutil.rmtree(cache, ignore_errors=True)
  wall = time.perf_counter() - began
  lines = [l.strip(' =') for l in done.stdout.splitlines() if l.strip()]
  failed = [l for l in lines if l.startswith(('FAILED ', 'ERROR '))]
  return {'command': 'python -m pytest', 'process_wall_s': wall,
          'summary': lines[-1] if lines else '', 'returncode': done.returncode, 'failed': failed}


def merge(paths: list, out: str):
  """One report of several runs of this benchmark (e.g. one instance count per device call):
  their rows and commands in order, the first file's provenance with the others' listed."""
  import common
  parts = []
  for path in paths:
    with open(path) as f:
      parts.append(json.load(f))
  result = {'provenance': common.merged_provenance(
      [dict(p['provenance'], file=os.path.basename(path)) for p, path in zip(parts, paths)],
      **parts[0]['provenance']),
            'task': parts[0]['task'],
            'rows': [row for p in parts for row in p['rows']],
            'commands': [c for p in parts for c in p['commands']]}
  common.write_result(out, result, markdown(result))


def markdown(result: dict) -> list:
  """The markdown lines of a result: its rows' phases and the real commands' process walls."""
  import common
  rows, commands = result['rows'], result['commands']
  phases = list(rows[0]['phases_s']) if rows else []
  table = [dict(instances=r['instances'], run=r['run'], process_wall_s=r['process_wall_s'],
                programs=r['programs_compiled'],
                cache_hits=r['persistent_cache_hits'], found=r['found'],
                **{p: r['phases_s'][p] for p in phases}) for r in rows]
  lines = common.markdown_header(f"Start-up of `pachs plan --task {result['task']}`",
                                 result['provenance'])
  if table:
    lines.append(common.markdown_table(table, list(table[0])))
  if commands:
    lines += ['', '## The real command (process wall, s)', '',
              common.markdown_table(commands, list(commands[0]))]
  return lines


# ---- profile: one command in this process, its phases

TIMES = collections.defaultdict(float)  # phase -> seconds (summed over its calls)
COUNTS = collections.Counter()


@contextlib.contextmanager
def profile_phase(name: str):
  began = time.perf_counter()
  try:
    yield
  finally:
    TIMES[name] += time.perf_counter() - began
    COUNTS[name] += 1


def add_to_phase(owner, attribute: str, name: str):
  """Wraps owner.attribute so that its calls add to phase `name`."""
  inner = getattr(owner, attribute)

  @functools.wraps(inner)
  def wrapper(*args, **kwargs):
    with profile_phase(name):
      return inner(*args, **kwargs)
  setattr(owner, attribute, wrapper)


def profile(argv) -> int:
  """Where the wall time of one `pachs plan` process goes, this process running it: imports,
  Warp's start and kernel module loads, the model, the env's physics, each search program
  (stored, JAX cache or compiled), the search itself and the output; one JSON line per run
  appended to --out."""
  parser = argparse.ArgumentParser(prog='bench_startup.py profile', description=profile.__doc__)
  parser.add_argument('--out', required=True, help='JSON file the phases are appended to')
  parser.add_argument('--label', default='', help='a name for this run in the JSON')
  parser.add_argument('--widen-backend', action='store_true',
                      help="let the CLI's --backend take every envs backend ('warp' too)")
  parser.add_argument('words', nargs='+', help="the `pachs` command's words, after '--'")
  args = parser.parse_args(argv)
  if args.widen_backend:
    add_argument = argparse._ActionsContainer.add_argument  # pylint: disable=protected-access

    def widened(self, *names, **kwargs):
      if names[:1] == ('--backend',) and 'choices' in kwargs:
        from pachs_jax.envs import backends
        kwargs['choices'] = list(backends.BACKENDS)
      return add_argument(self, *names, **kwargs)
    argparse._ActionsContainer.add_argument = widened  # pylint: disable=protected-access

  with profile_phase('import jax'):
    import jax
    jax.devices()
  with profile_phase('import mujoco, mjx (warp part)'):
    from pachs_jax.envs import warp_import
  warp_ok = warp_import.available()
  if warp_ok:
    with profile_phase('import warp, warp.init'):
      import warp
      warp.init()
    from warp._src import context as warp_context
    add_to_phase(warp_context.Module, 'load', 'warp module loads')
    add_to_phase(warp_context.Module, 'hash_module', 'warp module hashing (inside loads)')
  with profile_phase('import pachs_jax'):
    from pachs_jax import cli, planner
    from pachs_jax.runtime import compile_cache
    from pachs_jax.envs import backends
    from pachs_jax.sac import checkpoint
    from pachs_jax.runtime import programs
  add_to_phase(planner, 'load_model', 'load_model (env + physics + checkpoint)')
  physics = []
  inner_backend = backends.make_backend

  def make_backend(*a, **k):
    with profile_phase('make_backend (physics backend, put_model)'):
      env = inner_backend(*a, **k)
    physics.append(type(env).__name__)
    return env
  backends.make_backend = make_backend
  add_to_phase(checkpoint, 'load_actor_critic', 'checkpoint load')
  add_to_phase(planner, 'canonical_instances', 'canonical instances')
  add_to_phase(programs, 'check_model_outputs', 'model check (thread)')
  add_to_phase(programs, 'plan', 'programs.plan (programs + search)')
  stores = collections.Counter()
  inner_compiled = compile_cache.compiled_program

  def compiled_program(jitted, call_args, fingerprint, donate_argnums=(), prefetch=None):
    name = (fingerprint or '').rsplit(' ', 2)[-1] if fingerprint else 'unnamed'
    directory = jax.config.jax_compilation_cache_dir
    before = set(os.listdir(os.path.join(directory, compile_cache.TRACES))) if directory and \
        os.path.isdir(os.path.join(directory, compile_cache.TRACES)) else set()
    with profile_phase(f'program {name} (thread time)'):
      out = inner_compiled(jitted, call_args, fingerprint, donate_argnums, prefetch)
    after = set(os.listdir(os.path.join(directory, compile_cache.TRACES))) if directory and \
        os.path.isdir(os.path.join(directory, compile_cache.TRACES)) else set()
    new = sorted(after - before)
    stores[name] = ','.join(n.rsplit('.', 1)[-1] for n in new) or 'loaded or traced'
    return out
  compile_cache.compiled_program = compiled_program
  inner_compile = compile_cache._compile  # pylint: disable=protected-access

  def _compile(jitted, call_args):
    with profile_phase('trace+lower+XLA compile/JAX-cache load (not stored)'):
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
  with profile_phase('cli.main (all of the command)'):
    code = cli.main(args.words)
  builtins.print = real_print
  total = time.perf_counter() - T_START
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
  main()
