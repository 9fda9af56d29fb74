"""The sliding task (ch. 3): shaking a frying pan so an object slides along a commanded path.

One folder for what is the sliding task's alone, each file in the layer of its role (``tests/test_layers.py``):

* :mod:`.physics` — the Coulomb stick/slip contact (numba kernels with a hand-derived backward, the torch path for
  the GPU and the export) and ``SlidingPhysics`` (rank of ``physics``);
* :mod:`.data` — the physics-type and B-spline training commands and the named ones (``circle``, ``line``,
  ``figure_eight``, ``sm.tasks.sliding.data.circle``) that ``seqmotion plan`` and the reproductions plan for
  (rank of ``data``);
* :mod:`.task` — the task (:class:`SlidingTask`: options, curriculum, loss, errors), its plan
  (:class:`SlidingPlan`) and planner (:class:`SlidingPlanner`, ``sm.load_pretrained("sliding")``), exported here;
* :mod:`.robot` — the plan on a robot: the execution check's result (:class:`SlidingExecutionCheck`) and the
  robot's joint limits as a latent objective term (:class:`PanJointLimits`), which the planner keeps (the task's
  rank);
* :mod:`.latent` — ``refine_plan`` and the ``Tracking`` objective, built on the latent optimiser, which sits below
  the tasks (the task's rank; not imported here: ``sm.refine_plan``).

Its MuJoCo run and its check on a simulated arm stay in :mod:`seqmotion.sim.sliding` and
:mod:`seqmotion.sim.executable_sliding`, beside the simulator's other scenes.
"""

from ...core.execution import BindingLimit, ExecutionCheck
from . import data, physics
from .robot import (
    ACCEL_MARGIN,
    ACCEPT_CLEARANCE,
    ACCEPT_SHARE,
    RANGE_CLEARANCE,
    ROBOT_KINDS,
    ROBOT_MARGIN,
    RUN_KINDS,
    PanJointLimits,
    SlidingExecutionCheck,
    check_limit_kinds,
    pan_acceleration_reach,
)
from .task import (
    PAN_LIMIT,
    RESULT_PARTS,
    TASK,
    TRACKING_TOLERANCE,
    TRADE_OFF,
    VARIANTS,
    SlidingOptions,
    SlidingParams,
    SlidingPlan,
    SlidingPlanner,
    SlidingTask,
    chapter3_curriculum,
    command_tracking,
    friction_trained,
    model_config,
    training_friction,
    warn_if_not_executable,
)

__all__ = [
    "ACCEL_MARGIN", "ACCEPT_CLEARANCE", "ACCEPT_SHARE", "PAN_LIMIT", "RANGE_CLEARANCE", "RESULT_PARTS", "ROBOT_KINDS",
    "ROBOT_MARGIN", "RUN_KINDS", "TASK", "TRACKING_TOLERANCE", "TRADE_OFF", "VARIANTS", "BindingLimit",
    "ExecutionCheck", "PanJointLimits", "SlidingExecutionCheck", "SlidingOptions", "SlidingParams", "SlidingPlan",
    "SlidingPlanner", "SlidingTask", "chapter3_curriculum", "check_limit_kinds", "command_tracking",
    "data", "friction_trained", "model_config", "pan_acceleration_reach", "physics", "training_friction",
    "warn_if_not_executable",
]
