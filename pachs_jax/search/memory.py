"""Will the search fit? The device memory of a PACHS search state, from its config, checked
before compiling (a budget that cannot fit is refused, naming the largest one that can)."""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Callable, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from pachs_jax.envs import base


def tree_bytes(tree) -> int:
  """Bytes of every array (or ShapeDtypeStruct) leaf of tree."""
  return sum(int(np.prod(x.shape, dtype=np.int64)) * np.dtype(x.dtype).itemsize
             for x in jax.tree.leaves(tree))


def device_memory(device=None) -> Tuple[int, str]:
  """(bytes the search may use on device, how that was found).

  An accelerator: `memory_stats()`'s bytes_limit less bytes_in_use; otherwise (the CPU, or no
  statistics) the machine's physical RAM.
  """
  device = jax.devices()[0] if device is None else device
  stats = None
  try:
    stats = device.memory_stats()
  except Exception:  # pylint: disable=broad-except  (backends without statistics)
    stats = None
  if stats and stats.get('bytes_limit'):
    limit, in_use = int(stats['bytes_limit']), int(stats.get('bytes_in_use', 0))
    return limit - in_use, (f'{device.platform}:{device.id} has {_gb(limit - in_use)} free of '
                            f'{_gb(limit)}')
  ram = os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES')
  return ram, f'the machine has {_gb(ram)} of RAM'


def _gb(num_bytes: float) -> str:
  """'61.2 GB' (MB below 0.1 GB, TB from 1000 GB)."""
  for unit, scale in (('TB', 1e12), ('GB', 1e9)):
    if num_bytes >= 0.1 * scale * (10 if unit == 'TB' else 1):
      return f'{num_bytes / scale:.3g} {unit}'
  return f'{num_bytes / 1e6:.3g} MB'


def _instance_specs(start_nodes: base.NodeState, num_instances: int):
  """ShapeDtypeStructs of start_nodes and [I, 2] keys with num_instances rows."""
  nodes = jax.tree.map(lambda x: jax.ShapeDtypeStruct((num_instances,) + np.shape(x)[1:],
                                                      jnp.result_type(x)), start_nodes)
  return nodes, jax.ShapeDtypeStruct((num_instances, 2), jnp.uint32)


def search_bytes(search, start_nodes: base.NodeState, num_instances: int) -> int:
  """Device bytes of a PACHS search over num_instances instances shaped like start_nodes: its
  state (`Search.init`, exact, traced without running) plus the SearchResult; one iteration's
  working set is `iteration_bytes`'s."""
  nodes, keys = _instance_specs(start_nodes, num_instances)
  state = jax.eval_shape(search.init, nodes, keys)
  return tree_bytes(state) + tree_bytes(jax.eval_shape(search.result, state))


def iteration_bytes(env: base.Env, config, num_instances: int) -> int:
  """A lower bound of the device bytes one iteration works on beside the search state, for
  num_instances instances: the expansion's network batch (I x K states: the state, its
  observation, N sampled actions and their Q) and the evaluation's physics batch (I x K edges
  of H transitions: a state, an action, a cost and flags per transition), each counted twice
  (inputs and outputs). A physics engine's own buffers (MJX's per-world data) come on top."""
  node_bytes = tree_bytes(env.node_spec)
  lanes = num_instances * config.pop_size
  steps = getattr(config, 'edge_steps', 1)
  expansion = node_bytes + 4 * env.observation_size + config.num_actions * 4 * (
      env.action_size + 1)
  evaluation = steps * (node_bytes + 4 * env.action_size + 8)
  return 2 * lanes * (expansion + evaluation)


def largest_budget(bytes_at, budget: int, available: int, minimum: int = 1) -> int:
  """The largest budget in [minimum, budget] whose bytes_at(budget) <= available, within 0.5%
  (0 when even `minimum` does not fit). bytes_at must grow with the budget; it grows about
  linearly, so each probe interpolates between the budgets known to fit and not to fit, and a
  probe that fits is followed by one 0.5% above it (one that does not, by one 0.5% below),
  which ends the search where the line was right (bisection where it was not)."""
  low, low_bytes = minimum, bytes_at(minimum)
  if low_bytes > available:
    return 0
  high, high_bytes = budget, bytes_at(budget)
  if high_bytes <= available:
    return budget
  close = lambda low, high: high - low <= max(1, low // 200)
  interpolate = True
  while not close(low, high):
    if interpolate:
      probe = low + int((available - low_bytes) * (high - low) // max(high_bytes - low_bytes, 1))
    else:
      probe = int(math.sqrt(low * high)) if high > 2 * low else (low + high) // 2
    probe = min(max(probe, low + 1), high - 1)
    width = high - low
    fits = (probe_bytes := bytes_at(probe)) <= available
    if fits:
      low, low_bytes = probe, probe_bytes
      probe = min(low + max(1, low // 200), high - 1)  # 0.5% above: not fitting, it ends it
    else:
      high, high_bytes = probe, probe_bytes
      probe = max(high - max(1, high // 201), low + 1)  # 0.5% below: fitting, it ends it
    if not close(low, high):
      if (probe_bytes := bytes_at(probe)) <= available:
        low, low_bytes = probe, probe_bytes
      else:
        high, high_bytes = probe, probe_bytes
    interpolate = high - low < width // 4 or not interpolate  # bisect after a poor guess
  return low


def _round_down(n: int) -> int:
  """n rounded down to 3 significant digits."""
  if n < 1000:
    return n
  scale = 10**(len(str(n)) - 3)
  return n // scale * scale


def check_fits(search_for: Callable, search, start_nodes: base.NodeState, num_instances: int,
               device=None, need: Optional[int] = None, working: int = 0) -> int:
  """Returns the device bytes of a PACHS search of num_instances (padded) instances, its state
  and one iteration's working set; ValueError when they exceed the device's memory
  (`device_memory`), naming K and N when the working set is the larger part, else the largest
  budget that fits beside the working set. search_for(config) -> the search
  of another budget (e.g. `make_search` with env, model and the search's capacities bound).
  need: the state's bytes when the caller knows them (None: traced with `search_bytes`).
  working: one iteration's bytes (`iteration_bytes`). Compiles nothing."""
  config = search.config
  available, where = device_memory(device)
  need = search_bytes(search, start_nodes, num_instances) if need is None else need
  if need + working <= available:
    return need + working
  if working >= need:  # K and N, not the budget, are what does not fit
    raise ValueError(f'K={config.pop_size} (pop_size) and N={config.num_actions} need at least '
                     f'{_gb(working)} per iteration for {num_instances} '
                     f'instance{"s" * (num_instances > 1)} per device, but {where}: lower -K or '
                     '-N, or plan fewer instances at once')
  available -= working

  def bytes_at(budget):
    if budget == config.budget:
      return need
    smaller = search_for(dataclasses.replace(config, budget=budget))
    return search_bytes(smaller, start_nodes, num_instances)

  steps = getattr(config, 'edge_steps', 1)  # a budget below one edge's transitions is invalid
  best = largest_budget(bytes_at, config.budget, available, minimum=steps)
  what = (f'the budget of {config.budget:,} evaluations needs {_gb(need)} of search '
          f'state for {num_instances} instance{"s" * (num_instances > 1)} per device, but '
          f'{where}')
  if best == 0:
    raise ValueError(f'{what}; not even a budget of {steps} fits: plan fewer instances at once')
  raise ValueError(f'{what}: the largest budget that fits is about {_round_down(best):,} (or '
                   'plan fewer instances at once)')
