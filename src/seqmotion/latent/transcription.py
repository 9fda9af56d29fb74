"""The peer of latent optimisation: the end-pose problem by direct transcription with CasADi + IPOPT.

Same problem as case 1 of ch. 4: K = 500 samples, start at rest at the origin, minimise
``J1 = |D (p[K-1] − p_end)|² + α Σ_k F_c[k]``. Decision variables are all states X (K × 6),
inputs U ((K−1) × 3) and slacks s ((K−1),) with ``s_k ≥ |ψ_k| − atan μ``, ``s_k ≥ 0``
(the exact epigraph of F_c); the dynamics ``x[k+1] = A x[k] + B u[k]`` are equality
constraints. IPOPT starts from the same S-curve the seq2seq model is given (its implied
inputs, integrated so the start is dynamically consistent).

To compare times fairly, an iteration callback integrates the current inputs (the motion one
would execute) and records its true J1 and the wall time since IPOPT started; the time to
reach ``J1 < threshold`` is read from that log. Building the symbolic problem is timed apart.
CasADi is an optional dependency (``pip install seqmotion[peer]``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..data import pancake as inputs
from ..physics import pancake as physics
from ..physics.integrator import DT, implied_accel, integrate_numpy, transition_matrices

D_WEIGHTS = np.array([1.0, 1.0, 0.1])


@dataclass
class TranscriptionResult:
    """Outcome of one IPOPT solve.

    Attributes:
        states, accel: the final motion, ``(K, 6)`` and ``(K-1, 3)`` (inputs integrated).
        j1: its true J1; ``max_fc`` its largest cone violation [rad].
        history: ``(iterations + 1, 2)`` rows of (seconds since IPOPT started, J1 of the iterate).
        seconds_to_threshold: first time J1 < threshold (None if never).
        solve_seconds, build_seconds: IPOPT's wall time; building the symbolic NLP.
        status: IPOPT's return status.
    """

    states: np.ndarray
    accel: np.ndarray
    j1: float
    max_fc: float
    history: np.ndarray
    seconds_to_threshold: float | None
    solve_seconds: float
    build_seconds: float
    status: str


def true_j1(accel: np.ndarray, target: np.ndarray, alpha: float = 1.0, mu: float = physics.MU) -> tuple[float, float]:
    """``(J1, max F_c)`` of the motion that inputs ``accel`` (K−1, 3) produce from rest at 0."""
    states = integrate_numpy(np.zeros(6), accel)
    fc = physics.violation(states[:-1], accel, mu)
    err = D_WEIGHTS * (states[-1, :3] - target)
    return float((err**2).sum() + alpha * fc.sum()), float(fc.max())


def solve_end_pose(
    target: tuple[float, float, float],
    length: int = 500,
    alpha: float = 1.0,
    mu: float = physics.MU,
    threshold: float = 1e-3,
    max_iter: int = 500,
    dt: float = DT,
) -> TranscriptionResult:
    """Solve J1 for one target with IPOPT (see the module docstring)."""
    try:
        import casadi as ca
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("the IPOPT peer needs CasADi: pip install 'seqmotion[peer]'") from exc

    target_arr = np.asarray(target, dtype=np.float64)
    k = length
    build_start = time.perf_counter()
    a_mat, b_mat = transition_matrices(3, dt)
    x = ca.SX.sym("x", 6, k)
    u = ca.SX.sym("u", 3, k - 1)
    s = ca.SX.sym("s", 1, k - 1)
    # dynamics as equality constraints (direct transcription)
    dynamics = x[:, 1:] - (ca.DM(a_mat) @ x[:, :-1] + ca.DM(b_mat) @ u)
    # ψ: the specific force g − u seen from the spatula's normal, rotated by −θ (smooth except upside down)
    fy, fz = -u[0, :], -physics.GRAVITY - u[1, :]
    big_x, big_y = -fz, fy  # arg(f) = atan2(big_y, big_x)
    theta = x[2, :-1]
    psi = ca.atan2(-big_x * ca.sin(theta) + big_y * ca.cos(theta), big_x * ca.cos(theta) + big_y * ca.sin(theta))
    cone = math.atan(mu)
    g = ca.vertcat(ca.vec(dynamics), x[:, 0], ca.vec(s - psi + cone), ca.vec(s + psi + cone))
    end_err = ca.DM(D_WEIGHTS) * (x[:3, -1] - ca.DM(target_arr))
    objective = ca.sumsqr(end_err) + alpha * ca.sum2(s)
    variables = ca.vertcat(ca.vec(u), ca.vec(x), ca.vec(s))
    n_u = 3 * (k - 1)

    log: list[tuple[float, float]] = []
    clock = {"start": 0.0}

    class _Log(ca.Callback):
        """Records (time, true J1 of the integrated inputs) after every IPOPT iteration."""

        def __init__(self) -> None:
            ca.Callback.__init__(self)
            self.construct("log", {})

        def get_n_in(self) -> int:
            return ca.nlpsol_n_out()

        def get_n_out(self) -> int:
            return 1

        def get_name_in(self, i: int) -> str:
            return ca.nlpsol_out(i)

        def get_name_out(self, i: int) -> str:
            return "ret"

        def get_sparsity_in(self, i: int):  # noqa: ANN201
            name = ca.nlpsol_out(i)
            sizes = {"x": variables.numel(), "lam_x": variables.numel(), "g": g.numel(), "lam_g": g.numel(), "f": 1}
            return ca.Sparsity.dense(sizes.get(name, 0), 1)

        def eval(self, arg):  # noqa: ANN001, ANN201
            now = time.perf_counter() - clock["start"]
            accel = np.array(arg[0][:n_u]).reshape(k - 1, 3)  # vec() is column-major: u[:, j] contiguous
            log.append((now, true_j1(accel, target_arr, alpha, mu)[0]))
            return [0]

    callback = _Log()
    solver = ca.nlpsol(
        "j1", "ipopt", {"x": variables, "f": objective, "g": g},
        {"iteration_callback": callback, "ipopt.print_level": 0, "print_time": False,
         "ipopt.max_iter": max_iter, "ipopt.tol": 1e-8},
    )
    # start: the same S-curve the model gets, made consistent with the integrator
    start_states = inputs.straight(target_arr, k)
    accel0 = implied_accel(start_states)
    x0 = integrate_numpy(np.zeros(6), accel0)
    fc0 = physics.violation(x0[:-1], accel0, mu)
    # vec() is column-major, so a (K, 6) row-major array flattens to the same order as vec(x)
    guess = np.concatenate([accel0.reshape(-1), x0.reshape(-1), fc0 + 1e-6])
    lbg = np.concatenate([np.zeros(6 * (k - 1) + 6), np.zeros(2 * (k - 1))])
    ubg = np.concatenate([np.zeros(6 * (k - 1) + 6), np.full(2 * (k - 1), np.inf)])
    lbx = np.concatenate([np.full(n_u + 6 * k, -np.inf), np.zeros(k - 1)])
    build_seconds = time.perf_counter() - build_start

    clock["start"] = time.perf_counter()
    sol = solver(x0=guess, lbg=lbg, ubg=ubg, lbx=lbx, ubx=np.inf)
    solve_seconds = time.perf_counter() - clock["start"]
    accel = np.array(sol["x"][:n_u]).reshape(k - 1, 3)
    states = integrate_numpy(np.zeros(6), accel)
    j1, max_fc = true_j1(accel, target_arr, alpha, mu)
    history = np.array([(0.0, true_j1(accel0, target_arr, alpha, mu)[0])] + log)
    reached = np.flatnonzero(history[:, 1] < threshold)
    return TranscriptionResult(
        states=states,
        accel=accel,
        j1=j1,
        max_fc=max_fc,
        history=history,
        seconds_to_threshold=float(history[reached[0], 0]) if reached.size else None,
        solve_seconds=solve_seconds,
        build_seconds=build_seconds,
        status=str(solver.stats()["return_status"]),
    )
