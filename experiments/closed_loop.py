"""Closed loop: plans made with MJX or Warp (float32) executed in MuJoCo C worlds (float64).

The protocol is the original's (README, 'Closed loop'); all episodes of a planner share each
query's wall clock; `--perturb` scales the worlds' parameters (`world_lib.Perturbation`);
`--world planner` executes the plans in the planners' own edge physics instead, so that they
transfer (up to the numerics of another batch size). PushT tasks, and Playground tasks
(`--task playground:NAME`: worlds `playground_world.PlaygroundWorld`)."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import os
import sys
import time
from typing import Dict, List, Optional

import numpy as np

import common
from pachs_jax import argtypes, flags

PLANNERS = ('single', 'parallel', 'pachs', 'pachs-original', 'mppi')
# physics batches of PACHS and the parallel rollout: the lanes of the episodes still running,
# gathered, once they fit one of these fractions of the full batch
COMPACT_FRACTIONS = (0.75, 0.5, 0.25, 0.125)
WORLDS = ('mujoco-c', 'planner')


def _task(text: str) -> str:
  """--task: a PushT task or 'playground:NAME' (NAME checked when its env is made)."""
  if text in ('pusht-fixed', 'pusht-rand', 'pusht-obs') or (
      text.startswith('playground:') and len(text) > len('playground:')):
    return text
  raise argparse.ArgumentTypeError(f"{text!r}: pusht-fixed, pusht-rand, pusht-obs or "
                                   'playground:NAME')


def build_parser() -> argtypes.OneLineParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argtypes.OneLineParser(description=__doc__.splitlines()[0])
  parser.add_argument('--task', default='pusht-fixed', type=_task,
                      help="pusht-fixed (default), pusht-rand, pusht-obs or playground:NAME")
  parser.add_argument('--planners', default=','.join(PLANNERS))
  parser.add_argument('--rounds', type=argtypes.positive_int, default=5)
  parser.add_argument('--query-time', type=argtypes.positive_float, default=3.0,
                      help="s per planning query; with Warp or MJX physics on a GPU it also "
                      "chooses PACHS's K, the task's for that query time, unless -K is given")
  parser.add_argument('--execute', type=argtypes.positive_int, default=10,
                      help='actions executed per query')
  parser.add_argument('--max-queries', type=argtypes.positive_int, default=30)
  parser.add_argument('--fill-with-policy', type=int, default=1, choices=[0, 1],
                      help='1: a path shorter than --execute is followed by policy actions up '
                      'to --execute world steps per query')
  parser.add_argument('--fill-check', type=int, default=None, choices=[0, 1],
                      help="1: PACHS's session follows each short answer's policy fill in the "
                      "planner's physics and the fill stops before the first invalid edge there "
                      "(a T tipped over), the next query sooner (replan.Session.fill_steps); "
                      "default: for an in-process PACHS that fills with the policy, the task's "
                      "for the query time (planner.replan_fill_check), else 0")
  parser.add_argument('--budget', type=argtypes.positive_int, default=100_000,
                      help='evaluation budget per query and episode')
  parser.add_argument('--copies', type=argtypes.positive_int, default=256,
                      help='parallel-rollout copies')
  flags.add_search_flags(parser, ['realtime_answer', 'pop_size', 'edge_steps',
                                 'chain_restart', 'improve_allowance', 'compact_fractions'],
                         defaults={'compact_fractions': COMPACT_FRACTIONS})
  parser.add_argument('--candidates', default=None,
                      type=lambda text: tuple(c for c in text.split(',') if c),
                      help="what competes with PACHS's path in each query (replan.Session): "
                      "'remainder' (the last answer's unexecuted actions), 'policy' (the "
                      "policy's rollout); '' (the default) the search's path alone")
  parser.add_argument('--replay-remainder', type=int, default=None, choices=[0, 1],
                      help="1: each PACHS search's first chain lane replays the last answer's "
                      'remainder (replan.Session.replay_remainder); 0: not; default: where '
                      'the search has chain lanes')
  parser.add_argument('--chunk-iterations', type=argtypes.positive_int, default=1,
                      help='PACHS / parallel-rollout iterations between wall-clock checks')
  parser.add_argument('--check-copies', type=argtypes.integer(low=0), default=0,
                      help="PACHS (PushT): each answer's first --execute actions followed from "
                      "this many perturbed copies of its start (the T moved 1 mm and turned "
                      "0.01 rad, standard deviations, times --check-scale) and executed only up "
                      "to the first a copy could not take, then replanned (replan.AnswerCheck; "
                      "default 0: no check)")
  parser.add_argument('--check-scale', type=argtypes.positive_float, default=1.0,
                      help='scale of the --check-copies perturbation (default 1)')
  parser.add_argument('--server', default=None,
                      help="plan 'pachs' through a running `pachs serve` at this URL (its task, "
                      'budget and settings; docs/serving.md)')
  parser.add_argument('--perturb', default='', help="world parameter scales, e.g. "
                      "'friction=1.2,t_mass=0.8'")
  parser.add_argument('--trace', type=int, default=0, choices=[0, 1],
                      help="1: also write each planner's episodes, the worlds' states, the "
                      'actions executed and the states PACHS planned for them, as '
                      "<out>.<planner>.trace.npz (MuJoCo C worlds; episodes.trace)")
  parser.add_argument('--world', default='mujoco-c', choices=WORLDS,
                      help="where the plans run: MuJoCo C worlds (float64), or 'planner': the "
                      "planners' own edge physics (--backend), so that plans transfer")
  common.add_common_args(parser, out=None, instances=20, backend=True, seed=True, layout=True,
                         physics=True)
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import stats  # noqa: E402
from pachs_jax import planner, replan, trees  # noqa: E402
from pachs_jax.runtime import anytime, compile_cache, programs, signals  # noqa: E402
from pachs_jax import episodes as episodes_lib  # noqa: E402
from pachs_jax.episodes import Worlds  # noqa: E402
from pachs_jax.envs import pusht, world as world_lib  # noqa: E402
from pachs_jax.search import baselines as bl  # noqa: E402
from pachs_jax.search import compact, memory  # noqa: E402
from pachs_jax.search.result import StopReason  # noqa: E402
# pylint: enable=wrong-import-position


def parse_perturbation(text: str) -> world_lib.Perturbation:
  if not text:
    return world_lib.Perturbation()
  values = {}
  for item in text.split(','):
    name, _, value = item.partition('=')
    if name not in {f.name for f in dataclasses.fields(world_lib.Perturbation)}:
      raise ValueError(f'unknown perturbation {name!r}; valid: '
                       f'{[f.name for f in dataclasses.fields(world_lib.Perturbation)]}')
    try:
      values[name] = float(value)
    except ValueError:
      raise ValueError(f'--perturb {name}: a number, got {value!r}') from None
  return world_lib.Perturbation(**values)



class PlannerWorldEpisodes(Worlds):
  """E episodes whose world is the planners' own edge physics (`env.evaluate`, one batched
  call per step), so that a plan replays as it was planned."""

  def __init__(self, env, starts):
    self.env = env
    self.num = jax.tree.leaves(starts)[0].shape[0]
    self.nodes = jax.tree.map(jnp.asarray, starts)
    self._step = jax.jit(lambda nodes, actions, moving: trees.where(
        moving, env.evaluate(nodes, actions).next_node, nodes))
    self._start_bookkeeping()

  def batch(self):
    return self.nodes

  def execute(self, actions: np.ndarray, lengths: np.ndarray, by_policy=None) -> None:
    for j in range(actions.shape[1]):
      moving = self.active & (lengths > j)
      if not moving.any():
        break
      self.nodes = self._step(self.nodes, jnp.asarray(actions[:, j], jnp.float32),
                              jnp.asarray(moving))
      self.steps[moving] += 1
      self._judge(moving)


def policy_actions(env, model):
  """jitted nodes [E] -> [E, A] deterministic actions of the policy."""
  return jax.jit(lambda nodes: model.deterministic_action(env.observe(nodes)))


@dataclasses.dataclass
class Asked:
  """A query's answer for `episodes.run` and the planner's row: actions [E, T, A] and length
  [E] (numpy), evaluated [E] edge evaluations, found [E] the answer ends at a goal, info: a
  session's extras (`SessionAnswers`), safe_length [E]: the actions to execute where an
  `AnswerCheck` ran (None: length)."""

  actions: np.ndarray
  length: np.ndarray
  evaluated: np.ndarray
  found: np.ndarray
  info: dict
  safe_length: Optional[np.ndarray] = None
  fill_length: Optional[np.ndarray] = None  # `replan.Answer.fill_length` (--fill-check, or a
                                            # server with fill steps)
  kind: Optional[np.ndarray] = None  # with --trace: the session's `replan.AnswerKind` [E]
  states: Optional[object] = None  # with --trace: the answer's states NodeState [E, T + 1]


def pachs_config(name: str, task: str, env, args):
  """The SearchConfig of planner `name` (pachs: the default, K from the query time unless -K
  says; pachs-original: the published algorithm) under the command line's settings."""
  algorithm = 'original' if name == 'pachs-original' else 'pachs'
  overrides = flags.search_overrides(args)
  if algorithm == 'pachs' and overrides.get('pop_size') is None:  # K from the query time
    overrides['pop_size'] = planner.replan_pop_size(task, args.query_time, env.physics)
  return planner.default_config(task, algorithm, budget=args.budget, **overrides)


def rollout_config(args) -> bl.ParallelRolloutConfig:
  """The parallel rollout's config under the command line's --copies and --budget."""
  return bl.ParallelRolloutConfig(num_copies=args.copies, budget=args.budget)


def check_rollout_memory(env, model, starts, args) -> None:
  """ValueError naming --copies when the parallel rollout's state for the episodes' starts
  [E] (their copies' states; traced, nothing compiled) exceeds the device's memory."""
  rollout = bl.make_parallel_rollout(env, model, rollout_config(args))
  num = jax.tree.leaves(starts)[0].shape[0]
  keys = jax.ShapeDtypeStruct((num, 2), jnp.uint32)
  need = memory.tree_bytes(jax.eval_shape(rollout.init, starts, keys))
  available, where = memory.device_memory()
  if need > available:
    raise ValueError(f'--copies {args.copies}: the parallel rollout of {num} episode{"s" * (num > 1)} keeps '
                     f'{need / 1e9:.3g} GB of state, but {where}: lower --copies, or run fewer '
                     '--instances or --rounds')


def make_query(name: str, task: str, env, model, args, num: int):
  """(query(nodes [E], keys [E, 2], executed [E], running [E]) -> `Asked`, the planner's
  config).

  Every planner's clock covers the whole query, its result included (`anytime.timed_result`).
  parallel: steps in chunks, then its best rollout; pachs: real-time mode
  (`--realtime-answer`); mppi: warm-started from the policy, then from its previous plan shifted
  by the executed actions."""
  if name == 'pachs' and args.server:
    return served_query(task, args, num)
  if name in ('pachs', 'pachs-original'):  # the default PACHS, or the published algorithm
    config = pachs_config(name, task, env, args)
    check = None
    if args.check_copies:
      check = replan.AnswerCheck(functools.partial(
          pusht.perturb_t, position_m=0.001 * args.check_scale,
          yaw_rad=0.01 * args.check_scale), copies=args.check_copies, steps=args.execute)
    session = replan.Session(env, model, config, candidates=args.candidates,
                             replay_remainder=(None if args.replay_remainder is None
                                               else bool(args.replay_remainder)),
                             chunk_iterations=args.chunk_iterations, check=check,
                             fill_steps=args.execute if args.fill_check else 0)

    session_query = episodes_lib.session_query(session)

    def query(nodes, keys, executed, running, time_limit_s):
      answer = session_query(nodes, keys, executed, running, time_limit_s)
      search = answer.search
      return Asked(answer.actions, answer.length, search.evaluated, answer.reaches_goal,
              {'kind': answer.kind, 'search_length': search.path_length,
               'generated': search.generated, 'invalid': search.invalid,
               'iterations': search.iterations, 'stop': search.stop_reason,
               'lane_utilization': search.lane_utilization,
               'search_s': float(search.wall_time_s), 'follow_s': session.timing['follow_s'],
               'choose_s': session.timing['choose_s'],
               'remainder_followed': 'remainder' in session.candidates,
               'remainder_steps': np.asarray(session.followed['remainder'].steps),
               'remainder_goal': np.asarray(session.followed['remainder'].reached_goal)},
              safe_length=answer.safe_length if check is not None else None,
              fill_length=answer.fill_length,
              **({'kind': answer.kind, 'states': answer.states} if args.trace else {}))
    return query, config
  if name == 'parallel':
    config = rollout_config(args)
    rollout = bl.make_parallel_rollout(env, model, config)
    # physics batches as PACHS's: the copies of the episodes still running, gathered
    sizes = compact.batch_sizes(num * args.copies, args.compact_fractions, minimum=args.copies)
    compiled, steps, timing = {}, {}, {}
    episodes_at_goal = jax.jit(env.is_goal)

    def query(nodes, keys, executed, running, time_limit_s):
      if not compiled:  # compiled in the first query, before its clock, as PACHS and MPPI are
        shape = jax.eval_shape(rollout.init, nodes, keys)
        compiled.update(init=rollout.init.lower(nodes, keys).compile(),
                        **{f: getattr(rollout, f).lower(shape).compile()
                           for f in ('stop', 'result')})
        steps.update({s: rollout.step.lower(shape, size=s).compile() for s in (None,) + sizes})
        # one unclocked run of each program, as PACHS's: what a program's first run loads
        # lazily (MuJoCo Warp's kernel modules, XLA's kernels) is on no query's clock
        warm = compiled['init'](nodes, keys)
        for step in steps.values():
          warm = step(warm)
        jax.block_until_ready(compiled['result'](compiled['stop'](warm)))
      # the smallest batch that holds the running episodes' copies (instances only stop)
      live = int(np.sum(~np.asarray(episodes_at_goal(nodes)))) * args.copies
      size = next((s for s in sizes if s >= live), None)

      def chunk(state):
        for _ in range(args.chunk_iterations):
          state = steps[size](state)
        return state

      # the clock covers init, the steps, and the stop and result (timed as their last runs),
      # as in PACHS and MPPI; at the limit the unfinished copies compete too (TIME_LIMIT)
      start = time.perf_counter()
      out = anytime.timed_result(chunk, compiled['init'](nodes, keys),
                                 lambda state: compiled['result'](compiled['stop'](state)),
                                 time_limit_s, start, timing)
      return Asked(np.asarray(out.path_actions), np.asarray(out.path_length),
                   np.asarray(out.evaluated), np.asarray(out.found),
                   {'iterations': np.asarray(out.iterations)})
    return query, config
  if name == 'mppi':
    config = bl.MppiConfig(budget=args.budget)
    config = dataclasses.replace(config, max_iterations=config.budget
                                 // config.evaluations_per_iteration)
    mppi = bl.make_mppi(env, model, config)
    previous, timing, compiled = {}, {}, {}  # (compiled: its programs, kept between queries)

    def query(nodes, keys, executed, running, time_limit_s):
      # warm start: the last plan without its executed actions (its last action repeated),
      # or the policy's rollout from the current state where nothing of it is left
      nominal = np.asarray(mppi.init(nodes, keys).nominal)
      if previous:
        left = previous['length'] - executed
        last = np.maximum(previous['length'] - 1, 0)
        idx = np.minimum(np.arange(config.horizon)[None] + executed[:, None], last[:, None])
        shifted = np.take_along_axis(previous['actions'], idx[:, :, None], axis=1)
        nominal = np.where((left > 0)[:, None, None], shifted, nominal)
      out = anytime.run_search(mppi, nodes, keys, jnp.asarray(nominal),
                               time_limit_s=time_limit_s, timing=timing, compiled=compiled)
      previous.update(actions=np.asarray(out.path_actions), length=np.asarray(out.path_length))
      return Asked(previous['actions'], previous['length'], np.asarray(out.evaluated),
                   np.asarray(out.found), {})
    return query, config
  raise ValueError(f'unknown planner {name!r}')


def served_query(task: str, args, num: int):
  """make_query's PACHS query through `pachs serve` at args.server: the episodes go out in
  requests of at most the server's max batch, each its own client and session, asked at once
  (the server gathers them), each with the episodes' own keys."""
  import concurrent.futures  # pylint: disable=import-outside-toplevel
  from pachs_jax import client  # pylint: disable=import-outside-toplevel
  with client.Client(args.server, task) as asking:
    health = asking.health()
  served = health['tasks'][task]
  if served['budget'] != args.budget:
    raise SystemExit(f'closed_loop.py: --budget {args.budget} differs from the server\'s '
                     f'{served["budget"]} for {task}')
  if args.pop_size is not None and served.get('pop_size') != args.pop_size:
    raise SystemExit(f'closed_loop.py: -K {args.pop_size} differs from the server\'s '
                     f'{served.get("pop_size")} for {task}')
  if served.get('fill_steps', 0) not in (0, args.execute):
    raise SystemExit(f'closed_loop.py: --execute {args.execute} differs from the server\'s '
                     f'fill steps {served["fill_steps"]} for {task}')
  size = health['max_batch']
  parts = [slice(i, min(i + size, num)) for i in range(0, num, size)]
  clients = [client.Client(args.server, task) for _ in parts]
  pool = concurrent.futures.ThreadPoolExecutor(len(parts))
  asked = [0]

  def query(nodes, keys, executed, running, time_limit_s):
    fields = client.node_fields(nodes)
    ask = lambda c, rows: c.plan({k: v[rows] for k, v in fields.items()},
                                 executed=np.asarray(executed)[rows], keys=np.asarray(keys)[rows],
                                 time_limit_s=time_limit_s, reset=asked[0] == 0)
    answers = list(pool.map(ask, clients, parts))
    asked[0] += 1
    join = lambda get: np.concatenate([get(a) for a in answers])
    return Asked(join(lambda a: a.actions), join(lambda a: a.length),
                 join(lambda a: a.evaluated), join(lambda a: a.reaches_goal),
            {'kind': join(lambda a: a.kind),
             'search_length': join(lambda a: a.search['path_length']),
             'generated': join(lambda a: a.search['generated']),
             'invalid': join(lambda a: a.search['invalid']),
             'iterations': join(lambda a: a.search['iterations']),
             'stop': join(lambda a: a.search['stop_reason']),
             'search_s': max(a.search_s for a in answers),
             'follow_s': max(a.follow_s for a in answers),
             'remainder_followed': bool(np.any(join(lambda a: a.remainder['steps']) > 0)),
             'remainder_steps': join(lambda a: a.remainder['steps']),
             'remainder_goal': join(lambda a: a.remainder['reaches_goal'])},
                 fill_length=(None if answers[0].fill_length is None
                              else join(lambda a: a.fill_length)))
  return query, (f'served by {args.server} ({health["backend"]}, budget {served["budget"]}, '
                 f'K {served.get("pop_size")}, '
                 f'max batch {size}, buckets {health["buckets"]})')


def run_single(env, model, episodes: Worlds, steps: int) -> List[float]:
  """The deterministic policy in the world for up to `steps` steps; returns per-step times."""
  act = policy_actions(env, model)
  times = []
  for _ in range(steps):
    if not episodes.active.any():
      break
    start = time.perf_counter()
    actions = np.asarray(act(episodes.batch()))[:, None]
    times.append(time.perf_counter() - start)
    episodes.execute(actions, np.ones(actions.shape[0], np.int64))
  return times


class SessionAnswers:
  """What a planner's queries answered, for its row: answers by kind (`replan.AnswerKind`);
  queries whose search returned no edge (stop reasons, evaluations, invalid edges, nodes
  generated, the T off the table square or tipped over: why it had nothing to say); the
  evaluations of the searches that ran to the clock, and how many ended before it (a goal found
  and improved); iterations, search and follow seconds per query (after the first, which
  compiles); and, where the
  remainder is followed, after a goal answer executed as given, whether its remainder still
  reaches the goal from the world's state (how well goal paths survive the world).
  is_pusht: the T's counts apply (a PushT task)."""

  def __init__(self, is_pusht: bool):
    self.is_pusht = is_pusht
    self.kinds = np.zeros(len(replan.AnswerKind.NAMES), np.int64)
    self.empty_search = {'queries': 0, 'stop': {}, 'evaluated': 0, 'invalid_edges': 0,
                         'only_start_generated': 0, 't_off_table': 0, 't_off_table_queries': 0,
                         't_tipped': 0, 't_tipped_queries': 0}
    self.iterations, self.search_s, self.follow_s, self.choose_s = [], [], [], []
    self.clocked, self.ended_before_clock = [], 0  # evaluations [per query and episode], count
    self.clocked_lanes, self.clocked_iterations = [], []  # of the clocked searches: evaluations
    # over their lanes' transitions, iterations
    self.first_iterations = []  # the running episodes' mean iterations at queries 0, 1, 2
    self.previous_goal, self.survival, self.followed = None, [0, 0], False

  def add(self, query: int, info: Dict, nodes, running, evaluated, executed, found) -> None:
    """One query's answers [E] (info: the query's extras) for the running episodes [E]."""
    if 'kind' in info:
      self.kinds += np.bincount(info['kind'][running], minlength=len(self.kinds))
      clocked = running & (info['stop'] == StopReason.TIME_LIMIT)
      self.clocked.extend(evaluated[clocked].tolist())
      if 'lane_utilization' in info:
        self.clocked_lanes.extend(np.asarray(info['lane_utilization'])[clocked].tolist())
        self.clocked_iterations.extend(np.asarray(info['iterations'])[clocked].tolist())
      self.ended_before_clock += int(np.sum(running & ~clocked))
      nothing = running & (info['search_length'] == 0)
      empty = self.empty_search
      empty['queries'] += int(nothing.sum())
      for code in info['stop'][nothing]:
        empty['stop'][StopReason.name(code)] = empty['stop'].get(StopReason.name(code), 0) + 1
      empty['evaluated'] += int(evaluated[nothing].sum())
      empty['invalid_edges'] += int(info['invalid'][nothing].sum())
      empty['only_start_generated'] += int(np.sum(info['generated'][nothing] <= 1))
      if self.is_pusht:
        outside = np.asarray(pusht.box_excess(nodes.qpos)) > 0
        empty['t_off_table'] += int(np.sum(outside & nothing))
        empty['t_off_table_queries'] += int(np.sum(outside & running))
        tipped = np.asarray(pusht.t_tilt(nodes.qpos)) >= pusht.MAX_T_TILT
        empty['t_tipped'] += int(np.sum(tipped & nothing))
        empty['t_tipped_queries'] += int(np.sum(tipped & running))
    if info.get('remainder_followed') and self.previous_goal is not None:
      kept = running & self.previous_goal & (np.asarray(executed) < replan.DIVERGED)
      self.survival[0] += int(kept.sum())
      self.survival[1] += int(np.sum(kept & info['remainder_goal']
                                     & (info['remainder_steps'] > 0)))
    self.followed = self.followed or bool(info.get('remainder_followed'))
    self.previous_goal = found.copy() if 'kind' in info else None
    if query < 3 and 'iterations' in info and running.any():
      self.first_iterations.append(float(np.mean(info['iterations'][running])))
    if query > 0 and 'iterations' in info:
      self.iterations.append(float(np.max(info['iterations'][running])))
      if 'search_s' in info:
        self.search_s.append(info['search_s'])
        self.follow_s.append(info['follow_s'])
      if 'choose_s' in info:  # (in process: the choice, the check and the fill's follow)
        self.choose_s.append(info['choose_s'])

  def summary(self) -> Dict:
    session = bool(self.kinds.any())
    return {'answers': ({n: int(c) for n, c in zip(replan.AnswerKind.NAMES, self.kinds)}
                        if session else None),
            'empty_search': self.empty_search if session else None,
            'iterations_per_query_mean': stats.mean_or_none(self.iterations),
            'iterations_first_queries': self.first_iterations or None,
            'evaluations_per_clocked_query_mean': stats.mean_or_none(self.clocked),
            'lane_utilization_clocked_mean': stats.mean_or_none(self.clocked_lanes),
            'iterations_per_clocked_query_mean': stats.mean_or_none(self.clocked_iterations),
            'searches_ended_before_clock': self.ended_before_clock if session else None,
            'goal_answers_followed': self.survival[0] if self.followed else None,
            'remainders_still_at_goal': self.survival[1] if self.followed else None,
            'search_s_mean': stats.mean_or_none(self.search_s),
            'follow_s_mean': stats.mean_or_none(self.follow_s),
            'choose_s_mean': stats.mean_or_none(self.choose_s)}


def run_planner(name, task, env, model, episodes: Worlds, args, key,
                stop=lambda: False, trace_path: Optional[str] = None) -> Dict:
  """Runs one planner's episodes (`pachs_jax.episodes.run`); stop() is checked before each
  query (a signal: the episodes end where they are, and the row says 'interrupted');
  trace_path: where `episodes.trace` of its episodes goes (npz; None: nowhere)."""
  num = episodes.num
  if name == 'single':
    times = run_single(env, model, episodes, args.max_queries * args.execute)
    return {'queries_per_episode_mean': None, 'step_time_s_mean': float(np.mean(times))}
  query, config = make_query(name, task, env, model, args, num)
  query_times, compile_s = [], [None]
  empty_answers, actions_per_query, evaluations_per_query = [0], [], []
  by_query = []  # [running episodes, goal answers] per query
  answers = SessionAnswers(is_pusht=task.startswith('pusht'))

  def on_answer(q, nodes, running, executed, answer, elapsed):
    answers.add(q, answer.info, nodes, running, answer.evaluated, executed, answer.found)
    if q == 0:
      compile_s[0] = elapsed  # the first query includes compilation
    else:
      query_times.append(elapsed)
    lengths = np.minimum(answer.length, args.execute)
    if answer.safe_length is not None:  # a checked answer runs to its safe length
      lengths = np.minimum(lengths, answer.safe_length)
    empty_answers[0] += int(np.sum((lengths == 0) & running))
    by_query.append([int(running.sum()), int(np.sum(answer.found & running))])
    actions_per_query.extend(lengths[running].tolist())
    evaluations_per_query.extend(answer.evaluated[running].tolist())

  log = episodes_lib.run(query, episodes, args.query_time, execute=args.execute,
                         max_queries=args.max_queries,
                         key=key, fill_with_policy=bool(args.fill_with_policy),
                         policy=policy_actions(env, model),
                         stop=stop, on_answer=on_answer)
  if trace_path:
    np.savez_compressed(trace_path, **episodes_lib.trace(episodes, log))
  return {'config': common.config_record(config),
          'interrupted_at_query': log.interrupted_at_query,
          'queries_per_episode_mean': float(np.mean(log.queries)),
          'query_time_s_mean': stats.mean_or_none(query_times),
          'query_time_s_max': float(np.max(query_times)) if query_times else None,
          'first_query_s_incl_compile': compile_s[0], 'empty_answers': empty_answers[0],
          'goal_answers': sum(goals for _, goals in by_query), 'goal_answers_by_query': by_query,
          'policy_fill_steps': int(log.policy_steps.sum()) - empty_answers[0],
          'failures_on_policy_steps': int(log.failed_on_policy.sum()),
          'cut_answers': int(log.cut_answers.sum()),
          'cut_fills': int(log.cut_fills.sum()),
          'fill_wait_s_mean': stats.mean_or_none(log.fill_wait_s),
          'fill_charged_s_mean': stats.mean_or_none(log.charged_s),
          'fill_charged_s_max': max(log.charged_s) if log.charged_s else None,
          'actions_per_query_mean': stats.mean_or_none(actions_per_query),
          'evaluations_per_query_mean': stats.mean_or_none(evaluations_per_query),
          **answers.summary()}

def fill_check(args, physics: str) -> int:
  """--fill-check as given, else where it applies (an in-process PACHS, no --server, that
  fills short answers with the policy, --fill-with-policy 1) the task's for the query time
  with the planners' physics (`planner.replan_fill_check`), else 0."""
  if args.fill_check is not None:
    return args.fill_check
  return int(args.server is None and bool(args.fill_with_policy)
             and planner.replan_fill_check(args.task, args.query_time, physics))


def main():
  parser = build_parser()
  args = parser.parse_args()
  if args.candidates is None:
    args.candidates = replan.DEFAULT_CANDIDATES
  if args.world == 'planner' and args.trace:
    parser.error('--trace records MuJoCo C worlds (--world mujoco-c)')
  if args.world == 'planner' and args.perturb:
    parser.error('--perturb applies to MuJoCo C worlds only (--world mujoco-c)')
  if args.check_copies and args.server:
    parser.error('--check-copies checks the answers of an in-process PACHS, not --server')
  if args.fill_check and (args.server or not args.fill_with_policy):
    parser.error('--fill-check follows the policy fill (--fill-with-policy 1) of an in-process '
                 'PACHS; a server checks it when started with pachs serve --fill-steps')
  common.check_layout(parser, args.task, args.layout)
  if args.task.startswith('playground:') and (args.perturb or args.check_copies):
    parser.error('--perturb and --check-copies apply to the PushT tasks')
  common.check_physics(parser, args.task, args.physics)
  common.task_instances(args.task, args.instances, parser)
  names = [n for n in args.planners.split(',') if n]
  unknown = [n for n in names if n not in PLANNERS]
  if not names or unknown:
    parser.error(f'--planners: {"unknown " + ", ".join(unknown) if unknown else "none named"}; '
                 f'valid: {", ".join(PLANNERS)}')
  unknown = sorted(set(args.candidates) - set(replan.CANDIDATES))
  if unknown:
    parser.error(f'--candidates: unknown {", ".join(unknown)}; valid: '
                 f'{", ".join(replan.CANDIDATES)}')
  for name in ('pachs', 'pachs-original'):  # a bad search setting before any work
    if name in names:
      config = common.checked(parser, lambda name=name: planner.default_config(
          args.task, 'original' if name == 'pachs-original' else 'pachs',
          budget=args.budget, **flags.search_overrides(args)))
      if args.replay_remainder and not config.rollout_lanes:
        parser.error(f'--replay-remainder 1: {name} on {args.task} has no chain lanes to '
                     'replay the remainder in (rollout share 0)')
  if args.server is not None and args.physics is not None:
    parser.error('--physics with --server: the server plans on the physics it was started with')
  if args.server is not None and 'pachs' in names:
    from pachs_jax import client  # pylint: disable=import-outside-toplevel
    try:
      with client.Client(args.server, args.task) as asking:
        args.server_device = asking.health().get('device')
    except Exception as err:  # pylint: disable=broad-except
      parser.error(f'--server {args.server!r}: no pachs serve answers there ({err})')
  perturbation = common.checked(parser, lambda: parse_perturbation(args.perturb))
  common.check_out(parser, args.out)
  label = common.task_label(args.task, args.layout, args.physics)
  out = args.out or f'experiments/results/closed_loop_{label}.json'

  compile_cache.enable()  # a later run of the same programs skips XLA's compilation
  env, model = common.checked(parser, lambda: planner.load_model(
      args.task, backend=args.backend, layout=args.layout, physics=args.physics))
  args.fill_check = fill_check(args, env.physics)
  starts = env.canonical_instances(args.instances)
  index = np.tile(np.arange(args.instances), args.rounds)
  starts = jax.tree.map(lambda x: np.asarray(x)[index], starts)
  for name in {'pachs', 'pachs-original'} & set(names) - ({'pachs'} if args.server else set()):
    # a search that cannot hold its budget, or does not fit the device, before any planner runs
    common.checked(parser, lambda name=name: programs.check_memory(
        env, model, starts, pachs_config(name, args.task, env, args)))
  if 'parallel' in names:
    common.checked(parser, lambda: check_rollout_memory(env, model, starts, args))
  payload = {'provenance': common.provenance(getattr(args, 'server_device', None)),
             'task': args.task, 'env': env.name,
             'settings': {k: v for k, v in vars(args).items() if k != 'out'},
             'perturbation': dataclasses.asdict(perturbation), 'summary': [], 'episodes': {}}
  # SIGINT or SIGTERM (a time limit's `timeout`): the running planner stops before its next
  # query and its episodes so far are written, marked interrupted; no later planner starts
  guard = signals.SignalGuard('closed_loop.py', 'stopping before the next query and writing '
                              'what ran; a second signal exits at once')
  with guard:
    stop = guard.keep()
    for name in names:
      if stop():
        break
      run_one(name, args, env, model, starts, perturbation, payload, out, stop)
  if payload['summary']:
    plot(payload, os.path.splitext(out)[0] + '.png')
  return guard.exit_code


def run_one(name, args, env, model, starts, perturbation, payload, out, stop) -> None:
  """One planner's episodes, their row added to payload and the files written."""
  episodes = (Worlds(env, starts, perturbation if args.perturb else None)
              if args.world == 'mujoco-c' else PlannerWorldEpisodes(env, starts))
  start = time.perf_counter()
  info = run_planner(name, args.task, env, model, episodes, args,
                     jax.random.PRNGKey(args.seed), stop,
                     f'{os.path.splitext(out)[0]}.{name}.trace.npz' if args.trace else None)
  total = time.perf_counter() - start
  k, n = int(episodes.success.sum()), episodes.num
  low, high = stats.instance_bootstrap_interval(episodes.success, np.arange(n) % args.instances)
  wilson = stats.wilson_interval(k, n)
  won = episodes.success_step[episodes.success]
  row = {'planner': name, 'episodes': n, 'successes': k, 'success_rate': k / n,
         'failures': int(episodes.failed.sum()),
         'ci95_low': low, 'ci95_high': high, 'wilson_ci95': list(wilson),
         'world_steps_failed_mean': stats.mean_where(episodes.steps, ~episodes.success),
         'steps_to_success_mean': stats.mean_or_none(won),
         'total_s': total, **info}
  print(row, flush=True)
  payload['summary'].append(row)
  payload['episodes'][name] = {'success': episodes.success.tolist(),
                               'failed': episodes.failed.tolist(),
                               'success_step': episodes.success_step.tolist(),
                               'steps': episodes.steps.tolist()}
  common.write_result(out, payload, markdown(payload))
  print(f'wrote {os.path.abspath(out)} and its .md', flush=True)


def markdown(payload: Dict) -> List[str]:
  """The markdown lines of a closed-loop result: settings, perturbation and the planners'
  summary rows."""
  rows = []
  for s in payload['summary']:
    rows.append(dict(s, success=f'{s["successes"]}/{s["episodes"]} = '
                     f'{100 * s["success_rate"]:.0f}% [{100 * s["ci95_low"]:.0f}, '
                     f'{100 * s["ci95_high"]:.0f}]'))
  world = ('MuJoCo C worlds' if payload['settings'].get('world', 'mujoco-c') == 'mujoco-c'
           else "the planners' own physics")
  return common.markdown_header(
      f'Closed loop in {world}, {payload["task"]}', payload['provenance'],
      f'Settings: {payload["settings"]}', f'World perturbation: {payload["perturbation"]}') + [
          common.markdown_table(rows, [
              'planner', 'success', 'steps_to_success_mean', 'world_steps_failed_mean',
              'queries_per_episode_mean', 'empty_answers', 'goal_answers',
              'actions_per_query_mean', 'evaluations_per_query_mean',
              'iterations_per_query_mean', 'policy_fill_steps', 'cut_fills', 'answers',
              'query_time_s_mean', 'query_time_s_max', 'total_s']), '',
          'Success: 95% interval with the instances resampled (cluster bootstrap over the '
          'instances; the rounds of an instance are not independent).']


def plot(payload: Dict, path: str) -> None:
  import matplotlib
  matplotlib.use('Agg')
  import matplotlib.pyplot as plt
  fig, ax = plt.subplots(figsize=(6, 4))
  for name, ep in payload['episodes'].items():
    steps = np.asarray(ep['success_step'])
    horizon = payload['settings']['max_queries'] * payload['settings']['execute']
    grid = np.arange(horizon + 1)
    ax.plot(grid, [np.mean((steps >= 0) & (steps <= g)) for g in grid], label=name)
  ax.set_xlabel('world steps executed')
  ax.set_ylabel('success rate')
  ax.set_title(f'closed loop, {payload["task"]}')
  ax.legend()
  fig.tight_layout()
  fig.savefig(path, dpi=110)
  plt.close(fig)


if __name__ == '__main__':
  sys.exit(main())
