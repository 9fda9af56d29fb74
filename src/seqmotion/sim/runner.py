"""Execute generated motions on the simulated arm and measure what the object did.

* :func:`run_pancake` — planar spatula states ``(K, 6)`` → the spatula command of eq. 4.9,
  executed at 1 ms with PD + DOB, then 0.1 s of constant deceleration and a hold; measures
  tracking, the pancake's slip along the blade, its separation from the blade, and whether it
  ends turned over.
* :func:`run_sliding` — pan states ``(K, 4)`` (or a chapter-3 plan) → the pan command of eq.
  3.28; measures the object's path in the pan frame against the command, the pan's excursion,
  and whether the object fell off.

Both share :func:`_execute`: inverse kinematics to the first commanded pose, the object placed
at rest on the tool, a short settling hold, then the 1 ms loop (``mj_step1`` → controller →
``mj_step2``, physics substeps holding the torque), logging the tool and object poses.

**Losing contact** (the sim's counterpart of the 2-D model's friction-cone constraint, which
says the pancake *sticks* to the blade): the pancake has lost contact once its centre has
slipped more than :data:`SLIP_LIMIT` = 5 mm along the blade from where it was placed, or
risen more than :data:`GAP_LIMIT` = 2 mm off its resting height. Both are well above what a
sticking contact does in this model (≤ 0.7 mm of slip and ≤ 0.3 mm of gap over 100 feasible
motions; 3 µm of creep in 1.5 s held still at 40°; the pancake is placed 0.1 mm above the
blade and drops onto it) and small against the pancake (radius 55 mm, thickness 10 mm): a
visible slide or a visible gap. They were fixed before any trajectory set was measured;
``benchmarks/RESULTS_sim.md`` reports how the counts change with half or twice the limits.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import as_trajectories
from ..physics.pancake import violation as _violation
from .control import Gains, TaskSpaceController, resolve_gains, solve_ik
from .kinematics import (
    Reference,
    pan_reference,
    planar_reference,
    planar_tilt,
    quat_to_matrix,
    rotation_angle,
)
from .scene import (
    BLADE_CENTRE,
    BLADE_HALF,
    CONTROL_DT,
    FOREARM,
    GRAVITY,
    OBJECT_HALF_HEIGHT,
    OBJECT_MASS,
    PAN_CENTRE,
    PAN_ORIGIN,
    PAN_RADIUS,
    PANCAKE_HALF_THICKNESS,
    PANCAKE_MASS,
    PANCAKE_ORIGIN,
    SHOULDER_HEIGHT,
    SHOULDER_OFFSET,
    SUBSTEPS,
    TABLE_TOP,
    UPPER_ARM,
    WRIST_TO_FLANGE,
    Scene,
    build_scene,
    import_mujoco,
)

SLIP_LIMIT = 5e-3
"""Slip of the pancake's centre along the blade beyond which contact counts as lost [m]."""
GAP_LIMIT = 2e-3
"""Rise of the pancake's centre above its resting height beyond which contact counts as lost [m]."""
TRACKING_LIMIT = 0.1
"""A tool position error beyond this aborts the run as 'lost tracking' [m]."""
FREE_FALL = 1.0
"""Specific force [m/s²] below which the executed motion counts as free fall (no cone to violate)."""
REACH_MARGIN = 0.02
"""The wrist centre must stay this far inside the arm's full extension [m] (elbow singularity)."""

_SITE_IN_TOOL = {
    # The control site in the tool frame (z along the tool, x the surface's down normal) [m].
    "pancake": np.array([-BLADE_HALF[0] - PANCAKE_HALF_THICKNESS, 0.0, BLADE_CENTRE]),
    "sliding": np.array([0.0, 0.0, PAN_CENTRE]),
}


@lru_cache(maxsize=2)
def get_scene(kind: str) -> Scene:
    """The compiled scene (compiled once per process; runs never modify the model)."""
    return build_scene(kind)


def workspace_problem(reference: Reference, kind: str) -> str | None:
    """Why the commanded tool path cannot be executed by the arm, or ``None`` if it can.

    Checks, per sample, that the wrist centre stays within the arm's reach (minus
    :data:`REACH_MARGIN`), away from the base axis (shoulder singularity) and that the tool
    stays above the table. The arm's own wrist singularity is not predicted here; the run
    reports it as lost tracking if it happens.
    """
    rot = quat_to_matrix(reference.quat)
    flange = reference.pos - rot @ _SITE_IN_TOOL[kind]
    wrist = flange - WRIST_TO_FLANGE * rot[:, :, 2]
    heading = np.arctan2(wrist[:, 1], wrist[:, 0])
    shoulder = np.stack(
        [SHOULDER_OFFSET * np.cos(heading), SHOULDER_OFFSET * np.sin(heading), np.full_like(heading, SHOULDER_HEIGHT)],
        -1,
    )
    dist = np.linalg.norm(wrist - shoulder, axis=1)
    reach = UPPER_ARM + FOREARM - REACH_MARGIN
    checks = [
        (dist > reach, lambda k: f"the wrist centre is {dist[k]:.3f} m from the shoulder (reach {reach:.3f} m)"),
        (dist < abs(UPPER_ARM - FOREARM) + 0.05, lambda k: f"the wrist centre is {dist[k]:.3f} m from the shoulder"),
        (np.hypot(wrist[:, 0], wrist[:, 1]) < 0.05, lambda k: "the wrist centre is over the base axis"),
        (reference.pos[:, 2] < TABLE_TOP + 0.11,
         lambda k: f"the tool is down at the table (z = {reference.pos[k, 2]:.3f} m)"),
    ]
    first = None
    for bad, why in checks:
        idx = np.flatnonzero(bad)
        if idx.size and (first is None or idx[0] < first[0]):
            first = (int(idx[0]), why)
    if first is None:
        return None
    k, why = first
    return f"sample {k} (t = {k * reference.dt:.3f} s, tool at {np.round(reference.pos[k], 3).tolist()}): {why(k)}"


@dataclass
class _Log:
    """What :func:`_execute` records at every control period of the reference (index k ↔ t = k dt)."""

    tool_pos: np.ndarray
    tool_quat: np.ndarray
    tool_twist: np.ndarray
    body_pos: np.ndarray
    body_quat: np.ndarray
    torque: np.ndarray
    body_rel_placed: np.ndarray
    steps: int
    diverged: str | None
    wall_time: float
    simulated_time: float
    frames: list = field(default_factory=list)
    frame_steps: list = field(default_factory=list)


def _execute(
    scene: Scene,
    ref: Reference,
    gains: Gains,
    *,
    model_bias: bool,
    place: Any,
    load: np.ndarray,
    settle_time: float,
    frame_steps: set[int] | None = None,
    camera: str = "front",
    size: tuple[int, int] = (640, 480),
) -> _Log:
    """Run the reference on the arm. ``place(data)`` puts the object at rest on the tool."""
    mujoco = import_mujoco()
    m = scene.model
    d = mujoco.MjData(m)
    d.qpos[scene.arm_qpos] = solve_ik(scene, ref.pos[0], ref.quat[0])
    mujoco.mj_forward(m, d)
    place(d)
    mujoco.mj_forward(m, d)
    # Where the object was put, in the tool site's frame (slip is measured from here).
    body_rel_placed = d.site_xmat[scene.site].reshape(3, 3).T @ (
        d.qpos[scene.body_qpos : scene.body_qpos + 3] - d.site_xpos[scene.site]
    )
    ctl = TaskSpaceController(scene, gains, model_bias=model_bias)
    ctl.reset(d, load)

    recorder = None
    if frame_steps:
        from .render import FrameRecorder

        recorder = FrameRecorder(m, camera=camera, width=size[0], height=size[1])

    n = len(ref)
    twist = np.concatenate([ref.vel, ref.omega], axis=1)
    accel = np.concatenate([ref.acc, ref.alpha], axis=1)
    still = np.zeros(6)
    log = {name: np.zeros((n, dim)) for name, dim in
           [("tool_pos", 3), ("tool_quat", 4), ("tool_twist", 6), ("body_pos", 3), ("body_quat", 4), ("torque", 6)]}
    site, bq = scene.site, scene.body_qpos
    n_settle = round(settle_time / ref.dt)
    frame_steps_done: list[int] = []
    limit2 = TRACKING_LIMIT**2
    bad_qacc = mujoco.mjtWarning.mjWARN_BADQACC
    diverged = None
    steps = 0
    start = _time.perf_counter()
    try:
        for k in range(-n_settle, n):
            mujoco.mj_step1(m, d)  # kinematics, mass matrix, velocities of the current state
            if k < 0:  # settle: hold the first pose while the object comes to rest
                tau = ctl.torque(d, ref.pos[0], ref.quat[0], still, still)
            else:
                tau = ctl.torque(d, ref.pos[k], ref.quat[k], twist[k], accel[k])
                log["tool_pos"][k] = d.site_xpos[site]
                log["tool_quat"][k] = d.site_xquat[site]
                log["tool_twist"][k] = ctl.last_twist  # measured by the controller at this state
                log["body_pos"][k] = d.qpos[bq : bq + 3]
                log["body_quat"][k] = d.qpos[bq + 3 : bq + 7]
                log["torque"][k] = tau
                if recorder is not None and k in frame_steps:
                    recorder.capture(d, k * ref.dt)
                    frame_steps_done.append(k)
                steps = k + 1
            # Cheap per-period checks (NaN fails every comparison): torque finite, tool within reach of the command.
            err = ctl.last_error
            if not (tau @ tau < 1e12) or not (err[0] * err[0] + err[1] * err[1] + err[2] * err[2] < limit2):
                diverged = f"lost tracking at t = {k * ref.dt:.3f} s (tool error {np.linalg.norm(err[:3]):.3f} m)"
                break
            d.ctrl[:] = tau
            mujoco.mj_step2(m, d)
            for _ in range(SUBSTEPS - 1):
                mujoco.mj_step(m, d)
            if k % 50 == 0 and d.warning[bad_qacc].number:
                diverged = f"the simulation became unstable near t = {k * ref.dt:.3f} s"
                break
        if diverged is None and d.warning[bad_qacc].number:
            diverged = "the simulation became unstable"
    finally:
        wall = _time.perf_counter() - start
        if recorder is not None:
            recorder.close()
    return _Log(
        **{name: arr[:steps] for name, arr in log.items()},
        body_rel_placed=body_rel_placed,
        steps=steps,
        diverged=diverged,
        wall_time=wall,
        simulated_time=(n_settle + steps) * ref.dt,
        frames=[] if recorder is None else recorder.frames,
        frame_steps=frame_steps_done,
    )


@dataclass
class _Media:
    """Which control periods to render, and where to write the results."""

    video: str | Path | None
    snapshots: str | Path | None
    video_steps: set[int]
    snapshot_steps: list[int]
    fps: float

    @classmethod
    def plan(cls, ref: Reference, video, snapshots, n_snapshots: int, fps: float, slow_motion: float) -> _Media:
        video_steps: set[int] = set()
        if video is not None:
            if not (fps > 0 and slow_motion > 0):
                raise ValueError(f"fps and slow_motion must be positive, got {fps} and {slow_motion}")
            every = max(1, round(1.0 / (fps * slow_motion * ref.dt)))  # a frame every this many periods
            video_steps = set(range(0, len(ref), every))
        snap_steps: list[int] = []
        if snapshots is not None:
            if n_snapshots < 1:
                raise ValueError(f"n_snapshots must be at least 1, got {n_snapshots}")
            last = min(len(ref), ref.n_motion + round(0.1 / ref.dt)) - 1  # the motion and its deceleration
            snap_steps = sorted(set(np.linspace(0, last, n_snapshots).round().astype(int).tolist()))
        return cls(video, snapshots, video_steps, snap_steps, fps)

    @property
    def steps(self) -> set[int] | None:
        return (self.video_steps | set(self.snapshot_steps)) or None

    def write(self, log: _Log) -> None:
        from .render import write_strip, write_video

        by_step = dict(zip(log.frame_steps, log.frames, strict=True))
        if not by_step:  # the run was cut short before its first frame
            return
        if self.video is not None:
            write_video([by_step[k] for k in sorted(self.video_steps) if k in by_step], self.video, fps=self.fps)
        if self.snapshots is not None:
            picks = [k for k in self.snapshot_steps if k in by_step]
            labels = [f"t = {k * CONTROL_DT:.2f} s" for k in picks]
            write_strip([by_step[k] for k in picks], self.snapshots, labels=labels)


def _single_trajectory(array: object, dim: int, name: str) -> np.ndarray:
    arr, single = as_trajectories(array, dim, name, min_length=2)
    if not single:
        raise ValueError(f"{name} must be one trajectory of shape (K, {dim}); run a batch one trajectory at a time")
    return arr[0]


def _check_times(**times: float) -> None:
    for name, value in times.items():
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a non-negative number of seconds, got {value}")


# --------------------------------------------------------------------------------------------
# Pancake turning (chs. 2 and 4)


@dataclass
class PancakeResult:
    """What happened when the arm executed a planar spatula trajectory.

    Time ``time[k] = k dt`` with k = 0 the first input sample; samples ``[0, n_motion)`` are the
    input trajectory, the rest the deceleration tail and the hold. Positions in metres, angles
    in radians.

    Attributes:
        time: ``(N,)`` [s].
        command: ``(N, 6)`` commanded planar states ``[y, z, θ, v_y, v_z, v_θ]`` (input + tail).
        response: ``(N, 6)`` the same quantities of the executed spatula (θ unwrapped).
        slip: ``(N,)`` distance the pancake's centre has moved along the blade since it was placed.
        gap: ``(N,)`` height of the pancake's centre above its resting height on the blade.
        tilt: ``(N,)`` angle between the pancake's face and the blade.
        position_rmse, attitude_rmse: tool tracking RMSE over the input trajectory [m], [rad].
        max_slip, max_gap: maxima of ``slip`` and ``gap`` over the input trajectory.
        contact_lost: whether ``slip > SLIP_LIMIT`` or ``gap > GAP_LIMIT`` during the input trajectory.
        contact_lost_time: the first such time [s], or ``None``.
        contact_lost_in_tail: the same test during the deceleration tail and hold.
        on_spatula: the pancake rests on the blade at the end (centre over the blade, gap < 1 cm).
        turned_over: the pancake's top face points down at the end (it was turned over).
        executed_violation: ``(n_motion - 1,)`` F_c of the executed spatula motion (eq. 2.18),
            0 where its specific force is below :data:`FREE_FALL` (direction undefined).
        torque_peak: ``(6,)`` largest |joint torque| [N m].
        realtime_factor: simulated time / wall-clock time of the control loop.
        diverged: ``None``, or why the run was cut short (then arrays end there).
        n_motion: number of input samples.
    """

    time: np.ndarray
    command: np.ndarray
    response: np.ndarray
    slip: np.ndarray
    gap: np.ndarray
    tilt: np.ndarray
    position_rmse: float
    attitude_rmse: float
    max_slip: float
    max_gap: float
    contact_lost: bool
    contact_lost_time: float | None
    contact_lost_in_tail: bool
    on_spatula: bool
    turned_over: bool
    executed_violation: np.ndarray
    torque_peak: np.ndarray
    realtime_factor: float
    diverged: str | None
    n_motion: int

    def summary(self) -> dict[str, Any]:
        """The scalar metrics as a JSON-friendly dict."""
        return {
            "position_rmse_m": self.position_rmse,
            "attitude_rmse_rad": self.attitude_rmse,
            "max_slip_m": self.max_slip,
            "max_gap_m": self.max_gap,
            "contact_lost": self.contact_lost,
            "contact_lost_time_s": self.contact_lost_time,
            "contact_lost_in_tail": self.contact_lost_in_tail,
            "on_spatula": self.on_spatula,
            "turned_over": self.turned_over,
            "executed_max_violation_rad": float(self.executed_violation.max(initial=0.0)),
            "realtime_factor": self.realtime_factor,
            "diverged": self.diverged,
        }

    def describe(self) -> str:
        """One line for people: tracking, and what the pancake did."""
        track = f"tracking {self.position_rmse * 1e3:.1f} mm / {np.degrees(self.attitude_rmse):.2f}° RMSE"
        if self.diverged:
            return f"{track}; run cut short: {self.diverged}"
        if self.contact_lost:
            what = (f"pancake lost contact at t = {self.contact_lost_time:.3f} s "
                    f"(max slip {self.max_slip * 1e3:.0f} mm, gap {self.max_gap * 1e3:.0f} mm)")
        else:
            what = f"pancake stayed on (max slip {self.max_slip * 1e3:.1f} mm, gap {self.max_gap * 1e3:.1f} mm)"
        end = "turned over" if self.turned_over else "face up"
        where = "on the spatula" if self.on_spatula else "off the spatula"
        if not self.on_spatula and not self.contact_lost and self.contact_lost_in_tail:
            # Kept during the motion; the spatula then holds its final tilt, which gravity alone
            # can exceed (tilt > atan μ), so the pancake slides off in the tail.
            where += " (it slid off after the motion, during the hold)"
        return f"{track}; {what}; ends {end}, {where}"


def _place_on_tool(scene: Scene, height: float, offset: np.ndarray):
    """A ``place(data)`` that puts the object on the tool surface, face up, ``height`` above the site.

    ``offset``: ``(2,)`` position on the surface along the tool's (z, y) axes [m] — the planar
    (x, y) of the pan, or along/across the blade.
    """

    def place(data) -> None:
        mujoco = import_mujoco()
        rot = data.site_xmat[scene.site].reshape(3, 3)
        up, along, across = -rot[:, 0], rot[:, 2], rot[:, 1]
        pos = data.site_xpos[scene.site] + (height + 1e-4) * up + offset[0] * along + offset[1] * across
        quat = np.zeros(4)
        body_rot = np.stack([along, np.cross(up, along), up], axis=1)  # body z = the surface's up normal
        mujoco.mju_mat2Quat(quat, body_rot.flatten())
        data.qpos[scene.body_qpos : scene.body_qpos + 3] = pos
        data.qpos[scene.body_qpos + 3 : scene.body_qpos + 7] = quat
        data.qvel[scene.body_dof : scene.body_dof + 6] = 0.0

    return place


def _first(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def _rmse(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(err**2, axis=-1)))) if err.size else float("nan")


def run_pancake(
    states: object,
    *,
    gains: str | Gains = "ch2",
    video: str | Path | None = None,
    snapshots: str | Path | None = None,
    n_snapshots: int = 6,
    camera: str = "oblique",
    decel_time: float = 0.1,
    hold_time: float = 0.5,
    settle_time: float = 0.2,
    model_bias: bool = False,
    accel_feedforward: bool = True,
    check_workspace: bool = True,
    fps: float = 30.0,
    slow_motion: float = 4.0,
) -> PancakeResult:
    """Execute planar spatula states on the simulated MH3F-like arm with a pancake on the blade.

    The command is ``q = [0.5, y, z + 0.35, θ, π/2, 0]`` (eq. 4.9; attitude convention in
    :mod:`seqmotion.sim.kinematics`), fed at 1 ms with the states' velocities and accelerations
    (``u[k] = (v[k+1] - v[k]) / dt``) forward; then ``decel_time`` of constant deceleration to
    rest (§4.4.3) and ``hold_time`` held still (so a pancake thrown off can land).

    Args:
        states: ``(K, 6)`` ``[y, z, θ, v_y, v_z, v_θ]`` at 1 ms, starting anywhere in the workspace
            (the pancake is placed at rest on the blade at the first pose).
        gains: ``"ch2"``, ``"ch3"``, ``"ch4"`` or a :class:`~seqmotion.sim.control.Gains`.
        video: write an MP4 here (``slow_motion`` × slower than real time, at ``fps``).
        snapshots: write a PNG strip of ``n_snapshots`` frames over the motion here.
        camera: ``"oblique"`` (default) or ``"front"`` (looks along -x at the y–z plane of the motion).
        decel_time, hold_time, settle_time: [s]; ``settle_time`` is held at the first pose
            before the motion so the pancake comes to rest.
        model_bias: feed gravity/Coriolis forward instead of leaving them to the DOB.
        accel_feedforward: feed the states' accelerations forward (default). Without it the PD
            acts on position and velocity errors only; §4.4.1 is ambiguous on this, and the
            acceleration then lags the plan (see ``benchmarks/RESULTS_sim.md``).
        check_workspace: refuse (``ValueError``) commands the arm cannot reach.

    Returns:
        A :class:`PancakeResult`.
    """
    arr = _single_trajectory(states, 6, "states")
    _check_times(decel_time=decel_time, hold_time=hold_time, settle_time=settle_time)
    gains = resolve_gains(gains)
    ref = planar_reference(arr, decel_time=decel_time, hold_time=hold_time)
    if not accel_feedforward:
        ref.acc[:], ref.alpha[:] = 0.0, 0.0
    if check_workspace and (problem := workspace_problem(ref, "pancake")) is not None:
        raise ValueError(f"the spatula command leaves the arm's workspace at {problem}")
    scene = get_scene("pancake")
    media = _Media.plan(ref, video, snapshots, n_snapshots, fps, slow_motion)
    log = _execute(
        scene, ref, gains, model_bias=model_bias, place=_place_on_tool(scene, 0.0, np.zeros(2)),
        load=np.array([0.0, 0.0, -PANCAKE_MASS * GRAVITY]), settle_time=settle_time,
        frame_steps=media.steps, camera=camera,
    )
    media.write(log)
    return _pancake_metrics(ref, log, arr)


def _planar_command(ref: Reference) -> np.ndarray:
    """The reference back in planar coordinates ``(N, 6)``."""
    theta = np.unwrap(planar_tilt(quat_to_matrix(ref.quat)))
    return np.stack(
        [ref.pos[:, 1] - PANCAKE_ORIGIN[1], ref.pos[:, 2] - PANCAKE_ORIGIN[2], theta,
         ref.vel[:, 1], ref.vel[:, 2], ref.omega[:, 0]], -1)


def _pancake_metrics(ref: Reference, log: _Log, states: np.ndarray) -> PancakeResult:
    n, k_motion = log.steps, min(ref.n_motion, log.steps)
    command = _planar_command(ref)[:n]
    command[:, 2] += states[0, 2] - command[0, 2]  # unwrap relative to the input's own θ[0]
    rot = quat_to_matrix(log.tool_quat)
    theta = np.unwrap(planar_tilt(rot))
    theta += 2 * np.pi * np.round((command[0, 2] - theta[0]) / (2 * np.pi)) if n else 0.0
    response = np.stack(
        [log.tool_pos[:, 1] - PANCAKE_ORIGIN[1], log.tool_pos[:, 2] - PANCAKE_ORIGIN[2], theta,
         log.tool_twist[:, 1], log.tool_twist[:, 2], log.tool_twist[:, 3]], -1)

    # The pancake in the blade's frame: x = down normal, so -x is its height above the rest pose.
    rel = np.einsum("nji,nj->ni", rot, log.body_pos - log.tool_pos)
    slip = np.linalg.norm(rel[:, 1:] - log.body_rel_placed[1:], axis=1)
    gap = np.maximum(0.0, -rel[:, 0])
    body_up = quat_to_matrix(log.body_quat)[:, :, 2]
    tilt = np.arccos(np.clip(np.einsum("ni,ni->n", body_up, -rot[:, :, 0]), -1.0, 1.0))

    lost = (slip > SLIP_LIMIT) | (gap > GAP_LIMIT)
    first_lost = _first(lost[:k_motion])
    pos_err = log.tool_pos[:k_motion] - ref.pos[:k_motion]
    att_err = rotation_angle(log.tool_quat[:k_motion], ref.quat[:k_motion])

    # F_c of what the spatula actually did (accelerations from the measured velocities). Near free
    # fall the specific force g - u is ~0 and its direction (hence ψ) is noise: no force, nothing
    # to violate; such samples (|g - u| < FREE_FALL) count as 0.
    if k_motion >= 2:
        acc = np.diff(response[:k_motion, 3:], axis=0) / ref.dt
        executed = _violation(response[:k_motion], acc)
        felt = np.hypot(acc[:, 0], GRAVITY + acc[:, 1])
        executed = np.where(felt < FREE_FALL, 0.0, executed)
    else:
        executed = np.zeros(0)

    end = n - 1
    on_spatula = bool(
        n and gap[end] < 0.01 and abs(rel[end, 1]) < BLADE_HALF[1] and abs(rel[end, 2]) < BLADE_HALF[2]
    )
    return PancakeResult(
        time=np.arange(n) * ref.dt,
        command=command,
        response=response,
        slip=slip,
        gap=gap,
        tilt=tilt,
        position_rmse=_rmse(pos_err),
        attitude_rmse=float(np.sqrt(np.mean(att_err**2))) if att_err.size else float("nan"),
        max_slip=float(slip[:k_motion].max(initial=0.0)),
        max_gap=float(gap[:k_motion].max(initial=0.0)),
        contact_lost=first_lost is not None,
        contact_lost_time=None if first_lost is None else first_lost * ref.dt,
        contact_lost_in_tail=bool(lost[k_motion:].any()),
        on_spatula=on_spatula,
        turned_over=bool(n and body_up[end, 2] < 0.0),
        executed_violation=executed,
        torque_peak=np.abs(log.torque).max(axis=0) if n else np.zeros(6),
        realtime_factor=log.simulated_time / max(log.wall_time, 1e-9),
        diverged=log.diverged,
        n_motion=ref.n_motion,
    )


# --------------------------------------------------------------------------------------------
# Sliding an object on a frying pan (ch. 3)


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
        tipped: the object's axis tilted more than 45° from the pan's normal at some time.
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
        :func:`run_pancake`.

    Returns:
        A :class:`SlidingResult`.
    """
    plan_rel = None
    if hasattr(plan_or_pan_states, "pan_states") and hasattr(plan_or_pan_states, "rel_states"):
        pan = _single_trajectory(plan_or_pan_states.pan_states, 4, "plan.pan_states")
        plan_rel = _single_trajectory(plan_or_pan_states.rel_states, 4, "plan.rel_states")
        if plan_rel.shape[0] != pan.shape[0]:
            raise ValueError(
                f"plan.pan_states and plan.rel_states differ in length: {pan.shape[0]} vs {plan_rel.shape[0]}"
            )
    else:
        pan = _single_trajectory(plan_or_pan_states, 4, "pan_states")
    cmd = None
    if command is not None:
        c = np.asarray(command, dtype=np.float64) if not isinstance(command, np.ndarray) else command
        if c.ndim != 2 or c.shape[-1] not in (2, 4):
            raise ValueError(f"command must have shape (K, 4) or (K, 2), got {np.shape(command)}")
        cmd = _single_trajectory(c, c.shape[-1], "command")[:, :2]
        if cmd.shape[0] != pan.shape[0]:
            raise ValueError(f"command has {cmd.shape[0]} samples but the pan trajectory has {pan.shape[0]}")
    _check_times(decel_time=decel_time, hold_time=hold_time, settle_time=settle_time)
    gains = resolve_gains(gains)
    ref = pan_reference(pan, decel_time=decel_time, hold_time=hold_time)
    if not accel_feedforward:
        ref.acc[:], ref.alpha[:] = 0.0, 0.0
    if check_workspace and (problem := workspace_problem(ref, "sliding")) is not None:
        raise ValueError(f"the pan command leaves the arm's workspace at {problem}")
    start = cmd[0] if cmd is not None else (plan_rel[0, :2] if plan_rel is not None else np.zeros(2))
    if np.hypot(*start) > PAN_RADIUS - 0.04:
        raise ValueError(f"the object's start {start.tolist()} m is not on the pan (radius {PAN_RADIUS} m)")
    scene = get_scene("sliding")
    media = _Media.plan(ref, video, snapshots, n_snapshots, fps, slow_motion)
    # Planar (x, y) on the pan = the tool's (z, y) axes.
    log = _execute(
        scene, ref, gains, model_bias=model_bias, place=_place_on_tool(scene, OBJECT_HALF_HEIGHT, start),
        load=np.array([0.0, 0.0, -OBJECT_MASS * GRAVITY]), settle_time=settle_time,
        frame_steps=media.steps, camera=camera,
    )
    media.write(log)
    return _sliding_metrics(ref, log, cmd if cmd is not None else plan_rel, plan_rel)


def _sliding_metrics(ref: Reference, log: _Log, target, plan_rel) -> SlidingResult:
    n, k_motion = log.steps, min(ref.n_motion, log.steps)
    rot = quat_to_matrix(log.tool_quat)
    rel = np.einsum("nji,nj->ni", rot, log.body_pos - log.tool_pos)  # site frame: (-up, y, along)
    path = rel[:, [2, 1]]
    height = -rel[:, 0] - OBJECT_HALF_HEIGHT
    axis = quat_to_matrix(log.body_quat)[:, :, 2]
    tilt = np.arccos(np.clip(np.einsum("ni,ni->n", axis, -rot[:, :, 0]), -1.0, 1.0))
    off = (np.linalg.norm(path, axis=1) > PAN_RADIUS + 0.01) | (height < -0.01)
    first_off = _first(off)
    pan_cmd = ref.pos[:n, :2] - PAN_ORIGIN[:2]
    pan_resp = log.tool_pos[:, :2] - PAN_ORIGIN[:2]
    pan_accel = np.zeros((n, 2))
    pan_accel[:-1] = np.diff(log.tool_twist[:, :2], axis=0) / ref.dt
    if n > 1:
        pan_accel[-1] = pan_accel[-2]

    def rmse_to(target_xy):
        if target_xy is None:
            return None
        k = min(k_motion, target_xy.shape[0])
        return _rmse(path[:k] - target_xy[:k, :2])

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
        pan_rmse=_rmse(pan_resp[:k_motion] - pan_cmd[:k_motion]),
        pan_excursion=float(np.linalg.norm(pan_resp - pan_resp[:1], axis=1).max(initial=0.0)),
        pan_range=np.abs(ref.pos[: ref.n_motion, :2] - PAN_ORIGIN[:2]).max(axis=0),
        fell_off=first_off is not None,
        fell_off_time=None if first_off is None else first_off * ref.dt,
        tipped=bool((tilt > np.pi / 4).any()),
        torque_peak=np.abs(log.torque).max(axis=0) if n else np.zeros(6),
        realtime_factor=log.simulated_time / max(log.wall_time, 1e-9),
        diverged=log.diverged,
        n_motion=ref.n_motion,
    )
