"""PushT-Obs layouts: every one builds, its canonical instances are valid and fixed by seed, bad
layouts fail clearly when the env is made, and MuJoCo C and MJX see the same blocks."""

import jax
import mujoco
import numpy as np
import pytest

from pachs_jax import cli, envs
from pachs_jax.envs import backends, coverage, layouts, pusht


def _polygons_overlap(a: np.ndarray, b: np.ndarray, tol: float = 1e-6) -> bool:
  """Convex polygons a [N, 2], b [M, 2] overlap by more than tol (separating axis test)."""
  for poly in (a, b):
    edges = np.roll(poly, -1, axis=0) - poly
    for nx, ny in np.stack([-edges[:, 1], edges[:, 0]], -1):
      pa, pb = a @ (nx, ny), b @ (nx, ny)
      norm = np.hypot(nx, ny)
      if min(pa.max() - pb.min(), pb.max() - pa.min()) <= tol * norm:
        return False
  return True


def _box_polygon(cx, cy, hx, hy, yaw):
  c, s = np.cos(yaw), np.sin(yaw)
  local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
  return np.stack([cx + c * local[:, 0] - s * local[:, 1], cy + s * local[:, 0] + c * local[:, 1]],
                  -1)


def _t_boxes(pose):
  """The T at pose as its two boxes (bar, stem) in the world frame."""
  x, y, yaw = pose
  c, s = np.cos(yaw), np.sin(yaw)
  return [_box_polygon(x + c * bx - s * by, y + s * bx + c * by, hx, hy, yaw)
          for bx, by, hx, hy in coverage.T_BOXES.astype(np.float64)]


@pytest.fixture(scope='module')
def made():
  """{layout name: (env, canonical instances)} for every layout."""
  out = {}
  for name in layouts.NAMES:
    env = envs.make('pusht-obs', layout=name)
    out[name] = env, env.canonical_instances(envs.spec('pusht-obs').num_instances)
  return out


def test_every_layout_builds_with_its_blocks(made):
  assert layouts.DEFAULT == 'gate' and len(layouts.NAMES) >= 6
  assert envs.make('pusht-obs').name == 'pusht-obs'
  for name, (env, _) in made.items():
    lay = layouts.layout(name)
    assert env.name == ('pusht-obs' if name == layouts.DEFAULT else f'pusht-obs:{name}')
    np.testing.assert_array_equal(env.obstacles, np.array(lay.blocks, np.float32))
    assert env.mj_model.npair == 5 + 3 * len(lay.blocks)
    assert lay.kind and lay.description
  kinds = {layouts.layout(n).kind for n in layouts.NAMES}
  assert len(kinds) == len(layouts.NAMES)  # each layout is a different kind of problem


def test_canonical_instances_are_valid(made):
  for name, (env, nodes) in made.items():
    lay = layouts.layout(name)
    poses, goals = np.asarray(pusht.t_pose(nodes.qpos)), np.asarray(nodes.goal)
    assert poses.shape == (30, 3)
    np.testing.assert_array_equal(goals, np.broadcast_to(np.float32(pusht.FIXED_GOAL), (30, 3)))
    assert lay.in_start_region(poses).all(), name
    assert (np.asarray(coverage.coverage(poses, goals)) < coverage.SUCCESS_THRESHOLD).all()
    for i, pose in enumerate(poses):
      for box in lay.blocks:
        for part in _t_boxes(pose):
          assert not _polygons_overlap(part, _box_polygon(*box)), (name, i, box)
    np.testing.assert_array_equal(np.asarray(nodes.qpos[:, :7]),
                                  np.broadcast_to(np.float32(pusht.HOME_QPOS), (30, 7)))


def test_canonical_instances_are_fixed_by_seed(made):
  env, nodes = made['two-gaps']
  again = env.canonical_instances(30)
  np.testing.assert_array_equal(np.asarray(again.qpos), np.asarray(nodes.qpos))
  other = env.canonical_instances(30, seed=1)
  assert not np.array_equal(np.asarray(other.qpos), np.asarray(nodes.qpos))


def test_legacy_layout_reproduces_the_old_pusht_obs(made):
  env, nodes = made['legacy']
  np.testing.assert_array_equal(env.obstacles, np.float32([[-0.245, 0.035, 0.02, 0.02, 0],
                                                           [-0.065, 0.035, 0.02, 0.02, 0],
                                                           [-0.156, -0.265, 0.05, 0.02, 0]]))
  # the canonical instances before the layouts (the yaw read back from the free T's quaternion)
  poses = np.asarray(pusht.t_pose(nodes.qpos))
  np.testing.assert_allclose(poses[0], [-0.23514193, -0.096803725, 1.4356135], atol=1e-6)
  np.testing.assert_allclose(poses[29], [-0.17391759, -0.15615904, 0.032504216], atol=1e-6)


def test_unknown_layout_lists_the_valid_ones(capsys):
  names = '.*'.join(layouts.NAMES)
  with pytest.raises(ValueError, match=f'unknown PushT-Obs layout .nope.*{names}'):
    envs.make('pusht-obs', layout='nope')
  with pytest.raises(ValueError, match="task 'pusht-fixed' has no option layout"):
    envs.make('pusht-fixed', layout='gate')
  with pytest.raises(ValueError, match="'obs' variant only"):
    pusht.PushTEnv(pusht.PushTConfig(variant='rand', layout='gate'))
  with pytest.raises(SystemExit) as exit_info:
    cli.main(['plan', '--layout', 'nope'])
  assert exit_info.value.code == 2
  err = capsys.readouterr().err
  assert 'nope' in err and all(n in err for n in layouts.NAMES)
  with pytest.raises(SystemExit) as exit_info:
    cli.main(['plan', '--task', 'pusht-fixed', '--layout', 'gate'])
  assert exit_info.value.code == 2
  assert '--layout applies to --task pusht-obs only' in capsys.readouterr().err


@pytest.mark.parametrize('blocks,start,match', [
    # a block on the goal T
    (((-0.15, -0.1, 0.05, 0.02, 0.0),), ((-0.22, -0.08), (0.2, 0.3)), 'overlaps the goal T'),
    # a block just touching the goal T's bar end (x -0.26, y -0.045) within the 5 mm clearance
    (((-0.29, -0.045, 0.027, 0.02, 0.0),), ((-0.22, -0.08), (0.2, 0.3)), 'overlaps the goal T'),
    # a block over the whole start region
    (((-0.15, 0.25, 0.2, 0.15, 0.0),), ((-0.22, -0.08), (0.2, 0.3)), 'too few valid starts'),
    # a start region off the table, out of the arm's reach, or reversed
    ((), ((-0.22, -0.08), (0.3, 0.4)), 'leaves the table'),
    ((), ((-0.55, -0.45), (-0.05, 0.05)), 'from the robot base'),
    ((), ((-0.08, -0.22), (0.2, 0.3)), 'ordered finite range'),
])
def test_bad_layouts_fail_when_the_env_is_made(monkeypatch, blocks, start, match):
  bad = layouts.Layout('bad', 'test', blocks, start[0], start[1])
  monkeypatch.setitem(layouts.LAYOUTS, 'bad', bad)
  with pytest.raises(ValueError, match=f"PushT-Obs layout 'bad'.*{match}"):
    envs.make('pusht-obs', layout='bad')


def _obstacle_geometry(model):
  ids = [i for i in range(model.ngeom) if mujoco.mj_id2name(
      model, mujoco.mjtObj.mjOBJ_GEOM, i).startswith('obstacle')]
  return (np.asarray(model.geom_pos)[ids], np.asarray(model.geom_size)[ids],
          np.asarray(model.geom_quat)[ids])


def test_mujoco_c_and_mjx_see_the_same_blocks(made):
  env, nodes = made['gate']
  cenv = backends.make_backend(env, 'mujoco-c')
  try:
    pos, size, quat = _obstacle_geometry(env.mj_model)
    blocks = np.asarray(layouts.layout('gate').blocks)
    np.testing.assert_allclose(pos[:, :2], blocks[:, :2], atol=1e-9)
    np.testing.assert_allclose(size[:, :2], blocks[:, 2:4], atol=1e-9)
    # MJX's model is the same MjModel put on the device; MuJoCo C simulates that MjModel.
    for got, want in zip((env.mjx_model.geom_pos, env.mjx_model.geom_size,
                          env.mjx_model.pair_geom1, env.mjx_model.pair_geom2),
                         (env.mj_model.geom_pos, env.mj_model.geom_size,
                          env.mj_model.pair_geom1, env.mj_model.pair_geom2)):
      np.testing.assert_allclose(np.asarray(got), want, atol=1e-6)
    assert cenv._sim.model is env.mj_model
    # One edge both ways: a planar T pressed 5 mm into the left block's top (stem down, bar on
    # top) is pushed out upwards by the block, by the same amount in MJX and in MuJoCo C (the
    # free T's stiff contacts part the two engines on so deep a start).
    cenv.close()
    env = envs.make('pusht-obs', physics='planar')
    cenv = backends.make_backend(env, 'mujoco-c')
    top = blocks[0, 1] + blocks[0, 3]
    node = env.node_from_pose(np.float32([-0.3, top + 0.1375 - 0.005, np.pi]), pusht.FIXED_GOAL)
    batch = jax.tree.map(lambda x: x[None], node)
    still = np.zeros((1, 7), np.float32)
    moved_c, moved_mjx = (
        np.asarray(jax.jit(e.evaluate)(batch, still).next_node.qpos[0, 7:10] - node.qpos[7:10])
        for e in (cenv, env))
    assert moved_c[1] > 0.002, moved_c
    np.testing.assert_allclose(moved_mjx, moved_c, atol=1e-4)
  finally:
    cenv.close()
