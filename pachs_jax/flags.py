"""The command-line flags of `SearchConfig` fields, declared once for `pachs plan` and the
experiment scripts (no JAX import: flags are checked before JAX starts)."""

from __future__ import annotations

import argparse
from typing import Dict, Optional, Sequence

from pachs_jax import argtypes

REALTIME_ANSWERS = ('best_f', 'min_h', 'min_cost')  # SearchConfig.realtime_answer
CHAIN_RESTARTS = ('start', 'novel')  # SearchConfig.chain_restart
AFTER_GOALS = ('stop', 'improve')  # SearchConfig.after_goal

# SearchConfig field -> (flags, add_argument keywords); every default None: the task's
SEARCH_FLAGS: Dict[str, tuple] = {
    'weight': (('--weight', '-w'), dict(type=argtypes.number(0.0),
                                        help='heuristic weight w')),
    'num_actions': (('--num-actions', '-N'), dict(type=argtypes.positive_int,
                                                 help='actions per expansion')),
    'pop_size': (('--pop-size', '-K'), dict(type=argtypes.positive_int,
                                           help='edges popped per iteration')),
    'edge_steps': (('--edge-steps', '-H'), dict(
        type=argtypes.positive_int,
        help="transitions per edge (default: the task's; 1 = one-step edges)")),
    'rollout_share': (('--rollout-share',), dict(
        type=argtypes.number(0.0, 1.0, high_open=True),
        help="the share of the K lanes that extend chains of the actor's edges "
        "(default: the task's; 0: none)")),
    'chain_restart': (('--chain-restart',), dict(
        choices=CHAIN_RESTARTS, help="where a chain of the actor's edges restarts: the start, "
        "or a node of a rarely visited coarse cell (default: the task's)")),
    'after_goal': (('--after-goal',), dict(
        choices=AFTER_GOALS, help="what the first goal does: stop the search, or improve the "
        "path with the evaluations that remain (default: the task's)")),
    'improve_allowance': (('--improve-allowance',), dict(
        type=argtypes.number(0.0, allow_inf=True),
        help="with --after-goal improve, the evaluations spent after the first "
        "goal as a multiple of those spent up to it ('inf': until the budget ends; default: "
        "the task's)")),
    'uniform_share': (('--uniform-share',), dict(
        type=argtypes.number(0.0, 1.0),
        help="the probability that an action the search draws from the actor is "
        "drawn uniformly instead (default: the task's; 0: the actor's alone)")),
    'lattice_resolution': (('--lattice-resolution',), dict(
        type=lambda s: argtypes.numbers(s, 'cell sizes'),
        help='lattice cell sizes, comma separated')),
    'compact_fractions': (('--compact-fractions',), dict(
        type=lambda s: argtypes.numbers(s, 'fractions'),
        help='smaller physics batches as fractions of the I x K lanes, comma separated '
        "('' simulates every lane; default on a GPU: envs.registry.ACCELERATOR_SEARCH; on a "
        'CPU none)')),
    'realtime_answer': (('--realtime-answer',), dict(
        choices=REALTIME_ANSWERS, help="the state an unfinished search answers with: best_f "
        "(the best OPEN entry's; the original algorithm's and a user's task's default), min_h "
        "(least estimated cost-to-go) or min_cost (least cost per transition of the edge into "
        "the state; PushT's default)")),
}


def add_search_flags(parser: argparse.ArgumentParser, fields: Sequence[str],
                     defaults: Optional[dict] = None) -> None:
  """Adds the flags of the named SearchConfig fields (`SEARCH_FLAGS`), default None (the
  task's) unless `defaults` names another."""
  defaults = defaults or {}
  for field in fields:
    names, keywords = SEARCH_FLAGS[field]
    parser.add_argument(*names, dest=field, default=defaults.get(field), **keywords)


def search_overrides(args: argparse.Namespace, fields: Sequence[str] = tuple(SEARCH_FLAGS)):
  """{field: value} of the SearchConfig flags in args (those the parser has)."""
  return {field: getattr(args, field) for field in fields if hasattr(args, field)}
