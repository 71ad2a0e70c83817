"""Planning baselines of the experiments: rollouts of the policy, parallel beam search,
ePA*SE with a BFS-3D heuristic and MPPI, each jitted, batched over instances, returning
`SearchResult`."""

from pachs_jax.search.baselines.beam import BeamConfig, make_beam_search
from pachs_jax.search.baselines.common import replay
from pachs_jax.search.baselines.epase import Epase, EpaseConfig, Heuristic, make_epase
from pachs_jax.search.baselines.mppi import Mppi, MppiConfig, MppiState, make_mppi, shift_plan
from pachs_jax.search.baselines.rollouts import (ParallelRollout, ParallelRolloutConfig,
                                                 SingleRolloutConfig, make_parallel_rollout,
                                                 make_single_rollout)
from pachs_jax.search.baselines.voxel import (ShelfEpaseSetup, VoxelGrid, bfs_distance,
                                              box_occupancy, grid_heuristic, shelf_setup)

__all__ = ['BeamConfig', 'Epase', 'EpaseConfig', 'Heuristic', 'Mppi', 'MppiConfig', 'MppiState',
           'ParallelRollout', 'ParallelRolloutConfig', 'ShelfEpaseSetup', 'SingleRolloutConfig',
           'VoxelGrid', 'bfs_distance', 'box_occupancy', 'grid_heuristic', 'make_beam_search',
           'make_epase', 'make_mppi', 'make_parallel_rollout', 'make_single_rollout', 'replay',
           'shelf_setup', 'shift_plan']
