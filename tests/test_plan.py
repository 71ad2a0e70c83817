"""The `pachs plan` command end to end on the CPU, with small budgets, and its input errors."""

import importlib.util
import json
import os
import subprocess
import sys

import pytest

from pachs_jax import cli, planner
from pachs_jax.envs import registry


def test_sharded_plan_runs_end_to_end(tmp_path):
  # 'all' shards over every device, here the one CPU device (MuJoCo C physics in shard_map).
  out = tmp_path / 'rows.json'
  code = cli.main(['plan', '--task', 'pusht-fixed', '--instances', '0,3', '--budget', '16',
                   '-K', '4', '-N', '4', '--devices', 'all', '--json', str(out)])
  assert code == 0
  saved = json.loads(out.read_text())
  assert saved['devices'] == 1 and [r['instance'] for r in saved['rows']] == [0, 3]
  # 16 evaluations are far fewer than a PushT goal needs (about 100 above): both instances
  # spend the whole budget and return their best partial path
  for r in saved['rows']:
    assert (r['stop'], r['found'], r['evaluated']) == ('budget', False, 16), r
    assert r['path_length'] >= 1 and r['cost'] > 0, r


@pytest.mark.parametrize('argv, message', [
    (['plan', '--devices', '2'], '--devices 2 exceeds the 1 device(s) available'),
    (['plan', '--devices', 'all', '--time-limit', '1'], 'not supported with sharding'),
    (['plan', '--devices', '0'], "must be 'all' or a positive integer"),
    (['plan', '--devices', 'two'], "must be 'all' or a positive integer"),
])
def test_bad_devices_give_clear_errors(argv, message, capsys):
  with pytest.raises(SystemExit) as exit_info:
    cli.main(argv)
  assert exit_info.value.code == 2
  assert message in capsys.readouterr().err


@pytest.mark.parametrize('argv, message', [
    (['plan', '--task', 'pusht-fixed', '--instances', '40'], 'instances must lie in 0..29'),
    (['plan', '--task', 'pusht-fixed', '--budget', '0'], 'budget must be a positive'),
    (['plan', '--task', 'pusht-fixed', '-w', '-1'], '--weight/-w: must be a number >= 0, finite'),
    (['plan', '--task', 'pusht-fixed', '--checkpoint', planner.checkpoint_path('shelf')],
     "model of task 'shelf'"),
    (['plan', '--task', 'pusht-fixed', '--checkpoint', '/nonexistent'], 'no checkpoint'),
])
def test_bad_plan_arguments_give_clear_errors(argv, message, capsys):
  with pytest.raises(SystemExit) as exit_info:
    cli.main(argv)
  assert exit_info.value.code == 2
  assert message in capsys.readouterr().err


def test_unknown_task_is_rejected(capsys):
  with pytest.raises(SystemExit):
    cli.main(['plan', '--task', 'pusht'])
  assert "invalid choice: 'pusht'" in capsys.readouterr().err


def test_command_config_budget_and_cpu_overrides():
  # GPU: the task's defaults and the paper's budget (the original algorithm: its own settings)
  default = planner.command_config('pusht-obs', on_cpu=False, mujoco_c=False)
  assert (default.pop_size, default.edge_steps, default.budget) == (64, 8, 100_000)
  assert default.lattice_resolution is None
  gpu = planner.command_config('pusht-obs', on_cpu=False, mujoco_c=False, algorithm='original')
  assert (gpu.pop_size, gpu.edge_steps, gpu.budget) == (256, 1, 100_000)
  assert gpu.lattice_resolution == (0.005, 0.005, 0.05, 0.01, 0.01)
  assert gpu.compact_fractions == registry.ACCELERATOR_SEARCH['compact_fractions'] != ()
  assert planner.command_config('pusht-obs', False, False, compact_fractions=()) \
      .compact_fractions == ()
  # CPU without a budget: the CPU budget of the physics backend and the CPU overrides
  cpu = planner.command_config('pusht-obs', on_cpu=True, mujoco_c=True, algorithm='original')
  assert (cpu.pop_size, cpu.budget) == (64, 20_000)
  assert cpu.lattice_resolution == (0.01, 0.01, 0.1, 0.02, 0.02)
  assert cpu.compact_fractions == ()  # compaction does not pay on the CPU
  assert planner.command_config('pusht-fixed', True, False).budget == 2_000
  # a given budget keeps the tuned settings; explicit values win over everything
  assert planner.command_config('pusht-obs', True, True, 50_000, 'original').pop_size == 256
  mine = planner.command_config('pusht-obs', True, True, pop_size=32, weight=3.0)
  assert (mine.pop_size, mine.weight, mine.budget) == (32, 3.0, 20_000)
  with pytest.raises(ValueError, match='unknown task'):
    planner.command_config('pusht', False, False)


def test_plan_leaves_the_opengl_backend_alone():
  """`pachs plan` renders nothing with OpenGL, so it must not set MUJOCO_GL: on a machine
  without EGL, MUJOCO_GL=egl makes `import mujoco` fail. Only `pachs demo --gif` sets it."""
  # one process: `pachs plan`, then `pachs demo --gif` (each refused at its task), MUJOCO_GL
  # printed after each
  script = ('import os, sys; from pachs_jax import cli\n'
            'for argv in (sys.argv[1:4], sys.argv[4:]):\n'
            '  try: cli.main(argv)\n'
            '  except SystemExit: pass\n'
            '  print("MUJOCO_GL=" + str(os.environ.get("MUJOCO_GL")))')
  env = {k: v for k, v in os.environ.items() if k != 'MUJOCO_GL'}
  argv = ['plan', '--task', 'nope', 'demo', '--gif', 'x.gif', '--task', 'nope']
  done = subprocess.run([sys.executable, '-c', script] + argv, capture_output=True, text=True,
                        env=env, check=True)
  printed = [line for line in done.stdout.splitlines() if line.startswith('MUJOCO_GL=')]
  assert printed == ['MUJOCO_GL=None', 'MUJOCO_GL=egl'], done.stdout


def test_the_command_imports_mujoco_without_starting_a_process():
  """pyglfw (imported by mujoco) starts a Python process to probe each GLFW library unless
  PYGLFW_LIBRARY names one; `pachs` names the bundled one, so that its start-up starts no
  process (and a signal then leaves no traceback of that process)."""
  names = {}
  cli.skip_glfw_probe(names)
  if importlib.util.find_spec('glfw') is None:
    assert names == {}
    return
  assert os.path.isfile(names['PYGLFW_LIBRARY']) and '/x11/' in names['PYGLFW_LIBRARY']
  mine = {'PYGLFW_LIBRARY': '/my/libglfw.so'}
  cli.skip_glfw_probe(mine)
  assert mine == {'PYGLFW_LIBRARY': '/my/libglfw.so'}
  wayland = {'XDG_SESSION_TYPE': 'wayland'}
  cli.skip_glfw_probe(wayland)
  assert '/wayland/' in wayland.get('PYGLFW_LIBRARY', '/wayland/')
  script = ('import os, sys; from pachs_jax import cli\n'
            'started = []\n'
            'sys.addaudithook(lambda e, a: started.append(e) if e == "subprocess.Popen" else None)\n'
            'if sys.argv[1] == "skip": cli.skip_glfw_probe(os.environ)\n'
            'import mujoco\n'
            'print(len(started))')
  env = {k: v for k, v in os.environ.items() if k not in ('PYGLFW_LIBRARY', 'MUJOCO_GL')}
  counts = [subprocess.run([sys.executable, '-c', script, how], capture_output=True, text=True,
                           env=env, check=True).stdout.split()[-1] for how in ('probe', 'skip')]
  assert counts[1] == '0' and counts[0] != '0', counts
