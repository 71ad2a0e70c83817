"""The slow tier (tests/conftest.py, SLOW) names files and tests that exist, and marks them."""

import ast
import os

import pytest
from conftest import SLOW, is_slow

TESTS = os.path.dirname(os.path.abspath(__file__))


@pytest.mark.parametrize('entry', SLOW)
def test_every_slow_entry_names_a_test_file_or_function(entry):
  file, _, name = entry.partition('::')
  path = os.path.join(TESTS, file)
  assert os.path.isfile(path), f'{entry}: no such test file'
  if name:
    tree = ast.parse(open(path).read())
    names = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    assert name in names, f'{entry}: no such test function'


def test_is_slow_matches_files_tests_and_their_parameters():
  assert is_slow('tests/test_playground.py::test_goal_rules')
  assert is_slow('tests/test_segment.py::test_segments_with_compaction_equal_without[0.5-x]')
  assert not is_slow('tests/test_segment.py::test_segment_paths_replay_and_end_at_goals')
  assert not is_slow('tests/test_pusht.py::test_bad_actions_and_states_more')
