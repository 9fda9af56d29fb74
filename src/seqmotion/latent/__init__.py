"""Latent-space adjustment (ch. 4): gradient descent on z for any differentiable objective."""

from . import objectives
from .optimize import OptimizationResult, optimize_latent, optimize_trajectory

__all__ = ["OptimizationResult", "objectives", "optimize_latent", "optimize_trajectory"]
