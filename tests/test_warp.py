"""The MuJoCo Warp PushT backend: restore-then-step is the search's own transition bit for bit,
agreement with MuJoCo C without contact, overflow reported per edge, backend selection and the
quiet import (these two also where Warp is not installed)."""

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pachs_jax.envs import backends, mujoco_c, point_mass, pusht, warp_import

needs_warp = pytest.mark.skipif(not warp_import.available(),
                                reason=f'MuJoCo Warp is not installed ({warp_import.INSTALL_HINT})')


@pytest.fixture(scope='module')
def warp_env():
  from pachs_jax.envs import warp_physics  # pylint: disable=import-outside-toplevel
  return warp_physics.WarpPushTEnv(pusht.PushTConfig(variant='obs', layout='two-gaps'))


def _edges(env, num=4):
  nodes = env.canonical_instances(num)
  actions = jax.random.uniform(jax.random.PRNGKey(3), (num, env.action_size), minval=-1,
                               maxval=1)
  return nodes, actions


@needs_warp
def test_restore_then_step_reproduces_the_transition(warp_env):
  nodes, actions = _edges(warp_env)
  evaluate = jax.jit(warp_env.evaluate)
  first = evaluate(nodes, actions)
  # the next edge from the stored node state, in a batch of another size (another contact
  # buffer), equals the same edge in the first batch's size, and a single transition (to
  # float32 rounding: the free T's table contacts are summed in another order)
  again = evaluate(first.next_node, actions)
  part = jax.jit(warp_env.evaluate)(jax.tree.map(lambda x: x[:2], first.next_node), actions[:2])
  one = jax.jit(warp_env.transition)(jax.tree.map(lambda x: x[1], first.next_node), actions[1])
  for got, want in ((part, jax.tree.map(lambda x: x[:2], again)),
                    (one, jax.tree.map(lambda x: x[1], again))):
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
      np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-5)
  assert bool(np.all(np.asarray(first.is_valid)))


@needs_warp
def test_agrees_with_mujoco_c_without_contact(warp_env):
  # the stick starts away from the T: one edge moves the arm only; float32 Warp against MuJoCo
  # C (float64) on the same model, and the T stays where it rests (it settles 0.3 mm into the
  # table's soft contact)
  nodes, actions = _edges(warp_env)
  got = jax.jit(warp_env.evaluate)(nodes, actions)
  c_env = mujoco_c.MujocoCEnv(pusht.PushTEnv(warp_env.config), nthread=1)
  want = c_env.evaluate(nodes, actions)
  np.testing.assert_allclose(np.asarray(got.next_node.qpos), np.asarray(want.next_node.qpos),
                             atol=2e-4)
  np.testing.assert_allclose(np.asarray(got.next_node.qpos)[:, 7:],
                             np.asarray(nodes.qpos)[:, 7:], atol=5e-4)
  assert np.abs(np.asarray(got.next_node.qpos - nodes.qpos)[:, :7]).max() > 1e-3


@needs_warp
def test_the_t_touches_the_blocks_in_warp_as_in_mujoco_c(warp_env):
  # the T tilted 0-20 degrees against two-gaps' first block, its bar's long side to the block's
  # face: the same contacts (number, points, depths) in both engines; Warp's general convex
  # collider (its default for box pairs, which the model turns off) finds others
  import mujoco  # pylint: disable=import-outside-toplevel
  import physics_agreement  # pylint: disable=import-outside-toplevel
  model = warp_env.mj_model
  block = model.geom('obstacle0').id
  rng = np.random.default_rng(0)
  poses = []
  for tilt_deg in (0.0, 2.0, 5.0, 10.0, 15.0, 20.0):
    tilt, azimuth, yaw = np.radians(tilt_deg), rng.uniform(0, 2 * np.pi), rng.uniform(-0.3, 0.3)
    qpos = np.zeros(model.nq)
    qpos[:7] = pusht.HOME_QPOS
    # the bar's far side (y = -0.0625 in the T's frame) 1 mm into the block's +y face
    qpos[7:9] = model.geom_pos[block][:2] + [0.0, model.geom_size[block][1] + 0.0625 - 0.001]
    qpos[9] = pusht.T_HALF_HEIGHT + 0.005 * rng.uniform()
    mujoco.mju_mulQuat(qpos[10:14], [np.cos(tilt / 2), np.sin(tilt / 2) * np.cos(azimuth),
                                     np.sin(tilt / 2) * np.sin(azimuth), 0.0],
                       [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
    poses.append(qpos)
  warp_models = physics_agreement.warp_cpu_models(
      {'model': model, 'convex': physics_agreement.convex_boxes(model)})
  pairs = [physics_agreement.t_block_contacts(model, warp_models, qpos) for qpos in poses]
  assert all(c for c, _ in pairs), 'every pose touches the block in MuJoCo C'
  for c, found in pairs:
    assert len(c) == len(found['model'])
    np.testing.assert_allclose(np.asarray(found['model']), np.asarray(c), atol=5e-4)
  assert any(len(c) != len(found['convex']) or not np.allclose(c, found['convex'], atol=5e-4)
             for c, found in pairs)


@needs_warp
def test_overflow_is_reported_per_edge():
  from pachs_jax.envs import warp_physics  # pylint: disable=import-outside-toplevel
  config = pusht.physics_preset('planar', variant='obs', layout='two-gaps')
  # the planar T: room for its three friction-loss rows, not for contact rows too (a contact buffer
  # overflow marks every edge of the call: Warp counts contacts for the whole batch)
  env = warp_physics.WarpPushTEnv(config, constraints_per_world=4)
  nodes, actions = _edges(env, 2)
  # edge 0 starts with the T against block 0 (contact constraints), edge 1 free
  block = env.obstacles[0]
  pose = jnp.array([block[0] + block[2] + 0.02, block[1], 0.0])
  qpos = nodes.qpos.at[0, 7:10].set(pose)
  nodes = nodes.replace(qpos=qpos)
  over = np.asarray(jax.jit(env.overflowed)(nodes, actions))
  out = jax.jit(env.evaluate)(nodes, actions)
  assert over.tolist() == [True, False]
  assert np.asarray(out.is_valid).tolist() == [False, True]


def test_make_backend_warp_choices(monkeypatch):
  env = pusht.PushTEnv()
  with pytest.raises(ValueError, match="backend 'warp' needs a PushT env"):
    backends.make_backend(point_mass.PointMassEnv(), 'warp')
  monkeypatch.setattr(warp_import, 'available', lambda: False)
  with pytest.raises(ImportError, match=r"pip install -e '\.\[cuda\]'"):
    backends.make_backend(env, 'warp')
  # auto never picks Warp where it is missing, and on the CPU picks MuJoCo C for PushT
  if jax.default_backend() == 'cpu':
    assert isinstance(backends.make_backend(env, 'auto', 1), mujoco_c.MujocoCEnv)


@needs_warp
def test_make_backend_builds_and_unwraps_warp():
  from pachs_jax.envs import warp_physics  # pylint: disable=import-outside-toplevel
  env = pusht.PushTEnv(pusht.PushTConfig(variant='obs'))
  warp_env = backends.make_backend(env, 'warp')
  assert isinstance(warp_env, warp_physics.WarpPushTEnv) and warp_env.config == env.config
  assert warp_env.fingerprint != env.fingerprint
  back = backends.make_backend(warp_env, 'mjx')
  assert type(back) is pusht.PushTEnv and back.config == env.config


def test_import_without_warp_prints_nothing():
  # warp-lang made unimportable: importing the envs (and MJX) writes nothing to stdout
  code = ('import sys; sys.modules["warp"] = None\n'
          'import pachs_jax.envs, pachs_jax.envs.pusht\n'
          'from pachs_jax.envs import warp_import\n'
          'assert not warp_import.available()\n')
  done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                        check=False)
  assert done.returncode == 0, done.stderr
  assert done.stdout == ''
  assert 'Failed to import warp' not in done.stderr
