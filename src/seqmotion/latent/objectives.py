"""Objectives for latent-space adjustment (ch. 4, eqs. 4.3–4.4 and 4.10).

An objective maps a batch of decoded motions to one value per trajectory::

    J(states (B, K, S), accel (B, K-1, d)) -> (B,)

:class:`EndPose` (J1) and :class:`Ranges` (J2) are the dissertation's, for the pancake task's
states ``[y, z, θ, v_y, v_z, v_θ]``. Any differentiable callable with that signature is an
objective too (returning ``(B,)`` or a scalar), and objectives compose with ``+`` and ``*``::

    objective = 2 * EndPose((0.1, 0.0, math.pi)) + my_callable
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import torch

from ..physics.pancake import MU, violation_torch

D_WEIGHTS = (1.0, 1.0, 0.1)
"""D = diag(1, 1, 0.1): metres against radians (eqs. 2.25, 4.3)."""

ObjectiveFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


class Objective:
    """Base class: callable on ``(states, accel)``, composable with ``+`` and ``*``.

    Objectives of least-squares form ``J = |r|² + p`` may also expose ``residuals`` (B, m) and
    ``penalty`` (B,); the Levenberg–Marquardt optimiser (``optimizer="lm"``) needs them.
    """

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def residuals(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        raise ValueError(f"{self!r} has no least-squares residuals; use optimizer='sgd' or 'adam'")

    def penalty(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        raise ValueError(f"{self!r} has no least-squares residuals; use optimizer='sgd' or 'adam'")

    def __add__(self, other: object) -> Objective:
        return Sum([self, as_objective(other)])

    def __radd__(self, other: object) -> Objective:
        if isinstance(other, (int, float)) and other == 0:  # so sum([...]) works
            return self
        return Sum([as_objective(other), self])

    def __mul__(self, weight: float) -> Objective:
        if not isinstance(weight, (int, float)):
            raise ValueError(f"objectives can only be scaled by numbers, got {type(weight).__name__}")
        return Scaled(float(weight), self)

    __rmul__ = __mul__


class Sum(Objective):
    def __init__(self, parts: Sequence[Objective]) -> None:
        self.parts = list(parts)

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return sum(part(states, accel) for part in self.parts)  # type: ignore[return-value]

    def residuals(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return torch.cat([part.residuals(states, accel) for part in self.parts], dim=-1)

    def penalty(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return sum(part.penalty(states, accel) for part in self.parts)  # type: ignore[return-value]

    def __repr__(self) -> str:
        return " + ".join(map(repr, self.parts))


class Scaled(Objective):
    def __init__(self, weight: float, inner: Objective) -> None:
        self.weight, self.inner = weight, inner

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return self.weight * self.inner(states, accel)

    def residuals(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        if self.weight < 0:
            raise ValueError("a negatively weighted objective has no least-squares form")
        return self.weight**0.5 * self.inner.residuals(states, accel)

    def penalty(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return self.weight * self.inner.penalty(states, accel)

    def __repr__(self) -> str:
        return f"{self.weight:g} * {self.inner!r}"


class Function(Objective):
    """Wraps a plain callable ``f(states, accel) -> scalar or (B,) tensor``."""

    def __init__(self, fn: ObjectiveFn) -> None:
        self.fn = fn

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        value = self.fn(states, accel)
        if not torch.is_tensor(value):
            raise ValueError(f"objective {self.fn!r} must return a torch tensor, got {type(value).__name__}")
        if value.ndim > 1 or (value.ndim == 1 and value.shape[0] != states.shape[0]):
            shape = tuple(value.shape)
            raise ValueError(f"objective must return a scalar or one value per trajectory, got shape {shape}")
        return value

    def __repr__(self) -> str:
        return getattr(self.fn, "__name__", repr(self.fn))


def as_objective(value: object) -> Objective:
    if isinstance(value, Objective):
        return value
    if callable(value):
        return Function(value)  # type: ignore[arg-type]
    raise ValueError(f"an objective must be an Objective or a callable f(states, accel), got {type(value).__name__}")


def dynamic_penalty(states: torch.Tensor, accel: torch.Tensor, mu: float = MU) -> torch.Tensor:
    """``f_dyn = Σ_k F_c[k]`` per trajectory (eq. 4.4) [rad]."""
    return violation_torch(states[:, : accel.shape[1], 2], accel, mu).sum(1)


class EndPose(Objective):
    """J1 (eqs. 4.3–4.4): ``|D (p[K-1] − p_end)|² + α Σ_k F_c[k]``.

    Args:
        target: ``(y, z, θ)`` [m, m, rad], or ``(B, 3)`` one target per trajectory.
        alpha: weight α of the friction-cone penalty.
    """

    def __init__(self, target: Sequence[float] | np.ndarray, alpha: float = 1.0, mu: float = MU) -> None:
        target_arr = np.asarray(target, dtype=np.float64)
        if target_arr.shape[-1:] != (3,) or target_arr.ndim > 2 or not np.all(np.isfinite(target_arr)):
            raise ValueError(f"target must be finite (y, z, theta) or (B, 3), got {np.shape(target)}")
        self.target, self.alpha, self.mu = target_arr, float(alpha), float(mu)

    def end_error(self, states: torch.Tensor) -> torch.Tensor:
        """``D (p[K-1] − p_end)`` per trajectory, ``(B, 3)``."""
        target = torch.as_tensor(self.target, dtype=states.dtype)
        d = torch.tensor(D_WEIGHTS, dtype=states.dtype)
        return d * (states[:, -1, :3] - target)

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return (self.end_error(states) ** 2).sum(-1) + self.penalty(states, accel)

    def residuals(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return self.end_error(states)

    def penalty(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return self.alpha * dynamic_penalty(states, accel, self.mu)

    def __repr__(self) -> str:
        return f"EndPose(target={self.target.tolist()}, alpha={self.alpha:g})"


class Ranges(Objective):
    """J2 (eq. 4.10): bands on the end pose, the cone penalty and velocity limits.

    ``max(|p_yz[K-1]| − p_lim, 0) + 0.1 max(|θ[K-1] − θ_end| − θ_lim, 0) + α f_dyn
    + β/K Σ_k |max(0, D(|ṗ[k]| − v_lim))|²``

    Defaults are the dissertation's: p_lim = 0.2 m, θ_end = −3π/4, θ_lim = 0.5 rad, α = 1,
    β = 0.01, v_lim = (1.5 m/s, 1.5 m/s, 4.5 rad/s).
    """

    def __init__(
        self,
        p_lim: float = 0.2,
        theta_end: float = -3 * math.pi / 4,
        theta_lim: float = 0.5,
        alpha: float = 1.0,
        beta: float = 0.01,
        v_lim: Sequence[float] = (1.5, 1.5, 4.5),
        mu: float = MU,
    ) -> None:
        if len(v_lim) != 3 or min(v_lim) < 0 or p_lim < 0 or theta_lim < 0:
            raise ValueError("Ranges needs nonnegative p_lim, theta_lim and three velocity limits")
        self.p_lim, self.theta_end, self.theta_lim = float(p_lim), float(theta_end), float(theta_lim)
        self.alpha, self.beta, self.v_lim, self.mu = float(alpha), float(beta), tuple(map(float, v_lim)), float(mu)

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        end = states[:, -1]
        position_band = torch.relu(torch.sqrt(end[:, 0] ** 2 + end[:, 1] ** 2 + 1e-30) - self.p_lim)
        attitude_band = 0.1 * torch.relu((end[:, 2] - self.theta_end).abs() - self.theta_lim)
        d = torch.tensor(D_WEIGHTS, dtype=states.dtype)
        v_lim = torch.tensor(self.v_lim, dtype=states.dtype)
        excess = torch.relu(d * (states[..., 3:].abs() - v_lim))
        velocity = self.beta / states.shape[1] * (excess**2).sum((1, 2))
        return position_band + attitude_band + self.alpha * dynamic_penalty(states, accel, self.mu) + velocity

    def __repr__(self) -> str:
        return f"Ranges(p_lim={self.p_lim}, theta_end={self.theta_end:.4f}, theta_lim={self.theta_lim})"
