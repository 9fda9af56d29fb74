"""The double integrator in closed form, in NumPy: the runner's fast path for dynamics that are one.

``x = [p (d), v (d)]``, ``v[k+1] = v[k] + dt u[k]``, ``p[k+1] = p[k] + dt v[k] + dt²/2 u[k]``. The contract
says ``"closed_form": "double_integrator"`` only where the task's own dynamics compute exactly this (checked
on random states and inputs when the contract is made: :func:`seqmotion.core.stepper.closed_form`); the
runner then predicts with :func:`integrate` instead of a session run of ``dynamics.onnx``, which stays
the definition. The stepper's rare calls (a chunk boundary, the stop) find this in cache where a session's
graph and constants are not. NumPy only: ``export-onnx`` copies this file beside the graphs.
"""

from __future__ import annotations

import numpy as np


def integrate(x0: np.ndarray, accel: np.ndarray, dt: float) -> np.ndarray:
    """States ``x[1..n]`` ``(B, n, 2d)`` of the double integrator from ``x0`` ``(B, 2d)`` under ``accel`` ``(B, n, d)``
    [SI units, ``dt`` in s]: ``v[n] = v0 + dt S1[n]``, ``p[n] = p0 + n dt v0 + dt² (S2[n] + S1[n] / 2)`` with
    ``S1`` the running sum of the inputs and ``S2`` that of ``S1`` before each sample."""
    d = accel.shape[-1]
    p0, v0 = x0[:, None, :d], x0[:, None, d : 2 * d]
    s1 = np.cumsum(accel, axis=1)
    s2 = np.cumsum(np.concatenate([np.zeros_like(s1[:, :1]), s1[:, :-1]], axis=1), axis=1)
    n = np.arange(1, accel.shape[1] + 1, dtype=np.float64)[None, :, None]
    return np.concatenate([p0 + n * dt * v0 + dt**2 * (s2 + 0.5 * s1), v0 + dt * s1], axis=-1)


__all__ = ["integrate"]
