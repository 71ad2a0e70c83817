"""The task protocol (docs/own_task.md): check_task's errors on broken tasks, and the page's
worked example (a user-written task) checked, trained and planned end to end on the CPU."""

import dataclasses
import os
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pachs_jax import envs
from pachs_jax.envs import base
from pachs_jax.envs.point_mass import PointMassEnv

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOC = os.path.join(REPO, 'docs', 'own_task.md')


def _doc_task_module() -> dict:
  """The names defined by the first python block of docs/own_task.md (the worked task)."""
  with open(DOC) as f:
    text = f.read()
  block = re.findall(r'```python\n(.*?)```', text, re.S)[0]
  names: dict = {}
  exec(compile(block, DOC, 'exec'), names)  # pylint: disable=exec-used
  return names


@pytest.fixture(scope='module')
def doc():
  return _doc_task_module()


def test_doc_task_follows_the_protocol(doc):
  envs.check_task(doc['Puck']())
  envs.check_task(PointMassEnv())


def _raises(env, match):
  with pytest.raises(envs.TaskError, match=match) as info:
    envs.check_task(env)
  assert '\n' not in str(info.value)
  assert repr(env.name) in str(info.value)


def test_positive_reward_is_named(doc):
  class Rewarding(doc['Puck']):
    name = 'rewarding-puck'

    def transition(self, node, action):
      out = super().transition(node, action)
      return out.replace(cost=-out.cost)  # a reward used as the cost: negative

  _raises(Rewarding(), r'edge cost is negative .* must be >= 0')


def test_wrong_shapes_are_named(doc):
  Puck = doc['Puck']

  class IntObservation(Puck):
    name = 'int-obs'

    def observation(self, node):
      return super().observation(node).astype(jnp.int32)

  class BatchCost(Puck):
    name = 'batch-cost'

    def transition(self, node, action):
      out = super().transition(node, action)
      return out.replace(cost=jnp.stack([out.cost, out.cost]))

  class NoStepCounter(Puck):
    name = 'no-t'

    def sample_instance(self, key):
      node = super().sample_instance(key)
      return node.replace(t=jnp.zeros((), jnp.float32))

  class WrongCells(Puck):
    name = 'wrong-cells'

    def lattice_coords(self, node, resolution):
      return super().lattice_coords(node, resolution)[:2]

  _raises(IntObservation(), r'observation\(node\) must be \[O\] float32')
  _raises(BatchCost(), r"transition's cost must be \[\] float32 for one node, got \(2,\)")
  _raises(NoStepCounter(), r'field t: \[\] int32')
  _raises(WrongCells(), r'lattice_coords.* must be \[4\] int32, got \(2,\)')


def test_state_outside_the_node_is_named(doc):
  """A training step that keeps state outside the node (here: it ignores the velocity the
  node holds) is not the search's transition: the search would plan another system."""

  class Forgetful(doc['Puck']):
    name = 'forgetful'

    def step(self, state, action):
      node = state.pipeline_state
      stepped = super().step(state.replace(pipeline_state=node.replace(
          velocity=jnp.zeros_like(node.velocity))), action)
      return stepped

  _raises(Forgetful(), r'step \(training\) and transition \(search\) disagree')


def test_not_an_env_is_named():
  with pytest.raises(envs.TaskError, match='is not a pachs_jax.envs.Env'):
    envs.check_task(object())


def test_doc_task_trains_and_plans_end_to_end(doc, tmp_path):
  """The page's task: trained briefly with our SAC (critic kept), loaded by the Planner (which
  checks it again) and planned; every path found replays through the env to a goal at the
  reported cost."""
  from pachs_jax.planner import Planner
  from pachs_jax.sac import presets, train
  from pachs_jax.sac.trainer import make_trainer
  env = doc['Puck']()
  config = dataclasses.replace(presets.preset('point-mass'), eval_instances=0)
  run = str(tmp_path / 'puck')
  train.train(make_trainer(env, config), run, 8000)
  planner = Planner(env, checkpoint=run, budget=1500, cache=False)
  result = planner.plan(instances=range(4))
  found = np.asarray(result.found)
  assert found.sum() >= 3, found
  starts = planner.canonical(range(4))
  for i in np.flatnonzero(found):
    node = jax.tree.map(lambda x: x[i:i + 1], starts)
    total = 0.0
    for step in range(int(result.path_length[i])):
      out = env.evaluate(node, result.path_actions[i:i + 1, step])
      assert bool(out.is_valid[0])
      total += float(out.cost[0])
      node = out.next_node
    assert bool(env.is_goal(node)[0])
    np.testing.assert_allclose(total, float(result.cost[i]), rtol=1e-4)
  # a model of another task is refused with one line

  class Renamed(doc['Puck']):
    name = 'other-puck'

  with pytest.raises(ValueError, match="holds a model of task 'puck'"):
    Planner(Renamed(), checkpoint=run, cache=False)


def test_missing_playground_extra_names_the_install_command(monkeypatch, capsys):
  """Without MuJoCo Playground, a playground task fails with one line giving the pip command,
  from the library and from both commands; the core package never imports it, and importing
  it prints nothing (MJX itself imports warp-lang where it is installed: not checked here)."""
  import subprocess
  import sys

  from pachs_jax import cli
  code = ('import sys, pachs_jax.envs, pachs_jax.planner, pachs_jax.cli; '
          'print(sorted(m for m in sys.modules if m.startswith("mujoco_playground")))')
  out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True)
  assert out.stdout.strip() == '[]', out.stdout
  monkeypatch.setitem(sys.modules, 'mujoco_playground', None)  # import raises ImportError
  with pytest.raises(ImportError, match=r"pip install -e '\.\[playground\]'"):
    envs.make('playground:PointMass')
  with pytest.raises(SystemExit):
    cli.main(['plan', '--env', 'playground:PointMass', '--no-cache'])
  err = capsys.readouterr().err.strip()
  assert len(err.splitlines()) == 1 and "pip install -e '.[playground]'" in err, err
  import importlib.util
  spec = importlib.util.spec_from_file_location(
      'train_cli', os.path.join(REPO, 'experiments', 'train.py'))
  train_script = importlib.util.module_from_spec(spec)
  spec.loader.exec_module(train_script)
  assert train_script.parse_args(['--env', 'playground:PointMass', '--steps', '1', '--out',
                                  'x']).task == 'playground:PointMass'
  with pytest.raises(SystemExit, match=r"error: .*pip install -e '\.\[playground\]'"):
    train_script.make_env('playground:PointMass')
