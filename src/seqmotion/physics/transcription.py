"""Direct transcription of a double-integrator motion with constraints, solved by IPOPT (CasADi).

One builder serves two jobs:

* **the peer** of latent optimisation (ch. 4): minimise the weighted end error
  ``|W (p[K-1] − p_end)|²`` over all states and inputs, with the task's constraint (the
  pancake's friction cone in force form) as hard constraints, cold-started from a sketch;
* **the exact polish** of a learned motion (``optimize_latent(..., exact=True)``,
  ``deform(..., keep_end=True)``): the motion closest to a reference input sequence,
  ``min Σ_k |w ⊙ (u[k] − u_ref[k])|² / K``, subject to the dynamics, the task's constraint and
  the objective's own constraints (end pose = target, end at rest, bands...). Started at the
  reference with a small initial barrier (``mu_init = 1e-6``), IPOPT needs a handful of
  iterations when the reference is nearly feasible, which is what latent optimisation delivers.

Decision variables are the inputs ``U`` ((K−1) × d) and states ``X`` (K × 2d); the dynamics
``x[k+1] = A x[k] + B u[k]`` and ``x[0] = x0`` are equality constraints (sparse, exact Hessian).
A :class:`Constraint` is a symbolic function of ``(X, U, p)`` with bounds, where ``p`` are its
parameters (a target, per call); built NLPs are cached by structure, so a new target or a new
reference costs no rebuild.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np

from ..errors import check_finite_array, check_number
from .integrator import DT, integrate_numpy, transition_matrices

SymbolicFn = Callable[[Any, Any, Any], Any]
"""``g(X (2d, K), U (d, K-1), p (n_params,))`` → a CasADi column of constraint values."""

WARM_OPTIONS = {
    "ipopt.warm_start_init_point": "yes",
    "ipopt.mu_init": 1e-6,
    "ipopt.warm_start_bound_push": 1e-9,
    "ipopt.warm_start_mult_bound_push": 1e-9,
    "ipopt.warm_start_slack_bound_push": 1e-9,
}
"""IPOPT started at a nearly feasible point: a small barrier, and no push away from it."""


def casadi() -> Any:
    """The ``casadi`` module, or an ImportError that says how to install it."""
    try:
        import casadi as ca
    except ImportError as exc:  # pragma: no cover - casadi is a dependency; a broken install lands here
        raise ImportError("exact constraints and the IPOPT peer need CasADi: pip install 'casadi>=3.6'") from exc
    return ca


@dataclass(frozen=True)
class Constraint:
    """``lower ≤ g(X, U, p) ≤ upper`` elementwise.

    Attributes:
        name: what it is (reported when it is not met).
        key: everything that fixes its symbolic structure besides the name (e.g. μ, columns,
            limits) — NLPs are cached on it, so two constraints with one key must build the same.
        build: the symbolic function (see :data:`SymbolicFn`).
        lower, upper: bounds, scalars or one per element (``±inf`` for none).
        n_params: length of ``p``; its value is given per solve (e.g. the target).
    """

    name: str
    key: tuple
    build: SymbolicFn = field(compare=False, hash=False)
    lower: float | tuple[float, ...] = 0.0
    upper: float | tuple[float, ...] = 0.0
    n_params: int = 0


@dataclass(frozen=True)
class JointSpace:
    """A change of variables for the transcription: the double integrator runs on a robot's joints, and the task's
    states and inputs are functions of them (forward kinematics), on which the task's constraints are evaluated.

    Attributes:
        name: what it is (a robot's joints).
        key: everything that fixes its symbolic structure (NLPs are cached on it).
        dim: the number of joints (state = the joint angles, then their speeds; inputs = joint accelerations).
        to_task: ``(x (2·dim, K), u (dim, K-1)) -> (x_task (2d, K), u_task (d, K-1))`` symbolically: the task's
            states along the joint trajectory and the task's inputs (its accelerations, exactly, at samples
            0..K-2).
        constraints: the robot's own constraints on ``(x, u, p)`` in joint space (the flange clear of a
            singularity, …).
        state_bounds: ``(lower, upper)``, one per state row (joint ranges [rad], then rated speeds [rad/s];
            ``±inf`` for none): bounds on every sample from 1 on, which IPOPT keeps as variable bounds (no
            constraint rows: on a 1000-sample motion they are half its constraints).
        options: IPOPT options for this kind of problem (``(("ipopt.mu_strategy", "adaptive"),)``).
    """

    name: str
    key: tuple
    dim: int
    to_task: Callable[[Any, Any], tuple[Any, Any]] = field(compare=False, hash=False)
    constraints: tuple[Constraint, ...] = ()
    state_bounds: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    options: tuple[tuple[str, Any], ...] = ()


@dataclass
class Solution:
    """One IPOPT solve.

    Attributes:
        accel: ``(K-1, d)`` the inputs found; ``states`` ``(K, 2d)`` what they produce from x0
            (integrated in float64, so the dynamics hold exactly).
        status: IPOPT's return status; ``success`` whether it converged (``Solve_Succeeded`` or
            ``Solved_To_Acceptable_Level``); ``infeasible`` whether IPOPT proved the constraints
            cannot all hold (locally).
        iterations, seconds: IPOPT's iteration count and wall time.
    """

    accel: np.ndarray
    states: np.ndarray
    status: str
    success: bool
    infeasible: bool
    iterations: int
    seconds: float


class Transcription:
    """The NLP of one structure (use :func:`transcription`, which caches them)."""

    def __init__(
        self, dim: int, length: int, dt: float, constraints: tuple[Constraint, ...],
        accel_weights: tuple[float, ...] | None, end_columns: tuple[int, ...] | None,
        end_weights: tuple[float, ...] | None, warm: bool, tol: float, max_iter: int, symbolic: str,
        smoothness: float = 0.0, joint_space: JointSpace | None = None,
    ) -> None:
        ca = casadi()
        start = time.perf_counter()
        if joint_space is not None:  # the double integrator runs on the joints; the task's constraints on FK
            dim, constraints = joint_space.dim, constraints + joint_space.constraints
        self.dim, self.length, self.constraints, self.dt = dim, length, constraints, dt
        k, s = length, 2 * dim
        a_mat, b_mat = transition_matrices(dim, dt)
        sym = {"SX": ca.SX, "MX": ca.MX}[symbolic]
        x, u = sym.sym("x", s, k), sym.sym("u", dim, k - 1)
        params, g, lower, upper = [], [ca.vec(x[:, 1:] - (ca.DM(a_mat) @ x[:, :-1] + ca.DM(b_mat) @ u))], [], []
        x0 = sym.sym("x0", s)
        params.append(x0)
        g.append(x[:, 0] - x0)
        lower += [np.zeros(s * (k - 1)), np.zeros(s)]
        own = set() if joint_space is None else {id(c) for c in joint_space.constraints}
        task_x, task_u = (x, u) if joint_space is None else joint_space.to_task(x, u)
        for c in constraints:
            p = sym.sym(f"p_{c.name}", c.n_params)
            params.append(p)
            value = ca.vec(c.build(x, u, p) if id(c) in own else c.build(task_x, task_u, p))
            for bound in (c.lower, c.upper):
                if np.size(bound) not in (1, value.numel()):  # named here, not as NumPy's broadcast error
                    raise ValueError(f"constraint {c.name!r} has {value.numel()} values but {np.size(bound)} bounds")
            g.append(value)
            lower.append(np.broadcast_to(np.asarray(c.lower, float), (value.numel(),)))
            upper.append(np.broadcast_to(np.asarray(c.upper, float), (value.numel(),)))
        self.lbg = np.concatenate(lower)
        self.ubg = np.concatenate([np.zeros(s * k), *upper])
        self.n_constraint_values = [int(np.asarray(lo).size) for lo in lower[2:]]
        cost = 0
        if accel_weights is not None:  # distance to a reference input sequence
            ref = sym.sym("u_ref", dim, k - 1)
            params.append(ca.vec(ref))
            w = ca.repmat(ca.DM(np.sqrt(accel_weights)), 1, k - 1)
            cost += ca.sumsqr(w * (u - ref)) / k
            if smoothness > 0:  # and smooth, from rest and back to rest: the arm cannot step its acceleration
                zero = ca.DM.zeros(dim, 1)
                jerk = ca.horzcat(zero, u, zero)
                cost += smoothness * ca.sumsqr(ca.repmat(ca.DM(np.sqrt(accel_weights)), 1, k)
                                               * (jerk[:, 1:] - jerk[:, :-1])) / k
        if end_columns is not None:  # the peer's weighted end error
            target = sym.sym("end_target", len(end_columns))
            params.append(target)
            cost += ca.sumsqr(ca.DM(end_weights) * (task_x[list(end_columns), -1] - target))
        options = {"ipopt.print_level": 0, "print_time": False, "ipopt.tol": tol, "ipopt.max_iter": max_iter}
        if warm:
            options.update(WARM_OPTIONS)
        if joint_space is not None:
            options.update(dict(joint_space.options))
        variables = ca.vertcat(ca.vec(u), ca.vec(x))  # vec() is column-major: u[:, j] contiguous
        self.lbx, self.ubx = np.full(variables.numel(), -np.inf), np.full(variables.numel(), np.inf)
        if joint_space is not None and joint_space.state_bounds is not None:
            low, high = (np.asarray(b, dtype=float) for b in joint_space.state_bounds)
            first = dim * (k - 1) + s  # x[:, 1] onward
            self.lbx[first:], self.ubx[first:] = np.tile(low, k - 1), np.tile(high, k - 1)
        self.solver = ca.nlpsol("transcription", "ipopt",
                                {"x": variables, "f": cost, "g": ca.vertcat(*g), "p": ca.vertcat(*params)}, options)
        self.n_accel = dim * (k - 1)
        self.build_seconds = time.perf_counter() - start

    def solve(
        self, x0: np.ndarray, guess: np.ndarray, params: Sequence[np.ndarray] = (),
        reference: np.ndarray | None = None, end_target: np.ndarray | None = None,
    ) -> Solution:
        """Solve from the input sequence ``guess`` ``(K-1, d)`` (states: integrated from ``x0``).

        ``params``: one array per constraint (in order; empty for those without parameters);
        ``reference``: ``u_ref`` ``(K-1, d)`` for the distance cost; ``end_target`` for the end-error cost.
        """
        x0 = np.asarray(x0, np.float64)
        guess = np.asarray(guess, np.float64)
        states = integrate_numpy(x0, guess, self.dt)
        p = [x0] + [np.asarray(v, np.float64).reshape(-1) for v in params]
        if reference is not None:
            p.append(np.asarray(reference, np.float64).reshape(-1))
        if end_target is not None:
            p.append(np.asarray(end_target, np.float64).reshape(-1))
        start = time.perf_counter()
        sol = self.solver(x0=np.concatenate([guess.reshape(-1), states.reshape(-1)]), lbg=self.lbg, ubg=self.ubg,
                          lbx=self.lbx, ubx=self.ubx, p=np.concatenate(p))
        seconds = time.perf_counter() - start
        stats = self.solver.stats()
        status = str(stats["return_status"])
        accel = np.array(sol["x"][: self.n_accel]).reshape(self.length - 1, self.dim)
        return Solution(
            accel=accel, states=integrate_numpy(x0, accel, self.dt), status=status,
            success=status in ("Solve_Succeeded", "Solved_To_Acceptable_Level"),
            infeasible=status in ("Infeasible_Problem_Detected", "Restoration_Failed"),
            iterations=int(stats["iter_count"]), seconds=seconds,
        )


_requests: dict[tuple, int] = {}


def transcription(
    dim: int, length: int, constraints: tuple[Constraint, ...], *, dt: float = DT,
    accel_weights: tuple[float, ...] | None = None, end_columns: tuple[int, ...] | None = None,
    end_weights: tuple[float, ...] | None = None, warm: bool = False, tol: float = 1e-9, max_iter: int = 3000,
    symbolic: str = "auto", smoothness: float = 0.0, joint_space: JointSpace | None = None,
) -> Transcription:
    """The (cached) NLP for a motion of ``length`` samples of a ``dim``-axis double integrator.

    Give ``accel_weights`` for the distance-to-reference cost (the polish), or ``end_columns``
    and ``end_weights`` for the weighted end-error cost (the peer); ``warm`` for a start at a
    nearly feasible point.

    ``symbolic``: CasADi's ``"SX"`` (scalar graph: slow to build — 0.3 s at K = 500, 1 s at 1000 —
    but fast per IPOPT iteration) or ``"MX"`` (builds ~10× faster, iterations ~1.5× slower).
    ``"auto"`` (default): MX the first time a structure is asked for (a one-off length, as
    ``keep_end`` on motions of every length meets), SX from the second time on (it will be reused).
    ``smoothness`` λ adds ``λ Σ_k |√w ⊙ (u[k+1] − u[k])|² / K`` to the distance cost, with ``u[-1] =
    u[K-1] = 0`` (the motion starts and ends with zero acceleration): the correction is spread over
    about √λ samples instead of packed into a few large inputs, which a real arm cannot follow.
    ``joint_space``: solve on a robot's joints instead (:class:`JointSpace`): ``dim``, the states, inputs,
    reference and solution are then the joints', and ``constraints`` (and the end cost) are the task's, evaluated
    on its forward kinematics.
    """
    check_number("a transcribed motion's length (samples)", length, minimum=2, integer=True)
    if accel_weights is None and end_columns is None:
        raise ValueError("a transcription needs a cost: accel_weights (polish) or end_columns (end error)")
    if symbolic not in ("auto", "SX", "MX"):
        raise ValueError(f"symbolic must be 'auto', 'SX' or 'MX', got {symbolic!r}")
    key = (dim, length, constraints, dt, accel_weights, end_columns, end_weights, warm, tol, max_iter,
           float(smoothness), joint_space)
    if symbolic == "auto":
        _requests[key] = _requests.get(key, 0) + 1
        symbolic = "MX" if _requests[key] == 1 else "SX"
    return _build(*key, symbolic=symbolic)


@lru_cache(maxsize=64)
def _build(
    dim: int, length: int, constraints: tuple[Constraint, ...], dt: float, accel_weights: tuple[float, ...] | None,
    end_columns: tuple[int, ...] | None, end_weights: tuple[float, ...] | None, warm: bool, tol: float,
    max_iter: int, smoothness: float, joint_space: JointSpace | None, symbolic: str,
) -> Transcription:
    return Transcription(dim, length, dt, constraints, accel_weights, end_columns, end_weights, warm, tol, max_iter,
                         symbolic, smoothness, joint_space)


def scale_rows(expression: Any, factors: Sequence[float]) -> Any:
    """``diag(factors) @ expression`` for a CasADi SX or MX matrix (which do not broadcast a column)."""
    return casadi().DM(np.diag(np.asarray(factors, dtype=float))) @ expression


def end_values(columns: Sequence[int], name: str = "end") -> Constraint:
    """``x[K-1, columns] = p``: the motion ends at given values of some state fields (p: the values)."""
    cols = tuple(int(c) for c in columns)
    return Constraint(name, ("end_values", cols), lambda x, u, p: x[list(cols), -1] - p, 0.0, 0.0, len(cols))


def end_bands(
    columns: Sequence[int], low: Sequence[float], high: Sequence[float], name: str = "end bands"
) -> Constraint:
    """``low[j] ≤ x[K-1, columns[j]] ≤ high[j]``: the motion ends inside a band on each of some state fields."""
    cols = tuple(int(c) for c in columns)
    lows, highs = tuple(float(v) for v in low), tuple(float(v) for v in high)
    if not cols or not len(cols) == len(lows) == len(highs):
        raise ValueError(f"end bands need one (low, high) per column, got {len(cols)} columns, {len(lows)} lows and "
                         f"{len(highs)} highs")
    # the columns are this function's own: a lambda built in a caller's loop or branch would read whatever its
    # variable names last, e.g. another constraint's columns
    return Constraint(name, ("end_bands", cols, lows, highs), lambda x, u, p: x[list(cols), -1], lows, highs)


def state_limits(columns: Sequence[int], limits: Sequence[float], name: str = "limits") -> Constraint:
    """``|x[k, columns[j]]| ≤ limits[j]`` for every sample from 1 on (sample 0 is the given start), scaled so each
    bound is ±1."""
    cols = tuple(int(c) for c in columns)
    lims = tuple(float(v) for v in np.ravel(check_finite_array("state limits", limits, minimum=0.0,
                                                                strict_minimum=True)))
    if not cols or len(cols) != len(lims):
        raise ValueError(f"state limits need one limit per column, got {limits!r} for {cols}")
    scale = tuple(1.0 / v for v in lims)
    return Constraint(name, ("state_limits", cols, lims), lambda x, u, p: scale_rows(x[list(cols), 1:], scale),
                      -1.0, 1.0)


def input_limits(limits: Sequence[float], name: str = "input limits") -> Constraint:
    """``|u[k, j]| ≤ limits[j]`` for every sample (scaled so each bound is ±1)."""
    scale = 1.0 / check_finite_array("input limits", limits, minimum=0.0, strict_minimum=True)
    if scale.ndim != 1:
        raise ValueError(f"input limits need one limit per input, got {limits!r}")
    return Constraint(name, ("input_limits", *map(float, limits)), lambda x, u, p: scale_rows(u, scale), -1.0, 1.0)


def within_reach(columns: Sequence[int], radius: float, name: str = "within reach") -> Constraint:
    """``|x[k, columns]| ≤ radius`` for every sample: the positions stay in a disc (ball) about the origin
    — a robot's workspace, conservatively (scaled so the bound is 1)."""
    cols = tuple(int(c) for c in columns)
    check_number("a reach radius", radius, minimum=0.0, strict_minimum=True)

    def build(x: Any, u: Any, p: Any) -> Any:
        return sum(x[c, :] ** 2 for c in cols) / radius**2

    return Constraint(name, ("within_reach", cols, float(radius)), build, -np.inf, 1.0)
