"""Latent-space adjustment (ch. 4): gradient descent on z for any differentiable objective of any task
(:mod:`.objectives`, :mod:`.optimize`) and the exact polish, on trained models (``core``) and below the tasks: what
belongs beside one task is in its folder, built on this — the pancake's J2 bands and IPOPT peer
(:mod:`seqmotion.tasks.pancake.latent`), the sliding planner's tracking refinement
(:mod:`seqmotion.tasks.sliding.latent`) — and a robot's rated limits as an objective are the robot layer's
(:class:`seqmotion.sim.ArmLimits`)."""

from . import objectives
from .optimize import OptimizationResult, optimize_latent, optimize_trajectory

__all__ = ["OptimizationResult", "objectives", "optimize_latent", "optimize_trajectory"]
