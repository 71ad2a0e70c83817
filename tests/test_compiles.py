"""Programs compiled by `programs.plan` (issue 15): the search compiles a few whole programs, never
one program per array operation, and a second call of the same shapes compiles nothing."""

import threading

import jax
import numpy as np
import pytest

from pachs_jax.runtime import compile_cache
from pachs_jax.envs import gridworld
from pachs_jax.search import SearchConfig, make_search
from pachs_jax.runtime.programs import Programs, plan

OBSTACLES = np.zeros((8, 8), bool)
OBSTACLES[1:7, 4] = True
STARTS = np.array([[3, 1], [0, 0], [7, 7]])
GOALS = np.array([[3, 7], [7, 7], [0, 0]])
CONFIG = SearchConfig(weight=1.0, num_actions=8, pop_size=4, budget=400,
                      compact_fractions=(0.5,))


@pytest.fixture(scope='module')
def grid():
  env = gridworld.GridWorld(OBSTACLES, connectivity=8)
  return env, gridworld.GridActorCritic(env), env.node(STARTS, GOALS)


def test_plan_compiles_whole_programs_once(grid):
  env, ac, nodes = grid
  search = Programs(make_search(env, ac, CONFIG))
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


def test_prefetch_loads_what_the_command_line_used_last_time(tmp_path, monkeypatch):
  # A command line's stored executables are listed in its index when it finishes; the next
  # process with the same words loads them in the prefetch thread and `compiled_program` takes
  # them from there. (The CPU stores no executables: they are faked here by name.)
  monkeypatch.setenv(compile_cache.ENV_VAR, str(tmp_path))
  previous = jax.config.jax_compilation_cache_dir
  jax.config.update('jax_compilation_cache_dir', str(tmp_path))
  compiled, parsed = {}, []
  real = compile_cache._compile_trace

  def compile_and_store(exported, out_def, args, specs, donate_argnums, path):
    out = real(exported, out_def, args, specs, donate_argnums, path)
    compiled[path + '.executable'] = out
    with open(path + '.executable', 'w') as f:
      f.write(path + '.executable')
    return out

  def load(blob):
    parsed.append((blob.decode(), threading.current_thread().name))
    return compiled[blob.decode()]

  monkeypatch.setattr(compile_cache, '_compile_trace', compile_and_store)
  monkeypatch.setattr(compile_cache, '_executable', load)
  double = jax.jit(lambda x: 2 * x)
  x = np.arange(3.0, dtype=np.float32)
  words = ['plan', '--task', 'grid']
  index = compile_cache.command_index(words)
  assert index != compile_cache.command_index(words + ['--weight', '2'])
  try:
    prefetch = compile_cache.Prefetch(index)
    prefetch.load()  # no index yet: nothing to load
    assert prefetch.last_ready_s() is None
    np.testing.assert_allclose(
        compile_cache.compiled_program(double, (x,), 'double', prefetch=prefetch)(x), 2 * x)
    prefetch.ready_s = 12.5  # the command's time to its search, for the next run's note
    prefetch.finish()
    assert compile_cache.Prefetch(index).last_ready_s() == 12.5
    with open(index) as f:
      listed = f.read().split()
    assert listed == list(compiled) and parsed == []
    prefetch = compile_cache.Prefetch(index)
    thread = threading.Thread(target=prefetch.load, name='prefetch')
    thread.start()
    thread.join()
    program = compile_cache.compiled_program(double, (x,), 'double', prefetch=prefetch)
    np.testing.assert_allclose(program(x), 2 * x)
    assert parsed == [(listed[0], 'prefetch')]  # loaded once, in the prefetch thread
    prefetch.finish()
  finally:
    prefetch.finish()
    jax.config.update('jax_compilation_cache_dir', previous)


def test_the_loop_writes_the_lattice_table_the_heaps_and_the_pools_costs_in_place(grid):
  # XLA copies a loop-carried buffer that an iteration reads after (or unordered with) its
  # in-place write: at a large budget that copy, not the search, was most of an iteration
  env, ac, nodes = grid
  search = make_search(env, ac, SearchConfig(weight=1.0, num_actions=8, pop_size=4,
                                             budget=20_000))
  state = search.init(nodes, jax.random.split(jax.random.PRNGKey(0), len(STARTS)))
  text = search.loop.lower(state, 2).compile().as_text()
  in_loop, computation = [], None  # the copies outside the entry computation (the loop's)
  for line in text.splitlines():
    if line and not line.startswith(' ') and line.rstrip().endswith('{'):
      computation = line.split()[0]
    elif computation != 'ENTRY' and ' copy(' in line:
      in_loop.append(line)
  shapes = {'lattice table keys': state.table.keys.shape, 'edge heap keys':
            state.edge_heap.keys.shape, 'dummy heap keys': state.dummy_heap.keys.shape,
            "pool's costs": state.pool.g.shape}
  for name, shape in shapes.items():
    dims = '[' + ','.join(map(str, shape)) + ']'
    copied = [line.strip() for line in in_loop if dims in line]
    assert not copied, f'the {name} {dims} are copied in the loop: {copied[:2]}'
