"""The resident planner (`serve`, `client`, `wire`, `pachs serve`): a real server on localhost
with real clients, on the point mass (a server in a thread, shared by the file) and on PushT
(`pachs serve` in a subprocess, for SIGTERM)."""

import argparse
import dataclasses
import re
import signal
import subprocess
import sys
import threading
import time

import jax
import jax.numpy as jnp
import msgpack
import numpy as np
import pytest
import closed_loop
from conftest import UniformActorCritic
from websockets.sync.client import connect

from pachs_jax import cli, client, replan, serve, wire
from pachs_jax.runtime import programs
from pachs_jax.envs.point_mass import PointMassEnv
from pachs_jax.search import SearchConfig, pachs

TASK = 'point-mass'
MAX_BATCH = 4


class TowardGoal(UniformActorCritic):
  """The policy steps straight at the goal (obs[:, 2:] = goal - position)."""

  def deterministic_action(self, obs):
    away = obs[:, 2:]
    return away / jnp.maximum(jnp.linalg.norm(away, axis=1, keepdims=True), 1e-6)


@dataclasses.dataclass
class PointMassPlanner:
  """What a server needs of a planner: env, model, config and the search's programs."""

  env: object
  model: object
  config: SearchConfig
  search: programs.Programs


@pytest.fixture(scope='module')
def planner():
  env, model = PointMassEnv(), TowardGoal(2)
  config = SearchConfig(weight=1.0, pop_size=4, num_actions=4, budget=64)
  return PointMassPlanner(env, model, config,
                          programs.Programs(pachs.make_search(env, model, config)))


@pytest.fixture(scope='module')
def server(planner):
  """A warm server on localhost (one bucket of 4 episodes; a 0.1 s gathering window so that
  the test's threads reach one batch)."""
  built = serve.Server({TASK: planner}, serve.ServeConfig(
      window_s=0.1, max_batch=MAX_BATCH, buckets=(MAX_BATCH,), max_time_limit_s=5.0))
  built.warm()
  with serve.Running(built) as running:
    yield running


def _starts(planner, num, seed=3):
  return jax.jit(planner.env.initial_nodes)(jax.random.split(jax.random.PRNGKey(seed), num))


def _reference(planner, states, seeds_executed):
  """The in-process answers of a session asked in turn with (seed, executed)."""
  session = replan.Session(planner.env, planner.model, planner.config, planner.search)
  return [jax.tree.map(np.asarray, session.plan(states, executed, key=jax.random.PRNGKey(seed)))
          for seed, executed in seeds_executed]


def _same(answer, reference):
  np.testing.assert_array_equal(answer.actions, reference.actions)
  for field in ('length', 'kind', 'reaches_goal', 'cost'):
    np.testing.assert_array_equal(getattr(answer, field), getattr(reference, field))


def test_health_says_what_is_loaded_and_warm(server):
  with client.Client(server.url) as asking:
    health = asking.health()
    assert asking.task == TASK
  assert health['ready'] and health['tasks'][TASK]['warm']
  assert health['tasks'][TASK]['warm_buckets'] == [MAX_BATCH]
  assert health['tasks'][TASK]['budget'] == 64
  assert health['tasks'][TASK]['node_fields']['qpos'] == {'shape': [2], 'dtype': 'float32'}
  assert health['buckets'] == [MAX_BATCH] and health['max_batch'] == MAX_BATCH
  assert server.url.startswith('ws://127.0.0.1:')  # localhost unless told otherwise


def test_an_answer_through_the_server_is_the_librarys_and_keeps_the_session(server, planner):
  states = _starts(planner, 2)
  want = _reference(planner, states, [(7, None), (8, [3, replan.DIVERGED])])
  with client.Client(server.url) as asking:
    first = asking.plan(states, seed=7)
    _same(first, want[0])
    np.testing.assert_array_equal(first.search['path_length'], want[0].search.path_length)
    # per-episode keys instead of a seed: the same keys, the same answer
    keyed = asking.plan(states, keys=jax.random.split(jax.random.PRNGKey(7), 2), reset=True)
    _same(keyed, want[0])
    # the next query starts from the session's last answer: its remainder after 3 actions
    _same(asking.plan(states, executed=[3, client.DIVERGED], seed=8), want[1])
    assert first.batch == {'requests': 1, 'episodes': 2, 'bucket': MAX_BATCH}


def test_a_server_answers_from_its_largest_bucket_and_warms_the_others_while_idle(planner):
  states = _starts(planner, 1, seed=13)
  want = _reference(planner, states, [(5, None)])[0]
  for idle in (False, True):
    built = serve.Server({TASK: planner}, serve.ServeConfig(
        max_batch=MAX_BATCH, buckets=(1, MAX_BATCH), max_time_limit_s=5.0,
        warm_idle_s=0.05 if idle else None))
    built.warm(every=False)
    health = built.health()  # ready once the largest bucket, which holds any batch, is warm
    assert health['ready'] and health['tasks'][TASK]['warm_buckets'] == [MAX_BATCH]
    with serve.Running(built) as running, client.Client(running.url) as asking:
      if idle:  # the planning thread warms bucket 1 once no request came for warm_idle_s
        deadline = time.time() + 120
        while asking.health()['tasks'][TASK]['warm_buckets'] != [1, MAX_BATCH]:
          assert time.time() < deadline, 'bucket 1 never warmed while idle'
          time.sleep(0.05)
      answer = asking.plan(states, seed=5)
      # a cold bucket is not compiled for a request while a warm one holds it
      assert answer.batch['bucket'] == (1 if idle else MAX_BATCH)
      _same(answer, want)  # the answer does not depend on its bucket
      assert asking.health()['tasks'][TASK]['warm_buckets'] == (
          [1, MAX_BATCH] if idle else [MAX_BATCH])


def test_a_server_with_fill_steps_answers_how_far_the_policy_may_fill_as_the_library_does(
    server, planner):
  states = _starts(planner, 3, seed=17)
  session = replan.Session(planner.env, planner.model, planner.config, planner.search,
                           fill_steps=10)
  want = jax.tree.map(np.asarray, session.plan(states, key=jax.random.PRNGKey(5)))
  assert np.any(want.length < 10)  # a budget of 64: short answers, whose fill is followed
  built = serve.Server({TASK: planner}, serve.ServeConfig(
      max_batch=MAX_BATCH, buckets=(MAX_BATCH,), max_time_limit_s=5.0, fill_steps=10))
  built.warm()
  assert built.health()['tasks'][TASK]['fill_steps'] == 10
  with serve.Running(built) as running, client.Client(running.url) as asking:
    answer = asking.plan(states, seed=5)
    # closed_loop.py --server executes the server's fill lengths (episodes.run reads them)
    args = argparse.Namespace(server=running.url, budget=64, pop_size=None, execute=10,
                              query_time=None)
    query, _ = closed_loop.served_query(TASK, args, 3)
    asked = query(states, jax.random.split(jax.random.PRNGKey(5), 3), np.zeros(3, np.int32),
                  np.ones(3, bool), None)
    np.testing.assert_array_equal(asked.fill_length, want.fill_length)
  _same(answer, want)
  np.testing.assert_array_equal(answer.fill_length, want.fill_length)
  assert np.all(answer.fill_length == 10 - np.minimum(want.length, 10))  # no edge invalid here
  with client.Client(server.url) as asking:  # a server without fill steps follows no fill
    assert asking.plan(states, seed=5).fill_length is None


def test_a_window_that_restarts_gathers_a_burst_of_requests_whole(planner):
  """Four one-episode requests 0.2 s apart: a 0.3 s window from the first holds two of them;
  restarting at each request (max_wait_s), it holds all four."""
  states = _starts(planner, 4, seed=17)
  for max_wait in (None, 5.0):
    built = serve.Server({TASK: planner}, serve.ServeConfig(
        window_s=0.3, max_wait_s=max_wait, max_batch=MAX_BATCH, buckets=(MAX_BATCH,),
        max_time_limit_s=5.0))
    built.warm()
    sizes = [None] * 4
    with serve.Running(built) as running:
      asking = [client.Client(running.url) for _ in range(4)]
      go = threading.Barrier(4)

      def ask(i):
        go.wait()
        time.sleep(0.2 * i)
        sizes[i] = asking[i].plan(jax.tree.map(lambda x: x[i:i + 1], states),
                                  seed=i).batch['requests']
      threads = [threading.Thread(target=ask, args=(i,)) for i in range(4)]
      for t in threads:
        t.start()
      for t in threads:
        t.join()
      for c in asking:
        c.close()
    assert sizes[0] == (2 if max_wait is None else 4), sizes


def test_bad_idle_warm_up_split_and_wait_settings_are_named():
  for bad in (-1.0, float('nan'), True, '2'):
    with pytest.raises(ValueError, match='warm_idle_s must be a finite number of seconds'):
      serve.ServeConfig(warm_idle_s=bad)
  for bad in (-1, True, 2.0):
    with pytest.raises(ValueError, match='fill_steps must be an int >= 0'):
      serve.ServeConfig(fill_steps=bad)
  with pytest.raises(ValueError, match="split must be one of mesh, threads, got 'shards'"):
    serve.ServeConfig(split='shards')
  with pytest.raises(ValueError, match='max_wait_s must be None or a finite number of seconds '
                     '>= window_s 0.005, got 0.001'):
    serve.ServeConfig(max_wait_s=0.001)


def test_concurrent_clients_are_planned_in_one_search_and_get_their_own_answers(server, planner):
  states = _starts(planner, MAX_BATCH, seed=11)
  one = lambda i: jax.tree.map(lambda x: x[i:i + 1], states)
  want = [_reference(planner, one(i), [(i, None)])[0] for i in range(MAX_BATCH)]
  with client.Client(server.url) as asking:
    before = asking.health()['counters']
  clients = [client.Client(server.url) for _ in range(MAX_BATCH)]
  answers, go = {}, threading.Barrier(MAX_BATCH)

  def ask(i):
    go.wait()
    answers[i] = clients[i].plan(one(i), seed=i)
  threads = [threading.Thread(target=ask, args=(i,)) for i in range(MAX_BATCH)]
  for t in threads:
    t.start()
  for t in threads:
    t.join()
  for i in range(MAX_BATCH):
    _same(answers[i], want[i])
    clients[i].close()
  with client.Client(server.url) as asking:
    after = asking.health()['counters']
  assert after['requests'] - before.get('requests', 0) == MAX_BATCH
  searches = after['searches'] - before.get('searches', 0)
  assert searches < MAX_BATCH  # batched: fewer search calls than requests
  assert max(a.batch['requests'] for a in answers.values()) > 1


def _raw(url, message):
  """The server's response to one raw message (bytes, or text)."""
  with connect(url) as connection:
    connection.send(message)
    return wire.unpack(connection.recv(timeout=60))


def test_bad_requests_get_one_line_errors_and_the_server_keeps_serving(server, planner):
  good = client.node_fields(_starts(planner, 1))
  plan = lambda **fields: wire.pack(dict({'type': 'plan', 'task': TASK, 'states': good}, **fields))
  bad_states = lambda field, value: plan(states=dict(good, **{field: value}))
  evil = msgpack.packb({'type': 'plan', 'task': TASK, 'states': dict(good, qpos={
      '__ndarray__': True, 'dtype': 'object', 'shape': [1, 2], 'data': b'\0' * 16})},
                       default=wire._encode)  # pylint: disable=protected-access
  cases = [
      (plan(task='pusht-obs'), "task 'pusht-obs' is not loaded here"),
      (bad_states('qpos', np.zeros((1, 3), np.float32)), 'states.qpos has shape [1, 3]'),
      (bad_states('qpos', np.zeros((1, 2), np.int32)), 'states.qpos has dtype int32'),
      (bad_states('goal', np.full((1, 2), np.nan, np.float32)), 'NaN or infinite'),
      (bad_states('qvel', np.full((1, 2), np.inf)), 'NaN or infinite'),
      (plan(states={'qpos': good['qpos']}), 'states must map the NodeState fields'),
      (plan(states={k: np.repeat(v, 5, 0) for k, v in good.items()}), '1 to 4 episodes'),
      (plan(time_limit_s=50.0), 'exceeds the server\'s 5.0 s'),
      (plan(budget=10**6), 'plans point-mass at 64 evaluations'),
      (plan(executed=[1, 2]), 'executed must hold 1 integer counts'),
      (plan(instances=[0]), 'give either states'),
      (plan(seed='x'), 'seed must be a 64-bit integer'),
      (plan(speed=3), "unknown request field 'speed'"),
      (wire.pack({'type': 'shutdown'}), "unknown request type 'shutdown'"),
      (b'\xc1not msgpack', 'not a msgpack message'),
      ('a text frame', 'binary msgpack'),
      (evil, "array dtype 'object' is not allowed"),
  ]
  for message, error in cases:
    response = _raw(server.url, message)
    assert response['ok'] is False and not response['busy']
    assert error in response['error'] and '\n' not in response['error'], response['error']
  with client.Client(server.url) as asking:
    assert asking.plan(good).length.shape == (1,)
    with pytest.raises(client.ServerError, match='not loaded here'):
      asking.plan(good, task='shelf')


def test_a_warm_server_compiles_nothing_for_any_episode_count(server, planner, caplog):
  every = jax.tree.map(np.asarray, _starts(planner, MAX_BATCH, seed=5))  # no program per count
  starts = [jax.tree.map(lambda x, n=num: x[:n], every) for num in range(1, MAX_BATCH + 1)]
  with client.Client(server.url) as asking:
    asking.plan(starts[0], seed=0, reset=True)  # the client's own first calls
    jax.config.update('jax_log_compiles', True)  # for every thread: the server plans in its own
    try:
      with caplog.at_level('WARNING'):
        for num, states in enumerate(starts, 1):
          answer = asking.plan(states, seed=num, reset=True)
          assert answer.actions.shape[0] == num
    finally:
      jax.config.update('jax_log_compiles', False)
  compiled = [r.getMessage() for r in caplog.records if 'ompil' in r.getMessage()]
  assert not compiled, compiled


def test_a_client_gone_mid_request_costs_nothing_else(server, planner):
  states = client.node_fields(_starts(planner, 1))
  with client.Client(server.url) as asking:
    before = asking.health()
  with connect(server.url) as connection:  # asks, then leaves before the answer
    connection.send(wire.pack({'type': 'plan', 'task': TASK, 'session': 'gone', 'states': states}))
  with client.Client(server.url) as asking:
    assert asking.plan(states).length.shape == (1,)
    deadline = time.time() + 10
    while asking.health()['queued'] and time.time() < deadline:
      time.sleep(0.05)
    after = asking.health()
  assert after['counters']['requests'] - before['counters']['requests'] == 2
  assert after['counters']['answered'] - before['counters']['answered'] == 1
  assert after['sessions'] == before['sessions'] + 1  # the gone client's answer is not kept


def test_a_full_queue_answers_busy_at_once(server, planner):
  states = _starts(planner, 1)
  full = dataclasses.replace(server.server.config, max_queue=1)
  kept, server.server.config = server.server.config, full
  try:
    first = {}
    with client.Client(server.url) as waiting, client.Client(server.url) as busy:
      thread = threading.Thread(target=lambda: first.update(a=waiting.plan(states)))
      thread.start()
      deadline = time.time() + 5
      while not server.server.health()['queued'] and time.time() < deadline:
        time.sleep(0.001)
      began = time.perf_counter()
      with pytest.raises(client.ServerError, match='busy') as refused:
        busy.plan(states)
      assert refused.value.busy and time.perf_counter() - began < 0.1
      thread.join()
      assert first['a'].length.shape == (1,)
  finally:
    server.server.config = kept


def test_wire_arrays_round_trip_and_refuse_what_is_not_allowed():
  arrays = {'f': np.arange(6, dtype=np.float32).reshape(2, 3), 'i': np.array([1, -2], np.int64),
            'b': np.array([True, False]), 'big': np.arange(3, dtype='>f8')}
  back = wire.unpack(wire.pack(dict(arrays, n=np.int32(3), text='x')))
  for name, array in arrays.items():
    np.testing.assert_array_equal(back[name], array)
  assert back['n'] == 3 and back['text'] == 'x'
  with pytest.raises(wire.WireError, match='complex128 do not travel'):
    wire.pack({'z': np.zeros(2, complex)})
  short = msgpack.packb({'a': {'__ndarray__': True, 'dtype': 'float32', 'shape': [4],
                               'data': b'\0' * 8}})
  with pytest.raises(wire.WireError, match='needs 16 bytes, got 8'):
    wire.unpack(short)
  with pytest.raises(wire.WireError, match='must be a map'):
    wire.unpack(msgpack.packb([1, 2]))


def test_pachs_serve_refuses_bad_flags_in_one_line(capsys):
  for argv, message in ((['--task', 'nope'], "invalid choice: 'nope'"),
                        (['--max-batch', '0'], '--max-batch: must be a positive integer'),
                        (['--port', '70000'], '--port must be in 0..65535'),
                        (['--task', 'shelf', '--layout', 'wall'], '--layout applies to'),
                        (['--buckets', '3,16'], 'buckets must be powers of two'),
                        (['--buckets', '1,x'], "--buckets '1,x': comma-separated"),
                        (['-K', '0'], 'argument --pop-size/-K: must be a positive integer'),
                        (['--query-time', '0'], '--query-time: must be a positive number'),
                        (['--fill-steps', '-1'], '--fill-steps: must be >= 0, got -1')):
    with pytest.raises(SystemExit) as exit_info:
      cli.main(['serve'] + argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert message in err and err.count('\n') == 1


@dataclasses.dataclass
class CanonicalPlanner(PointMassPlanner):
  """A planner with 6 canonical instances, counting the calls of `canonical`."""

  num_instances: int = 6
  calls: int = 0

  def canonical(self, indices):
    self.calls += 1
    return jax.tree.map(lambda x: x[np.asarray(indices)], _starts(self, self.num_instances, 11))


def test_instance_requests_are_the_canonical_states_taken_on_the_host(planner):
  with_instances = CanonicalPlanner(planner.env, planner.model, planner.config, planner.search)
  built = serve.Server({TASK: with_instances}, serve.ServeConfig(
      max_batch=MAX_BATCH, buckets=(MAX_BATCH,), max_time_limit_s=5.0))
  built.warm()
  # every instance is fetched once, at start-up: a request's thread runs no JAX, which beside
  # the planning thread's can crash a GPU process inside MuJoCo Warp's callbacks
  assert with_instances.calls == 1
  states = with_instances.canonical([4, 1])
  with serve.Running(built) as running, client.Client(running.url) as asking:
    assert asking.health()['tasks'][TASK]['instances']
    by_index = asking.plan(instances=[4, 1], seed=3)
    _same(by_index, asking.plan(states, seed=3, reset=True))
    with pytest.raises(client.ServerError, match=r'instances must lie in 0\.\.5, got 6'):
      asking.plan(instances=[6])
    # an array of instances beyond the batch is refused as a list is; the server keeps serving
    response = _raw(running.url, wire.pack({'type': 'plan', 'task': TASK,
                                            'instances': np.arange(5)}))
    assert not response['ok'] and "5 episodes exceed the server's 4" in response['error']
    _same(asking.plan(instances=[4, 1], seed=3, reset=True), by_index)
  assert with_instances.calls == 2  # the test's own call only


def test_sigterm_answers_the_request_in_flight_and_exits_0():
  process = subprocess.Popen(
      [sys.executable, '-m', 'pachs_jax.cli', 'serve', '--task', 'pusht-obs', '--budget', '20000',
       '--max-batch', '1', '--port', '0'], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
      text=True)
  try:
    line = process.stdout.readline()
    assert 'ready on ws://127.0.0.1:' in line, process.stderr.read()
    url = re.search(r'ws://\S+', line).group(0)
    answered = {}
    with client.Client(url) as asking:
      assert asking.health()['tasks']['pusht-obs']['warm']
      thread = threading.Thread(target=lambda: answered.update(
          a=asking.plan(instances=[0], time_limit_s=1.5)))
      thread.start()
      time.sleep(0.5)  # the request is being planned (1.5 s of a 20,000-evaluation search)
      process.send_signal(signal.SIGTERM)
      thread.join(30)
    assert answered['a'].length.shape == (1,)
    assert process.wait(30) == 0
    assert 'Traceback' not in process.stderr.read()
  finally:
    if process.poll() is None:
      process.kill()
