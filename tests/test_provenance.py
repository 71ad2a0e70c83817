"""Result files name the command that made them: through a wrapper script too."""

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_a_script_run_through_heldout_layouts_records_the_wrapper_command(tmp_path):
  """heldout_layouts.py runs the script in its own process; the recorded command is the one
  typed (wrapper, script and flags), which a reader can run again, not the inner script's."""
  script = tmp_path / 'show_command.py'
  script.write_text('import common, sys\nprint(common.command_line())\n')
  out = subprocess.run(
      [sys.executable, os.path.join(ROOT, 'experiments', 'heldout_layouts.py'), str(script),
       '--layout', 'gate-mirror'],
      capture_output=True, text=True, check=True, cwd=ROOT,
      env=dict(os.environ, PYTHONPATH=os.path.join(ROOT, 'experiments') + os.pathsep + ROOT))
  words = out.stdout.split()
  assert words[1].endswith('experiments/heldout_layouts.py'), out.stdout
  assert words[2:] == [str(script), '--layout', 'gate-mirror'], out.stdout
