"""The README's Python snippets run as written, one after another in one namespace, after the
shell command that writes the rows.json the first one reads; the client snippet asks a server
on ws://127.0.0.1:8000 that serves the snippets' own planner (slow tier)."""

import os
import re
import subprocess
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _readme_python_blocks():
  with open(os.path.join(ROOT, 'README.md')) as f:
    return re.findall(r'```python\n(.*?)```', f.read(), flags=re.S)


def test_the_readme_python_snippets_run_as_written(tmp_path, monkeypatch):
  from pachs_jax.envs import registry  # pylint: disable=import-outside-toplevel
  # the snippets as written, their searches small (a CPU's default budget would plan for
  # minutes beside the other slow tests)
  monkeypatch.setitem(registry.CPU_PLANNING, 'mujoco-c', registry.CpuPlanning('all', 1_000))
  blocks = _readme_python_blocks()
  assert len(blocks) == 4, 'the README changed: update this test'
  assert 'rows.json' in blocks[0] and 'ws://127.0.0.1:8000' in blocks[3]
  monkeypatch.chdir(tmp_path)
  command = [sys.executable, '-m', 'pachs_jax.cli', 'plan', '--task', 'pusht-obs', '--layout',
             'wall', '--instances', '0-1', '--budget', '1000', '--json', 'rows.json']
  subprocess.run(command, check=True, capture_output=True, timeout=600)
  names = {}
  for block in blocks[:3]:
    exec(compile(block, 'README.md', 'exec'), names)  # pylint: disable=exec-used
  assert names['result'].found.shape == (2,) and names['answer'].actions.shape[0] == 2
  assert names['replayed'].valid  # replayed in the physics that made it
  from pachs_jax import serve  # pylint: disable=import-outside-toplevel
  server = serve.Server({'pusht-obs': names['planner']},
                        serve.ServeConfig(max_batch=2, buckets=(2,)))
  server.warm()
  with serve.Running(server, port=8000):
    exec(compile(blocks[3], 'README.md', 'exec'), names)  # pylint: disable=exec-used
  assert np.asarray(names['answer'].actions).shape[0] == 2
