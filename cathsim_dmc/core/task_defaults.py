"""The navigation task's defaults (the paper's task), importable without dm_control or MuJoCo.

They are the keyword defaults of the Python API (`tasks.load`, `Navigate`, `NavigationReward`,
`StartPose`, the arena's physics) and of the command-line tools (cathsim_dmc.app.train_schema's
TaskConfig), defined once here. They sit in the lowest layer rather than beside `Navigate`
because the tools' schemas read them, and a command line must be checked (and a typo refused)
before the simulator loads: importing cathsim_dmc.tasks loads dm_control and MuJoCo.
"""

import math

SUCCESS_RADIUS_M = 0.004  # the paper's delta: the tip within 4 mm of the target succeeds
SUCCESS_REWARD = 10.0  # the reward of the step that succeeds
DENSE_REWARD = True  # minus the distance every step (False: only the success reward)
MAX_STEPS = 300  # the paper's episode limit, in control steps
# Safe success (the evaluation reports' safe_success_pct): the target reached without any
# control step's wall force (the step's mean) above this, newtons.
SAFE_FORCE_N = 1.5
# The start pose: the robot's rotation drawn from START_ROTATION_RAD +- START_ROTATION_JITTER_RAD
# (pi: the tip's bend in the view's plane), its insertion from [0, START_INSERTION_JITTER_M].
START_ROTATION_RAD = math.pi
START_ROTATION_JITTER_RAD = 0.3
START_INSERTION_JITTER_M = 0.002
# The solver settings' name (cathsim_dmc.sim.physics.PHYSICS_SETTINGS): PGS, prism wall; docs/model.md#physics
PHYSICS = "fast"
