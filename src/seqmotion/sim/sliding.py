"""Sliding an object on a frying pan with the simulated arm (ch. 3): :func:`run_sliding`.

Pan states ``(K, 4)`` (or a chapter-3 plan) → the pan command of eq. 3.28, executed at 1 ms
with PD + DOB (:func:`seqmotion.sim.arm.execute`); measures the object's path in the pan frame
against the command, the pan's excursion, and whether the object fell off or tipped.

The simulated object–pan contact has μ = μ' = 0.5 (:data:`~seqmotion.sim.scene.MU_OBJECT`);
no friction coefficient enters the measurements (they are of positions), so :func:`run_sliding`
takes none.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .arm import (
    ExecutionLog,
    Media,
    check_times,
    execute,
    first_true,
    prepare_reference,
    rmse,
    single_trajectory,
)
from .control import Gains, resolve_gains
from .kinematics import Reference, pan_reference
from .scene import OBJECT_HALF_HEIGHT, OBJECT_MASS, PAN_ORIGIN, PAN_RADIUS

TIP_ANGLE = np.pi / 4
"""The object counts as tipped once its axis is further than this from the pan's normal [rad]."""


@dataclass
class SlidingResult:
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
        command: ``(K, 2)`` the object path it was asked for (``None`` if none was given).
        rmse: RMSE between ``object_path`` and ``command`` over the command's samples.
        rmse_plan: RMSE against the plan's 2-D prediction ``rel_states`` (if a plan was given).
        pan_rmse: pan tracking RMSE over the trajectory.
        pan_excursion: largest distance of the pan from its start over the run.
        pan_range: ``(2,)`` largest |x_p|, |y_p| commanded.
        fell_off: the object left the pan (beyond its wall, or below its surface).
        fell_off_time: when it first did [s], or ``None``.
        tipped: the object's axis tilted more than :data:`TIP_ANGLE` (45°) from the pan's normal at some time.
        torque_peak, realtime_factor, diverged, n_motion: as in :class:`PancakeResult`.
    """

    time: np.ndarray
    pan_command: np.ndarray
    pan_response: np.ndarray
    pan_accel: np.ndarray
    object_path: np.ndarray
    object_height: np.ndarray
    command: np.ndarray | None
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

    def summary(self) -> dict[str, Any]:
        """The scalar metrics as a JSON-friendly dict."""
        return {
            "object_rmse_m": self.rmse,
            "object_rmse_vs_plan_m": self.rmse_plan,
            "pan_rmse_m": self.pan_rmse,
            "pan_excursion_m": self.pan_excursion,
            "pan_range_m": self.pan_range.tolist(),
            "fell_off": self.fell_off,
            "fell_off_time_s": self.fell_off_time,
            "tipped": self.tipped,
            "realtime_factor": self.realtime_factor,
            "diverged": self.diverged,
        }

    def describe(self) -> str:
        """One line for people: how well the object followed, and whether it stayed on."""
        parts = []
        if self.rmse is not None:
            parts.append(f"object RMSE {self.rmse * 1e3:.1f} mm against the command")
        parts.append(f"pan within {self.pan_excursion * 1e3:.0f} mm of its start")
        parts.append("object fell off" if self.fell_off else ("object tipped" if self.tipped else "object stayed on"))
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
    model_bias: bool = False,
    accel_feedforward: bool = True,
    check_workspace: bool = True,
    fps: float = 30.0,
    slow_motion: float = 2.0,
) -> SlidingResult:
    """Shake the frying pan along planned pan states and watch the object (§3.5).

    The command is ``q = [x_p + 0.65, y_p, 0.3, 0, π/2, 0]`` (eq. 3.28), with the pan states'
    velocities and accelerations fed forward, then ``decel_time`` of constant deceleration and
    ``hold_time`` at rest. The object (cylinder, μ = μ' = 0.5) starts at rest at the first
    commanded object position (default the pan centre).

    Args:
        plan_or_pan_states: an object with attributes ``pan_states (K, 4)`` and ``rel_states (K, 4)``
            (a chapter-3 plan: ``[x, y, vx, vy]`` of the pan and of the object relative to it),
            or the pan states ``(K, 4)`` themselves.
        command: ``(K, 4)`` (or ``(K, 2)``) object-relative path the motion was planned for;
            the RMSE is measured against it. Without it, a plan's ``rel_states`` are used.
        gains: ``"ch3"`` (default), ``"ch2"``, ``"ch4"`` or a :class:`~seqmotion.sim.control.Gains`.
        video, snapshots, n_snapshots, camera (``"front"`` or ``"top"``), decel_time, hold_time,
        settle_time, model_bias, accel_feedforward, check_workspace, fps, slow_motion: as in
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
    gains = resolve_gains(gains)
    ref = pan_reference(pan, decel_time=decel_time, hold_time=hold_time)
    prepare_reference(ref, "sliding", accel_feedforward=accel_feedforward, check_workspace=check_workspace)
    start = cmd[0] if cmd is not None else (plan_rel[0, :2] if plan_rel is not None else np.zeros(2))
    if np.hypot(*start) > PAN_RADIUS - 0.04:
        raise ValueError(f"the object's start {start.tolist()} m is not on the pan (radius {PAN_RADIUS} m)")
    media = Media.plan(ref, video, snapshots, n_snapshots, fps, slow_motion, camera)
    # Planar (x, y) on the pan = the tool's (z, y) axes; the object stands on the pan's surface.
    log = execute("sliding", ref, gains, model_bias=model_bias, object_height=OBJECT_HALF_HEIGHT, object_offset=start,
                  object_mass=OBJECT_MASS, settle_time=settle_time, media=media)
    return _sliding_metrics(ref, log, cmd if cmd is not None else plan_rel, plan_rel)


def _sliding_metrics(
    ref: Reference, log: ExecutionLog, target: np.ndarray | None, plan_rel: np.ndarray | None
) -> SlidingResult:
    """The measurements of a run against ``target`` ``(K, ≥2)`` and the plan's ``plan_rel`` ``(K, 4)``."""
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
        return rmse(path[:k] - target_xy[:k, :2])

    return SlidingResult(
        time=np.arange(n) * ref.dt,
        pan_command=pan_cmd,
        pan_response=pan_resp,
        pan_accel=pan_accel,
        object_path=path,
        object_height=height,
        command=None if target is None else target[:, :2],
        rmse=rmse_to(target),
        rmse_plan=rmse_to(plan_rel) if (plan_rel is not None) else None,
        pan_rmse=rmse(pan_resp[:k_motion] - pan_cmd[:k_motion]),
        pan_excursion=float(np.linalg.norm(pan_resp - pan_resp[:1], axis=1).max(initial=0.0)),
        pan_range=np.abs(ref.pos[: ref.n_motion, :2] - PAN_ORIGIN[:2]).max(axis=0),
        fell_off=first_off is not None,
        fell_off_time=None if first_off is None else first_off * ref.dt,
        tipped=bool((obj.tilt > TIP_ANGLE).any()),
        torque_peak=log.torque_peak,
        realtime_factor=log.realtime_factor,
        diverged=log.diverged,
        n_motion=ref.n_motion,
    )
