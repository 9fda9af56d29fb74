"""Planar spatula–pancake physics and its friction-cone constraint (ch. 2, SPEC §3).

State ``x = [y, z, θ, v_y, v_z, v_θ]`` (m, rad, m/s, rad/s); input ``u = [a_y, a_z, a_θ]``.
The pancake stays on the spatula while the specific force it feels, ``g - u`` with
``g = (0, -9.8)`` in (y, z), points into the friction cone around the spatula's normal.

``arg(v) = atan2(v_y, -v_z)`` is the angle of v from straight down, positive toward +y, so a
still spatula tilted by θ has ``ψ = -θ`` and holds iff ``|θ| < atan μ`` (45° for μ = 1).

``ψ[k] = wrap(arg(g - u[k]) - θ[k])`` in (-π, π];  ``F_c[k] = max(0, |ψ[k]| - atan μ)`` (eq. 2.18).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import torch

from ...errors import as_trajectories, check_friction
from ...physics.integrator import DT, implied_accel
from ...physics.layout import StateLayout
from ...physics.parameters import Physics
from ...physics.transcription import Constraint, casadi

GRAVITY = 9.8
"""Magnitude of gravity [m/s²]; the vector is ``(0, -GRAVITY)`` in (y, z)."""
MU = 1.0
"""Static friction coefficient between pancake and spatula (the dissertation's value)."""


@dataclasses.dataclass(frozen=True)
class PancakePhysics(Physics, saved_as="seqmotion.physics.pancake.PancakePhysics"):  # its name in saved files
    """The spatula–pancake friction the cone is judged at: static μ > 0 (half-angle ``atan μ``; 45° at μ = 1)."""

    mu: float = MU

    def __post_init__(self) -> None:
        object.__setattr__(self, "mu", check_mu(self.mu))

    @property
    def cone_half_angle(self) -> float:
        """atan μ [rad]: the largest |ψ| at which the pancake holds."""
        return cone_half_angle(self.mu)


def check_mu(mu: object) -> float:
    """``mu`` as a float, or ``ValueError`` unless it is a positive finite number (a friction coefficient): the
    library's one friction check, :func:`~seqmotion.errors.check_friction`, for the pancake's one μ."""
    return check_friction(mu)[0]


def cone_half_angle(mu: float) -> float:
    """atan μ [rad]: the half-angle of the friction cone, the largest |ψ| at which the pancake holds (45° at
    μ = 1). Every cone drawn or judged takes its angle from here."""
    return math.atan(mu)


STATE_LAYOUT = StateLayout(("y", "z", "theta", "v_y", "v_z", "v_theta"), ("m", "m", "rad", "m/s", "m/s", "rad/s"),
                           "pancake state")
ACCEL_LAYOUT = StateLayout(("a_y", "a_z", "a_theta"), ("m/s²", "m/s²", "rad/s²"), "spatula acceleration")
STATE_DIM = STATE_LAYOUT.dim
ACCEL_DIM = ACCEL_LAYOUT.dim


def wrap_angle(angle: torch.Tensor) -> torch.Tensor:
    """Wrap angles into (-π, π] (differentiable: the identity between jumps)."""
    return math.pi - torch.remainder(math.pi - angle, 2 * math.pi)


def arg(vy: torch.Tensor, vz: torch.Tensor) -> torch.Tensor:
    """Angle of the vector (vy, vz) measured from straight down, positive toward +y [rad].

    At the zero vector (free fall: no contact force at all) the angle is defined as 0 and
    its gradient is kept finite.
    """
    down = -vz
    degenerate = (vy == 0) & (down == 0)
    down = torch.where(degenerate, torch.full_like(down, 1e-12), down)
    return torch.atan2(vy, down)


def violation_angle(theta: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
    """ψ: angle between the specific force ``g - u`` and the spatula normal [rad].

    Args:
        theta: ``(...)`` spatula attitude θ.
        accel: ``(..., 3)`` accelerations ``[a_y, a_z, a_θ]``.
    """
    fy = -accel[..., 0]
    fz = -GRAVITY - accel[..., 1]
    return wrap_angle(arg(fy, fz) - theta)


def violation_torch(theta: torch.Tensor, accel: torch.Tensor, mu: float = MU) -> torch.Tensor:
    """``F_c = max(0, |ψ| - atan μ)`` (eq. 2.18) in torch, differentiable. Shapes as above."""
    return torch.relu(violation_angle(theta, accel).abs() - cone_half_angle(mu))


def tilt_for(accel_yz: np.ndarray) -> np.ndarray:
    """The attitude θ at which ψ = 0 for a given (a_y, a_z): the spatula faces ``g - u``."""
    a = torch.as_tensor(np.asarray(accel_yz, dtype=np.float64))
    return arg(-a[..., 0], -GRAVITY - a[..., 1]).numpy()


def _prepare(states: object, accel: object) -> tuple[torch.Tensor, torch.Tensor, bool]:
    st, single = as_trajectories(states, STATE_DIM, "states", min_length=1)
    ac, single_a = as_trajectories(accel, ACCEL_DIM, "accel", min_length=1)
    if single != single_a:
        raise ValueError(f"states and accel must both be batched or both single, got {st.shape} and {ac.shape}")
    if st.shape[0] != ac.shape[0]:
        raise ValueError(f"states and accel have different batch sizes: {st.shape[0]} vs {ac.shape[0]}")
    if ac.shape[1] > st.shape[1]:
        raise ValueError(f"accel has more samples ({ac.shape[1]}) than states ({st.shape[1]})")
    theta = torch.as_tensor(st[:, : ac.shape[1], 2])
    return theta, torch.as_tensor(ac), single


def violation(states: object, accel: object, mu: float = MU) -> np.ndarray:
    """F_c per sample (eq. 2.18) for NumPy trajectories.

    Args:
        states: ``(K, 6)`` or ``(B, K, 6)``.
        accel: ``(N, 3)`` or ``(B, N, 3)`` with ``N ≤ K``; sample k pairs ``u[k]`` with ``θ[k]``
            (usually ``N = K - 1``: ``u[0..K-2]``).
        mu: static friction coefficient.

    Returns:
        ``(N,)`` or ``(B, N)`` violations [rad]; zero where the pancake holds.
    """
    check_mu(mu)
    theta, ac, single = _prepare(states, accel)
    out = violation_torch(theta, ac, mu).numpy()
    return out[0] if single else out


def psi(states: object, accel: object) -> np.ndarray:
    """ψ per sample (the quantity plotted in Figs. 2.6, 2.9, 4.3c); shapes as :func:`violation`."""
    theta, ac, single = _prepare(states, accel)
    out = violation_angle(theta, ac).numpy()
    return out[0] if single else out


def violation_of_states(states: object, mu: float = MU, dt: float = DT) -> np.ndarray:
    """F_c of a state trajectory alone, with ``u`` implied by its velocities (``(K-1,)`` or ``(B, K-1)``).

    This is how a rough input motion is scored: a user sketch carries no accelerations.
    """
    st, single = as_trajectories(states, STATE_DIM, "states")
    out = violation(st, implied_accel(st, dt), mu)
    return out[0] if single else out


def cone_constraint(mu: float = MU, margin: float = 0.0) -> Constraint:
    """The friction cone in force form, for :mod:`.transcription` (exact polish and the IPOPT peer).

    In the spatula frame, with the specific force ``f = g − u`` (``g = (0, −9.8)``):
    ``n = f_y sin θ − f_z cos θ`` (along the spatula's normal) and ``t = f_y cos θ + f_z sin θ``
    (along its surface). The pancake holds iff ``μ n − t ≥ 0`` and ``μ n + t ≥ 0`` — the same set
    as ``|ψ| ≤ atan μ`` without the angle's wrap-around, two smooth constraints per sample
    (``2 (K−1)`` values: the first row of pairs, then the second).

    ``margin`` [m/s²]: require ``μ n ∓ t ≥ margin`` instead. At 0 a solver may settle on free fall
    (``f ≈ 0``, spatula and pancake falling together), where the constraints hold to its tolerance
    but ψ — the angle of a vanishing force — is arbitrary; a small margin keeps the pancake pressed
    on (``n ≥ margin / μ``), so ``|ψ| ≤ atan μ`` holds exactly.
    """
    mu = check_mu(mu)
    if not (isinstance(margin, int | float) and math.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin must be a finite number ≥ 0, got {margin!r}")

    def build(x: Any, u: Any, p: Any) -> Any:
        ca = casadi()
        fy, fz, theta = -u[0, :], -GRAVITY - u[1, :], x[2, :-1]
        normal = fy * ca.sin(theta) - fz * ca.cos(theta)
        tangent = fy * ca.cos(theta) + fz * ca.sin(theta)
        return ca.vertcat(mu * normal - tangent, mu * normal + tangent)

    return Constraint("friction cone", ("pancake_cone", mu, float(margin)), build, float(margin), math.inf)
