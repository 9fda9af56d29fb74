"""Sliding an object on a frying pan with the simulated arm (ch. 3): :func:`run_sliding`.

Pan states ``(K, 4)`` (or a chapter-3 plan) → the pan command of eq. 3.28, executed at 1 ms
with PD + DOB (:func:`seqmotion.sim.arm.execute`); measures the object's path in the pan frame
against the command, the pan's excursion, and whether the object fell off or tipped.

Two ways the arm differs from the 2-D model a plan is made in, and what to do about them
(``benchmarks/bench_refine_arm.py`` measures both):

* **friction** — the simulated object–pan contact has μ = μ' = 0.5 (:data:`ARM_PHYSICS`), the
  planner's nominal physics μ = 1.0, μ' = 0.5. A plan refined at one friction exploits it, and
  tracks an order of magnitude worse on the arm than in 2-D. Plan and refine for the arm at
  :data:`ARM_PHYSICS` (``planner.plan(line, mu=0.5, mu_dyn=0.5)``, ``seqmotion plan --mu 0.5 --mu-dyn 0.5``).
* **the pan's wall** — the 2-D object is a point on an unbounded pan; the arm's object is a
  cylinder of radius 3 cm in a pan of radius 12 cm, so its centre stays within
  :data:`WALL_CLEARANCE` (9 cm) of the pan's centre. The 2-D physics is the same wherever on the
  pan the object starts, so :func:`run_sliding` places the command's origin where the commanded
  path clears the wall (:func:`object_origin`; a 5 cm circle from the centre reaches 10 cm and
  is centred) and measures against the command placed there.

No friction coefficient enters the measurements (they are of positions), so :func:`run_sliding`
takes none.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..data.trajectories import tracking_rmse
from ..tasks.sliding.physics import SlidingPhysics
from .arm import (
    ExecutionLog,
    JointReport,
    Media,
    Observer,
    RobotFlags,
    check_times,
    execute,
    first_true,
    prepare_reference,
    single_trajectory,
)
from .control import Gains, resolve_gains
from .kinematics import Reference, pan_reference
from .robot_models import Robot, resolve_robot
from .scene import MU_OBJECT, OBJECT_HALF_HEIGHT, OBJECT_MASS, OBJECT_RADIUS, PAN_ORIGIN, PAN_RADIUS

TIP_ANGLE = np.pi / 4
"""The object counts as tipped once its axis is further than this from the pan's normal [rad]."""
ARM_PHYSICS = SlidingPhysics(mu=MU_OBJECT, mu_dyn=MU_OBJECT)
"""The friction of the simulated object–pan contact (μ = μ' = 0.5): plan and refine at it
(``mu=ARM_PHYSICS.mu, mu_dyn=ARM_PHYSICS.mu_dyn``) a plan that :func:`run_sliding` is to execute."""
ARM_FRICTION = ARM_PHYSICS.to_dict()  # the same as keywords: refine_plan(planner, command, **ARM_FRICTION)
WALL_CLEARANCE = PAN_RADIUS - OBJECT_RADIUS
"""Farthest the object's centre gets from the pan's centre before its side touches the wall [m]."""


def object_origin(command_xy: np.ndarray) -> np.ndarray:
    """Where on the pan to put the origin of a commanded object path ``(K, ≥2)`` [m], ``(2,)`` [m].

    ``(0, 0)`` (the pan's centre) when the whole path keeps the object's centre within
    :data:`WALL_CLEARANCE` of it; otherwise the shift that centres the path's bounding box on
    the pan (the path may still reach the wall if it is wider than the pan allows).
    """
    xy = np.asarray(command_xy, dtype=np.float64)[:, :2]
    if np.linalg.norm(xy, axis=1).max(initial=0.0) <= WALL_CLEARANCE:
        return np.zeros(2)
    return -(xy.max(axis=0) + xy.min(axis=0)) / 2


@dataclass
class SlidingResult(RobotFlags):
    """What happened when the arm shook the pan.

    Positions in metres, in the 2-D model's axes (x forward, y left); the object's path is in
    the pan frame (relative to the pan's centre). ``time[k] = k dt``; samples ``[0, n_motion)``
    are the given trajectory.

    Attributes:
        time: ``(N,)`` [s].
        pan_command: ``(N, 2)`` commanded ``(x_p, y_p)``.
        pan_response: ``(N, 2)`` executed ``(x_p, y_p)``.
        pan_accel: ``(N, 2)`` executed pan acceleration [m/s²] (differences of the measured velocity).
        object_path: ``(N, 2)`` object centre relative to the pan centre, pan frame.
        object_height: ``(N,)`` object base above the pan surface (≈ 0 while it stands on it).
        command: ``(K, 2)`` the object path it was asked for, placed on the pan (``origin`` added;
            ``None`` if none was given).
        origin: ``(2,)`` where the command's origin was put, relative to the pan's centre
            (:func:`object_origin`).
        rmse: RMSE between ``object_path`` and ``command`` over the command's samples.
        rmse_plan: RMSE against the plan's 2-D prediction ``rel_states`` placed likewise (if a plan was given).
        pan_rmse: pan tracking RMSE over the trajectory.
        pan_excursion: largest distance of the pan from its start over the run.
        pan_range: ``(2,)`` largest |x_p|, |y_p| commanded.
        fell_off: the object left the pan (beyond its wall, or below its surface).
        fell_off_time: when it first did [s], or ``None``.
        tipped: the object's axis tilted more than :data:`TIP_ANGLE` (45°) from the pan's normal at some time.
        torque_peak, realtime_factor, diverged, n_motion, joints: as in :class:`PancakeResult`.
    """

    time: np.ndarray
    pan_command: np.ndarray
    pan_response: np.ndarray
    pan_accel: np.ndarray
    object_path: np.ndarray
    object_height: np.ndarray
    command: np.ndarray | None
    origin: np.ndarray
    rmse: float | None
    rmse_plan: float | None
    pan_rmse: float
    pan_excursion: float
    pan_range: np.ndarray
    fell_off: bool
    fell_off_time: float | None
    tipped: bool
    torque_peak: np.ndarray
    realtime_factor: float
    diverged: str | None
    n_motion: int
    joints: JointReport | None = None

    def summary(self) -> dict[str, Any]:
        """The scalar metrics as a JSON-friendly dict."""
        return {
            "object_rmse_m": self.rmse,
            "object_rmse_vs_plan_m": self.rmse_plan,
            "command_origin_m": self.origin.tolist(),
            "pan_rmse_m": self.pan_rmse,
            "pan_excursion_m": self.pan_excursion,
            "pan_range_m": self.pan_range.tolist(),
            "fell_off": self.fell_off,
            "fell_off_time_s": self.fell_off_time,
            "tipped": self.tipped,
            "realtime_factor": self.realtime_factor,
            "diverged": self.diverged,
            **({"robot": self.robot} if self.joints is None else self.joints.summary()),
        }

    def describe(self) -> str:
        """One line for people: how well the object followed, and whether it stayed on."""
        parts = []
        if self.rmse is not None:
            parts.append(f"object RMSE {self.rmse * 1e3:.1f} mm against the command")
        if np.any(self.origin != 0):
            x, y = 1e3 * self.origin + 0.0  # no "-0"
            parts.append(f"command placed at ({x:.0f}, {y:.0f}) mm from the pan's centre to clear its wall")
        parts.append(f"pan within {self.pan_excursion * 1e3:.0f} mm of its start")
        parts.append("object fell off" if self.fell_off else ("object tipped" if self.tipped else "object stayed on"))
        robot = None if self.joints is None else self.joints.describe()  # limits broken, or unknown
        if robot:
            parts.append(robot)
        if self.diverged:
            parts.append(f"run cut short: {self.diverged}")
        return "; ".join(parts)


def run_sliding(
    plan_or_pan_states: object,
    command: object | None = None,
    *,
    gains: str | Gains = "ch3",
    video: str | Path | None = None,
    snapshots: str | Path | None = None,
    n_snapshots: int = 6,
    camera: str = "front",
    decel_time: float = 0.1,
    hold_time: float = 0.2,
    settle_time: float = 0.2,
    origin: object = "auto",
    model_bias: bool = False,
    accel_feedforward: bool = True,
    check_workspace: bool = True,
    fps: float = 30.0,
    slow_motion: float = 2.0,
    robot: str | Robot | None = None,
    observe: Observer | None = None,
) -> SlidingResult:
    """Shake the frying pan along planned pan states and watch the object (§3.5).

    The command is ``q = [x_p + 0.65, y_p, 0.3, 0, π/2, 0]`` (eq. 3.28), with the pan states'
    velocities and accelerations fed forward, then ``decel_time`` of constant deceleration and
    ``hold_time`` at rest. The object (cylinder, μ = μ' = 0.5: plan at :data:`ARM_PHYSICS`) starts
    at rest at the first commanded object position, placed on the pan at ``origin``.

    Args:
        plan_or_pan_states: an object with attributes ``pan_states (K, 4)`` and ``rel_states (K, 4)``
            (a chapter-3 plan: ``[x, y, vx, vy]`` of the pan and of the object relative to it),
            or the pan states ``(K, 4)`` themselves.
        command: ``(K, 4)`` (or ``(K, 2)``) object-relative path the motion was planned for;
            the RMSE is measured against it. Without it, a plan's ``rel_states`` are used.
        gains: ``"ch3"`` (default), ``"ch2"``, ``"ch4"`` or a :class:`~seqmotion.sim.control.Gains`.
        origin: where the origin of the command (and of the plan's ``rel_states``) lies on the
            pan, ``(2,)`` [m] from its centre; ``"auto"`` (default): :func:`object_origin` of the
            command (or of the plan's path), i.e. the centre unless the path would reach the wall.
        video, snapshots, n_snapshots, camera (``"front"`` or ``"top"``), decel_time, hold_time,
        settle_time, model_bias, accel_feedforward, check_workspace, fps, slow_motion, robot, observe: as in
        :func:`~seqmotion.sim.pancake.run_pancake`.

    Returns:
        A :class:`SlidingResult`.
    """
    plan_rel = None
    if hasattr(plan_or_pan_states, "pan_states") and hasattr(plan_or_pan_states, "rel_states"):
        pan = single_trajectory(plan_or_pan_states.pan_states, 4, "plan.pan_states")
        plan_rel = single_trajectory(plan_or_pan_states.rel_states, 4, "plan.rel_states")
        if plan_rel.shape[0] != pan.shape[0]:
            raise ValueError(
                f"plan.pan_states and plan.rel_states differ in length: {pan.shape[0]} vs {plan_rel.shape[0]}"
            )
    else:
        pan = single_trajectory(plan_or_pan_states, 4, "pan_states")
    cmd = None
    if command is not None:
        c = np.asarray(command, dtype=np.float64) if not isinstance(command, np.ndarray) else command
        if c.ndim != 2 or c.shape[-1] not in (2, 4):
            raise ValueError(f"command must have shape (K, 4) or (K, 2), got {np.shape(command)}")
        cmd = single_trajectory(c, c.shape[-1], "command")[:, :2]
        if cmd.shape[0] != pan.shape[0]:
            raise ValueError(f"command has {cmd.shape[0]} samples but the pan trajectory has {pan.shape[0]}")
    check_times(decel_time=decel_time, hold_time=hold_time, settle_time=settle_time)
    path = cmd if cmd is not None else plan_rel
    start = path[0, :2] if path is not None else np.zeros(2)
    if np.hypot(*start) > PAN_RADIUS - 0.04:  # as given: a command from the pan's centre
        raise ValueError(f"the object's start {start.tolist()} m is not on the pan (radius {PAN_RADIUS} m)")
    if isinstance(origin, str):
        if origin != "auto":
            raise ValueError(f"origin must be 'auto' or (x, y) in metres, got {origin!r}")
        shift = object_origin(path) if path is not None else np.zeros(2)
    else:
        try:
            shift = np.asarray(origin, dtype=np.float64)
        except (TypeError, ValueError):
            shift = np.full(1, np.nan)
        if shift.shape != (2,) or not np.isfinite(shift).all() or np.hypot(*shift) > PAN_RADIUS:
            raise ValueError(f"origin must be 'auto' or (x, y) [m] on the pan (radius {PAN_RADIUS} m), got {origin!r}")
    if cmd is not None:  # from here on, paths are in the pan-centre frame
        cmd = cmd + shift
    if plan_rel is not None:
        plan_rel = plan_rel.copy()
        plan_rel[:, :2] += shift
    gains = resolve_gains(gains)
    arm = resolve_robot(robot)  # None: the built-in arm
    ref = pan_reference(pan, decel_time=decel_time, hold_time=hold_time)
    prepare_reference(ref, "sliding", accel_feedforward=accel_feedforward, check_workspace=check_workspace,
                      robot=arm)
    if np.hypot(*(start + shift)) > PAN_RADIUS - 0.04:
        raise ValueError(f"the object's start {start.tolist()} m, with the command's origin at {shift.tolist()} m, "
                         f"is not on the pan (radius {PAN_RADIUS} m)")
    start = start + shift
    media = Media.plan(ref, video, snapshots, n_snapshots, fps, slow_motion, camera)
    # Planar (x, y) on the pan = the tool's (z, y) axes; the object stands on the pan's surface.
    log = execute("sliding", ref, gains, model_bias=model_bias, object_height=OBJECT_HALF_HEIGHT, object_offset=start,
                  object_mass=OBJECT_MASS, settle_time=settle_time, media=media, robot=arm,
                  observe=observe)
    return _sliding_metrics(ref, log, cmd if cmd is not None else plan_rel, plan_rel, shift)


def _sliding_metrics(
    ref: Reference, log: ExecutionLog, target: np.ndarray | None, plan_rel: np.ndarray | None, origin: np.ndarray
) -> SlidingResult:
    """The measurements of a run against ``target`` ``(K, ≥2)`` and the plan's ``plan_rel`` ``(K, 4)``, both
    in the pan-centre frame (the command's ``origin`` ``(2,)`` added)."""
    n, k_motion = log.steps, min(ref.n_motion, log.steps)
    obj = log.object_in_tool()
    rel = obj.rel  # site frame: (-up, y, along)
    path = rel[:, [2, 1]]
    height = -rel[:, 0] - OBJECT_HALF_HEIGHT
    off = (np.linalg.norm(path, axis=1) > PAN_RADIUS + 0.01) | (height < -0.01)
    first_off = first_true(off)
    pan_cmd = ref.pos[:n, :2] - PAN_ORIGIN[:2]
    pan_resp = log.tool_pos[:, :2] - PAN_ORIGIN[:2]
    pan_accel = np.zeros((n, 2))
    pan_accel[:-1] = np.diff(log.tool_twist[:, :2], axis=0) / ref.dt
    if n > 1:
        pan_accel[-1] = pan_accel[-2]

    def rmse_to(target_xy: np.ndarray | None) -> float | None:
        if target_xy is None:
            return None
        k = min(k_motion, target_xy.shape[0])
        return tracking_rmse(path[:k], target_xy[:k, :2])

    return SlidingResult(
        time=np.arange(n) * ref.dt,
        pan_command=pan_cmd,
        pan_response=pan_resp,
        pan_accel=pan_accel,
        object_path=path,
        object_height=height,
        command=None if target is None else target[:, :2],
        origin=np.asarray(origin, dtype=np.float64),
        rmse=rmse_to(target),
        rmse_plan=rmse_to(plan_rel) if (plan_rel is not None) else None,
        pan_rmse=tracking_rmse(pan_resp[:k_motion], pan_cmd[:k_motion]),
        pan_excursion=float(np.linalg.norm(pan_resp - pan_resp[:1], axis=1).max(initial=0.0)),
        pan_range=np.abs(ref.pos[: ref.n_motion, :2] - PAN_ORIGIN[:2]).max(axis=0),
        fell_off=first_off is not None,
        fell_off_time=None if first_off is None else first_off * ref.dt,
        tipped=bool((obj.tilt > TIP_ANGLE).any()),
        torque_peak=log.torque_peak,
        realtime_factor=log.realtime_factor,
        diverged=log.diverged,
        n_motion=ref.n_motion,
        joints=log.joints,
    )
