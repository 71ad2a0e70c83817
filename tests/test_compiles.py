"""Programs compiled by `pachs.plan` (issue 15): the search compiles a few whole programs, never
one program per array operation, and a second call of the same shapes compiles nothing."""

import jax
import numpy as np
import pytest

from pachs_jax import compile_cache
from pachs_jax.envs import gridworld
from pachs_jax.search import SearchConfig, make_search, plan

OBSTACLES = np.zeros((8, 8), bool)
OBSTACLES[1:7, 4] = True
STARTS = np.array([[3, 1], [0, 0], [7, 7]])
GOALS = np.array([[3, 7], [7, 7], [0, 0]])
CONFIG = SearchConfig(weight=1.0, num_actions=8, pop_size=4, max_evaluations=400,
                      compact_fractions=(0.5,))


@pytest.fixture(scope='module')
def grid():
  env = gridworld.GridWorld(OBSTACLES, connectivity=8)
  return env, gridworld.GridActorCritic(env), env.node(STARTS, GOALS)


def test_plan_compiles_whole_programs_once(grid):
  env, ac, nodes = grid
  search = make_search(env, ac, CONFIG)
  key = jax.random.PRNGKey(0)
  with compile_cache.compile_log() as log:
    out = plan(env, ac, nodes, CONFIG, key, search=search)
  first = log.compiled
  assert np.asarray(out.found).all()
  # the search's own programs (init, loops, result), the model check, key splitting and the
  # padding / cutting of the instance axis: no program per array operation
  assert 0 < len(first) <= 10, first
  single_ops = [n for n in first if n.strip('jit()') in (
      'concatenate', 'gather', 'dynamic_slice', 'broadcast_in_dim', 'convert_element_type',
      'reshape', 'iota', 'less', 'subtract', '_reduce_any', 'stage', 'select_n', 'add', 'copy')]
  assert not single_ops, first
  with compile_cache.compile_log() as log:
    plan(env, ac, nodes, CONFIG, key, search=search)
  assert log.compiled == []
  # 4 instances fall in the bucket of 3 (padded to 4): at most the key split and the cut of
  # the result to the instance count are new (other tests may have compiled those already)
  more = jax.tree.map(lambda x: np.concatenate([x, x[:1]]), jax.device_get(nodes))
  with compile_cache.compile_log() as log:
    plan(env, ac, jax.device_put(more), CONFIG, key, search=search)
  assert set(log.compiled) <= {'jit(_threefry_split)', 'jit(first_rows)'}, log.compiled
