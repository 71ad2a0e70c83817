"""The package's layers: no import runs back up (the search core and the envs never import the
run-time machinery or the entry points above them), and `import pachs_jax` stays light while
its top-level names reach the entry points."""

import ast
import pathlib
import subprocess
import sys

import pytest

PACKAGE = pathlib.Path(__file__).resolve().parent.parent / 'pachs_jax'
TOP = ('planner', 'replan', 'episodes', 'saved_plans', 'cli', 'demo', 'outputs', 'serve',
       'client', 'wire')
# each layer and the pachs_jax modules it must not import (a prefix matches its submodules); the
# trainer writes its files through the run-time machinery's atomic files
FORBIDDEN = {
    'envs': ('search', 'runtime', 'sac') + TOP,
    'search': ('runtime', 'sac') + TOP,
    'sac': ('search', 'runtime.programs', 'runtime.anytime', 'runtime.sharding') + TOP,
    'runtime': TOP,
}


def _pachs_imports(path: pathlib.Path):
  """The pachs_jax modules a file imports, anywhere in it ('pachs_jax.x.y' without the prefix;
  `from pachs_jax import a` gives 'a')."""
  names = set()
  for node in ast.walk(ast.parse(path.read_text())):
    if isinstance(node, ast.Import):
      names.update(a.name for a in node.names)
    elif isinstance(node, ast.ImportFrom) and node.module:
      if node.module == 'pachs_jax':
        names.update(f'pachs_jax.{a.name}' for a in node.names)
      else:
        names.add(node.module)
  return {n[len('pachs_jax.'):] for n in names if n.startswith('pachs_jax.')}


def _layer_files():
  for layer in FORBIDDEN:
    for path in sorted((PACKAGE / layer).rglob('*.py')):
      yield layer, path


@pytest.mark.parametrize('layer,path', list(_layer_files()),
                         ids=lambda x: str(x.relative_to(PACKAGE)) if isinstance(x, pathlib.Path)
                         else x)
def test_no_import_runs_back_up(layer, path):
  bad = sorted(name for name in _pachs_imports(path)
               if any(name == f or name.startswith(f + '.') for f in FORBIDDEN[layer]))
  assert not bad, f'{path.relative_to(PACKAGE)} ({layer}) imports {bad}'


def test_the_forbidden_rule_sees_an_upward_import(tmp_path):
  # the check itself: an import of the run-time machinery from the search core is caught
  probe = tmp_path / 'probe.py'
  probe.write_text('from pachs_jax.runtime import anytime\nfrom pachs_jax import planner, trees\n')
  assert _pachs_imports(probe) == {'runtime', 'planner', 'trees'}


def test_top_level_names_are_lazy_entry_points():
  code = ('import sys, pachs_jax; light = "jax" not in sys.modules; '
          'from pachs_jax import planner, replan, search, envs; '
          'print(light, pachs_jax.Planner is planner.Planner, pachs_jax.Session is replan.Session, '
          'pachs_jax.make_search is search.make_search, pachs_jax.envs is envs)')
  out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True)
  assert out.stdout.split() == ['True'] * 5, out.stdout + out.stderr
  import pachs_jax
  with pytest.raises(AttributeError, match='no attribute'):
    pachs_jax.NoSuchThing  # pylint: disable=pointless-statement
