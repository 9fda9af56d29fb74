"""The exact polish's data: a task's motion as an NLP (:class:`ExactForm`) and the time a rest-to-rest
move needs (what ``keep_end`` and ``exact=True`` build on; the NLP is :mod:`seqmotion.physics.transcription`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..physics.integrator import integrate_numpy
from ..physics.transcription import Constraint, JointSpace, Solution, transcription


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
        workspace: the built-in arm's own constraints (pancake: its reach); a robot's :class:`ArmForm` replaces
            them when the polish is asked for that robot.
        on_joints: the task's constraints for a polish on a robot's joints (:attr:`ArmForm.joint_space`), where they
            differ from ``constraints`` (pancake: the cone with a lower normal-force floor, the joints tracking
            their planned path more closely than the built-in arm its task-space one); ``None``: ``constraints``.
    """

    dim: int
    dt: float
    constraints: tuple[Constraint, ...]
    accel_weights: tuple[float, ...]
    smoothness: float = 0.0
    accel_limits: tuple[float, ...] | None = None
    travel_accel: tuple[float, ...] | None = None
    workspace: tuple[Constraint, ...] = ()
    on_joints: tuple[Constraint, ...] | None = None


@dataclass(frozen=True)
class ArmForm:
    """A robot's limits in the exact polish, built by the robot layer for one task.

    Attributes:
        robot: the robot, ``"name (source)"``.
        constraints: constraints on the task's states and inputs that replace the built-in arm's
            :attr:`ExactForm.workspace` (e.g. a reach).
        joint_space: where the polish runs on the robot's joints instead
            (:class:`~seqmotion.physics.transcription.JointSpace`: rated speeds, ranges, … as its own constraints,
            the task's on its forward kinematics), or ``None``.
        to_joints: with ``joint_space``: task states ``(K, S)`` → joint states ``(K, 2n)`` (inverse kinematics).
        to_task: with ``joint_space``: joint states ``(K, 2n)`` and accelerations ``(K-1, n)`` → the task's states
            ``(K, S)`` and inputs ``(K-1, d)`` (forward kinematics).
        hold: with ``joint_space``: the joints' accelerations are held over this many samples (the NLP's knots; a
            quarter of the variables at 4, and the joint path between knots is still the exact double integrator).
    """

    robot: str
    constraints: tuple[Constraint, ...]
    joint_space: JointSpace | None = None
    to_joints: Callable[[np.ndarray], np.ndarray] | None = None
    to_task: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None
    hold: int = 1


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


ARM_MIN_DURATION = 1.0
"""[s] The shortest motion a polish on a robot's joints plans (:class:`ArmForm`; a longer input keeps its length): a
turn past the cone's half-angle becomes a loop of the arm within its rated speeds, and on the UR5e every one of 25
README-style turns (θ 2–3 rad, 0.3–0.8 s sketches) found a loop that ends at rest within 1 s. A much longer one is no
safer: slow loops press the pancake on more weakly, and executed motions of 5–10 s lost it."""
ARM_ITERATIONS = 150
"""IPOPT iterations of the exact polish on a robot's joints, started from the motion that ends as near the end pose as
the limits allow: one it can reach converged in 14–70 on the UR5e; one it cannot is given up on here (1–2 s)."""
ARM_ATTEMPTS = 2
"""Tries of the near-end polish on a robot's joints (:data:`ARM_MIN_DURATION`, then :data:`EXTEND_GROWTH` × longer):
from standing still it converged in 22–62 iterations on every turn tried."""
ARM_EXACT_REACH = 0.03
"""Where the motion that ends as near the end pose as a robot's limits allow still misses it by more than this (in the
task's polish metric: metres, radians times their weight), the exact polish is not tried: on the UR5e every turn
whose near end missed by ≤ 0.023 (e.g. 0.22 rad) polished exactly, those missing by ≥ 0.076 never did."""

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


def retimed(accel: np.ndarray, steps: int) -> np.ndarray:
    """Inputs ``(N, d)`` of a motion from rest, run ``s = steps / N`` times slower: ``(steps, d)`` resampled along
    the same time axis and scaled by ``1/s²``, so the motion follows (nearly) the same path at 1/s the speed."""
    n = len(accel)
    scale = steps / n
    t = np.arange(steps) / scale
    return np.stack([np.interp(t, np.arange(n), accel[:, j]) for j in range(accel.shape[1])], axis=1) / scale**2


def polish_in_joints(
    form: ExactForm, arm: ArmForm, x0: np.ndarray, accel: np.ndarray, constraints: Sequence[Constraint],
    params: Sequence[np.ndarray], start: np.ndarray | None, cold_iterations: int, symbolic: str,
    end_cost: tuple[Sequence[int], Sequence[float], np.ndarray] | None,
) -> Solution:
    """:meth:`~seqmotion.core.trained.TrainedModel.polish` of a task's motion (``form``) on a robot's joints
    (``arm.joint_space``): the motion is mapped to the joints by the arm's inverse kinematics, IPOPT moves the joints
    (cold: the change from a motion about a fixed point to one an arm can run is no small step) with the robot's
    limits as their own constraints and the task's on the forward kinematics, and the result comes back as the task's
    states and inputs (exact forward kinematics at every sample: the states' recursion through the inputs then holds
    to O(dt³) per sample, not to rounding).

    The joints' accelerations are held over ``arm.hold`` samples (the NLP's knots; the motion may grow by up to
    ``hold - 1`` samples to a whole number of knots): the joint path between knots is the double integrator's
    exactly, so speeds and the end state are exact, and the task's constraint, imposed at the knots, is judged
    at every sample by the caller."""
    space, to_joints, to_task = arm.joint_space, arm.to_joints, arm.to_task
    task = form.constraints if form.on_joints is None else form.on_joints
    own = task + arm.constraints  # the robot's own limits stand for the built-in arm's accelerations
    every = own + tuple(constraints)
    # the joints' own constraints come after the task's in the NLP (Transcription appends them)
    values = ([np.zeros(0)] * len(own) + [np.asarray(p, np.float64) for p in params]
              + [np.zeros(0)] * len(space.constraints))
    dt = form.dt

    hold, knots = arm.hold, math.ceil(len(accel) / arm.hold)

    low, high = ((np.full(2 * space.dim, -np.inf), np.full(2 * space.dim, np.inf)) if space.state_bounds is None
                 else (np.asarray(b, dtype=float) for b in space.state_bounds))

    def joint_inputs(task_accel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The start's joint state and the joint accelerations held over each knot (their means), of the joint
        speeds held within their bounds: where the motion passes a singularity or out of reach, the IK's speeds
        run to infinity, and the polish only needs a start and a reference to stay near."""
        joints = to_joints(integrate_numpy(x0, task_accel, dt))
        speeds = np.clip(np.nan_to_num(joints[:, space.dim:]), low[space.dim:], high[space.dim:])
        fine = np.diff(speeds, axis=0) / dt
        fine = np.concatenate([fine, np.zeros((knots * hold - len(fine), space.dim))])
        return joints[0], fine.reshape(knots, hold, space.dim).mean(axis=1)

    q0, reference = joint_inputs(accel)
    _, guess = joint_inputs(accel if start is None else start)
    kwargs: dict[str, Any] = {"dt": hold * dt, "accel_weights": (1.0,) * space.dim,
                              "smoothness": form.smoothness / hold**2, "symbolic": symbolic,
                              "joint_space": space}
    target = None
    if end_cost is not None:
        columns, weights, target = end_cost
        kwargs |= {"end_columns": tuple(int(c) for c in columns), "end_weights": tuple(map(float, weights))}
    nlp = transcription(space.dim, knots + 1, every, max_iter=cold_iterations, **kwargs)
    solution = nlp.solve(q0, guess, values, reference=reference, end_target=target)
    # the joints' accelerations are held over each knot: the 1 ms motion is the same motion, exactly
    joint_accel = np.repeat(solution.accel, hold, axis=0)
    states, task_accel = to_task(integrate_numpy(q0, joint_accel, dt), joint_accel)
    return Solution(accel=task_accel, states=states, status=solution.status, success=solution.success,
                    infeasible=solution.infeasible, iterations=solution.iterations, seconds=solution.seconds)
