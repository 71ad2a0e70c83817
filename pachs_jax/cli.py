"""The `pachs` console command."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
import warnings

from pachs_jax import argtypes, flags
from pachs_jax.runtime import signals

# The command's flags are checked before JAX, MuJoCo or matplotlib load: the imports of
# pachs_jax modules that load them stand inside the functions that need them (start-up path).


def check_output_path(flag: str, path: str) -> None:
  """ValueError naming flag and path unless a file can be written at path: not a directory, its
  directory exists, and creating (or opening) the file works; a file created for the test is
  removed again."""
  where = f'{flag} {path}'
  if os.path.isdir(path):
    raise ValueError(f'{where}: is a directory, not a file')
  parent = os.path.dirname(os.path.abspath(path))
  if not os.path.isdir(parent):
    if os.path.exists(parent):
      raise ValueError(f'{where}: {parent} is not a directory')
    raise ValueError(f'{where}: the directory {parent} does not exist')
  existed = os.path.exists(path)
  try:
    os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o666))
  except OSError as err:
    raise ValueError(f'{where}: cannot write there ({err.strerror})') from None
  if not existed:
    os.remove(path)


def _check_image_path(flag: str, path: str) -> None:
  """ValueError unless matplotlib can save an image with path's extension (none: PNG)."""
  check_output_path(flag, path)
  ext = os.path.splitext(path)[1].lower().lstrip('.')
  if ext:
    from matplotlib.backend_bases import FigureCanvasBase  # start-up path: lazy
    formats = FigureCanvasBase.get_supported_filetypes()
    if ext not in formats:
      raise ValueError(f'{flag} {path}: cannot draw .{ext} images (use one of '
                       f'{", ".join(sorted(formats))})')


def _check_gif_path(flag: str, path: str) -> None:
  """ValueError unless path can be written and names a .gif file (animations are GIFs)."""
  check_output_path(flag, path)
  if os.path.splitext(path)[1].lower() != '.gif':
    raise ValueError(f'{flag} {path}: animations are written as GIF; name a .gif file')


def _write_outputs(prog: str, outputs) -> int:
  """Runs each (flag, path, write) in turn, also after one fails; a failure prints one line
  '{prog}: error: ...'. Returns 0, or 2 when any failed."""
  code = 0
  for flag, path, write in outputs:
    try:
      write()
    except (OSError, ValueError, RuntimeError) as err:
      detail = err.strerror if isinstance(err, OSError) and err.strerror else str(err)
      print(f'{prog}: error: {flag} {path}: {detail}', file=sys.stderr)
      code = 2
  return code


def _demo(args: argparse.Namespace) -> int:
  _check_image_path('--out', args.out)
  if args.gif:
    _check_gif_path('--gif', args.gif)
  from pachs_jax import demo  # start-up path: lazy (MuJoCo)
  summary = demo.run_demo(args.task, args.instance, args.out, args.steps, args.gif,
                          progress=True)
  print(json.dumps(summary, indent=1))
  return 0


class _TaskChoices:
  """--task / --env choices: `envs.TASKS` and any 'playground:NAME' (NAME is checked when the
  env is made); argparse's 'invalid choice' message lists them."""

  def __init__(self, tasks):
    self.tasks = tuple(tasks)

  def __contains__(self, text) -> bool:
    from pachs_jax import envs  # start-up path: lazy (JAX)
    return text in self.tasks or (envs.is_playground(text) and len(text) > len('playground:'))

  def __iter__(self):
    return iter(self.tasks + ('playground:NAME',))


def _devices_arg(text: str):
  """--devices: 'all' or a positive device count."""
  if text == 'all':
    return text
  try:
    return argtypes.positive_int(text)
  except argparse.ArgumentTypeError:
    raise argparse.ArgumentTypeError(f"must be 'all' or a positive integer, got {text!r}") from None


def _plan_devices(args: argparse.Namespace):
  """The devices to shard the instances over (None: one device, no sharding).

  'all': every device of the job (after joining a multi-host job when the environment describes
  one, see `sharding.initialize_multihost`); N > 1: the first N devices of this host.
  """
  if args.devices == 1:
    return None
  if args.time_limit is not None:
    raise ValueError('--time-limit (anytime mode) is not supported with sharding: use '
                     '--devices 1, or drop --time-limit to run every instance to completion')
  import jax  # start-up path: lazy

  from pachs_jax.runtime import sharding
  if args.devices == 'all':
    sharding.initialize_multihost()
    return jax.devices()
  local = jax.local_devices()
  if args.devices > len(local):
    raise ValueError(f'--devices {args.devices} exceeds the {len(local)} device(s) available '
                     f'on this host ({local[0].platform})')
  return local[:args.devices]


def _plan(args: argparse.Namespace, prefetch=None, guard=None) -> int:
  """`pachs plan`; prefetch: the command line's `compile_cache.Prefetch` (None: none); guard:
  the command's `signals.SignalGuard` (None: signals as Python handles them)."""

  # every output path first: nothing is planned for results that could not be written
  from pachs_jax import outputs  # start-up path: lazy (JAX)
  outputs.check_plan_outputs(args.task, {'--json': args.json, '--render': args.render,
                                         '--animate': args.animate})
  if args.json:
    check_output_path('--json', args.json)
  if args.render:
    _check_image_path('--render', args.render)
  if args.animate:
    check_output_path('--animate', args.animate)
  from pachs_jax.envs import registry  # start-up path: light (no physics, no JAX work)
  if args.instances not in (None, 'all') and args.task in registry.SPECS:  # before JAX's work
    argtypes.instance_indices(args.instances, registry.spec(args.task).num_instances)
  devices = _plan_devices(args)  # first: a multi-host job must be joined before other JAX calls

  import jax  # start-up path: lazy, after the outputs' checks

  from pachs_jax import planner
  from pachs_jax.runtime import programs, progress
  from pachs_jax.sac import checkpoint as checkpoint_lib

  say = _say if jax.process_index() == 0 else lambda *a, **k: None
  on_cpu = jax.default_backend() == 'cpu'
  if getattr(args, 'improve_allowance', None) is not None:  # before the model loads
    after_goal = args.after_goal or planner.default_config(args.task, args.algorithm).after_goal
    if after_goal != 'improve':
      raise ValueError(f'--improve-allowance applies with --after-goal improve; here the first '
                       f'goal ends the search (after_goal {after_goal!r})')
  with warnings.catch_warnings():  # (its physics note is said below, as a note)
    warnings.simplefilter('ignore', UserWarning)
    planning = planner.Planner(args.task, args.checkpoint, args.backend, args.budget,
                               cache=not args.no_cache, layout=args.layout, prefetch=prefetch,
                               algorithm=args.algorithm, **flags.search_overrides(args))
  env, config, num_available = planning.env, planning.config, planning.num_instances
  cpu = registry.cpu_planning(env.physics)
  few = args.instances is None and on_cpu and cpu.instances != 'all' and num_available > 1
  if args.instances is None:
    args.instances = cpu.instances if on_cpu else 'all'
  if args.instances == 'all':
    args.instances = f'0-{num_available - 1}'
  instances = argtypes.instance_indices(args.instances, num_available)
  shown = outputs.check_show_instance(args.show_instance, instances)
  if on_cpu:
    physics = {'mujoco-c': 'MuJoCo C on all CPU threads',
               'warp': 'MuJoCo Warp on the CPU (slow: its kernels are made for CUDA GPUs; '
                       '--backend auto picks MuJoCo C here)'}.get(
                           env.physics, 'MJX on the CPU (slow: milliseconds per world and step)')
    gpu = planner.command_config(args.task, False, False)
    say(f'note: JAX has no accelerator here; edges are simulated by {physics}. A GPU plans '
        f'{num_available} instances x {gpu.budget:,} evaluations in seconds: pip '
        'install -e .[cuda]', file=sys.stderr, flush=True)
  if planning.physics_note is not None:
    say(f'note: {planning.physics_note}', file=sys.stderr, flush=True)
  if few:
    say(f'note: on this CPU (MJX physics) only instance {args.instances} of 0-'
        f'{num_available - 1} is planned; --instances 0-{num_available - 1} (or all) plans '
        'more', file=sys.stderr, flush=True)
  if devices is None:  # the memory the search needs, before the 'planning' line
    programs.check_memory(env, planning.model, planning.canonical(instances), config,
                          planning.search.search)
  model_path = args.checkpoint or planner.checkpoint_path(args.task)
  where = jax.devices()[0].platform
  if devices is not None:
    where = f'{len(devices)} {where} device(s), instances sharded'
  say(f'planning {env.name} instances {args.instances} with {model_path}: '
      f'w={config.weight} N={config.num_actions} K={config.pop_size} H={config.edge_steps} '
      f'R={config.rollout_lanes} '
      f'budget={config.budget} '
      f'on {where}', flush=True)
  start = time.perf_counter()
  last_s = prefetch.last_ready_s() if prefetch is not None else None
  say('note: compiling (or loading from the cache) the search programs'
      + (f' (ready after {last_s:.1f} s last time)' if last_s is not None else ''),
      file=sys.stderr, flush=True)

  def started():
    ready_s = time.perf_counter() - start
    if prefetch is not None:
      prefetch.ready_s = ready_s
    say(f'note: programs ready after {ready_s:.1f} s; searching', file=sys.stderr,
        flush=True)
    if guard is not None:  # once the search runs, a first signal stops it at its next
      guard.keep()         # chunk and the command keeps what it found

  if devices is None:
    line = progress.ProgressLine()
    try:
      # one-shot (shrink=False): the whole search in the loop of the live instances' physics
      # size, no further loop to compile or load (docs/startup_and_caching.md)
      result = planning.plan(instances, seed=args.seed, time_limit_s=args.time_limit,
                             stop=guard and guard.stop, started=started, shrink=False,
                             progress=line if jax.process_index() == 0 else None)
    finally:
      line.close()
  elif jax.process_count() == 1:  # sharded on one host: stopped at its next chunk as well
    result = planning.plan(instances, seed=args.seed, devices=devices, started=started,
                           stop=guard and guard.stop)
  else:  # across hosts the search runs in one call, and a signal ends the job
    if guard is not None:
      guard.phase = 'the multi-host search (it keeps no partial results)'
    result = planning.plan(instances, seed=args.seed, devices=devices)
  total = time.perf_counter() - start
  rows = planner.result_rows(result, instances)
  if jax.process_index() != 0:
    return 0  # every host got the whole result; the first one reports it
  print(planner.format_table(rows, ['instance', 'found', 'cost', 'path_length', 'expanded',
                                    'evaluated', 'stop', 'overflow']))
  found = sum(r['found'] for r in rows)
  print(f'found {found}/{len(rows)}; search time {float(result.wall_time_s):.2f} s '
        f'(all instances in one call, compile excluded); {total:.1f} s with compilation')
  interrupted = sum(r['stop'] == 'interrupted' for r in rows)
  if interrupted:
    improving = sum(r['stop'] == 'interrupted' and r['found'] for r in rows)
    detail = (f'; {improving} had found a goal and answer with the cheapest one, their '
              'improvement cut short' if improving else '')
    print(f'interrupted: {interrupted} of {len(rows)} instances stopped early (stop '
          f'\'interrupted\', each with the path to its best state so far{detail})', flush=True)
  # the JSON first (a failed drawing loses no result), each output on its own
  writes = []
  if args.json:
    saved = {'task': args.task, 'layout': getattr(env, 'layout', None) and env.layout.name,
             'physics': env.physics, 'physics_settings': env.physics_settings,
             'model': {'path': model_path,
                       'params_sha256': checkpoint_lib.params_sha256(model_path)},
             'config': dataclasses.asdict(config), 'rows': rows,
             'devices': 1 if devices is None else len(devices),
             'search_time_s': float(result.wall_time_s), 'interrupted': bool(interrupted)}

    def write_json():
      outputs.write_json(args.json, outputs.json_document(saved, result, instances,
                                                          env.physics, env.physics_settings))
      print(f'wrote the rows and each instance\'s plan to {args.json}')
    writes.append(('--json', args.json, write_json))
  if args.render:
    def draw():
      path = outputs.write_still(args.render, env, result, instances, shown)
      print(f'drew instance {shown} to {path}')
    writes.append(('--render', args.render, draw))
  if args.animate:
    def animate():
      path, note = outputs.write_animation(args.animate, env, result, instances, shown)
      print(f'animated instance {shown} to {path}' + (f' ({note})' if note else ''))
    writes.append(('--animate', args.animate, animate))
  code = _write_outputs('pachs plan', writes)
  return code or (guard.exit_code if guard is not None else 0)


def _loop(args: argparse.Namespace, guard=None) -> int:
  """`pachs loop`: episodes of canonical instances in MuJoCo C worlds, planned through a
  replanning session (`episodes.run`); a table per episode, then --json and --video. guard: the
  command's `signals.SignalGuard` (None: signals as Python handles them): once the episodes
  run, a first signal ends them before the next query and what ran is written."""
  from pachs_jax import outputs  # start-up path: lazy (JAX)
  if args.json:
    check_output_path('--json', args.json)
  if args.video:
    _check_gif_path('--video', args.video)
  outputs.check_distinct({'--json': args.json, '--video': args.video})
  from pachs_jax import envs, episodes, planner, replan
  num_available = envs.spec(args.task).num_instances
  instances = argtypes.instance_indices(args.instances, num_available)
  shown = outputs.check_show_instance(args.show_instance, instances)
  with warnings.catch_warnings():  # (its physics note is said below, as a note)
    warnings.simplefilter('ignore', UserWarning)
    planning = planner.Planner(args.task, args.checkpoint, args.backend, args.budget,
                               cache=not args.no_cache, layout=args.layout,
                               pop_size=args.pop_size)
  if planning.physics_note is not None:
    print(f'note: {planning.physics_note}', file=sys.stderr, flush=True)
  if args.fill_check is None:  # the task's for the query time (`Planner.replan_fill_check`)
    args.fill_check = int(planning.replan_fill_check(args.query_time))
  env, session = planning.env, planning.session(
      query_time_s=args.query_time, fill_steps=args.execute if args.fill_check else 0)
  config = session.config
  worlds = episodes.Worlds(env, planning.canonical(instances))
  print(f'closed loop: {env.name} instances {args.instances} in MuJoCo C worlds, planned with '
        f'{env.physics} physics: {args.query_time:g} s per query, {args.execute} actions '
        f'executed, at most {args.max_queries} queries, budget {config.budget}, '
        f'K {config.pop_size}, the policy\'s fill {"" if args.fill_check else "not "}checked',
        flush=True)
  import jax  # pylint: disable=import-outside-toplevel
  stop = None
  if guard is not None:
    guard.notice = 'stopping before the next query; a second signal exits at once'
    stop = guard.keep()

  def said(query, nodes, running, executed, answer, seconds):  # a line per query (stderr)
    print(f'query {query}: answered {int(running.sum())} running episodes in {seconds:.2f} s',
          file=sys.stderr, flush=True)

  log = episodes.run(session, worlds, args.query_time, args.execute,
                     args.max_queries, jax.random.PRNGKey(args.seed), stop=stop,
                     on_answer=said)
  names = replan.AnswerKind.NAMES
  rows = [dict({'instance': int(inst), 'success': bool(worlds.success[e]),
                'failed': bool(worlds.failed[e]),
                'steps': int(worlds.steps[e]), 'queries': int(log.queries[e]),
                'policy_steps': int(log.policy_steps[e]), 'cut_fills': int(log.cut_fills[e])},
               **{name: int(log.answers[e, k]) for k, name in enumerate(names)})
          for e, inst in enumerate(instances)]
  print(planner.format_table(rows, ['instance', 'success', 'failed', 'steps', 'queries']
                             + list(names) + ['policy_steps', 'cut_fills']))
  print(f'reached the goal in {int(worlds.success.sum())}/{len(rows)} episodes'
        + ('' if log.interrupted_at_query is None else
           f' (interrupted before query {log.interrupted_at_query}: the episodes end there)'))
  if log.fill_wait_s:  # (the fill's follow after each answer, while its own actions ran)
    waited = 1e3 * sum(log.fill_wait_s) / len(log.fill_wait_s)
    print(f'the checked fill took {waited:.0f} ms a query after the answer, '
          f'{1e3 * sum(log.charged_s):.0f} ms of it charged to the next queries\' clocks')
  writes = []
  if args.json:
    document = {'task': args.task, 'layout': getattr(env, 'layout', None) and env.layout.name,
                'physics': env.physics, 'world': 'mujoco-c',
                'config': dataclasses.asdict(config),
                'settings': {'query_time_s': args.query_time, 'execute': args.execute,
                             'max_queries': args.max_queries, 'fill_check': args.fill_check,
                             'seed': args.seed},
                'rows': rows, 'interrupted_at_query': log.interrupted_at_query,
                'queries': {'clock_s': log.clock_s, 'fill_wait_s': log.fill_wait_s,
                            'charged_s': log.charged_s}}

    def write_json():
      outputs.write_json(args.json, document)
      print(f'wrote the episodes to {args.json}')
    writes.append(('--json', args.json, write_json))
  if args.video:
    def video():
      e = list(instances).index(shown)
      outcome = 'reached the goal' if worlds.success[e] else 'no goal'
      frames = episodes.video_frames(worlds, log, e, f'{env.name} instance {shown}, closed '
                                     f'loop: {outcome}')
      outputs.write_gif(args.video, env, frames, int(worlds.steps[e]) + 1)
      print(f'wrote the world of instance {shown} to {args.video}')
    writes.append(('--video', args.video, video))
  return _write_outputs('pachs loop', writes) or (guard.exit_code if guard is not None else 0)


def _check_listen(host: str, port: int) -> None:
  """ValueError naming --host or --port unless a socket can listen there now (the port is
  given back at once; 0 picks any free one)."""
  import socket  # pylint: disable=import-outside-toplevel
  if not 0 <= port < 65536:
    raise ValueError(f'--port {port}: must be in 0..65535')
  try:
    family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
  except OSError as err:
    raise ValueError(f'--host {host}: not an address of this machine ({err})') from None
  with socket.socket(family, kind, proto) as probe:
    probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
      probe.bind(address)
    except OSError as err:
      raise ValueError(f'--host {host} --port {port}: cannot listen there ({err})') from None


def _serve(args: argparse.Namespace) -> int:
  """`pachs serve`: loads and warms the tasks' planners, then answers planning requests over a
  websocket until SIGTERM or SIGINT (docs/serving.md)."""
  _check_listen(args.host, args.port)  # before the minutes of loading and warming
  from pachs_jax import planner, serve  # start-up path: lazy (JAX)
  buckets = None
  if args.buckets is not None:
    try:
      buckets = tuple(int(b) for b in args.buckets.split(','))
    except ValueError:
      raise ValueError(f'--buckets {args.buckets!r}: comma-separated powers of two, the largest '
                       '>= --max-batch') from None
  config = serve.ServeConfig(window_s=args.window_ms / 1000, max_batch=args.max_batch,
                             max_wait_s=None if args.max_wait_ms is None
                             else args.max_wait_ms / 1000,
                             max_queue=args.max_queue, max_time_limit_s=args.max_time_limit,
                             devices=args.devices, split=args.split, buckets=buckets,
                             fill_steps=args.fill_steps)
  import jax  # pylint: disable=import-outside-toplevel
  if args.devices > jax.device_count():  # before any model loads
    raise ValueError(f'--devices {args.devices}: this host has {jax.device_count()} '
                     f'{jax.default_backend()} device(s)')
  tasks = list(dict.fromkeys(args.task or ['pusht-obs']))
  if args.layout is not None and 'pusht-obs' not in tasks:
    raise ValueError(f'--layout applies to --task pusht-obs, not {", ".join(tasks)}')
  planners = {}
  for task in tasks:
    _say(f'pachs serve: loading {task}', file=sys.stderr)
    overrides = flags.search_overrides(args)
    if overrides.get('pop_size') is None:  # K for the clients' query time, as Planner.session
      overrides['pop_size'] = planner.replan_pop_size(task, args.query_time, args.backend)
    planners[task] = planner.Planner(task, backend=args.backend, budget=args.budget,
                                     cache=not args.no_cache,
                                     layout=args.layout if task == 'pusht-obs' else None,
                                     **overrides)
  server = serve.Server(planners, config)
  server.warm(lambda text: _say(f'pachs serve: {text}', file=sys.stderr), every=args.warm_all)
  return serve.serve_forever(server, args.host, args.port, lambda url: _say(
      f'pachs serve: ready on {url} '
      f'({", ".join(f"{t} K {planners[t].config.pop_size}" for t in tasks)}; '
      f'batches of up to {args.max_batch} '
      f'episodes gathered for {args.window_ms:g} ms)'))


def main(argv=None) -> int:
  """Parses argv (None: sys.argv) and runs `pachs demo` or `pachs plan`; returns the exit code.

  SIGINT or SIGTERM (in the main thread): during start-up one line and 128 + the signal's
  number; during `pachs plan`'s search the first one stops it at its next chunk and the
  command writes what it has (the unfinished instances marked 'interrupted'), a second one
  exits at once.
  """
  words = sys.argv[1:] if argv is None else list(argv)
  # a one-shot command: GPU memory taken as needed, not 75% of the card up front (which takes
  # seconds on a large GPU; docs/startup_and_caching.md); read when JAX starts its backend
  os.environ.setdefault('XLA_PYTHON_CLIENT_PREALLOCATE', 'false')
  skip_glfw_probe(os.environ)
  command = (f'pachs {words[0]}' if words[:1] in (['plan'], ['demo'], ['loop'], ['serve'])
             else 'pachs')
  with signals.SignalGuard(command) as guard:
    try:
      return _main_prefetching(words, guard)
    except (signals.Interrupted, ImportError) as err:  # (an import the signal broke)
      interrupted = signals.interrupted_by(err)
      if interrupted is None:
        raise
      name = guard.phase or ('start-up' if words[:1] == ['plan'] else 'the command')
      print(f'{command}: {signal_name(interrupted.signum)}: stopped during {name}; nothing '
            'written', file=sys.stderr, flush=True)
      return interrupted.exit_code


def skip_glfw_probe(environ) -> None:
  """Names pyglfw's bundled GLFW library (Linux: its x11 build, or wayland where the session or
  PYGLFW_LIBRARY_VARIANT says so) in environ['PYGLFW_LIBRARY'], unless that is set or the
  library is missing. `import mujoco` imports glfw, which otherwise starts a Python subprocess
  to read each candidate library's version: a process start per command, and a traceback of
  that process (a broken pipe) when a signal ends the command meanwhile."""
  if environ.get('PYGLFW_LIBRARY'):
    return
  import importlib.util  # start-up path: only here
  spec = importlib.util.find_spec('glfw')
  if spec is None or not spec.submodule_search_locations:
    return
  variant = environ.get('PYGLFW_LIBRARY_VARIANT', '').lower()
  if variant not in ('x11', 'wayland'):
    variant = 'wayland' if environ.get('XDG_SESSION_TYPE') == 'wayland' else 'x11'
  library = os.path.join(list(spec.submodule_search_locations)[0], variant, 'libglfw.so')
  if sys.platform.startswith('linux') and os.path.isfile(library):
    environ['PYGLFW_LIBRARY'] = library


def _say(text: str, file=None, flush: bool = True) -> None:
  """Prints text and its newline in one write (a signal's message never lands mid-line)."""
  file = sys.stdout if file is None else file
  file.write(f'{text}\n')
  if flush:
    file.flush()


def signal_name(signum: int) -> str:
  """'SIGINT' for 2."""
  return signals.signal.Signals(signum).name


def _main_prefetching(words, guard) -> int:
  # `pachs plan`: the executables this command used last time load beside the imports and model
  # load (not with --no-cache, nor where --devices may join a multi-host job first)
  if words[:1] == ['plan'] and not any(w.startswith(('--no-cache', '--devices')) for w in words):
    from pachs_jax.runtime import compile_cache  # start-up path: lazy (JAX)
    with compile_cache.prefetching(words) as prefetch:
      return _main(words, prefetch, guard)
  return _main(words, guard=guard)


def run() -> None:
  """The `pachs` console command: `main()`, then the process ends at once (output flushed),
  skipping the interpreter's and JAX's teardown (measured in docs/startup_and_caching.md); a
  multi-process JAX job ends normally."""
  code = main()
  jax = sys.modules.get('jax')
  if jax is not None and jax.process_count() > 1:
    sys.exit(code)
  sys.stdout.flush()
  sys.stderr.flush()
  os._exit(code)


def _main(words, prefetch=None, guard=None) -> int:
  if any(w == '--gif' or w.startswith('--gif=') for w in words):
    # MuJoCo picks its OpenGL backend on import; only a GIF needs one (a machine without EGL
    # fails to import mujoco when MUJOCO_GL=egl is set).
    os.environ.setdefault('MUJOCO_GL', 'egl')
  if words[:1] == ['loop'] and any(w.split('=')[-1].startswith('playground:') for w in words) \
      and any(w.startswith('--video') for w in words):
    os.environ.setdefault('MUJOCO_GL', 'egl')  # a Playground task's video: MuJoCo's renderer
  from pachs_jax import envs  # start-up path: lazy, after MUJOCO_GL is chosen
  from pachs_jax.envs import layouts, registry
  pusht_tasks = [t for t in envs.TASKS if t.startswith('pusht')]
  parser = argtypes.OneLineParser(prog='pachs', description='PACHS in JAX')
  sub = parser.add_subparsers(dest='command', required=True)
  demo = sub.add_parser('demo', help='scripted PushT rollout through the MJX task, drawn to PNG')
  demo.add_argument('--task', default='pusht-obs', choices=pusht_tasks)
  demo.add_argument('--instance', type=int, default=0, help='index into the canonical set')
  demo.add_argument('--steps', type=argtypes.positive_int, default=300,
                    help='control steps (20 Hz), at most 2000')
  demo.add_argument('--out', default='demo.png', type=argtypes.path('a file'))
  demo.add_argument('--gif', default=None, type=argtypes.path('a file'),
                    help='also render a MuJoCo GIF (needs OpenGL)')
  demo.set_defaults(func=_demo)
  plan = sub.add_parser('plan', help='plan with the shipped model of a task (PACHS)')
  plan.add_argument('--task', '--env', dest='task', default='pusht-obs',
                    choices=_TaskChoices(envs.TASKS), metavar='TASK',
                    help=f'{", ".join(envs.TASKS)} (default pusht-obs), or '
                    'playground:NAME: a MuJoCo Playground env (pip install -e .[playground]; '
                    'models shipped for playground:ReacherEasy and ReacherHard, others need '
                    '--checkpoint)')
  plan.add_argument('--layout', default=None, choices=layouts.NAMES,
                    help=f'pusht-obs only: the obstacle layout (default: {layouts.DEFAULT})')
  plan.add_argument('--instances', default=None,
                    help="canonical instances, e.g. '0-29', '0,4' or 'all' (default: all; "
                         "on a CPU with MJX physics, '0')")
  gpu_budgets = ', '.join(f'{name} {spec.search_defaults["budget"]}'
                          for name, spec in registry.SPECS.items())
  cpu = registry.CPU_PLANNING
  plan.add_argument('--budget', type=int, default=None,
                    help=f"edge evaluations per instance (default: the task's, on a GPU "
                         f"{gpu_budgets}; on a CPU {cpu['mujoco-c'].budget} with MuJoCo C "
                         f"physics, {cpu['other'].budget} with MJX)")
  plan.add_argument('--seed', type=argtypes.seed, default=0, help='PRNG seed (64-bit integer)')
  flags.add_search_flags(plan, ['weight', 'num_actions'])
  plan.add_argument('--algorithm', default='pachs', choices=registry.ALGORITHMS,
                    help="pachs (default: edges that follow the actor for edge_steps "
                    "transitions) or original (the published one-step edges, its settings)")
  flags.add_search_flags(plan, ['edge_steps', 'rollout_share', 'chain_restart', 'pop_size',
                               'uniform_share', 'lattice_resolution'])
  plan.add_argument('--time-limit', type=argtypes.positive_float, default=None,
                    help='anytime mode: wall-clock seconds, then the path to the best state')
  flags.add_search_flags(plan, ['compact_fractions', 'realtime_answer', 'after_goal',
                               'improve_allowance'])
  plan.add_argument('--devices', type=_devices_arg, default=1,
                    help="devices to shard the instances over: 1 (default, no sharding), N "
                         "(the first N of this host) or 'all' (every device; across hosts "
                         "when JAX_COORDINATOR_ADDRESS, SLURM or mpirun describe a job)")
  plan.add_argument('--checkpoint', default=None, type=argtypes.path('a model directory'),
                    help='another actor-critic directory')
  plan.add_argument('--backend', default='auto', choices=registry.BACKENDS,
                    help='physics of PushT edges: auto = MuJoCo C when JAX has no accelerator '
                    '(Playground tasks: MJX only)')
  plan.add_argument('--render', default=None, type=argtypes.path('a file'),
                    help='draw one instance\'s plan (PNG; the extension names the format)')
  plan.add_argument('--animate', default=None, type=argtypes.path('a file'),
                    help='write a GIF of one instance\'s plan executing (PushT, shelf)')
  plan.add_argument('--show-instance', '--animate-instance', dest='show_instance', type=int,
                    default=None, help='the instance --render and --animate show (default: '
                    'the first planned)')
  plan.add_argument('--json', default=None, type=argtypes.path('a file'),
                    help='write the result rows, each with its '
                    'instance\'s plan (actions, states; pachs_jax.saved_plans.from_json), as JSON')
  plan.add_argument('--no-cache', action='store_true',
                    help='no persistent compilation cache (default: on, in ~/.cache/pachs_jax; '
                         'PACHS_COMPILATION_CACHE=DIR or =0 also sets it)')
  plan.set_defaults(func=_plan)
  loop = sub.add_parser('loop', help='closed loop: plan, execute the first actions in a MuJoCo C '
                        'world, observe, plan again (PushT, Playground tasks)')
  loop.add_argument('--task', '--env', dest='task', default='pusht-obs',
                    choices=_TaskChoices(pusht_tasks), metavar='TASK',
                    help=f'{", ".join(pusht_tasks)} (default pusht-obs), or playground:NAME '
                    '(its world: its MuJoCo model in MuJoCo C, its own step around it)')
  loop.add_argument('--layout', default=None, choices=layouts.NAMES,
                    help=f'pusht-obs only: the obstacle layout (default: {layouts.DEFAULT})')
  loop.add_argument('--instances', default='0', help="canonical instances, e.g. '0-3' or '0,4' "
                    "(default: 0); each an episode")
  loop.add_argument('--query-time', type=argtypes.positive_float, default=3.0,
                    help='wall-clock seconds per query, for all episodes together (default '
                    "3); on a GPU it also chooses K, the task's for that query time, unless -K "
                    'is given')
  loop.add_argument('--execute', type=argtypes.positive_int, default=10,
                    help='actions of each answer executed before the next query (default 10)')
  loop.add_argument('--max-queries', type=argtypes.positive_int, default=30,
                    help='queries per episode (default 30)')
  loop.add_argument('--fill-check', type=int, default=None, choices=[0, 1],
                    help="1: a short answer's policy fill stops before the first edge the "
                    "planner's physics finds invalid (a T tipped over), the next query sooner; "
                    '0: the policy fills up to --execute actions (default: 1; on a GPU from '
                    "the task's query time on, pusht-obs's 2 s)")
  loop.add_argument('--budget', type=argtypes.positive_int, default=None,
                    help="edge evaluations per query and episode (default: the task's)")
  loop.add_argument('--seed', type=argtypes.seed, default=0, help='PRNG seed (64-bit integer)')
  flags.add_search_flags(loop, ['pop_size'])
  loop.add_argument('--backend', default='auto', choices=registry.BACKENDS,
                    help="the planner's physics (the world is MuJoCo C)")
  loop.add_argument('--checkpoint', default=None, type=argtypes.path('a model directory'),
                    help='another actor-critic directory')
  loop.add_argument('--json', default=None, type=argtypes.path('a file'),
                    help='write the per-episode rows and settings as JSON')
  loop.add_argument('--video', default=None, type=argtypes.path('a file'),
                    help="write a GIF of one episode's world, the plan being executed drawn "
                    'dashed (Playground tasks: rendered by MuJoCo, OpenGL)')
  loop.add_argument('--show-instance', type=int, default=None,
                    help='the instance --video shows (default: the first)')
  loop.add_argument('--no-cache', action='store_true',
                    help='no persistent compilation cache')
  loop.set_defaults(func=_loop)
  served = sub.add_parser('serve', help='a resident planner: answer planning requests over a '
                          'websocket, batching clients together (docs/serving.md)')
  served.add_argument('--task', action='append', default=None,
                      choices=_TaskChoices(envs.TASKS), metavar='TASK',
                      help='a task to serve (repeatable; default pusht-obs)')
  served.add_argument('--layout', default=None, choices=layouts.NAMES,
                      help=f'pusht-obs\'s obstacle layout (default: {layouts.DEFAULT})')
  served.add_argument('--backend', default='auto', choices=registry.BACKENDS,
                      help='physics of PushT edges (auto: MuJoCo C when JAX has no accelerator)')
  served.add_argument('--budget', type=argtypes.positive_int, default=None,
                      help="edge evaluations per episode and request (default: the task's, as "
                      'pachs plan)')
  served.add_argument('--host', default='127.0.0.1',
                      help='the address to listen on (default 127.0.0.1: this machine only)')
  served.add_argument('--port', type=int, default=8000, help='the port (0: any free one)')
  served.add_argument('--window-ms', type=argtypes.positive_float, default=5.0,
                      help='how long requests are gathered into one search (default 5 ms)')
  served.add_argument('--max-wait-ms', type=argtypes.positive_float, default=None,
                      help='the window restarts at each request that arrives, up to this long '
                      'after the first (default: it does not)')
  served.add_argument('--max-batch', type=argtypes.positive_int, default=16,
                      help='the most episodes in one search call and request (default 16)')
  served.add_argument('--max-queue', type=argtypes.positive_int, default=64,
                      help='requests waiting before one more is answered busy (default 64)')
  served.add_argument('--max-time-limit', type=argtypes.positive_float, default=60.0,
                      help='the largest time_limit_s a request may ask (default 60 s)')
  served.add_argument('--devices', type=argtypes.positive_int, default=1,
                      help="the host's first N devices share each batch's search (default 1)")
  flags.add_search_flags(served, ['pop_size'])
  served.add_argument('--query-time', type=argtypes.positive_float, default=None,
                      help="the seconds the clients' queries mostly last: on a GPU it chooses "
                      "K as `pachs loop --query-time` does (default: the task's K)")
  served.add_argument('--fill-steps', type=argtypes.integer(0), default=0,
                      help="the actions each client executes per query, where it fills a short "
                      "answer with the policy's: the server follows that fill in its physics "
                      'and answers how far it holds (fill_length; default 0: none)')
  served.add_argument('--split', choices=('mesh', 'threads'), default='mesh',
                      help='how --devices share a batch: one search sharded over them (mesh, '
                      'the default) or a part per device, each searched from its own thread')
  served.add_argument('--buckets', default=None,
                      help='the batch sizes a batch is padded to (each compiled once): '
                      'comma-separated powers of two (default: every power of two up to '
                      "--max-batch's on a CPU, the powers of four and it on an accelerator; "
                      'fewer: a shorter start, longer searches of small batches)')
  served.add_argument('--warm-all', action='store_true',
                      help='warm every bucket before answering (default: the largest, which '
                      'holds any batch, then the others, each after 2 s without a request)')
  served.add_argument('--no-cache', action='store_true',
                      help='no persistent compilation cache')
  served.set_defaults(func=_serve)
  args = parser.parse_args(words)
  if args.command == 'serve' and not 0 <= args.port < 65536:
    served.error(f'--port must be in 0..65535, got {args.port}')
  num_instances = envs.spec(args.task if args.command != 'serve' else 'pusht-obs').num_instances
  if args.command == 'demo' and not 0 <= args.instance < num_instances:
    demo.error(f'--instance must be in 0..{num_instances - 1}, got {args.instance}')
  if args.command in ('plan', 'loop') and args.layout is not None and args.task != 'pusht-obs':
    parser.exit(2, f'pachs {args.command}: error: --layout applies to --task pusht-obs only, '
                f'not {args.task!r} (see --help)\n')
  try:
    if args.command == 'plan':
      return args.func(args, prefetch, guard)
    return args.func(args, guard) if args.command == 'loop' else args.func(args)
  except (ValueError, OSError, ImportError) as err:  # one line, no traceback
    if guard is not None and guard.early is not None:  # a library turned the signal's
      raise signals.Interrupted(guard.early) from err  # Interrupted into an error of its own
    message = ' '.join(str(err).split()) if not isinstance(err, OSError) or not err.strerror \
        else f'{err.strerror}: {err.filename}' if err.filename else err.strerror
    parser.exit(2, f'pachs {args.command}: error: {message}\n')


if __name__ == '__main__':
  run()
