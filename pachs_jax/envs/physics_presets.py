"""PushT's named physics settings: PushTConfig fields over its defaults, in a module without
MuJoCo so that scripts check a preset name before loading it (experiments/results/physics/
has the measurements)."""

PHYSICS_PRESETS = {
    # the defaults: ManiSkill PushT-v1's free T (0.8 kg, under gravity) with stiff blocks; T-table
    # friction 1.65 is PhysX's average of the T's material (3) and ManiSkill's default (0.3);
    # 2.5 ms x 20 steps and 20 solver iterations hold the stiff contacts
    'faithful': {},
    # the faithful physics with the blocks' contacts acting from 3 mm: block penetration under
    # 2 mm over the policy's pushes at the faithful cost per step (a candidate for the default;
    # 1.25 ms x 40 steps with a 2 mm margin also held it, at twice the cost)
    'hard-blocks': dict(block_margin=0.003),
    # a T that slides and turns on the table plane (joints with friction loss, no gravity) at
    # 12.5 ms x 4, soft blocks: about 9x cheaper per step in MuJoCo C, the CPU tests' physics
    # (the shipped models were not trained on it)
    'planar': dict(t_body='planar', table_friction=0.5, physics_dt=0.0125, substeps=4,
                   solver_iterations=4, ls_iterations=8, block_solref=None, block_solimp=None),
}
NAMES = tuple(PHYSICS_PRESETS)
