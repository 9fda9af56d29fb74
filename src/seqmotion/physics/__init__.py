"""Differentiable, batched physics every task shares: the double integrator, named state layouts, typed physics
parameters and the direct transcription. A built-in task's own physics is in its folder
(:mod:`seqmotion.tasks.pancake.physics`, :mod:`seqmotion.tasks.sliding.physics`)."""

from . import integrator

__all__ = ["integrator"]
