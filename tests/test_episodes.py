"""Closed-loop episodes (`episodes`, `pachs loop`): MuJoCo C worlds, a replanning session that
drives them, and what the command writes."""

import json
import time
import types

import jax
import numpy as np
from PIL import Image

from pachs_jax import cli, envs, episodes, replan
from pachs_jax.envs import pusht


def test_worlds_judge_success_in_the_world_and_stop_finished_ones():
  env = envs.make('pusht-fixed')
  at_goal = env.node_from_pose(np.asarray(pusht.FIXED_GOAL), np.asarray(pusht.FIXED_GOAL))
  away = env.node_from_pose(np.array([0.1, 0.1, 0.0]), np.asarray(pusht.FIXED_GOAL))
  starts = jax.tree.map(lambda a, b: np.stack([np.asarray(a), np.asarray(b)]), at_goal, away)
  worlds = episodes.Worlds(env, starts, None)
  assert worlds.success.tolist() == [True, False]  # the first starts at the goal
  actions = np.zeros((2, 3, env.action_size), np.float32)
  worlds.execute(actions, np.array([3, 2]))
  # the finished episode does not move; the other runs its 2 actions in the world
  assert worlds.steps.tolist() == [0, 2]
  assert worlds.success.tolist() == [True, False]
  assert int(np.asarray(worlds.nodes[1].t)) == 2
  assert [len(worlds.trajectory(e).t) for e in range(2)] == [1, 3]


def test_an_episode_whose_t_tipped_over_has_failed_and_stops():
  env = envs.make('pusht-fixed')
  away = env.node_from_pose(np.array([0.1, 0.1, 0.0]), np.asarray(pusht.FIXED_GOAL))
  tipped = away.replace(qpos=np.asarray(away.qpos).copy())
  tipped.qpos[10:14] = [np.cos(0.4), np.sin(0.4), 0.0, 0.0]  # 46 degrees about the x axis
  starts = jax.tree.map(lambda a, b: np.stack([np.asarray(a), np.asarray(b)]), away, tipped)
  assert np.asarray(env.is_failure(starts)).tolist() == [False, True]
  worlds = episodes.Worlds(env, starts, None)
  assert worlds.failed.tolist() == [False, True] and worlds.active.tolist() == [True, False]
  worlds.execute(np.zeros((2, 2, env.action_size), np.float32), np.array([2, 2]))
  assert worlds.steps.tolist() == [2, 0]  # the failed episode does not move


class _FailOnOne:
  """Worlds of E episodes at integer positions; an action of 1 fails its episode."""

  def __init__(self, num):
    self.num, self.steps = num, np.zeros(num, np.int64)
    self.success, self.failed = np.zeros(num, bool), np.zeros(num, bool)

  @property
  def active(self):
    return ~self.success & ~self.failed

  def batch(self):
    return self.steps.astype(np.float32)

  def execute(self, actions, lengths, by_policy=None):
    for j in range(actions.shape[1]):
      moving = self.active & (lengths > j)
      self.steps += moving
      self.failed |= moving & (actions[:, j, 0] == 1)


def _run_twice(answer):
  """(worlds, log, what each query was told executed) of two queries of 3 actions, each
  answered with `answer` in `_FailOnOne` worlds, the policy's action 0."""
  num, told = len(answer.length), []

  def query(nodes, keys, executed, running, time_limit_s):
    told.append(np.asarray(executed).tolist())
    return answer
  worlds = _FailOnOne(num)
  log = episodes.run(query, worlds, execute=3, max_queries=2,
                     policy=lambda nodes: np.zeros((num, 1), np.float32))
  return worlds, log, told


def test_a_failure_on_a_policy_step_is_told_from_one_on_a_planned_step():
  """Episode 0 gets an empty answer and fails on the policy's action; 1 fails on its plan's
  second action; 2 plans 1 action, then the policy fills and fails; 3 never fails."""
  plan = np.zeros((4, 3, 1), np.float32)
  plan[1, 1] = 1.0
  answer = type('Answer', (), {'actions': plan, 'length': np.array([0, 3, 1, 3])})
  fails = np.array([True, False, True, False])  # the policy's action fails 0 and 2
  policy = lambda nodes: np.where(fails, 1.0, 0.0)[:, None].astype(np.float32)
  worlds = _FailOnOne(4)
  log = episodes.run(lambda *args: answer, worlds, execute=3, max_queries=1, policy=policy)
  assert worlds.failed.tolist() == [True, True, True, False]
  assert log.failed_on_policy.tolist() == [True, False, True, False]


def test_an_answer_cut_by_its_check_runs_to_its_safe_length_then_replans_unfilled():
  """Episode 0's answers are safe for 1 of their 3 actions (`replan.AnswerCheck`): it executes 1
  per query, the policy does not fill the rest, and the next query is told 1 was executed (so
  the session keeps its remainder); episode 1's are safe whole."""
  answer = type('Answer', (), {'actions': np.zeros((2, 3, 1), np.float32),
                               'length': np.array([3, 3]), 'safe_length': np.array([1, 3])})
  worlds, log, told = _run_twice(answer)
  assert worlds.steps.tolist() == [2, 6]
  assert told == [[0, 0], [1, 3]]
  assert log.policy_steps.tolist() == [0, 0] and log.cut_answers.tolist() == [2, 0]


def test_a_policy_fill_stops_at_the_answer_s_fill_length_and_the_next_query_comes_sooner():
  """Answers of 1, 1, 0 and 3 actions of 3 per query whose policy fill the planner's physics
  allows for 0, 2, 1 and 0 actions (`replan.Answer.fill_length`): episode 0 executes its action
  and replans (told 1 executed: its remainder holds); 1 is filled to 3; 2's empty answer plays
  one policy action and replans; 3 executes its 3."""
  answer = type('Answer', (), {'actions': np.zeros((4, 3, 1), np.float32),
                               'length': np.array([1, 1, 0, 3]),
                               'fill_length': np.array([0, 2, 1, 0])})
  worlds, log, told = _run_twice(answer)
  assert worlds.steps.tolist() == [2, 6, 2, 6]
  assert told[1] == [1, replan.DIVERGED, replan.DIVERGED, 3]
  assert log.policy_steps.tolist() == [0, 4, 2, 0]
  assert log.cut_fills.tolist() == [2, 0, 2, 0]


class _Slow:
  """An array still being computed: reading it takes `seconds` the first time."""

  def __init__(self, value, seconds):
    self.value, self.seconds = value, seconds

  def __array__(self, dtype=None, copy=None):
    time.sleep(self.seconds)
    self.seconds = 0.0
    return np.asarray(self.value, dtype)


def test_a_fill_still_computing_past_the_answer_s_own_actions_is_charged_to_the_next_query():
  """Answers of 2 and 3 actions of 3 (0.1 s of a robot's time per action) whose fill length takes
  0.3 s to read at the first query: episode 0 needs its fill after 0.2 s, so the wait past that
  comes off the second query's 1 s clock; the second answer's fill is ready (no charge), and a
  wait of more than half a clock takes only half (the charge still logged whole)."""
  clocks = []

  def run(seconds):
    answers = iter([0.3, 0.0, 0.0])

    def query(nodes, keys, executed, running, time_limit_s):
      clocks.append(time_limit_s)
      return types.SimpleNamespace(actions=np.zeros((2, 3, 1), np.float32),
                                   length=np.array([2, 3]),
                                   fill_length=_Slow(np.array([1, 0]), next(answers) * seconds))
    return episodes.run(query, _FailOnOne(2), 1.0, execute=3, max_queries=3, period_s=0.1,
                        policy=lambda nodes: np.zeros((2, 1), np.float32))
  log = run(1.0)
  assert log.fill_wait_s[0] >= 0.3 and log.charged_s[0] == log.fill_wait_s[0] - 0.2
  assert log.clock_s == clocks[:3] == [1.0, 1.0 - log.charged_s[0], 1.0 - log.charged_s[1]]
  assert log.charged_s[1] < 0.05  # (read at once)
  clocks.clear()
  log = run(3.0)  # 0.9 s of fill: a charge of 0.7 s, half the clock taken
  assert log.charged_s[0] >= 0.7 and log.clock_s[1] == 0.5


def test_trace_records_the_actions_who_took_them_and_the_plan_for_each_world_state():
  """Episode 0 executes 3 planned actions per query; episode 1's answers hold 1, the policy
  fills 2. The trace's planned qpos at world state s is the state the answer being executed
  planned there (the second query's from state 3 on), NaN where the policy filled."""
  env = envs.make('pusht-fixed')
  away = env.node_from_pose(np.array([0.1, 0.1, 0.0]), np.asarray(pusht.FIXED_GOAL))
  starts = jax.tree.map(lambda a: np.stack([np.asarray(a)] * 2), away)
  worlds = episodes.Worlds(env, starts, None)
  size = np.asarray(away.qpos).shape[-1]
  asked = []

  def query(nodes, keys, executed, running, time_limit_s):
    number = len(asked)
    asked.append(number)
    planned = number + 0.1 * np.arange(4)[None, :, None] + np.zeros((2, 4, size))
    actions = np.full((2, 3, env.action_size), 0.01 * (number + 1), np.float32)
    states = jax.tree.map(lambda x: np.broadcast_to(np.asarray(x), (2, 4) + x.shape), away)
    return types.SimpleNamespace(actions=actions, length=np.array([3, 1]),
                                 kind=np.zeros(2, np.int64), states=states.replace(qpos=planned))
  policy = lambda nodes: np.full((2, env.action_size), -0.02, np.float32)
  log = episodes.run(query, worlds, execute=3, max_queries=2, policy=policy)
  out = episodes.trace(worlds, log)
  assert out['steps'].tolist() == [6, 6] and out['asked_at'].tolist() == [[0, 0], [3, 3]]
  assert out['by_policy'].tolist() == [[False] * 6, [False, True, True] * 2]
  np.testing.assert_allclose(out['actions'][0, :, 0], [0.01] * 3 + [0.02] * 3)
  np.testing.assert_allclose(out['actions'][1, :, 0], [0.01, -0.02, -0.02, 0.02, -0.02, -0.02])
  np.testing.assert_allclose(out['planned_qpos'][0, :, 0], [0, 0.1, 0.2, 1, 1.1, 1.2, 1.3])
  np.testing.assert_allclose(out['planned_qpos'][1, :, 0],
                             [0, 0.1, np.nan, 1, 1.1, np.nan, np.nan])
  # the worlds' states: the start, then one per action executed
  np.testing.assert_array_equal(out['world_qpos'][:, 0], starts.qpos)
  np.testing.assert_array_equal(out['world_qpos'][0, 6], worlds.nodes[0].qpos)
  assert not np.isnan(out['world_qvel']).any()


def test_executed_plans_follow_the_queries_of_an_episode():
  states = lambda value: jax.tree.map(lambda x: np.full((2, 5), value), {'q': 0})
  log = episodes.Log(queries=np.zeros(2), answers=np.zeros((2, 5)), policy_steps=np.zeros(2),
                     failed_on_policy=np.zeros(2, bool))
  # episode 0 asked at world steps 0 and 3; episode 1 only at 0 (then it had finished)
  log.plans = [(np.array([0, 0]), states(1.0), np.array([4, 2])),
               (np.array([3, -1]), states(2.0), np.array([1, 0]))]
  plans = log.executed_plans(0, 6)
  assert [p['q'][0] for p in plans] == [1, 1, 1, 2, 2, 2]
  assert [len(p['q']) for p in plans] == [5, 5, 5, 2, 2, 2]  # length + 1 states
  assert plans[0] is plans[2]  # one object per query (the video draws each plan once)
  assert [p['q'][0] for p in log.executed_plans(1, 3)] == [1, 1, 1]


def test_pachs_loop_runs_episodes_and_writes_rows_and_a_video(tmp_path):
  rows, video = tmp_path / 'loop.json', tmp_path / 'loop.gif'
  code = cli.main(['loop', '--task', 'pusht-obs', '--layout', 'wall', '--instances', '0,3',
                   '--query-time', '0.5', '--max-queries', '2', '--execute', '4',
                   '--budget', '512', '-K', '32', '--json', str(rows), '--video', str(video),
                   '--show-instance', '3'])
  assert code == 0
  saved = json.loads(rows.read_text())
  assert saved['config']['pop_size'] == 32
  assert (saved['physics'], saved['world'], saved['layout']) == ('mujoco-c', 'mujoco-c', 'wall')
  assert [r['instance'] for r in saved['rows']] == [0, 3]
  for row in saved['rows']:
    answers = sum(row[k] for k in ('none', 'goal_path', 'partial_path', 'remainder', 'policy'))
    assert answers == row['queries'] <= 2
    # each query executes 4 actions of its answer, or the policy's where it is shorter, unless
    # the policy's fill was cut before an edge the planner found invalid (on by default)
    assert saved['settings']['fill_check'] == 1
    if not row['success']:
      assert (row['steps'] < 4 * row['queries'] if row['cut_fills']
              else row['steps'] == 4 * row['queries'])
  # each query's clock: 0.5 s less what the last fill's wait past its answer's own actions
  # charged (the fill followed after each answer)
  clocks = saved['queries']
  assert len(clocks['clock_s']) == max(r['queries'] for r in saved['rows'])
  assert len(clocks['fill_wait_s']) == len(clocks['charged_s']) == len(clocks['clock_s'])
  assert clocks['clock_s'][0] == 0.5 and all(
      c == max(0.5 - charged, 0.5 * episodes.MIN_CLOCK_SHARE)
      for c, charged in zip(clocks['clock_s'][1:], clocks['charged_s']))
  with Image.open(video) as gif:  # a frame per world state of instance 3
    assert gif.n_frames == saved['rows'][1]['steps'] + 1


def test_pachs_loop_refuses_bad_arguments_in_one_line(capsys):
  for argv, message in ((['--query-time', '0'], '--query-time: must be a positive number'),
                        (['--task', 'pusht-fixed', '--layout', 'wall'], '--layout applies to'),
                        (['--instances', '40'], 'instances must lie in 0..29'),
                        (['--show-instance', '5'], '5'),
                        (['-K', '0'], '--pop-size/-K')):
    try:
      code = cli.main(['loop'] + argv)
    except SystemExit as exit_info:
      code = exit_info.code
    assert code == 2
    assert message in capsys.readouterr().err
