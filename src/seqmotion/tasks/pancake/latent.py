"""Latent adjustment beside the pancake task (ch. 4): its J2 bands (eq. 4.10) and the IPOPT peer of J1.

* :class:`PancakeRanges` — ``sm.objectives.Ranges()`` without field names: the dissertation's
  velocity-limited turn, bands on the end position and attitude, limits on the velocities, and the
  friction cone at the bound model's μ.
* :func:`solve_end_pose` — the formulation a robotics user would write for chapter 4's J1 (K = 500
  samples, start at rest at the origin): all states X (K × 6) and inputs U ((K−1) × 3) are decision
  variables, the dynamics ``x[k+1] = A x[k] + B u[k]`` equality constraints, the friction cone *hard*
  constraints in force form in the spatula frame (:func:`seqmotion.tasks.pancake.physics.cone_constraint`:
  ``μ n − t ≥ 0``, ``μ n + t ≥ 0``), and the cost the weighted end error ``|D (p[K-1] − p_end)|²``,
  D = diag(1, 1, 0.1). Exact Hessian, sparse (CasADi's default with IPOPT/MUMPS). IPOPT starts cold from
  the same S-curve the seq2seq model is given (its implied inputs, integrated so the start is dynamically
  consistent). The NLP is built once per (K, μ) and reused for every target (the target is a parameter);
  building is timed apart. It is the transcription the exact polish uses
  (:mod:`seqmotion.physics.transcription`), with another cost and start.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ...core.results import FEASIBLE_TOLERANCE
from ...errors import check_finite_array, check_number
from ...latent.objectives import register_fieldless_ranges
from ...latent.terms import Objective, Term, as_numpy, check_layout, check_weight, max_per_trajectory, unbound
from ...physics.integrator import DT, implied_accel, integrate_numpy
from ...physics.transcription import Constraint, scale_rows, transcription
from . import data as sketches
from . import physics

D_WEIGHTS = (1.0, 1.0, 0.1)
"""D = diag(1, 1, 0.1) on (y, z, θ): metres against radians (eqs. 2.25, 4.3; the pancake task's ``end_pose``)."""


def dynamic_penalty(states: torch.Tensor, accel: torch.Tensor, mu: float) -> torch.Tensor:
    """``f_dyn = Σ_k F_c[k]`` per trajectory (eq. 4.4) [rad] of pancake ``states`` ``(B, K, 6)``, ``accel``
    ``(B, K-1, 3)`` at friction ``mu``."""
    return physics.violation_torch(states[:, : accel.shape[1], 2], accel, mu).sum(1)


class PancakeRanges(Objective):
    """J2 (eq. 4.10), the pancake's bands::

        max(|p_yz[K-1]| − p_lim, 0) + 0.1 max(|θ[K-1] − θ_end| − θ_lim, 0) + α f_dyn
        + β/K Σ_k |max(0, D(|ṗ[k]| − v_lim))|²

    with the dissertation's defaults p_lim = 0.2 m, θ_end = −3π/4, θ_lim = 0.5 rad, α = 1, β = 0.01,
    v_lim = (1.5 m/s, 1.5 m/s, 4.5 rad/s), and f_dyn the friction cone at the bound model's μ (or ``mu``).
    Terms: ``"end position band"``, ``"end attitude band"``, ``"velocity limits"``, ``"friction cone"``.
    ``sm.objectives.Ranges()`` without field names builds one; :meth:`bind` refuses a model of another layout.

    Args:
        p_lim, theta_end, theta_lim, v_lim: the bands [m, rad, rad, (m/s, m/s, rad/s)].
        alpha: weight α ≥ 0 of the cone's penalty; beta: weight β ≥ 0 of the velocity limits.
        mu: judge the cone at this μ instead of the model's own.
    """

    def __init__(
        self,
        p_lim: float | None = None,
        theta_end: float | None = None,
        theta_lim: float | None = None,
        alpha: float = 1.0,
        beta: float = 0.01,
        v_lim: Sequence[float] | None = None,
        mu: float | None = None,
    ) -> None:
        self.alpha, self.beta = check_weight("alpha", alpha), check_weight("beta", beta)
        self.mu = None if mu is None else check_weight("mu", mu, positive=True)
        p_lim = 0.2 if p_lim is None else p_lim
        theta_end = -3 * math.pi / 4 if theta_end is None else theta_end
        theta_lim = 0.5 if theta_lim is None else theta_lim
        v_lim = (1.5, 1.5, 4.5) if v_lim is None else v_lim
        for name, value in (("p_lim", p_lim), ("theta_lim", theta_lim)):
            check_weight(name, value)
        check_number("theta_end", theta_end)
        if isinstance(v_lim, str) or not hasattr(v_lim, "__len__") or len(v_lim) != 3:
            raise ValueError(f"Ranges needs three velocity limits (v_y, v_z, v_theta), got {v_lim!r}")
        for value in v_lim:
            check_weight("v_lim", value)
        self.layout = physics.STATE_LAYOUT
        self.p_lim, self.theta_end, self.theta_lim = float(p_lim), float(theta_end), float(theta_lim)
        self.v_lim = tuple(map(float, v_lim))

    @property
    def keeps_constraint(self) -> bool:
        return True

    @property
    def end_fields(self) -> frozenset[str]:
        return frozenset(("y", "z", "theta"))  # the end position band (y, z) and the attitude band (θ)

    def bind(self, model: Any) -> PancakeRanges:
        """These bands for a pancake model (μ from its physics unless given); another layout is refused by name."""
        try:
            check_layout(self, model)
        except ValueError as exc:
            raise ValueError(f"{exc}; for its layout give the bands by field name: "
                             f"Ranges(end={{field: (low, high)}}, limits={{field: limit}})") from None
        mu = self.mu if self.mu is not None else model.physics.mu
        return PancakeRanges(self.p_lim, self.theta_end, self.theta_lim, self.alpha, self.beta, self.v_lim, mu)

    def _mu(self) -> float:
        if self.mu is None:
            raise unbound(self)
        return self.mu

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        mu = self._mu()
        end = states[:, -1]
        position_band = torch.relu(torch.sqrt(end[:, 0] ** 2 + end[:, 1] ** 2 + 1e-30) - self.p_lim)
        attitude_band = 0.1 * torch.relu((end[:, 2] - self.theta_end).abs() - self.theta_lim)
        d = torch.tensor(D_WEIGHTS, dtype=states.dtype, device=states.device)
        v_lim = torch.tensor(self.v_lim, dtype=states.dtype, device=states.device)
        excess = torch.relu(d * (states[..., 3:].abs() - v_lim))
        velocity = self.beta / states.shape[1] * (excess**2).sum((1, 2))
        return position_band + attitude_band + self.alpha * dynamic_penalty(states, accel, mu) + velocity

    def _excess(self, states: torch.Tensor) -> dict[str, torch.Tensor]:
        """How far each band is overstepped, ``(B,)`` each (0 where it holds)."""
        end = states[:, -1]
        v_lim = torch.tensor(self.v_lim, dtype=states.dtype, device=states.device)
        return {
            "end position band": torch.relu(torch.sqrt(end[:, 0] ** 2 + end[:, 1] ** 2) - self.p_lim),
            "end attitude band": torch.relu((end[:, 2] - self.theta_end).abs() - self.theta_lim),
            # from sample 1: the start state is given, not generated (a linear sketch starts moving)
            "velocity limits": torch.relu(states[:, 1:, 3:].abs() - v_lim).amax((1, 2)),
        }

    def report(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, Term]:
        """Each band's excess (met at 0, to 1e-6) and the largest cone violation F_c [rad] (≤ 0.01)."""
        mu = self._mu()
        with torch.no_grad():
            units = {"end position band": "m", "end attitude band": "rad", "velocity limits": "(m/s, rad/s)"}
            terms = {name: Term(as_numpy(v), 1e-6, units[name]) for name, v in self._excess(states).items()}
            cone = physics.violation_torch(states[:, : accel.shape[1], 2], accel, mu)
            terms["friction cone"] = Term(as_numpy(max_per_trajectory(cone)), FEASIBLE_TOLERANCE, "rad")
        return terms

    def exact_constraints(self) -> list[tuple[Constraint, np.ndarray]]:
        """The bands and velocity limits (from sample 1) as hard constraints (the cone is the polish's own)."""
        none = np.zeros((1, 0))
        p_lim, theta_end, theta_lim, v_lim = self.p_lim, self.theta_end, self.theta_lim, np.array(self.v_lim)
        return [
            (Constraint("end position band", ("ranges_position", p_lim),
                        lambda x, u, p: x[0, -1] ** 2 + x[1, -1] ** 2, -math.inf, p_lim**2), none),
            (Constraint("end attitude band", ("ranges_attitude", theta_end, theta_lim),
                        lambda x, u, p: x[2, -1], theta_end - theta_lim, theta_end + theta_lim), none),
            # |v| ≤ v_lim per field, scaled so every bound is ±1
            (Constraint("velocity limits", ("ranges_velocity", *self.v_lim),
                        lambda x, u, p: scale_rows(x[3:6, 1:], 1 / np.maximum(v_lim, 1e-12)), -1.0, 1.0), none),
        ]

    def __repr__(self) -> str:
        return f"Ranges(p_lim={self.p_lim}, theta_end={self.theta_end:.4f}, theta_lim={self.theta_lim})"


# --- the IPOPT peer of J1 ------------------------------------------------------------------------------


@dataclass
class PeerResult:
    """Outcome of one IPOPT solve (:func:`solve_end_pose`).

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
    """``(J1, max F_c)`` of the motion that inputs ``accel`` (K−1, 3) produce from rest at 0, at friction ``mu``."""
    states = integrate_numpy(np.zeros(6), accel)
    fc = physics.violation(states[:-1], accel, mu)
    err = np.array(D_WEIGHTS) * (states[-1, :3] - target)
    return float((err**2).sum() + alpha * fc.sum()), float(fc.max())


def solve_end_pose(
    target: tuple[float, float, float], length: int = 500, mu: float = physics.MU, max_iter: int = 3000,
    dt: float = DT,
) -> PeerResult:
    """Solve J1 for one ``target`` ``(y, z, θ)`` [m, m, rad] at friction ``mu`` with IPOPT, cold from the S-curve
    (see the module docstring)."""
    target_arr = check_finite_array("target (y, z, theta)", target)
    if target_arr.shape != (3,):
        raise ValueError(f"target must be a finite (y, z, theta), got {target!r}")
    nlp = transcription(3, length, (physics.cone_constraint(mu),), dt=dt, end_columns=(0, 1, 2),
                        end_weights=D_WEIGHTS, max_iter=max_iter, symbolic="SX")  # cached: reused per target
    build_seconds, nlp.build_seconds = nlp.build_seconds, 0.0  # counted once
    accel0 = implied_accel(sketches.straight(tuple(target_arr), length))
    solution = nlp.solve(np.zeros(6), accel0, [np.zeros(0)], end_target=target_arr)
    j1, max_fc = true_j1(solution.accel, target_arr, mu=mu)
    return PeerResult(solution.states, solution.accel, j1, max_fc, solution.status, solution.iterations,
                      solution.seconds, build_seconds)


register_fieldless_ranges(PancakeRanges)  # sm.objectives.Ranges() without field names: eq. 4.10's bands

__all__ = ["D_WEIGHTS", "PancakeRanges", "PeerResult", "dynamic_penalty", "solve_end_pose", "true_j1"]
