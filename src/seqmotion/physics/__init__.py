"""Differentiable, batched physics: the shared double integrator and one module per task."""

from . import integrator, pancake

__all__ = ["integrator", "pancake"]
