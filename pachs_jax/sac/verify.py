"""Check actor-critic exports, or record the parameter hash of exports written before hashes.

python -m pachs_jax.sac.verify DIR...             load each (parameter hash included)
python -m pachs_jax.sac.verify --add-hash DIR...  record the hash of the files as they are
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
                 help='record the hash of the parameters as they are (trusts the files)')
  args = p.parse_args(argv)
  status = 0
  for path in args.paths:
    try:
      if args.add_hash:
        print(f'{path}: {checkpoint.HASH_KEY} {checkpoint.add_params_hash(path)}')
      else:
        ac = checkpoint.load_actor_critic(path)
        print(f'{path}: ok (task {ac.config.task}, {checkpoint.HASH_KEY} verified)')
    except checkpoint.CheckpointError as e:
      print(f'error: {e}', file=sys.stderr)
      status = 1
  return status


if __name__ == '__main__':
  sys.exit(main())
