"""Latent-space adjustment (ch. 4): gradient descent on z for any differentiable objective, exact polish,
and the sliding planner's tracking refinement."""

from . import objectives
from .optimize import OptimizationResult, optimize_latent, optimize_trajectory
from .tracking import Tracking, refine_plan

__all__ = ["OptimizationResult", "Tracking", "objectives", "optimize_latent", "optimize_trajectory", "refine_plan"]
