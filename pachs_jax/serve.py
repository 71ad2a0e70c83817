"""A resident planner: `pachs serve` keeps tasks' planners warm and answers planning requests
over a websocket (msgpack with NumPy arrays, `wire`), planning the requests that arrive together
in one search call on the instance axis and keeping each client's last answer between its
requests (docs/serving.md)."""

from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import contextlib
import dataclasses
import functools
import math
import queue
import signal
import threading
import time
import uuid
from typing import Callable, Dict, List, Mapping, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from pachs_jax import planner as planner_lib
from pachs_jax import replan, wire
from pachs_jax.runtime import programs, sharding

# a request's `executed` for an episode that did something else than its last answer
DIVERGED = replan.DIVERGED

REQUEST_TYPES = ('plan', 'health', 'reset')

# how several devices share a batch (`ServeConfig.split`)
SPLITS = ('mesh', 'threads')

# the `SearchResult` fields [E] an answer carries in its 'search' map
SEARCH_FIELDS = ('path_length', 'found', 'stop_reason', 'expanded', 'generated', 'invalid',
                 'iterations')


@dataclasses.dataclass(frozen=True)
class ServeConfig:
  """How the server gathers, bounds and keeps requests.

  window_s: after a request arrives, how long (s) the server waits for others to plan with it.
  max_wait_s: None, or the window restarts at each request of the batch's task that arrives,
    up to this long (s) after the gathering began: a burst of requests (clients answered
    together that ask again) is gathered whole.
  max_batch: the most episodes in one search call (and in one request).
  max_queue: the most requests waiting or being planned; one more is answered busy at once.
  max_time_limit_s: the largest time_limit_s a request may ask.
  max_sessions: client sessions kept (the least recently used are forgotten beyond it).
  buckets: the padded batch sizes, powers of two whose largest holds max_batch (None: every
    power of two up to max_batch's on a CPU, where padded episodes cost their physics; on an
    accelerator the powers of four and max_batch's power of two, fewer programs to warm: there
    a padded episode costs less, but not nothing (one episode alone, padded to 256, searched
    for 2.2 s where 30 took 3.3 s, on an H200 at 10,000 evaluations)). A batch is padded on
    the host to the smallest warm bucket that holds it, so a warm server compiles nothing.
  warm_time_s: the time limit of each warm-up query (s).
  warm_idle_s: the buckets `Server.warm` left cold (`every=False`: the largest alone, which
    holds every batch) are warmed by the planning thread one at a time, each after this many
    seconds without a request (None: never); a request that arrives during one waits for it,
    so a client that asks at shorter intervals (a robot's control loop) is never held up.
  devices: the first this many of `jax.devices()` share each batch's search, its episodes split
    over them (1: one device, with lane compaction).
  split: how several devices share a batch: 'mesh', one search sharded over them
    (`sharding.ShardedSearch`: the devices in lockstep, every lane simulated), or 'threads',
    the batch cut into an even part per device (each padded to bucket / devices episodes,
    rounded up),
    each searched by its own one-device session (lane compaction) from its own host thread,
    all at once.
  fill_steps: the actions a client executes per query: where an answer is shorter, the policy's
    fill up to fill_steps in all is followed from its end in the planner's physics and the
    answer says how many of its actions hold before an invalid edge (`fill_length`,
    `replan.Session.fill_steps`); 0: no fill followed.
  """

  window_s: float = 0.005
  max_wait_s: Optional[float] = None
  max_batch: int = 16
  max_queue: int = 64
  max_time_limit_s: float = 60.0
  max_sessions: int = 4096
  buckets: Optional[Tuple[int, ...]] = None
  warm_time_s: float = 0.05
  warm_idle_s: Optional[float] = 2.0
  devices: int = 1
  split: str = 'mesh'
  fill_steps: int = 0

  def __post_init__(self):
    for name in ('max_batch', 'max_queue', 'max_sessions', 'devices'):
      value = getattr(self, name)
      if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f'{name} must be a positive int, got {value!r}')
    if self.warm_idle_s is not None and (
        isinstance(self.warm_idle_s, bool) or not isinstance(self.warm_idle_s, (int, float))
        or not math.isfinite(self.warm_idle_s) or self.warm_idle_s < 0):
      raise ValueError(f'warm_idle_s must be a finite number of seconds >= 0 or None, got '
                       f'{self.warm_idle_s!r}')
    for name in ('window_s', 'max_time_limit_s', 'warm_time_s'):
      value = getattr(self, name)
      if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0 or (
          name != 'window_s' and value == 0):
        raise ValueError(f'{name} must be a finite number of seconds '
                         f'{">= 0" if name == "window_s" else "> 0"}, got {value!r}')
    if self.max_wait_s is not None and (
        isinstance(self.max_wait_s, bool) or not isinstance(self.max_wait_s, (int, float))
        or not math.isfinite(self.max_wait_s) or self.max_wait_s < self.window_s):
      raise ValueError(f'max_wait_s must be None or a finite number of seconds >= window_s '
                       f'{self.window_s}, got {self.max_wait_s!r}')
    if (isinstance(self.fill_steps, bool) or not isinstance(self.fill_steps, int)
        or self.fill_steps < 0):
      raise ValueError(f'fill_steps must be an int >= 0 (0: no fill followed), got '
                       f'{self.fill_steps!r}')
    if self.split not in SPLITS:
      raise ValueError(f'split must be one of {", ".join(SPLITS)}, got {self.split!r}')
    if self.buckets is not None:
      sizes = tuple(self.buckets)
      if (not sizes or any(isinstance(b, bool) or not isinstance(b, int) or b < 1
                           or b & (b - 1) for b in sizes) or max(sizes) < self.max_batch):
        raise ValueError(f'buckets must be powers of two, the largest >= max_batch '
                         f'{self.max_batch}, got {self.buckets!r}')

  def bucket_sizes(self, on_cpu: bool) -> Tuple[int, ...]:
    """The padded batch sizes, ascending."""
    if self.buckets is not None:
      return tuple(sorted(set(self.buckets)))
    top = 1 << (self.max_batch - 1).bit_length()
    step = 1 if on_cpu else 2
    return tuple(sorted({1 << k for k in range(0, top.bit_length(), step)} | {top}))


class RequestError(ValueError):
  """A request the server refuses (one line, sent back as the answer's error)."""


class Busy(RequestError):
  """The server's queue is full."""


def one_line(err: BaseException) -> str:
  """err's message on one line."""
  return ' '.join(str(err).split()) or type(err).__name__


@dataclasses.dataclass
class Task:
  """A loaded task: its planner (a `planner.Planner`, or any object with env, model, config and
  search, and canonical(indices) with num_instances for instance requests), its replanning
  session, what a request's states must look like and the canonical instances on the host."""

  name: str
  planner: object
  session: replan.Session
  fields: Dict[str, Tuple[Tuple[int, ...], np.dtype]]  # NodeState field -> (trailing shape, dtype)
  warm: bool = False  # the largest bucket warm: any request is answered without compiling
  warm_buckets: Tuple[int, ...] = ()  # ascending (`mark_warm`)
  remainder: Callable = None
  instances: Optional[Dict[str, np.ndarray]] = None  # the canonical instances' fields [N, ...]
  # split 'threads': one session per device, the first `session` (else just it)
  device_sessions: Tuple[replan.Session, ...] = ()

  @property
  def budget(self) -> int:
    return int(self.session.config.budget)

  def mark_warm(self, bucket: int) -> None:
    """Records bucket as compiled (`warm_buckets` replaced whole: health reads it elsewhere)."""
    self.warm_buckets = tuple(sorted({*self.warm_buckets, bucket}))

  def describe(self) -> dict:
    env = self.session.env
    return {'warm': self.warm, 'warm_buckets': list(self.warm_buckets), 'budget': self.budget,
            'pop_size': int(self.session.config.pop_size),
            'horizon': int(self.session.horizon), 'fill_steps': int(self.session.fill_steps),
            'action_size': int(env.action_size), 'physics': getattr(env, 'physics', None),
            'node_fields': {k: {'shape': list(s), 'dtype': d.name}
                            for k, (s, d) in self.fields.items()},
            'instances': self.instances is not None}


@dataclasses.dataclass
class Request:
  """A checked plan request: states [E] as NumPy fields, executed [E] or None."""

  task: str
  session: str
  states: Dict[str, np.ndarray]
  executed: Optional[np.ndarray]
  seed: int
  time_limit_s: Optional[float]
  reset: bool
  id: object = None
  keys: Optional[np.ndarray] = None  # [E, 2] uint32 per-episode PRNG keys (None: from seed)
  alive: Callable[[], bool] = lambda: True
  deliver: Callable[[dict, Callable[[], None]], None] = None
  arrived: float = 0.0

  @property
  def episodes(self) -> int:
    return int(next(iter(self.states.values())).shape[0])


class Server:
  """Loaded tasks, their warm programs, the client sessions and the planning thread.

  planners: task name -> a `planner.Planner` (or an object with env, model, config, search and
    optionally canonical(indices) and num_instances). config: a `ServeConfig`.
  """

  def __init__(self, planners: Mapping[str, object], config: ServeConfig = ServeConfig()):
    if not planners:
      raise ValueError('a server needs at least one task')
    self.config = config
    # read once here: a request's thread asks JAX nothing (see `_states`)
    self.backend = jax.default_backend()
    self.on_cpu = self.backend == 'cpu'
    self.device = f'{self.backend}: {jax.devices()[0].device_kind} x{config.devices}'
    self.buckets = config.bucket_sizes(self.on_cpu)
    self.tasks: Dict[str, Task] = {}
    if config.devices > jax.device_count():
      raise ValueError(f'devices {config.devices}: this host has {jax.device_count()} '
                       f'{jax.default_backend()} device(s)')
    self.devices = tuple(jax.devices()[:config.devices])
    threads = config.devices > 1 and config.split == 'threads'
    self.mesh = (sharding.instance_mesh(self.devices)
                 if config.devices > 1 and not threads else None)
    # split 'threads': a host thread per device, each driving its own device's search
    self._workers = (concurrent.futures.ThreadPoolExecutor(config.devices, 'pachs-serve-device')
                     if threads else None)
    for name, planner in planners.items():
      # chain lanes: each session's own search, which replays remainders; else the planner's
      # (compiled for one device: the other devices' sessions get their own programs)
      shared = None if planner.config.rollout_lanes else getattr(planner, 'search', None)
      sessions = []
      for i, device in enumerate(self.devices if threads else self.devices[:1]):
        search = shared if i == 0 or shared is None else programs.Programs(
            getattr(shared, 'search', shared))
        with jax.default_device(device):
          sessions.append(replan.Session(planner.env, planner.model, planner.config, search,
                                         mesh=self.mesh, fill_steps=config.fill_steps))
      session = sessions[0]
      spec = planner.env.node_spec
      fields = {f.name: (tuple(getattr(spec, f.name).shape), np.dtype(getattr(spec, f.name).dtype))
                for f in dataclasses.fields(spec)}
      instances = None
      if hasattr(planner, 'canonical'):  # on the host: a request's thread runs no JAX (below)
        if not isinstance(getattr(planner, 'num_instances', None), int):
          raise ValueError(f'task {name}: a planner with canonical(indices) needs '
                           'num_instances, the size of its canonical set')
        nodes = planner.canonical(list(range(planner.num_instances)))
        instances = {k: np.asarray(getattr(nodes, k)) for k in fields}
      self.tasks[name] = Task(name, planner, session, fields, remainder=jax.jit(replan.remainder),
                              instances=instances,
                              device_sessions=tuple(sessions) if threads else ())
    self.counters = collections.Counter()
    self._sessions: 'collections.OrderedDict[Tuple[str, str], Tuple[np.ndarray, np.ndarray]]' = \
        collections.OrderedDict()
    self._in_flight = set()
    self._lock = threading.Lock()
    self._inbox: 'queue.Queue[Optional[Request]]' = queue.Queue()
    self._waiting = 0
    self._thread: Optional[threading.Thread] = None
    self.draining = False
    self._say: Callable[[str], None] = lambda text: None
    self._warm_inputs: Dict[str, Tuple[Dict[str, np.ndarray], np.ndarray]] = {}
    self._warm_failed = set()  # (task, bucket) whose idle warm-up raised: not tried again

  # -- start-up ------------------------------------------------------------------------------

  def warm(self, say: Callable[[str], None] = lambda text: None, every: bool = True) -> None:
    """Compiles and runs one warm-up query per task and bucket (a time-limited search from the
    env's initial states): afterwards no request compiles. every=False: the largest bucket
    alone (the server answers any request at once; `ServeConfig.warm_idle_s` warms the rest)."""
    self._say = say
    for task in self.tasks.values():
      began = time.perf_counter()
      for bucket in self.buckets if every else self.buckets[-1:]:
        self._warm_bucket(task, bucket)
        say(f'{task.name}: batch size {bucket} warm after {time.perf_counter() - began:.1f} s')
      task.warm = True
      say(f'{task.name}: warm ({len(task.warm_buckets)} batch size(s) '
          f'{",".join(map(str, task.warm_buckets))}) in {time.perf_counter() - began:.1f} s')

  def _warm_bucket(self, task: Task, bucket: int) -> None:
    """One warm-up query of task padded to bucket (compiles its programs once)."""
    if task.name not in self._warm_inputs:
      keys = jax.random.split(jax.random.PRNGKey(0), self.buckets[-1])
      nodes = jax.jit(task.session.env.initial_nodes)(keys)
      for num in range(1, self.config.max_batch + 1):  # a request's seed split into its keys
        jax.random.split(jax.random.PRNGKey(0), num)
      self._warm_inputs[task.name] = (
          {k: np.asarray(getattr(nodes, k)) for k in task.fields}, np.asarray(keys))
    states, keys = self._warm_inputs[task.name]
    self._answer(task, [({k: v[:bucket] for k, v in states.items()}, None, None, None)],
                 keys[:bucket], self.config.warm_time_s, bucket)
    task.mark_warm(bucket)

  def start(self) -> None:
    """Starts the planning thread."""
    if self._thread is None:
      self._thread = threading.Thread(target=self._plan_forever, name='pachs-serve-planner',
                                      daemon=True)
      self._thread.start()

  def stop(self) -> None:
    """Plans what is queued, then ends the planning thread."""
    if self._thread is not None:
      self._inbox.put(None)
      self._thread.join()
      self._thread = None

  @property
  def idle(self) -> bool:
    """No request waits or is being planned."""
    return self._waiting == 0

  # -- requests ------------------------------------------------------------------------------

  def health(self) -> dict:
    """What is loaded and warm, the bounds, and the counters (requests, batches, searches,
    episodes planned, errors, busy answers)."""
    return {'ok': True, 'ready': all(t.warm for t in self.tasks.values()),
            'draining': self.draining,
            'tasks': {name: t.describe() for name, t in self.tasks.items()},
            'backend': self.backend, 'devices': self.config.devices, 'device': self.device,
            'split': self.config.split if self.config.devices > 1 else None,
            'buckets': list(self.buckets),
            'max_batch': self.config.max_batch, 'max_queue': self.config.max_queue,
            'window_s': self.config.window_s, 'max_wait_s': self.config.max_wait_s,
            'max_time_limit_s': self.config.max_time_limit_s,
            'queued': self._waiting, 'sessions': len(self._sessions),
            'counters': dict(self.counters)}

  def check(self, message: dict, default_session: str) -> Request:
    """The checked `Request` of a plan message; RequestError (one line) for anything wrong."""
    known = {'type', 'id', 'task', 'session', 'states', 'instances', 'executed', 'seed',
             'keys', 'time_limit_s', 'budget', 'reset'}
    unknown = sorted(set(message) - known)
    if unknown:
      raise RequestError(f'unknown request field {unknown[0]!r}; valid: {", ".join(sorted(known))}')
    name = message.get('task')
    if name not in self.tasks:
      raise RequestError(f'task {name!r} is not loaded here; loaded: {", ".join(self.tasks)}')
    task = self.tasks[name]
    sid = message.get('session', default_session)
    if not isinstance(sid, str) or not 0 < len(sid) <= 200:
      raise RequestError(f'session must be a string of 1 to 200 characters, got {sid!r}')
    budget = message.get('budget')
    if budget is not None and budget != task.budget:
      raise RequestError(f'budget {budget!r}: this server plans {name} at {task.budget} '
                         'evaluations per episode (compiled in); leave budget out or give that')
    limit = message.get('time_limit_s')
    if limit is not None:
      if isinstance(limit, bool) or not isinstance(limit, (int, float)) or not (
          math.isfinite(limit) and limit > 0):
        raise RequestError(f'time_limit_s must be a number of seconds > 0 or None, got {limit!r}')
      if limit > self.config.max_time_limit_s:
        raise RequestError(f'time_limit_s {limit} exceeds the server\'s '
                           f'{self.config.max_time_limit_s} s (--max-time-limit)')
    seed = message.get('seed', 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or not -2**63 <= seed < 2**63:
      raise RequestError(f'seed must be a 64-bit integer, got {seed!r}')
    reset = message.get('reset', False)
    if not isinstance(reset, bool):
      raise RequestError(f'reset must be true or false, got {reset!r}')
    states = self._states(task, message)
    num = next(iter(states.values())).shape[0]
    executed = message.get('executed')
    if executed is not None:
      try:
        executed = np.asarray(executed)
      except Exception:  # pylint: disable=broad-except
        raise RequestError('executed must be a list of counts') from None
      if (executed.shape != (num,) or executed.dtype == bool
          or not np.issubdtype(executed.dtype, np.integer) or np.any(executed < 0)):
        raise RequestError(f'executed must hold {num} integer counts >= 0 (or DIVERGED), got '
                           f'shape {executed.shape} dtype {executed.dtype}')
      executed = np.minimum(executed.astype(np.int64), DIVERGED)
    keys = message.get('keys')
    if keys is not None:
      if 'seed' in message:
        raise RequestError('give either seed or keys')
      if not isinstance(keys, np.ndarray) or keys.shape != (num, 2) or keys.dtype != np.uint32:
        raise RequestError(f'keys must be a uint32 array [{num}, 2] (one PRNG key an episode)')
    return Request(name, sid, states, executed, int(seed),
                   None if limit is None else float(limit), reset, message.get('id'), keys=keys)

  def _states(self, task: Task, message: dict) -> Dict[str, np.ndarray]:
    """The request's start states as NodeState fields [E, ...] in the task's dtypes."""
    states, instances = message.get('states'), message.get('instances')
    if (states is None) == (instances is None):
      raise RequestError('give either states (NodeState fields) or instances (canonical '
                         'indices)')
    limit = self.config.max_batch
    if instances is not None:
      if task.instances is None:
        raise RequestError(f'task {task.name} has no canonical instances: send states')
      available = next(iter(task.instances.values())).shape[0]
      try:
        index = planner_lib.check_indices(instances, available)
      except ValueError as err:
        raise RequestError(one_line(err)) from None
      if len(index) > limit:
        raise RequestError(f'{len(index)} episodes exceed the server\'s {limit} per request '
                           '(--max-batch)')
      # NumPy, not the planner's device arrays: JAX work beside the planning thread's can crash
      # a GPU process inside MuJoCo Warp's callbacks
      return {k: v[index] for k, v in task.instances.items()}
    if not isinstance(states, dict) or set(states) != set(task.fields):
      got = sorted(states) if isinstance(states, dict) else type(states).__name__
      raise RequestError(f'states must map the NodeState fields {", ".join(task.fields)}, '
                         f'got {got}')
    out, num = {}, None
    for field, (shape, dtype) in task.fields.items():
      x = states[field]
      if not isinstance(x, np.ndarray):
        raise RequestError(f'states.{field} must be an array, got {type(x).__name__}')
      if x.ndim != len(shape) + 1 or tuple(x.shape[1:]) != shape:
        raise RequestError(f'states.{field} has shape {list(x.shape)}; {task.name} takes '
                           f'[E{"".join(", " + str(n) for n in shape)}]')
      num = x.shape[0] if num is None else num
      if x.shape[0] != num:
        raise RequestError(f'states.{field} holds {x.shape[0]} episodes, the others {num}')
      floating = np.issubdtype(dtype, np.floating)
      allowed = (np.float32, np.float64) if floating else (np.int32, np.int64)
      if x.dtype not in allowed:
        raise RequestError(f'states.{field} has dtype {x.dtype}; {task.name} takes '
                           f'{" or ".join(np.dtype(a).name for a in allowed)}')
      if floating and not np.all(np.isfinite(x)):
        raise RequestError(f'states.{field} holds NaN or infinite values')
      if floating and np.any(np.abs(x) > np.finfo(dtype).max):
        raise RequestError(f'states.{field} holds values beyond {dtype.name}')
      out[field] = x.astype(dtype)
    if not 1 <= num <= limit:
      raise RequestError(f'a request plans 1 to {limit} episodes (--max-batch), got {num}')
    return out

  def submit(self, request: Request) -> None:
    """Queues a checked request (its `deliver` called from the planning thread); Busy at once
    when max_queue requests wait, RequestError while draining or for a session with a request
    already in flight."""
    with self._lock:
      if self.draining:
        raise RequestError('the server is shutting down')
      if self._waiting >= self.config.max_queue:
        self.counters['busy'] += 1
        raise Busy(f'busy: {self._waiting} requests queued (--max-queue '
                   f'{self.config.max_queue}); ask again later')
      key = (request.task, request.session)
      if key in self._in_flight:
        raise RequestError(f'session {request.session!r} has a request in flight; a session '
                           'asks one at a time')
      self._in_flight.add(key)
      self._waiting += 1
      self.counters['requests'] += 1
    request.arrived = time.perf_counter()
    self._inbox.put(request)

  def release(self, request: Request) -> None:
    """The request is answered (or its client gone): its session may ask again."""
    with self._lock:
      self._in_flight.discard((request.task, request.session))

  def forget(self, task: str, session: str) -> bool:
    """Drops a session's last answer; whether there was one."""
    with self._lock:
      return self._sessions.pop((task, session), None) is not None

  def _keep(self, key, actions: np.ndarray, length: np.ndarray) -> None:
    with self._lock:
      self._sessions[key] = (actions, length)
      self._sessions.move_to_end(key)
      while len(self._sessions) > self.config.max_sessions:
        self._sessions.popitem(last=False)

  # -- the planning thread -------------------------------------------------------------------

  def _plan_forever(self) -> None:
    pending: List[Request] = []
    stopping = False
    while not (stopping and not pending):
      if not pending:
        item = self._next_request()
        if item is None:
          break
        pending.append(item)
      # gather: the first request's task, until the window closes or a batch is full
      began = time.perf_counter()
      deadline = began + self.config.window_s
      while not stopping:
        same = sum(r.episodes for r in pending if r.task == pending[0].task)
        left = deadline - time.perf_counter()
        if same >= self.config.max_batch or left <= 0:
          break
        try:
          item = self._inbox.get(timeout=left)
        except queue.Empty:
          break
        if item is None:
          stopping = True
        else:
          pending.append(item)
          if self.config.max_wait_s is not None and item.task == pending[0].task:
            # the window restarts, up to max_wait_s
            deadline = min(time.perf_counter() + self.config.window_s,
                           began + self.config.max_wait_s)
      batch, rest, size = [], [], 0
      for r in pending:
        if r.task == pending[0].task and size + r.episodes <= self.config.max_batch:
          batch.append(r)
          size += r.episodes
        else:
          rest.append(r)
      pending = rest
      self._plan_batch(batch)

  def _next_request(self) -> Optional[Request]:
    """The next request from the inbox (None: stop); after each `ServeConfig.warm_idle_s`
    without one, warms one of the warm tasks' cold buckets, smallest first."""
    while self.config.warm_idle_s is not None:
      cold = [(bucket, name) for name, task in self.tasks.items() if task.warm
              for bucket in self.buckets if bucket not in task.warm_buckets
              and (name, bucket) not in self._warm_failed]
      if not cold:
        break
      try:
        return self._inbox.get(timeout=self.config.warm_idle_s)
      except queue.Empty:
        pass
      bucket, name = min(cold)
      began = time.perf_counter()
      try:
        self._warm_bucket(self.tasks[name], bucket)
        self._say(f'{name}: batch size {bucket} warm in {time.perf_counter() - began:.1f} s '
                  '(while idle)')
      except Exception as err:  # pylint: disable=broad-except  (the largest bucket still serves)
        self._warm_failed.add((name, bucket))
        self.counters['warm_errors'] += 1
        self._say(f'{name}: batch size {bucket} not warmed: {one_line(err)}')
    return self._inbox.get()

  def _finish(self, request: Request, response: dict, commit=lambda: None) -> None:
    with self._lock:
      self._waiting -= 1
    try:
      request.deliver(response, commit)
    except Exception:  # pylint: disable=broad-except  (a client gone: nothing else to do)
      pass

  def _plan_batch(self, batch: List[Request]) -> None:
    """Plans the live requests of one task in one search call; each gets its answer."""
    live = [r for r in batch if r.alive()]
    for r in batch:
      if r not in live:
        self.counters['dropped'] += 1
        self._finish(r, {'ok': False, 'id': r.id, 'error': 'client gone'})
    if not live:
      return
    try:
      responses = self._plan_requests(live)
    except Exception as err:  # pylint: disable=broad-except
      if len(live) == 1:
        self.counters['errors'] += 1
        self._finish(live[0], {'ok': False, 'id': live[0].id, 'error': one_line(err)})
        return
      for r in live:  # one bad request must not fail the others: each alone
        self._plan_batch([r])
      return
    for r, (response, commit) in zip(live, responses):
      self._finish(r, response, commit)

  def _plan_requests(self, requests: List[Request]):
    task = self.tasks[requests[0].task]
    num = sum(r.episodes for r in requests)
    # the smallest warm bucket that holds the batch (a cold one compiles here, then is warm)
    bucket = next((b for b in task.warm_buckets if b >= num), None) or next(
        b for b in self.buckets if b >= num)
    parts = []
    for r in requests:
      with self._lock:
        if r.reset:
          self._sessions.pop((r.task, r.session), None)
        kept = self._sessions.get((r.task, r.session))
      if kept is not None and kept[1].shape[0] != r.episodes:
        raise RequestError(f'session {r.session!r} plans {kept[1].shape[0]} episodes, got '
                           f'{r.episodes} (reset=True starts new episodes)')
      last_actions, last_length = (None, None) if kept is None else kept
      parts.append((r.states, last_actions, last_length, r.executed))
    # per-episode keys as `Session.plan` splits one request's seed: answers do not depend on
    # the batch a request was planned in
    keys = np.concatenate([r.keys if r.keys is not None else
                           np.asarray(jax.random.split(jax.random.PRNGKey(r.seed), r.episodes))
                           for r in requests])
    limits = [r.time_limit_s for r in requests if r.time_limit_s is not None]
    began = time.perf_counter()
    answer = self._answer(task, parts, keys, min(limits) if limits else None, bucket)
    task.mark_warm(bucket)
    search_s = time.perf_counter() - began
    self.counters['batches'] += 1
    self.counters['searches'] += 1
    self.counters['episodes'] += num
    out, row = [], 0
    for r in requests:
      rows = slice(row, row + r.episodes)
      row += r.episodes
      actions, length = answer['actions'][rows], answer['length'][rows]
      response = {'ok': True, 'id': r.id, 'task': r.task, 'session': r.session,
                  'actions': actions, 'length': length, 'kind': answer['kind'][rows],
                  'reaches_goal': answer['reaches_goal'][rows], 'cost': answer['cost'][rows],
                  'evaluated': answer['evaluated'][rows],
                  'search': {k: v[rows] for k, v in answer['search'].items()},
                  'remainder': {k: v[rows] for k, v in answer['remainder'].items()},
                  'follow_s': answer['follow_s'],
                  **({'fill_length': answer['fill_length'][rows]}
                     if 'fill_length' in answer else {}),
                  'batch': {'requests': len(requests), 'episodes': num, 'bucket': bucket},
                  'queued_s': began - r.arrived, 'search_s': search_s}
      out.append((response, functools.partial(self._keep, (r.task, r.session), actions, length)))
    return out

  def _answer(self, task: Task, parts, keys, time_limit_s, bucket) -> Dict[str, np.ndarray]:
    """The answer fields (NumPy) of the episodes of parts, each (states, last actions, last
    length, executed) with last None for none, planned together in a batch padded to bucket
    (split 'threads': an even part per device, each padded to bucket / devices, at once)."""
    horizon = task.session.horizon
    num = sum(next(iter(p[0].values())).shape[0] for p in parts)
    last_actions = np.zeros((num, horizon, task.session.env.action_size), np.float32)
    last_length = np.zeros(num, np.int32)
    executed = np.full(num, DIVERGED, np.int32)
    row = 0
    for states, actions, length, done in parts:
      n = next(iter(states.values())).shape[0]
      if actions is not None and done is not None:
        last_actions[row:row + n], last_length[row:row + n] = actions, length
        executed[row:row + n] = done
      row += n
    episodes = {k: np.concatenate([p[0][k] for p in parts]) for k in task.fields}
    episodes.update(last_actions=last_actions, last_length=last_length, executed=executed,
                    keys=np.asarray(keys)[:num])
    if self._workers is None:
      return self._answer_on(task, task.session, None, episodes, time_limit_s, bucket)
    # an even part per device (at most bucket / devices episodes, rounded up: each device's
    # warm size)
    size = -(-bucket // len(self.devices))
    cuts = np.array_split(np.arange(num), min(len(self.devices), num))
    futures = [self._workers.submit(
        self._answer_on, task, task.device_sessions[i], self.devices[i],
        {k: v[rows] for k, v in episodes.items()}, time_limit_s, size)
               for i, rows in enumerate(cuts)]
    concurrent.futures.wait(futures)  # every part done before any error is raised: a retry
    answers = [f.result() for f in futures]  # must not find a device's session still busy
    join = lambda *xs: np.concatenate(xs)
    merged = jax.tree.map(join, *[{k: v for k, v in a.items() if k != 'follow_s'}
                                  for a in answers])
    return dict(merged, follow_s=max(a['follow_s'] for a in answers))

  def _answer_on(self, task: Task, session: replan.Session, device, episodes, time_limit_s,
                 bucket) -> Dict[str, np.ndarray]:
    """`_answer`'s fields of episodes (NodeState fields, last_actions, last_length, executed,
    keys [n, ...] NumPy) planned by session on device (None: the default) in a batch padded to
    bucket, from each last answer's remainder."""
    num = episodes['keys'].shape[0]
    # every array at the bucket's size, padded on the host with copies of the last episode that
    # do not search (`active`): one set of compiled programs serves every episode count
    # (on its device: a program compiled for another would raise, not copy)
    put = jnp.asarray if device is None else lambda x: jax.device_put(x, device)
    pad = lambda x: put(np.concatenate([x, np.repeat(x[-1:], bucket - num, axis=0)]))
    with jax.default_device(device) if device is not None else contextlib.nullcontext():
      states = type(session.env.node_spec)(**{k: pad(episodes[k]) for k in task.fields})
      # the padding has no last answer
      actions, length = task.remainder(pad(episodes['last_actions']),
                                       put(np.pad(episodes['last_length'], (0, bucket - num))),
                                       pad(episodes['executed']))
      answer = session.answer(states, actions, length,
                              pad(episodes['keys']), time_limit_s, bucket,
                              active=np.arange(bucket) < num)
      first = lambda x: np.asarray(x)[:num]
      filled = {} if answer.fill_length is None else {'fill_length': first(answer.fill_length)}
      return {**filled, 'actions': first(answer.actions), 'length': first(answer.length),
              'kind': first(answer.kind), 'reaches_goal': first(answer.reaches_goal),
              'cost': first(answer.cost), 'evaluated': first(answer.search.evaluated),
              'search': {k: first(getattr(answer.search, k)) for k in SEARCH_FIELDS},
              'remainder': {'steps': first(session.followed['remainder'].steps),
                            'reaches_goal': first(session.followed['remainder'].reached_goal)},
              'follow_s': float(session.timing['follow_s'])}

  # -- the websocket -------------------------------------------------------------------------

  async def handle(self, connection) -> None:
    """Answers one client's messages in turn (websockets connection handler)."""
    from websockets.exceptions import ConnectionClosed  # pylint: disable=import-outside-toplevel
    from websockets.protocol import State  # pylint: disable=import-outside-toplevel
    loop = asyncio.get_running_loop()
    default_session = uuid.uuid4().hex
    try:
      async for data in connection:
        message_id = None
        try:
          message = wire.unpack(data)
          message_id = message.get('id')
          kind = message.get('type', 'plan')
          if kind not in REQUEST_TYPES:
            raise RequestError(f'unknown request type {kind!r}; valid: {", ".join(REQUEST_TYPES)}')
          if kind == 'health':
            await connection.send(wire.pack(dict(self.health(), id=message_id)))
            continue
          if kind == 'reset':
            task, sid = message.get('task'), message.get('session', default_session)
            if task not in self.tasks:
              raise RequestError(f'task {task!r} is not loaded here; loaded: '
                                 f'{", ".join(self.tasks)}')
            forgot = self.forget(task, sid)
            await connection.send(wire.pack({'ok': True, 'id': message_id, 'forgot': forgot}))
            continue
          request = self.check(message, default_session)
          future = loop.create_future()

          def deliver(response, commit, future=future):
            loop.call_soon_threadsafe(_resolve, future, (response, commit))
          request.deliver = deliver
          request.alive = lambda: connection.state is State.OPEN
          self.submit(request)
        except (RequestError, wire.WireError) as err:
          if not isinstance(err, Busy):
            self.counters['errors'] += 1
          await connection.send(wire.pack({'ok': False, 'id': message_id,
                                           'error': one_line(err),
                                           'busy': isinstance(err, Busy)}))
          continue
        try:
          response, commit = await future
          await connection.send(wire.pack(response))
          if response.get('ok'):
            commit()  # kept once delivered: a client that never got it replans from scratch
            self.counters['answered'] += 1
        finally:
          self.release(request)
    except ConnectionClosed:
      pass

  async def serve_until(self, host: str, port: int, stopped: asyncio.Event,
                        ready: Callable[[str], None] = lambda url: None) -> None:
    """Serves on host:port until `stopped` is set, then answers what is queued and closes."""
    from websockets.asyncio.server import serve  # pylint: disable=import-outside-toplevel
    self.start()
    async with serve(self.handle, host, port, max_size=wire.MAX_MESSAGE_BYTES,
                     compression=None) as server:
      bound = server.sockets[0].getsockname()
      ready(f'ws://{_host_text(bound[0])}:{bound[1]}')
      await stopped.wait()
      with self._lock:
        self.draining = True
      while not self.idle:  # the requests in flight get their answers
        await asyncio.sleep(0.01)
      await asyncio.sleep(0.05)  # their sends leave before the connections close
      server.close()
      await server.wait_closed()
    await asyncio.get_running_loop().run_in_executor(None, self.stop)


def _resolve(future: asyncio.Future, value) -> None:
  if not future.done():
    future.set_result(value)


def _host_text(host: str) -> str:
  return f'[{host}]' if ':' in host else host


def serve_forever(server: Server, host: str = '127.0.0.1', port: int = 8000,
                  ready: Callable[[str], None] = lambda url: None) -> int:
  """Serves in this (main) thread until SIGTERM or SIGINT, then finishes the requests in flight
  and returns 0."""
  async def main():
    stopped = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGTERM, signal.SIGINT):
      loop.add_signal_handler(signum, stopped.set)
    try:
      await server.serve_until(host, port, stopped, ready)
    finally:
      for signum in (signal.SIGTERM, signal.SIGINT):
        loop.remove_signal_handler(signum)
  asyncio.run(main())
  return 0


class Running:
  """A server serving in a thread of this process (tests, notebooks): `url`, and `stop()`,
  which answers what is queued and ends it; a context manager."""

  def __init__(self, server: Server, host: str = '127.0.0.1', port: int = 0):
    self.server = server
    self.url: Optional[str] = None
    self._ready = threading.Event()
    self._error: Optional[BaseException] = None
    self._loop: Optional[asyncio.AbstractEventLoop] = None
    self._stopped: Optional[asyncio.Event] = None
    self._thread = threading.Thread(target=self._run, args=(host, port), daemon=True,
                                    name='pachs-serve')
    self._thread.start()
    self._ready.wait()
    if self._error is not None:
      raise self._error

  def _run(self, host, port) -> None:
    async def main():
      self._loop = asyncio.get_running_loop()
      self._stopped = asyncio.Event()

      def ready(url):
        self.url = url
        self._ready.set()
      await self.server.serve_until(host, port, self._stopped, ready)
    try:
      asyncio.run(main())
    except BaseException as err:  # pylint: disable=broad-except
      self._error = err
      self._ready.set()

  def stop(self) -> None:
    if self._loop is not None and self._thread.is_alive():
      self._loop.call_soon_threadsafe(self._stopped.set)
      self._thread.join()

  def __enter__(self) -> 'Running':
    return self

  def __exit__(self, *exc) -> None:
    self.stop()
