"""Replanning: a session over E episodes that plans again from their new states, keeps its last
answer, and answers with its search's path, or the best of it, the last answer's remainder and
the policy's rollout (docs/closed_loop.md)."""

from __future__ import annotations

import concurrent.futures
import dataclasses
import time
from typing import Callable, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pachs_jax import trees
from pachs_jax.runtime import programs, sharding
from pachs_jax.envs import base
from pachs_jax.search import capacity
from pachs_jax.search.checks import check_seconds, check_start_nodes, instance_keys
from pachs_jax.search.result import SearchResult

# `Session.plan`'s `executed` for an episode whose last answer was not followed as given
# (its remainder is dropped)
DIVERGED = np.iinfo(np.int32).max

# folded into an episode's key for its `AnswerCheck` copies (a stream the search does not use)
CHECK_STREAM = 0x636b

# the clock (s) of the throwaway answer that runs a session's programs once before its first
# clocked query (`Session.answer`): one chunk of the search
WARM_UP_S = 1e-3


class AnswerKind:
  """What a query answered with ([E] int32 codes in `Answer.kind`)."""

  NONE = 0  # nothing can act: no candidate's first edge is valid in the planner's physics
  GOAL_PATH = 1  # the search's path to a goal
  PARTIAL_PATH = 2  # the search's real-time answer: a path that ends short of a goal
  REMAINDER = 3  # the last answer's actions not yet executed, simulated from the new state
  POLICY = 4  # the deterministic policy's rollout from the new state

  NAMES = ('none', 'goal_path', 'partial_path', 'remainder', 'policy')

  @classmethod
  def name(cls, code: int) -> str:
    return cls.NAMES[int(code)]


@struct.dataclass
class Followed:
  """Paths followed in the planner's physics, lanes [B].

  actions: [B, T, A] float32 the actions applied; rows >= steps are 0.
  steps: [B] int32 edges applied: a path stops at its length, at its first goal state and
    before its first invalid edge.
  reached_goal: [B] bool the path ends at a goal state (a start at a goal counts, steps 0).
  cost: [B] float32 the applied edges' summed cost (the env's cost units).
  states: NodeState [B, T + 1, ...] the states along the path, the start first (rows past
    steps repeat the last).
  """

  actions: jax.Array
  steps: jax.Array
  reached_goal: jax.Array
  cost: jax.Array
  states: base.NodeState


def follow(env: base.Env, policy: Callable[[jax.Array], jax.Array], start: base.NodeState,
           actions: jax.Array, length: jax.Array, use_policy: jax.Array) -> Followed:
  """Follows paths from start [B] for their first length [B] edges (at most T): actions
  [B, T, A], or where use_policy [B] the policy's action at each state, policy(obs [B, O]) ->
  [B, A]. A pure function (jit it); the loop ends once every lane has stopped."""
  batch, horizon = actions.shape[:2]

  def cond(carry):
    t, _, running, *_ = carry
    return (t < horizon) & jnp.any(running)

  def body(carry):
    t, node, running, taken, steps, reached, cost, states = carry
    action = jnp.where(use_policy[:, None], policy(env.observe(node)), actions[:, t])
    out = env.evaluate(node, action)
    take = running & out.is_valid & jnp.isfinite(out.cost) & (t < length)
    node = trees.where(take, out.next_node, node)
    taken = taken.at[:, t].set(jnp.where(take[:, None], action, 0.0))
    reached = reached | (take & out.is_goal)
    running = take & ~out.is_goal
    states = jax.tree.map(lambda s, n: s.at[:, t + 1].set(n), states, node)
    return (t + 1, node, running, taken, steps + take, reached,
            cost + jnp.where(take, out.cost, 0.0), states)

  at_goal = env.is_goal(start)
  states = jax.tree.map(lambda x: jnp.repeat(x[:, None], horizon + 1, axis=1), start)
  carry = (jnp.zeros((), jnp.int32), start, ~at_goal & (length > 0),
           jnp.zeros_like(actions, jnp.float32), jnp.zeros((batch,), jnp.int32), at_goal,
           jnp.zeros((batch,), jnp.float32), states)
  t, last, _, taken, steps, reached, cost, states = jax.lax.while_loop(cond, body, carry)
  # rows the loop did not reach repeat the last state
  later = jnp.arange(horizon + 1) > t
  states = jax.tree.map(lambda s, n: jnp.where(
      later.reshape((1, -1) + (1,) * (s.ndim - 2)), n[:, None], s), states, last)
  return Followed(actions=taken, steps=steps, reached_goal=reached, cost=cost, states=states)


def remainder(actions: jax.Array, length: jax.Array, executed: jax.Array):
  """(actions [E, T, A], length [E]) of the paths actions [E, T, A] of length [E] without their
  first executed [E] actions (length 0 where executed exceeds the length)."""
  horizon = actions.shape[1]
  index = jnp.minimum(jnp.arange(horizon)[None] + executed[:, None], horizon - 1)
  left = jnp.where(executed <= length, length - executed, 0)
  shifted = jnp.take_along_axis(actions, index[:, :, None], axis=1)
  return jnp.where((jnp.arange(horizon)[None] < left[:, None])[:, :, None], shifted, 0.0), left


@struct.dataclass
class Answer:
  """A query's answer for E episodes.

  actions: [E, T, A] float32 the answer's actions (T: the session's horizon); rows >= length 0.
  length: [E] int32 actions in the answer.
  kind: [E] int32 `AnswerKind` code.
  reaches_goal: [E] bool the answer ends at a goal state in the planner's physics.
  cost: [E] float32 the answer's cost in the planner's physics.
  states: NodeState [E, T + 1, ...] where the answer goes in the planner's physics, the start
    first (rows past length repeat the last; all the start for `none`).
  search: the query's `SearchResult` [E].
  safe_length: [E] int32 the answer's first actions to execute before the next query: its
    length, or where an `AnswerCheck` found a perturbed copy of the start that could not take
    one of its first actions, the actions before it (at least 1).
  fill_length: [E] int32 the policy's actions that may follow a short answer before the next
    query (`fill_length`, a session with `fill_steps`; `Session.answer` returns it as a
    `PendingFill`, still being followed); None: as many as the caller fills.
  """

  actions: jax.Array
  length: jax.Array
  kind: jax.Array
  reaches_goal: jax.Array
  cost: jax.Array
  states: base.NodeState
  search: SearchResult
  safe_length: jax.Array = None
  fill_length: jax.Array = None


class PendingFill:
  """[E] int32 fill lengths (`fill_length`) that a session's background thread is still
  following: np.asarray(pending), result() or block_until_ready() wait for them."""

  def __init__(self, future: concurrent.futures.Future):
    self._future = future

  def result(self) -> np.ndarray:
    return np.asarray(self._future.result())

  def block_until_ready(self) -> 'PendingFill':
    self._future.result()
    return self

  def __array__(self, dtype=None, copy=None):  # pylint: disable=unused-argument
    return self.result() if dtype is None else self.result().astype(dtype)


@dataclasses.dataclass(frozen=True)
class AnswerCheck:
  """Each answer's first `steps` actions followed from `copies` perturbed copies of its start
  in the planner's physics, one batch: an answer is executed only up to the first action that
  some copy could not take (`Answer.safe_length`), so that a plan that holds in the planner's
  physics but not near it (a T that tips over in another engine) is replanned sooner.

  perturb: (nodes [B], keys [B, 2]) -> nodes [B] near them (`pusht.perturb_t`).
  copies: perturbed copies per episode.
  steps: the first actions checked (a closed loop's actions per query).
  """

  perturb: Callable[[base.NodeState, jax.Array], base.NodeState]
  copies: int = 8
  steps: int = 10

  def __post_init__(self):
    if not callable(self.perturb):
      raise ValueError(f'AnswerCheck.perturb must be a function, got {self.perturb!r}')
    for name in ('copies', 'steps'):
      value = getattr(self, name)
      if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f'AnswerCheck.{name} must be a positive int, got {value!r}')


def safe_length(env: base.Env, policy: Callable[[jax.Array], jax.Array], check: AnswerCheck,
                start: base.NodeState, actions: jax.Array, length: jax.Array,
                keys: jax.Array) -> jax.Array:
  """[E] int32 the actions of paths actions [E, T, A] of length [E] from start [E] that all of
  `check.copies` perturbed copies of each start take in env (keys [E, 2]: each episode's
  copies; a copy that reaches a goal first counts as taking them all); length where they all
  take the first check.steps, else at least 1. A pure function."""
  num, copies, steps = length.shape[0], check.copies, check.steps
  first = jnp.minimum(length, steps)
  copy_keys = jax.vmap(lambda k: jax.random.split(k, copies))(keys).reshape(num * copies, -1)
  starts = check.perturb(jax.tree.map(lambda x: jnp.repeat(x, copies, axis=0), start), copy_keys)
  repeated = jnp.repeat(first, copies)
  took = follow(env, policy, starts, jnp.repeat(actions[:, :steps], copies, axis=0), repeated,
                jnp.zeros((num * copies,), bool))
  taken = jnp.where(took.reached_goal, repeated, took.steps).reshape(num, copies).min(axis=1)
  return jnp.where(taken < first, jnp.maximum(taken, 1), length).astype(jnp.int32)


def fill_length(env: base.Env, policy: Callable[[jax.Array], jax.Array], end: base.NodeState,
                length: jax.Array, steps: int) -> jax.Array:
  """[E] int32 the policy's actions after answers of length [E] (up to `steps` actions in all)
  that env takes from the answers' ends, end [E], before its first invalid edge (a T tipped
  over): steps - length where the policy reaches a goal or takes them all, 0 where the answer
  holds `steps` actions. A pure function."""
  want = jnp.maximum(steps - length, 0).astype(jnp.int32)
  num = length.shape[0]
  took = follow(env, policy, end, jnp.zeros((num, steps, env.action_size), jnp.float32), want,
                want > 0)  # each lane only as far as its fill goes
  return jnp.where(took.reached_goal | (took.steps >= want), want, took.steps).astype(jnp.int32)


def choose(search: SearchResult, last: Followed, policy: Followed, horizon: int) -> Answer:
  """The `Answer` of a query from its candidates [E]: the search's result, the last answer's
  remainder and the policy's rollout (both `follow`ed from the same states). Goal paths first,
  the cheapest (ties: search, remainder, policy); then the search's partial path, the
  remainder, the policy, each where it holds an edge. A pure function."""
  search_actions = search.path_actions[:, :horizon]
  search_length = jnp.minimum(search.path_length, horizon)
  # the search's states, rows past its length repeating its last (the kept path's end)
  rows = jnp.minimum(jnp.arange(horizon + 1)[None], search_length[:, None])
  search_states = jax.tree.map(
      lambda x: jnp.take_along_axis(x, rows.reshape(rows.shape + (1,) * (x.ndim - 2)), axis=1),
      search.path_nodes)
  found = search.found & search.path_is_goal & (search.path_length <= horizon)
  goal_cost = jnp.stack([jnp.where(found, search.cost, jnp.inf),
                         jnp.where(last.reached_goal & (last.steps > 0), last.cost, jnp.inf),
                         jnp.where(policy.reached_goal & (policy.steps > 0), policy.cost,
                                   jnp.inf)], axis=1)
  best_goal = jnp.argmin(goal_cost, axis=1)
  any_goal = jnp.isfinite(jnp.min(goal_cost, axis=1))
  kind = jnp.select(
      [any_goal & (best_goal == 0), any_goal & (best_goal == 1), any_goal,
       search_length > 0, last.steps > 0, policy.steps > 0],
      [AnswerKind.GOAL_PATH, AnswerKind.REMAINDER, AnswerKind.POLICY,
       AnswerKind.PARTIAL_PATH, AnswerKind.REMAINDER, AnswerKind.POLICY],
      AnswerKind.NONE).astype(jnp.int32)
  from_search = (kind == AnswerKind.GOAL_PATH) | (kind == AnswerKind.PARTIAL_PATH)
  pick = lambda a, b, c: jnp.where(
      from_search.reshape((-1,) + (1,) * (a.ndim - 1)), a,
      jnp.where((kind == AnswerKind.REMAINDER).reshape((-1,) + (1,) * (a.ndim - 1)), b, c))
  length = jnp.where(kind == AnswerKind.NONE, 0,
                     pick(search_length, last.steps, policy.steps)).astype(jnp.int32)
  return Answer(
      actions=pick(search_actions, last.actions, policy.actions),
      length=length, safe_length=length,
      kind=kind,
      reaches_goal=pick(found, last.reached_goal, policy.reached_goal) & (kind != AnswerKind.NONE),
      cost=jnp.where(kind == AnswerKind.NONE, 0.0, pick(search.cost, last.cost, policy.cost)),
      states=jax.tree.map(pick, search_states, last.states, policy.states),
      search=search)


def _counts(executed, num: int) -> np.ndarray:
  """[num] int32 `executed` counts (>= 0, DIVERGED for larger); ValueError naming it."""
  try:
    values = np.asarray(executed)
  except (TypeError, ValueError):
    values = None
  if (values is None or values.shape != (num,) or values.dtype.kind not in 'iu'
      or np.any(values < 0)):
    raise ValueError(f'executed must hold {num} integer counts >= 0, got {executed!r}')
  return np.minimum(values.astype(np.int64), DIVERGED).astype(np.int32)


def _check_query(time_limit_s, active, num: int) -> None:
  """ValueError naming the argument for a time limit that is not seconds > 0 (or None) and an
  active mask that is not [num] bools."""
  check_seconds(time_limit_s, 'time_limit_s')
  if active is not None:
    mask = np.asarray(active)
    if mask.shape != (num,) or mask.dtype != bool:
      raise ValueError(f'active must be [{num}] bools, got {active!r}')


CANDIDATES = ('remainder', 'policy')
# none: on PushT's faithful physics, following them took half of a 3 s query on an H200 and they
# won few answers; the search's path alone solved more episodes (docs/results.md, closed loop)
DEFAULT_CANDIDATES = ()


@dataclasses.dataclass
class Session:
  """A planner session over E episodes: `plan` plans from their current states and answers
  with the best candidate (`choose`; the search's path alone without candidates); the session
  keeps its last answer between queries.

  env, actor_critic, config: as in `programs.plan` (the actor-critic's
    `deterministic_action(obs [B, O]) -> [B, A]` is the policy).
  search: a `programs.Programs` whose compiled programs the session reuses (None: built, with
    room for the remainder's replay).
  horizon: T, the actions an answer keeps and the policy's rollout takes at most (None: the
    env's episode length).
  candidates: which of `CANDIDATES` compete with the search's path ('remainder', 'policy';
    `DEFAULT_CANDIDATES`: none).
  chunk_iterations: as in `programs.plan`.
  mesh: a `jax.sharding.Mesh` over which the search splits the episodes
    (`sharding.ShardedSearch`; None: one device, `programs.plan` with its lane compaction).
  replay_remainder: the search's first chain lane replays the last answer's remainder from the
    new state inside the search's physics batches (`search.replay`), so the search goes on from
    where the last answer got without following it first (needs chain lanes and a search with
    room for it); None: wherever it can (a search built here gets the room).
  check: an `AnswerCheck` of each answer's first actions (None: none; `Answer.safe_length` is
    the length).
  fill_steps: the actions a closed loop executes per query: where an answer is shorter, the
    policy's actions up to fill_steps in all are followed from its end in the planner's physics
    and `Answer.fill_length` says how many it took before an invalid edge (0: not followed,
    fill_length None). That follow runs on a background thread after the answer is returned
    (fill_length a `PendingFill`, off the query's clock), so that a caller can execute the
    answer's own actions meanwhile (`episodes.run` does, and charges a longer wait to the next
    query).
  """

  env: base.Env
  actor_critic: object
  config: object
  search: Optional[programs.Programs] = None
  horizon: Optional[int] = None
  candidates: Sequence[str] = DEFAULT_CANDIDATES
  chunk_iterations: Optional[int] = None
  mesh: Optional[object] = None
  replay_remainder: Optional[bool] = None
  check: Optional[AnswerCheck] = None
  fill_steps: int = 0
  timing: dict = dataclasses.field(default_factory=dict)

  def __post_init__(self):
    if not (isinstance(self.candidates, (list, tuple, set, frozenset))
            and all(isinstance(c, str) for c in self.candidates)):
      raise ValueError(f'candidates must be a sequence of names from {", ".join(CANDIDATES)} '
                       f'(() for none), got {self.candidates!r}')
    self.candidates = tuple(self.candidates)
    unknown = sorted(set(self.candidates) - set(CANDIDATES))
    if unknown:
      raise ValueError(f'unknown replanning candidate {unknown[0]!r}; valid: '
                       f'{", ".join(CANDIDATES)}')
    if not hasattr(self.actor_critic, 'deterministic_action'):
      raise ValueError('replanning needs an actor-critic with deterministic_action(obs) (the '
                       'policy candidate)')
    if self.horizon is None:
      self.horizon = int(self.env.episode_length)
    if isinstance(self.horizon, bool) or not isinstance(self.horizon, int) or self.horizon < 1:
      raise ValueError(f'horizon must be a positive int, got {self.horizon!r}')
    if self.replay_remainder is None:  # wherever the search can
      self.replay_remainder = bool(self.config.rollout_lanes) and (
          self.search is None or self.search.search.sizes.replay >= self.horizon)
    if not isinstance(self.replay_remainder, bool):
      raise ValueError(f'replay_remainder must be a bool or None, got {self.replay_remainder!r}')
    if self.replay_remainder and not self.config.rollout_lanes:
      raise ValueError('replay_remainder needs chain lanes (SearchConfig.rollout_share > 0)')
    if self.search is None:  # with room for the remainder's replay
      from pachs_jax.search.pachs import make_search  # pylint: disable=import-outside-toplevel
      self.search = programs.Programs(make_search(
          self.env, self.actor_critic, self.config, capacities=capacity.Capacities(
              replay=self.horizon if self.replay_remainder else 0)))
    if self.replay_remainder and self.search.search.sizes.replay < self.horizon:
      raise ValueError(f'the search replays paths of at most {self.search.search.sizes.replay} '
                       f'actions, the session keeps {self.horizon} (Capacities.replay)')
    if self.check is not None and not isinstance(self.check, AnswerCheck):
      raise ValueError(f'check must be an AnswerCheck or None, got {self.check!r}')
    if (isinstance(self.fill_steps, bool) or not isinstance(self.fill_steps, int)
        or self.fill_steps < 0):
      raise ValueError(f'fill_steps must be an int >= 0 (0: the fill not followed), got '
                       f'{self.fill_steps!r}')
    env, policy, check = self.env, self.actor_critic.deterministic_action, self.check
    fill_steps = self.fill_steps
    self._follow = jax.jit(lambda *args: follow(env, policy, *args))
    self._safe_length = None if check is None else jax.jit(
        lambda *args: safe_length(env, policy, check, *args))
    self._fill_length = None if not fill_steps else jax.jit(  # (live [E]: the episodes searched)
        lambda end, length, live: fill_length(env, policy, end,
                                              jnp.where(live, length, fill_steps), fill_steps))
    self._choose = jax.jit(choose, static_argnums=3)
    self._remainder = jax.jit(remainder)
    self._compiled = {}  # episodes -> the compiled follow
    self._checks = {}  # episodes -> the compiled check
    self._fills = {}  # episodes -> the compiled fill_length
    self._warmed = set()  # episodes whose programs ran a throwaway answer (`answer`)
    self._background = (concurrent.futures.ThreadPoolExecutor(1, 'pachs-fill') if fill_steps
                        else None)
    self._sharded = (None if self.mesh is None
                     else sharding.ShardedSearch(self.search.search, self.mesh))
    self.last: Optional[Answer] = None
    self.followed = {}  # the last query's candidates: 'remainder', 'policy' -> Followed [E]

  def _check_states(self, states) -> int:
    """E, the episodes of states [E] (ValueError unless the env's NodeState [E, ...])."""
    want = type(self.env.node_spec)
    if type(states) is not want:  # pylint: disable=unidiomatic-typecheck
      raise ValueError(f'states must be the env\'s {want.__name__} [E, ...], got '
                       f'{type(states).__name__}')
    return check_start_nodes(states, self.env)

  def reset(self) -> None:
    """Forgets the last answer (new episodes)."""
    self.last = None

  def plan(self, states: base.NodeState, executed=None, key: jax.Array = None,
           time_limit_s: Optional[float] = None, active=None) -> Answer:
    """The `Answer` [E] from the episodes' current states [E].

    executed: [E] ints, the actions of the last answer executed since it was given
      (`DIVERGED` where the episode did something else); None: the last answer is dropped.
    key: one PRNG key or per-episode keys [E, 2] (None: PRNGKey(0)).
    time_limit_s: the whole query's wall clock (s): following the candidates, the search and
      the choice; None searches to the end of the budget. The first clocked query of a bucket
      first runs a throwaway answer, unclocked (compiling, and the first runs' lazy loads).
    active: [E] bool the episodes to search (None: all); the others' searches stop at once
      (their answer: a candidate's, or none). One device only (a mesh searches all).
    """
    num = self._check_states(states)
    key = jax.random.PRNGKey(0) if key is None else key
    if self.last is not None and self.last.length.shape[0] != num:
      raise ValueError(f'the session plans {self.last.length.shape[0]} episodes, got {num} '
                       'states (reset() starts new episodes)')
    horizon, action_size = self.horizon, self.env.action_size
    done = None if executed is None else _counts(executed, num)
    if self.last is None or done is None or not (
        'remainder' in self.candidates or self.replay_remainder):
      actions = jnp.zeros((num, horizon, action_size), jnp.float32)
      length = jnp.zeros((num,), jnp.int32)
    else:
      actions, length = self._remainder(self.last.actions, self.last.length, jnp.asarray(done))
    self.last = self.answer(states, actions, length, key, time_limit_s, active=active)
    return self.last

  def answer(self, states: base.NodeState, actions: jax.Array, length: jax.Array,
             key: jax.Array = None, time_limit_s: Optional[float] = None,
             bucket: Optional[int] = None, active=None) -> Answer:
    """The `Answer` [E] from states [E] given each episode's remainder candidate, actions
    [E, T, A] of length [E] (length 0: none), without the session's last answer (`plan` keeps
    that; a server that keeps its clients' answers itself calls this). key, time_limit_s as in
    `plan`, active as there. The remainder is followed where 'remainder' is a candidate and replayed by the
    search where replay_remainder. bucket: a power of two >= E that the follow and the search are
    padded to (one compiled program for every E up to it; None: E's own bucket)."""
    num = self._check_states(states)
    key = jax.random.PRNGKey(0) if key is None else key
    _check_query(time_limit_s, active, num)
    try:
      instance_keys(key, num)
    except (TypeError, ValueError):
      raise ValueError(f'key must be one PRNG key or [{num}, 2] keys, got {key!r}') from None
    horizon = self.horizon
    replay = (actions, length) if self.replay_remainder else None
    if 'remainder' not in self.candidates:  # nothing to follow
      length = jnp.zeros_like(length)
    rows = num if bucket is None else bucket
    if rows < num:
      raise ValueError(f'bucket {bucket} holds fewer than the {num} episodes')
    if time_limit_s is not None and rows not in self._warmed:
      # a throwaway answer first, unclocked: the choice compiles and each program's first run
      # loads what it loads lazily (MuJoCo Warp's kernel modules) off this query's clock, and
      # the next query's clock keeps no first run's time in reserve
      self._warmed.add(rows)
      warm = self.answer(states, actions, length, key, WARM_UP_S, bucket, active)
      if isinstance(warm.fill_length, PendingFill):
        warm.fill_length.result()
      self.timing.pop('choose_s', None)
    pad = lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], rows - num, axis=0)]) \
        if rows > num else x
    # the remainder and the policy's rollout in one batch [2 rows]
    use_policy = np.repeat(np.array([False, 'policy' in self.candidates]), rows)
    both = jax.tree.map(lambda x: jnp.concatenate([pad(x), pad(x)]), states)
    args = (both, jnp.concatenate([pad(actions), pad(actions)]),
            jnp.concatenate([pad(length), jnp.full((rows,), horizon if use_policy[-1] else 0,
                                                   jnp.int32)]),
            jnp.asarray(use_policy))
    if rows not in self._compiled:  # compiled before the query's clock, as the search is
      self._compiled[rows] = self._follow.lower(*args).compile()
    if self.check is not None:  # each episode's own keys for its perturbed copies
      check_starts = jax.tree.map(pad, states)
      check_keys = jax.vmap(lambda k: jax.random.fold_in(k, CHECK_STREAM))(
          pad(instance_keys(key, num)))
      if rows not in self._checks:  # (args: the remainders [2 rows], the first row an answer's)
        self._checks[rows] = self._safe_length.lower(
            check_starts, args[1][:rows], args[2][:rows], check_keys).compile()
    if self._fill_length is not None and rows not in self._fills:  # (an answer's end states)
      self._fills[rows] = self._fill_length.lower(
          jax.tree.map(pad, states), jnp.zeros((rows,), jnp.int32),
          np.ones((rows,), bool)).compile()
    began = time.perf_counter()
    followed = jax.block_until_ready(self._compiled[rows](*args))
    last = jax.tree.map(lambda x: x[:num], followed)
    policy = jax.tree.map(lambda x: x[rows:rows + num], followed)
    self.followed = {'remainder': last, 'policy': policy}
    self.timing['follow_s'] = time.perf_counter() - began
    left = None
    if time_limit_s is not None:
      left = max(time_limit_s - (time.perf_counter() - began)
                 - self.timing.get('choose_s', 0.0), 1e-3)
    if self._sharded is not None:
      result = self._sharded.plan(states, key, time_limit_s=left, min_bucket=bucket,
                                  replay=replay)
      # on the default device, as one device's search leaves it: the follow and the choice
      # are compiled for one device
      result = jax.device_put(result, jax.devices()[0])
    else:
      result = programs.plan(self.env, self.actor_critic, states, self.config, key,
                             time_limit_s=left, chunk_iterations=self.chunk_iterations,
                             search=self.search, min_bucket=bucket, replay=replay, live=active)
    choosing = time.perf_counter()
    # the choice (and the check) in the padded batch too (its rows after num dropped)
    grow = lambda x: pad(x) if jnp.ndim(x) else x  # (a scalar: the wall time)
    answer = self._choose(jax.tree.map(grow, result), jax.tree.map(grow, last),
                          jax.tree.map(grow, policy), horizon)
    if self.check is not None:
      answer = answer.replace(safe_length=self._checks[rows](
          check_starts, answer.actions, answer.length, check_keys))
    padded = answer
    answer = jax.block_until_ready(jax.tree.map(lambda x: x[:num] if jnp.ndim(x) else x, answer))
    self.timing['choose_s'] = time.perf_counter() - choosing  # the check's included
    if self._fill_length is None:
      return answer
    # the policy from each answer's end (its last state row), of the searched episodes only
    # (no padding), on a thread once the answer is ready (its physics' loops hold the thread
    # that runs them), while the caller executes the answer
    live = np.arange(rows) < num
    if active is not None:
      live[:num] &= np.asarray(active)
    return answer.replace(fill_length=PendingFill(self._background.submit(
        lambda run, ends, length: np.asarray(run(ends, length, live))[:num], self._fills[rows],
        jax.tree.map(lambda x: x[:, -1], padded.states), padded.length)))
