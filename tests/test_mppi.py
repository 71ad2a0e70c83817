"""MPPI baseline on the analytic point mass (CPU, stand-in actor-critics)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import UniformActorCritic, assert_results_equal, take

from pachs_jax.envs.point_mass import PointMassEnv
from pachs_jax.runtime import anytime
from pachs_jax.search import StopReason
from pachs_jax.search import baselines as bl
from pachs_jax.search.baselines import common
from pachs_jax.search import instance_keys

DIM = 2


class Attractor:
  """A critic that pulls toward POINT instead of the goal: Q(s, a) = -10 |p + 0.1 a - POINT|
  (p the position, obs[:, :2]); the deterministic policy is a constant sideways step."""

  POINT = jnp.array([-0.6, 0.0], jnp.float32)
  ACTION = jnp.array([0.0, 0.3], jnp.float32)

  def deterministic_action(self, obs):
    return jnp.broadcast_to(self.ACTION, (obs.shape[0], DIM))

  def q_values(self, obs, actions):
    moved = obs[:, None, :DIM] + 0.1 * actions
    return -10.0 * jnp.linalg.norm(moved - self.POINT, axis=-1)


def _nodes(env, starts, goals):
  return jax.vmap(env.node_from_positions)(jnp.asarray(starts, jnp.float32),
                                           jnp.asarray(goals, jnp.float32))


def _replay_cost(env, start, actions):
  length = jnp.full((actions.shape[0],), actions.shape[1], jnp.int32)
  nodes, cost, _, is_goal = common.replay(env, start, actions, length)
  return np.asarray(cost), np.asarray(is_goal), nodes


@pytest.fixture(scope='module')
def env():
  return PointMassEnv()


# two goals 0.7 to 0.8 away (reachable in 12 steps of 0.1, never by standing still); the third
# instance starts at its goal
@pytest.fixture(scope='module')
def start(env):
  return _nodes(env, [[-0.3, -0.3], [0.4, 0.0], [0.1, 0.1]],
                [[0.3, 0.2], [-0.3, 0.1], [0.1, 0.1]])


@pytest.fixture(scope='module')
def planner(env):
  config = bl.MppiConfig(num_samples=64, horizon=12, temperature=0.1, noise_std=0.5,
                         max_iterations=20, policy_prior_samples=8)
  # a poor actor-critic: the deterministic policy stays put, the proposals are uniform noise
  # and the critic knows nothing
  return bl.make_mppi(env, UniformActorCritic(DIM), config)


@pytest.fixture(scope='module')
def result(planner, start):
  # a wall-clock limit far away: one jitted iteration per host step, the same compiled step
  # as the tests that call planner.step
  return anytime.run_search(planner, start, jax.random.PRNGKey(0), time_limit_s=1e6)


# ---------------------------------------------------------------- behaviour


def test_iterations_improve_the_nominal_until_a_goal(env, start, planner):
  state = planner.init(start, jax.random.PRNGKey(0))
  np.testing.assert_array_equal(np.asarray(state.nominal), 0.0)  # the policy's warm start
  costs = []
  while bool(jnp.any(state.active)):
    cost, is_goal, _ = _replay_cost(env, start, state.nominal)
    assert not is_goal[:2].any()
    costs.append(cost[:2])
    state = planner.step(state)
  costs = np.array(costs)
  assert len(costs) >= 2
  # the nominal's 12-step cost falls from the standing-still cost by more than a half
  assert np.all(costs[-1] < 0.5 * costs[0]), costs
  assert np.all(np.diff(costs, axis=0) <= 1e-5), costs
  assert bool(jnp.all(state.found))
  np.testing.assert_array_equal(np.asarray(state.stop_reason), StopReason.GOAL)
  np.testing.assert_array_equal(np.asarray(state.iterations)[2], 0)


def test_result_reaches_goal_and_replays(env, start, planner, result):
  h = planner.config.horizon
  assert result.path_actions.shape == (3, h, DIM)
  np.testing.assert_array_equal(np.asarray(result.found), True)
  np.testing.assert_array_equal(np.asarray(result.path_is_goal), True)
  np.testing.assert_array_equal(np.asarray(result.stop_reason), StopReason.GOAL)
  length = np.asarray(result.path_length)
  assert np.all(length[:2] >= 6) and np.all(length[:2] <= h) and length[2] == 0
  rows = np.arange(h)[None, :, None] >= length[:, None, None]
  assert np.all(np.where(rows, np.asarray(result.path_actions), 0.0) == 0.0)
  # replaying path_actions from the start through env.evaluate gives path_nodes and cost
  node, total = start, np.zeros(3)
  for t in range(h):
    live = t < length
    np.testing.assert_array_equal(np.asarray(result.path_nodes.qpos)[live, t],
                                  np.asarray(node.qpos)[live])
    out = env.evaluate(node, result.path_actions[:, t])
    assert np.all(np.asarray(out.is_valid)[live])
    total += np.where(live, np.asarray(out.cost), 0.0)
    node = jax.tree.map(lambda n, o: jnp.where(
        live.reshape((-1,) + (1,) * (n.ndim - 1)), n, o), out.next_node, node)
  np.testing.assert_array_equal(np.asarray(result.path_nodes.qpos)[np.arange(3), length],
                                np.asarray(node.qpos))
  assert bool(jnp.all(env.is_goal(node)))
  np.testing.assert_allclose(total, np.asarray(result.cost), rtol=1e-6)
  # counters: S * H per iteration, none for the start-at-goal instance
  s, evaluated = planner.config.num_samples, np.asarray(result.evaluated)
  np.testing.assert_array_equal(evaluated, np.asarray(result.iterations) * s * h)
  assert evaluated[2] == 0 and np.all(evaluated[:2] > 0)
  assert np.all(np.asarray(result.generated)[:2] > 1)
  assert np.isfinite(float(result.wall_time_s)) and float(result.wall_time_s) > 0


def test_batch_equals_one_by_one(start, planner, result):
  keys = instance_keys(jax.random.PRNGKey(0), 3)
  for i in range(3):
    one = anytime.run_search(planner, take(start, i), keys[i:i + 1], time_limit_s=1e6)
    assert_results_equal(one, take(result, i))


class _Counted:
  """A jitted function whose compiled programs note each run in `runs` (under `name`)."""

  def __init__(self, fn, runs, name):
    self.fn, self.runs, self.name = fn, runs, name

  def __call__(self, *args):
    return self.fn(*args)

  def lower(self, *args):
    lowered, runs, name = self.fn.lower(*args), self.runs, self.name

    class Lowered:
      def compile(self):
        program = lowered.compile()
        return lambda *a: runs.append(name) or program(*a)
    return Lowered()


def test_kept_programs_compile_once_and_run_once_before_the_first_clock(start, planner, result):
  """With a dict kept between calls, run_search compiles a shape's programs once and runs them
  once before their first clock (a first run's lazy loads on no clock); a later call neither
  compiles nor warms again, and both return the uncached result."""
  runs, compiled = [], {}
  counted = dataclasses.replace(planner, **{name: _Counted(getattr(planner, name), runs, name)
                                            for name in ('init', 'step', 'result')})
  got = anytime.run_search(counted, start, jax.random.PRNGKey(0), time_limit_s=1e6,
                           compiled=compiled)
  assert runs[:4] == ['init', 'step', 'result', 'init'], runs[:4]  # the warm-up, then the search
  assert_results_equal(got, result)
  runs.clear()
  again = anytime.run_search(counted, start, jax.random.PRNGKey(0), time_limit_s=1e6,
                             compiled=compiled)
  assert runs.count('init') == 1 and len(compiled) == 1
  assert_results_equal(again, result)


def test_time_limit_stops_after_one_iteration(start, planner):
  out = anytime.run_search(planner, start, jax.random.PRNGKey(0), time_limit_s=1e-9)
  np.testing.assert_array_equal(np.asarray(out.iterations), [1, 1, 0])
  np.testing.assert_array_equal(np.asarray(out.stop_reason),
                                [StopReason.TIME_LIMIT, StopReason.TIME_LIMIT, StopReason.GOAL])
  # without a goal the path is the nominal, cut at nothing (all edges valid, no goal)
  np.testing.assert_array_equal(np.asarray(out.found), [False, False, True])
  np.testing.assert_array_equal(np.asarray(out.path_length), [12, 12, 0])


# the critic-steering and budget tests share one small configuration: goal 0.6 to the right,
# out of reach in 4 steps of 0.1; the Attractor's critic pulls to the left


@pytest.fixture(scope='module')
def small_config():
  return bl.MppiConfig(num_samples=32, horizon=4, temperature=0.1, noise_std=0.5,
                       max_iterations=100, budget=1100, policy_prior_samples=0,
                       terminal_weight=0.0)


@pytest.fixture(scope='module')
def far(env):
  return _nodes(env, [[0.0, 0.0]], [[0.6, 0.0]])


def test_budget_is_respected(env, far, small_config):
  planner = bl.make_mppi(env, Attractor(), small_config)
  out = anytime.run_search(planner, far, jax.random.PRNGKey(1))
  assert int(out.stop_reason[0]) == StopReason.BUDGET and not bool(out.found[0])
  assert int(out.evaluated[0]) <= small_config.budget
  assert int(out.evaluated[0]) == int(out.iterations[0]) * 32 * 4 == 1024
  # without the critic the edge costs pull the plan toward the goal
  _, _, nodes = _replay_cost(env, far, out.path_actions)
  assert float(nodes.qpos[0, -1, 0]) > 0.2
  # replay gives path_nodes
  np.testing.assert_array_equal(np.asarray(nodes.qpos), np.asarray(out.path_nodes.qpos))


def test_terminal_critic_steers_the_plan(env, far, small_config):
  config = dataclasses.replace(small_config, terminal_weight=1.0, budget=1024)
  planner = bl.make_mppi(env, Attractor(), config)
  state = planner.init(far, jax.random.PRNGKey(1))
  # warm start: the deterministic policy's actions
  np.testing.assert_allclose(np.asarray(state.nominal),
                             np.broadcast_to(Attractor.ACTION, (1, 4, DIM)))
  state = planner.run(state)
  assert int(state.stop_reason[0]) == StopReason.BUDGET and int(state.iterations[0]) == 8
  out = planner.result(state)
  _, _, nodes = _replay_cost(env, far, out.path_actions)
  assert float(nodes.qpos[0, -1, 0]) < -0.25  # toward the critic's point, away from the goal
  assert np.isfinite(float(state.best_score[0]))
  # fallback='best' returns the lowest-score sampled sequence instead of the nominal
  best = bl.make_mppi(env, Attractor(), dataclasses.replace(config, fallback='best'))
  np.testing.assert_array_equal(np.asarray(best.result(state).path_actions),
                                np.asarray(state.best_actions))


def test_given_nominal_and_shift_plan(env, far, small_config):
  planner = bl.make_mppi(env, Attractor(), small_config)
  nominal = jnp.arange(8, dtype=jnp.float32).reshape(1, 4, 2) / 10.0
  state = planner.init(far, jax.random.PRNGKey(1), nominal)
  np.testing.assert_array_equal(np.asarray(state.nominal), np.asarray(nominal))
  shifted = bl.shift_plan(nominal, 3)
  np.testing.assert_array_equal(np.asarray(shifted)[0], np.asarray(nominal)[0, [3, 3, 3, 3]])
  with pytest.raises(ValueError, match='nominal must have shape'):
    planner.init(far, jax.random.PRNGKey(1), nominal[:, :3])


class Wall(PointMassEnv):
  """The point mass with a wall: an edge that ends at x > 0.2 is invalid."""

  def transition(self, node, action):
    out = super().transition(node, action)
    inside = out.next_node.qpos[0] > 0.2
    return out.replace(is_valid=out.is_valid & ~inside, is_goal=out.is_goal & ~inside)


class PushRight(UniformActorCritic):
  """A stochastic policy that always pushes right (into the Wall)."""

  def sample_actions(self, key, obs, num):
    del key
    return jnp.broadcast_to(jnp.array([1.0, 0.0], jnp.float32), (obs.shape[0], num, DIM))


def test_invalid_edges_are_penalised_and_cut(far, small_config):
  env = Wall()
  config = dataclasses.replace(small_config, policy_prior_samples=16, budget=1024)
  planner = bl.make_mppi(env, PushRight(DIM), config)
  state = planner.run(planner.init(far, jax.random.PRNGKey(2)))
  iterations = int(state.iterations[0])
  assert iterations == 8
  # each iteration the 16 policy rollouts hit the wall on their third edge, and end there
  assert int(state.invalid[0]) >= 16 * iterations
  assert int(state.live[0]) < int(state.evaluated[0])
  assert int(state.applied[0]) + int(state.invalid[0]) == int(state.live[0])
  out = planner.result(state)
  assert 0.0 < float(out.lane_utilization[0]) < 1.0
  # the penalty keeps the nominal out of the wall: its whole horizon is valid
  assert int(out.path_length[0]) == 4
  _, _, valid, _ = common.replay(env, far, out.path_actions, out.path_length)
  assert bool(valid[0]) and float(jnp.max(out.path_nodes.qpos[0, :, 0])) <= 0.2
  # a nominal that runs into the wall is returned up to its first invalid edge
  into_wall = jnp.broadcast_to(jnp.array([1.0, 0.0], jnp.float32), (1, 4, DIM))
  out = planner.result(planner.init(far, jax.random.PRNGKey(2), into_wall))
  assert int(out.path_length[0]) == 2 and not bool(out.found[0])
  np.testing.assert_allclose(np.asarray(out.path_nodes.qpos[0, -1]), [0.2, 0.0], atol=1e-6)


# ---------------------------------------------------------------- validation


@pytest.mark.parametrize('kwargs, match', [
    (dict(temperature=0.0), 'temperature'),
    (dict(temperature=-1.0), 'temperature'),
    (dict(temperature=float('nan')), 'temperature'),
    (dict(horizon=0), 'horizon'),
    (dict(num_samples=True), 'num_samples'),
    (dict(noise_std=-0.1), 'noise_std'),
    (dict(max_iterations=0), 'max_iterations'),
    (dict(num_samples=8, policy_prior_samples=9), 'policy_prior_samples'),
    (dict(terminal_weight=float('inf')), 'terminal_weight'),
    (dict(invalid_penalty=-1.0), 'invalid_penalty'),
    (dict(num_samples=10, horizon=10, budget=99), 'budget'),
    (dict(fallback='mean'), 'fallback'),
])
def test_bad_configs_raise(kwargs, match):
  with pytest.raises(ValueError, match=match):
    bl.MppiConfig(**kwargs)


def test_bad_inputs_raise(env, start, planner):
  with pytest.raises(ValueError, match='MppiConfig'):
    bl.make_mppi(env, UniformActorCritic(DIM), bl.BeamConfig())
  with pytest.raises(ValueError, match='sample_actions'):
    bl.make_mppi(env, Attractor(), bl.MppiConfig(policy_prior_samples=1))
  with pytest.raises(ValueError, match='time_limit_s'):
    anytime.run_search(planner, start, jax.random.PRNGKey(0), time_limit_s=0.0)
  with pytest.raises(ValueError, match='start_nodes'):
    anytime.run_search(planner, jax.tree.map(lambda x: x[0], start), jax.random.PRNGKey(0))
