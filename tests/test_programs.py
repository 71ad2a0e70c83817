"""`programs.plan`'s compiling rule: with compile_first (a benchmark's pure search time) every
loop a search can reach is compiled before the clock starts, and the result is the same."""

import concurrent.futures
import dataclasses

import jax
import numpy as np

from conftest import assert_results_equal
from pachs_jax.envs import gridworld
from pachs_jax.runtime.programs import Programs, plan
from pachs_jax.search import SearchConfig, make_search


def _loops(search: Programs):
  """{lanes layout: compiled program or Future} of the search's single bucket."""
  (programs,) = search.compiled.values()
  return {name[1]: p for name, p in programs.items() if isinstance(name, tuple)}


def _four_instances():
  """(env, actor-critic, config, start nodes [4], key): an open 8 x 8 grid, K 4, three lane
  layouts (compact fractions 0.25 and 0.5)."""
  env = gridworld.GridWorld(np.zeros((8, 8), bool), connectivity=8)
  config = SearchConfig(weight=1.5, num_actions=8, pop_size=4, budget=200,
                        compact_fractions=(0.25, 0.5))
  nodes = env.node(np.array([[0, 0], [7, 7], [2, 6], [5, 1]]),
                   np.array([[6, 5], [0, 1], [7, 0], [5, 6]]))
  return env, gridworld.GridActorCritic(env), config, nodes, jax.random.PRNGKey(3)


def test_compile_first_compiles_every_reachable_loop_before_the_search():
  env, ac, config, nodes, key = _four_instances()
  pending = {}

  def record(search):
    return lambda: pending.update({
        lanes: isinstance(p, concurrent.futures.Future) for lanes, p in _loops(search).items()})

  first = Programs(make_search(env, ac, config))
  got = plan(env, ac, nodes, config, key, search=first, compile_first=True,
             started=record(first))
  reachable = first.search.reachable(4, 4)
  assert len(reachable) == 3 and set(pending) == set(reachable)
  assert not any(pending.values()), pending  # all compiled when the search began
  # without it the smaller loops may still compile while the search runs; the result is equal
  second = Programs(make_search(env, ac, dataclasses.replace(config)))
  pending.clear()
  want = plan(env, ac, nodes, config, key, search=second, started=record(second))
  assert set(pending) == set(reachable)
  assert_results_equal(got, want)


def test_a_clocked_plan_first_runs_its_new_programs_once_off_the_clock():
  """With a time limit, the first call whose programs have not run yet runs one iteration of
  every reachable layout's loop (each from an init) and the result once before the clock (what a
  first run loads lazily, e.g. MuJoCo Warp's kernel modules, is on no clock, also where the
  search shrinks to a smaller layout later); later calls do not, and the result is that of an
  unclocked plan."""
  env, ac, config, nodes, key = _four_instances()
  search = Programs(make_search(env, ac, config))
  want = plan(env, ac, nodes, config, key, search=search)  # unclocked: compiles, no warm-up
  (programs,) = search.compiled.values()
  runs, advanced = [], []  # the programs run; the iterations each loop run reached

  def count(name):
    program = programs[name]

    def run(*args):
      runs.append(name)
      out = program(*args)
      if isinstance(name, tuple):
        advanced.append(int(np.max(np.asarray(out.iterations))))
      return out
    programs[name] = run

  reachable = search.search.reachable(4, 4)
  assert len(reachable) == 3
  for name in ['init', 'result'] + [('loop', lanes) for lanes in reachable]:
    count(name)
  got = plan(env, ac, nodes, config, key, search=search, time_limit_s=600.0)
  warm_up = runs[:runs.index('result')]
  assert warm_up == [name for lanes in reachable for name in ('init', ('loop', lanes))], warm_up
  assert advanced[:len(reachable)] == [1] * len(reachable)  # one iteration each
  assert_results_equal(got, want)
  runs.clear()
  plan(env, ac, nodes, config, key, search=search, time_limit_s=600.0)
  assert runs.count('init') == 1  # warmed once
