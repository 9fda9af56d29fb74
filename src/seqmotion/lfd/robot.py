"""``seqmotion.lfd.robot``: the pushing world on a standard arm, now :mod:`seqmotion.lfd.env.robot`; its episodes
(:func:`run_trial`) run through :mod:`seqmotion.lfd.rollout` and its evaluation (:func:`run_on_robot`) is in
:mod:`seqmotion.lfd.evaluation` (this name stays importable).
"""

from __future__ import annotations

from .env.robot import (
    BASE as BASE,
)
from .env.robot import (
    GAINS_PUSHING as GAINS_PUSHING,
)
from .env.robot import (
    MODES as MODES,
)
from .env.robot import (
    PEN_LENGTH as PEN_LENGTH,
)
from .env.robot import (
    PEN_YAW as PEN_YAW,
)
from .env.robot import (
    SENSE_CUTOFF_HZ as SENSE_CUTOFF_HZ,
)
from .env.robot import (
    TIP_FILTER_HZ as TIP_FILTER_HZ,
)
from .env.robot import (
    TIP_FLOOR as TIP_FLOOR,
)
from .env.robot import (
    PenRobot as PenRobot,
)
from .env.robot import (
    RobotPushingScene as RobotPushingScene,
)
from .env.robot import (
    RobotRun as RobotRun,
)
from .env.robot import (
    TipFilter as TipFilter,
)
from .env.robot import (
    TipTracking as TipTracking,
)
from .env.robot import (
    TouchTwin as TouchTwin,
)
from .env.robot import (
    pen_down_rotation as pen_down_rotation,
)
from .env.robot import (
    touch_angles as touch_angles,
)
from .env.robot import (
    touch_jacobian as touch_jacobian,
)
from .env.robot import (
    track_tip as track_tip,
)
from .evaluation import (
    RobotEvaluation as RobotEvaluation,
)
from .evaluation import (
    run_on_robot as run_on_robot,
)
from .rollout import (
    run_trial as run_trial,
)
