"""The joint state a Touch arm reports and a controller commands, and what every closed-loop run records of them
(no simulator needed to use it)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .pushing import BlockPosition


@dataclass
class ArmState:
    """Measured state of one arm: angles θ [rad], velocities θ̇ [rad/s], reaction torques τ [N m], each ``(3,)``."""

    theta: np.ndarray
    dtheta: np.ndarray
    tau: np.ndarray

    def as_vector(self) -> np.ndarray:
        """``(9,)``: θ, θ̇, τ concatenated."""
        return np.concatenate([self.theta, self.dtheta, self.tau])


@dataclass
class RunRecord:
    """What every closed-loop run records, sampled every ``dt`` [s]: the block placement ``position``, the Touch
    slave's joint state ``slave_theta/dtheta/tau`` and the held command in force ``command_theta/dtheta/tau``, each
    ``(K, 3)`` [rad, rad/s, N m]. :class:`seqmotion.lfd.rollout.AutonomousRun` and
    :class:`seqmotion.lfd.env.robot.RobotRun` add what their body records."""

    position: BlockPosition
    dt: float
    slave_theta: np.ndarray
    slave_dtheta: np.ndarray
    slave_tau: np.ndarray
    command_theta: np.ndarray
    command_dtheta: np.ndarray
    command_tau: np.ndarray
