"""Plan, execute, observe: episodes in MuJoCo C worlds (float64) driven by a replanning session
(`replan.Session`): each query's first actions run in the worlds, which are observed and planned
from again (docs/closed_loop.md). PushT's worlds are `world.World`s, a Playground task's
`playground_world.PlaygroundWorld`s."""

from __future__ import annotations

import dataclasses
import time
from typing import Callable, List, Optional

import jax
import jax.numpy as jnp
import numpy as np

from pachs_jax import replan
from pachs_jax.envs import base, playground, playground_world
from pachs_jax.envs import world as world_lib
from pachs_jax.search.checks import check_seconds


# a query's clock is never cut below this share of the loop's by a fill's wait
MIN_CLOCK_SHARE = 0.5


def make_worlds(env: base.Env, num: int,
                perturbation: Optional[world_lib.Perturbation] = None) -> list:
  """num MuJoCo C worlds of env: `world.World`s of a PushT env (any backend), or
  `playground_world.PlaygroundWorld`s of a Playground task (one `WorldSteps` shared)."""
  if isinstance(env, playground.PlaygroundEnv):
    if perturbation is not None:
      raise ValueError(f'a perturbation applies to the PushT worlds, not to {env.name}')
    steps = playground_world.WorldSteps(env)
    return [playground_world.PlaygroundWorld(env, steps) for _ in range(num)]
  return [world_lib.World(env, perturbation) for _ in range(num)]


class Worlds:
  """E worlds in MuJoCo C (`make_worlds`), each with its success bookkeeping and the states it
  went through.

  env: the PushT env (any backend) or Playground task whose model and control rule the worlds
    use.
  starts: NodeState [E] the episodes' start states.
  perturbation: a `world_lib.Perturbation` of PushT worlds' models (None: the env's model).
  """

  def __init__(self, env: base.Env, starts: base.NodeState,
               perturbation: Optional[world_lib.Perturbation] = None):
    self.env = env
    self.num = num = jax.tree.leaves(starts)[0].shape[0]
    self.worlds = make_worlds(env, num, perturbation)
    self.nodes = [w.reset(jax.tree.map(lambda x, i=i: np.asarray(x[i]), starts))
                  for i, w in enumerate(self.worlds)]
    self.visited: List[List[base.NodeState]] = [[node] for node in self.nodes]
    self.actions: List[List[np.ndarray]] = [[] for _ in self.nodes]  # [A] per step taken
    self.by_policy: List[List[bool]] = [[] for _ in self.nodes]  # the step was the policy's
    self._start_bookkeeping()

  def _start_bookkeeping(self) -> None:
    """Success (episodes that start at a goal count), failure (`env.is_failure`: no edge
    leaves the state), steps and the step of each success."""
    self.is_goal = jax.jit(self.env.is_goal)
    self.is_failure = jax.jit(self.env.is_failure)
    self.success = np.array(self.is_goal(self.batch()))
    self.failed = np.array(self.is_failure(self.batch())) & ~self.success
    self.steps = np.zeros(self.num, np.int64)
    self.success_step = np.full(self.num, -1, np.int64)

  @property
  def active(self) -> np.ndarray:
    """[E] bool the episodes that have neither reached the goal nor failed."""
    return ~self.success & ~self.failed

  def batch(self) -> base.NodeState:
    """NodeState [E] of the worlds' current states."""
    return jax.tree.map(jnp.asarray, world_lib.stack_nodes(self.nodes))

  def execute(self, actions: np.ndarray, lengths: np.ndarray,
              by_policy: Optional[np.ndarray] = None) -> None:
    """Runs actions [E, T, A], the first lengths[e] of each, in the active worlds, checking the
    goal after every step; by_policy [E] bool: episode e's first action is the policy's (the
    record of `trace`; None: none is)."""
    for j in range(actions.shape[1]):
      moving = self.active & (lengths > j)
      if not moving.any():
        break
      for e in np.flatnonzero(moving):
        self.nodes[e] = self.worlds[e].execute(actions[e, j:j + 1])[-1]
        self.visited[e].append(self.nodes[e])
        self.actions[e].append(np.asarray(actions[e, j]))
        self.by_policy[e].append(bool(by_policy is not None and by_policy[e] and j == 0))
        self.steps[e] += 1
      self._judge(moving)

  def _judge(self, moving: np.ndarray) -> None:
    batch = self.batch()
    reached = np.asarray(self.is_goal(batch)) & moving
    self.success_step[reached] = self.steps[reached]
    self.success |= reached
    self.failed |= np.asarray(self.is_failure(batch)) & moving & ~reached

  def trajectory(self, episode: int) -> base.NodeState:
    """NodeState [S + 1, ...] the states episode went through, the start first."""
    return world_lib.stack_nodes(self.visited[episode])


@dataclasses.dataclass
class Log:
  """What a closed loop did, per episode e of E.

  queries: [E] int the queries each episode made.
  answers: [E, len(AnswerKind.NAMES)] int its answers of each `replan.AnswerKind` (a planner
    whose answers have no kind: zeros).
  policy_steps: [E] int world steps the policy took: after a short answer, and one for an empty
    answer.
  failed_on_policy: [E] bool the episode failed (`Worlds.failed`) on a step the policy took.
  cut_answers: [E] int answers executed only up to their `safe_length` (`replan.AnswerCheck`).
  cut_fills: [E] int short answers whose policy fill stopped at the answer's `fill_length`
    (the planner's physics found the policy's next edge invalid there).
  plans: per query, (the world step of each episode when it was asked [E], the answer's
    states in the planner's physics NodeState [E, T + 1] (numpy), the answer's length [E]);
    for answers that carry their states.
  interrupted_at_query: the query before which `stop` ended the episodes (None: it did not).
  clock_s: per query, the clock it was given (s; None: none).
  fill_wait_s, charged_s: per answer with a fill_length, the s waited for it after the answer
    came, and the part of that wait charged to the next query (past the answer's own actions).
  """

  queries: np.ndarray
  answers: np.ndarray
  policy_steps: np.ndarray
  failed_on_policy: np.ndarray
  cut_answers: np.ndarray = None
  cut_fills: np.ndarray = None
  plans: list = dataclasses.field(default_factory=list)
  interrupted_at_query: Optional[int] = None
  clock_s: list = dataclasses.field(default_factory=list)
  fill_wait_s: list = dataclasses.field(default_factory=list)
  charged_s: list = dataclasses.field(default_factory=list)

  def executed_plans(self, episode: int, num_states: int) -> list:
    """Per world state s < num_states of `episode`, the answer being executed there (its
    planned states NodeState [L + 1], one object per query) or None before the first."""
    asked = []
    for at, states, length in self.plans:
      if at[episode] >= 0:
        n = int(length[episode])
        asked.append((int(at[episode]), jax.tree.map(lambda x, n=n: x[episode, :n + 1], states)))
    current, out = None, []
    for s in range(num_states):
      while asked and asked[0][0] <= s:
        current = asked.pop(0)[1]
      out.append(current)
    return out


def trace(worlds: Worlds, log: Log) -> dict:
  """What E episodes' worlds did and what their plans said there, numpy arrays padded past each
  episode's S_e steps (S the longest; NaN, False or -1):
  world_<field> [E, S + 1, ...]: the worlds' states as observed (NodeState fields: qpos, qvel,
    ctrl, qacc_warmstart), the start first; goal [E, ...];
  actions [E, S, A]: the actions executed; by_policy [E, S]: the step was the policy's (an
    empty answer's action or the fill after a short answer);
  planned_qpos [E, S + 1, nq]: the qpos that the answer being executed planned for the world's
    state s, in the planner's physics (NaN where it planned none: before its first query, past
    its length, or a planner whose answers carry no states);
  asked_at [Q, E]: the world state at which each query asked for episode e (-1: it had
    ended; queries whose answers carry no states are left out);
  steps [E]: S_e; success, failed [E]."""
  num, longest = worlds.num, int(worlds.steps.max(initial=0))
  paths = [worlds.trajectory(e) for e in range(num)]
  out = {}
  for name in ('qpos', 'qvel', 'ctrl', 'qacc_warmstart'):
    field = np.full((num, longest + 1) + getattr(paths[0], name).shape[1:], np.nan)
    for e, path in enumerate(paths):
      field[e, :len(path.t)] = getattr(path, name)
    out['world_' + name] = field
  out['goal'] = np.stack([path.goal[0] for path in paths])
  actions = np.full((num, longest, worlds.env.action_size), np.nan)
  by_policy = np.zeros((num, longest), bool)
  planned = np.full((num, longest + 1, paths[0].qpos.shape[-1]), np.nan)
  for e in range(num):
    taken = len(worlds.actions[e])
    if taken:
      actions[e, :taken] = np.stack(worlds.actions[e])
      by_policy[e, :taken] = worlds.by_policy[e]
    plans, begun = log.executed_plans(e, longest + 1), 0
    for s, plan in enumerate(plans):
      if plan is None:
        continue
      if s == 0 or plan is not plans[s - 1]:
        begun = s  # the world state its query asked at
      if s - begun < len(plan.qpos):
        planned[e, s] = plan.qpos[s - begun]
  asked_at = np.array([at for at, _, _ in log.plans], np.int64).reshape(-1, num)
  out.update(actions=actions, by_policy=by_policy, planned_qpos=planned, asked_at=asked_at,
             steps=worlds.steps.copy(), success=worlds.success.copy(),
             failed=worlds.failed.copy())
  return out


def video_frames(worlds: Worlds, log: Log, episode: int, title: str) -> np.ndarray:
  """frames [F, H, W, 3] uint8 of what episode's world did, the plan being executed drawn
  dashed: PushT drawn from above with title (`render.loop_frames`), a Playground task by
  MuJoCo's renderer (`playground_video.loop_frames`, no title)."""
  states = worlds.trajectory(episode)
  plans = log.executed_plans(episode, len(states.t))
  if isinstance(worlds.env, playground.PlaygroundEnv):
    from pachs_jax.envs import playground_video  # pylint: disable=import-outside-toplevel
    return playground_video.loop_frames(worlds.env, states, plans)
  from pachs_jax.envs import render  # pylint: disable=import-outside-toplevel  (matplotlib)
  return render.loop_frames(worlds.env, states, plans, title)


def control_period_s(env: Optional[base.Env]) -> float:
  """s of a robot's time per action of env: PushT's physics_dt x substeps, a Playground task's
  control dt; 0 for an env with no real time (the analytic envs, None)."""
  if isinstance(env, playground.PlaygroundEnv):
    return float(env.playground_env.dt)
  config = getattr(env, 'config', None)
  if hasattr(config, 'physics_dt') and hasattr(config, 'substeps'):
    return float(config.physics_dt) * int(config.substeps)
  return 0.0


def session_query(session: replan.Session) -> Callable:
  """query(nodes [E], keys [E, 2], executed [E], running [E], time_limit_s) -> the session's
  `replan.Answer` (numpy, but fill_length still being computed) of a time_limit_s query,
  searched for the running episodes (`run`'s planner)."""

  def query(nodes, keys, executed, running, time_limit_s):
    answer = session.plan(nodes, executed, keys, time_limit_s=time_limit_s, active=running)
    fill = answer.fill_length
    return jax.tree.map(np.asarray, answer.replace(fill_length=None)).replace(fill_length=fill)
  return query


def fill_cover_s(lengths: np.ndarray, running: np.ndarray, need: np.ndarray,
                 period_s: float) -> float:
  """s of a robot's time that executing the answers' own actions, lengths [E], covers before a
  fill is needed: the soonest episode to need its fill (need [E]: its answer is short; an empty
  answer's one policy action first), else the longest of the running episodes' actions (the
  next query waits for them)."""
  if need.any():
    return period_s * float(np.min(np.maximum(lengths[need], 1)))
  return period_s * float(np.max(lengths[running], initial=0))


def run(planner, worlds: Worlds, time_limit_s: Optional[float] = None, execute: int = 10,
        max_queries: int = 30, key: Optional[jax.Array] = None, fill_with_policy: bool = True,
        policy: Optional[Callable] = None, stop: Optional[Callable[[], bool]] = None,
        on_answer: Optional[Callable] = None, period_s: Optional[float] = None) -> Log:
  """Runs the worlds' episodes in closed loop: a query for all episodes still running, the
  first `execute` actions of each answer in its world (an empty answer: one action of the
  policy; a shorter answer followed by the policy's actions up to `execute` when
  fill_with_policy, at most the answer's `fill_length` where it has one; an answer with a
  shorter `safe_length`, `replan.AnswerCheck`: that many, then the next query), until every
  episode reached the goal or made max_queries queries.

  An answer's fill_length may still be computing when it comes (`replan.Session.fill_steps`):
  a robot executes the answer's own actions meanwhile, so a wait for it longer than those
  actions take (period_s each, `fill_cover_s`) is charged to the next query's clock
  (`Log.charged_s`).

  planner: a `replan.Session` (reset, then asked for `time_limit_s` s per query), or
    query(nodes [E], keys [E, 2], executed [E], running [E], time_limit_s) -> an answer with
    actions [E, T, A] and length [E] (numpy; its kind and states are logged where it has them).
    executed: the actions of the last answer executed (`replan.DIVERGED` where the policy
    moved the episode after it); running: the episodes still going (`Worlds.active`);
    time_limit_s: the query's clock (s; None: the planner's own).
  key: the PRNG key each query's per-episode keys are folded from (None: PRNGKey(0)).
  policy: nodes [E] -> actions [E, A] (None: the session's deterministic actor).
  stop: checked before each query; once True the episodes end where they are.
  on_answer(query, nodes, running [E], executed [E], answer, seconds): after each query.
  period_s: s of a robot's time per action (None: `control_period_s` of the worlds' env).
  """
  if isinstance(planner, replan.Session):
    query = session_query(planner)
    planner.reset()
    if policy is None:
      env, model = planner.env, planner.actor_critic
      policy = jax.jit(lambda nodes: model.deterministic_action(env.observe(nodes)))
  else:
    query = planner
  if policy is None:
    raise ValueError('run needs the policy that fills short answers (policy=...)')
  check_seconds(time_limit_s, 'time_limit_s')
  period_s = control_period_s(getattr(worlds, 'env', None)) if period_s is None else period_s
  num = worlds.num
  log = Log(queries=np.zeros(num, np.int64),
            answers=np.zeros((num, len(replan.AnswerKind.NAMES)), np.int64),
            policy_steps=np.zeros(num, np.int64), failed_on_policy=np.zeros(num, bool),
            cut_answers=np.zeros(num, np.int64), cut_fills=np.zeros(num, np.int64))
  key = jax.random.PRNGKey(0) if key is None else key
  executed = np.zeros(num, np.int64)
  charge = 0.0  # s the last fill's wait takes from this query's clock
  for number in range(max_queries):
    running = worlds.active
    if not running.any():
      break
    if stop is not None and stop():
      log.interrupted_at_query = number
      break
    nodes = worlds.batch()
    keys = jax.vmap(lambda i, q=number: jax.random.fold_in(jax.random.fold_in(key, q), i))(
        jnp.arange(num))
    limit = None if time_limit_s is None else max(time_limit_s - charge,
                                                   MIN_CLOCK_SHARE * time_limit_s)
    log.clock_s.append(limit)
    began = time.perf_counter()
    answer = query(nodes, keys, executed, running, limit)
    answered = time.perf_counter()
    lengths = np.minimum(answer.length, execute)
    # an answer that a check cut (`replan.AnswerCheck`) is executed up to its safe length, then
    # replanned at once: no policy fill
    safe = getattr(answer, 'safe_length', None)
    safe = lengths if safe is None else np.asarray(safe)
    cut = running & (safe < lengths)
    lengths = np.where(cut, safe, lengths)
    fill, charge = getattr(answer, 'fill_length', None), 0.0
    if fill is not None:  # followed while the answer's own actions execute: a wait past them
      fill = np.asarray(fill)  # is the next query's
      waited = time.perf_counter() - answered
      short = running & ~cut & (lengths < execute) if fill_with_policy else np.zeros(num, bool)
      charge = max(0.0, waited - fill_cover_s(lengths, running, short, period_s))
      log.fill_wait_s.append(waited)
      log.charged_s.append(charge)
    if on_answer is not None:
      on_answer(number, nodes, running, executed, answer, answered - began)
    log.queries += running
    if getattr(answer, 'kind', None) is not None:
      log.answers[np.flatnonzero(running), answer.kind[running]] += 1
      log.plans.append((np.where(running, worlds.steps, -1), answer.states, answer.length))
    log.cut_answers += cut
    actions = answer.actions[:, :execute]
    # the policy's steps stop at the answer's fill length (where the session followed it)
    fill_ends = np.full(num, execute) if fill is None else lengths + fill
    empty = running & (lengths == 0)
    if empty.any():  # one action of the policy where the answer has none
      actions = actions.copy()
      actions[empty, 0] = np.asarray(policy(nodes))[empty]
      lengths = np.where(empty, 1, lengths)
      log.policy_steps += empty
    failed = worlds.failed.copy()
    worlds.execute(actions, lengths, by_policy=empty)
    log.failed_on_policy |= empty & worlds.failed & ~failed
    # the answer's actions executed; an episode the policy moved diverges from it
    moved = empty.copy()
    if fill_with_policy:
      for j in range(1, execute):
        need = worlds.active & (lengths <= j) & ~cut
        log.cut_fills += need & (j == np.maximum(fill_ends, 1))
        need &= j < fill_ends
        if not need.any():
          continue
        log.policy_steps += need
        moved |= need
        failed = worlds.failed.copy()
        worlds.execute(np.asarray(policy(worlds.batch()))[:, None], need.astype(np.int64),
                       by_policy=need)
        log.failed_on_policy |= worlds.failed & ~failed
    executed = np.where(moved, replan.DIVERGED, lengths)
  return log
