"""experiments/report.py: the committed docs/results.md and README table match the result files,
and every file they cite exists."""

import json
import os
import re
import shutil

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

import report  # noqa: E402  pylint: disable=wrong-import-position


def read(path):
  with open(os.path.join(ROOT, path)) as f:
    return f.read()


def test_committed_report_is_current():
  for path, text in report.generate().items():
    assert read(path) == text, f'{path} is stale: run python experiments/report.py'


def test_cited_result_files_exist():
  cited = report.cited_files()
  assert len(cited) > 30
  missing = [p for p in cited if not os.path.isfile(os.path.join(ROOT, p))]
  assert not missing


def test_result_links_in_readme_and_docs_exist():
  """Every experiments/results path named in the README or a doc exists."""
  docs = ['README.md'] + [os.path.join('docs', n) for n in os.listdir(os.path.join(ROOT, 'docs'))
                          if n.endswith('.md')]
  pattern = re.compile(r'experiments/results/[\w./-]*\w')
  named = {(doc, m) for doc in docs for m in pattern.findall(read(doc))}
  assert named
  missing = [(doc, p) for doc, p in named if not os.path.exists(os.path.join(ROOT, p))]
  assert not missing


def test_links_to_sections_of_the_results_exist():
  """Every results.md#anchor in the README, a doc or a results README names a section."""
  anchors = {report.anchor(title) for title, _ in report.SECTIONS}
  docs = ['README.md'] + [os.path.join('docs', n) for n in os.listdir(os.path.join(ROOT, 'docs'))
                          if n.endswith('.md')]
  docs += [os.path.relpath(os.path.join(folder, 'README.md'), ROOT)
           for folder, _, names in os.walk(os.path.join(ROOT, 'experiments', 'results'))
           if 'README.md' in names]
  named = {(doc, a) for doc in docs for a in re.findall(r'results\.md#([\w-]+)', read(doc))}
  assert named
  assert not [(doc, a) for doc, a in named if a not in anchors]


def test_readme_table_sits_between_the_markers():
  readme = read('README.md')
  block, _ = report.headline_table()
  assert f'{report.BEGIN}\n{block}\n{report.END}' in readme
  with pytest.raises(ValueError, match='markers'):
    report.readme_with_table('no markers here', block)


@pytest.fixture
def copy_root(tmp_path):
  """A copy of the files the report reads and writes, to change."""
  shutil.copytree(os.path.join(ROOT, 'experiments', 'results'),
                  tmp_path / 'experiments' / 'results')
  shutil.copy(os.path.join(ROOT, 'README.md'), tmp_path / 'README.md')
  return tmp_path


def rewrite(root, name, change):
  path = root / 'experiments' / 'results' / name
  payload = json.loads(path.read_text())
  change(payload)
  path.write_text(json.dumps(payload))


def test_a_changed_result_makes_the_report_stale(copy_root):
  """Fewer successes of PACHS's default on the wall layout show in both outputs."""
  def fewer(payload):
    row = report.summary_of(payload, 'pachs-improve')
    row['successes'], row['success_rate'] = 75, 0.5

  rewrite(copy_root, 'faithful_gpu/wall.json', fewer)
  written = report.generate(str(copy_root))
  assert written != report.generate()
  assert '| PushT-Obs, wall | 50% |' in written['README.md']
  assert '| wall | 75/150 (50%) [' in written['docs/results.md']


def test_measured_cpu_timings_replace_the_placeholders(copy_root):
  """Once the maintainer's commands have written them, the CPU main job's and the test suite's
  times appear in the README."""
  prov = {'device': 'cpu: cpu x1', 'host_cpus': 2, 'git_revision': 'abc', 'command': 'c'}
  commands = [dict(instances=30, run='cold', process_wall_s=37.25, summary='found 30/30'),
              dict(instances=30, run='warm', process_wall_s=21.0, summary='found 30/30'),
              dict(instances=30, run='warm', process_wall_s=22.5, summary='found 30/30')]
  (copy_root / 'experiments/results/cpu_main_job.json').write_text(json.dumps(
      {'provenance': prov, 'task': 'pusht-obs', 'rows': [], 'commands': commands}))
  (copy_root / 'experiments/results/test_suite_cpu.json').write_text(json.dumps(
      {'provenance': prov, 'command': 'python -m pytest', 'process_wall_s': 540.0,
       'summary': '300 passed in 540.00s', 'returncode': 0}))
  block, _ = report.headline_table(str(copy_root))
  assert '37.2 s cold, 21.0-22.5 s warm' in block
  assert ('Tests: 9.0 min for `python -m pytest`, the default tier (300 passed in 540.00s; 2 '
          'CPUs)') in block
  assert 'not measured yet' not in block


def test_every_result_file_is_read_by_the_report_or_beside_one():
  """Result files no section reads leave the tree (git keeps them; the ledger names the commit):
  what stays is a cited JSON, the .md and trace beside it, a figure the README shows or a job
  script."""
  cited = set(report.cited_files())
  kept = ({p[:-len('.json')] + '.md' for p in cited}
          | {p[:-len('.json')] + '.pachs.trace.npz' for p in cited} | cited)
  readme = read('README.md')
  stray = []
  for folder, _, names in os.walk(os.path.join(ROOT, 'experiments', 'results')):
    for name in names:
      path = os.path.relpath(os.path.join(folder, name), ROOT)
      if path in kept or name.endswith('.sh') or name == 'README.md' or path in readme:
        continue
      stray.append(path)
  assert not stray


def test_every_experiment_script_is_used():
  """An experiment script stays while something uses it: a result file's command or a job
  script runs it, a test or another script imports it, or it draws a figure the README shows;
  otherwise it leaves the tree with its results (git keeps both)."""
  def text(path):
    with open(os.path.join(ROOT, path), errors='replace') as f:
      return f.read()
  users = {}
  for folder, _, names in os.walk(os.path.join(ROOT, 'experiments', 'results')):
    for name in names:
      if name.endswith(('.json', '.sh')):
        path = os.path.relpath(os.path.join(folder, name), ROOT)
        users[path] = text(path)
  for folder in ('tests', 'experiments'):
    for name in os.listdir(os.path.join(ROOT, folder)):
      if name.endswith(('.py', '.sh')):
        users[f'{folder}/{name}'] = text(f'{folder}/{name}')
  readme = read('README.md')
  unused = []
  for name in sorted(os.listdir(os.path.join(ROOT, 'experiments'))):
    if not name.endswith('.py'):
      continue
    script, stem = f'experiments/{name}', name[:-len('.py')]
    used = any(name in t or re.search(rf'^\s*(import|from) {stem}\b', t, re.M)
               for path, t in users.items() if path != script)
    figures = re.findall(r'([\w-]+\.png)', text(script).split('"""')[1])
    if not (used or any(figure in readme for figure in figures)):
      unused.append(script)
  assert not unused


def test_the_ledger_reads_its_numbers_from_the_files(copy_root):
  """A ledger row computed from the files follows them; a row of removed files names a commit."""
  def slower(payload):
    run = next(r for r in payload['runs'] if r['name'] == 'height, failure cost 25, scratch')
    run['env_steps'] += 5e6

  before = report.generate(str(copy_root))['docs/results.md']
  rewrite(copy_root, 'training/runs.json', slower)
  after = report.generate(str(copy_root))['docs/results.md']
  row = lambda text: next(line for line in text.splitlines()
                          if line.startswith('| SAC on the free T with a failed end charged 25'))
  steps = lambda line: float(re.search(r'after ([0-9.]+) M env steps', line).group(1))
  assert steps(row(after)) - steps(row(before)) == pytest.approx(5.0)
  for what, result, where in report.LEDGER:
    assert where.startswith('in this tree') or re.match(r'`[0-9a-f]{7}`: ', where), what


def test_sources_group_files_by_device_and_revision():
  runs = lambda revision: {'provenance': {'device': 'gpu: H100 x1', 'git_revision': revision,
                                          'command': 'c'}}
  lines = report.provenance_lines([('experiments/results/a.json', runs('1' * 40)),
                                   ('experiments/results/b.json', runs('1' * 40)),
                                   ('experiments/results/c.json', runs('2' * 40))], 'docs')
  assert lines == [
      '- gpu: H100 x1, revision 1111111: [`a.json`](../experiments/results/a.json), '
      '[`b.json`](../experiments/results/b.json)',
      '- gpu: H100 x1, revision 2222222: [`c.json`](../experiments/results/c.json)']
  merged = {'provenance': {'merged_from': [runs('1' * 40)['provenance'],
                                           runs('2' * 40)['provenance']]}}
  assert report.provenance_lines([('experiments/results/m.json', merged)], 'docs') == [
      '- gpu: H100 x1, revisions 1111111, 2222222: [`m.json`](../experiments/results/m.json)']


def test_formats():
  assert report.pct(1.0) == '100%'
  assert report.pct(0.9666666) == '96.7%'
  assert report.pct(None) == '-'
  assert report.ci(0.9, 1.0) == ' [90, 100]'
  assert report.ci(1.0, 1.0) == ''
  assert report.num(3000000.0) == '3,000,000'
  assert report.num(0.2482) == '0.248'
  assert report.short_revision('e8963aa100994b440cc98c4af706a1c91c4d2450+dirty') == 'e8963aa+dirty'


@pytest.mark.parametrize('damage, message', [
    ('truncate', r'open_loop_shelf.json: not valid JSON'),
    ('delete', r'open_loop_shelf.json: missing \(the report reads it\)'),
    ('list', r'open_loop_shelf.json: not a result \(a JSON object\), got list'),
    ('no summary', r"section '.*' \(last read .*open_loop_shelf.json\): KeyError 'summary'"),
])
def test_a_damaged_result_file_is_named_in_one_line(tmp_path, damage, message):
  _damage_and_check(tmp_path, damage, message)


@pytest.mark.parametrize('change, message', [
    ({'success_rate': 2.5}, r'open_loop_shelf.json: pachs success_rate must lie in \[0, 1\], got 2.5'),
    ({'successes': -1}, r'pachs successes must be a count \(an int >= 0\), got -1'),
    ({'successes': 7.5}, r'pachs successes must be a count'),
    ({'successes': 101}, r'pachs successes 101 exceed its 100 runs'),
    ({'cost_success_mean': float('nan')}, r'pachs cost_success_mean is nan \(not a finite'),
])
def test_impossible_numbers_in_a_result_file_are_named(tmp_path, change, message):
  _damage_and_check(tmp_path, change, message)


def _damage_and_check(tmp_path, damage, message):
  shutil.copytree(os.path.join(ROOT, 'experiments', 'results'),
                  tmp_path / 'experiments' / 'results')
  shutil.copy(os.path.join(ROOT, 'README.md'), tmp_path / 'README.md')
  target = tmp_path / 'experiments' / 'results' / 'open_loop_shelf.json'
  payload = json.loads(target.read_text())
  if damage == 'truncate':
    target.write_text(target.read_text()[:100])
  elif damage == 'delete':
    target.unlink()
  elif damage == 'list':
    target.write_text('[]')
  elif isinstance(damage, dict):
    row = next(r for r in payload['summary'] if r['planner'] == 'pachs')
    row.update(damage)
    target.write_text(json.dumps(payload))
  else:
    target.write_text(json.dumps({k: v for k, v in payload.items() if k != 'summary'}))
  with pytest.raises(report.ReportError, match=message):
    report.generate(str(tmp_path))


def test_report_check_exits_with_one_line_on_a_damaged_file(monkeypatch, capsys):
  def damaged(*_):
    raise report.ReportError('experiments/results/x.json: missing (the report reads it)')
  monkeypatch.setattr(report, 'generate', damaged)
  assert report.main(['--check']) == 2
  err = capsys.readouterr().err
  assert err == 'report.py: error: experiments/results/x.json: missing (the report reads it)\n'


def _replayed(episode, plan_max, planner_at_failure, c_at_failure, on_policy=True):
  """A `trace_replay.py` episode whose last row is the failure."""
  return {'episode': episode, 'on_policy_step': on_policy, 'plan_max_tilt': plan_max,
          'planner_replay_tilt_at_failure': planner_at_failure,
          'rows': [{'tilt_world': c_at_failure, 'tilt_c_replay': c_at_failure,
                    'tilt_planner_replay': planner_at_failure, 'tilt_plan': None,
                    't_contacts': ['stick / t_bar']}]}


def test_the_replay_sentence_tells_how_each_failed_episode_tipped():
  r = {'planner_physics': 'warp', 'episodes': [
      _replayed(0, 8.0, 31.0, 31.0),  # both engines tipped it, on a policy step
      _replayed(1, 10.0, 12.0, 35.0, on_policy=False),  # MuJoCo C only: an engine difference
      _replayed(2, 28.0, 25.0, 33.0, on_policy=False)]}  # a plan near the limit
  text = report.replay_sentence('gate', 'x.replay.json', r, 20.0)
  assert "gate's 3 failed episodes" in text
  assert 'In 1 both engines tipped the T alike (episode 0: 31.0 degrees in MuJoCo C, 31.0 in ' \
         'warp, on a policy step after a plan of at most 8.0 degrees' in text
  assert 'in 1 the plan kept the T within 20 degrees' in text and 'episode 1: 12.0' in text
  assert text.endswith('in the others the plan had tilted the T past 20 degrees itself.')
  one = report.replay_sentence('gate', 'x.replay.json',
                               {'planner_physics': 'warp', 'episodes': r['episodes'][2:]}, 20.0)
  assert "gate's 1 failed episode," in one
  assert one.endswith('In each the plan had tilted the T past 20 degrees itself.')
