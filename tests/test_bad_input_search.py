"""Bad input is refused before any work with a clear error, never searched into a silent
'open_empty' or a crash: non-finite starts, a damaged model, overflowing lattice cells, budgets
that cannot fit in memory, numpy numbers in configs, and the CLI's arguments and output paths."""

import dataclasses
import functools
import json
import os
import re

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from pachs_jax import cli, planner
from pachs_jax.envs import gridworld, point_mass, pusht
from pachs_jax.search import Capacities, SearchConfig, StopReason, make_search, memory, pachs
from pachs_jax.runtime import programs
from pachs_jax.runtime.programs import plan
from pachs_jax.runtime import sharding
from pachs_jax.search import baselines as bl
from pachs_jax.search.baselines import epase
from pachs_jax.search.checks import instance_keys

SIZE = 10
CONFIG = SearchConfig(weight=1.0, num_actions=8, pop_size=2, budget=500)


@pytest.fixture(scope='module')
def grid():
  obstacles = np.zeros((SIZE, SIZE), bool)
  obstacles[4, 2:8] = True
  env = gridworld.GridWorld(obstacles)
  starts = np.array([[0, 0], [9, 9], [0, 9], [2, 5]])
  goals = np.array([[9, 9], [0, 0], [9, 0], [7, 5]])
  return env, gridworld.GridActorCritic(env), env.node(starts, goals)


class NanCritic(gridworld.GridActorCritic):
  """A damaged model: the critic's Q is NaN everywhere."""

  def q_values(self, obs, actions):
    return super().q_values(obs, actions) * jnp.nan


class NanActor(gridworld.GridActorCritic):
  """A damaged model: the actor proposes NaN actions."""

  def sample_actions(self, key, obs, num):
    return super().sample_actions(key, obs, num) * jnp.nan


# ---- 1. non-finite start states and goals ----

@pytest.mark.parametrize('field, rows', [('qpos', [1]), ('goal', [0, 3])])
def test_non_finite_starts_are_refused_naming_the_instances(grid, field, rows):
  env, ac, nodes = grid
  value = getattr(nodes, field).at[jnp.asarray(rows), 0].set(jnp.nan)
  if len(rows) > 1:
    value = value.at[rows[-1], 1].set(jnp.inf)
  bad = nodes.replace(**{field: value})
  want = re.escape(f'instance{"s" * (len(rows) > 1)} {rows} are not finite (NaN or inf in '
                   f'{field})')
  with pytest.raises(ValueError, match=want):
    plan(env, ac, bad, CONFIG, jax.random.PRNGKey(0))
  with pytest.raises(ValueError, match=want):
    sharding.plan_sharded(env, ac, bad, CONFIG, jax.random.PRNGKey(0))


def test_finite_starts_plan_as_before(grid):
  env, ac, nodes = grid
  result = plan(env, ac, nodes, CONFIG, jax.random.PRNGKey(0))
  np.testing.assert_array_equal(np.asarray(result.found), True)


# ---- 2. a damaged model: non-finite network outputs on valid starts ----

@pytest.mark.parametrize('model, message', [
    (NanCritic, 'actor-critic returns non-finite Q on the start states (instances [0, 1, 2, 3])'
                ': the model is damaged or does not fit the task'),
    (NanActor, 'actor-critic samples non-finite actions on the start states')])
def test_non_finite_model_outputs_are_a_model_error(grid, model, message):
  env, _, nodes = grid
  damaged = model(env)
  with pytest.raises(ValueError, match=re.escape(message)):
    plan(env, damaged, nodes, CONFIG, jax.random.PRNGKey(0))
  with pytest.raises(ValueError, match=re.escape(message)):
    sharding.plan_sharded(env, damaged, nodes, CONFIG, jax.random.PRNGKey(0))


def test_without_the_check_a_nan_critic_looks_like_an_exhausted_search(grid):
  # what the check prevents: the search itself drops every edge of NaN Q and reports OPEN
  # empty after 0 evaluations, which reads like an exhaustively searched task
  env, _, nodes = grid
  search = make_search(env, NanCritic(env), CONFIG)
  keys = instance_keys(jax.random.PRNGKey(0), 4)
  result = search.result(search.run(search.init(nodes, keys)))
  np.testing.assert_array_equal(np.asarray(result.stop_reason), StopReason.OPEN_EMPTY)
  np.testing.assert_array_equal(np.asarray(result.evaluated), 0)


# ---- 3. lattice cells that overflow the int32 coordinates ----

def test_overflowing_lattice_resolution_is_refused_naming_the_smallest_cells(grid):
  env, ac, nodes = grid
  smallest = (SIZE - 1) / 2**30  # 8.4e-09
  too_fine = dataclasses.replace(CONFIG, lattice_resolution=(1e-30, 1.0))
  want = (r'lattice_resolution \(1e-30, 1\) overflows the int32 lattice coordinates of '
          r'gridworld10x10 \(coordinate 0\): cell sizes must be at least \(8.4e-09, 8.4e-09\)')
  with pytest.raises(ValueError, match=want):
    make_search(env, ac, too_fine)
  with pytest.raises(ValueError, match=want):
    plan(env, ac, nodes, too_fine, jax.random.PRNGKey(0))
  with pytest.raises(ValueError, match='at least'):  # 1e-50 is 0 in float32
    make_search(env, ac, dataclasses.replace(CONFIG, lattice_resolution=(1.0, 1e-50)))
  # the baselines that take a resolution
  with pytest.raises(ValueError, match=want):
    bl.make_beam_search(env, ac, bl.BeamConfig(lattice_resolution=(1e-30, 1.0)))
  heuristic = epase.Heuristic(init=lambda s: jnp.zeros(s.t.shape),
                              value=lambda d, n: jnp.zeros(n.t.shape))
  with pytest.raises(ValueError, match=want):
    epase.make_epase(env, env.moves, heuristic, epase.EpaseConfig(lattice_resolution=(1e-30, 1)))
  # the printed bound is allowed, and it keeps distinct cells distinct
  make_search(env, ac, dataclasses.replace(CONFIG, lattice_resolution=(8.4e-9, 8.4e-9)))
  corner = env.node(jnp.array([[SIZE - 1.0, SIZE - 1.0], [SIZE - 2.0, SIZE - 1.0]]),
                    jnp.zeros((2, 2)))
  fine = np.asarray(env.lattice_key(corner, jnp.array([smallest, smallest], jnp.float32)))
  assert fine[0, 0] != fine[1, 0] and fine.max() < 2**31 - 1
  # what the check prevents: too small a cell saturates, and distinct cells become one
  saturated = np.asarray(env.lattice_key(corner, jnp.array([1e-30, 1e-30], jnp.float32)))
  assert (saturated[0] == saturated[1]).all()


def test_lattice_extents_bound_the_states_of_each_env():
  grid_env = gridworld.GridWorld(np.zeros((3, 7), bool))
  np.testing.assert_array_equal(grid_env.lattice_extent, [2, 6])
  pm = point_mass.PointMassEnv()
  nodes = pm.initial_nodes(jax.random.split(jax.random.PRNGKey(0), 64))
  far = pm.evaluate(nodes, jnp.ones((64, 2)) * jnp.sign(nodes.qpos))  # towards the walls
  for _ in range(20):
    far = pm.evaluate(far.next_node, jnp.ones((64, 2)) * jnp.sign(far.next_node.qpos))
  assert np.abs(np.asarray(far.next_node.qpos)).max() <= np.min(pm.lattice_extent)
  # PushT: the tip over random arm configurations within the joint limits (MuJoCo C)
  env = pusht.PushTEnv()
  extent = env.lattice_extent
  assert extent.shape == (5,) and np.isclose(extent[2], 2 * np.pi)
  m, data = env.mj_model, mujoco.MjData(env.mj_model)
  rng = np.random.default_rng(0)
  tips = []
  for _ in range(300):
    data.qpos[:7] = rng.uniform(m.jnt_range[:7, 0], m.jnt_range[:7, 1])
    mujoco.mj_kinematics(m, data)
    tips.append(data.site_xpos[m.site('tip').id, :2].copy())
  assert np.abs(np.array(tips)).max() <= extent[3] == extent[4]
  assert extent[3] < 2.5  # a bound, but not a useless one
  t_lo = np.asarray(pusht.FIXED_GOAL[:2]) - pusht.TABLE_HALF_EXTENT
  np.testing.assert_allclose(extent[:2], np.abs(t_lo))


# ---- 4. budgets whose search state cannot fit in memory ----

def _fake_memory(monkeypatch, limit):
  monkeypatch.setattr(memory, 'device_memory',
                      lambda device=None: (limit, f'the test device has {limit} bytes'))


def test_a_budget_that_cannot_fit_is_refused_naming_the_largest_that_can(grid, monkeypatch):
  """plan and plan_sharded refuse a budget whose state exceeds the (faked) device memory before
  searching, naming a budget whose traced state fits while 5% more does not; the memory check
  that plan runs (`programs.check_memory`) accepts the named budget and names the smallest
  valid one (one edge's transitions) when nothing fits."""
  env, ac, nodes = grid
  limit = 40_000_000
  _fake_memory(monkeypatch, limit)
  huge = dataclasses.replace(CONFIG, budget=5_000_000)
  with pytest.raises(ValueError, match='budget of 5,000,000 evaluations needs .* of search state for 4 '
                     'instances per device') as info:
    plan(env, ac, nodes, huge, jax.random.PRNGKey(0))
  best = int(re.search(r'largest budget that fits is about ([\d,]+)', str(info.value))
             .group(1).replace(',', ''))
  size = lambda budget: memory.search_bytes(
      make_search(env, ac, dataclasses.replace(CONFIG, budget=budget)), nodes, 4)
  assert size(best) <= limit < size(int(best * 1.05))
  check = lambda config: programs.check_memory(env, ac, nodes, config)
  assert size(best) < check(dataclasses.replace(CONFIG, budget=best)) <= limit
  with pytest.raises(ValueError, match='largest budget that fits'):
    sharding.plan_sharded(env, ac, nodes, huge, jax.random.PRNGKey(0))
  # edges of 4 transitions: the budgets tried stay at or above 4 (a smaller one is invalid)
  with pytest.raises(ValueError, match='largest budget that fits is about'):
    check(dataclasses.replace(huge, edge_steps=4))
  _fake_memory(monkeypatch, 1000)
  with pytest.raises(ValueError, match='not even a budget of 1 fits: plan fewer instances'):
    check(CONFIG)
  with pytest.raises(ValueError, match='not even a budget of 4 fits'):
    check(dataclasses.replace(CONFIG, edge_steps=4))


def test_state_bytes_are_exact_and_checked_against_real_memory(grid):
  env, ac, nodes = grid
  search = make_search(env, ac, CONFIG)
  state = search.init(nodes, instance_keys(jax.random.PRNGKey(0), 4))
  assert memory.search_bytes(search, nodes, 4) == (
      memory.tree_bytes(state) + memory.tree_bytes(search.result(state)))
  available, where = memory.device_memory()
  assert available > 0 and ('RAM' in where or 'free' in where)
  # 8192 instances of a 10**6 budget: 2 TB, more than any machine (traced, not allocated);
  # a budget of 1 takes 0.3 GB
  big = make_search(env, ac, dataclasses.replace(CONFIG, budget=10**6))
  with pytest.raises(ValueError, match=r'needs 2.\d+ TB .* largest budget that fits'):
    memory.check_fits(functools.partial(make_search, env, ac), big, nodes, 8192)


# ---- 5. numpy and JAX numbers in configs ----

def test_numpy_and_jax_numbers_are_accepted_and_normalised():
  mixed = SearchConfig(weight=np.float32(2.0), pop_size=np.int64(8), num_actions=jnp.int32(4),
                       budget=np.uint16(100),
                       lattice_resolution=np.array([0.5, 1.0], np.float32),
                       compact_fractions=(np.float64(0.5), jnp.float32(0.25)))
  plain = SearchConfig(weight=2.0, pop_size=8, num_actions=4, budget=100,
                       lattice_resolution=(0.5, 1.0),
                       compact_fractions=(0.5, 0.25))
  assert mixed == plain and hash(mixed) == hash(plain)
  assert type(mixed.weight) is float and type(mixed.pop_size) is int
  assert type(mixed.num_actions) is int and type(mixed.budget) is int
  assert all(type(r) is float for r in mixed.lattice_resolution)
  assert type(SearchConfig(weight=2).weight) is float
  capped = Capacities(max_iterations=np.int32(7), pool=jnp.int64(8), table=np.uint8(16))
  assert capped == Capacities(max_iterations=7, pool=8, table=16)
  assert hash(capped) == hash(Capacities(max_iterations=7, pool=8, table=16))
  assert type(capped.max_iterations) is int and type(capped.table) is int
  for bad in (dict(pop_size=True), dict(pop_size=np.bool_(True)), dict(pop_size=np.float64(8)),
              dict(weight=np.float32('nan')), dict(weight=True),
              dict(lattice_resolution=(np.float32(1.0), True))):
    with pytest.raises(ValueError):
      SearchConfig(**bad)
  beam = bl.BeamConfig(beam_width=np.int64(4), weight=np.float32(1.5),
                       lattice_resolution=[np.float64(1.0), 1])
  assert beam == bl.BeamConfig(beam_width=4, weight=1.5, lattice_resolution=(1.0, 1.0))
  assert type(beam.beam_width) is int
  mppi = bl.MppiConfig(num_samples=np.int32(16), horizon=np.int64(4),
                       temperature=np.float32(0.5), budget=jnp.int32(1000),
                       policy_prior_samples=np.int64(2))
  assert mppi == bl.MppiConfig(num_samples=16, horizon=4, temperature=0.5,
                               budget=1000, policy_prior_samples=2)
  assert bl.ParallelRolloutConfig(num_copies=np.int64(4)).num_copies.__class__ is int
  assert bl.SingleRolloutConfig(max_steps=np.int16(3)) == bl.SingleRolloutConfig(max_steps=3)
  assert epase.EpaseConfig(weight=np.float64(3)) == epase.EpaseConfig(weight=3.0)


# ---- 6. the CLI ----

@pytest.fixture
def no_planning(monkeypatch):
  """Fails the test if the command gets as far as loading a model or planning."""
  def reached(*args, **kwargs):
    raise AssertionError('the command went on to load a model or plan')
  monkeypatch.setattr(planner, 'load_model', reached)
  monkeypatch.setattr(programs, 'plan', reached)


def _one_line_error(argv, capsys):
  with pytest.raises(SystemExit) as info:
    cli.main(argv)
  assert info.value.code == 2
  err = capsys.readouterr().err
  assert err.endswith('\n') and err.count('\n') == 1, err  # one line, no traceback
  return err


@pytest.mark.parametrize('argv, message', [
    (['demo', '--steps', '-5'], 'pachs demo: error: argument --steps: must be a positive '
                                "integer, got '-5'"),
    (['demo', '--steps', '0'], 'must be a positive integer'),
    (['demo', '--instance', '99'], 'pachs demo: error: --instance must be in 0..29'),
    (['demo', '--out', '{tmp}'], 'pachs demo: error: --out {tmp}: is a directory, not a file'),
    (['plan', '--seed', str(2**64)], 'pachs plan: error: argument --seed: must fit in 64 bits'),
    (['plan', '--seed', 'x'], 'argument --seed: must be an integer'),
    (['plan', '--json', '{tmp}'], 'pachs plan: error: --json {tmp}: is a directory, not a file'),
    (['plan', '--json', '{tmp}/missing/rows.json'],
     '--json {tmp}/missing/rows.json: the directory {tmp}/missing does not exist'),
    (['plan', '--render', '{tmp}/file.txt/path.png'], '{tmp}/file.txt is not a directory'),
    (['plan', '--json', '/proc/pachs_rows.json'], '--json /proc/pachs_rows.json: cannot write '
                                                  'there'),
    (['plan', '--render', '{tmp}/path.xyz'], 'cannot draw .xyz images'),
    (['plan', '--task', 'playground:ReacherEasy', '--render', '{tmp}/path.png'],
     "--render draws the PushT tasks and the shelf; task 'playground:ReacherEasy' has no"),
    (['plan', '--time-limit', '-1'], 'argument --time-limit: must be a positive number'),
    (['plan', '--lattice-resolution', '0.1,a'], 'argument --lattice-resolution: must be cell '
                                                'sizes'),
    (['plan', '--task', 'pusht'], "invalid choice: 'pusht'"),
    (['plan', '--after-goal', 'stop', '--improve-allowance', '2'],
     '--improve-allowance applies with --after-goal improve'),
    (['plan', '--task', 'pusht-fixed', '--improve-allowance', '2'],
     "the first goal ends the search (after_goal 'stop')"),
])
def test_bad_cli_input_is_one_line_before_any_work(argv, message, tmp_path, capsys, no_planning):
  (tmp_path / 'file.txt').write_text('x')
  fill = lambda s: s.replace('{tmp}', str(tmp_path))
  assert fill(message) in _one_line_error([fill(a) for a in argv], capsys)
  assert sorted(os.listdir(tmp_path)) == ['file.txt']  # the checks leave no file behind


@pytest.mark.skipif(os.geteuid() == 0, reason='root may write anywhere')
def test_unwritable_directory_is_refused(tmp_path, capsys, no_planning):
  locked = tmp_path / 'locked'
  locked.mkdir(mode=0o500)
  err = _one_line_error(['plan', '--json', str(locked / 'rows.json')], capsys)
  assert f'--json {locked}/rows.json: cannot write there (Permission denied)' in err


def test_overflowing_lattice_resolution_in_the_cli(capsys, monkeypatch):
  monkeypatch.setattr(programs, 'plan', lambda *a, **k: pytest.fail('planned'))
  err = _one_line_error(['plan', '--task', 'pusht-fixed', '--lattice-resolution',
                         '1e-30,0.01,0.1,0.02,0.02'], capsys)
  assert ('pachs plan: error: lattice_resolution (1e-30, 0.01, 0.1, 0.02, 0.02) overflows the '
          'int32 lattice coordinates of pusht-fixed (coordinate 0): cell sizes must be at least '
          '(5.7e-10, 5.2e-10, 5.9e-09, 1.9e-09, 1.9e-09)') in err


def test_the_json_is_written_when_drawing_fails(tmp_path, capsys, monkeypatch):
  from pachs_jax import outputs
  def no_space(*args, **kwargs):
    raise OSError(28, 'No space left on device')
  monkeypatch.setattr(outputs, 'write_still', no_space)
  rows, png = tmp_path / 'rows.json', tmp_path / 'path.png'
  code = cli.main(['plan', '--task', 'pusht-fixed', '--instances', '0', '--budget', '50',
                   '-K', '4', '-N', '4', '--no-cache', '--render', str(png), '--json', str(rows)])
  assert code == 2
  captured = capsys.readouterr()
  errors = [line for line in captured.err.splitlines() if not line.startswith('note: ')]
  assert errors == [f'pachs plan: error: --render {png}: No space left on device']
  saved = json.loads(rows.read_text())
  assert [r['instance'] for r in saved['rows']] == [0]
  assert saved['rows'][0]['evaluated'] == 48  # 6 edges of 8 transitions fit the budget of 50
  assert not png.exists()


@pytest.mark.parametrize('kwargs, message', [
    ({'time_limit_s': '5'}, "time_limit_s must be a number of seconds > 0 or None, got '5'"),
    ({'time_limit_s': 0}, 'time_limit_s must be a number of seconds > 0 or None, got 0'),
    ({'stop': 'yes'}, "stop must be a function or None, got 'yes'"),
    ({'progress': 5}, 'progress must be a function or None, got 5'),
])
def test_plan_arguments_of_the_wrong_kind_are_named(grid, kwargs, message):
  env, ac, nodes = grid
  with pytest.raises(ValueError, match=re.escape(message)):
    plan(env, ac, nodes, CONFIG, jax.random.PRNGKey(0), **kwargs)


@pytest.mark.parametrize('field, value', [('table_friction', -1.0), ('t_damping', float('nan')),
                                          ('w_reach', -0.5), ('success_coverage', 0.0)])
def test_pusht_physics_out_of_range_is_refused_naming_the_field(field, value):
  with pytest.raises(ValueError, match=f'PushTConfig.{field} must be'):
    pusht.check_physics(pusht.PushTConfig(**{field: value}))
