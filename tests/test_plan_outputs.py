"""A short `pachs plan` end to end and what it writes of a result (plans in --json, a still,
an animation), the drawings of PushT and shelf plans, and `pachs demo`'s scripted pusher."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import trees_equal
from PIL import Image

from pachs_jax import cli, demo, envs, outputs, saved_plans
from pachs_jax.runtime import programs
from pachs_jax.envs import backends, render
from pachs_jax.search import baselines as bl


@pytest.fixture
def captured_plans(monkeypatch):
  """Records (env, starts, result) of every `programs.plan` call, so a test can replay the plan
  `pachs plan` found on the very physics backend it planned with."""
  calls = []
  real = programs.plan

  def recording(env, model, starts, config, key, **kwargs):
    result = real(env, model, starts, config, key, **kwargs)
    calls.append((env, starts, result))
    return result

  monkeypatch.setattr(programs, 'plan', recording)
  return calls


def test_short_pusht_plan_finds_paths_that_replay_and_writes_them(tmp_path, capsys,
                                                                   captured_plans):
  """One `pachs plan` of PushT-Fixed: both instances reach their goals; the result arrays
  replay on the backend it planned with ('auto' on a CPU: MuJoCo C) to the costs in the rows;
  the plans in --json replay bit for bit; the still and the animation show instance 1."""
  # instances 0 and 1 need about 100 evaluations at K=16, N=8 (found at 96 and 88 with seed 0);
  # 400 leaves room and stays a few seconds of MuJoCo C physics
  rows_path, png, gif = tmp_path / 'rows.json', tmp_path / 'still.png', tmp_path / 'plan.gif'
  code = cli.main(['plan', '--task', 'pusht-fixed', '--instances', '0,1', '--budget', '400',
                   '-K', '16', '-N', '8', '--json', str(rows_path), '--render', str(png),
                   '--animate', str(gif), '--show-instance', '1'])
  assert code == 0
  out = capsys.readouterr().out
  assert 'found 2/2' in out
  assert 'drew instance 1' in out and 'animated instance 1' in out
  rows = json.loads(rows_path.read_text())['rows']
  assert [r['instance'] for r in rows] == [0, 1]
  for row in rows:
    assert row['found'] and row['stop'] == 'goal', row
    assert 0 < row['evaluated'] <= 400 and row['path_length'] >= 1

  # the returned result arrays, replayed from the starts on the backend it planned with, are
  # valid, end at the goal and cost what the rows say
  [(c_env, starts, result)] = captured_plans
  assert type(c_env).__name__ == 'MujocoCEnv'
  _, cost, valid, is_goal = bl.replay(c_env, starts, result.path_actions, result.path_length)
  np.testing.assert_array_equal(np.asarray(valid), True)
  np.testing.assert_array_equal(np.asarray(is_goal), True)
  np.testing.assert_array_equal(np.asarray(result.path_length), [r['path_length'] for r in rows])
  np.testing.assert_allclose(np.asarray(cost), [r['cost'] for r in rows], rtol=1e-5)

  # the plans in the rows replay bit for bit on the same physics
  env = backends.make_backend(envs.make('pusht-fixed'), 'mujoco-c')
  for row in rows:
    assert {'instance', 'found', 'cost', 'path_length', 'stop'} <= set(row)  # kept keys
    plan = saved_plans.from_json(row['plan'])
    assert plan.length == row['path_length'] and plan.cost == row['cost'] and plan.found
    again = saved_plans.replay(env, plan)
    assert trees_equal(again.states, plan.states)  # the same physics: bit for bit
    assert again.valid and again.is_goal
    assert again.cost == pytest.approx(plan.cost, rel=1e-5)
  frames = Image.open(gif)
  assert frames.n_frames == rows[1]['path_length'] + 1  # every state, the start first
  assert Image.open(png).size[0] > 300 and png.stat().st_size > 10_000


@pytest.mark.parametrize('argv, message', [
    (['--json', '{tmp}/same.png', '--render', '{tmp}/same.png'],
     '--json and --render name the same file'),
    (['--render', '{tmp}/a.png', '--animate', '{tmp}/a.png'],
     '--render and --animate name the same file'),
    (['--animate', '{tmp}/a.mp4'], 'animations are written as GIF'),
    (['--task', 'playground:ReacherEasy', '--animate', '{tmp}/a.gif'],
     "task 'playground:ReacherEasy' has no drawing"),
    (['--show-instance', '5', '--instances', '0,1'], '--show-instance 5 is not among'),
])
def test_bad_outputs_are_refused_before_planning(argv, message, tmp_path, capsys):
  argv = [a.replace('{tmp}', str(tmp_path)) for a in argv]
  with pytest.raises(SystemExit) as exit_info:
    cli.main(['plan', '--task', 'pusht-fixed'] + argv if '--task' not in argv else
             ['plan'] + argv)
  assert exit_info.value.code == 2
  err = capsys.readouterr()
  assert message in err.err and 'planning' not in err.out
  assert not list(tmp_path.iterdir())  # nothing written


def test_atomic_writes_keep_the_old_file_and_report_a_full_device(tmp_path):
  path = tmp_path / 'rows.json'
  path.write_text('old')

  def broken(f):
    f.write(b'new, half')
    raise OSError(28, 'No space left on device')

  with pytest.raises(OSError):
    outputs.write_atomically(str(path), broken)
  assert path.read_text() == 'old' and [p.name for p in tmp_path.iterdir()] == ['rows.json']
  outputs.write_json(str(path), {'a': 1})
  assert json.loads(path.read_text()) == {'a': 1}
  with pytest.raises(OSError):
    outputs.write_atomically('/dev/full', lambda f: f.write(b'x' * 100_000))


def _shelf_states(env, steps=6):
  node = jax.tree.map(lambda x: x[0], env.canonical_instances(1))
  action = jnp.asarray([0.0, 0.8, 0.0, 0.8, 0.0, -0.5, 0.0], jnp.float32)
  states, transition = [node], jax.jit(env.transition)
  for _ in range(steps):
    out = transition(states[-1], action)
    assert bool(out.is_valid)
    states.append(out.next_node)
  return jax.tree.map(lambda *x: np.stack(x), *states)


def test_shelf_plans_are_drawn_and_animated():
  env = envs.make('shelf')
  states = _shelf_states(env)
  fig = render.plan_figure(env, states, 'shelf')
  assert render.figure_pixels(fig).shape[2] == 3
  frames, note = render.animation_frames(env, states, 'shelf', arm=False)
  assert frames.shape[0] == 7 and note is None
  # the arm drawn moves with the plan: the tip (last point) follows env.tip_position
  arms = render.arm_points(env.mj_model, states.qpos)
  tips = np.stack([np.asarray(env.tip_position(q)) for q in states.qpos])
  np.testing.assert_allclose(arms[:, -1], tips, atol=1e-5)
  assert not np.array_equal(frames[0], frames[-1])


def test_scripted_pusher_pushes_the_t_through_the_gate():
  env = backends.make_backend(envs.make('pusht-obs', physics='planar'), 'mujoco-c')
  node = jax.tree.map(lambda x: x[0], env.canonical_instances(1))
  nodes, tips, cov, pushes = demo.scripted_push(env, node, 200)
  start, end = nodes.qpos[0, 7:9], nodes.qpos[-1, 7:9]
  goal = np.asarray(node.goal)[:2]
  assert pushes > 20
  assert start[1] > 0.1 > end[1]  # through the gate, below the blocks at y = 0.06 .. 0.10
  assert np.linalg.norm(end - goal) < 0.5 * np.linalg.norm(start - goal)
  assert cov[0] == 0.0 and cov.max() > 0.2
  assert tips.shape == (201, 3) and nodes.qpos.shape == (201, 10)


@pytest.mark.parametrize('steps, out, gif, message', [
    (100_000, 'a.png', None, 'steps must be an integer in 1..2000'),
    (10, 'a.png', 'a.png', '--out and --gif name the same file'),
])
def test_demo_refuses_bad_arguments_before_work(steps, out, gif, message, tmp_path):
  with pytest.raises(ValueError, match=message):
    demo.run_demo('pusht-obs', 0, str(tmp_path / out), steps,
                  gif and str(tmp_path / gif))
  assert not list(tmp_path.iterdir())
