"""PushT physics options (free T reference, block contacts) and the planner-world agreement
check (`experiments/agreement.py`)."""

import jax
import mujoco
import numpy as np
import pytest


import agreement  # noqa: E402  pylint: disable=wrong-import-position
from pachs_jax.envs import pusht  # noqa: E402  pylint: disable=wrong-import-position


@pytest.mark.parametrize('field, value, words', [
    ('t_body', 'floating', 't_body'), ('solver', 'PGS', 'solver'),
    ('physics_dt', -0.01, 'physics_dt'), ('substeps', 0, 'substeps'),
    ('block_solref', (0.01,), 'block_solref'), ('block_margin', -0.001, 'block_margin')])
def test_bad_physics_fields_are_named(field, value, words):
  config = pusht.PushTConfig(**{field: value})
  with pytest.raises(ValueError, match=words):
    pusht.model_xml(config)


FREE = dict(t_body='free', table_friction=3.0, physics_dt=0.005, substeps=10)


def test_free_env_reads_the_same_pose_cost_and_observation():
  planar = pusht.PushTEnv(pusht.physics_preset('planar'))
  free = pusht.PushTEnv(pusht.PushTConfig(**FREE))
  pose, goal = np.array([-0.1, 0.05, 1.0]), np.asarray(pusht.FIXED_GOAL)
  node_p, node_f = planar.node_from_pose(pose, goal), free.node_from_pose(pose, goal)
  assert node_f.qpos.shape == (14,) and node_f.qvel.shape == (13,)
  np.testing.assert_allclose(pusht.t_pose(node_f.qpos), pose, atol=1e-6)
  np.testing.assert_allclose(free.observation(node_f), planar.observation(node_p), atol=1e-5)
  # the tip 6 cm from the T's centre in the plane: at the T's half height both costs agree; 5 cm
  # higher, only the free T's reach term (3D, as ManiSkill's reward) and its height term count
  tip = np.array([pose[0] + 0.06, pose[1], pusht.T_HALF_HEIGHT])
  assert float(free._cost(node_f, tip)) == pytest.approx(float(planar._cost(node_p, tip)),
                                                        abs=1e-6)
  high = tip + np.array([0.0, 0.0, 0.05])
  assert float(planar._cost(node_p, high)) == pytest.approx(float(planar._cost(node_p, tip)))
  extra = (free.config.w_reach * (np.hypot(0.06, 0.05) - 0.05 - 0.01)
           + free.config.w_height * 0.05)
  assert float(free._cost(node_f, high)) == pytest.approx(float(free._cost(node_f, tip)) + extra,
                                                         abs=1e-5)
  at_goal = free.node_from_pose(goal, goal)
  assert bool(free.goal_reached(at_goal)) and not bool(free.goal_reached(node_f))


def test_free_env_mujoco_c_edges_follow_the_world():
  from pachs_jax.envs import mujoco_c, world as world_lib
  env = pusht.PushTEnv(pusht.PushTConfig(**FREE))
  backend = mujoco_c.MujocoCEnv(env, nthread=1)
  world = world_lib.World(env)
  node = env.node_from_pose(np.array([-0.3, -0.25, 0.3]), np.asarray(pusht.FIXED_GOAL))
  node = jax.tree.map(np.asarray, node)
  world.reset(node)
  model, data = world.model, mujoco.MjData(world.model)
  start = np.asarray(pusht.t_pose(node.qpos))
  for _ in range(12):  # the tip goes through the T's centre: contact
    action = pusht.jacobian_action(model, data, np.array([-0.25, -0.2, 0.02]),
                                   np.asarray(node.qpos, np.float64))
    out = backend.evaluate(jax.tree.map(lambda x: np.asarray(x)[None], node),
                           np.asarray(action, np.float32)[None])
    assert bool(out.is_valid[0])
    node = jax.tree.map(lambda x: np.asarray(x[0]), out.next_node)
    truth = world.execute(action[None])[-1]
    np.testing.assert_allclose(node.qpos, truth.qpos, atol=1e-3)
  assert np.linalg.norm(np.asarray(pusht.t_pose(node.qpos))[:2] - start[:2]) > 0.005  # pushed


def test_a_tipped_free_t_is_invalid():
  from pachs_jax.envs import mujoco_c
  env = pusht.PushTEnv(pusht.PushTConfig(**FREE))
  backend = mujoco_c.MujocoCEnv(env, nthread=1)
  node = env.node_from_pose(np.array([-0.1, 0.05, 0.0]), np.asarray(pusht.FIXED_GOAL))
  on_side = np.array([0.0, 0.0, 0.05, np.cos(0.7), np.sin(0.7), 0.0, 0.0])  # 80 deg about x
  node = node.replace(qpos=node.qpos.at[7:].set(on_side))
  out = backend.evaluate(jax.tree.map(lambda x: x[None], node), np.zeros((1, 7), np.float32))
  assert not bool(out.is_valid[0])
  assert float(pusht.t_tilt(out.next_node.qpos[0])) > pusht.MAX_T_TILT


def test_defaults_build_the_free_t_and_the_planar_preset_its_joints():
  model = mujoco.MjModel.from_xml_string(pusht.model_xml(pusht.PushTConfig()))
  assert (model.nq, model.nv) == (14, 13) and model.opt.gravity[2] == pytest.approx(-9.81)
  assert model.opt.timestep == 0.0025 and model.opt.iterations == 20
  table = [p for p in range(model.npair) if 'table' in (
      model.geom(model.pair_geom1[p]).name, model.geom(model.pair_geom2[p]).name)]
  assert sorted(model.pair_friction[table, 0].round(6))[1:] == [1.65, 1.65]  # bar, stem
  # the planar preset: the T on slide and hinge joints with friction loss, no gravity
  model = mujoco.MjModel.from_xml_string(pusht.model_xml(pusht.physics_preset('planar')))
  assert (model.nq, model.nv) == (10, 10)
  assert model.opt.gravity[2] == 0.0
  fl = model.dof_frictionloss[7:10]
  np.testing.assert_allclose(fl, [0.5 * 0.8 * 9.81] * 2 + [0.5 * 0.8 * 9.81 * 0.05], rtol=1e-6)


def test_planar_and_free_states_round_trip():
  rng = np.random.default_rng(0)
  qpos, qvel = rng.normal(size=(5, 10)), rng.normal(size=(5, 10))
  qpos[:, 9] = rng.uniform(-np.pi, np.pi, 5)
  free_q, free_v = pusht.free_t_state(qpos, qvel)
  assert free_q.shape == (5, 14) and free_v.shape == (5, 13)
  np.testing.assert_allclose(np.linalg.norm(free_q[:, 10:14], axis=-1), 1.0)
  back_q, back_v = pusht.planar_t_state(free_q, free_v)
  np.testing.assert_allclose(back_q, qpos, atol=1e-12)
  np.testing.assert_allclose(back_v, qvel, atol=1e-12)


def _free_t(mu: float):
  config = pusht.PushTConfig(t_body='free', table_friction=mu, physics_dt=0.002, substeps=1)
  model = mujoco.MjModel.from_xml_string(pusht.model_xml(config))
  data = mujoco.MjData(model)
  home = np.concatenate([pusht.HOME_QPOS, [0.1, 0.2, 0.0]])
  data.qpos[:], _ = pusht.free_t_state(home, np.zeros(10))
  data.ctrl[:] = pusht.HOME_QPOS
  return model, data


def test_free_t_rests_on_the_table_under_gravity():
  model, data = _free_t(3.0)
  start = data.qpos.copy()
  mujoco.mj_step(model, data, nstep=500)  # 1 s
  assert np.linalg.norm(data.qpos[7:9] - start[7:9]) < 1e-4
  assert 0.0 < pusht.T_HALF_HEIGHT - data.qpos[9] < 2e-3  # MuJoCo's soft contact: < 2 mm
  np.testing.assert_allclose(np.abs(data.qpos[10]), 1.0, atol=1e-6)  # no tilt


@pytest.mark.parametrize('ratio', [0.7, 1.5])
def test_free_t_obeys_coulomb_friction(ratio):
  # a horizontal force at the T's centre: below mu m g it sticks, above it slides with
  # acceleration (F - mu m g) / m
  mu, g, seconds = 0.5, 9.81, 0.5
  model, data = _free_t(mu)
  mujoco.mj_step(model, data, nstep=100)  # settle
  start = data.qpos[7].copy()
  force = ratio * mu * pusht.T_MASS * g
  data.xfrc_applied[model.body('tblock').id, 0] = force
  mujoco.mj_step(model, data, nstep=int(seconds / model.opt.timestep))
  moved = data.qpos[7] - start
  expected = 0.5 * max(force - mu * pusht.T_MASS * g, 0.0) / pusht.T_MASS * seconds ** 2
  if expected == 0.0:
    assert abs(moved) < 1e-3
  else:
    assert moved == pytest.approx(expected, rel=0.2)


def test_agreement_check_passes_the_same_physics():
  # the MuJoCo C edge backend (float32 states) replays the float64 world of its own config
  report = agreement.check_agreement(pusht.PushTConfig(), 'mujoco-c', instances=3, steps=20)
  assert report.passed, report.message()
  assert report.replays == 6
  assert report.position_mm_p90 < 0.5 and report.angle_deg_p90 < 0.2
  assert 'agrees with' in report.message()


def test_agreement_check_reports_a_large_time_step_with_numbers():
  # planner physics at 25 ms x 2 against the task's 2.5 ms x 20 world: refused, with numbers
  coarse = pusht.PushTConfig(physics_dt=0.025, substeps=2)
  report = agreement.check_agreement(coarse, 'mujoco-c', instances=3, steps=20,
                                     world_config=pusht.PushTConfig())
  assert not report.passed
  assert report.position_mm_p90 > 5.0
  message = report.message()
  assert 'DOES NOT agree' in message
  assert f'{report.position_mm_p90:.2f} mm' in message and '0.025 s x 2 substeps' in message


def test_agreement_command_exit_status(capsys):
  bad = ['--variant', 'fixed', '--planner', 'mujoco-c', '--instances', '3', '--physics-dt',
         '0.025', '--substeps', '2', '--world-physics-dt', '0.0125', '--world-substeps', '4']
  assert agreement.main(bad) == 1
  assert 'DOES NOT agree' in capsys.readouterr().out
  with pytest.raises(SystemExit):  # a bad field: one line from argparse, before any work
    agreement.main(['--variant', 'fixed', '--physics-dt', '-1'])
  assert 'physics_dt' in capsys.readouterr().err

