"""Discrete-time filters and observers of motion control (refs. [48, 49, 80] of the dissertation).

All work per joint on NumPy vectors and advance one control period ``dt`` per ``update``:

* :class:`LowPass` — first-order ``g / (s + g)``.
* :class:`PseudoDerivative` — ``g s / (s + g)``: a velocity estimate from positions.
* :class:`DisturbanceObserver` — with the plant written as ``J_n θ̈ = τ_ref - τ_dis``, it
  estimates ``τ̂_dis = g/(s+g) [τ_ref + g J_n θ̇] - g J_n θ̇`` (no acceleration measurement
  needed). Commanding ``τ_ref = J_n θ̈_ref + τ̂_dis`` makes the plant behave like the
  nominal inertia below the cutoff ``g`` [rad/s]; at 2 Hz, g = 12.57 rad/s.
* :class:`ReactionTorqueObserver` — the same estimate minus the modelled internal torques
  (gravity, friction), leaving the torque the environment exerts.

Filters are discretised exactly for a constant input over the period (zero-order hold):
``y ← y + (1 - e^{-g dt}) (x - y)``.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import check_finite_array, check_number


def _check_cutoff(cutoff: float, dt: float) -> None:
    check_number("cutoff [rad/s]", cutoff, minimum=0.0, strict_minimum=True)
    check_number("dt [s]", dt, minimum=0.0, strict_minimum=True)


class LowPass:
    """First-order low-pass filter ``g / (s + g)`` with cutoff ``cutoff`` [rad/s]."""

    def __init__(self, cutoff: float, dt: float, initial: np.ndarray | float = 0.0) -> None:
        _check_cutoff(cutoff, dt)
        self.cutoff, self.dt = float(cutoff), float(dt)
        self.alpha = 1.0 - math.exp(-cutoff * dt)
        self.value = np.array(initial, dtype=np.float64)

    def reset(self, initial: np.ndarray | float = 0.0) -> None:
        self.value = np.array(initial, dtype=np.float64)

    def update(self, x: np.ndarray | float) -> np.ndarray:
        self.value = self.value + self.alpha * (np.asarray(x, dtype=np.float64) - self.value)
        return self.value


class PseudoDerivative:
    """Velocity estimate ``g s / (s + g)`` of a position signal (cutoff ``cutoff`` [rad/s]).

    Discretised as ``v[k] = (α/dt)(x[k] - w[k-1])``, ``w[k] = w[k-1] + α (x[k] - w[k-1])``
    (α as in :class:`LowPass`), which is exact on ramps: a constant slope is estimated
    without bias whatever ``g dt``.
    """

    def __init__(self, cutoff: float, dt: float, initial_position: np.ndarray | float = 0.0) -> None:
        self._lowpass = LowPass(cutoff, dt, initial_position)
        self.cutoff, self._gain = float(cutoff), self._lowpass.alpha / dt

    def reset(self, position: np.ndarray | float = 0.0) -> None:
        self._lowpass.reset(position)

    def update(self, position: np.ndarray | float) -> np.ndarray:
        position = np.asarray(position, dtype=np.float64)
        velocity = self._gain * (position - self._lowpass.value)
        self._lowpass.update(position)
        return velocity


class DisturbanceObserver:
    """Per-joint disturbance observer with nominal inertia ``J_n`` and cutoff ``g``.

    Args:
        nominal_inertia: ``(n,)`` nominal inertia per joint [kg m²] (or a scalar).
        cutoff: observer bandwidth g [rad/s].
        dt: control period [s].
    """

    def __init__(self, nominal_inertia: np.ndarray | float, cutoff: float, dt: float) -> None:
        self.nominal_inertia = check_finite_array("nominal inertia [kg m²]", nominal_inertia, minimum=0.0,
                                                  strict_minimum=True)
        self.cutoff = float(cutoff)
        self._lowpass = LowPass(cutoff, dt, np.zeros_like(self.nominal_inertia))
        self.estimate = np.zeros_like(self.nominal_inertia)

    def reset(self, velocity: np.ndarray | float = 0.0, estimate: np.ndarray | float = 0.0) -> None:
        """Start at the given joint velocity with the given estimate (default zero).

        A known static disturbance (e.g. the gravity torque of the pose the robot starts in)
        can be given as ``estimate`` so the robot does not sag while the observer converges.
        """
        gjv = self.cutoff * self.nominal_inertia * np.asarray(velocity, dtype=np.float64)
        start = np.asarray(estimate, dtype=np.float64) + np.zeros_like(self.nominal_inertia)
        self._lowpass.reset(start + gjv)
        self.estimate = start.copy()

    def update(self, torque_reference: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """Advance one period with the torque just applied and the measured velocity; return τ̂_dis."""
        gjv = self.cutoff * self.nominal_inertia * np.asarray(velocity, dtype=np.float64)
        self.estimate = self._lowpass.update(np.asarray(torque_reference, dtype=np.float64) + gjv) - gjv
        return self.estimate


class ReactionTorqueObserver(DisturbanceObserver):
    """Estimates the external (reaction) torque: the DOB estimate minus modelled internal torques."""

    def update_reaction(
        self, torque_reference: np.ndarray, velocity: np.ndarray, internal_torque: np.ndarray
    ) -> np.ndarray:
        """``internal_torque``: modelled gravity + friction torque the joint feels now [N m]."""
        reference = np.asarray(torque_reference, dtype=np.float64) - np.asarray(internal_torque, dtype=np.float64)
        return self.update(reference, velocity)
