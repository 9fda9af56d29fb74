"""``seqmotion.lfd.teleop``: bilateral teleoperation, now :mod:`seqmotion.lfd.env.teleop`, and the closed loop with
a command source in the master's place, now :mod:`seqmotion.lfd.rollout` (this name stays importable).
"""

from __future__ import annotations

from .env.teleop import (
    MOTION_COLUMNS as MOTION_COLUMNS,
)
from .env.teleop import (
    ArmServo as ArmServo,
)
from .env.teleop import (
    ArmState as ArmState,
)
from .env.teleop import (
    BilateralGains as BilateralGains,
)
from .env.teleop import (
    Demonstration as Demonstration,
)
from .env.teleop import (
    Operator as Operator,
)
from .env.teleop import (
    ReplayMaster as ReplayMaster,
)
from .env.teleop import (
    TouchSlave as TouchSlave,
)
from .env.teleop import (
    bilateral_torques as bilateral_torques,
)
from .env.teleop import (
    motion_matrix as motion_matrix,
)
from .env.teleop import (
    slave_torque as slave_torque,
)
from .env.teleop import (
    teleoperate as teleoperate,
)
from .rollout import (
    AutonomousRun as AutonomousRun,
)
from .rollout import (
    run_autonomous as run_autonomous,
)
