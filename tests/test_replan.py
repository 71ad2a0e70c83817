"""Replanning sessions (`replan`) on the analytic point mass (CPU): candidates followed in the
planner's physics, the choice between them, and a session that keeps its last answer."""

import threading

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import UniformActorCritic

from pachs_jax import envs, replan
from pachs_jax.envs import base, pusht
from pachs_jax.envs.point_mass import PointMassConfig, PointMassEnv
from pachs_jax.replan import AnswerKind
from pachs_jax.search import SearchConfig

DIM = 2


class TowardGoal(UniformActorCritic):
  """The policy steps straight at the goal at full speed (obs[:, 2:] = goal - position); the
  proposals are uniform noise and the critic knows nothing."""

  def deterministic_action(self, obs):
    away = obs[:, DIM:]
    return away / jnp.maximum(jnp.linalg.norm(away, axis=1, keepdims=True), 1e-6)


def _nodes(env, starts, goals):
  return jax.vmap(env.node_from_positions)(jnp.asarray(starts, jnp.float32),
                                           jnp.asarray(goals, jnp.float32))


def _straight(start, goal, steps, horizon):
  """[horizon, 2] actions moving from start to goal in `steps` equal moves (0 after them)."""
  actions = np.zeros((horizon, DIM), np.float32)
  actions[:steps] = (np.asarray(goal) - np.asarray(start)) / (0.1 * steps)
  return actions


@pytest.fixture(scope='module')
def env():
  return PointMassEnv()


@pytest.fixture(scope='module')
def follow(env):
  return jax.jit(lambda *args: replan.follow(env, TowardGoal(DIM).deterministic_action, *args))


def test_remainder_drops_the_executed_actions():
  actions = jnp.arange(2 * 5 * 1, dtype=jnp.float32).reshape(2, 5, 1) + 1
  shifted, left = replan.remainder(actions, jnp.array([4, 2]), jnp.array([1, 3]))
  np.testing.assert_array_equal(left, [3, 0])
  np.testing.assert_array_equal(shifted[0, :, 0], [2, 3, 4, 0, 0])
  np.testing.assert_array_equal(shifted[1, :, 0], 0)
  # an episode that diverged from its answer keeps nothing of it
  _, left = replan.remainder(actions, jnp.array([4, 2]), jnp.array([replan.DIVERGED, 0]))
  np.testing.assert_array_equal(left, [0, 2])


def test_follow_stops_at_the_length_the_goal_and_an_invalid_edge(env, follow):
  horizon = 12
  starts, goals = [[0.0, 0.0]] * 6, [[0.5, 0.0]] * 6
  actions = np.zeros((6, horizon, DIM), np.float32)
  actions[:, :] = [1.0, 0.0]  # 0.1 per step: the goal after 5 steps
  actions[2, 2] = np.nan  # lane 2's third edge is invalid
  out = jax.tree.map(np.asarray, follow(
      _nodes(env, starts, goals), jnp.asarray(actions), jnp.array([3, 9, 9, 9, 2, 0]),
      jnp.array([False, False, False, True, True, True])))
  # lane 0 stops at its length, lane 1 at the goal, lane 2 before its invalid edge; lanes 3-5
  # follow the policy (straight at the goal) instead of their paths, each up to its length
  np.testing.assert_array_equal(out.steps, [3, 5, 2, 5, 2, 0])
  np.testing.assert_array_equal(out.reached_goal, [False, True, False, True, False, False])
  np.testing.assert_array_equal(out.actions[1, 5:], 0.0)
  np.testing.assert_allclose(out.actions[3, :5], [[1.0, 0.0]] * 5, atol=1e-6)
  np.testing.assert_array_equal(out.actions[4, 2:], 0.0)
  np.testing.assert_allclose(out.states.qpos[4, 2:], [[0.2, 0.0]] * (horizon - 1), atol=1e-6)
  # the states along each path: lane 1 moves 0.1 a step to the goal, then stays there
  np.testing.assert_allclose(out.states.qpos[1, :, 0], [0.0, 0.1, 0.2, 0.3, 0.4]
                             + [0.5] * (horizon - 4), atol=1e-6)
  np.testing.assert_allclose(out.states.qpos[2, :, 0], [0.0, 0.1] + [0.2] * (horizon - 1),
                             atol=1e-6)
  # the cost is the env's: the distance to the goal after each move plus the action cost
  np.testing.assert_allclose(out.cost[1], 0.4 + 0.3 + 0.2 + 0.1 + 0.0 + 5 * 0.01, atol=1e-5)
  np.testing.assert_allclose(out.cost[0], 0.4 + 0.3 + 0.2 + 3 * 0.01, atol=1e-5)


def _followed(steps, reached, cost, horizon=4, mark=1.0):
  """Followed candidates whose actions are 1 and states `mark` (a leaf [E, T + 1, 1])."""
  steps = jnp.asarray(steps, jnp.int32)
  actions = jnp.where(jnp.arange(horizon)[None, :, None] < steps[:, None, None], 1.0, 0.0)
  return replan.Followed(actions=actions * jnp.ones((1, 1, DIM)), steps=steps,
                         reached_goal=jnp.asarray(reached), cost=jnp.asarray(cost, jnp.float32),
                         states=jnp.full((len(steps), horizon + 1, 1), mark))


class _Search:
  """The SearchResult fields `choose` reads."""

  def __init__(self, found, length, cost, horizon=4):
    self.found = jnp.asarray(found)
    self.path_is_goal = jnp.asarray(found)
    self.path_length = jnp.asarray(length, jnp.int32)
    self.path_actions = jnp.full((len(found), horizon + 2, DIM), -1.0)
    self.path_nodes = jnp.full((len(found), horizon + 3, 1), -1.0)
    self.cost = jnp.asarray(cost, jnp.float32)


def test_choose_prefers_the_cheapest_goal_then_the_search_then_the_remainder_then_the_policy():
  # episodes: 0 search goal cheapest; 1 remainder goal cheaper than the search's; 2 only the
  # policy reaches the goal; 3 no goal, the search's partial path; 4 no goal, the search empty;
  # 5 nothing but the policy moves; 6 nothing moves; 7 a tie: the search's goal path
  search = _Search([1, 1, 0, 0, 0, 0, 0, 1], [3, 3, 2, 2, 0, 0, 0, 2],
                   [1.0, 5.0, 9.0, 9.0, 0.0, 0.0, 0.0, 2.0])
  last = _followed([2, 2, 1, 1, 3, 0, 0, 2], [0, 1, 0, 0, 0, 0, 0, 1],
                   [0.5, 4.0, 1.0, 1.0, 1.0, 0.0, 0.0, 2.0], mark=1.0)
  policy = _followed([4, 4, 4, 4, 4, 1, 0, 4], [0, 0, 1, 0, 0, 0, 0, 0],
                     [9.0, 9.0, 7.0, 1.0, 1.0, 1.0, 0.0, 9.0], mark=2.0)
  answer = jax.tree.map(np.asarray, replan.choose(search, last, policy, 4))
  names = [AnswerKind.name(k) for k in answer.kind]
  assert names == ['goal_path', 'remainder', 'policy', 'partial_path', 'remainder', 'policy',
                   'none', 'goal_path']
  np.testing.assert_array_equal(answer.length, [3, 2, 4, 2, 3, 1, 0, 2])
  np.testing.assert_array_equal(answer.reaches_goal, [1, 1, 1, 0, 0, 0, 0, 1])
  np.testing.assert_allclose(answer.cost, [1.0, 4.0, 7.0, 9.0, 1.0, 1.0, 0.0, 2.0])
  np.testing.assert_array_equal(answer.actions[0, :3], -1.0)  # the search's path
  np.testing.assert_array_equal(answer.actions[1, :2], 1.0)  # the remainder's
  np.testing.assert_array_equal(answer.states[:, 0, 0], [-1, 1, 2, -1, 1, 2, 2, -1])
  # a search goal path longer than the horizon is no goal answer (its end is not kept)
  long = _Search([1], [6], [0.1])
  answer = replan.choose(long, _followed([0], [0], [0.0]), _followed([4], [1], [3.0]), 4)
  assert AnswerKind.name(answer.kind[0]) == 'policy'


@pytest.fixture(scope='module')
def session(env):
  # a budget of 16 one-step edges: far too few for a goal 0.6 to 0.8 away in 0.1 steps
  # among uniform proposals; the policy candidate off (TowardGoal would solve it)
  config = SearchConfig(weight=1.0, pop_size=4, num_actions=4, budget=16)
  return replan.Session(env, TowardGoal(DIM), config, horizon=16, candidates=('remainder',))


def test_an_answer_is_never_worse_than_the_last_answers_remainder(env, session):
  starts = np.array([[-0.3, -0.3], [0.4, 0.0], [0.0, 0.3]], np.float32)
  goals = np.array([[0.3, 0.2], [-0.3, 0.1], [0.0, -0.3]], np.float32)
  nodes = _nodes(env, starts, goals)
  session.reset()
  first = session.plan(nodes, key=jax.random.PRNGKey(0))
  assert not np.any(np.asarray(first.reaches_goal))  # the budget finds no goal
  assert set(np.asarray(first.kind)) == {AnswerKind.PARTIAL_PATH}
  # the last answer replaced by straight paths to the goals in 10 moves; 3 of them executed
  straight = np.stack([_straight(s, g, 10, 16) for s, g in zip(starts, goals)])
  session.last = session.last.replace(actions=jnp.asarray(straight),
                                      length=jnp.full((3,), 10, jnp.int32))
  moved = _nodes(env, starts + 3 * 0.1 * straight[:, 0], goals)
  answer = jax.tree.map(np.asarray, session.plan(moved, executed=[3, 3, 3],
                                                 key=jax.random.PRNGKey(1)))
  assert [AnswerKind.name(k) for k in answer.kind] == ['remainder'] * 3
  np.testing.assert_array_equal(answer.length, 7)
  assert answer.reaches_goal.all()
  np.testing.assert_allclose(answer.actions[:, :7], straight[:, :7], atol=1e-6)
  np.testing.assert_allclose(answer.states.qpos[:, 7], goals, atol=1e-5)  # where it ends
  # the remainder's cost as the env counts it: the distances after each of its 7 moves
  distance = np.linalg.norm(goals - starts, axis=1)
  want = sum(distance * (6 - j) / 10 for j in range(7)) + 7 * 0.01 * np.sum(
      np.square(straight[:, 0]), axis=1)
  np.testing.assert_allclose(answer.cost, want, rtol=1e-4)
  # an episode that did something else keeps nothing of its last answer
  again = session.plan(moved, executed=[replan.DIVERGED] * 3, key=jax.random.PRNGKey(1))
  assert set(np.asarray(again.kind)) == {AnswerKind.PARTIAL_PATH}


def test_a_search_goal_cheaper_than_the_remainder_wins(env):
  config = SearchConfig(weight=1.0, pop_size=8, num_actions=8, budget=4000)
  session = replan.Session(env, TowardGoal(DIM), config, horizon=32, candidates=('remainder',))
  start, goal = np.array([[0.0, 0.0]], np.float32), np.array([[0.3, 0.0]], np.float32)
  nodes = _nodes(env, start, goal)
  session.plan(nodes)
  # the last answer: a detour to the goal (up, right, down) that costs more than the search's
  detour = np.zeros((1, 32, DIM), np.float32)
  detour[0, :3] = [0.0, 1.0]
  detour[0, 3:6] = [1.0, 0.0]
  detour[0, 6:9] = [0.0, -1.0]
  session.last = session.last.replace(actions=jnp.asarray(detour),
                                      length=jnp.array([9], jnp.int32))
  answer = jax.tree.map(np.asarray, session.plan(nodes, executed=[0]))
  assert AnswerKind.name(answer.kind[0]) == 'goal_path' and answer.reaches_goal[0]
  remainder = session._follow(nodes, jnp.asarray(detour), jnp.array([9]), jnp.array([False]))
  assert bool(remainder.reached_goal[0])
  assert answer.cost[0] <= float(remainder.cost[0])


def test_a_replayed_remainder_is_the_search_s_own_goal(env):
  # the remainder is no candidate here: the search's first chain lane replays it from the new
  # state, reaches the goal and answers with it
  config = SearchConfig(weight=1.0, pop_size=4, num_actions=4, budget=64, rollout_share=0.5,
                        chain_restart='start')
  session = replan.Session(env, TowardGoal(DIM), config, horizon=16, replay_remainder=True)
  starts = np.array([[-0.3, -0.3], [0.4, 0.0]], np.float32)
  goals = np.array([[0.3, 0.2], [-0.3, 0.1]], np.float32)
  session.plan(_nodes(env, starts, goals), key=jax.random.PRNGKey(0))
  straight = np.stack([_straight(s, g, 10, 16) for s, g in zip(starts, goals)])
  session.last = session.last.replace(actions=jnp.asarray(straight),
                                      length=jnp.full((2,), 10, jnp.int32))
  moved = _nodes(env, starts + 3 * 0.1 * straight[:, 0], goals)
  answer = jax.tree.map(np.asarray, session.plan(moved, executed=[3, 3],
                                                 key=jax.random.PRNGKey(1)))
  assert [AnswerKind.name(k) for k in answer.kind] == ['goal_path'] * 2
  np.testing.assert_array_equal(answer.length, 7)
  np.testing.assert_allclose(answer.actions[:, :7], straight[:, :7], atol=1e-6)
  np.testing.assert_allclose(answer.states.qpos[:, 7], goals, atol=1e-5)


def test_sessions_replay_wherever_their_search_can(env):
  # chain lanes and one device: the session builds its search with room for the remainder;
  # no chain lanes, or a given search without room: no replay
  from pachs_jax.runtime import programs  # pylint: disable=import-outside-toplevel
  from pachs_jax.search.pachs import make_search  # pylint: disable=import-outside-toplevel
  chains = SearchConfig(budget=16, rollout_share=0.5)
  session = replan.Session(env, TowardGoal(DIM), chains, horizon=8)
  assert session.replay_remainder and session.search.search.sizes.replay == 8
  assert not replan.Session(env, TowardGoal(DIM), SearchConfig(budget=16)).replay_remainder
  shared = programs.Programs(make_search(env, TowardGoal(DIM), chains))
  assert not replan.Session(env, TowardGoal(DIM), chains, shared, horizon=8).replay_remainder


@pytest.mark.parametrize('kwargs, message', [
    ({'candidates': ('remainder', 'previous')}, "unknown replanning candidate 'previous'"),
    ({'horizon': 0}, 'horizon must be a positive int'),
    ({'candidates': 'policy'}, 'candidates must be a sequence of names'),
    ({'candidates': None}, 'candidates must be a sequence of names'),
    ({'replay_remainder': True}, 'replay_remainder needs chain lanes'),
    ({'replay_remainder': 1}, 'replay_remainder must be a bool or None'),
    ({'fill_steps': -1}, 'fill_steps must be an int >= 0'),
    ({'fill_steps': True}, 'fill_steps must be an int >= 0'),
])
def test_bad_session_settings_are_refused(env, kwargs, message):
  with pytest.raises(ValueError, match=message):
    kwargs = {'config': SearchConfig(budget=16), **kwargs}
    replan.Session(env, TowardGoal(DIM), **kwargs)


@pytest.mark.parametrize('kwargs, message', [
    ({'states': None}, "states must be the env's NodeState"),
    ({'time_limit_s': '1'}, 'time_limit_s must be a number of seconds > 0'),
    ({'time_limit_s': -1.0}, 'time_limit_s must be a number of seconds > 0'),
    ({'key': 'x'}, 'key must be one PRNG key or \\[2, 2\\] keys'),
    ({'active': [True]}, 'active must be \\[2\\] bools'),
    ({'active': [1, 0]}, 'active must be \\[2\\] bools'),
    ({'executed': [np.nan, 1]}, 'executed must hold 2 integer counts'),
    ({'executed': [1.5, 1]}, 'executed must hold 2 integer counts'),
    ({'executed': [-1, 1]}, 'executed must hold 2 integer counts'),
])
def test_bad_query_arguments_are_refused_by_name(env, session, kwargs, message):
  nodes = _nodes(env, [[0.0, 0.0]] * 2, [[0.3, 0.0]] * 2)
  args = {'states': nodes, **kwargs}
  session.reset()
  with pytest.raises(ValueError, match=message):
    session.plan(args.pop('states'), **args)


def test_episodes_not_active_are_not_searched(env, session):
  nodes = _nodes(env, [[0.0, 0.0]] * 3, [[0.5, 0.0]] * 3)
  session.reset()
  answer = jax.tree.map(np.asarray, session.plan(nodes, active=np.array([True, False, True])))
  assert answer.search.evaluated.tolist()[1] == 0 and answer.search.path_length[1] == 0
  assert answer.search.evaluated[0] > 0 and answer.search.evaluated[2] > 0


def test_executed_must_match_the_episodes(env, session):
  nodes = _nodes(env, [[0.0, 0.0]] * 3, [[0.3, 0.0]] * 3)
  session.reset()
  session.plan(nodes)
  with pytest.raises(ValueError, match='executed must hold 3 integer counts'):
    session.plan(nodes, executed=[1, 2])
  with pytest.raises(ValueError, match='the session plans 3 episodes, got 2'):
    session.plan(jax.tree.map(lambda x: x[:2], nodes), executed=[1, 1])


def test_a_planner_s_sessions_share_one_replaying_search_per_horizon(monkeypatch):
  # PushT-Obs has chain lanes: its sessions replay, in a search apart from `plan`'s, built
  # once per horizon; PushT-Fixed has none: its sessions share `plan`'s search
  from pachs_jax import planner  # pylint: disable=import-outside-toplevel
  obs = planner.Planner('pusht-obs', backend='mujoco-c', budget=400, cache=False)
  first, second, short = obs.session(), obs.session(), obs.session(horizon=8)
  assert first.replay_remainder and first.search is second.search
  assert first.search is not obs.search and obs.search.search.sizes.replay == 0
  assert first.search.search.sizes.replay == obs.env.episode_length
  assert short.search.search.sizes.replay == 8
  fixed = planner.Planner('pusht-fixed', backend='mujoco-c', budget=400, cache=False)
  session = fixed.session()
  assert not session.replay_remainder and session.search is fixed.search
  assert session.check is None
  check = replan.AnswerCheck(pusht.perturb_t, copies=2)
  assert fixed.session(check=check).check is check
  assert session.fill_steps == 0 and fixed.session(fill_steps=10).fill_steps == 10
  # on a CPU the query time leaves K as it is; on an accelerator (the task's rule, forced here)
  # a 3 s session pops 128 in a search of its own, built once, and a 1 s one keeps 64
  if jax.default_backend() == 'cpu':
    assert obs.session(query_time_s=3.0).search is first.search
  monkeypatch.setattr(planner, 'replan_pop_size',
                      lambda task, seconds, physics: envs.spec(task).replan_pop_size(seconds))
  long_a, long_b = obs.session(query_time_s=3.0), obs.session(query_time_s=2.5)
  assert long_a.config.pop_size == long_b.config.pop_size == 128 != obs.config.pop_size
  assert long_a.search is long_b.search and long_a.search is not first.search
  assert long_a.search.search.sizes.replay == obs.env.episode_length
  assert obs.session(query_time_s=1.0).search is first.search
  for bad in (0, -1.0, float('nan'), float('inf'), '3', True):
    with pytest.raises(ValueError, match='query_time_s must be a number of seconds > 0'):
      obs.session(query_time_s=bad)
  for bad in (0, -3, 2.5, True):
    with pytest.raises(ValueError, match='horizon must be a positive int'):
      obs.session(horizon=bad)


def test_a_planner_on_an_accelerator_takes_k_from_the_query_time_unless_its_edges_run_on_cpus(
    monkeypatch):
  # a GPU host as the Planner sees it: MJX edges take the task's K for the query time; MuJoCo
  # C edges (CPU threads) and an explicit K keep theirs
  from pachs_jax import planner  # pylint: disable=import-outside-toplevel
  monkeypatch.setattr(planner.jax, 'default_backend', lambda: 'gpu')
  on_gpu = planner.Planner('pusht-obs', backend='mjx', budget=400, cache=False)
  assert on_gpu.replan_config(3.0).pop_size == 128 and on_gpu.replan_config(1.0).pop_size == 64
  for kwargs in (dict(backend='mujoco-c'), dict(backend='mjx', pop_size=32)):
    kept = planner.Planner('pusht-obs', budget=400, cache=False, **kwargs)
    assert kept.replan_config(3.0) == kept.config
  # the fill check likewise: MJX edges from the task's query time on, MuJoCo C edges always
  assert on_gpu.replan_fill_check(3.0) and not on_gpu.replan_fill_check(1.0)
  assert planner.Planner('pusht-obs', backend='mujoco-c', budget=400,
                         cache=False).replan_fill_check(1.0)
  with pytest.raises(ValueError, match='query_time_s must be a number of seconds > 0'):
    on_gpu.replan_fill_check(-1.0)


def test_the_replanning_k_follows_the_query_time_on_an_accelerator():
  from pachs_jax import planner  # pylint: disable=import-outside-toplevel
  obs = envs.spec('pusht-obs')
  assert [obs.replan_pop_size(t) for t in (3.0, 2.0, 1.99, 1.0, None)] == [
      128, 128, None, None, None]
  assert planner.replan_pop_size('pusht-obs', 3.0, 'mujoco-c') is None
  if jax.default_backend() == 'cpu':
    assert planner.replan_pop_size('pusht-obs', 3.0, 'mjx') is None
  assert envs.spec('pusht-fixed').replan_pop_size(3.0) is None


def test_the_fill_check_follows_the_query_time_on_an_accelerator(monkeypatch):
  from pachs_jax import planner  # pylint: disable=import-outside-toplevel
  obs = envs.spec('pusht-obs')
  assert [obs.replan_fill_check(t) for t in (3.0, 2.0, 1.99, 1.0, None)] == [
      True, True, False, False, True]
  assert envs.spec('pusht-fixed').replan_fill_check(0.5)  # no threshold: always
  monkeypatch.setattr(planner.jax, 'default_backend', lambda: 'gpu')
  assert not planner.replan_fill_check('pusht-obs', 1.0, 'warp')
  assert planner.replan_fill_check('pusht-obs', 3.0, 'warp')
  assert planner.replan_fill_check('pusht-obs', 1.0, 'mujoco-c')
  assert planner.replan_fill_check('playground:ReacherEasy', 1.0, 'mjx')  # outside the registry
  monkeypatch.setattr(planner.jax, 'default_backend', lambda: 'cpu')
  assert planner.replan_fill_check('pusht-obs', 1.0, 'mjx')


class Cliff(PointMassEnv):
  """The point mass with a cliff: a move that ends beyond x = 0.55 is an invalid edge."""

  def transition(self, node, action):
    out = super().transition(node, action)
    ok = out.is_valid & (out.next_node.qpos[0] <= 0.55)
    return out.replace(is_valid=ok, is_goal=out.is_goal & ok)


def _shift_right(nodes, keys):
  """Every copy 0.08 to the right (a perturbation that does not draw)."""
  del keys
  return nodes.replace(qpos=nodes.qpos.at[:, 0].add(0.08))


def test_an_answer_is_safe_up_to_the_first_action_a_perturbed_copy_cannot_take():
  env = Cliff()
  check = replan.AnswerCheck(_shift_right, copies=3, steps=10)
  safe = jax.jit(lambda *args: replan.safe_length(env, TowardGoal(DIM).deterministic_action,
                                                  check, *args))
  # moves of 0.1 along x: 0 ends at 0.5 (its copies at 0.58 on their 5th move: 4 safe); 1 far
  # from the cliff; 2 goes on past it (12 moves: 4 safe); 3 one move to 0.48 (its copies fall
  # on it: at least one action is kept); 4's copies reach the goal at 0.3 before the cliff (a
  # copy at a goal has taken them all)
  starts = [[0.0, 0.0], [-0.5, 0.0], [0.0, 0.0], [0.38, 0.0], [0.0, 0.0]]
  goals = [[-0.9, -0.9]] * 4 + [[0.3, 0.0]]
  actions = np.zeros((5, 16, DIM), np.float32)
  actions[:, :, 0] = 1.0
  length = jnp.array([5, 5, 12, 1, 5])
  keys = jax.random.split(jax.random.PRNGKey(0), 5)
  got = safe(_nodes(env, starts, goals), jnp.asarray(actions), length, keys)
  np.testing.assert_array_equal(got, [4, 5, 4, 1, 5])
  short = replan.AnswerCheck(_shift_right, copies=3, steps=3)
  got = jax.jit(lambda *args: replan.safe_length(
      env, TowardGoal(DIM).deterministic_action, short, *args))(
          _nodes(env, starts, goals), jnp.asarray(actions), length, keys)
  # checked on their first 3 moves only: the cliff lies past them but for 3
  np.testing.assert_array_equal(got, [5, 5, 12, 1, 5])


def test_the_policy_fills_an_answer_up_to_the_first_edge_the_planner_finds_invalid():
  env = Cliff()
  fill = jax.jit(lambda end, length: replan.fill_length(
      env, TowardGoal(DIM).deterministic_action, end, length, 10))
  # the policy moves 0.1 a step at its goal. 0: from 0.2 to a goal past the cliff, 3 moves
  # (0.3-0.5) before the one off it; 1: the answer holds all 10 actions; 2: the goal at 0.4 on
  # its 2nd move (the rest is the world's business: all 8); 3: away from the cliff, all 8;
  # 4: an empty answer from 0.4 (one move, then the cliff)
  ends = [[0.2, 0.0], [0.2, 0.0], [0.2, 0.0], [0.2, 0.0], [0.4, 0.0]]
  goals = [[2.0, 0.0], [2.0, 0.0], [0.4, 0.0], [-2.0, 0.0], [2.0, 0.0]]
  got = fill(_nodes(env, ends, goals), jnp.array([2, 10, 2, 2, 0]))
  np.testing.assert_array_equal(got, [3, 0, 8, 8, 1])


def test_a_session_with_fill_steps_says_how_far_the_policy_may_fill_each_answer():
  env = Cliff()
  config = SearchConfig(weight=1.0, pop_size=4, num_actions=4, budget=16)
  session = replan.Session(env, TowardGoal(DIM), config, horizon=16, fill_steps=10)
  starts = np.array([[0.0, 0.0], [0.3, 0.0], [-0.5, 0.0]], np.float32)
  goals = np.array([[2.0, 0.0], [2.0, 0.0], [-2.0, 0.0]], np.float32)
  answer = jax.tree.map(np.asarray, session.plan(_nodes(env, starts, goals),
                                                 key=jax.random.PRNGKey(0)))
  # the policy from each answer's end (its state at its length) for the actions the answer
  # leaves of the 10: toward the goal at 0.1 a step, stopped by the cliff past x = 0.55
  end = answer.states.qpos[np.arange(3), answer.length]
  assert np.all(answer.length < 10)  # a budget of 16 evaluations: short answers
  heading = goals - end[:, :DIM]
  heading /= np.linalg.norm(heading, axis=1, keepdims=True)
  want = 10 - answer.length
  moves = [next((m - 1 for m in range(1, w + 1) if e[0] + 0.1 * m * h[0] > 0.55 + 1e-5), w)
           for e, h, w in zip(end, heading, want)]
  np.testing.assert_array_equal(answer.fill_length, moves)
  assert answer.fill_length[2] == want[2]  # away from the cliff the fill is whole
  # an episode the query does not search (its episode over) gets no fill
  quiet = session.plan(_nodes(env, starts, goals), key=jax.random.PRNGKey(0),
                       active=np.array([True, True, False]))
  # (followed on the session's thread after the answer: a PendingFill)
  assert isinstance(quiet.fill_length, replan.PendingFill)
  assert int(quiet.length[2]) < 10 and int(quiet.fill_length.result()[2]) == 0
  # without fill_steps no fill is followed
  plain = replan.Session(env, TowardGoal(DIM), config, horizon=16)
  assert plain.plan(_nodes(env, starts, goals), key=jax.random.PRNGKey(0)).fill_length is None


def test_a_session_answers_before_the_policy_s_fill_is_followed():
  """The fill's follow runs after the answer is returned (`replan.PendingFill`): a follow that
  can only end once the caller holds the answer still ends, and its lengths arrive."""
  env = Cliff()
  config = SearchConfig(weight=1.0, pop_size=4, num_actions=4, budget=16)
  session = replan.Session(env, TowardGoal(DIM), config, horizon=16, fill_steps=10)
  starts = np.array([[0.0, 0.0], [0.3, 0.0], [-0.5, 0.0]], np.float32)
  nodes = _nodes(env, starts, np.array([[2.0, 0.0]] * 3, np.float32))
  session.plan(nodes, key=jax.random.PRNGKey(0))  # compiles the follow for 3 episodes
  answered = threading.Event()

  def follow(ends, length, live):  # stands in for the compiled follow
    return np.where(answered.wait(timeout=60), 7, -1) + np.zeros(len(live), np.int32)
  session._fills[3] = follow  # pylint: disable=protected-access
  answer = session.plan(nodes, key=jax.random.PRNGKey(0))
  answered.set()
  np.testing.assert_array_equal(np.asarray(answer.fill_length), [7, 7, 7])


def test_a_session_s_first_clocked_query_first_answers_once_off_its_clock(env, monkeypatch):
  """The first clocked query (per bucket) first runs a throwaway answer with a clock of
  `replan.WARM_UP_S` (compiling the choice, the programs' first runs), then its own; later
  and unclocked queries search once; the answer is the one an unclocked query gives."""
  config = SearchConfig(weight=1.0, pop_size=4, num_actions=4, budget=16)
  session = replan.Session(env, TowardGoal(DIM), config, horizon=16, fill_steps=10)
  clocks = []
  plan = replan.programs.plan

  def spy(*args, **kwargs):
    clocks.append(kwargs['time_limit_s'])
    return plan(*args, **kwargs)
  monkeypatch.setattr(replan.programs, 'plan', spy)
  starts = np.array([[0.0, 0.0], [0.3, 0.0], [-0.5, 0.0]], np.float32)
  nodes = _nodes(env, starts, np.array([[0.6, 0.0]] * 3, np.float32))
  unclocked = jax.tree.map(np.asarray, session.plan(nodes, key=jax.random.PRNGKey(0)))
  assert clocks == [None]
  clocked = session.plan(nodes, key=jax.random.PRNGKey(0), time_limit_s=600.0)
  assert len(clocks) == 3 and clocks[1] == replan.WARM_UP_S and clocks[2] > 100
  assert session.last is clocked  # the throwaway answer is not kept
  # a 600 s clock and a budget of 16: the search runs to its budget, as unclocked
  np.testing.assert_array_equal(np.asarray(clocked.length), unclocked.length)
  np.testing.assert_array_equal(np.asarray(clocked.actions), unclocked.actions)
  np.testing.assert_array_equal(np.asarray(clocked.fill_length), unclocked.fill_length)
  session.plan(nodes, key=jax.random.PRNGKey(0), time_limit_s=600.0)
  assert len(clocks) == 4


def test_a_session_with_a_check_answers_with_its_safe_length():
  env = Cliff(PointMassConfig(success_radius=0.01))
  config = SearchConfig(weight=1.0, pop_size=4, num_actions=4, budget=16)
  check = replan.AnswerCheck(_shift_right, copies=2, steps=10)
  session = replan.Session(env, TowardGoal(DIM), config, horizon=16, candidates=('remainder',),
                           check=check)
  starts = np.array([[0.0, 0.0], [-0.5, 0.0]], np.float32)
  goals = np.array([[0.5, 0.0], [0.0, 0.0]], np.float32)
  session.plan(_nodes(env, starts, goals), key=jax.random.PRNGKey(0))
  # the last answer replaced by 5 moves right to the goals, 1 executed: the remainder's 4 moves
  # reach them; episode 0's copies, 0.08 further right, miss its goal and fall off the cliff on
  # their 4th move (3 safe), episode 1's take all 4
  straight = np.zeros((2, 16, DIM), np.float32)
  straight[:, :5, 0] = 1.0
  session.last = session.last.replace(actions=jnp.asarray(straight),
                                      length=jnp.full((2,), 5, jnp.int32))
  moved = _nodes(env, starts + [0.1, 0.0], goals)
  answer = jax.tree.map(np.asarray, session.plan(moved, executed=[1, 1],
                                                 key=jax.random.PRNGKey(1)))
  assert [AnswerKind.name(k) for k in answer.kind] == ['remainder'] * 2
  np.testing.assert_array_equal(answer.length, [4, 4])
  np.testing.assert_array_equal(answer.safe_length, [3, 4])
  # without a check the safe length is the length
  plain = replan.Session(env, TowardGoal(DIM), config, horizon=16)
  answer = plain.plan(moved, key=jax.random.PRNGKey(1))
  np.testing.assert_array_equal(answer.safe_length, answer.length)


@pytest.mark.parametrize('kwargs, message', [
    ({'perturb': None}, 'AnswerCheck.perturb must be a function'),
    ({'copies': 0}, 'AnswerCheck.copies must be a positive int'),
    ({'steps': 2.0}, 'AnswerCheck.steps must be a positive int'),
])
def test_bad_answer_checks_are_refused(kwargs, message):
  with pytest.raises(ValueError, match=message):
    replan.AnswerCheck(**{'perturb': _shift_right, **kwargs})


def test_perturb_t_moves_and_turns_the_t_by_its_draws_and_keeps_its_tilt():
  # two free Ts (arm, x y z, quaternion w x y z): one upright at yaw 0.3, one also tilted 0.2
  # rad about x; and a planar T (arm, x y yaw)
  upright = np.array([np.cos(0.15), 0.0, 0.0, np.sin(0.15)])
  tilted = np.array([np.cos(0.1), np.sin(0.1), 0.0, 0.0])
  w1, x1, y1, z1 = upright
  w2, x2, y2, z2 = tilted  # upright * tilted: yaw 0.3 of a T tilted about its own x axis
  both = np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                   w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])
  qpos = np.zeros((2, 14), np.float32)
  qpos[:, 7:10] = [0.1, 0.2, 0.02]
  qpos[0, 10:], qpos[1, 10:] = upright, both
  zeros = lambda n: jnp.zeros((2, n))
  free = base.NodeState(qpos=jnp.asarray(qpos), qvel=zeros(13), ctrl=zeros(7),
                        qacc_warmstart=zeros(13), goal=zeros(3), t=jnp.zeros(2, jnp.int32))
  keys = jax.random.split(jax.random.PRNGKey(4), 2)
  noise = np.asarray(jax.vmap(lambda k: jax.random.normal(k, (3,)))(keys)) * [0.002, 0.002, 0.05]
  moved = pusht.perturb_t(free, keys, position_m=0.002, yaw_rad=0.05)
  before, after = np.asarray(pusht.t_pose(free.qpos)), np.asarray(pusht.t_pose(moved.qpos))
  np.testing.assert_allclose(after - before, noise, atol=1e-5)
  np.testing.assert_allclose(pusht.t_tilt(moved.qpos), pusht.t_tilt(free.qpos), atol=1e-5)
  np.testing.assert_allclose(np.linalg.norm(np.asarray(moved.qpos)[:, 10:], axis=1), 1.0,
                             atol=1e-6)
  np.testing.assert_array_equal(moved.qpos[:, 9], free.qpos[:, 9])  # the height stays
  planar = free.replace(qpos=free.qpos[:, :10].at[:, 9].set(0.3))
  turned = pusht.perturb_t(planar, keys, position_m=0.002, yaw_rad=0.05)
  np.testing.assert_allclose(np.asarray(turned.qpos[:, 7:10] - planar.qpos[:, 7:10]), noise,
                             atol=1e-6)
