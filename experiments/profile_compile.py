"""Where the XLA compilation of `pachs plan`'s search loop goes: trace + lower and XLA compile
times of the loop's parts, each jitted alone at the loop's lane count, next to the whole loop,
with the number of kernels (GPU: fusions and custom calls) each compiled program holds. No
persistent cache. Parts: one transition of the physics (`env.evaluate`), one H-step edge
(`segment`), the networks (actor samples and critic values), the whole loop of one size.

  python experiments/profile_compile.py --task pusht-obs --out /tmp/profile.json
"""

from __future__ import annotations

import argparse
import json
import re
import time


def timed_compile(fn, *args, options=None) -> dict:
  """Trace + lower and XLA compile times (s) of jax.jit(fn)(*args) with XLA `options`, the
  compiled program's size (HLO instructions, kernels: fusion and custom-call instructions) and
  on an accelerator the time to load its serialised executable back, alone and as two loads in
  two threads at once."""
  import concurrent.futures
  import jax
  began = time.perf_counter()
  lowered = jax.jit(fn).lower(*args)
  lowered_at = time.perf_counter()
  compiled = lowered.compile(compiler_options=options or None)
  done = time.perf_counter()
  text = compiled.as_text() or ''
  loaded = {}
  if jax.default_backend() != 'cpu':  # XLA:CPU executables do not load back reliably
    from jax.experimental import serialize_executable
    blob = serialize_executable.serialize(compiled)
    loading = time.perf_counter()
    serialize_executable.deserialize_and_load(*blob)
    loaded = {'load_s': time.perf_counter() - loading, 'executable_mb': len(blob[0]) / 1e6}
    loading = time.perf_counter()
    with concurrent.futures.ThreadPoolExecutor(2) as threads:
      list(threads.map(lambda _: serialize_executable.deserialize_and_load(*blob), range(2)))
    loaded['two_loads_in_threads_s'] = time.perf_counter() - loading
  return {**loaded, 'lower_s': lowered_at - began, 'compile_s': done - lowered_at,
          'stablehlo_lines': lowered.as_text().count('\n'),
          'hlo_instructions': len(re.findall(r'^\s+\S+ = ', text, re.M)),
          'fusions': len(re.findall(r' fusion\(', text)),
          'custom_calls': len(re.findall(r'custom-call\(', text)),
          'while_loops': len(re.findall(r' while\(', text))}


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument('--task', default='pusht-obs')
  parser.add_argument('--bucket', type=int, default=32, help='padded instance count')
  parser.add_argument('--parts', default='physics,segment,networks,loop')
  parser.add_argument('--sizes', default='all', help="loop sizes: 'all' (every lane size of "
                      "the bucket and all lanes) or comma-separated lane counts, 0 = all lanes")
  parser.add_argument('--xla-option', action='append', default=[],
                      help='NAME=VALUE, an XLA option for every compile (repeatable)')
  parser.add_argument('--out', required=True)
  args = parser.parse_args()
  options = {name: {'true': True, 'false': False}.get(value.lower(), value)
             for name, value in (item.split('=', 1) for item in args.xla_option)}
  import jax
  import jax.numpy as jnp
  import common
  from pachs_jax import planner
  from pachs_jax.search import pachs, segment
  from pachs_jax.search.checks import instance_keys
  env, model = planner.load_model(args.task, None, 'mjx')
  config = planner.command_config(args.task, False, False, None)  # the GPU's settings
  search = pachs.make_search(env, model, config)
  lanes_all = args.bucket * config.pop_size
  if args.sizes == 'all':
    sizes = [None] + list(reversed(search.lane_sizes(args.bucket)))
  else:
    sizes = [int(s) or None for s in args.sizes.split(',')]
  start = env.canonical_instances(1)
  rows = []
  for size in sizes:
    lanes = size or lanes_all
    nodes = jax.tree.map(lambda x: jnp.repeat(x, lanes, axis=0), start)
    actions = jnp.zeros((lanes, env.action_size), jnp.float32)
    keys = jax.random.split(jax.random.PRNGKey(0), lanes)
    obs = jnp.zeros((lanes, env.observation_size), jnp.float32)
    parts = {
        'physics': lambda: timed_compile(env.evaluate, nodes, actions, options=options),
        'segment': lambda: timed_compile(
            segment.make_segment_fn(env, model, config.edge_steps), nodes, (actions, keys),
            options=options),
        'networks': lambda: timed_compile(
            lambda o, k: (segment.actor_samples(model, k, o),
                          model.q_values(o, model.sample_actions(k[0], o, config.num_actions))),
            obs, keys, options=options),
    }
    for part in args.parts.split(','):
      if part == 'loop':
        instances = jax.tree.map(lambda x: jnp.repeat(x, args.bucket, axis=0), start)
        state = jax.eval_shape(search.init, instances,
                               instance_keys(jax.random.PRNGKey(0), args.bucket))
        row = timed_compile(lambda s, n: search.loop(s, n, size=size), state, jnp.int32(32),
                            options=options)
      else:
        row = parts[part]()
      row.update(part=part, lanes=lanes)
      rows.append(row)
      print(json.dumps(row), flush=True)
  out = {'provenance': common.provenance(), 'task': args.task, 'bucket': args.bucket,
         'xla_options': options,
         'config': {'pop_size': config.pop_size, 'edge_steps': config.edge_steps,
                    'compact_fractions': list(config.compact_fractions)}, 'rows': rows}
  common.write_json(args.out, out)


if __name__ == '__main__':
  main()
