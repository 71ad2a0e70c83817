"""The experiment scripts' own logic: statistics, curves, cost ratios, closed-loop bookkeeping."""

import json
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest


import bench_serve  # noqa: E402  pylint: disable=wrong-import-position
import closed_loop  # noqa: E402  pylint: disable=wrong-import-position
import merge_results  # noqa: E402  pylint: disable=wrong-import-position
import open_loop  # noqa: E402  pylint: disable=wrong-import-position
import stats  # noqa: E402  pylint: disable=wrong-import-position
import trace_replay  # noqa: E402  pylint: disable=wrong-import-position
from pachs_jax import envs, planner  # noqa: E402  pylint: disable=wrong-import-position
from pachs_jax.envs import point_mass, pusht  # noqa: E402  pylint: disable=wrong-import-position


def test_wilson_interval_known_values_and_edges():
  low, high = stats.wilson_interval(137, 150)
  assert low == pytest.approx(0.8566, abs=1e-3) and high == pytest.approx(0.9489, abs=1e-3)
  assert stats.wilson_interval(150, 150)[1] == 1.0  # exactly 1, not 0.99999...
  assert stats.wilson_interval(0, 10) == (0.0, pytest.approx(0.2775, abs=1e-3))
  low, high = stats.wilson_interval(5, 10)
  assert low < 0.5 < high and low == pytest.approx(1 - high)


def test_success_curve_counts_runs_found_within_budget():
  rows = [{'found': True, 'evaluated': 50}, {'found': True, 'evaluated': 500},
          {'found': False, 'evaluated': 1000}, {'found': True, 'evaluated': 5000}]
  assert stats.success_curve(rows, [10, 50, 499, 500, 10_000]) == [0, 0.25, 0.25, 0.5, 0.75]


def test_mcnemar_p_known_values():
  assert stats.mcnemar_p(0, 0) == 1.0
  assert stats.mcnemar_p(0, 5) == pytest.approx(2 / 32)  # all 5 discordant pairs one way
  assert stats.mcnemar_p(2, 7) == pytest.approx(2 * (1 + 9 + 36) / 512)  # scipy.stats.binomtest
  assert stats.mcnemar_p(4, 4) == 1.0


def test_most_behind_pairs_runs_and_counts_first_goals():
  run = lambda i, found, first, total=None: {'instance': i, 'round': 0, 'found': found,
                                             'first_goal_evaluated': first,
                                             'evaluated': total or first}
  # a: runs 0-2 solved at 100, 4000 and 9000 (run 1 improves its path until 20,000);
  # b: runs 0-2 solved at 100, 3500, 3500; run 3 unsolved by both; b's list in another order
  a = [run(0, True, 100), run(1, True, 4000, 20_000), run(2, True, 9000), run(3, False, 0, 50)]
  b = [run(2, True, 3500), run(3, False, 0, 50), run(1, True, 3500), run(0, True, 100)]
  runs, budget, p = stats.most_behind(a, b, [100, 3000, 3500, 5000, 10_000])
  assert (runs, budget) == (2, 3500) and p == pytest.approx(stats.mcnemar_p(0, 2))
  assert stats.most_behind(b, a, [100, 3000, 3500, 5000, 10_000]) == (0, None, None)
  assert stats.most_behind(a, b, [100, 3000, 3500], start=4000) == (0, None, None)


def test_cost_ratios_use_runs_both_solved():
  rows = {'a': [{'found': True, 'cost': 2.0}, {'found': True, 'cost': 4.0},
                {'found': False, 'cost': 9.0}],
          'b': [{'found': True, 'cost': 1.0}, {'found': False, 'cost': 1.0},
                {'found': True, 'cost': 3.0}]}
  ratios = stats.cost_ratios(rows)
  assert ratios['a']['b'] == {'mean_ratio': 2.0, 'runs': 1}
  assert ratios['b']['a'] == {'mean_ratio': 0.5, 'runs': 1}
  assert ratios['a']['a'] == {'mean_ratio': 1.0, 'runs': 2}


def test_run_keys_differ_per_run_and_repeat_per_seed():
  keys = np.asarray(open_loop.run_keys(0, 3, 2))
  assert keys.shape == (6, 2) and len({tuple(k) for k in keys}) == 6
  np.testing.assert_array_equal(keys, np.asarray(open_loop.run_keys(0, 3, 2)))


def test_perturbation_parsing():
  p = closed_loop.parse_perturbation('friction=1.5,t_mass=0.5')
  assert (p.friction, p.t_mass, p.actuator_gain) == (1.5, 0.5, 1.0)
  with pytest.raises(ValueError, match='unknown perturbation'):
    closed_loop.parse_perturbation('gravity=2')


def test_planner_world_replays_a_plan_in_the_planners_physics_and_stops_finished_ones():
  env = point_mass.PointMassEnv()
  starts = env.initial_nodes(jax.random.split(jax.random.PRNGKey(0), 2))
  actions = np.array(jax.random.uniform(jax.random.PRNGKey(1), (2, 3, 2), minval=-1.0))
  actions[1, 2] = (0.8, 0.0)
  reference = jax.tree.map(lambda x: x[1:], starts)  # the edges one at a time
  for j in range(2):
    reference = env.evaluate(reference, jnp.asarray(actions[1:, j])).next_node
  # the first episode starts at its goal; the second's goal is 0.08 beyond its second step
  goal = starts.goal.at[0].set(starts.qpos[0]).at[1].set(reference.qpos[0] + jnp.array([0.08, 0]))
  episodes = closed_loop.PlannerWorldEpisodes(env, starts.replace(goal=goal))
  assert episodes.success.tolist() == [True, False]
  episodes.execute(actions, np.array([3, 2]))
  # the finished episode does not move; the other runs its 2 actions as the planner would
  assert episodes.steps.tolist() == [0, 2] and episodes.success.tolist() == [True, False]
  np.testing.assert_array_equal(np.asarray(episodes.nodes.qpos[0]), np.asarray(starts.qpos[0]))
  np.testing.assert_array_equal(np.asarray(episodes.nodes.qpos[1]), np.asarray(reference.qpos[0]))
  episodes.execute(actions[:, 2:], np.array([1, 1]))  # the third action reaches the goal
  assert episodes.success.tolist() == [True, True] and episodes.success_step.tolist() == [-1, 3]


def test_instance_bootstrap_interval_treats_rounds_as_one_instance():
  # 30 instances x 5 rounds of a deterministic planner: one instance fails all its rounds
  instance = np.tile(np.arange(30), 5)
  found = instance != 7
  low, high = stats.instance_bootstrap_interval(found, instance)
  wilson_low, _ = stats.wilson_interval(int(found.sum()), found.size)
  assert low < wilson_low < 29 / 30 <= high <= 1.0  # wider than 150 independent runs
  assert stats.instance_bootstrap_interval(np.ones(10, bool), np.arange(10)) == (1.0, 1.0)
  # resampling is seeded: the same interval every call
  assert stats.instance_bootstrap_interval(found, instance) == (low, high)


def test_paired_difference_resamples_instances_of_paired_runs():
  run = lambda i, k, found, first=100: {'instance': i, 'round': k, 'found': found,
                                        'first_goal_evaluated': first, 'evaluated': first}
  # 20 instances x 2 rounds; a solves every run, b misses both rounds of instances 0-4 and
  # solves instance 5's rounds only after the budget
  a = [run(i, k, True) for i in range(20) for k in range(2)]
  b = [run(i, k, i >= 5, 5000 if i == 5 else 100) for i in range(20) for k in range(2)]
  difference, low, high = stats.paired_difference(a, b[::-1], budget=1000)
  assert difference == 12 and low < difference < high
  assert low >= 0 and high <= 40  # resampled instances are whole: differences come in pairs
  assert stats.paired_difference(a, b, budget=1000) == (difference, low, high)  # seeded
  assert stats.paired_difference(a, b, budget=10_000)[0] == 10  # instance 5 solved by then
  assert stats.paired_difference(a, a, budget=1000) == (0, 0.0, 0.0)


def _closed(planners, **settings):
  base = {'task': 'pusht-obs', 'instances': 2, 'rounds': 1, 'query_time': 3.0, 'execute': 10,
          'max_queries': 30, 'fill_with_policy': 1, 'perturb': '', 'seed': 0}
  return {'provenance': {'command': ' '.join(planners)}, 'task': 'pusht-obs',
          'settings': {**base, **settings}, 'perturbation': {'friction': 1.0},
          'summary': [{'planner': p, 'successes': i} for i, p in enumerate(planners)],
          'episodes': {p: {'success': [i > 0, True]} for i, p in enumerate(planners)}}


def test_merge_closed_keeps_every_planner_and_labels_min_h():
  merged = merge_results.merge_closed([_closed(['single', 'pachs']),
                                       _closed(['pachs'], realtime_answer='min_h')])
  assert [r['planner'] for r in merged['summary']] == ['single', 'pachs', 'pachs-min_h']
  assert merged['episodes']['pachs-min_h'] == {'success': [False, True]}
  assert len(merged['provenance']['merged_from']) == 2
  with pytest.raises(ValueError, match='query_time'):
    merge_results.merge_closed([_closed(['single']), _closed(['pachs'], query_time=1.0)])
  with pytest.raises(ValueError, match='two sources'):
    merge_results.merge_closed([_closed(['pachs']), _closed(['pachs'])])


def _open(costs):
  runs = {p: [{'found': c is not None, 'cost': c if c is not None else float('nan')}
              for c in cs] for p, cs in costs.items()}
  return {'provenance': {}, 'task': 'shelf', 'model': 'm',
          'settings': {'instances': 2, 'rounds': 1, 'budget': 10, 'time_limit_s': 60.0},
          'configs': {p: p for p in costs}, 'summary': [{'planner': p} for p in costs],
          'runs': runs, 'curve_budgets': [1, 10], 'success_curve': {p: [0, 1] for p in costs}}


def test_merge_open_replaces_a_planner_and_recomputes_cost_ratios():
  base = _open({'pachs': [1.0, 2.0], 'epase': [None, None]})
  rerun = _open({'epase': [2.0, 8.0]})
  merged = merge_results.merge_open([base, rerun])
  assert [r['planner'] for r in merged['summary']] == ['pachs', 'epase']
  assert merged['runs']['epase'] == rerun['runs']['epase']
  ratio = merged['cost_ratios']['pachs']['epase']
  assert ratio['runs'] == 2 and ratio['mean_ratio'] == pytest.approx((0.5 + 0.25) / 2)
  with pytest.raises(ValueError, match='budget'):
    merge_results.merge_open([base, dict(rerun, settings=dict(rerun['settings'], budget=5))])
  # runs on another instance set (open_loop.py --instance-seed) never merge with the canonical
  # set; files from before the option count as set 0
  other_set = dict(rerun, settings=dict(rerun['settings'], instance_seed=1))
  with pytest.raises(ValueError, match='instance_seed: 0 vs 1'):
    merge_results.merge_open([base, other_set])
  same_set = dict(rerun, settings=dict(rerun['settings'], instance_seed=0))
  assert merge_results.merge_open([base, same_set])['settings']['instance_seed'] == 0


def test_merge_source_rename_keeps_an_earlier_variant_beside_a_new_default(tmp_path):
  path = tmp_path / 'old.json'
  path.write_text(json.dumps(_open({'pachs': [1.0, 2.0], 'parallel': [2.0, 2.0]})))
  old = merge_results.load_source(f'{path}#pachs=pachs-h8')
  merged = merge_results.merge_open([old, _open({'pachs': [4.0, None]})])
  assert [r['planner'] for r in merged['summary']] == ['pachs-h8', 'parallel', 'pachs']
  assert merged['runs']['pachs-h8'][1]['cost'] == 2.0
  assert merged['cost_ratios']['pachs']['pachs-h8'] == {'mean_ratio': 4.0, 'runs': 1}
  for bad in ('#nope=x', '#pachs=parallel', '#pachs'):
    with pytest.raises(ValueError, match='rename'):
      merge_results.load_source(f'{path}{bad}')


def test_merge_open_of_a_merged_file_keeps_its_sources_flat():
  first = dict(_open({'pachs': [1.0, 2.0]}), provenance={'git_revision': 'a'})
  second = dict(_open({'beam': [3.0, None]}), provenance={'git_revision': 'b'})
  second['settings'] = dict(second['settings'], note='beam run')
  merged = merge_results.merge_open([first, second])
  third = dict(_open({'pachs': [2.0, 2.0]}), provenance={'git_revision': 'c'})
  again = merge_results.merge_open([merged, third])
  assert [p['git_revision'] for p in again['provenance']['merged_from']] == ['a', 'b', 'c']
  assert again['settings_per_planner']['beam']['note'] == 'beam run'
  assert again['runs']['pachs'] == third['runs']['pachs']


@pytest.mark.parametrize('script, argv, message', [
    (open_loop, ['--budget', '-1'], "--budget: must be a positive integer, got '-1'"),
    (open_loop, ['--copies', '0'], "--copies: must be a positive integer, got '0'"),
    (open_loop, ['--lattice-scale', '0'], "--lattice-scale: must be a positive number"),
    (open_loop, ['--weight', 'nan'], 'argument --weight/-w: must be a number >= 0, finite'),
    (open_loop, ['--rounds', '0'], "--rounds: must be a positive integer, got '0'"),
    (open_loop, ['--instances', '31'], '--instances 31 exceeds the 30 canonical instances'),
    (open_loop, ['--planners', ','], '--planners: none named'),
    (open_loop, ['--out', '/'], "--out '/': a .json file"),
    (open_loop, ['--out', '/tmp/results.md'], "--out '/tmp/results.md': a .json file"),
    (open_loop, ['--out', '/proc/no/x.json'], '--out /proc/no/x.json'),
    (closed_loop, ['--task', 'pusht-fixed', '--replay-remainder', '1', '--planners', 'pachs'],
     'has no chain lanes to replay'),
    (closed_loop, ['--server', 'nosuch', '--planners', 'pachs'], "--server 'nosuch': no pachs"),
    (closed_loop, ['--query-time', '0'], "--query-time: must be a positive number, got '0'"),
    (closed_loop, ['--execute', '0'], "--execute: must be a positive integer, got '0'"),
    (closed_loop, ['--perturb', 'friction=abc'], "--perturb friction: a number, got 'abc'"),
    (closed_loop, ['--instances', '0'], "--instances: must be a positive integer, got '0'"),
    (closed_loop, ['--planners', ''], '--planners: none named'),
    (closed_loop, ['--planners', 'pachs,foo'], '--planners: unknown foo'),
    (closed_loop, ['--candidates', 'policy,x'], '--candidates: unknown x'),
    (closed_loop, ['--physics', 'soft'], "argument --physics: invalid choice: 'soft'"),
    (closed_loop, ['--server', 'ws://x', '--physics', 'planar'], '--physics with --server'),
    (closed_loop, ['--planners', 'pachs', '-K', '0'], 'argument --pop-size/-K: must be a positive integer'),
    (closed_loop, ['--check-copies', '-1'], 'argument --check-copies: must be >= 0, got -1'),
    (closed_loop, ['--world', 'planner', '--trace', '1'], '--trace records MuJoCo C worlds'),
    # found once the model is loaded, before the first planner (here the policy alone) runs
    (closed_loop, ['--backend', 'mujoco-c', '--instances', '1', '--rounds', '1',
                   '--planners', 'single,pachs', '--budget', '10000000000'],
     'the pool capacity * (edges per node + 1) must stay below 2**31'),
    (closed_loop, ['--backend', 'mujoco-c', '--instances', '1', '--rounds', '1',
                   '--planners', 'parallel', '--copies', '100000000'],
     '--copies 100000000: the parallel rollout of 1 episode keeps'),
    (trace_replay, ['/nonexistent/run.json'], '/nonexistent/run.json: no trace beside it'),
    (closed_loop, ['--server', 'ws://x', '--check-copies', '2'],
     '--check-copies checks the answers of an in-process PACHS, not --server'),
    (closed_loop, ['--fill-check', '1', '--fill-with-policy', '0'],
     '--fill-check follows the policy fill (--fill-with-policy 1)'),
    (bench_serve, ['--out', '/tmp', '--clients', '0'], "--clients: client counts must be >= 1"),
    (bench_serve, ['--out', '/tmp', '--big', '-1'], "--big: episode counts must not be negative"),
])
def test_bad_script_flags_stop_in_one_line_before_any_work(script, argv, message, monkeypatch,
                                                           capsys):
  monkeypatch.setattr(sys, 'argv', [script.__name__ + '.py'] + argv)
  with pytest.raises(SystemExit) as exit_info:
    script.main()
  assert exit_info.value.code == 2
  err = capsys.readouterr().err
  assert message in err and err.count('\n') == 1, err


def test_the_policy_fill_is_checked_by_default_wherever_a_session_fills(monkeypatch):
  parse = lambda *argv, physics='warp': closed_loop.fill_check(
      closed_loop.build_parser().parse_args(['--task', 'pusht-obs', *argv]), physics)
  monkeypatch.setattr(planner.jax, 'default_backend', lambda: 'gpu')  # the task's rule
  assert parse() == 1 and parse('--query-time', '3') == 1
  assert parse('--query-time', '1') == 0  # pusht-obs: from 2 s on an accelerator
  assert parse('--query-time', '1', physics='mujoco-c') == 1
  assert parse('--query-time', '1', '--fill-check', '1') == 1
  assert parse('--fill-with-policy', '0') == 0
  assert parse('--server', 'localhost:8765') == 0
  assert parse('--fill-check', '0') == 0


def _closed_loop_args(**changes):
  """closed_loop.py's flags for run_planner: PACHS on a tiny budget, K 4, changes applied."""
  flags = dict(budget=64, realtime_answer=None, pop_size=4, chain_restart=None,
               compact_fractions=(), candidates=(), replay_remainder=0, chunk_iterations=1,
               max_queries=30, execute=10, query_time=1.0, fill_with_policy=1, server=None,
               check_copies=0, check_scale=1.0, trace=0, fill_check=0)
  return closed_loop.argparse.Namespace(**{**flags, **changes})


def test_a_stop_request_ends_a_planners_episodes_before_the_next_query():
  from pachs_jax import planner  # pylint: disable=import-outside-toplevel
  env, model = planner.load_model('pusht-fixed')
  starts = env.canonical_instances(2)
  args = _closed_loop_args()
  worlds = closed_loop.Worlds(env, starts)
  info = closed_loop.run_planner('pachs', 'pusht-fixed', env, model, worlds, args,
                                 jax.random.PRNGKey(0), stop=lambda: True)
  assert info['interrupted_at_query'] == 0 and info['queries_per_episode_mean'] == 0.0
  assert worlds.steps.tolist() == [0, 0]  # nothing ran in the worlds


def test_a_traced_planner_writes_its_worlds_and_the_states_pachs_planned_for_them(tmp_path):
  from pachs_jax import planner  # pylint: disable=import-outside-toplevel
  env, model = planner.load_model('pusht-fixed')
  starts = env.canonical_instances(2)
  args = _closed_loop_args(max_queries=1, execute=3, query_time=300.0, trace=1)  # budget binds
  worlds = closed_loop.Worlds(env, starts)
  path = tmp_path / 'run.pachs.trace.npz'
  info = closed_loop.run_planner('pachs', 'pusht-fixed', env, model, worlds, args,
                                 jax.random.PRNGKey(0), trace_path=str(path))
  # the budget, not the 300 s clock, ended both searches
  assert info['searches_ended_before_clock'] == 2
  assert info['evaluations_per_clocked_query_mean'] is None
  trace = np.load(path)
  assert trace['asked_at'].tolist() == [[0, 0]] and trace['steps'].tolist() == [3, 3]
  # the plan starts at the world's state, and the world executed the plan's actions
  np.testing.assert_allclose(trace['planned_qpos'][:, 0], starts.qpos, atol=1e-6)
  np.testing.assert_array_equal(trace['world_qpos'][:, 0], starts.qpos)
  assert not trace['by_policy'].any()
  # the T where the plan put it, to 0.1 mm (MJX float32 planners, the MuJoCo C world, 3 steps)
  np.testing.assert_allclose(trace['world_qpos'][:, 1:, 7:9], trace['planned_qpos'][:, 1:, 7:9],
                             atol=1e-4)


def test_the_replay_starts_at_the_last_query_of_the_episode():
  """The last world state of `asked_at` before the episode's end (-1: a query after it)."""
  trace = {'steps': np.array([7]), 'asked_at': np.array([[0], [3], [6], [-1]])}
  assert trace_replay.last_query(trace, 0) == 6
