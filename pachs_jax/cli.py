"""The `pachs` console command."""

from __future__ import annotations

import argparse
import json
import os
import sys


def _demo(args: argparse.Namespace) -> int:
  from pachs_jax import demo
  summary = demo.run_demo(args.task, args.instance, args.out, args.steps, args.gif)
  print(json.dumps(summary, indent=1))
  return 0


def main(argv=None) -> int:
  os.environ.setdefault('MUJOCO_GL', 'egl')
  parser = argparse.ArgumentParser(prog='pachs', description='PACHS in JAX')
  sub = parser.add_subparsers(dest='command', required=True)
  demo = sub.add_parser('demo', help='scripted PushT rollout through the MJX task, drawn to PNG')
  demo.add_argument('--task', default='pusht-obs',
                    choices=['pusht-fixed', 'pusht-rand', 'pusht-obs'])
  demo.add_argument('--instance', type=int, default=0, help='index into the canonical set')
  demo.add_argument('--steps', type=int, default=60, help='control steps (20 Hz)')
  demo.add_argument('--out', default='demo.png')
  demo.add_argument('--gif', default=None, help='also render a MuJoCo GIF (needs OpenGL)')
  demo.set_defaults(func=_demo)
  args = parser.parse_args(argv)
  if getattr(args, 'instance', 0) < 0 or not 0 <= args.instance < 30:
    parser.error(f'--instance must be in 0..29, got {args.instance}')
  return args.func(args)


if __name__ == '__main__':
  sys.exit(main())
