"""Runs an experiment script with two PushT-Obs layouts that the defaults were not chosen on
(a check of the defaults beyond the suite): `gate-mirror` (the gate's gap on the other side of
the starts) and `wall-right` (a wall moved right, the starts with it).

  python experiments/heldout_layouts.py experiments/open_loop.py --layout gate-mirror ...
"""

import os
import runpy
import sys

from pachs_jax.envs import layouts

HELD_OUT = (
    layouts.Layout(
        name='gate-mirror', kind='pass between two blocks, the gap on the left',
        blocks=(layouts._box(-0.50, -0.42, 0.06, 0.10), layouts._box(-0.18, 0.25, 0.06, 0.10)),
        start_x=(-0.14, -0.04), start_y=(0.20, 0.28),
        description='Held out: the starts above the right block, the gap to their left.'),
    layouts.Layout(
        name='wall-right', kind='go around a wall shifted right',
        blocks=(layouts._box(-0.22, 0.02, 0.03, 0.07),),
        start_x=(-0.20, -0.04), start_y=(0.20, 0.30),
        description='Held out: the wall layout moved 0.1 m to the right, the starts with it.'),
)


def main():
  for held in HELD_OUT:
    layouts.LAYOUTS[held.name] = held
  layouts.NAMES = tuple(layouts.LAYOUTS)
  if len(sys.argv) < 2 or not sys.argv[1].endswith('.py') or not os.path.isfile(sys.argv[1]):
    sys.exit('usage: python experiments/heldout_layouts.py SCRIPT.py [its flags]  (e.g. '
             'experiments/open_loop.py --layout gate-mirror); held-out layouts: '
             + ', '.join(held.name for held in HELD_OUT))
  script = sys.argv[1]
  sys.path.insert(0, os.path.dirname(os.path.abspath(script)))
  sys.argv = sys.argv[1:]
  runpy.run_path(script, run_name='__main__')


if __name__ == '__main__':
  main()
