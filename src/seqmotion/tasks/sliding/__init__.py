"""The sliding task (ch. 3): shaking a frying pan so an object slides along a commanded path.

One folder for what is the sliding task's alone:

* :mod:`.task` — the task (:class:`SlidingTask`: options, curriculum, loss, errors), its plan
  (:class:`SlidingPlan`) and planner (:class:`SlidingPlanner`, ``sm.load_pretrained("sliding")``);
* :mod:`.robot` — the plan on a robot: the execution check's result (:class:`SlidingExecutionCheck`) and the
  robot's joint limits as a latent objective term (:class:`PanJointLimits`).

Its other parts sit in the layers their imports allow (``tests/test_layers.py``): the contact physics
:mod:`seqmotion.physics.sliding` and the command generators :mod:`seqmotion.data.sliding` below the task
contract (the task and its planner import them), the tracking refinement :mod:`seqmotion.latent.sliding` (built on
the latent optimiser) and the simulated run :mod:`seqmotion.sim.sliding` (MuJoCo) above it.
"""

from ...core.execution import BindingLimit, ExecutionCheck
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
    "friction_trained", "model_config", "pan_acceleration_reach", "training_friction", "warn_if_not_executable",
]
