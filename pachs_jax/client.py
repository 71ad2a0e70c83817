"""A client of `pachs serve`: plan requests over a websocket, answers as NumPy arrays, and an
action-chunk helper for a control loop (docs/serving.md). Needs NumPy, msgpack and websockets
only (no JAX)."""

from __future__ import annotations

import contextlib
import dataclasses
import uuid
from typing import Optional, Sequence

import numpy as np

from pachs_jax import wire

# `executed` for an episode that did something else than its last answer (`replan.DIVERGED`)
DIVERGED = np.iinfo(np.int32).max

KIND_NAMES = ('none', 'goal_path', 'partial_path', 'remainder', 'policy')  # replan.AnswerKind


class ServerError(RuntimeError):
  """The server refused a request (its one-line reason); `busy` when its queue was full."""

  def __init__(self, message: str, busy: bool = False):
    super().__init__(message)
    self.busy = busy


@dataclasses.dataclass
class Answer:
  """A plan request's answer for E episodes (the fields of `replan.Answer`, as NumPy).

  actions: [E, T, A] float32; rows >= length are 0. length: [E] int32. kind: [E] int32
  `replan.AnswerKind` codes (`kind_names`). reaches_goal: [E] bool. cost: [E] float32.
  evaluated: [E] edge evaluations of the search. batch: the search call it was planned in
  (requests, episodes, bucket). queued_s, search_s: the server's time before and in the search.
  search: the search's [E] path_length, found, stop_reason, expanded, generated, invalid,
  iterations. remainder: the last answer's remainder followed from the states, [E] steps and
  reaches_goal. follow_s: the server's time following the candidates. fill_length: [E] the
  policy's actions that may follow a short answer before the first edge the server's physics
  finds invalid (a server with `ServeConfig.fill_steps`; None: no fill followed).
  """

  actions: np.ndarray
  length: np.ndarray
  kind: np.ndarray
  reaches_goal: np.ndarray
  cost: np.ndarray
  evaluated: np.ndarray
  batch: dict
  queued_s: float
  search_s: float
  search: dict = dataclasses.field(default_factory=dict)
  remainder: dict = dataclasses.field(default_factory=dict)
  follow_s: float = 0.0
  fill_length: Optional[np.ndarray] = None

  @property
  def kind_names(self):
    return [KIND_NAMES[int(k)] for k in self.kind]


def node_fields(states) -> dict:
  """A NodeState [E] (or a map of its fields) as the request's map of NumPy arrays."""
  if isinstance(states, dict):
    items = states.items()
  elif dataclasses.is_dataclass(states):
    items = ((f.name, getattr(states, f.name)) for f in dataclasses.fields(states))
  else:
    raise ValueError(f'states must be a NodeState or a map of its fields, got '
                     f'{type(states).__name__}')
  return {k: np.asarray(v) for k, v in items}


class Client:
  """A connection to a planning server; one session (the server keeps its last answer).

  url: 'ws://127.0.0.1:8000'. task: the task asked by default (None: the server's only one).
  session: the session's name (None: a new one). timeout_s: how long to wait for an answer.
  """

  def __init__(self, url: str, task: Optional[str] = None, session: Optional[str] = None,
               timeout_s: float = 120.0):
    from websockets.sync.client import connect  # pylint: disable=import-outside-toplevel
    self.url = url
    self.session = session or uuid.uuid4().hex
    self.timeout_s = timeout_s
    self._open = contextlib.ExitStack()  # the connection, entered as its context
    self._connection = self._open.enter_context(connect(
        url, max_size=wire.MAX_MESSAGE_BYTES, compression=None, open_timeout=timeout_s))
    self._next_id = 0
    if task is None:
      tasks = list(self.health()['tasks'])
      if len(tasks) != 1:
        raise ValueError(f'the server serves {", ".join(tasks)}: name the task')
      task = tasks[0]
    self.task = task

  def _ask(self, message: dict) -> dict:
    self._next_id += 1
    message = dict(message, id=self._next_id)
    self._connection.send(wire.pack(message))
    while True:
      response = wire.unpack(self._connection.recv(timeout=self.timeout_s))
      if response.get('id') == self._next_id:
        break
    if not response.get('ok'):
      raise ServerError(response.get('error', 'error'), bool(response.get('busy')))
    return response

  def health(self) -> dict:
    """The server's tasks (loaded, warm, budget, node fields), bounds and counters."""
    return self._ask({'type': 'health'})

  def plan(self, states=None, instances: Optional[Sequence[int]] = None, executed=None,
           seed: int = 0, time_limit_s: Optional[float] = None, reset: bool = False,
           task: Optional[str] = None, keys=None) -> Answer:
    """The `Answer` [E] from states (a NodeState [E] or a map of its fields) or the task's
    canonical instances; executed: [E] actions of the last answer executed since
    (`DIVERGED` where an episode did something else; None drops the last answer); seed,
    time_limit_s as in `Session.plan` (keys: per-episode PRNG keys [E, 2] instead of seed);
    reset: forget the last answer first (new episodes).
    ServerError with the server's reason for a refused request."""
    message = {'type': 'plan', 'task': task or self.task, 'session': self.session,
               'reset': bool(reset)}
    if keys is None:
      message['seed'] = int(seed)
    else:
      message['keys'] = np.asarray(keys, np.uint32)
    if states is not None:
      message['states'] = node_fields(states)
    if instances is not None:
      message['instances'] = [int(i) for i in instances]
    if executed is not None:
      message['executed'] = np.minimum(np.asarray(executed, np.int64), DIVERGED)
    if time_limit_s is not None:
      message['time_limit_s'] = float(time_limit_s)
    r = self._ask(message)
    return Answer(actions=r['actions'], length=r['length'], kind=r['kind'],
                  reaches_goal=r['reaches_goal'], cost=r['cost'], evaluated=r['evaluated'],
                  batch=r['batch'], queued_s=r['queued_s'], search_s=r['search_s'],
                  search=r['search'], remainder=r['remainder'], follow_s=r['follow_s'],
                  fill_length=r.get('fill_length'))

  def reset(self, task: Optional[str] = None) -> bool:
    """Forgets the session's last answer on the server; whether it had one."""
    return bool(self._ask({'type': 'reset', 'task': task or self.task,
                           'session': self.session})['forgot'])

  def close(self) -> None:
    self._open.close()

  def __enter__(self) -> 'Client':
    return self

  def __exit__(self, *exc) -> None:
    self.close()


class ActionChunks:
  """A control loop's view of a session: `chunk(states)` asks for a plan and returns the first
  `execute` actions of each episode ([E, execute, A] and how many are real, [E]); the next
  chunk tells the server how many of them the loop said it executed (`executed`, set by the
  caller, default all of them)."""

  def __init__(self, client: Client, execute: int = 10, time_limit_s: Optional[float] = None,
               seed: int = 0):
    if isinstance(execute, bool) or not isinstance(execute, int) or execute < 1:
      raise ValueError(f'execute must be a positive int, got {execute!r}')
    self.client, self.execute, self.time_limit_s, self.seed = client, execute, time_limit_s, seed
    self.executed: Optional[np.ndarray] = None  # what the loop did of the last chunk
    self.last: Optional[Answer] = None
    self.queries = 0

  def chunk(self, states):
    """(actions [E, execute, A], lengths [E]): the next actions of each episode."""
    answer = self.client.plan(states, executed=self.executed, seed=self.seed + self.queries,
                              time_limit_s=self.time_limit_s, reset=self.queries == 0)
    self.queries += 1
    self.last = answer
    lengths = np.minimum(answer.length, self.execute)
    self.executed = lengths.copy()
    return answer.actions[:, :self.execute], lengths

  def diverged(self, episodes) -> None:
    """Marks episodes (a bool mask [E] or indices) as having done something else since the
    last chunk (e.g. policy actions after a short one): their remainder is dropped."""
    self.executed[episodes] = DIVERGED
