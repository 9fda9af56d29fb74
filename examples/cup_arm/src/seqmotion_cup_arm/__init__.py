"""A seqmotion task with its own physics: a two-link arm carrying an open cup (see ``task.py`` and ``arm.py``)."""

from .arm import CupArmDynamics, CupArmPhysics
from .task import TASK, CupArmOptions, CupArmTask

__all__ = ["TASK", "CupArmDynamics", "CupArmOptions", "CupArmPhysics", "CupArmTask"]
