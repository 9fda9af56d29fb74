"""Hand-made motions for calibrating and checking the scenes (pure NumPy, 1 ms samples).

* :func:`still` — planar spatula states holding one pose (the 40°/50° friction check).
* :func:`pan_circle` — the pan moved on a circle at constant speed after a smooth run-up:
  once on the circle its acceleration has the constant magnitude ``r ω²``, so an object with
  friction μ sticks if ``r ω² < μ g`` and slides if it is larger — Coulomb's law in one number.
* :func:`pan_ramp` — the pan shaken along x with an acceleration amplitude growing linearly
  in time, to find the acceleration at which the object breaks away.
"""

from __future__ import annotations

import numpy as np

from .scene import CONTROL_DT


def still(theta: float = 0.0, duration: float = 1.0, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    """``(K, 6)`` planar states at rest at ``(y, z, θ)`` for ``duration`` [s]."""
    k = max(2, round(duration / CONTROL_DT))
    states = np.zeros((k, 6))
    states[:, :3] = (y, z, theta)
    return states


def _smoothstep(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quintic 0→1 on [0, 1] (zero slope and curvature at both ends), and its two derivatives."""
    x = np.clip(x, 0.0, 1.0)
    return x**3 * (10 - 15 * x + 6 * x**2), 30 * x**2 * (1 - x) ** 2, 60 * x * (1 - x) * (1 - 2 * x)


def pan_circle(accel: float, freq: float = 3.0, duration: float = 1.0, ramp: float = 0.3) -> np.ndarray:
    """``(K, 4)`` pan states ``[x, y, vx, vy]`` on a circle with acceleration ``accel`` [m/s²].

    ``x = r(t) (cos ωt - 1)``, ``y = r(t) sin ωt`` with ``ω = 2π freq`` and the radius growing from 0
    to ``r = accel / ω²`` by a quintic over ``ramp`` seconds, so the pan starts at rest at the
    origin; afterwards ``|ẍ| = accel`` exactly. Velocities are analytic.
    """
    omega = 2 * np.pi * freq
    t = np.arange(max(2, round(duration / CONTROL_DT))) * CONTROL_DT
    s, ds, _ = _smoothstep(t / ramp)
    r, dr = accel / omega**2 * s, accel / omega**2 * ds / ramp
    c, sn = np.cos(omega * t), np.sin(omega * t)
    x, y = r * (c - 1), r * sn
    vx = dr * (c - 1) - r * omega * sn
    vy = dr * sn + r * omega * c
    return np.stack([x, y, vx, vy], axis=1)


def pan_ramp(max_accel: float, freq: float = 4.0, duration: float = 2.0) -> np.ndarray:
    """``(K, 4)`` pan states shaken along x with acceleration amplitude rising linearly to ``max_accel``.

    ``x = -A(t) sin(ωt) / ω²`` with ``A(t) = max_accel · t / duration``: the acceleration is
    ``A sin ωt`` plus a small ``2 Ȧ cos(ωt) / ω`` term; the pan starts at rest at the origin.
    """
    omega = 2 * np.pi * freq
    t = np.arange(max(2, round(duration / CONTROL_DT))) * CONTROL_DT
    amp, damp = max_accel * t / duration, max_accel / duration
    x = -amp * np.sin(omega * t) / omega**2
    vx = -(damp * np.sin(omega * t) + amp * omega * np.cos(omega * t)) / omega**2
    zeros = np.zeros_like(t)
    return np.stack([x, zeros, vx, zeros], axis=1)
