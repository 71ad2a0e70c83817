"""The MuJoCo Playground adapter (envs/playground.py) on PointMass, whose assets ship in the
playground wheel: restore-then-step against the env's own step bit for bit, the goal rule,
costs, the protocol check; and `pachs plan` on ReacherEasy with its shipped model (CPU, MJX)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip('mujoco_playground')

from pachs_jax import envs  # pylint: disable=wrong-import-position
from pachs_jax.envs import playground  # pylint: disable=wrong-import-position

BATCH, STEPS = 4, 8  # the shapes of the protocol check's `restore_rollout` (one program)


@pytest.fixture(scope='module')
def env():
  return playground.make('playground:PointMass')  # check_task runs here (restore included)


@pytest.fixture(scope='module')
def rollout(env):
  """The env's own reset and step (vmapped) beside the adapter's evaluate along random-action
  rollouts (`restore_rollout`, the program the env fixture's check compiled): (env
  States [STEPS, BATCH], adapter edges [STEPS, BATCH])."""
  keys = jax.random.split(jax.random.PRNGKey(7), BATCH)
  actions = jax.random.uniform(jax.random.PRNGKey(8), (STEPS, BATCH, env.action_size),
                               jnp.float32, -1.0, 1.0)
  return env.restore_rollout(keys, actions)


def _same(a, b) -> bool:
  la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
  return len(la) == len(lb) and all(
      np.asarray(x).dtype == np.asarray(y).dtype
      and np.asarray(x).tobytes() == np.asarray(y).tobytes() for x, y in zip(la, lb))


def test_restore_then_step_is_the_envs_step_bit_for_bit(env, rollout):
  want, got = rollout
  node = got.next_node
  assert _same(want.obs, node.obs) and _same(want.reward, node.reward)
  assert _same(want.metrics, node.metrics) and _same(want.info, node.info)
  restored = jax.vmap(jax.vmap(env.state_from_node))(node)
  for field in playground.STATE_FIELDS:
    assert _same(getattr(want.data, field), getattr(restored.data, field)), field
  # the motion is real (not a fixed point that any restore would reproduce)
  assert np.abs(np.diff(np.asarray(node.qpos), axis=0)).max() > 1e-4


def test_costs_goal_and_steps(env, rollout):
  want, got = rollout
  np.testing.assert_array_equal(np.asarray(got.cost), 1.0 - np.asarray(want.reward))
  assert (np.asarray(got.cost) >= 0).all() and np.asarray(got.is_valid).all()
  near = np.asarray(want.metrics['reward/near_target']) >= 1.0
  np.testing.assert_array_equal(np.asarray(got.is_goal), near)
  np.testing.assert_array_equal(np.asarray(got.next_node.t[:, 0]), np.arange(1, STEPS + 1))
  assert env.name == 'playground:PointMass' and env.episode_length == 200


def test_goal_rules(env):
  pg = env.playground_env
  state = jax.jit(pg.reset)(jax.random.PRNGKey(0))
  inside = state.replace(metrics=dict(state.metrics, **{'reward/near_target': jnp.ones(())}))
  assert bool(env.goal_of_state(inside)) and not bool(env.goal_of_state(state))
  by_callable = playground.from_playground(
      pg, is_goal=lambda s: jnp.linalg.norm(s.data.qpos) < 10.0, check=False)
  assert bool(by_callable.goal_of_state(state))
  missing = playground.from_playground(pg, is_goal='no/such_metric', check=False)
  with pytest.raises(ValueError, match="goal metric 'no/such_metric' is not in"):
    jax.eval_shape(missing.sample_instance, jax.random.PRNGKey(0))


def test_check_finds_a_node_that_does_not_restore(env):
  """A node without data.time: stepped from a restored node, time restarts from zero."""

  class NoTime(playground.PlaygroundEnv):
    def __init__(self, *a, **k):
      super().__init__(*a, **k)
      self._fields = tuple(f for f in self._fields if f != 'time')

  broken = NoTime(env.playground_env, env.config, name='playground:PointMass')
  assert broken.restore_mismatches(num_steps=2) == ['data.time']
  assert env.restore_mismatches() == []  # the check the env fixture ran (its program stored)


def test_negative_cost_is_named(env):
  with pytest.raises(envs.TaskError, match='edge cost is negative'):
    playground.from_playground(env.playground_env, reward_max=-1.0)


def test_bad_names_and_backend():
  with pytest.raises(ValueError, match="unknown Playground env 'NoSuchEnv'; valid names "
                     'include AcrobotSwingup'):
    envs.make('playground:NoSuchEnv')
  with pytest.raises(ValueError, match='give the Playground env'):
    envs.spec('playground:')
  from pachs_jax import planner
  with pytest.raises(ValueError, match='--backend mujoco-c simulates the PushT tasks only'):
    planner.load_model('playground:PointMass', backend='mujoco-c')
  with pytest.raises(ValueError, match='needs MuJoCo Menagerie assets'):
    envs.make('playground:PandaPickCube')


def test_pachs_plan_command_with_the_shipped_model(tmp_path, capsys):
  """`pachs plan --env playground:ReacherEasy` plans with the shipped model (PACHS on the
  adapter's nodes, within the budget), and a found plan replays through the env's own
  transition to its goal at the reported cost; a checkpoint of another task and the MuJoCo C
  backend are refused with one line each."""
  import json

  from pachs_jax import cli, planner, saved_plans
  rows = str(tmp_path / 'rows.json')
  code = cli.main(['plan', '--env', 'playground:ReacherEasy', '--instances', '0-1',
                   '--budget', '200', '--no-cache', '--json', rows])
  assert code == 0, capsys.readouterr().err
  with open(rows) as f:
    saved = json.load(f)
  assert saved['task'] == 'playground:ReacherEasy' and len(saved['rows']) == 2
  assert all(0 < r['evaluated'] <= 200 for r in saved['rows'])
  found = [r for r in saved['rows'] if r['found']]
  assert found
  reacher = playground.make('playground:ReacherEasy', check=False)
  plan = saved_plans.from_json(found[0]['plan'],
                         like=jax.eval_shape(reacher.sample_instance, jax.random.PRNGKey(0)))
  assert plan.length > 0
  evaluate = jax.jit(reacher.evaluate)  # one program for every step (an eager step compiles)
  node, total = jax.tree.map(lambda x: x[:1], plan.states), 0.0
  for step in range(plan.length):
    out = evaluate(node, plan.actions[step:step + 1])
    assert bool(out.is_valid[0])
    total += float(out.cost[0])
    node = out.next_node
    np.testing.assert_allclose(np.asarray(node.qpos[0]), plan.states.qpos[step + 1], atol=1e-5)
  assert bool(out.is_goal[0])
  np.testing.assert_allclose(total, found[0]['cost'], rtol=1e-5)
  for argv, message in (
      (['--checkpoint', planner.checkpoint_path('shelf')],
       "holds a model of task 'shelf'; task 'playground:ReacherEasy' plans with a model of "
       'playground:ReacherEasy'),
      (['--backend', 'mujoco-c'], '--backend mujoco-c simulates the PushT tasks only')):
    with pytest.raises(SystemExit):
      cli.main(['plan', '--env', 'playground:ReacherEasy', '--no-cache'] + argv)
    err = capsys.readouterr().err
    errors = [line for line in err.strip().splitlines() if not line.startswith('note: ')]
    assert message in err and len(errors) == 1, err  # one line beside the CPU's notes


def test_warp_implementation_restores_and_matches_jax(env):
  """An env built with impl='warp' (Playground's default): the protocol check passes (restore
  then step equals the env's own step bit for bit), a vmapped batch of edges equals the env's
  own vmapped step, and the JAX implementation's edges from the same starts."""
  from pachs_jax.envs import warp_import  # pylint: disable=import-outside-toplevel
  if not warp_import.available():
    pytest.skip(f'MuJoCo Warp is not installed ({warp_import.INSTALL_HINT})')
  from mujoco_playground import registry  # pylint: disable=import-outside-toplevel
  raw = registry.load('PointMass', config_overrides={'impl': 'warp'})
  warp_env = playground.from_playground(raw)  # check_task, restore included
  assert warp_env.impl == 'warp' and env.impl == 'jax'
  keys = jax.random.split(jax.random.PRNGKey(7), BATCH)
  actions = jax.random.uniform(jax.random.PRNGKey(8), (STEPS, BATCH, env.action_size),
                               jnp.float32, -1.0, 1.0)
  want, got = warp_env.restore_rollout(keys, actions)  # the check's program
  assert bool(np.all(np.asarray(got.is_valid)))
  assert _same((want.data.qpos, want.data.qvel, want.reward),
               (got.next_node.qpos, got.next_node.qvel, got.next_node.reward))
  actions = actions[0]
  starts = env.canonical_instances(BATCH)
  assert _same(starts.qpos, warp_env.canonical_instances(BATCH).qpos)
  jax_out = jax.jit(env.evaluate)(starts, actions)
  warp_out = jax.jit(warp_env.evaluate)(starts, actions)
  np.testing.assert_allclose(np.asarray(warp_out.next_node.qpos),
                             np.asarray(jax_out.next_node.qpos), atol=1e-5)
  np.testing.assert_allclose(np.asarray(warp_out.cost), np.asarray(jax_out.cost), atol=1e-5)


def _c_rollout(env, node, actions, n_substeps):
  """qpos [T, nq] float64 of a MuJoCo C rollout of env's MjModel from node (no batch axis)
  with ctrl = each action, run here by hand: the reference of the world."""
  import mujoco  # pylint: disable=import-outside-toplevel
  model = env.playground_env.mj_model
  data = mujoco.MjData(model)
  data.qpos[:], data.qvel[:] = np.asarray(node.qpos), np.asarray(node.qvel)
  data.time = float(node.sim['time'])
  mujoco.mj_forward(model, data)
  out = []
  for action in actions:
    data.ctrl[:] = action
    mujoco.mj_step(model, data, nstep=n_substeps)
    out.append(data.qpos.copy())
  return np.stack(out)


def test_world_simulates_in_mujoco_c_and_observes_with_the_envs_step(env):
  """A Playground world's states are MuJoCo C's (a rollout by hand, float64 kept between
  steps), its observations, rewards and goal flags those the env's own step computes from them:
  each world step is close to the env's MJX step from the same node."""
  from pachs_jax.envs import playground_world, world  # pylint: disable=import-outside-toplevel
  steps = playground_world.WorldSteps(env)
  start = jax.tree.map(lambda x: x[0], env.canonical_instances(1))
  actions = np.asarray(jax.random.uniform(jax.random.PRNGKey(3), (12, env.action_size),
                                          jnp.float32, -1.0, 1.0))
  ctrl, edits = steps.control(start, actions[0])
  np.testing.assert_array_equal(np.asarray(ctrl), actions[0])
  assert 'qvel' in edits and not any(bool(changed) for _, changed in edits.values())
  worlds = playground_world.PlaygroundWorld(env, steps)
  nodes = [worlds.reset(start)] + worlds.execute(actions)
  states = world.stack_nodes(nodes)
  want = _c_rollout(env, start, actions, steps.n_substeps)
  np.testing.assert_array_equal(states.qpos[1:], want.astype(np.float32))
  np.testing.assert_array_equal(np.asarray(worlds.data.qpos), want[-1])  # float64 carried
  assert np.abs(np.diff(states.qpos, axis=0)).max() > 1e-4  # it moved
  np.testing.assert_array_equal(states.t, np.arange(13))
  mjx = jax.jit(env.evaluate)(jax.tree.map(lambda x: x[:-1], states), actions)
  np.testing.assert_allclose(states.qpos[1:], np.asarray(mjx.next_node.qpos), atol=1e-4)
  np.testing.assert_allclose(states.obs[1:], np.asarray(mjx.next_node.obs), atol=1e-4)
  np.testing.assert_allclose(states.reward[1:], np.asarray(mjx.next_node.reward), atol=1e-3)
  # the goal flag: the env's rule (near_target) on the world's own state
  np.testing.assert_array_equal(states.success[1:],
                                states.metrics['reward/near_target'][1:] >= 1.0)


def test_world_takes_over_what_the_envs_step_sets_before_simulating(env):
  """An env whose step changes the state before it simulates (here: a push of 0.5 in qvel at
  every step, as Playground's perturbed locomotion envs set xfrc_applied): the world simulates
  the changed state, as the env's MJX step does; a node with a batch axis is refused."""
  import copy  # pylint: disable=import-outside-toplevel
  from pachs_jax.envs import playground_world, world  # pylint: disable=import-outside-toplevel
  raw = env.playground_env

  class Pushed(type(raw)):
    def step(self, state, action):
      return super().step(state.replace(data=state.data.replace(qvel=state.data.qvel + 0.5)),
                          action)

  pushed = copy.copy(raw)
  pushed.__class__ = Pushed
  pushed_env = playground.PlaygroundEnv(pushed, env.config)
  start = jax.tree.map(lambda x: x[0], pushed_env.canonical_instances(1))
  actions = np.zeros((5, env.action_size), np.float32)
  worlds = playground_world.PlaygroundWorld(pushed_env)
  states = world.stack_nodes([worlds.reset(start)] + worlds.execute(actions))
  mjx = jax.jit(pushed_env.evaluate)(jax.tree.map(lambda x: x[:-1], states), actions)
  assert np.abs(states.qvel[1:]).max() > 0.1  # the push moved it
  np.testing.assert_allclose(states.qvel[1:], np.asarray(mjx.next_node.qvel), atol=1e-4)
  with pytest.raises(ValueError, match=r'reset takes one node of playground:Pushed \(qpos'):
    worlds.reset(jax.tree.map(lambda x: x[None], start))


def test_world_refuses_an_env_whose_step_does_not_simulate_once(env):
  import copy  # pylint: disable=import-outside-toplevel
  from pachs_jax.envs import playground_world  # pylint: disable=import-outside-toplevel
  raw = env.playground_env

  class Twice(type(raw)):
    def step(self, state, action):
      return super().step(super().step(state, action), action)

  twice = copy.copy(raw)
  twice.__class__ = Twice
  with pytest.raises(ValueError, match="its step called mujoco_playground's mjx_env.step 2 "
                     'times; a MuJoCo C world runs an env whose step calls it once'):
    playground_world.WorldSteps(playground.PlaygroundEnv(twice, env.config))


def test_pachs_loop_on_a_playground_task_writes_rows_and_a_rendered_video(tmp_path):
  """`pachs loop --task playground:ReacherEasy`: its episodes in MuJoCo C worlds reach the
  goal through a session with the shipped model, and the video is MuJoCo's rendering of the
  world, the plan drawn over it."""
  import json  # pylint: disable=import-outside-toplevel
  import os  # pylint: disable=import-outside-toplevel
  import subprocess  # pylint: disable=import-outside-toplevel
  import sys  # pylint: disable=import-outside-toplevel
  from PIL import Image  # pylint: disable=import-outside-toplevel
  rows, video = tmp_path / 'loop.json', tmp_path / 'loop.gif'
  # a process of its own: MuJoCo picks its OpenGL back end on import, here the command's
  environ = {k: v for k, v in os.environ.items() if k != 'MUJOCO_GL'}
  proc = subprocess.run([sys.executable, '-m', 'pachs_jax.cli', 'loop', '--task',
                         'playground:ReacherEasy', '--instances', '0-1', '--query-time', '1',
                         '--max-queries', '6', '--json', str(rows), '--video', str(video)],
                        capture_output=True, text=True, env=environ, timeout=600, check=False)
  assert proc.returncode == 0, proc.stderr
  saved = json.loads(rows.read_text())
  assert saved['task'] == 'playground:ReacherEasy' and saved['world'] == 'mujoco-c'
  assert [r['instance'] for r in saved['rows']] == [0, 1]
  assert any(r['success'] for r in saved['rows'])
  for row in saved['rows']:
    assert sum(row[k] for k in ('none', 'goal_path', 'partial_path', 'remainder',
                                'policy')) == row['queries']
  with Image.open(video) as gif:  # a frame per world state of instance 0, each one different
    assert gif.n_frames == saved['rows'][0]['steps'] + 1
    assert gif.size == (320, 240)
    assert gif.info['duration'] == 20  # ms: the env's control rate (dt 0.02 s), as it happened
