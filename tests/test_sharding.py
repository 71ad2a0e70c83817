"""Sharded planners equal the unsharded ones, instance by instance: PACHS (`plan_sharded`) and
the baselines (`plan_sharded_fn`), on 4 simulated CPU devices (a subprocess, since the device
count is fixed when JAX starts) and on this process's default mesh."""

import os
import socket
import subprocess
import sys
import textwrap
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import assert_results_equal, jax_cache_env, result_leaves
from pachs_jax.search import SearchConfig, make_search
from pachs_jax.runtime.programs import plan
from pachs_jax.runtime import sharding

# Shared by the in-process tests and the subprocesses (the same source text).
SETUP = textwrap.dedent('''
    import jax
    import numpy as np
    from pachs_jax.envs import gridworld
    from pachs_jax.search import SearchConfig, StopReason
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
    CONFIG = SearchConfig(weight=1.5, num_actions=8, pop_size=2, budget=400)

    from pachs_jax.search import baselines as bl
    from pachs_jax.runtime import sharding

    class GreedyActor(RandomActor):
      # The single rollout's deterministic policy: the move of the best Q.
      def deterministic_action(self, obs):
        moves = jax.numpy.asarray(self.env.moves)
        q = self.q_values(obs, jax.numpy.broadcast_to(moves, obs.shape[:1] + moves.shape))
        return moves[jax.numpy.argmax(q, axis=1)]

    def baselines():
      # name -> (per-shard fn(start_nodes, keys), the unsharded call fn(start_nodes, key)).
      rollout = bl.make_parallel_rollout(
          ENV, AC, bl.ParallelRolloutConfig(num_copies=4, budget=300, episode_length=12))
      beam = bl.make_beam_search(ENV, AC, bl.BeamConfig(beam_width=4, num_actions=4,
                                                        budget=300))
      heuristic = bl.Heuristic(init=lambda s: jax.numpy.zeros(s.t.shape[:1]),
                               value=lambda data, n: AC.heuristic(n.qpos, n.goal))
      epase = bl.make_epase(ENV, ENV.moves, heuristic, bl.EpaseConfig(pop_size=2,
                                                                      budget=300))
      single = bl.make_single_rollout(ENV, GreedyActor(ENV))
      return {'rollout': (rollout.plan, rollout.plan), 'beam': (beam, beam),
              'epase': (sharding.keyless(epase.plan), lambda s, k: epase.plan(s)),
              'single': (sharding.keyless(single), lambda s, k: single(s))}

    REFERENCE_KEY = 3  # the key of the unsharded results the subprocesses compare with

    def assert_matches_reference(name, result, path):
      # result's arrays, its wall time aside, equal NAME_0, NAME_1, ... of the .npz at path
      saved = np.load(path)
      leaves = jax.tree.leaves(result.replace(wall_time_s=None))
      assert len(leaves) == int(saved[name + '_leaves']) > 0
      for i, leaf in enumerate(leaves):
        assert np.array_equal(saved[f'{name}_{i}'], np.asarray(leaf)), (name, i)
''')
_scope = {}
exec(SETUP, _scope)  # pylint: disable=exec-used
ENV, AC, NODES, CONFIG = _scope['ENV'], _scope['AC'], _scope['NODES'], _scope['CONFIG']
REFERENCE_KEY = _scope['REFERENCE_KEY']
BASELINES = ('rollout', 'beam', 'epase', 'single')

# 6 instances over 4 devices (padded to 8), each planner's result compared, every field but the
# wall time, with the unsharded result this process saved (`references`), so that the
# subprocess compiles only the sharded programs. Prints NAME_OK per planner, or NAME_FAILED
# with the error (each planner is checked).
FOUR_DEVICES = SETUP + textwrap.dedent('''
    import sys
    import traceback
    from pachs_jax.search import make_search
    assert len(jax.devices()) == 4, jax.devices()
    key = jax.random.PRNGKey(REFERENCE_KEY)
    mesh = sharding.instance_mesh()

    def same(name, got):
      assert got.found.shape == (6,), got.found.shape
      assert_matches_reference(name, got, sys.argv[1])
      assert np.isfinite(got.wall_time_s) and got.wall_time_s > 0
      assert np.asarray(got.evaluated).sum() > 0

    SEARCH = make_search(ENV, AC, CONFIG)

    def stopped_after_a_chunk():
      # in chunks, stopped after the first: the instances that finished keep their results
      asked = []
      got = sharding.plan_sharded(ENV, AC, NODES, CONFIG, key, mesh=mesh, search=SEARCH,
                                  stop=lambda: asked.append(1) or len(asked) > 1)
      saved = np.load(sys.argv[1])
      treedef = jax.tree.structure(got.replace(wall_time_s=None))
      want = jax.tree.unflatten(treedef, [saved[f'pachs_{i}']
                                          for i in range(int(saved['pachs_leaves']))])
      stop = np.asarray(got.stop_reason)
      kept = stop != int(StopReason.INTERRUPTED)
      assert 0 < kept.sum() < 6 and np.all(np.asarray(want.stop_reason)[~kept] != stop[~kept])
      for a, b in zip(jax.tree.leaves(got.replace(wall_time_s=None)), jax.tree.leaves(want)):
        assert np.array_equal(np.asarray(a)[kept], np.asarray(b)[kept])

    def session_over_the_mesh():
      # a replanning session (and a server) whose search splits its episodes over the devices
      # answers as the one-device session does
      import dataclasses
      import types
      from pachs_jax import replan, serve
      from pachs_jax.runtime import programs
      policy = GreedyActor(ENV)
      plain = replan.Session(ENV, policy, CONFIG, programs.Programs(SEARCH))
      split = replan.Session(ENV, policy, CONFIG, programs.Programs(SEARCH), mesh=mesh)
      fields = ('actions', 'length', 'kind', 'cost', 'reaches_goal')
      want = plain.plan(NODES, key=key)
      got = split.plan(NODES, key=key)
      for name in fields:
        assert np.array_equal(np.asarray(getattr(want, name)), np.asarray(getattr(got, name))), name
      later = split.plan(NODES, executed=np.full(6, 2), key=key, time_limit_s=5.0)
      assert later.actions.shape[0] == 6 and np.all(np.asarray(later.length) >= 0)
      # with chain lanes each session builds its own search and replays the last answer's
      # remainder in it, split over the devices as on one
      chains = dataclasses.replace(CONFIG, rollout_share=0.5)
      replaying = [replan.Session(ENV, policy, chains, horizon=16, mesh=m) for m in (None, mesh)]
      assert all(r.replay_remainder for r in replaying)
      for r in replaying:
        r.plan(NODES, key=key)
      want, got = [r.plan(NODES, executed=np.full(6, 1), key=key) for r in replaying]
      assert np.asarray(want.length).max() > 0
      for name in fields:
        assert np.array_equal(np.asarray(getattr(want, name)), np.asarray(getattr(got, name))), name
      task = types.SimpleNamespace(env=ENV, model=policy, config=CONFIG,
                                   search=programs.Programs(SEARCH))
      try:
        serve.Server({'grid': task}, serve.ServeConfig(devices=8))
        raise AssertionError('8 devices on a host of 4 were taken')
      except ValueError as err:
        assert 'this host has 4 cpu device(s)' in str(err), err
      server = serve.Server({'grid': task}, serve.ServeConfig(devices=2, max_batch=8,
                                                              buckets=(8,)))
      assert server.health()['devices'] == 2
      states = {k: np.asarray(getattr(NODES, k)) for k in server.tasks['grid'].fields}
      keys = np.asarray(jax.random.split(key, 6))
      answer = server._answer(server.tasks['grid'], [(states, None, None, None)], keys, None, 8)
      reference = plain.answer(NODES, jax.numpy.zeros((6, plain.horizon, 2)),
                               jax.numpy.zeros(6, jax.numpy.int32), keys, None, 8)
      for name in fields:
        assert np.array_equal(answer[name], np.asarray(getattr(reference, name))), name
      # split 'threads': 6 episodes in parts of 2, 2, 1 and 1 (each padded to 8 / 4), one per
      # device at once, each searched by its own one-device session, answer as one device does
      threaded = serve.Server({'grid': task}, serve.ServeConfig(devices=4, split='threads',
                                                                max_batch=8, buckets=(8,)))
      assert threaded.health()['split'] == 'threads' and threaded.mesh is None
      threaded.warm()  # each device's part of the bucket compiled on its device
      assert threaded.tasks['grid'].warm_buckets == (8,)
      answer = threaded._answer(threaded.tasks['grid'], [(states, None, None, None)], keys,
                                None, 8)
      for name in fields:
        assert np.array_equal(answer[name], np.asarray(getattr(reference, name))), name
      # each part's arrays are committed to its device, so that a program of its session
      # compiled for another device (in a helper thread, say) raises instead of copying: the
      # equal answers above say every program ran on its part's device; the follows' devices
      used = [sorted({d.id for c in s._compiled.values() for x in c.input_shardings[0]
                      for d in jax.tree.leaves(x)[0].device_set})
              for s in threaded.tasks['grid'].device_sessions]
      assert used == [[0], [1], [2], [3]], used
      # three devices for a batch of 8: parts of 3, 3 and 2, each padded to ceil(8 / 3)
      three = serve.Server({'grid': task}, serve.ServeConfig(devices=3, split='threads',
                                                             max_batch=8, buckets=(8,)))
      answer = three._answer(three.tasks['grid'], [(states, None, None, None)], keys, None, 8)
      for name in fields:
        assert np.array_equal(answer[name], np.asarray(getattr(reference, name))), name

    checks = {'pachs': lambda: same('pachs', sharding.plan_sharded(
        ENV, AC, NODES, CONFIG, key, mesh=mesh, search=SEARCH)),
              'pachs_chunked': lambda: same('pachs', sharding.plan_sharded(
                  ENV, AC, NODES, CONFIG, key, mesh=mesh, search=SEARCH, stop=lambda: False)),
              'pachs_stopped': stopped_after_a_chunk, 'session': session_over_the_mesh}
    for name, (shard_fn, _) in baselines().items():
      checks[name] = (lambda n, s: lambda: same(n, sharding.plan_sharded_fn(s, NODES, key,
                                                                            mesh)))(name, shard_fn)
    for name, check in checks.items():
      try:
        check()
        print(f'{name.upper()}_OK', flush=True)
      except Exception:  # pylint: disable=broad-except
        print(f'{name.upper()}_FAILED', traceback.format_exc(), flush=True)
''')
@pytest.fixture(scope='module')
def search():
  return make_search(ENV, AC, CONFIG)


@pytest.fixture(scope='module')
def baselines():
  return _scope['baselines']()


@pytest.fixture(scope='module')
def references(tmp_path_factory, search, baselines):
  """(the unsharded results of PACHS and each baseline with PRNGKey(REFERENCE_KEY), by name;
  a .npz file of their arrays for the subprocesses: NAME_leaves, NAME_0, NAME_1, ...)."""
  key = jax.random.PRNGKey(REFERENCE_KEY)
  results = {'pachs': plan(ENV, AC, NODES, CONFIG, key, search=search)}
  results.update((name, unsharded(NODES, key)) for name, (_, unsharded) in baselines.items())
  arrays = {}
  for name, result in results.items():
    leaves = result_leaves(result)
    arrays[name + '_leaves'] = np.asarray(len(leaves))
    arrays.update((f'{name}_{i}', leaf) for i, leaf in enumerate(leaves))
  path = tmp_path_factory.mktemp('sharding') / 'references.npz'
  np.savez(path, **arrays)
  return results, str(path)


@pytest.fixture(scope='module')
def four_devices(compilation_cache_dir, references):
  """stdout of the 4-device script (run once for the module), which compiles with the test
  run's persistent cache."""
  env = jax_cache_env(compilation_cache_dir,
                      XLA_FLAGS='--xla_force_host_platform_device_count=4', JAX_PLATFORMS='cpu')
  proc = subprocess.run([sys.executable, '-c', FOUR_DEVICES, references[1]], env=env,
                        capture_output=True, text=True, timeout=600)
  assert proc.returncode == 0, proc.stderr[-4000:]
  return proc.stdout


@pytest.mark.parametrize('name', ('pachs', 'pachs_chunked', 'pachs_stopped', 'session')
                         + BASELINES)
def test_four_devices_equal_unsharded(four_devices, name):
  assert f'{name.upper()}_OK' in four_devices, four_devices[-4000:]


def test_default_mesh_equals_plan(search, references):
  key = jax.random.PRNGKey(REFERENCE_KEY)
  want = references[0]['pachs']
  got = sharding.plan_sharded(ENV, AC, NODES, CONFIG, key, search=search)
  assert np.asarray(want.found).sum() >= 4  # most instances finish with real paths
  assert (np.asarray(want.path_length) > 0).sum() >= 4
  assert_results_equal(got, want)
  # The keys matter (so equal results also check that each instance got its own key).
  other = plan(ENV, AC, NODES, CONFIG, jax.random.PRNGKey(8), search=search)
  assert any(not np.array_equal(w, o) for w, o in zip(result_leaves(want), result_leaves(other)))
  assert got.found.shape == (NODES.qpos.shape[0],)
  assert np.isfinite(got.wall_time_s) and got.wall_time_s > 0


@pytest.mark.parametrize('name', BASELINES)
def test_baseline_default_mesh_equals_unsharded(baselines, references, name):
  shard_fn, unsharded = baselines[name]
  key = jax.random.PRNGKey(REFERENCE_KEY)
  want = references[0][name]
  got = sharding.plan_sharded_fn(shard_fn, NODES, key)
  assert got.found.shape == (NODES.qpos.shape[0],)
  assert np.isfinite(got.wall_time_s) and got.wall_time_s > 0
  assert_results_equal(got, want)
  if name in ('rollout', 'beam'):  # random proposals: each instance must get its own key
    other = unsharded(NODES, jax.random.PRNGKey(6))
    assert any(not np.array_equal(w, o) for w, o in zip(result_leaves(want), result_leaves(other)))
  # per-instance keys [I, 2] are taken as they are
  keys = jax.random.split(key, NODES.qpos.shape[0])
  again = sharding.plan_sharded_fn(shard_fn, NODES, keys)
  assert_results_equal(again, want)


def test_initialize_multihost_needs_a_job(monkeypatch):
  for name in ('JAX_COORDINATOR_ADDRESS', 'SLURM_NTASKS', 'OMPI_COMM_WORLD_SIZE'):
    monkeypatch.delenv(name, raising=False)
  assert sharding.initialize_multihost() is False  # a single process: nothing to join
  monkeypatch.setenv('SLURM_NTASKS', '1')
  monkeypatch.setenv('SLURM_PROCID', '0')
  assert sharding.initialize_multihost() is False  # one task is no multi-process job
  assert sharding.to_host({'a': 1}) == {'a': 1}


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
    other = SearchConfig(weight=1.0, num_actions=8, pop_size=2, budget=400)
    sharding.plan_sharded(ENV, AC, NODES, other, key, search=search)


# Two processes ("hosts") of 2 CPU devices each, joined by `initialize_multihost` through the
# JAX_COORDINATOR_ADDRESS variables: 6 instances over the 4 global devices (padded to 8), the
# result gathered whole on every process, equal field by field to the unsharded plan this
# process saved (`references`).
TWO_HOSTS = textwrap.dedent('''
    from pachs_jax.runtime import sharding as _sharding
    assert _sharding.initialize_multihost(), 'the job was not joined'
''') + SETUP + textwrap.dedent('''
    import sys
    from pachs_jax.search import make_search
    assert jax.process_count() == 2 and len(jax.devices()) == 4, jax.devices()
    assert len(jax.local_devices()) == 2
    key = jax.random.PRNGKey(REFERENCE_KEY)
    got = sharding.plan_sharded(ENV, AC, NODES, CONFIG, key, mesh=sharding.instance_mesh(),
                                search=make_search(ENV, AC, CONFIG))
    assert np.asarray(got.found).shape == (6,) and np.asarray(got.found).sum() >= 4
    assert_matches_reference('pachs', got, sys.argv[1])
    print(f'PROCESS{jax.process_index()}_OK', flush=True)
''')


def _run_two_processes(tmp_path, port, cache_dir, references):
  """(return code, output) of each of the two processes joined at 127.0.0.1:port, compiling
  with the persistent cache at cache_dir (None: none), comparing with the .npz references."""
  procs = []
  for i in range(2):
    env = jax_cache_env(cache_dir, XLA_FLAGS='--xla_force_host_platform_device_count=2',
                        JAX_PLATFORMS='cpu', JAX_COORDINATOR_ADDRESS=f'127.0.0.1:{port}',
                        JAX_NUM_PROCESSES='2', JAX_PROCESS_ID=str(i))
    log = open(tmp_path / f'process{i}_{port}.log', 'w+')  # files: no pipe can fill and stall
    procs.append((subprocess.Popen([sys.executable, '-c', TWO_HOSTS, references], env=env,
                                   text=True, stdout=log, stderr=subprocess.STDOUT), log))
  deadline = time.monotonic() + 600
  results = []
  try:
    for proc, log in procs:
      try:
        code = proc.wait(timeout=max(1.0, deadline - time.monotonic()))
      except subprocess.TimeoutExpired:
        code = None
      log.seek(0)
      results.append((code, log.read()))
  finally:
    for proc, log in procs:
      proc.kill()
      log.close()
  return results


def test_two_processes_equal_unsharded(tmp_path, compilation_cache_dir, references):
  for attempt in range(2):  # a second port if another program took the first one meanwhile
    with socket.socket() as s:
      s.bind(('127.0.0.1', 0))
      port = s.getsockname()[1]
    results = _run_two_processes(tmp_path, port, compilation_cache_dir, references[1])
    if attempt == 0 and any('address already in use' in out.lower() for _, out in results):
      continue
    break
  for i, (code, out) in enumerate(results):
    assert code == 0 and f'PROCESS{i}_OK' in out, f'process {i}, exit {code}:\n{out[-4000:]}'
