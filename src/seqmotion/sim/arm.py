"""The simulated arm — the built-in MH3F-like arm or a standard robot (``robot="ur5e"``) — shared by the pancake and
sliding scenes and the Gymnasium envs.

* :func:`get_scene` — the compiled scene, once per process.
* :class:`Arm` — one ``MjData`` of a scene driven by its controller (:func:`~seqmotion.sim.control.make_controller`:
  task space on the built-in arm, differential IK + joint-space PD + DOB on a standard one):
  :meth:`Arm.reset` (inverse kinematics to a start pose, the object placed at rest on the
  tool, the controller started) and :meth:`Arm.step` (one 1 ms control period through
  :func:`seqmotion.sim.backend.control_period`, the torque held over :data:`SUBSTEPS` physics steps).
* :func:`place_on_tool`, :func:`weight` — put the object on the tool; the load it puts on it.
* :func:`execute` — run a whole :class:`~seqmotion.sim.kinematics.Reference`: a settling hold
  at the first pose, then the reference, logging the tool and object every period
  (:class:`ExecutionLog`) and rendering the periods a :class:`Media` plan asks for.
* :func:`workspace_problem` — why a commanded tool path is out of the arm's reach.

The scenes' runners (:mod:`seqmotion.sim.pancake`, :mod:`seqmotion.sim.sliding`) turn a
trajectory into a reference, call :func:`execute`, and measure what the object did.
"""

from __future__ import annotations

import time as _time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ..errors import as_trajectories, check_number
from .backend import CONTROL_DT, GRAVITY, control_period, import_mujoco
from .control import Gains, JointSpaceController, TaskSpaceController, make_controller, solve_ik
from .kinematics import Reference, quat_to_matrix
from .limits import JointLimits
from .robot_models import Robot, built_in_limits, resolve_robot
from .scene import (
    FOREARM,
    SHOULDER_HEIGHT,
    SHOULDER_OFFSET,
    SITE_IN_TOOL,
    TABLE_CLEARANCE,
    TABLE_TOP,
    UPPER_ARM,
    WRIST_TO_FLANGE,
    Scene,
    get_scene,
)

TRACKING_LIMIT = 0.1
"""A tool position error beyond this aborts the run as 'lost tracking' [m]."""
REACH_MARGIN = 0.02
"""The wrist centre must stay this far inside the arm's full extension [m] (elbow singularity)."""


Place = Callable[[Any], None]
"""``place(data)``: puts the object at rest on the tool of a scene's ``mujoco.MjData``."""


def weight(mass: float) -> np.ndarray:
    """``(3,)`` force [N] an object of ``mass`` [kg] resting on the tool puts on it (world frame)."""
    return np.array([0.0, 0.0, -mass * GRAVITY])


def place_on_tool(scene: Scene, height: float, offset: np.ndarray) -> Place:
    """A ``place(data)`` that puts the object on the tool surface, face up, ``height`` above the site.

    Args:
        scene: the scene whose tool and object are meant.
        height: the object's centre above the site along the surface's up normal [m] (0.1 mm
            more is added, so the object drops onto the surface rather than starting in it).
        offset: ``(2,)`` position on the surface along the tool's (z, y) axes [m] — the planar
            (x, y) of the pan, or along/across the blade.
    """

    def place(data: Any) -> None:
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


class Arm:
    """One simulation of a scene: its ``MjData`` and the task-space controller driving the arm.

    Args:
        scene: the compiled scene (e.g. :func:`get_scene`).
        gains: the controller's PD gains and observer cutoff.
        model_bias: feed MuJoCo's gravity/Coriolis torque forward (see
            :class:`~seqmotion.sim.control.TaskSpaceController`).

    Attributes:
        data: the ``mujoco.MjData`` (read it between steps; :meth:`step` advances it); pass ``data`` to drive
            one that a world already holds (the pushing world's standard arm).
        controller: the controller started by the latest :meth:`reset` (``None`` before).
    """

    def __init__(self, scene: Scene, gains: Gains, *, model_bias: bool = False, data: Any = None) -> None:
        self._mj = import_mujoco()
        self.scene, self.gains, self.model_bias = scene, gains, model_bias
        self.data = self._mj.MjData(scene.model) if data is None else data
        # Physics steps per 1 ms control period: the arm scenes' SUBSTEPS; 1 where the model steps at 1 ms.
        self.substeps = max(1, round(CONTROL_DT / scene.model.opt.timestep))
        self.controller: TaskSpaceController | JointSpaceController | None = None

    def reset(self, pos: np.ndarray, quat: np.ndarray, place: Place, load: np.ndarray) -> None:
        """Start at rest with the tool site at ``pos`` ``(3,)`` [m] and attitude ``quat`` ``(4,)``.

        The arm is put there by inverse kinematics, ``place(data)`` puts the object on the tool,
        and a fresh controller starts with its observer at the static disturbance of ``load``
        ``(3,)`` [N] (the object's :func:`weight`).
        """
        mj, m, d = self._mj, self.scene.model, self.data
        mj.mj_resetData(m, d)
        d.qpos[self.scene.arm_qpos] = solve_ik(self.scene, pos, quat)
        mj.mj_forward(m, d)
        place(d)
        mj.mj_forward(m, d)
        self.start(load)

    def start(self, load: np.ndarray | None = None) -> None:
        """A fresh controller at rest at ``data``'s current state (kinematics current: ``mj_forward``), its
        observer at the static disturbance of ``load`` ``(3,)`` [N] (none: the arm's own weight only)."""
        self.controller = make_controller(self.scene, self.gains, model_bias=self.model_bias)
        self.controller.reset(self.data, load)

    def step(
        self,
        pos: np.ndarray,
        quat: np.ndarray,
        twist: np.ndarray,
        accel: np.ndarray,
        inspect: Callable[[np.ndarray], bool] | None = None,
    ) -> np.ndarray | None:
        """One control period toward the commanded tool state (arguments of
        :meth:`~seqmotion.sim.control.TaskSpaceController.torque`), by the one control step
        :func:`~seqmotion.sim.backend.control_period`.

        ``inspect(tau)``, if given, is its recording hook: called with the torque ``(n,)`` [N m] while
        ``data`` still holds the kinematics of the state it was computed from (a logger reads the tool
        and the object there); returning ``False`` stops before the state is advanced.

        Returns:
            The torque applied, or ``None`` if ``inspect`` stopped the period.
        """
        ctl, d = self.controller, self.data
        if ctl is None:
            raise RuntimeError("call Arm.reset() before Arm.step()")
        return control_period(self.scene.model, d, lambda: ctl.torque(d, pos, quat, twist, accel), self.substeps,
                              inspect)

    def diverged(self) -> bool:
        """Whether MuJoCo has flagged a bad acceleration (the simulation became unstable)."""
        return bool(self.data.warning[self._mj.mjtWarning.mjWARN_BADQACC].number)


def workspace_problem(reference: Reference, kind: str, robot: str | Robot | None = None) -> str | None:
    """Why the commanded tool path cannot be executed by the arm, or ``None`` if it can.

    Checks, per sample, that the wrist centre stays within the built-in arm's reach (minus
    :data:`REACH_MARGIN`), away from the base axis (shoulder singularity) and that the tool
    stays above the table. The arm's own wrist singularity is not predicted here; the run
    reports it as lost tracking if it happens. ``robot`` is resolved by
    :func:`~seqmotion.sim.robot_models.resolve_robot`: ``None`` and ``"mh3f"`` are the built-in arm; on a
    standard robot (a name or a :class:`~seqmotion.sim.robot_models.Robot`) only the table is checked
    here: its reach and joint limits are judged during the run, by the IK that tracks the path
    (:class:`JointReport` names the worst pose out of reach and the worst crossing of each limit).

    Raises:
        ValueError: an unknown or unavailable robot.
    """
    standard = resolve_robot(robot)
    rot = quat_to_matrix(reference.quat)
    flange = reference.pos - rot @ SITE_IN_TOOL[kind]
    wrist = flange - WRIST_TO_FLANGE * rot[:, :, 2]
    heading = np.arctan2(wrist[:, 1], wrist[:, 0])
    shoulder = np.stack(
        [SHOULDER_OFFSET * np.cos(heading), SHOULDER_OFFSET * np.sin(heading), np.full_like(heading, SHOULDER_HEIGHT)],
        -1,
    )
    dist = np.linalg.norm(wrist - shoulder, axis=1)
    reach = UPPER_ARM + FOREARM - REACH_MARGIN
    table = (reference.pos[:, 2] < TABLE_TOP + TABLE_CLEARANCE,
             lambda k: f"the tool is down at the table (z = {reference.pos[k, 2]:.3f} m)")
    checks = [table] if standard is not None else [
        (dist > reach, lambda k: f"the wrist centre is {dist[k]:.3f} m from the shoulder (reach {reach:.3f} m)"),
        (dist < abs(UPPER_ARM - FOREARM) + 0.05, lambda k: f"the wrist centre is {dist[k]:.3f} m from the shoulder"),
        (np.hypot(wrist[:, 0], wrist[:, 1]) < 0.05, lambda k: "the wrist centre is over the base axis"),
        table,
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


def prepare_reference(
    ref: Reference, kind: str, *, accel_feedforward: bool, check_workspace: bool, robot: str | Robot | None = None
) -> Reference:
    """Drop the reference's acceleration feedforward unless asked for; refuse paths out of reach.

    Modifies ``ref`` in place (and returns it). Raises ``ValueError`` naming the first sample
    out of reach (:func:`workspace_problem` on ``robot``: ``None`` or ``"mh3f"`` the built-in arm) if
    ``check_workspace``.
    """
    if not accel_feedforward:
        ref.acc[:], ref.alpha[:] = 0.0, 0.0
    if check_workspace and (problem := workspace_problem(ref, kind, robot)) is not None:
        tool = "spatula" if kind == "pancake" else "pan"
        raise ValueError(f"the {tool} command leaves the arm's workspace at {problem}")
    return ref


class RobotFlags:
    """What a run's result says of the robot (for results with a ``joints: JointReport`` field)."""

    joints: JointReport | None

    @property
    def robot(self) -> str:
        """The robot that ran it, ``"name (source)"``."""
        return BUILT_IN_ARM if self.joints is None else self.joints.robot

    @property
    def joint_limits_ok(self) -> bool | None:
        return None if self.joints is None else self.joints.joint_limits_ok

    @property
    def torque_limits_ok(self) -> bool | None:
        return None if self.joints is None else self.joints.torque_limits_ok

    @property
    def velocity_limits_ok(self) -> bool | None:
        return None if self.joints is None else self.joints.velocity_limits_ok


IK_TOLERANCE = (2e-3, np.radians(1.0))
"""IK residual [m, rad] beyond which a commanded pose counts as out of the robot's reach (its limits or its
workspace forbid it)."""

CROSSING_KINDS = ("speed", "torque", "range", "reach")
"""The limits a run's joints are judged against (:class:`LimitCrossing`)."""


@dataclass(frozen=True)
class LimitCrossing:
    """The worst crossing of one kind of limit during a run (one per kind crossed).

    Attributes:
        kind: ``"speed"`` (a rated joint speed), ``"torque"`` (the model's torque limit), ``"range"`` (a joint's
            range) or ``"reach"`` (the commanded tool pose out of the robot's reach: IK residual past
            :data:`IK_TOLERANCE`).
        joint: the joint that crossed it worst (``None`` for ``"reach"``).
        peak: the worst value: |q̇| [rad/s], |τ| [N m], the joint's position [rad], or the IK position residual [m].
        limit: what it crossed: the rated speed [rad/s], the torque limit [N m], the range end passed [rad], or the
            IK position tolerance [m].
        share: how far past, as a share of the limit (> 1: past it). Speed: |q̇| / rated; torque: |τ| / limit
            (1: the command was clipped at the limit, so the joint needed more); range: the excursion from the
            range's middle over half the range; reach: the larger IK residual over its tolerance.
        time: when the worst value was reached [s].
        first_time: when this joint first crossed the limit [s].
        duration: how long this joint was past the limit in all [s].
        others: the other joints past this kind of limit and their peak shares, worst first.
        detail: more words for people (the reach's attitude residual), or ``""``.
    """

    kind: str
    joint: str | None
    peak: float
    limit: float
    share: float
    time: float
    first_time: float
    duration: float
    others: tuple[tuple[str, float], ...] = ()
    detail: str = ""

    def describe(self) -> str:
        """One clause for people: the joint, its peak against the limit, the share, and when."""
        span = f"{self.duration * 1e3:.0f} ms from t = {self.first_time:.3f} s"
        if self.others:
            span += "; other joints past it: " + ", ".join(f"{name!r} {share:.2f}×" for name, share in self.others)
        if self.kind == "speed":
            return (f"joint {self.joint!r} turned at {self.peak:.2f} rad/s at t = {self.time:.3f} s, "
                    f"{self.share:.2f}× its rated {self.limit:.2f} rad/s (over it for {span})")
        if self.kind == "torque":
            return (f"joint {self.joint!r} needed more than its {self.limit:.1f} N m (peak {self.peak:.1f} N m, "
                    f"{self.share:.2f}× the limit: clipped there for {span})")
        if self.kind == "range":
            return (f"joint {self.joint!r} reached {self.peak:.3f} rad at t = {self.time:.3f} s, past its range end "
                    f"{self.limit:.3f} rad ({self.share:.2f}× its half-range from the middle; out of range for "
                    f"{span})")
        return (f"the commanded tool pose was out of the robot's reach: IK residual {self.detail} at "
                f"t = {self.time:.3f} s, {self.share:.1f}× the {IK_TOLERANCE[0] * 1e3:.0f} mm / "
                f"{np.degrees(IK_TOLERANCE[1]):.0f}° tolerance (for {span})")

    def summary(self) -> dict[str, Any]:
        """JSON-friendly fields."""
        return {"kind": self.kind, "joint": self.joint, "peak": self.peak, "limit": self.limit, "share": self.share,
                "time_s": self.time, "first_time_s": self.first_time, "duration_s": self.duration,
                "others": [list(o) for o in self.others]}


_JUDGED = {"range": "position", "speed": "velocity", "torque": "torque"}
"""Each limit a run is judged against → the :class:`~seqmotion.sim.limits.JointLimits` kind it reads."""


@dataclass(frozen=True)
class JointReport:
    """What the robot's joints did during a run against its limits: peaks as shares of them, each crossing named.

    Shares are ``(n,)`` arrays, NaN-free, or ``None`` where the limit is unknown (never treated as unlimited:
    :attr:`unknown` says which and why). A share above 1 is a limit broken. Rated accelerations, where published,
    are in :attr:`limits` but not judged here (generation is to keep them).

    Attributes:
        robot: the robot, ``"name (source)"`` (e.g. ``"panda (robosuite)"``, ``"mh3f (seqmotion)"``).
        joints: the joint names, base to flange.
        joint_limits_ok: every joint stayed within its range (``None``: the ranges are unknown).
        velocity_limits_ok: every joint speed stayed within its rated speed (``None``: unknown).
        torque_limits_ok: no torque command reached the model's limit (``None``: unknown).
        torque_share: ``(n,)`` peak |torque| / limit per joint (``None``: unknown).
        ik_error: largest residual of the IK reference ``(position [m], attitude [rad])`` (0 without IK).
        problem: every crossing (:attr:`crossings`), worst first, each naming its joint, peak, limit, share and
            time, or ``None``.
        speed_peak: ``(n,)`` peak |joint speed| [rad/s] (measured; known whatever the limits).
        torque_peak: ``(n,)`` peak |joint torque| applied [N m].
        speed_share: ``(n,)`` peak |joint speed| / rated speed (``None``: unknown).
        range_share: ``(n,)`` peak excursion from the middle of the joint's range over half the range (1: at an
            end; 0 for a continuous joint, which has none; ``None``: unknown).
        crossings: the worst crossing of each kind of limit broken (:class:`LimitCrossing`), worst share first.
        limits: the limits judged against, with their sources.
    """

    robot: str
    joints: tuple[str, ...]
    joint_limits_ok: bool | None
    velocity_limits_ok: bool | None
    torque_limits_ok: bool | None
    torque_share: np.ndarray | None
    ik_error: tuple[float, float]
    problem: str | None
    speed_peak: np.ndarray | None = None
    torque_peak: np.ndarray | None = None
    speed_share: np.ndarray | None = None
    range_share: np.ndarray | None = None
    crossings: tuple[LimitCrossing, ...] = ()
    limits: JointLimits | None = None

    @property
    def ok(self) -> bool | None:
        """``False``: a limit broken or a pose out of reach; ``None``: none broken, but some limit unknown (not
        checked); ``True``: every limit known and kept."""
        if self.problem is not None:
            return False
        return None if self.unknown else True

    @property
    def unknown(self) -> dict[str, str]:
        """Each limit judged (``"range"``, ``"speed"``, ``"torque"``) whose values are unknown → why."""
        if self.limits is None:
            return {}
        return {kind: why for kind, of in _JUDGED.items() if (why := self.limits.unknown(of)) is not None}

    def describe(self) -> str | None:
        """One clause for people: ``"<robot>: <problem>"``, the limits that are unknown, or ``None`` (all kept)."""
        parts = [self.problem] if self.problem else []
        unknown = self.unknown
        if unknown:
            names = [{"range": "joint ranges", "speed": "rated speeds", "torque": "torque limits"}[k] for k in unknown]
            listed = names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]
            parts.append(f"{listed} unknown (not checked)")
        return f"{self.robot}: {'; '.join(parts)}" if parts else None

    def summary(self) -> dict[str, Any]:
        def listed(values: np.ndarray | None) -> list[float] | None:
            return None if values is None else [round(float(x), 4) for x in values]

        return {"robot": self.robot, "joints": list(self.joints), "joint_limits_ok": self.joint_limits_ok,
                "velocity_limits_ok": self.velocity_limits_ok, "torque_limits_ok": self.torque_limits_ok,
                "speed_peak_rad_s": listed(self.speed_peak), "speed_share": listed(self.speed_share),
                "torque_peak_nm": listed(self.torque_peak), "torque_share": listed(self.torque_share),
                "range_share": listed(self.range_share), "limits_unknown": self.unknown,
                "limit_sources": None if self.limits is None else dict(self.limits.sources),
                "limit_crossings": [c.summary() for c in self.crossings],
                "ik_error_m": self.ik_error[0], "ik_error_rad": self.ik_error[1], "limits_problem": self.problem}


BUILT_IN_ARM = "mh3f (seqmotion)"
"""The label of the built-in MH3F-like arm (no joint ranges, speed or torque limits modelled; the MOTOMAN-MH3F's
published ones were not found: :func:`~seqmotion.sim.robot_models.built_in_limits`)."""


def _crossing(kind: str, names: tuple[str, ...], share: np.ndarray, over: np.ndarray, value: np.ndarray,
              limit: np.ndarray, dt: float) -> LimitCrossing | None:
    """The worst crossing in ``over`` ``(N, n)`` (periods × joints past the limit): the joint with the largest
    ``share`` ``(N, n)`` there (ties: the longest over), its ``value`` ``(N, n)`` at that period and ``limit``
    ``(N, n)`` it passed; ``None`` if nothing crossed."""
    if not over.any():
        return None
    masked = np.where(over, share, -np.inf)
    peaks = masked.max(axis=0)
    counts = over.sum(axis=0)
    crossed = [j for j in range(len(names)) if counts[j]]
    j = max(crossed, key=lambda i: (peaks[i], counts[i]))
    k = int(np.argmax(masked[:, j]))
    others = tuple((names[i], round(float(peaks[i]), 4)) for i in sorted(crossed, key=lambda i: -peaks[i]) if i != j)
    return LimitCrossing(kind, names[j], float(value[k, j]), float(limit[k, j]), float(peaks[j]), k * dt,
                         int(np.argmax(over[:, j])) * dt, float(counts[j]) * dt, others)


def joint_report(scene: Scene, dt: float, *, joint_pos: np.ndarray, joint_vel: np.ndarray, torque: np.ndarray,
                 saturated: np.ndarray, ik_error: np.ndarray) -> JointReport:
    """Judge a run's joints against the scene robot's limits (:class:`JointReport`).

    Args:
        scene: the scene the run was on (its arm joints and :attr:`Scene.robot`'s limits; the built-in arm's
            when ``None``).
        dt: the period between the recorded rows [s].
        joint_pos, joint_vel, torque: ``(N, n)`` the arm's joint positions [rad], velocities [rad/s] and
            applied torques [N m], one row per executed period (N = 0: nothing executed).
        saturated: ``(N,)`` whether the torque command hit a limit.
        ik_error: ``(N, 2)`` the IK reference's residual [m, rad] (zeros without IK in the loop).

    Every kind of limit broken is named by its worst crossing (largest share, with its time), not only its first.
    """
    m = scene.model
    names = tuple(m.joint(int(m.dof_jntid[i])).name for i in scene.arm_dof)
    robot = scene.robot
    limits = built_in_limits(names) if robot is None else robot.limits
    q, qd, tau = (np.asarray(a, dtype=float) for a in (joint_pos, joint_vel, torque))
    ik_error = np.asarray(ik_error, dtype=float)
    n = len(names)
    steps = len(q)
    if not steps:  # nothing executed: no peak, nothing crossed
        q, qd, tau = np.zeros((1, n)), np.zeros((1, n)), np.zeros((1, n))
    speed_peak, torque_peak = np.abs(qd).max(axis=0), np.abs(tau).max(axis=0)
    crossings: list[LimitCrossing] = []

    def judge(kind: str, share: np.ndarray, over: np.ndarray, value: np.ndarray, limit: np.ndarray) -> bool:
        crossing = _crossing(kind, names, share, over, value, limit, dt) if steps else None
        if crossing is not None:
            crossings.append(crossing)
        return crossing is None

    range_share = joints_ok = None
    if limits.position is not None:
        lo, hi = limits.position.T
        finite = np.isfinite(lo) & np.isfinite(hi)
        # A continuous joint (no ends) uses no share of a range; written without inf - inf, which would be NaN.
        mid = np.where(finite, (lo + hi) / 2, 0.0)
        half = np.where(finite, (hi - lo) / 2, 1.0)
        share = np.where(finite, np.abs(q - mid) / half, 0.0)
        range_share = share.max(axis=0)
        end = np.broadcast_to(np.where(q < mid, lo, hi), q.shape)
        joints_ok = judge("range", share, (q < lo) | (q > hi), q, end)
    speed_share = speed_ok = None
    if limits.velocity is not None:
        share = np.abs(qd) / limits.velocity
        speed_share = share.max(axis=0)
        speed_ok = judge("speed", share, share > 1.0, np.abs(qd), np.broadcast_to(limits.velocity, qd.shape))
    torque_share = torque_ok = None
    if limits.torque is not None:
        share = np.abs(tau) / limits.torque
        torque_share = share.max(axis=0)
        # The controller clips its command at the limit, so a joint that needed more sits exactly at it.
        clipped = np.asarray(saturated, dtype=bool).reshape(-1, 1) & (share >= 1 - 1e-9)
        torque_ok = judge("torque", share, clipped, np.abs(tau), np.broadcast_to(limits.torque, tau.shape))
    ik = ik_error.max(axis=0) if steps else np.zeros(2)
    if steps:
        ik_share = (ik_error / np.array(IK_TOLERANCE)).max(axis=1)
        if (ik_share > 1).any():
            k = int(np.argmax(ik_share))
            over = ik_share > 1
            crossings.append(LimitCrossing(
                "reach", None, float(ik_error[k, 0]), IK_TOLERANCE[0], float(ik_share[k]), k * dt,
                int(np.argmax(over)) * dt, float(over.sum()) * dt,
                detail=f"{ik_error[k, 0] * 1e3:.1f} mm, {np.degrees(ik_error[k, 1]):.1f}°"))
    crossings.sort(key=lambda c: -c.share)
    problem = "; ".join(c.describe() for c in crossings) or None
    return JointReport(limits.robot, names, joints_ok, speed_ok, torque_ok, torque_share,
                       (float(ik[0]), float(ik[1])), problem, speed_peak, torque_peak, speed_share, range_share,
                       tuple(crossings), limits)


class ObjectInTool(NamedTuple):
    """The logged object seen from the tool, per logged period (N of them)."""

    rot: np.ndarray
    """``(N, 3, 3)`` tool attitude (columns: the tool's x = surface down normal, y, z = along the tool)."""
    rel: np.ndarray
    """``(N, 3)`` object centre relative to the site, in the tool frame [m] (``-rel[:, 0]`` is its height)."""
    up: np.ndarray
    """``(N, 3)`` the object's own z axis (its top face's normal), world frame."""
    tilt: np.ndarray
    """``(N,)`` angle between the object's z axis and the surface's up normal [rad]."""


@dataclass
class ExecutionLog:
    """What :func:`execute` records at every control period of the reference (index k ↔ t = k dt).

    Arrays have one row per executed period (``steps`` of them; fewer than the reference if
    the run was cut short): tool site position ``(N, 3)`` [m], quaternion ``(N, 4)``, measured
    twist ``(N, 6)`` [m/s, rad/s]; object position ``(N, 3)`` [m] and quaternion ``(N, 4)``;
    joint torque ``(N, n)`` [N m], joint positions ``(N, n)`` [rad] and velocities ``(N, n)`` [rad/s] of the
    arm's n joints; the IK reference's residual ``(N, 2)`` [m, rad] (zeros on the built-in arm, which has
    no IK in its loop) and whether the torque hit a limit ``(N,)``. ``body_rel_placed`` ``(3,)`` is where
    the object was put, in the tool site's frame [m]. ``frames`` are rendered at the periods ``frame_steps``.
    """

    tool_pos: np.ndarray
    tool_quat: np.ndarray
    tool_twist: np.ndarray
    body_pos: np.ndarray
    body_quat: np.ndarray
    torque: np.ndarray
    joint_pos: np.ndarray
    joint_vel: np.ndarray
    ik_error: np.ndarray
    saturated: np.ndarray
    body_rel_placed: np.ndarray
    steps: int
    diverged: str | None
    wall_time: float
    simulated_time: float
    frames: list = field(default_factory=list)
    frame_steps: list = field(default_factory=list)
    joints: JointReport | None = None

    @property
    def torque_peak(self) -> np.ndarray:
        """``(n,)`` largest |joint torque| [N m] (zeros if nothing was executed)."""
        return np.abs(self.torque).max(axis=0) if self.steps else np.zeros(self.torque.shape[1])

    @property
    def realtime_factor(self) -> float:
        """Simulated time / wall-clock time of the control loop."""
        return self.simulated_time / max(self.wall_time, 1e-9)

    def object_in_tool(self) -> ObjectInTool:
        """The object's position and attitude relative to the tool over the run."""
        rot = quat_to_matrix(self.tool_quat)
        rel = np.einsum("nji,nj->ni", rot, self.body_pos - self.tool_pos)
        up = quat_to_matrix(self.body_quat)[:, :, 2]
        tilt = np.arccos(np.clip(np.einsum("ni,ni->n", up, -rot[:, :, 0]), -1.0, 1.0))
        return ObjectInTool(rot, rel, up, tilt)


@dataclass
class Media:
    """Which control periods to render, and where to write the results."""

    video: str | Path | None
    snapshots: str | Path | None
    video_steps: set[int]
    snapshot_steps: list[int]
    fps: float
    camera: str = "front"
    size: tuple[int, int] = (640, 480)

    @classmethod
    def plan(
        cls,
        ref: Reference,
        video: str | Path | None,
        snapshots: str | Path | None,
        n_snapshots: int,
        fps: float,
        slow_motion: float,
        camera: str,
    ) -> Media:
        """A video at ``fps`` ``slow_motion`` × slower than real time, and/or ``n_snapshots`` evenly over the input
        motion, its first to its last sample (what happens after it, in the stop and the hold, the result says)."""
        video_steps: set[int] = set()
        if video is not None:
            if not (0 < fps <= 1000 and 0 < slow_motion <= 1000):
                raise ValueError(f"fps and slow_motion must be positive (at most 1000), got {fps} and {slow_motion}")
            every = max(1, round(1.0 / (fps * slow_motion * ref.dt)))  # a frame every this many periods
            video_steps = set(range(0, len(ref), every))
        snap_steps: list[int] = []
        if snapshots is not None:
            whole = isinstance(n_snapshots, int | np.integer) and not isinstance(n_snapshots, bool)
            if not whole or not 1 <= n_snapshots <= 100:
                raise ValueError(f"n_snapshots must be an integer in [1, 100], got {n_snapshots!r}")
            # The motion only: frames of the stop and hold after it showed a turned pancake already released,
            # which read as a failed turn.
            last = min(len(ref), ref.n_motion) - 1
            snap_steps = sorted(set(np.linspace(0, last, n_snapshots).round().astype(int).tolist()))
        return cls(video, snapshots, video_steps, snap_steps, fps, camera)

    @property
    def steps(self) -> set[int] | None:
        """The periods to render (``None``: none)."""
        return (self.video_steps | set(self.snapshot_steps)) or None

    def write(self, log: ExecutionLog) -> None:
        """Write the video and the snapshot strip from the frames ``log`` holds."""
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


Observer = Callable[[int, Any], None]
"""``observe(k, data)``: reads period ``k``'s state (``mujoco.MjData``, kinematics current) during :func:`execute`."""


def execute(
    kind: str,
    ref: Reference,
    gains: Gains,
    *,
    model_bias: bool,
    object_height: float,
    object_offset: np.ndarray,
    object_mass: float,
    settle_time: float,
    media: Media | None = None,
    robot: str | Robot | None = None,
    observe: Observer | None = None,
) -> ExecutionLog:
    """Run the reference on the arm of scene ``kind`` and log every control period.

    ``robot`` is a standard arm (its name, :func:`seqmotion.sim.robot_models.robots`, or a
    :class:`~seqmotion.sim.robot_models.Robot`); ``None`` or ``"mh3f"`` is the built-in arm.

    The arm starts at the reference's first pose with the object placed at rest on the tool
    (:func:`place_on_tool` with ``object_height`` [m] and ``object_offset`` ``(2,)`` [m]; the
    controller's observer starts at its weight, ``object_mass`` [kg]); it holds that pose for
    ``settle_time`` [s] while the object comes to rest, then follows the reference. A run is
    cut short (``diverged``) if the tool strays :data:`TRACKING_LIMIT` from the command, the
    torque is not finite, or MuJoCo flags the simulation unstable. ``media`` (if any) says which
    periods to render; its files are written at the end. ``observe(k, data)``, if given, reads every
    executed period ``k`` ≥ 0 of the reference through the control step's recording hook (``data``: the
    ``mujoco.MjData`` with the kinematics of that period's state): how a caller records the bodies of the very
    run it gets the verdict of (the viewer's replay), without simulating the motion a second time.
    """
    scene = get_scene(kind, robot)
    arm = Arm(scene, gains, model_bias=model_bias)
    arm.reset(ref.pos[0], ref.quat[0], place_on_tool(scene, object_height, object_offset), weight(object_mass))
    d, ctl = arm.data, arm.controller
    site, bq = scene.site, scene.body_qpos
    # Where the object was put, in the tool site's frame (slip is measured from here).
    body_rel_placed = d.site_xmat[site].reshape(3, 3).T @ (d.qpos[bq : bq + 3] - d.site_xpos[site])

    frame_steps = media.steps if media is not None else None
    recorder = None
    if frame_steps:
        from .render import FrameRecorder

        recorder = FrameRecorder(scene.model, camera=media.camera, width=media.size[0], height=media.size[1])

    n = len(ref)
    twist = np.concatenate([ref.vel, ref.omega], axis=1)
    accel = np.concatenate([ref.acc, ref.alpha], axis=1)
    still = np.zeros(6)
    joints = len(scene.arm_dof)
    qadr, vadr = scene.arm_qpos, scene.arm_dof
    log = {name: np.zeros((n, dim)) for name, dim in
           [("tool_pos", 3), ("tool_quat", 4), ("tool_twist", 6), ("body_pos", 3), ("body_quat", 4),
            ("torque", joints), ("joint_pos", joints), ("joint_vel", joints), ("ik_error", 2), ("saturated", 1)]}
    standard = isinstance(ctl, JointSpaceController)
    n_settle = round(settle_time / ref.dt)
    frame_steps_done: list[int] = []
    limit2 = TRACKING_LIMIT**2
    diverged = None
    steps = 0
    k = -n_settle  # the period being executed; inspect() reads it

    def inspect(tau: np.ndarray) -> bool:
        """Log period k (the state the torque was computed from); stop if the run diverged."""
        nonlocal steps, diverged
        if k >= 0:
            log["tool_pos"][k] = d.site_xpos[site]
            log["tool_quat"][k] = d.site_xquat[site]
            log["tool_twist"][k] = ctl.last_twist  # measured by the controller at this state
            log["body_pos"][k] = d.qpos[bq : bq + 3]
            log["body_quat"][k] = d.qpos[bq + 3 : bq + 7]
            log["torque"][k] = tau
            log["joint_pos"][k] = d.qpos[qadr]
            log["joint_vel"][k] = d.qvel[vadr]
            if standard:
                log["ik_error"][k] = ctl.ik_error
                log["saturated"][k] = ctl.saturated
            if recorder is not None and k in frame_steps:
                recorder.capture(d, k * ref.dt)
                frame_steps_done.append(k)
            if observe is not None:
                observe(k, d)
            steps = k + 1
        # Cheap per-period checks (NaN fails every comparison): torque finite, tool within reach of the command.
        err = ctl.last_error
        if not (tau @ tau < 1e12) or not (err[0] * err[0] + err[1] * err[1] + err[2] * err[2] < limit2):
            diverged = f"lost tracking at t = {k * ref.dt:.3f} s (tool error {np.linalg.norm(err[:3]):.3f} m)"
            return False
        return True

    start = _time.perf_counter()
    try:
        for k in range(-n_settle, n):  # inspect() reads k too
            if k < 0:  # settle: hold the first pose while the object comes to rest
                applied = arm.step(ref.pos[0], ref.quat[0], still, still, inspect)
            else:
                applied = arm.step(ref.pos[k], ref.quat[k], twist[k], accel[k], inspect)
            if applied is None:
                break
            if k % 50 == 0 and arm.diverged():
                diverged = f"the simulation became unstable near t = {k * ref.dt:.3f} s"
                break
        if diverged is None and arm.diverged():
            diverged = "the simulation became unstable"
    finally:
        wall = _time.perf_counter() - start
        if recorder is not None:
            recorder.close()
    log["saturated"] = log["saturated"][:, 0] > 0
    result = ExecutionLog(
        **{name: arr[:steps] for name, arr in log.items()},
        body_rel_placed=body_rel_placed,
        steps=steps,
        diverged=diverged,
        wall_time=wall,
        simulated_time=(n_settle + steps) * ref.dt,
        frames=[] if recorder is None else recorder.frames,
        frame_steps=frame_steps_done,
    )
    result.joints = joint_report(scene, ref.dt, joint_pos=result.joint_pos, joint_vel=result.joint_vel,
                                 torque=result.torque, saturated=result.saturated, ik_error=result.ik_error)
    if media is not None:
        media.write(result)
    return result


def single_trajectory(array: object, dim: int, name: str) -> np.ndarray:
    """``array`` as one ``(K, dim)`` float trajectory (K ≥ 2); ``ValueError`` naming ``name`` otherwise."""
    arr, single = as_trajectories(array, dim, name, min_length=2)
    if not single:
        raise ValueError(f"{name} must be one trajectory of shape (K, {dim}); run a batch one trajectory at a time")
    return arr[0]


MAX_EXTRA_TIME = 60.0
"""The longest deceleration, hold or settling phase a run may ask for [s] (a simulated minute)."""


def check_times(**times: float) -> None:
    """``ValueError`` naming the first of ``times`` [s] that is not a number of seconds in [0, 60]."""
    for name, value in times.items():
        check_number(f"{name} [s]", value, minimum=0.0, maximum=MAX_EXTRA_TIME)


def first_true(mask: np.ndarray) -> int | None:
    """Index of the first ``True`` in ``mask`` ``(N,)``, or ``None``."""
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


