"""Pancake turning on the simulated arm (chs. 2 and 4): :func:`run_pancake`.

Planar spatula states ``(K, 6)`` → the spatula command of eq. 4.9, executed at 1 ms with PD +
DOB (:func:`seqmotion.sim.arm.execute`), then 0.1 s of constant deceleration and a hold;
measures tracking, the pancake's slip along the blade, its separation from the blade, whether
it ends turned over, and the friction-cone violation of the motion the spatula really made.

**Losing contact** (the sim's counterpart of the 2-D model's friction-cone constraint, which
says the pancake *sticks* to the blade): the pancake has lost contact once its centre has
slipped more than :data:`SLIP_LIMIT` = 5 mm along the blade from where it was placed, or
risen more than :data:`GAP_LIMIT` = 2 mm off its resting height. Both are well above what a
sticking contact does in this model (≤ 0.7 mm of slip and ≤ 0.3 mm of gap over 100 feasible
motions; 3 µm of creep in 1.5 s held still at 40°; the pancake is placed 0.1 mm above the
blade and drops onto it) and small against the pancake (radius 55 mm, thickness 10 mm): a
visible slide or a visible gap. They were fixed before any trajectory set was measured;
``benchmarks/RESULTS_sim.md`` reports how the counts change with half or twice the limits.

**The task** (:attr:`PancakeResult.task`): a spatula that ends tilted more than atan μ (45°) from level cannot hold
a pancake at rest, so such a motion asks for the pancake to be carried through the turn and then released (turned
over where the tilt passes 90°); one that ends within 45° asks for it to be held on the spatula.
:meth:`PancakeResult.describe` says which, judges the motion by it, and says apart what happened after the motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..core.execution import ExecutionCheck
from ..data.trajectories import tracking_rmse
from ..tasks.pancake.physics import MU, check_mu, cone_half_angle, violation
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
from .backend import CONTROL_DT, GRAVITY
from .control import Gains, resolve_gains
from .executable import check_executable
from .kinematics import Reference, planar_reference, planar_tilt, quat_to_matrix, rotation_angle
from .robot_models import Robot, resolve_robot
from .scene import BLADE_HALF, MU_PANCAKE, PANCAKE_MASS, PANCAKE_ORIGIN

SLIP_LIMIT = 5e-3
"""Slip of the pancake's centre along the blade beyond which contact counts as lost [m]."""
GAP_LIMIT = 2e-3
"""Rise of the pancake's centre above its resting height beyond which contact counts as lost [m]."""
FREE_FALL = 1.0
"""Specific force [m/s²] below which the executed motion counts as free fall (no cone to violate)."""


@dataclass
class PancakeResult(RobotFlags):
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
        executed_violation: ``(n_motion - 1,)`` F_c of the executed spatula motion (eq. 2.18) for
            friction coefficient ``mu`` [rad]; 0 where its specific force is below
            :data:`FREE_FALL` (direction undefined).
        torque_peak: ``(n,)`` largest |joint torque| [N m] of the arm's n joints.
        realtime_factor: simulated time / wall-clock time of the control loop.
        diverged: ``None``, or why the run was cut short (then arrays end there).
        n_motion: number of input samples.
        mu: the friction coefficient ``executed_violation`` was judged with.
        joints: what the robot's joints did against its limits (:class:`~seqmotion.sim.arm.JointReport`);
            ``result.robot``, ``result.joint_limits_ok``, ``result.torque_limits_ok`` read it.
        end_tilt: the input's final tilt θ[K-1] [rad] (``None``: not recorded); it sets :attr:`task`.
        decel_time: the stop after the input [s] (the rest of the tail is the hold; ``None``: not recorded).
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
    mu: float = MU
    joints: JointReport | None = None
    end_tilt: float | None = None
    decel_time: float | None = None

    @property
    def task(self) -> str | None:
        """What the motion asks of the pancake, read from where the spatula ends: ``"hold"`` (it ends tilted at most
        atan μ from level, where a pancake can rest: carry it and keep it on the spatula), ``"turn"`` (it ends tilted
        past that: carry it through the turn, after which it is released), or ``None`` (``end_tilt`` not recorded).
        μ is the simulated contact's (:data:`~seqmotion.sim.scene.MU_PANCAKE`)."""
        if self.end_tilt is None:
            return None
        return "turn" if _level_tilt(self.end_tilt) > cone_half_angle(MU_PANCAKE) else "hold"

    @property
    def left_time(self) -> float | None:
        """When the pancake first lost contact after the input motion (slip or gap past its limit in the stop or
        the hold) [s], or ``None``."""
        k = first_true(self._lost()[self.n_motion:])
        return None if k is None else float(self.time[self.n_motion + k])

    def _lost(self) -> np.ndarray:
        return (self.slip > SLIP_LIMIT) | (self.gap > GAP_LIMIT)

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
            "task": self.task,
            "end_tilt_rad": self.end_tilt,
            "left_spatula_after_motion_time_s": self.left_time,
            "executed_max_violation_rad": float(self.executed_violation.max(initial=0.0)),
            "mu": self.mu,  # the friction coefficient the executed cone was judged with
            "realtime_factor": self.realtime_factor,
            "diverged": self.diverged,
            **({"robot": self.robot} if self.joints is None else self.joints.summary()),
        }

    def describe(self) -> str:
        """One line for people, in plain clauses: tracking; the robot's limits (broken, or unknown); what the task is
        (:attr:`task`); whether the pancake was carried as it asks during the motion (slip ≤ :data:`SLIP_LIMIT`, gap
        ≤ :data:`GAP_LIMIT`); and what happened after the motion, in the stop and the hold."""
        parts = [f"tracking {self.position_rmse * 1e3:.1f} mm / {np.degrees(self.attitude_rmse):.2f}° RMSE"]
        robot = None if self.joints is None else self.joints.describe()
        if robot:
            parts.append(robot)
        if self.diverged:
            return "; ".join([*parts, f"run cut short: {self.diverged}"])
        limits = f"limits {SLIP_LIMIT * 1e3:.0f} mm, {GAP_LIMIT * 1e3:.0f} mm"
        if self.contact_lost:
            during = (f"the pancake lost contact at t = {self.contact_lost_time:.3f} s (max slip "
                      f"{self.max_slip * 1e3:.0f} mm, gap {self.max_gap * 1e3:.0f} mm; {limits})")
        else:
            during = (f"the pancake stayed on (max slip {self.max_slip * 1e3:.1f} mm, gap {self.max_gap * 1e3:.1f} mm "
                      f"while the spatula moved; {limits})")
        task = self.task
        if task is not None:
            tilt, rest = np.degrees(_level_tilt(self.end_tilt)), np.degrees(cone_half_angle(MU_PANCAKE))
            if task == "turn":
                over = " turned over" if tilt > 90 else ""
                parts.append(f"task: carry the pancake through the turn, then release it{over} (the spatula ends "
                             f"tilted {tilt:.0f}°, past the {rest:.0f}° a pancake can rest at)")
                parts.append(f"carried through the turn: {'no' if self.contact_lost else 'yes'} — {during}")
            else:
                parts.append(f"task: carry the pancake and hold it on the spatula (it ends tilted {tilt:.0f}°, within "
                             f"the {rest:.0f}° a pancake can rest at)")
                held = not self.contact_lost and not self.contact_lost_in_tail and self.on_spatula
                parts.append(f"held on the spatula: {'yes' if held else 'no'} — {during}")
        else:
            parts.append(during)
        parts.append(f"after the motion: {self._after()}")
        return "; ".join(parts)

    def _after(self) -> str:
        """What the pancake did in the stop and the hold, and how it ends."""
        face, where = "turned over" if self.turned_over else "face up", "on" if self.on_spatula else "off"
        ends = f"ends {face}, {where} the spatula"
        left = None if self.contact_lost else self.left_time
        if left is None:
            return ends if self.contact_lost else f"it stayed on and {ends}"
        k = round(left / (self.time[1] - self.time[0])) if len(self.time) > 1 else 0
        how = "slid off" if self.slip[k] > SLIP_LIMIT else "lifted off"
        since = left - self.time[self.n_motion - 1] if self.n_motion else left
        hold = self.time[-1] - self.time[self.n_motion - 1] - (self.decel_time or 0.0)
        if self.decel_time is None:
            phase = "in the stop and hold after it"
        elif since <= self.decel_time + 1e-9:
            phase = f"while the spatula stopped (its {self.decel_time:.1f} s stop)"
        else:
            phase = f"during the {hold:.1f} s hold"
        released = "released — " if self.task == "turn" else ""
        return f"{released}it {how} at t = {left:.2f} s, {phase}, and {ends}"


def _level_tilt(theta: float) -> float:
    """How far the blade at tilt ``theta`` [rad] is from level, in [0, π] [rad] (a full turn is level again)."""
    return abs(math.remainder(float(theta), 2 * math.pi))


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
    mu: float = MU,
    robot: str | Robot | None = None,
    observe: Observer | None = None,
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
        fps, slow_motion: of the video.
        mu: friction coefficient the executed motion's friction cone is judged with
            (``executed_violation``, eq. 2.18; default the 2-D model's μ = 1). It does not change
            the simulation: the simulated pancake–blade contact has μ = 1
            (:data:`~seqmotion.sim.scene.MU_PANCAKE`). Judge a motion planned for a lower μ with it.
        robot: a standard arm to run it on (``"panda"``, ``"ur5e"``, ``"menagerie:<name>"``, …; see
            :func:`seqmotion.sim.robot_models.robots`; or a :class:`~seqmotion.sim.robot_models.Robot`), tracked by
            differential IK + joint-space PD + DOB; ``None`` (default) or ``"mh3f"``: the built-in MH3F-like arm.
        observe: ``observe(k, data)``, called at every executed period ``k`` ≥ 0 of the reference with the
            ``mujoco.MjData`` holding that period's state (:func:`~seqmotion.sim.arm.execute`): records the
            bodies of this very run (the viewer's replay).

    Returns:
        A :class:`PancakeResult`.

    Raises:
        ValueError: bad states or times, ``mu`` not a positive number, an unknown or unavailable robot, or
            (``check_workspace``) a command out of the arm's reach.
    """
    arr = single_trajectory(states, 6, "states")
    check_times(decel_time=decel_time, hold_time=hold_time, settle_time=settle_time)
    check_mu(mu)
    gains = resolve_gains(gains)
    arm = resolve_robot(robot)  # None: the built-in arm
    ref = planar_reference(arr, decel_time=decel_time, hold_time=hold_time)
    prepare_reference(ref, "pancake", accel_feedforward=accel_feedforward, check_workspace=check_workspace,
                      robot=arm)
    media = Media.plan(ref, video, snapshots, n_snapshots, fps, slow_motion, camera)
    # The pancake is placed on the blade's centre, resting on the site (its resting centre).
    log = execute("pancake", ref, gains, model_bias=model_bias, object_height=0.0, object_offset=np.zeros(2),
                  object_mass=PANCAKE_MASS, settle_time=settle_time, media=media, robot=arm,
                  observe=observe)
    return _pancake_metrics(ref, log, arr, mu, decel_time)


def check_pancake_executable(states: object, robot: Any, dt: float = CONTROL_DT) -> ExecutionCheck:
    """Whether ``robot`` can execute planar spatula states with the pancake on: the joint path against the robot's
    limits (:func:`~seqmotion.sim.executable.check_executable`), then, where no limit is broken, the motion executed
    in MuJoCo under PD + DOB (:func:`run_pancake`, the chapter-2 gains, its 0.1 s stop and no hold): where the pancake
    leaves the spatula during the motion (the arm's tracking error broke the friction cone that the plan kept), or
    the command leaves the arm's workspace (e.g. down at the table), ``ok`` is False and ``lost`` says which. What
    the registered check of the pancake task runs (:mod:`seqmotion.sim.registration`), so a motion
    ``deform(..., robot=…)`` calls feasible has been executed with the pancake kept; it costs one simulated run
    (~0.3 s for a 1 s motion).

    Args:
        states: ``(K, 6)`` ``[y, z, θ, v_y, v_z, v_θ]`` [m, m, rad, m/s, m/s, rad/s], K ≥ 2.
        robot: a robot's name, a :class:`~seqmotion.sim.robot_models.Robot`, or ``None`` / ``"mh3f"`` for the
            built-in arm.
        dt: the states' sample period [s] (the simulator runs at 1 ms: other periods are judged kinematically only).
    """
    check = check_executable(states, robot, dt=dt)
    if check.ok is False or abs(dt - CONTROL_DT) > 1e-12:
        return check
    try:
        run = run_pancake(states, robot=robot, hold_time=0.0)
    except ValueError as error:  # the command leaves the workspace (e.g. down at the table): not executable either
        return replace(check, ok=False, lost=f"{error} (with the simulator's 0.1 s stop after the motion's end): the "
                                            "motion must stay within the arm's workspace")
    if not run.contact_lost:
        return check
    lost = (f"the pancake left the spatula at t = {run.contact_lost_time:.3f} s when the arm executed the motion "
            f"(PD + DOB in MuJoCo: slid {run.max_slip * 1e3:.0f} mm, lifted {run.max_gap * 1e3:.0f} mm); the joints "
            "kept their limits, but the arm's tracking error broke the friction cone the plan kept: the motion needs "
            "more margin (a gentler one, or one pressing the pancake on harder)")
    return replace(check, ok=False, lost=lost)


def _planar_command(ref: Reference) -> np.ndarray:
    """The reference back in planar coordinates ``(N, 6)``."""
    theta = np.unwrap(planar_tilt(quat_to_matrix(ref.quat)))
    return np.stack(
        [ref.pos[:, 1] - PANCAKE_ORIGIN[1], ref.pos[:, 2] - PANCAKE_ORIGIN[2], theta,
         ref.vel[:, 1], ref.vel[:, 2], ref.omega[:, 0]], -1)


def _pancake_metrics(ref: Reference, log: ExecutionLog, states: np.ndarray, mu: float,
                     decel_time: float) -> PancakeResult:
    n, k_motion = log.steps, min(ref.n_motion, log.steps)
    command = _planar_command(ref)[:n]
    command[:, 2] += states[0, 2] - command[0, 2]  # unwrap relative to the input's own θ[0]
    obj = log.object_in_tool()
    rot = obj.rot
    theta = np.unwrap(planar_tilt(rot))
    theta += 2 * np.pi * np.round((command[0, 2] - theta[0]) / (2 * np.pi)) if n else 0.0
    response = np.stack(
        [log.tool_pos[:, 1] - PANCAKE_ORIGIN[1], log.tool_pos[:, 2] - PANCAKE_ORIGIN[2], theta,
         log.tool_twist[:, 1], log.tool_twist[:, 2], log.tool_twist[:, 3]], -1)

    # The pancake in the blade's frame: x = down normal, so -x is its height above the rest pose.
    rel = obj.rel
    slip = np.linalg.norm(rel[:, 1:] - log.body_rel_placed[1:], axis=1)
    gap = np.maximum(0.0, -rel[:, 0])

    lost = (slip > SLIP_LIMIT) | (gap > GAP_LIMIT)
    first_lost = first_true(lost[:k_motion])
    pos_err = log.tool_pos[:k_motion] - ref.pos[:k_motion]
    att_err = rotation_angle(log.tool_quat[:k_motion], ref.quat[:k_motion])

    # F_c of what the spatula actually did (accelerations from the measured velocities). Near free
    # fall the specific force g - u is ~0 and its direction (hence ψ) is noise: no force, nothing
    # to violate; such samples (|g - u| < FREE_FALL) count as 0. The cone is that of the μ asked for.
    if k_motion >= 2:
        acc = np.diff(response[:k_motion, 3:], axis=0) / ref.dt
        executed = violation(response[:k_motion], acc, mu)
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
        tilt=obj.tilt,
        position_rmse=tracking_rmse(pos_err),
        attitude_rmse=tracking_rmse(att_err[:, None]),
        max_slip=float(slip[:k_motion].max(initial=0.0)),
        max_gap=float(gap[:k_motion].max(initial=0.0)),
        contact_lost=first_lost is not None,
        contact_lost_time=None if first_lost is None else first_lost * ref.dt,
        contact_lost_in_tail=bool(lost[k_motion:].any()),
        on_spatula=on_spatula,
        turned_over=bool(n and obj.up[end, 2] < 0.0),
        executed_violation=executed,
        torque_peak=log.torque_peak,
        realtime_factor=log.realtime_factor,
        diverged=log.diverged,
        n_motion=ref.n_motion,
        mu=mu,
        joints=log.joints,
        end_tilt=float(states[-1, 2]),
        decel_time=decel_time,
    )

