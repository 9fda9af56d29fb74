"""Input trajectories for the pancake-turning task (ch. 2, eqs. 2.26–2.33, SPEC §3).

Two families, both vectorised over a batch and seeded through a ``numpy.random.Generator``:

* **acceleration type** — built in acceleration space so that the friction-cone angle stays
  below ``φ_max``: ``ψ = -φ_max tanh(a_φ)``. At ``φ_max = atan μ = π/4`` every sample
  satisfies the constraint (no deformation needed); raising φ_max makes inputs that need it.
* **position type** — a path through three random waypoints, timed by an S-curve: what a
  user would sketch, with no regard for the constraint.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ...data.trajectories import (
    TrajectoryBatch,
    combine,
    draw_lengths,
    normalized_time,
    path_states,
    quadratic_through,
    repeat_last,
)
from ...errors import check_number
from ...physics.integrator import DT, integrate
from .physics import GRAVITY

DEFAULT_LENGTH = (100, 500)
"""K is drawn uniformly in this range (samples at 1 ms)."""

# Bounds of the random control points (eqs. 2.27 and 2.32–2.33; SPEC fixes the |a_θ| < 50 typo).
ACCEL_RADIUS_MAX = 20.0  # a_r [m/s²]
ACCEL_THETA_MAX = 50.0  # a_θ [rad/s²]
WAYPOINT1_MAX = np.array([0.15, 0.15, 1.57])  # |y|, |z| [m], |θ| [rad] of c1
WAYPOINT2_MAX = np.array([0.3, 0.3, 3.14])  # of c2


def acceleration_type(
    n: int,
    rng: np.random.Generator,
    *,
    phi_max: float = math.pi / 4,
    length: int | tuple[int, int] | np.ndarray = DEFAULT_LENGTH,
    dt: float = DT,
) -> TrajectoryBatch:
    """Acceleration-type trajectories (eqs. 2.26–2.30).

    Control points ``a0 = 0`` and ``a1, a2`` with ``0 < a_r < 20``, ``|a_φ| < φ_max``,
    ``|a_θ| < 50`` are joined by the smooth quadratic through them over the K samples; θ is
    the double integral of a_θ from rest, and ``a'_φ = φ_max tanh(a_φ)``,
    ``a_y = |a_r| sin(a'_φ - θ)``, ``a_z = |a_r| cos(a'_φ - θ) - g``.

    Returns:
        A :class:`TrajectoryBatch` with ``states`` (n, K_max, 6) from rest at the origin and
        the exact inputs ``accel`` (n, K_max - 1, 3) that produce them.
    """
    if not 0 < phi_max <= math.pi:
        raise ValueError(f"phi_max must be in (0, pi], got {phi_max}")
    lengths = draw_lengths(rng, n, length)
    controls = np.zeros((n, 3, 3))  # (a_r, a_φ, a_θ) at τ = 0, ½, 1
    controls[:, 1:, 0] = rng.uniform(0.0, ACCEL_RADIUS_MAX, size=(n, 2))
    controls[:, 1:, 1] = rng.uniform(-phi_max, phi_max, size=(n, 2))
    controls[:, 1:, 2] = rng.uniform(-ACCEL_THETA_MAX, ACCEL_THETA_MAX, size=(n, 2))
    tau = normalized_time(lengths)[:, :-1]  # inputs u[0..K_max-2]
    curve, _ = quadratic_through(controls, tau)
    radius, phi, accel_theta = np.abs(curve[..., 0]), phi_max * np.tanh(curve[..., 1]), curve[..., 2]

    valid_input = np.arange(tau.shape[1])[None, :] < (lengths[:, None] - 1)
    accel_theta = np.where(valid_input, accel_theta, 0.0)
    theta_states = integrate(torch.zeros(n, 2, dtype=torch.float64), torch.from_numpy(accel_theta[..., None]), dt)
    theta = theta_states[..., 0].numpy()[:, :-1]  # θ[k] that u[k] acts at
    accel = np.stack(
        [radius * np.sin(phi - theta), radius * np.cos(phi - theta) - GRAVITY, accel_theta], axis=-1
    )
    accel = np.where(valid_input[..., None], accel, 0.0)
    states = integrate(torch.zeros(n, 6, dtype=torch.float64), torch.from_numpy(accel), dt).numpy()
    # The padding repeats the last real sample (the zero input above would keep it moving).
    return TrajectoryBatch(states=repeat_last(states, lengths), lengths=lengths, accel=accel)


def position_type(
    n: int,
    rng: np.random.Generator,
    *,
    length: int | tuple[int, int] | np.ndarray = DEFAULT_LENGTH,
    dt: float = DT,
) -> TrajectoryBatch:
    """Position-type trajectories (eqs. 2.31–2.33): a path through ``c0 = 0``, ``c1``, ``c2``.

    ``|c1| < (0.15 m, 0.15 m, 1.57 rad)``, ``|c2| < (0.3 m, 0.3 m, 3.14 rad)``; the path is
    the smooth quadratic through them, travelled rest to rest on an S-curve over K samples.
    """
    lengths = draw_lengths(rng, n, length)
    waypoints = np.zeros((n, 3, 3))
    waypoints[:, 1] = rng.uniform(-WAYPOINT1_MAX, WAYPOINT1_MAX, size=(n, 3))
    waypoints[:, 2] = rng.uniform(-WAYPOINT2_MAX, WAYPOINT2_MAX, size=(n, 3))
    return TrajectoryBatch(states=path_states(waypoints, lengths, dt), lengths=lengths)


def straight(
    end: np.ndarray | tuple[float, float, float],
    length: int = 500,
    *,
    start: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
    timing: str = "s_curve",
    dt: float = DT,
) -> np.ndarray:
    """A straight motion between two poses: ``(K, 6)`` states (ch. 4 inputs, Fig. 2.5).

    ``timing="s_curve"`` is rest to rest (eq. 4.8's inputs); ``"linear"`` is the uniform
    motion used as the J2 input (§4.4.2).
    """
    end_arr, start_arr = np.asarray(end, dtype=np.float64), np.asarray(start, dtype=np.float64)
    if end_arr.shape != (3,) or start_arr.shape != (3,):
        raise ValueError("start and end must be (y, z, theta) triples")
    waypoints = np.stack([start_arr, 0.5 * (start_arr + end_arr), end_arr])[None]
    return path_states(waypoints, np.array([length]), dt, timing)[0]


def mixture(
    n: int,
    rng: np.random.Generator,
    *,
    accel_type_prob: float,
    phi_max: float,
    length: int | tuple[int, int] | np.ndarray = DEFAULT_LENGTH,
    dt: float = DT,
) -> TrajectoryBatch:
    """Each trajectory is acceleration type with probability ``accel_type_prob``, else position type.

    This is the input mixture the chapter-2 curriculum moves through (epochs 61–80).
    """
    check_number("accel_type_prob", accel_type_prob, minimum=0.0, maximum=1.0)
    pick_accel = rng.random(n) < accel_type_prob
    lengths = draw_lengths(rng, n, length)
    parts = []
    for use_accel in (True, False):
        idx = np.flatnonzero(pick_accel == use_accel)
        if idx.size == 0:
            continue
        if use_accel:
            parts.append((idx, acceleration_type(idx.size, rng, phi_max=phi_max, length=lengths[idx], dt=dt)))
        else:
            parts.append((idx, position_type(idx.size, rng, length=lengths[idx], dt=dt)))
    return combine(lengths, parts)
