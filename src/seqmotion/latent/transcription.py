"""The peer of latent optimisation: the end-pose problem by direct transcription with CasADi + IPOPT.

The formulation a robotics user would write for chapter 4's J1 (K = 500 samples, start at rest
at the origin): all states X (K × 6) and inputs U ((K−1) × 3) are decision variables, the
dynamics ``x[k+1] = A x[k] + B u[k]`` equality constraints, the friction cone *hard*
constraints in force form in the spatula frame (:func:`seqmotion.physics.pancake.cone_constraint`:
``μ n − t ≥ 0``, ``μ n + t ≥ 0``), and the cost the weighted end error
``|D (p[K-1] − p_end)|²``, D = diag(1, 1, 0.1). Exact Hessian, sparse (CasADi's default with
IPOPT/MUMPS). IPOPT starts cold from the same S-curve the seq2seq model is given (its implied
inputs, integrated so the start is dynamically consistent).

The NLP is built once per (K, μ) and reused for every target (the target is a parameter);
building is timed apart. This is the same transcription the exact polish uses
(:mod:`seqmotion.physics.transcription`), with another cost and start.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..data import pancake as inputs
from ..physics import pancake as physics
from ..physics.integrator import DT, implied_accel, integrate_numpy
from ..physics.transcription import transcription

D_WEIGHTS = (1.0, 1.0, 0.1)


@dataclass
class PeerResult:
    """Outcome of one IPOPT solve.

    Attributes:
        states, accel: the final motion, ``(K, 6)`` and ``(K-1, 3)`` (inputs integrated).
        j1: its true J1 (``|D (p[K-1] − p_end)|² + Σ_k F_c[k]``); ``max_fc`` its largest cone violation [rad].
        status: IPOPT's return status; ``iterations`` its iteration count.
        solve_seconds: IPOPT's wall time; ``build_seconds``: building the NLP (0 when it was cached).
    """

    states: np.ndarray
    accel: np.ndarray
    j1: float
    max_fc: float
    status: str
    iterations: int
    solve_seconds: float
    build_seconds: float

    @property
    def exact(self) -> bool:
        """J1 ≤ 1e-9 with max F_c ≤ 1e-6 rad."""
        return self.j1 <= 1e-9 and self.max_fc <= 1e-6


def true_j1(accel: np.ndarray, target: np.ndarray, alpha: float = 1.0, mu: float = physics.MU) -> tuple[float, float]:
    """``(J1, max F_c)`` of the motion that inputs ``accel`` (K−1, 3) produce from rest at 0."""
    states = integrate_numpy(np.zeros(6), accel)
    fc = physics.violation(states[:-1], accel, mu)
    err = np.array(D_WEIGHTS) * (states[-1, :3] - target)
    return float((err**2).sum() + alpha * fc.sum()), float(fc.max())


def solve_end_pose(
    target: tuple[float, float, float], length: int = 500, mu: float = physics.MU, max_iter: int = 3000,
    dt: float = DT,
) -> PeerResult:
    """Solve J1 for one target with IPOPT, cold from the S-curve (see the module docstring)."""
    target_arr = np.asarray(target, dtype=np.float64)
    if target_arr.shape != (3,) or not np.all(np.isfinite(target_arr)):
        raise ValueError(f"target must be a finite (y, z, theta), got {target!r}")
    nlp = transcription(3, length, (physics.cone_constraint(mu),), dt=dt, end_columns=(0, 1, 2),
                        end_weights=D_WEIGHTS, max_iter=max_iter, symbolic="SX")  # cached: reused per target
    build_seconds, nlp.build_seconds = nlp.build_seconds, 0.0  # counted once
    accel0 = implied_accel(inputs.straight(tuple(target_arr), length))
    solution = nlp.solve(np.zeros(6), accel0, [np.zeros(0)], end_target=target_arr)
    j1, max_fc = true_j1(solution.accel, target_arr, mu=mu)
    return PeerResult(solution.states, solution.accel, j1, max_fc, solution.status, solution.iterations,
                      solution.seconds, build_seconds)
