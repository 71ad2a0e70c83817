"""Programs compiled by `pachs.plan` (issue 15): the search compiles a few whole programs, never
one program per array operation, and a second call of the same shapes compiles nothing."""

import contextlib
import logging

import jax
import numpy as np
import pytest

from pachs_jax.envs import gridworld
from pachs_jax.search import SearchConfig, make_search, plan

OBSTACLES = np.zeros((8, 8), bool)
OBSTACLES[1:7, 4] = True
STARTS = np.array([[3, 1], [0, 0], [7, 7]])
GOALS = np.array([[3, 7], [7, 7], [0, 0]])
CONFIG = SearchConfig(weight=1.0, num_actions=8, pop_size=4, max_evaluations=400,
                      compact_fractions=(0.5,))


@contextlib.contextmanager
def compiled_programs():
  """Collects the names of the XLA programs JAX compiles inside the block."""
  names = []

  class Record(logging.Handler):
    def emit(self, record):
      message = record.getMessage()
      if message.startswith('Compiling '):
        names.append(message.split(' ')[1])

  handler = Record(level=logging.DEBUG)
  logger = logging.getLogger('jax')
  logger.addHandler(handler)
  try:
    with jax.log_compiles(True):
      yield names
  finally:
    logger.removeHandler(handler)


@pytest.fixture(scope='module')
def grid():
  env = gridworld.GridWorld(OBSTACLES, connectivity=8)
  return env, gridworld.GridActorCritic(env), env.node(STARTS, GOALS)


def test_plan_compiles_whole_programs_once(grid):
  env, ac, nodes = grid
  search = make_search(env, ac, CONFIG)
  key = jax.random.PRNGKey(0)
  with compiled_programs() as first:
    out = plan(env, ac, nodes, CONFIG, key, search=search)
  assert np.asarray(out.found).all()
  # the search's own programs (init, loops, result), the model check, key splitting and the
  # padding / cutting of the instance axis: no program per array operation
  assert 0 < len(first) <= 10, first
  single_ops = [n for n in first if n.strip('jit()') in (
      'concatenate', 'gather', 'dynamic_slice', 'broadcast_in_dim', 'convert_element_type',
      'reshape', 'iota', 'less', 'subtract', '_reduce_any', 'stage', 'select_n', 'add', 'copy')]
  assert not single_ops, first
  with compiled_programs() as again:
    plan(env, ac, nodes, CONFIG, key, search=search)
  assert again == []
  # 4 instances fall in the bucket of 3 (padded to 4): at most the key split and the cut of
  # the result to the instance count are new (other tests may have compiled those already)
  more = jax.tree.map(lambda x: np.concatenate([x, x[:1]]), jax.device_get(nodes))
  with compiled_programs() as bucket:
    plan(env, ac, jax.device_put(more), CONFIG, key, search=search)
  assert set(bucket) <= {'jit(_threefry_split)', 'jit(first_rows)'}, bucket
