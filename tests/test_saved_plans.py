"""`plans`: each instance's plan as actions and states, its JSON form, and its replay through the
env's own transition, against the search's own path."""

import dataclasses
import json

import jax
import numpy as np
import pytest
from conftest import UniformActorCritic, trees_equal

from pachs_jax import saved_plans
from pachs_jax.envs import gridworld, point_mass, pusht
from pachs_jax.runtime.programs import plan
from pachs_jax.search import Capacities, SearchConfig, instance_keys, make_search


def _grid_problem():
  obstacles = np.zeros((12, 12), bool)
  obstacles[2:10, 6] = True  # a wall the path must go around
  env = gridworld.GridWorld(obstacles)
  starts = np.array([[5, 1], [0, 0], [11, 11]])
  goals = np.array([[5, 10], [11, 11], [11, 11]])  # the last: start == goal
  return env, gridworld.GridActorCritic(env), env.node(starts, goals), goals


@pytest.fixture(scope='module')
def grid_plans():
  env, actor_critic, nodes, goals = _grid_problem()
  config = SearchConfig(weight=1.0, num_actions=8, pop_size=2, budget=2000)
  result = plan(env, actor_critic, nodes, config, instance_keys(jax.random.PRNGKey(0), 3))
  return env, result, saved_plans.from_result(result), goals


def test_plans_hold_the_results_paths(grid_plans):
  env, result, found, goals = grid_plans
  assert len(found) == 3
  for i, p in enumerate(found):
    assert p.found and p.ends_at_goal and not p.truncated
    assert p.length == int(result.path_length[i]) and p.actions.shape == (p.length, 2)
    assert p.states.qpos.shape == (p.length + 1, 2)
    np.testing.assert_array_equal(p.states.qpos[-1], goals[i])
    assert p.cost == float(result.cost[i])
    cheapest = gridworld.shortest_path_cost(env.obstacles, p.states.qpos[0], goals[i])
    assert p.cost == pytest.approx(cheapest, rel=1e-6)  # w = 1, K small: optimal
  assert found[2].length == 0 and found[2].actions.shape == (0, 2)


def test_replay_reaches_the_searchs_states_bit_for_bit(grid_plans):
  env, _, found, _ = grid_plans
  for p in found:
    again = saved_plans.replay(env, p)
    assert trees_equal(again.states, p.states)
    assert again.valid and again.is_goal
    assert again.step_costs.shape == (p.length,)
    assert again.cost == pytest.approx(p.cost, rel=1e-6)


def test_json_round_trip_is_exact_and_replays(grid_plans):
  env, _, found, _ = grid_plans
  for p in found:
    back = saved_plans.from_json(json.loads(json.dumps(saved_plans.to_json(p))))
    assert trees_equal(back.states, p.states)
    np.testing.assert_array_equal(back.actions, p.actions)
    assert (back.cost, back.found, back.length) == (p.cost, p.found, p.length)
    assert trees_equal(saved_plans.replay(env, back).states, p.states)


def test_segment_edges_expand_into_transitions_and_replay_exactly():
  # edges of 3 transitions (one sampled action, then two of the actor's) on the point mass,
  # with paths cut at 4 transitions: the plan holds the transitions, and their prefix
  env = point_mass.PointMassEnv()
  nodes = env.initial_nodes(jax.random.split(jax.random.PRNGKey(3), 2))
  config = SearchConfig(weight=1.0, num_actions=4, pop_size=4, budget=600,
                        edge_steps=3)
  result = plan(env, UniformActorCritic(2), nodes, config, jax.random.PRNGKey(1))
  cut = plan(env, UniformActorCritic(2), nodes, config, jax.random.PRNGKey(1),
             search=make_search(env, UniformActorCritic(2), config,
                                capacities=Capacities(max_path_length=4)))
  for whole, part in zip(saved_plans.from_result(result), saved_plans.from_result(cut)):
    assert whole.length == whole.states.t[-1] > 3  # transitions, not edges
    again = saved_plans.replay(env, whole)
    assert trees_equal(again.states, whole.states) and again.valid
    assert again.cost == pytest.approx(whole.cost, rel=1e-5)
    assert part.truncated and part.length == 4
    np.testing.assert_array_equal(part.actions, whole.actions[:4])
    assert trees_equal(saved_plans.replay(env, part).states, part.states)


def test_bad_plans_are_refused():
  env = point_mass.PointMassEnv()
  with pytest.raises(ValueError, match='not a plan'):
    saved_plans.from_json({'actions': []})
  good = saved_plans.to_json(saved_plans.Plan(
      actions=np.zeros((2, 2), np.float32), cost=0.0, found=False, ends_at_goal=False,
      truncated=False, states=jax.tree.map(
          lambda x: np.stack([np.asarray(x)] * 3), env.node_from_positions([0, 0], [1, 1]))))
  with pytest.raises(ValueError, match='L \\+ 1 rows'):
    saved_plans.from_json(dict(good, actions=[[0.0, 0.0]]))
  three_d = saved_plans.from_json(good)
  with pytest.raises(ValueError, match='takes \\[L, 3\\]'):
    saved_plans.replay(point_mass.PointMassEnv(point_mass.PointMassConfig(dim=3)), three_d)


def test_a_plan_of_another_node_type_round_trips_through_json_with_like():
  from flax import struct

  @struct.dataclass
  class Node:
    pos: jax.Array
    extra: dict

  states = Node(pos=np.arange(6, dtype=np.float32).reshape(3, 2) / 7,
                extra={'count': np.arange(3, dtype=np.int32)})
  plan = saved_plans.Plan(actions=np.full((2, 1), 0.3, np.float32), states=states, cost=1.5,
                    found=True, ends_at_goal=True, truncated=False)
  data = json.loads(json.dumps(saved_plans.to_json(plan)))
  assert data['node_type'].endswith('Node')
  back = saved_plans.from_json(data, like=states)
  assert back.states.pos.tobytes() == states.pos.tobytes()
  np.testing.assert_array_equal(back.states.extra['count'], states.extra['count'])
  assert back.states.extra['count'].dtype == np.int32
  with pytest.raises(ValueError, match='needs like='):
    saved_plans.from_json(data)


def test_a_plan_records_its_physics_and_refuses_another(grid_plans):
  env, result, _, _ = grid_plans
  made = saved_plans.from_result(result, physics=env.physics)[0]
  back = saved_plans.from_json(json.loads(json.dumps(saved_plans.to_json(made))))
  assert back.physics == env.physics == 'jax'
  assert saved_plans.replay(env, back).is_goal
  # a plan made by another engine reaches other states here: refused in one line
  other = saved_plans.from_json(dict(saved_plans.to_json(made), physics='mujoco-c'))
  with pytest.raises(ValueError, match='made with mujoco-c physics .* simulates with jax'):
    saved_plans.replay(env, other)
  # plans saved without a record replay as before
  unknown = saved_plans.from_json({k: v for k, v in saved_plans.to_json(made).items() if k != 'physics'})
  assert unknown.physics is None and saved_plans.replay(env, unknown).is_goal


def test_a_plan_refuses_other_physics_settings_and_make_env_builds_them():
  env = saved_plans.make_env('pusht-fixed', 'mjx')
  start = env.initial_nodes(jax.random.split(jax.random.PRNGKey(0), 1))  # NodeState [1]
  plan = saved_plans.Plan(actions=np.zeros((0, 7), np.float32), states=start, cost=0.0,
                          found=False, ends_at_goal=False, truncated=False, physics='mjx',
                          physics_settings=dict(env.physics_settings, t_damping=0.7))
  back = saved_plans.from_json(json.loads(json.dumps(saved_plans.to_json(plan))))
  assert back.physics_settings == plan.physics_settings
  with pytest.raises(ValueError, match='other physics settings .*t_damping'):
    saved_plans.replay(env, back)
  other = saved_plans.make_env('pusht-fixed', 'mjx', physics_settings=back.physics_settings)
  assert other.config.t_damping == 0.7 and other.physics_settings == back.physics_settings
  planar = saved_plans.make_env('pusht-fixed', 'mjx', physics_settings=pusht.physics_settings(
      pusht.physics_preset('planar')))
  assert planar.config.t_body == 'planar'  # block contacts act nowhere on pusht-fixed
  assert planar.physics_settings == pusht.physics_settings(pusht.physics_preset('planar'),
                                                           blocks=False)
  # a plan saved when tasks without obstacles recorded block contacts replays as before
  old = dataclasses.replace(plan, physics_settings=pusht.physics_settings(env.config))
  assert set(pusht.BLOCK_FIELDS) <= set(old.physics_settings)
  assert saved_plans.make_env('pusht-fixed', 'mjx', physics_settings=old.physics_settings
                              ).physics_settings == env.physics_settings
  saved_plans.replay(env, old)
  with pytest.raises(ValueError, match="takes no physics settings t_damping"):
    saved_plans.make_env('shelf', 'jax', physics_settings={'t_damping': 0.7})
  partial = {k: v for k, v in env.physics_settings.items() if k != 'solver'}
  with pytest.raises(ValueError, match='record lacks solver, which task .pusht-fixed. simulates'):
    saved_plans.make_env('pusht-fixed', 'mjx', physics_settings=partial)


def test_the_shipped_models_record_their_physics_and_a_mismatch_is_said():
  from pachs_jax import planner
  from pachs_jax.sac import checkpoint
  path = planner.checkpoint_path('pusht-obs')  # the PushT-Fixed model
  default = pusht.PushTEnv(pusht.PushTConfig())
  assert checkpoint.trained_physics(path) == {'engine': 'warp',
                                              'settings': default.physics_settings}
  assert checkpoint.physics_mismatch(path, default) is None  # the same model in any engine
  planar = pusht.PushTEnv(pusht.physics_preset('planar'))
  note = checkpoint.physics_mismatch(path, planar)
  assert "trained on other physics than 'pusht-fixed'" in note
  assert 'physics_dt 0.0025 -> 0.0125' in note and 'and 2 more' in note  # 6 fields differ
  # a task without obstacles records no block contacts: the model trained on PushT-Fixed meets
  # any block settings of PushT-Obs without a mismatch, other settings with one
  assert not set(pusht.BLOCK_FIELDS) & set(default.physics_settings)
  for physics in ('faithful', 'soft-blocks'):
    obs = pusht.PushTEnv(pusht.physics_preset(physics, variant='obs', layout='wall'))
    assert obs.physics_settings['block_margin'] == obs.config.block_margin
    assert checkpoint.physics_mismatch(path, obs) is None
  damped = pusht.PushTEnv(pusht.PushTConfig(variant='obs', layout='wall', t_damping=0.7))
  assert 't_damping 0.5 -> 0.7' in checkpoint.physics_mismatch(path, damped)


def test_make_env_builds_the_engine_a_plan_names():
  assert saved_plans.make_env('pusht-fixed', 'mjx').physics == 'mjx'
  env = saved_plans.make_env('pusht-obs', 'mujoco-c', layout='wall')
  try:
    assert env.physics == 'mujoco-c' and env.layout.name == 'wall'
  finally:
    env.close()
  with pytest.raises(ValueError, match="'shelf' simulates with 'jax', not 'mjx'"):
    saved_plans.make_env('shelf', 'mjx')
