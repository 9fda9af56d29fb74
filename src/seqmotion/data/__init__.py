"""Trajectory generators and datasets, apart from any model."""

from . import pancake, sliding, trajectories
from .trajectories import TrajectoryBatch

__all__ = ["TrajectoryBatch", "pancake", "sliding", "trajectories"]
