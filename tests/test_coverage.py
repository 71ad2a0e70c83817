"""PushT goal coverage (rasterised, JAX) against exact polygon areas, and the drawing helpers."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image
from shapely import affinity
from shapely.geometry import Polygon

from pachs_jax.envs import coverage as cov_lib
from pachs_jax.envs import render

GOAL = np.array([-0.156, -0.1, 5.0 * np.pi / 3.0])  # the PushT-Fixed goal


@pytest.fixture(scope='module')
def coverage_fn():
  return jax.jit(cov_lib.coverage)


def _t_polygon(pose):
  poly = Polygon(cov_lib.T_OUTLINE.astype(np.float64))
  poly = affinity.rotate(poly, float(pose[2]), origin=(0.0, 0.0), use_radians=True)
  return affinity.translate(poly, float(pose[0]), float(pose[1]))


def _exact_coverage(t_pose, goal_pose):
  goal = _t_polygon(goal_pose)
  return _t_polygon(t_pose).intersection(goal).area / goal.area


def _random_near_goal(rng, n, dxy, dyaw):
  goal = np.stack([rng.uniform(-0.3, 0.3, n), rng.uniform(-0.3, 0.3, n),
                   rng.uniform(0.0, 2 * np.pi, n)], axis=1)
  offset = np.stack([rng.uniform(-dxy, dxy, n), rng.uniform(-dxy, dxy, n),
                     rng.uniform(-dyaw, dyaw, n)], axis=1)
  return goal + offset, goal


def test_geometry_constants():
  # Outline and boxes describe the same T: area 0.2*0.05 + 0.05*0.15, extents as designed.
  assert Polygon(cov_lib.T_OUTLINE).area == pytest.approx(0.0175, rel=1e-6)
  assert cov_lib.T_AREA == pytest.approx(0.0175, rel=1e-6)
  assert Polygon(cov_lib.T_OUTLINE).bounds == pytest.approx((-0.1, -0.0625, 0.1, 0.1375))
  # The rasterised goal: bar 42 x 10 cells, stem 10 x 32 cells on 4.6875 mm cells.
  assert cov_lib.GOAL_CELL_COUNT == 42 * 10 + 10 * 32
  assert cov_lib.goal_mask().shape == (64, 64)
  assert cov_lib.SUCCESS_THRESHOLD == 0.9
  # points_in_t: the box centres and a point just inside the stem tip, at the goal pose.
  local = np.array([[0.0, -0.0375], [0.0, 0.0625], [0.0, 0.135], [0.0, 0.14], [0.09, 0.0]])
  c, s = np.cos(GOAL[2]), np.sin(GOAL[2])
  world = local @ np.array([[c, s], [-s, c]]) + GOAL[:2]
  inside = np.asarray(cov_lib.points_in_t(world, GOAL))
  np.testing.assert_array_equal(inside, [True, True, True, False, False])


def test_matches_exact_polygon_near_goal(coverage_fn):
  """Random poses within 4 cm / 0.5 rad of random goals.

  Observed (seeds 0-4, 300 poses each): mean |error| 1.0 pp, max 3.7 pp, mean signed error
  +0.9 pp (the 64-cell raster slightly over-estimates coverage near the goal).
  """
  rng = np.random.default_rng(0)
  t_pose, goal = _random_near_goal(rng, 300, 0.04, 0.5)
  raster = np.asarray(coverage_fn(t_pose, goal))
  exact = np.array([_exact_coverage(t, g) for t, g in zip(t_pose, goal)])
  err = np.abs(raster - exact)
  assert exact.min() < 0.4 and exact.max() > 0.85  # the sample spans the interesting range
  assert err.mean() <= 0.02, err.mean()
  assert err.max() <= 0.05, err.max()


def test_axis_aligned_offsets_worst_case(coverage_fn):
  """T parallel to the goal, offset by under two cells: the raster's worst case.

  Cell edges line up with the T's edges, so the raster moves in steps of one cell row.
  Observed max error 8.6 pp (over 2000 random poses at offsets <= 5 mm).
  """
  rng = np.random.default_rng(1)
  t_pose, goal = _random_near_goal(rng, 200, 0.006, 0.0)
  raster = np.asarray(coverage_fn(t_pose, goal))
  exact = np.array([_exact_coverage(t, g) for t, g in zip(t_pose, goal)])
  assert np.abs(raster - exact).max() <= 0.1
  # A pure x shift below half a cell keeps every goal cell covered; exact drops 11.4 %/cm.
  shift = np.array([0.003, 0.0, 0.0])
  assert float(coverage_fn(shift, np.zeros(3))) == 1.0
  assert _exact_coverage(shift, np.zeros(3)) == pytest.approx(1 - 0.2 * 0.003 / 0.0175)


def test_known_values(coverage_fn):
  # At the goal, for yaw + 2 pi, and for a goal anywhere.
  assert float(coverage_fn(GOAL, GOAL)) == 1.0
  assert float(coverage_fn(GOAL + np.array([0, 0, 2 * np.pi]), GOAL)) == 1.0
  assert float(coverage_fn(GOAL - np.array([0, 0, 4 * np.pi]), GOAL)) == 1.0
  # Far away: nothing covered.
  assert float(coverage_fn(GOAL + np.array([0.5, 0.0, 0.0]), GOAL)) == 0.0
  assert float(coverage_fn(GOAL + np.array([0.0, -0.28, 1.0]), GOAL)) == 0.0
  # Rotated by pi about its reference point: exact overlap 0.00625 / 0.0175 = 0.357.
  flipped = float(coverage_fn(np.array([0.0, 0.0, np.pi]), np.zeros(3)))
  assert flipped == pytest.approx(0.00625 / 0.0175, abs=0.01)
  # Shifted 2 cm along the bar: exact 1 - 0.2 * 0.02 / 0.0175 = 0.771.
  shifted = float(coverage_fn(np.array([0.02, 0.0, 0.0]), np.zeros(3)))
  assert shifted == pytest.approx(1 - 0.2 * 0.02 / 0.0175, abs=0.02)


def test_rigid_motion_invariance(coverage_fn):
  rng = np.random.default_rng(2)
  t_pose, goal = _random_near_goal(rng, 500, 0.05, 1.0)
  base = np.asarray(coverage_fn(t_pose, goal))
  assert np.ptp(base) > 0.5
  for mx, my, myaw in [(0.3, -0.2, 1.0), (-1.0, 2.0, -2.5), (0.01, 0.0, np.pi / 2)]:
    c, s = np.cos(myaw), np.sin(myaw)

    def move(p):
      return np.stack([c * p[:, 0] - s * p[:, 1] + mx, s * p[:, 0] + c * p[:, 1] + my,
                       p[:, 2] + myaw], axis=1)

    moved = np.asarray(coverage_fn(move(t_pose), move(goal)))
    # Identical up to float32 rounding flipping a boundary cell.
    assert np.abs(moved - base).max() <= 2.0 / cov_lib.GOAL_CELL_COUNT


def test_numpy_version_matches_jax(coverage_fn):
  """The host checks' numpy coverage and points_in_t (no compiled programs) agree with JAX's."""
  rng = np.random.default_rng(3)
  poses = np.concatenate([GOAL[:2] + rng.uniform(-0.08, 0.08, (256, 2)),
                          rng.uniform(0, 2 * np.pi, (256, 1))], -1).astype(np.float32)
  want = np.asarray(coverage_fn(poses, GOAL))
  got = cov_lib.coverage(poses, GOAL, np)
  assert got.dtype == np.float32 and want.min() < 0.5 < want.max()
  np.testing.assert_allclose(got, want, atol=1.5 / cov_lib.GOAL_CELL_COUNT)
  points = rng.uniform(-0.3, 0.1, (256, 40, 2)).astype(np.float32)
  inside = np.asarray(jax.jit(cov_lib.points_in_t)(points, poses))
  assert inside.any() and (np.mean(cov_lib.points_in_t(points, poses, np) != inside) < 1e-3)


def test_non_finite_gives_zero(coverage_fn):
  poses = np.array([[np.nan, 0.0, 0.0], [0.0, 0.0, np.inf], [0.0, -np.inf, 0.0],
                    [0.0, 0.0, 0.0]])
  out = np.asarray(coverage_fn(poses, np.zeros(3)))
  np.testing.assert_array_equal(out, [0.0, 0.0, 0.0, 1.0])
  assert float(coverage_fn(np.zeros(3), np.array([0.0, np.nan, 0.0]))) == 0.0
  assert not bool(cov_lib.is_success(np.array([np.nan, 0.0, 0.0]), np.zeros(3)))


def test_broadcasting_vmap_and_success(coverage_fn):
  rng = np.random.default_rng(3)
  t_pose, goal = _random_near_goal(rng, 6, 0.03, 0.3)
  t_pose = jnp.asarray(t_pose, jnp.float32)
  goal = jnp.asarray(goal, jnp.float32)
  pairwise = coverage_fn(t_pose[:, None, :], goal[None, :, :])
  assert pairwise.shape == (6, 6) and pairwise.dtype == jnp.float32
  diag = jax.vmap(cov_lib.coverage)(t_pose, goal)
  np.testing.assert_array_equal(np.diagonal(np.asarray(pairwise)), np.asarray(diag))
  one_goal = coverage_fn(t_pose, goal[0])
  np.testing.assert_array_equal(np.asarray(one_goal), np.asarray(pairwise[:, 0]))
  succ = jax.jit(cov_lib.is_success)(jnp.stack([goal[0], goal[0] + jnp.array([0.02, 0, 0])]),
                                     goal[0])
  np.testing.assert_array_equal(np.asarray(succ), [True, False])


def test_bad_shapes_raise():
  with pytest.raises(ValueError, match='t_pose must have shape'):
    cov_lib.coverage(np.zeros((4, 2)), np.zeros(3))
  with pytest.raises(ValueError, match='goal_pose must have shape'):
    cov_lib.coverage(np.zeros(3), np.zeros(()))
  with pytest.raises(ValueError, match='must broadcast'):
    cov_lib.coverage(np.zeros((4, 3)), np.zeros((5, 3)))


# ---- drawings ----


def _run(n=30):
  s = np.linspace(0.0, 1.0, n)
  start = GOAL + np.array([0.08, 0.15, 1.2])
  t_poses = start[None, :] * (1 - s[:, None]) + GOAL[None, :] * s[:, None]
  pusher = t_poses[:, :2] + np.array([0.0, 0.12])
  obstacles = np.array([[0.0, 0.1, 0.05, 0.02, 0.3], [-0.3, 0.1, 0.03, 0.06, 0.0]])
  return t_poses, pusher, obstacles


def test_draw_pusht_artists():
  from matplotlib.figure import Figure

  t_poses, pusher, obstacles = _run()
  ax = Figure().add_subplot(1, 1, 1)
  render.draw_pusht(ax, t_poses, GOAL, pusher, obstacles, every=5)
  shown = len(range(0, 30, 5)) + 1  # every 5th pose plus the last
  assert len(ax.patches) == shown + 1 + len(obstacles)  # T poses, goal, obstacles
  labels = set(ax.get_legend_handles_labels()[1])
  assert {'goal', 'T start', 'T final', 'T over time', 'obstacle', 'pusher',
          'pusher start'} <= labels
  goal_patch = [p for p in ax.patches if p.get_label() == 'goal'][0]
  assert goal_patch.get_linestyle() == '--' and not goal_patch.get_fill()
  np.testing.assert_allclose(goal_patch.get_xy()[:8], render.t_polygon(GOAL), atol=1e-12)
  t_patches = ax.patches[len(obstacles):len(obstacles) + shown]  # drawn in time order
  assert t_patches[0].get_label() == 'T start' and t_patches[-1].get_label() == 'T final'
  middle = [p.get_alpha() for p in t_patches[1:-1]]
  assert middle == sorted(middle) and middle[0] < middle[-1]  # alpha grows with time
  assert ax.get_aspect() == 1.0
  assert ax.get_xlabel() == 'x (m)'


def test_save_pusht_figure_png(tmp_path):
  t_poses, pusher, obstacles = _run()
  path = render.save_pusht_figure(tmp_path / 'run.png', t_poses, GOAL, pusher, obstacles,
                                  every=3, title='PushT', figsize=(4, 4), dpi=100)
  assert os.path.exists(path) and os.path.getsize(path) > 5000
  with Image.open(path) as img:
    assert img.format == 'PNG' and img.size == (400, 400)
  # No pusher and no obstacles is fine too.
  path2 = render.save_pusht_figure(tmp_path / 'bare.png', t_poses[:1], GOAL)
  assert os.path.getsize(path2) > 2000


def test_draw_pusht_bad_input(tmp_path):
  t_poses, pusher, _ = _run()
  with pytest.raises(ValueError, match='t_poses'):
    render.save_pusht_figure(tmp_path / 'x.png', t_poses[:, :2], GOAL)
  with pytest.raises(ValueError, match='obstacles'):
    render.save_pusht_figure(tmp_path / 'x.png', t_poses, GOAL, obstacles=np.zeros((2, 4)))
  with pytest.raises(ValueError, match='every'):
    render.save_pusht_figure(tmp_path / 'x.png', t_poses, GOAL, every=0)


def test_save_gif(tmp_path):
  frames = np.zeros((4, 16, 20, 3), np.uint8)
  frames[:, :, :, 0] = np.arange(4, dtype=np.uint8)[:, None, None] * 60
  path = render.save_gif(tmp_path / 'a.gif', frames, fps=10)
  with Image.open(path) as img:
    assert img.format == 'GIF' and img.size == (20, 16) and img.n_frames == 4
    assert img.info['duration'] == 100
  with pytest.raises(ValueError, match='uint8'):
    render.save_gif(tmp_path / 'b.gif', frames.astype(np.float32), fps=10)
  with pytest.raises(ValueError, match='fps'):
    render.save_gif(tmp_path / 'b.gif', frames, fps=0)


_TINY_XML = """
<mujoco>
  <worldbody>
    <light pos="0 0 2"/>
    <camera name="top" pos="0 0 1.5"/>
    <geom type="plane" size="1 1 0.1" rgba="0.8 0.8 0.8 1"/>
    <body name="box" pos="0 0 0.1">
      <freejoint/>
      <geom type="box" size="0.1 0.1 0.1" rgba="0.9 0.1 0.1 1"/>
    </body>
  </worldbody>
</mujoco>
"""

_RENDER_SCRIPT = textwrap.dedent("""
    import sys
    import mujoco, numpy as np
    from pachs_jax.envs import render
    model = mujoco.MjModel.from_xml_string(sys.argv[1])
    qpos = np.tile(model.qpos0, (2, 1))
    qpos[1, 0] = 0.4
    try:
      frames = render.render_mujoco_frames(model, qpos, 32, 24, camera='top')
    except RuntimeError as err:
      assert 'OpenGL' in str(err) and 'MUJOCO_GL' in str(err), err
      print('UNAVAILABLE', str(err).replace(chr(10), ' '))
    else:
      assert frames.shape == (2, 24, 32, 3) and frames.dtype == np.uint8
      assert frames.std() > 0 and not np.array_equal(frames[0], frames[1])
      print('RENDERED')
""")


def test_render_mujoco_frames_bad_input_and_missing_opengl(monkeypatch):
  import mujoco

  model = mujoco.MjModel.from_xml_string(_TINY_XML)
  qpos = np.tile(model.qpos0, (2, 1))
  with pytest.raises(ValueError, match='qpos_seq'):
    render.render_mujoco_frames(model, qpos[:, :3], 32, 24)
  with pytest.raises(ValueError, match='offscreen buffer'):
    render.render_mujoco_frames(model, qpos, 10000, 24)

  def no_context(*args, **kwargs):
    raise mujoco.FatalError('gladLoadGL error')

  # a machine without OpenGL: a RuntimeError that names the cause and the fix
  monkeypatch.setattr(mujoco, 'Renderer', no_context)
  with pytest.raises(RuntimeError, match='no OpenGL context') as err:
    render.render_mujoco_frames(model, qpos, 32, 24)
  assert 'MUJOCO_GL=egl' in str(err.value) and 'gladLoadGL error' in str(err.value)


def test_render_mujoco_frames_in_process():
  import mujoco

  model = mujoco.MjModel.from_xml_string(_TINY_XML)
  qpos = np.tile(model.qpos0, (2, 1))
  qpos[1, 0] = 0.4  # the box moves in x
  try:
    frames = render.render_mujoco_frames(model, qpos, 32, 24, camera='top')
  except RuntimeError as err:
    pytest.skip(f'no OpenGL in this process (MUJOCO_GL={os.environ.get("MUJOCO_GL")!r}): {err}')
  assert frames.shape == (2, 24, 32, 3) and frames.dtype == np.uint8
  assert frames.std() > 0 and not np.array_equal(frames[0], frames[1])


def test_render_mujoco_frames_egl_subprocess():
  # MUJOCO_GL is read when mujoco is imported, so the EGL path needs a fresh process.
  env = dict(os.environ, MUJOCO_GL='egl', JAX_PLATFORMS='cpu')
  proc = subprocess.run([sys.executable, '-c', _RENDER_SCRIPT, _TINY_XML], env=env,
                        capture_output=True, text=True, timeout=120)
  assert proc.returncode == 0, proc.stderr[-2000:]
  last = proc.stdout.strip().splitlines()[-1]
  if last.startswith('UNAVAILABLE'):
    pytest.skip(f'no EGL rendering on this machine: {last[len("UNAVAILABLE "):]}')
  assert last == 'RENDERED', proc.stdout[-2000:]
