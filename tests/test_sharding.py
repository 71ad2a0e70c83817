"""plan_sharded: the sharded search equals the unsharded `plan`, instance by instance."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pachs_jax.search import SearchConfig, make_search, plan
from pachs_jax.search import sharding

# Shared by the in-process tests and the 4-device subprocess (the same source text).
SETUP = textwrap.dedent('''
    import jax
    import numpy as np
    from pachs_jax.envs import gridworld
    from pachs_jax.search import SearchConfig
    OBSTACLES = np.zeros((10, 10), bool)
    OBSTACLES[3:7, 5] = True
    OBSTACLES[7, 1:5] = True
    ENV = gridworld.GridWorld(OBSTACLES, connectivity=8)

    class RandomActor(gridworld.GridActorCritic):
      # Uniform random proposals: the result depends on each instance's key.
      def sample_actions(self, key, obs, num):
        return jax.random.uniform(key, obs.shape[:-1] + (num, 2), minval=-1.0, maxval=1.0)

    AC = RandomActor(ENV)
    STARTS = np.array([[0, 0], [9, 9], [2, 8], [5, 1], [0, 9], [8, 3]])
    GOALS = np.array([[9, 9], [0, 0], [8, 2], [5, 9], [9, 0], [8, 3]])  # the last: start == goal
    NODES = ENV.node(STARTS, GOALS)
    CONFIG = SearchConfig(weight=1.5, num_actions=8, pop_size=2, max_evaluations=400,
                          heap_kind='flat')
''')
_scope = {}
exec(SETUP, _scope)  # pylint: disable=exec-used
ENV, AC, NODES, CONFIG = _scope['ENV'], _scope['AC'], _scope['NODES'], _scope['CONFIG']

# 6 instances over 4 devices (padded to 8); compares every field but the wall time.
FOUR_DEVICES = SETUP + textwrap.dedent('''
    import jax
    from pachs_jax.search import plan, make_search
    from pachs_jax.search.sharding import instance_mesh, plan_sharded
    assert len(jax.devices()) == 4, jax.devices()
    search = make_search(ENV, AC, CONFIG)
    key = jax.random.PRNGKey(3)
    want = plan(ENV, AC, NODES, CONFIG, key, search=search)
    got = plan_sharded(ENV, AC, NODES, CONFIG, key, mesh=instance_mesh(), search=search)
    assert got.found.shape == (6,), got.found.shape
    assert np.asarray(want.found).sum() >= 4, want.found
    want_leaves = jax.tree.leaves(want.replace(wall_time_s=None))
    got_leaves = jax.tree.leaves(got.replace(wall_time_s=None))
    assert len(want_leaves) == len(got_leaves) > 0
    for w, g in zip(want_leaves, got_leaves):
      assert np.array_equal(np.asarray(w), np.asarray(g)), (w, g)
    assert np.isfinite(got.wall_time_s) and got.wall_time_s > 0
    print('SHARDED_OK')
''')


def _leaves(result):
  return [np.asarray(x) for x in jax.tree.leaves(result.replace(wall_time_s=None))]


def test_four_devices_equal_unsharded():
  env = dict(os.environ, XLA_FLAGS='--xla_force_host_platform_device_count=4',
             JAX_PLATFORMS='cpu')
  proc = subprocess.run([sys.executable, '-c', FOUR_DEVICES], env=env, capture_output=True,
                        text=True, timeout=300)
  assert proc.returncode == 0 and 'SHARDED_OK' in proc.stdout, proc.stderr[-4000:]


@pytest.fixture(scope='module')
def search():
  return make_search(ENV, AC, CONFIG)


def test_default_mesh_equals_plan(search):
  key = jax.random.PRNGKey(7)
  want = plan(ENV, AC, NODES, CONFIG, key, search=search)
  got = sharding.plan_sharded(ENV, AC, NODES, CONFIG, key, search=search)
  assert np.asarray(want.found).sum() >= 4  # most instances finish with real paths
  assert (np.asarray(want.path_length) > 0).sum() >= 4
  for w, g in zip(_leaves(want), _leaves(got)):
    np.testing.assert_array_equal(g, w)
  # The keys matter (so equal results also check that each instance got its own key).
  other = plan(ENV, AC, NODES, CONFIG, jax.random.PRNGKey(8), search=search)
  assert any(not np.array_equal(w, o) for w, o in zip(_leaves(want), _leaves(other)))
  assert got.found.shape == (NODES.qpos.shape[0],)
  assert np.isfinite(got.wall_time_s) and got.wall_time_s > 0


def test_pad_repeats_the_last_row():
  tree = {'a': jnp.arange(6).reshape(3, 2), 'b': jnp.array([1, 2, 3])}
  padded = sharding._pad(tree, 5)  # pylint: disable=protected-access
  np.testing.assert_array_equal(padded['a'], [[0, 1], [2, 3], [4, 5], [4, 5], [4, 5]])
  np.testing.assert_array_equal(padded['b'], [1, 2, 3, 3, 3])
  assert sharding._pad(tree, 3)['b'].shape == (3,)  # pylint: disable=protected-access


def test_bad_input_raises(search):
  key = jax.random.PRNGKey(0)
  wrong_axis = jax.sharding.Mesh(np.asarray(jax.devices()), ('batch',))
  with pytest.raises(ValueError, match="single axis 'instances'"):
    sharding.plan_sharded(ENV, AC, NODES, CONFIG, key, mesh=wrong_axis, search=search)
  with pytest.raises(ValueError, match='Mesh'):
    sharding.plan_sharded(ENV, AC, NODES, CONFIG, key, mesh=jax.devices(), search=search)
  with pytest.raises(ValueError, match='keys'):
    sharding.plan_sharded(ENV, AC, NODES, CONFIG, jnp.zeros((4, 2), jnp.uint32), search=search)
  with pytest.raises(ValueError, match='another config'):
    other = SearchConfig(weight=1.0, num_actions=8, pop_size=2, max_evaluations=400,
                         heap_kind='flat')
    sharding.plan_sharded(ENV, AC, NODES, other, key, search=search)
