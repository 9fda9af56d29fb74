"""Trajectory batches and the generators every task shares, apart from any model. A built-in task's own input
generators are in its folder (:mod:`seqmotion.tasks.pancake.data`, :mod:`seqmotion.tasks.sliding.data`)."""

from . import trajectories
from .trajectories import TrajectoryBatch

__all__ = ["TrajectoryBatch", "trajectories"]
