"""Latent-space adjustment (ch. 4): gradient descent on z for any differentiable objective of any task
(:mod:`.objectives`, :mod:`.optimize`), the exact polish, and what belongs beside one task: the pancake's J2
bands and IPOPT peer (:mod:`.pancake`), the sliding planner's tracking refinement (:mod:`.sliding`)."""

from . import objectives
from .optimize import OptimizationResult, optimize_latent, optimize_trajectory
from .sliding import Tracking, refine_plan

__all__ = ["OptimizationResult", "Tracking", "objectives", "optimize_latent", "optimize_trajectory", "refine_plan"]
