"""Check actor-critic exports, or record the hashes of exports written before them.

python -m pachs_jax.sac.verify DIR...             load each (parameter and metadata hashes)
python -m pachs_jax.sac.verify --add-hash DIR...  record the hashes of the files as they are
"""

from __future__ import annotations

import argparse
import sys

from pachs_jax.sac import checkpoint


def main(argv=None) -> int:
  p = argparse.ArgumentParser(prog='python -m pachs_jax.sac.verify',
                              description=__doc__.split('\n')[0])
  p.add_argument('paths', nargs='+', metavar='DIR', help='actor-critic export or run directory')
  p.add_argument('--add-hash', action='store_true',
                 help='record the hashes of the parameters and metadata as they are (trusts '
                      'the files)')
  args = p.parse_args(argv)
  status = 0
  for path in args.paths:
    try:
      if args.add_hash:
        print(f'{path}: {checkpoint.META_HASH_KEY} {checkpoint.add_hashes(path)}')
      else:
        ac = checkpoint.load_actor_critic(path)
        print(f'{path}: ok (task {ac.config.task}, {checkpoint.HASH_KEY} and '
              f'{checkpoint.META_HASH_KEY} verified)')
    except checkpoint.CheckpointError as e:
      print(f'error: {e}', file=sys.stderr)
      status = 1
  return status


if __name__ == '__main__':
  sys.exit(main())
