"""PushT-Obs obstacle layouts as data: the blocks on the table and the region the T starts in
(frames, units and checks: docs/tasks.md)."""

from __future__ import annotations

import dataclasses
from typing import Dict, Tuple

import numpy as np

Range = Tuple[float, float]
Block = Tuple[float, float, float, float, float]

TWO_PI = 2.0 * np.pi


@dataclasses.dataclass(frozen=True)
class Layout:
  """One PushT-Obs table (world frame, m and rad; see the module docstring).

  name: its name in `LAYOUTS`; kind: what the T must do, in a few words; description: the
  layout in a sentence or two. blocks: rows (cx, cy, half_x, half_y, yaw).
  start_x, start_y, start_yaw: (low, high) of the T's start pose.
  """

  name: str
  kind: str
  blocks: Tuple[Block, ...]
  start_x: Range
  start_y: Range
  start_yaw: Range = (0.0, TWO_PI)
  description: str = ''

  def blocks_array(self) -> np.ndarray:
    """[M, 5] float32 blocks (M may be 0)."""
    return np.array(self.blocks, np.float32).reshape(-1, 5)

  def in_start_region(self, poses: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """[N] bool: poses [N, 3] (x, y, yaw) inside the start region (the yaw range read modulo
    2 pi: a free T's pose reads its yaw in [-pi, pi])."""
    poses = np.asarray(poses, np.float64)
    ok = np.ones(len(poses), bool)
    for k, (lo, hi) in enumerate((self.start_x, self.start_y)):
      ok &= (poses[:, k] >= lo - tol) & (poses[:, k] <= hi + tol)
    lo, hi = self.start_yaw
    if hi - lo < 2 * np.pi - tol:
      offset = np.mod(poses[:, 2] - lo + tol, 2 * np.pi) - tol
      ok &= offset <= hi - lo + tol
    return ok


def _box(x0: float, x1: float, y0: float, y1: float) -> Block:
  """An axis-aligned block row from its extents: x in [x0, x1], y in [y0, y1] (m)."""
  return (round((x0 + x1) / 2, 6), round((y0 + y1) / 2, 6), round((x1 - x0) / 2, 6),
          round((y1 - y0) / 2, 6), 0.0)


DEFAULT = 'gate'

LAYOUTS: Dict[str, Layout] = {l.name: l for l in (
    Layout(
        name='gate', kind='pass between two blocks',
        blocks=(_box(-0.50, -0.16, 0.06, 0.10), _box(0.08, 0.25, 0.06, 0.10)),
        start_x=(-0.36, -0.22), start_y=(0.20, 0.30),
        description='The original PushT-Obs: two blocks across the table above the goal leave '
                    'a 0.24 m gap to the right of the line from the starts (above the left '
                    'block) to the goal; the T must be pushed between the blocks.'),
    Layout(
        name='slot', kind='pass a narrow gap turned',
        blocks=(_box(-0.50, -0.235, 0.03, 0.07), _box(-0.075, 0.20, 0.03, 0.07)),
        start_x=(-0.22, -0.09), start_y=(0.20, 0.30),
        description='A wall above the goal with a 0.16 m slot straight in front of the starts, '
                    'narrower than the T (0.2 m at its narrowest): the T must be turned while '
                    'it passes, one arm after the other.'),
    Layout(
        name='wall', kind='go around a wall',
        blocks=(_box(-0.32, -0.08, 0.03, 0.07),),
        start_x=(-0.28, -0.12), start_y=(0.20, 0.30),
        description='A 0.24 m wall between the starts and the goal: the T must be pushed around '
                    'one of its ends.'),
    Layout(
        name='detour', kind='move away from the goal first',
        blocks=(_box(-0.32, 0.02, -0.29, -0.25), _box(-0.32, -0.28, -0.36, -0.29),
                _box(-0.02, 0.02, -0.36, -0.29)),
        start_x=(-0.20, -0.10), start_y=(-0.46, -0.39),
        description='The T starts below the goal under a cap (a wall with a lip at each end) '
                    'that opens away from the goal: it must first be pushed down, out from '
                    'under the cap, then around one of its ends and up.'),
    Layout(
        name='two-gaps', kind='pass two offset gaps in series',
        blocks=(_box(-0.50, -0.36, 0.13, 0.17), _box(-0.12, 0.10, 0.13, 0.17),
                _box(-0.45, -0.21, 0.0, 0.04), _box(0.03, 0.15, 0.0, 0.04)),
        start_x=(-0.14, -0.02), start_y=(0.25, 0.30),
        description='Two walls above the goal, each with a 0.24 m gap, the upper one on the '
                    'left, the lower one on the right: the T must zigzag through both.'),
    Layout(
        name='legacy', kind='blocks that most starts never meet',
        blocks=((-0.245, 0.035, 0.02, 0.02, 0.0), (-0.065, 0.035, 0.02, 0.02, 0.0),
                (-0.156, -0.265, 0.05, 0.02, 0.0)),
        start_x=(-0.256, -0.056), start_y=(-0.2, 0.1),
        description='PushT-Obs before the layouts (its results up to then): two 4 cm blocks '
                    'make a 0.14 m gate above the goal, a third blocks the push from below; '
                    'starts at the goal + U[-0.1, 0.1] x U[-0.1, 0.2].'),
)}

NAMES = tuple(LAYOUTS)


def layout(name: str) -> Layout:
  """The named layout; raises ValueError listing the valid names."""
  if name not in LAYOUTS:
    raise ValueError(f'unknown PushT-Obs layout {name!r}; valid layouts: {", ".join(NAMES)}')
  return LAYOUTS[name]
