"""Statistics of the experiments: success-rate intervals, success curves, cost ratios, means."""

from __future__ import annotations

import math
from typing import Dict, List

import numpy as np
from pachs_jax.search.result import StopReason



def wilson_interval(successes: int, total: int, z: float = 1.96):
  """95% Wilson score interval (lower, upper) of a success rate."""
  if total == 0:
    return (math.nan, math.nan)
  p = successes / total
  centre = (p + z * z / (2 * total)) / (1 + z * z / total)
  half = z * math.sqrt(p * (1 - p) / total + z * z / (4 * total * total)) / (1 + z * z / total)
  low = 0.0 if successes == 0 else max(0.0, centre - half)
  high = 1.0 if successes == total else min(1.0, centre + half)
  return (low, high)


def mcnemar_p(only_a: int, only_b: int) -> float:
  """Exact two-sided McNemar p-value of paired binary outcomes: only_a pairs where only the
  first succeeded, only_b where only the second did (the other pairs carry no information)."""
  n, k = only_a + only_b, min(only_a, only_b)
  if n == 0:
    return 1.0
  return min(1.0, 2 * sum(math.comb(n, i) for i in range(k + 1)) / 2**n)


def most_behind(rows_a: List[Dict], rows_b: List[Dict], budgets, start: int = 3000):
  """Where planner a's success curve trails planner b's most, at the budgets >= start, on runs
  paired by (instance, round), a run solved at every budget >= its first goal's evaluations:
  (the runs behind, 0 where a never trails; that budget, None; the exact McNemar p of the
  paired outcomes there, None). The rounds of one instance are not independent runs, so the
  p-value understates the uncertainty: a large p says that the lag is within chance."""
  b_of = {(r['instance'], r['round']): r for r in rows_b}
  solved = lambda r, budget: bool(r['found']) and r.get('first_goal_evaluated',
                                                         r['evaluated']) <= budget
  worst = (0, None, None)
  for budget in (b for b in budgets if b >= start):
    pairs = [(solved(r, budget), solved(b_of[(r['instance'], r['round'])], budget))
             for r in rows_a]
    only_a = sum(x and not y for x, y in pairs)
    only_b = sum(y and not x for x, y in pairs)
    if only_b - only_a > worst[0]:
      worst = (only_b - only_a, budget, mcnemar_p(only_a, only_b))
  return worst


def instance_bootstrap_interval(found, instance, repeats: int = 10_000, seed: int = 0):
  """95% interval of the success rate with the instances resampled (a cluster bootstrap): the
  rounds of one instance are not independent runs (a deterministic planner repeats itself), so
  the instance is the unit of resampling. found, instance: [runs]."""
  found, instance = np.asarray(found, float), np.asarray(instance)
  ids = np.unique(instance)
  per_instance = np.array([found[instance == i].mean() for i in ids])
  rng = np.random.default_rng(seed)
  means = per_instance[rng.integers(0, len(ids), (repeats, len(ids)))].mean(axis=1)
  return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def paired_difference(rows_a: List[Dict], rows_b: List[Dict], budget: int,
                      repeats: int = 20_000, seed: int = 0):
  """Runs solved by budget (first goals) by planner a minus planner b, on runs paired by
  (instance, round), with its 95% interval from resampling the instances (a cluster bootstrap
  of the per-instance differences, as `instance_bootstrap_interval`): (difference, low, high)."""
  b_of = {(r['instance'], r['round']): r for r in rows_b}
  solved = lambda r: bool(r['found']) and r.get('first_goal_evaluated', r['evaluated']) <= budget
  per_instance = {}
  for r in rows_a:
    change = int(solved(r)) - int(solved(b_of[(r['instance'], r['round'])]))
    per_instance[r['instance']] = per_instance.get(r['instance'], 0) + change
  diffs = np.array(list(per_instance.values()))
  rng = np.random.default_rng(seed)
  sums = diffs[rng.integers(0, len(diffs), (repeats, len(diffs)))].sum(axis=1)
  return int(diffs.sum()), float(np.percentile(sums, 2.5)), float(np.percentile(sums, 97.5))


def success_curve(rows: List[Dict], budgets) -> List[float]:
  """Share of runs that found the goal within each budget of evaluations (a run that found its
  goal after e evaluations finds it with any budget >= e: the search up to a budget is a prefix
  of the full search)."""
  return [float(np.mean([r['found'] and r['evaluated'] <= b for r in rows])) for b in budgets]


def cost_ratios(per_planner: Dict[str, List[Dict]]) -> Dict[str, Dict[str, Dict]]:
  """ratio[a][b]: mean over runs both solved of cost_a / cost_b, and how many runs."""
  out = {}
  for a, rows_a in per_planner.items():
    out[a] = {}
    for b, rows_b in per_planner.items():
      pairs = [(x['cost'], y['cost']) for x, y in zip(rows_a, rows_b)
               if x['found'] and y['found'] and y['cost'] > 0]
      out[a][b] = {'mean_ratio': mean_or_none([x / y for x, y in pairs]), 'runs': len(pairs)}
  return out


def mean_or_none(values):
  """The mean as a float, None for no values."""
  return float(np.mean(values)) if len(values) else None


def mean_where(values, mask):
  """The mean of values[mask] (e.g. the cost over successful runs), None where mask is empty."""
  return mean_or_none(np.asarray(values)[np.asarray(mask)])


def stop_counts(stop_reasons) -> Dict[str, int]:
  """{stop reason name: runs}, in code order, reasons that occur only."""
  counts = np.bincount(np.asarray(stop_reasons).ravel())
  return {StopReason.name(c): int(n) for c, n in enumerate(counts) if n}
