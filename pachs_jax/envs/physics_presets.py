"""PushT's named physics settings: PushTConfig fields over its defaults, in a module without
MuJoCo so that scripts check a preset name before loading it (experiments/results/physics/
has the measurements)."""

PHYSICS_PRESETS = {
    # the defaults: ManiSkill PushT-v1's free T (0.8 kg, under gravity) with stiff blocks; T-table
    # friction 1.65 is PhysX's average of the T's material (3) and ManiSkill's default (0.3);
    # 2.5 ms x 20 steps and 20 solver iterations hold the stiff contacts, and the blocks'
    # contacts act from 3 mm, so that the T and the stick stop at a block's face (under 2 mm
    # into it over the policy's pushes, at no cost per step)
    'faithful': {},
    # the faithful physics with the blocks' contacts acting from their faces: the T sinks up to
    # 3 mm into a block, the stick 4.5 mm (the closed-loop screens in closed_loop_soft_gpu/)
    'soft-blocks': dict(block_margin=0.0),
    # a T that slides and turns on the table plane (joints with friction loss, no gravity) at
    # 12.5 ms x 4, soft blocks: about 9x cheaper per step in MuJoCo C, the CPU tests' physics
    # (the shipped models were not trained on it)
    'planar': dict(t_body='planar', table_friction=0.5, physics_dt=0.0125, substeps=4,
                   solver_iterations=4, ls_iterations=8, block_solref=None, block_solimp=None,
                   block_margin=0.0),
}
NAMES = tuple(PHYSICS_PRESETS)

# The contact settings of PushT's blocks: a task without obstacles records none of them.
BLOCK_FIELDS = ('block_solref', 'block_solimp', 'block_margin')


def differing_settings(recorded: dict, simulated: dict) -> list:
  """The sorted names of the physics settings (`Env.physics_settings`) whose values differ
  between a record (a model's, a saved plan's) and an env; a block field counts only where both
  hold it, every other field also where one of them lacks it."""
  unused = {k for k in BLOCK_FIELDS if k not in recorded or k not in simulated}
  return sorted(k for k in (set(recorded) | set(simulated)) - unused
                if recorded.get(k) != simulated.get(k))
