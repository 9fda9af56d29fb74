"""The tasks' closed-loop physics in NumPy alone, for running exported models without torch.

What :class:`~seqmotion.deploy.onnx_stepper.OnnxStepper` integrates its predictions with, as
``contract.json``'s ``"dynamics"`` describes it:

* ``double_integrator`` (pancake, tray, any task on :class:`seqmotion.physics.integrator.DoubleIntegratorDynamics`):
  ``x = [p (d), v (d)]``, ``v[k+1] = v[k] + dt u[k]``, ``p[k+1] = p[k] + dt v[k] + dt²/2 u[k]`` (in closed form).
* ``sliding`` (:class:`seqmotion.physics.sliding.SlidingDynamics`): the pan ``[x, y, vx, vy]`` is a
  2-D double integrator; the object's state relative to the pan follows the Coulomb stick/slip
  step of :mod:`seqmotion.physics.sliding` (the same arithmetic, in plain Python floats).

The decoder's input mapping of every shipped task is the identity (the decoder reads the states
as they are); a task's own mapping is inside the exported decoder graph. This module imports only
NumPy: ``seqmotion export-onnx`` copies it beside the graphs.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def integrate(x0: np.ndarray, accel: np.ndarray, dt: float) -> np.ndarray:
    """States ``x[1..n]`` ``(B, n, 2d)`` of the double integrator from ``x0`` ``(B, 2d)`` under ``accel`` ``(B, n, d)``.
    """
    d = accel.shape[-1]
    p0, v0 = x0[:, None, :d], x0[:, None, d : 2 * d]
    s1 = np.cumsum(accel, axis=1)  # Σ_{j≤i} u[j]
    s2 = np.cumsum(np.concatenate([np.zeros_like(s1[:, :1]), s1[:, :-1]], axis=1), axis=1)
    n = np.arange(1, accel.shape[1] + 1, dtype=np.float64)[None, :, None]
    v = v0 + dt * s1
    p = p0 + n * dt * v0 + dt**2 * (s2 + 0.5 * s1)
    return np.concatenate([p, v], axis=-1)


def contact(rel0: np.ndarray, pan_accel: np.ndarray, mu: float, mu_dyn: float, dt: float,
            gravity: float) -> np.ndarray:
    """The object's relative states ``(B, n, 4)`` after each pan acceleration (eq. 3.9, discrete as in
    :mod:`seqmotion.physics.sliding`: a step that would reverse the sliding ends at rest)."""
    b, n = pan_accel.shape[:2]
    out = np.empty((b, n, 4))
    slide_decel, stick_limit = mu_dyn * gravity, mu * gravity
    u_all = pan_accel.tolist()
    for i in range(b):
        px, py, vx, vy = (float(v) for v in rel0[i])
        row = out[i]
        for k, (ux, uy) in enumerate(u_all[i]):
            speed = math.sqrt(vx * vx + vy * vy)
            if speed > 0.0:
                nx, ny = vx / speed, vy / speed
                wx = vx + dt * (-ux - slide_decel * nx)
                wy = vy + dt * (-uy - slide_decel * ny)
                if wx * vx + wy * vy <= 0.0:
                    nvx = nvy = 0.0
                else:
                    nvx, nvy = wx, wy
            else:
                un = math.sqrt(ux * ux + uy * uy)
                if un >= stick_limit and un > 0.0:
                    mx, my = ux / un, uy / un
                    nvx = dt * (-ux + stick_limit * mx)
                    nvy = dt * (-uy + stick_limit * my)
                else:
                    nvx = nvy = 0.0
            px += 0.5 * dt * (vx + nvx)
            py += 0.5 * dt * (vy + nvy)
            vx, vy = nvx, nvy
            row[k] = (px, py, vx, vy)
    return out


class NumpyDynamics:
    """``contract["dynamics"]`` as a predictor: :meth:`predict` maps ``(x (B, S), accel (B, n, d))`` to
    the states ``(B, n, S)`` that follow.

    Args:
        spec: the contract's ``"dynamics"`` dict.
        physics: overrides of its parameters (sliding: ``mu``, ``mu_dyn``).
    """

    def __init__(self, spec: dict[str, Any], **physics: float) -> None:
        self.kind, self.dt = spec["kind"], float(spec["dt"])
        allowed = ("mu", "mu_dyn") if self.kind == "sliding" else ()
        unknown = sorted(set(physics) - set(allowed))
        if unknown:
            raise ValueError(f"the {self.kind!r} dynamics take no parameter(s) {unknown} (they take: "
                             f"{list(allowed) or 'none'})")
        if self.kind == "double_integrator":
            self.dim = int(spec["dim"])
        elif self.kind == "sliding":
            self.mu = float(physics.get("mu", spec["mu"]))
            self.mu_dyn = float(physics.get("mu_dyn", spec["mu_dyn"]))
            if not (self.mu > 0 and 0 <= self.mu_dyn <= self.mu and math.isfinite(self.mu)):
                raise ValueError(f"friction must satisfy mu > 0 and 0 <= mu_dyn <= mu, got {self.mu}, {self.mu_dyn}")
            self.gravity = float(spec["gravity"])
        else:
            raise ValueError(f"dynamics {spec.get('class', self.kind)!r} have no NumPy implementation "
                             "(known: double_integrator, sliding)")

    def predict(self, x: np.ndarray, accel: np.ndarray) -> np.ndarray:
        if self.kind == "double_integrator":
            return integrate(x, accel, self.dt)
        pan = integrate(x[:, :4], accel, self.dt)
        rel = contact(x[:, 4:], accel, self.mu, self.mu_dyn, self.dt, self.gravity)
        return np.concatenate([pan, rel], axis=-1)


__all__ = ["NumpyDynamics", "contact", "integrate"]
