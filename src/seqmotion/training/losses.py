"""Loss terms shared by tasks: Gaussian negative log-likelihoods with a variance floor.

The likelihood terms (eqs. 2.22, 3.21, 3.24) score a target position against the generated
one under the propagated covariance. That covariance starts at exactly zero (``S_x[0] = 0``)
and the first samples' variances are ~dt⁴σ² ≈ 1e-12 σ², which makes the NLL explode and
overflow float32. We therefore add a **variance floor** ``floor · I`` to every covariance
before scoring; ``floor = 1e-8`` (a standard deviation of 0.1 mm, or 1 mrad after D's 0.1
scaling of θ) by default. Below that accuracy the loss stops rewarding precision, which is
far below what a robot can track. The closed forms below avoid batched Cholesky calls.
"""

from __future__ import annotations

import math

import torch

DEFAULT_VARIANCE_FLOOR = 1e-8
_LOG_2PI = math.log(2 * math.pi)


def gaussian_nll_1d(diff: torch.Tensor, var: torch.Tensor, floor: float = DEFAULT_VARIANCE_FLOOR) -> torch.Tensor:
    """``-log N(diff | 0, var + floor)`` elementwise."""
    v = var + floor
    return 0.5 * (diff**2 / v + torch.log(v) + _LOG_2PI)


def gaussian_nll_2d(diff: torch.Tensor, cov: torch.Tensor, floor: float = DEFAULT_VARIANCE_FLOOR) -> torch.Tensor:
    """``-log N(diff | 0, cov + floor I)`` for ``diff (..., 2)``, ``cov (..., 2, 2)`` → ``(...)``."""
    a = cov[..., 0, 0] + floor
    b = 0.5 * (cov[..., 0, 1] + cov[..., 1, 0])
    c = cov[..., 1, 1] + floor
    det = a * c - b * b
    dx, dy = diff[..., 0], diff[..., 1]
    quad = (c * dx * dx - 2 * b * dx * dy + a * dy * dy) / det
    return 0.5 * (quad + torch.log(det)) + _LOG_2PI
