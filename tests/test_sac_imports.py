"""pachs_jax.sac imports: no cycle between its modules, and function-level imports only for
optional dependencies."""

import ast
import pathlib

SAC = pathlib.Path(__file__).resolve().parent.parent / 'pachs_jax' / 'sac'
OPTIONAL = {'tensorboardX'}


def _imports(path: pathlib.Path):
  """(module names imported anywhere, names imported inside functions) of one file."""
  tree = ast.parse(path.read_text())
  anywhere, nested = set(), set()
  for func in [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]:
    for node in ast.walk(func):
      if isinstance(node, (ast.Import, ast.ImportFrom)):
        nested.update(_names(node))
  for node in ast.walk(tree):
    if isinstance(node, (ast.Import, ast.ImportFrom)):
      anywhere.update(_names(node))
  return anywhere, nested


def _names(node):
  if isinstance(node, ast.Import):
    return {a.name for a in node.names}
  if node.module == 'pachs_jax.sac':
    return {f'pachs_jax.sac.{a.name}' for a in node.names}
  return {node.module}


def test_sac_modules_import_no_cycle_even_inside_functions():
  graph = {}
  for path in SAC.glob('*.py'):
    anywhere, _ = _imports(path)
    graph[f'pachs_jax.sac.{path.stem}'] = {m for m in anywhere if m.startswith('pachs_jax.sac.')}
  assert 'pachs_jax.sac.checkpoint' in graph['pachs_jax.sac.__init__']  # the graph is real

  def reaches(start, target, seen):
    for dep in graph.get(start, ()):
      if dep == target or (dep not in seen and reaches(dep, target, seen | {dep})):
        return True
    return False

  cycles = sorted(m for m in graph if m != 'pachs_jax.sac.__init__' and reaches(m, m, {m}))
  assert not cycles


def test_function_level_imports_only_for_optional_dependencies():
  found = {}
  for path in SAC.glob('*.py'):
    _, nested = _imports(path)
    extra = {m for m in nested if m.split('.')[0] not in OPTIONAL}
    if extra:
      found[path.name] = sorted(extra)
  assert found == {}
