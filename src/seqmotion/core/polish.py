"""The exact polish's data: a task's motion as an NLP (:class:`ExactForm`) and the time a rest-to-rest
move needs (what ``keep_end`` and ``exact=True`` build on; the NLP is :mod:`seqmotion.physics.transcription`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..physics.transcription import Constraint


@dataclass(frozen=True)
class ExactForm:
    """A task's motion as an NLP, for the exact polish (:mod:`seqmotion.physics.transcription`).

    Attributes:
        dim: axes of the double integrator the task's states follow (state = the ``dim``
            positions, then their velocities; inputs = ``dim`` accelerations).
        dt: its sampling interval [s].
        constraints: the task's own constraints in CasADi form (pancake: the friction cone in force form).
        accel_weights: the polish's metric, ``Σ_k |√w ⊙ (u[k] − u_ref[k])|² / K`` (pancake: 1, 1, 0.01 —
            radians count a tenth of metres, as in D).
        smoothness: λ of the polish's jerk term (:func:`seqmotion.physics.transcription.transcription`).
        accel_limits: ``|u[k, j]| ≤ accel_limits[j]`` (the robot's), or None.
        travel_accel: the accelerations per axis a rest-to-rest move can plan on, where the task's
            constraint takes part of the limits — ``keep_end`` gives a too-short input the bang-bang time
            at these (default: :data:`EXTEND_MARGIN` × ``accel_limits``).
    """

    dim: int
    dt: float
    constraints: tuple[Constraint, ...]
    accel_weights: tuple[float, ...]
    smoothness: float = 0.0
    accel_limits: tuple[float, ...] | None = None
    travel_accel: tuple[float, ...] | None = None


POLISH_VIOLATION_TOLERANCE = 1e-6
"""A polished motion is exact when the task's constraint violation is at most this (pancake: F_c [rad])."""
WARM_ITERATIONS = 20
"""IPOPT iterations the warm (small-barrier) start gets before the polish falls back to a cold start:
a nearly feasible motion converges within them (7–17 on the README's polishes), but most of the latent stage's
motions do not and finish cold in ~20 more (``benchmarks/bench_keep_end.py --readme``); a far one (e.g. J2's,
1.25 rad outside its band) is faster from IPOPT's default barrier."""
COLD_ITERATIONS = 300
"""…and the cold start gets this many: J2's polish needs ~90; a sketch that cannot end at rest within
the constraints (the arm's limits) is proved locally infeasible in ~50–150, or given up on here."""


def rest_to_rest_accel(
    x0: np.ndarray, columns: list[int], values: np.ndarray, steps: int, form: ExactForm
) -> tuple[float, ...] | None:
    """The accelerations an axis needs at least to go from rest at ``x0`` to rest at its end value in ``steps``
    samples (bang-bang: ``4 |Δp| / T²``), when some axis needs more than ``form.accel_limits``; else None.

    Only for axes that start and end at rest (otherwise no cheap bound is taken)."""
    if form.accel_limits is None:
        return None
    d, span = form.dim, steps * form.dt
    need, over = [], False
    for j, limit in enumerate(form.accel_limits):
        at_rest = d + j in columns and abs(x0[d + j]) < 1e-12 and abs(values[columns.index(d + j)]) < 1e-12
        if j not in columns or not at_rest:
            need.append(0.0)
            continue
        need.append(4 * abs(values[columns.index(j)] - x0[j]) / span**2)
        over |= need[-1] > limit * (1 + 1e-9)
    return tuple(round(float(n), 1) for n in need) if over else None


FALLBACK_END_WEIGHT = 1000.0
"""``keep_end``'s fallback, where no motion reaches the end pose exactly: the weight per metre (per radian,
times the axis's weight) of the end-pose error against the distance to the learned inputs (m/s²)."""

EXTEND_MARGIN = 0.5
"""``keep_end`` plans the time a too-short input needs as the bang-bang time at the task's
:attr:`ExactForm.travel_accel`, by default this share of the arm's acceleration limits (the task's constraint
takes part of them: at the full limits most such polishes are infeasible)…"""
EXTEND_GROWTH = 1.4
"""…and, when the polish is still infeasible, tries again with this many times more samples…"""
EXTEND_ATTEMPTS = 4
"""…up to this many polishes in all (the last 1.4³ ≈ 2.7× the first time)…"""
EXTEND_COLD_ITERATIONS = 100
"""…each but the last with this cap on IPOPT's iterations: a feasible polish converges in ~15–30, a local
proof of infeasibility takes 50–150, and a longer horizon is the cheaper way on. (The time is not searched on
a coarser transcription first: inputs held for several samples make the cone much harder to keep while the
spatula turns, and ask for far more time.)"""


def steps_to_stop(x0: np.ndarray, columns: list[int], values: np.ndarray, steps: int, form: ExactForm) -> int:
    """Input samples (``K - 1``) a rest-to-rest motion needs so each axis's bang-bang acceleration,
    ``4 |Δp| / T²``, stays within ``form.travel_accel`` (default :data:`EXTEND_MARGIN` of
    ``form.accel_limits``): at least ``steps``."""
    travel = form.travel_accel
    if travel is None and form.accel_limits is not None:
        travel = tuple(EXTEND_MARGIN * limit for limit in form.accel_limits)
    if travel is None:
        return steps
    need = steps
    for j, accel in enumerate(travel):
        if j in columns:
            span = math.sqrt(4 * abs(values[columns.index(j)] - x0[j]) / accel)
            need = max(need, math.ceil(span / form.dt))
    return need


