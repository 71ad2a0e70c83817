"""Learning curves and a results table of the SAC runs behind the shipped models.

Reads the runs' metrics.csv files (copied from the GPU into experiments/results/training/) and
writes training_curves.png and training.md there.

  python experiments/plot_training.py
"""

from __future__ import annotations

import argparse
import csv
import json
import os

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

import common

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'results', 'training')

# The runs, the command that made each (on one NVIDIA H200, jax 0.11.2; the PushT runs and the
# first shelf run at revision 4629af5, the shelf sweep at 003b21b; every command also had
# --progress lines --no-tensorboard), and whether the model ships.
RUNS = [
    ('pusht-fixed', 'pusht-fixed.metrics.csv', True,
     'experiments/train.py --task pusht-fixed --steps 24000000 --out runs/pusht-fixed '
     '--minutes 3.3 --nondeterministic'),
    ('pusht-rand', 'pusht-rand.metrics.csv', True,
     'experiments/train.py --task pusht-rand --steps 30000000 --out runs/pusht-rand '
     '--minutes 1.8 --nondeterministic  (stopped by --minutes at 9.4M steps)'),
    ('shelf (3x256, discount 0.97)', 'shelf-a.metrics.csv', True,
     'experiments/train.py --task shelf --steps 40000000 --out runs/shelf-a --minutes 2.2 '
     '--discount 0.97 --hidden 256,256,256 --nondeterministic  (stopped by --minutes)'),
    ('shelf (2x64, discount 0.97)', 'shelf-b.metrics.csv', False,
     'experiments/train.py --task shelf --steps 40000000 --out runs/shelf-b --minutes 2.2 '
     '--discount 0.97 --nondeterministic'),
    ('shelf (2x256, discount 0.9, alpha0 0.05)', 'shelf-c.metrics.csv', False,
     'experiments/train.py --task shelf --steps 40000000 --out runs/shelf-c --minutes 2.2 '
     '--discount 0.9 --hidden 256,256 --init-alpha 0.05 --nondeterministic'),
    ('shelf (2x64, discount 0.9: first preset)', 'shelf-attempt1.metrics.csv', False,
     'experiments/train.py --task shelf --steps 15000000 --out runs/shelf --minutes 1.8 '
     '--nondeterministic'),
]


def read_csv(path: str) -> dict:
  with open(path) as f:
    rows = list(csv.DictReader(f))
  out = {}
  for key in rows[0]:
    out[key] = np.array([float(r[key]) if r[key] not in ('', 'nan') else np.nan for r in rows])
  return out


def main():
  parser = argparse.ArgumentParser()
  parser.add_argument('--dir', default=HERE)
  args = parser.parse_args()
  fig = Figure(figsize=(12, 4.5))
  FigureCanvasAgg(fig)
  ax_train, ax_sps = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
  table = []
  for name, file, ships, command in RUNS:
    m = read_csv(os.path.join(args.dir, file))
    steps = m['env_steps'] / 1e6
    style = '-' if ships else ':'
    line, = ax_train.plot(steps, m['success_rate'], style, label=f'{name} (training episodes)')
    ev = ~np.isnan(m['eval_success_deterministic'])
    ax_train.plot(steps[ev], m['eval_success_deterministic'][ev], 'o', color=line.get_color())
    ax_sps.plot(steps[1:], m['sps'][1:] / 1e3, style, color=line.get_color(), label=name)
    last_eval = m['eval_success_deterministic'][ev][-1] if ev.any() else float('nan')
    table.append({
        'run': name, 'ships': 'yes' if ships else 'no',
        'env_steps_M': f'{m["env_steps"][-1] / 1e6:.1f}',
        'wall_min': f'{m["walltime"][-1] / 60:.1f}',
        'env_steps_per_s_k': f'{np.median(m["sps"][1:]) / 1e3:.0f}',
        'train_success_last': f'{m["success_rate"][-1]:.3f}',
        'eval_det_success_256_random': f'{last_eval:.3f}',
        'command': command})
  ax_train.set_xlabel('env steps (M)')
  ax_train.set_ylabel('success rate')
  ax_train.set_title('success: training episodes (lines), deterministic eval (dots)')
  ax_train.legend(fontsize=7)
  ax_train.grid(alpha=0.3)
  ax_sps.set_xlabel('env steps (M)')
  ax_sps.set_ylabel('env steps / s (thousands)')
  ax_sps.set_title('training throughput, one H200 (incl. gradient updates)')
  ax_sps.grid(alpha=0.3)
  fig.tight_layout()
  fig.savefig(os.path.join(args.dir, 'training_curves.png'), dpi=110)
  lines = ['# SAC training runs (one NVIDIA H200, jax 0.11.2, python 3.12)', '',
           'Runs made with experiments/train.py on the GPU machine; metrics.csv of each run is '
           'in this folder. Wall time includes compilation and periodic evaluation.', '',
           common.markdown_table(table, list(table[0]))]
  with open(os.path.join(args.dir, 'training.md'), 'w') as f:
    f.write('\n'.join(lines) + '\n')
  print(json.dumps(table, indent=1))


if __name__ == '__main__':
  main()
