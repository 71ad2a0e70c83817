"""Env steps/s of the three PushT physics engines in one run: MJX's JAX implementation, MuJoCo
Warp (MJX impl='warp') and MuJoCo C on all the host's threads, at several world counts, on
states with contacts drawn from policy rollouts; optionally PACHS's edges/s per backend.

  python experiments/bench_engines.py --layouts gate,two-gaps --worlds 1024,4096,16384,65536
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

import common

HERE = os.path.dirname(os.path.abspath(__file__))


def build_parser() -> argparse.ArgumentParser:
  """The script's flags (light modules only: a bad flag is refused before JAX loads)."""
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--layouts', default='gate,two-gaps', help='PushT-Obs layouts')
  parser.add_argument('--worlds', default='1024,4096,16384,65536')
  parser.add_argument('--engines', default='mjx,warp,mujoco-c')
  parser.add_argument('--steps', type=int, default=20, help='control steps per timed call')
  parser.add_argument('--repeats', type=int, default=3)
  parser.add_argument('--threads', type=int, default=os.cpu_count(), help='MuJoCo C threads')
  parser.add_argument('--rollout-copies', type=int, default=1024)
  parser.add_argument('--rollout-steps', type=int, default=60)
  parser.add_argument('--search-backends', default='',
                      help="comma list ('warp,mjx,mujoco-c'): also PACHS's edges/s per backend")
  parser.add_argument('--search-instances', type=int, default=30)
  parser.add_argument('--search-pop-sizes', default='64')
  parser.add_argument('--search-budget', type=int, default=20_000)
  common.add_common_args(parser, out='experiments/results/engines/bench_engines.json')
  return parser


if __name__ == '__main__':
  build_parser().parse_args()  # bad flags refused before the heavy imports below

# pylint: disable=wrong-import-position
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402
from mujoco import rollout  # noqa: E402

from pachs_jax import planner, trees  # noqa: E402
from pachs_jax.envs import mujoco_c, panda, pusht, warp_import, warp_physics  # noqa: E402
# pylint: enable=wrong-import-position


def mujoco_c_throughput(env, nodes, steps: int, nthread: int, repeats: int) -> dict:
  """Env steps/s of MuJoCo C (`mujoco.rollout`, nthread threads, one call) from nodes [W]
  with random joint-target walks held for `substeps` physics steps each."""
  m = env.mj_model
  worlds = int(nodes.qpos.shape[0])
  state, warm, _ = mujoco_c.batch_to_rollout(env, nodes)
  rng = np.random.default_rng(0)
  targets = np.asarray(nodes.qpos[:, None, :7]) + np.cumsum(
      pusht.ARM_ACTION_SCALE * rng.uniform(-1, 1, (worlds, steps, 7)), axis=1)
  control = np.repeat(np.clip(targets, panda.JOINT_LOWER, panda.JOINT_UPPER),
                      env.config.substeps, axis=1)
  datas = [mujoco.MjData(m) for _ in range(nthread)]
  with rollout.Rollout(nthread=nthread) as runner:
    times = []
    for _ in range(repeats + 1):
      start = time.perf_counter()
      runner.rollout([m] * worlds, datas, state, control, initial_warmstart=warm)
      times.append(time.perf_counter() - start)
  t = float(np.median(times[1:]))
  return {'worlds': worlds, 'steps': steps, 'threads': nthread, 'median_s': t,
          'env_steps_per_s': worlds * steps / t, 'ms_per_env_step': 1e3 * t / steps}


def contact_states(env, model, copies: int, steps: int, seed: int = 0):
  """(nodes [S] in contact, fraction of rollout states in contact): the stochastic policy run
  `steps` control steps from the canonical instances (`copies` runs in all) in `env`; a state
  is in contact when MuJoCo C finds a contact there (stick-T, T-block or stick-block)."""
  starts = env.canonical_instances(30)
  starts = jax.tree.map(lambda x: x[np.arange(copies) % 30], starts)

  @jax.jit
  def roll(nodes, key):
    def body(nodes, k):
      actions = model.sample_actions(k, env.observe(nodes), 1)[:, 0]
      out = env.evaluate(nodes, jnp.clip(actions, -1, 1))
      nodes = trees.where(out.is_valid, out.next_node, nodes)
      return nodes, nodes
    return jax.lax.scan(body, nodes, jax.random.split(key, steps))[1]

  visited = jax.device_get(roll(starts, jax.random.PRNGKey(seed)))
  flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), visited)
  m, d = env.mj_model, mujoco.MjData(env.mj_model)
  touching = np.zeros(flat.qpos.shape[0], bool)
  for i, q in enumerate(flat.qpos):
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    mujoco.mj_collision(m, d)
    touching[i] = d.ncon > 0
  keep = np.flatnonzero(touching)
  return jax.tree.map(lambda x: x[keep], flat), float(touching.mean())


def tile(nodes, worlds: int, seed: int = 0):
  """worlds nodes drawn (with replacement when needed) from nodes [S]."""
  num = nodes.qpos.shape[0]
  rng = np.random.default_rng(seed)
  index = rng.permutation(num)[:worlds] if worlds <= num else rng.integers(0, num, worlds)
  return jax.device_put(jax.tree.map(lambda x: x[index], nodes))


def search_rates(args) -> list:
  """PACHS run to budget per backend (`bench_search.py --run-to-budget`, one process each;
  MuJoCo C with JAX on the CPU): edges/s and the ratio to the same backend's raw rate."""
  rows = []
  with tempfile.TemporaryDirectory() as tmp:
    for backend in args.search_backends.split(','):
      out = os.path.join(tmp, f'{backend}.json')
      cmd = [sys.executable, os.path.join(HERE, 'bench_search.py'), '--task', 'pusht-obs',
             '--instances', str(args.search_instances), '--pop-sizes', args.search_pop_sizes,
             '--budget', str(args.search_budget), '--run-to-budget', '--backend', backend,
             '--out', out]
      env = dict(os.environ)
      if backend == 'mujoco-c':
        env['JAX_PLATFORMS'] = 'cpu'
      print(' '.join(cmd), flush=True)
      subprocess.run(cmd, check=True, env=env)
      with open(out) as f:
        for r in json.load(f)['rows']:
          rows.append({'backend': backend, 'instances': r['instances'], 'K': r['K'],
                       'budget': r['budget'], 'evaluated': r['evaluated'],
                       'wall_s': r['wall_s'], 'edges_per_s': r['edges_per_s'],
                       'raw_env_steps_per_s_same_batch': r['raw_env_steps_per_s_same_batch'],
                       'search_over_raw': r['search_over_raw']})
          print(rows[-1], flush=True)
  return rows


def main():
  parser = build_parser()
  args = parser.parse_args()
  engines = args.engines.split(',')
  if 'warp' in engines:
    warp_import.require('--engines warp')
  worlds = [int(w) for w in args.worlds.split(',')]
  result = {'provenance': common.provenance(), 'settings': vars(args), 'states': [],
            'rows': [], 'search': []}
  for layout in args.layouts.split(','):
    config = pusht.PushTConfig(variant='obs', layout=layout)
    base_env, model = planner.load_model('pusht-obs', backend='mjx', layout=layout)
    per_engine = {'mjx': base_env, 'mujoco-c': base_env}
    if 'warp' in engines:
      per_engine['warp'] = warp_physics.WarpPushTEnv(config)
    rollout_env = per_engine.get('warp', base_env)
    pool, fraction = contact_states(rollout_env, model, args.rollout_copies, args.rollout_steps)
    result['states'].append({'layout': layout, 'engine': type(rollout_env).__name__,
                             'rollout_states': args.rollout_copies * args.rollout_steps,
                             'in_contact': int(pool.qpos.shape[0]),
                             'contact_fraction': fraction})
    print(result['states'][-1], flush=True)
    for w in worlds:
      nodes = tile(pool, w)
      for engine in engines:
        if engine == 'mujoco-c':
          row = mujoco_c_throughput(base_env, nodes, args.steps, args.threads, args.repeats)
        else:
          row = common.env_throughput(per_engine[engine], w, args.steps, args.repeats, nodes)
        row = {'layout': layout, 'engine': engine, **row,
               'physics_steps_per_s': row['env_steps_per_s'] * config.substeps}
        print(row, flush=True)
        result['rows'].append(row)
        common.write_json(args.out, result)
  ratios = []
  for r in result['rows']:
    if r['engine'] == 'mujoco-c':
      continue
    c = [x for x in result['rows'] if x['engine'] == 'mujoco-c' and x['layout'] == r['layout']
         and x['worlds'] == r['worlds']]
    if c:
      ratios.append({'layout': r['layout'], 'worlds': r['worlds'], 'engine': r['engine'],
                     'over_mujoco_c': r['env_steps_per_s'] / c[0]['env_steps_per_s']})
  result['ratios'] = ratios
  if args.search_backends:
    result['search'] = search_rates(args)
  md = common.markdown_header(
      'PushT-Obs physics engines, env steps/s (one env step = '
      f'{pusht.PushTConfig().substeps} physics steps)', result['provenance'],
      f'Command settings: {vars(args)}', 'States: policy rollouts, only states in contact:')
  md += [common.markdown_table(result['states'], list(result['states'][0])), '',
         common.markdown_table(result['rows'], [
             'layout', 'engine', 'worlds', 'env_steps_per_s', 'physics_steps_per_s',
             'ms_per_env_step', 'compile_s', 'threads', 'invalid_edges']),
         '\n## Over MuJoCo C on all threads, same run\n',
         common.markdown_table(ratios, ['layout', 'worlds', 'engine', 'over_mujoco_c'])]
  if result['search']:
    md += ['\n## PACHS run to budget (edges/s) over the same backend\'s raw rate\n',
           common.markdown_table(result['search'], list(result['search'][0]))]
  common.write_result(args.out, result, md)


if __name__ == '__main__':
  main()
