"""The sliding plan on a robot: the limits an execution check judges and their map onto the pan's motion.

:class:`SlidingExecutionCheck` is what the simulator's execution check of a sliding plan returns (the robot's joint
speeds, accelerations, torques and ranges along the plan's joint path, and the linear map from the pan's motion to
the joints' about it); :class:`PanJointLimits` turns it into a latent objective term (ch. 4: limits as an
objective), which :meth:`~seqmotion.tasks.sliding.SlidingPlanner.fit_robot` minimises.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from ...core.execution import ExecutionCheck
from ...core.options import check_positive
from ...physics.integrator import DT

ROBOT_KINDS = ("speed", "range", "torque", "acceleration")
"""The limits :class:`PanJointLimits` maps onto the pan: rated joint speeds, joint ranges (with the reach), torque
limits, rated joint accelerations."""
RUN_KINDS = ("speed", "range", "torque")
"""The limits a simulated run judges (its ``JointReport``: speeds, ranges, reach, torques), kept first by
:meth:`SlidingPlanner.fit_robot`; rated accelerations are judged by the execution check alone."""
ROBOT_MARGIN = 0.9
""":meth:`SlidingPlanner.fit_robot` aims at this share of each rated speed and torque limit: the pan moves between
two checks, so the linear map about the checked path is off by a few per cent, and the run's joints lag and overshoot
their reference."""
ACCEPT_SHARE = 0.95
""":meth:`SlidingPlanner.fit_robot` accepts a plan once its checked joint speeds and torques stay within this share of
their limits (rated accelerations, judged by the check alone: within them): a simulated run's measured speeds and
torques came within ±0.04 of the check's on the Panda's sliding plans."""
ACCEPT_CLEARANCE = 0.02
""":meth:`SlidingPlanner.fit_robot` accepts a plan once every joint stays this far from its range's ends [rad]: the
differential IK holds a joint at an end exactly, and the run's joint then touches or passes it."""
ACCEL_MARGIN = 0.98
"""The share of the rated accelerations :class:`PanJointLimits` aims at (only the check judges them, on the path
the term predicts: a thin margin; more would leave the pan less of the acceleration that makes the object slide)."""
RANGE_CLEARANCE = 0.05
"""How far from each end of a joint's range :class:`PanJointLimits` keeps the joint [rad] (the differential IK bends
the path away from an end it nears, and the run's joints overshoot their reference)."""

@dataclass(frozen=True)
class SlidingExecutionCheck(ExecutionCheck):
    """Whether a robot can execute a sliding plan's pan motion (:class:`~seqmotion.core.execution.ExecutionCheck`),
    with what a planner needs to keep the limits (``seqmotion.sim.executable_sliding.check_sliding_executable``
    computes it).

    Attributes:
        rated_speed: ``(n,)`` the rated joint speeds judged against [rad/s], or ``None`` (unknown).
        rated_acceleration: ``(n,)`` the rated joint accelerations [rad/s²], or ``None`` (none published).
        torque_limit: ``(n,)`` the model's torque limits [N m], or ``None`` (unknown).
        range_ends: ``(n, 2)`` the joint ranges [rad] (``±inf`` for a continuous joint), or ``None`` (unknown).
        decel_time: the stop after the plan that was judged with it [s] (the run's constant deceleration to rest).
        accel_window: the joint speeds were averaged over this many samples before being differenced into
            accelerations.
        worst_share: limit kind (``"speed"``, ``"acceleration"``, ``"torque"``, ``"range"``, ``"reach"``) → the
            largest share of it the plan uses (> 1: broken), for each kind judged.
        pan_map: ``(N, n, 2)`` [rad/m]: per sample of the judged joint path (the plan's K, then its stop), the joint
            velocities per unit pan velocity along x and y (``q̇ ≈ pan_map[k] @ v_pan``), or ``None``.
        joint_path: ``(N, n)`` the judged joint path [rad], or ``None``.
        pan_path, pan_velocity: ``(N, 2)`` the pan positions [m] and velocities [m/s] it was judged for (the plan's,
            then its stop), or ``None``.
        torque_bias, mass_path: ``(M, n)`` [N m] and ``(M, n, n)`` [kg m²]: the torques are ``mass_path[i] @ q̈ +
            torque_bias[i]`` at the path's acceleration samples (inverse dynamics), or ``None``.
        (The last six are derived from the path, so not saved with a plan: ``None`` once loaded.)
    """

    rated_speed: np.ndarray | None = None
    rated_acceleration: np.ndarray | None = None
    torque_limit: np.ndarray | None = None
    range_ends: np.ndarray | None = None
    decel_time: float = 0.0
    accel_window: int = 1
    worst_share: dict[str, float] = field(default_factory=dict)
    pan_map: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)
    joint_path: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)
    pan_path: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)
    pan_velocity: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)
    torque_bias: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)
    mass_path: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)

    def fix(self) -> str:
        """What would make the plan executable, in words (``""`` where it already is or nothing is known)."""
        if self.ok is not False or self.binding is None:
            return ""
        change = "the pan's motion itself must change (planner.plan(command, robot=...) refines it to keep them)"
        if self.time_scale is not None and self.needed_duration is not None:
            return (f"the same joint paths would need ≥ {self.needed_duration:.2f} s instead of {self.duration:.2f} s "
                    f"({self.time_scale:.2f}× slower), but a slower pan slides the object differently: {change}")
        return change

    def kept(self, kinds: tuple[str, ...] = ROBOT_KINDS, share: float = 1.0, clearance: float = 0.0) -> bool | None:
        """Whether the limits of ``kinds`` (of :data:`ROBOT_KINDS`; ``"range"`` with the reach) are kept, each rated
        speed and torque limit within ``share`` of it (rated accelerations, which only this check judges: within
        them), each joint at least ``clearance`` [rad] from its range's ends: None where the speeds or ranges asked
        for are unknown; unknown torques and unpublished accelerations count as kept (``ok`` says what is known)."""
        if any(kind in self.unknown for kind in kinds if kind in ("speed", "range")):
            return None
        for kind in kinds:
            limit = 1.0 if kind == "acceleration" else share
            if kind in ("speed", "torque", "acceleration") and self.worst_share.get(kind, 0.0) > limit:
                return False
        if "range" in kinds:
            margin = float(np.min(self.range_margin, initial=np.inf)) if self.range_margin is not None else np.inf
            worst = max(self.worst_share.get("range", 0.0), self.worst_share.get("reach", 0.0))
            if worst > 1.0 or margin < clearance:
                return False
        return True



class PanJointLimits:
    """A robot's joint limits as a penalty on a sliding plan's pan motion (ch. 4: limits as a latent objective).

    Built from an execution check of a plan (:class:`SlidingExecutionCheck`, with its ``pan_map``): the rated joint
    speeds and accelerations, the torque limits and the joint ranges are mapped through the arm's Jacobian (and mass
    matrix) along that plan's joint path into what they allow the pan. For plan states ``(B, K, 8)`` (the run's stop
    after them added as the check adds it) the joints are predicted to first order about the checked path:
    ``q[k] = q_path[k] + M_k (p_pan[k] − p_path[k])`` and ``q̇[k] = q̇_path[k] + M_k (v̄_pan[k] − v̄_path[k])``
    (``M_k``: ``pan_map``; ``v̄``: the pan's velocity over the period), ``q̈`` as differences of ``q̇`` over the
    check's averaging window, ``τ = H q̈ + c`` with the path's mass matrices and the rest of its inverse dynamics —
    at the checked plan itself exactly what the check measured. Each is held against ``margin`` × its rated speed or
    torque limit (accelerations: :data:`ACCEL_MARGIN`), the positions against the range less :data:`RANGE_CLEARANCE`
    at each end. The penalty is ``Σ_k Σ_j max(0, share − 1)²`` per trajectory, in shares of those limits. The map
    is a linearisation at the checked plan: check again and rebuild it once the pan has moved
    (:meth:`SlidingPlanner.fit_robot` does).

    Args:
        check: a :class:`SlidingExecutionCheck` with its ``pan_map`` (a fresh check: a loaded one has none).
        kinds: the limits to keep, of :data:`ROBOT_KINDS` (an unknown or unpublished one is skipped).
        margin: the share of each rated speed and torque limit aimed at (0 < margin ≤ 1).
        dt: the sample period [s].
    """

    def __init__(self, check: SlidingExecutionCheck, kinds: tuple[str, ...] = ROBOT_KINDS,
                 margin: float = ROBOT_MARGIN, dt: float = DT) -> None:
        if check.pan_map is None or check.joint_path is None or check.pan_path is None or check.pan_velocity is None:
            raise ValueError("PanJointLimits needs a fresh execution check of a plan on a robot with rated speeds "
                             "(check.pan_map is None: the rated speeds are unknown, or the check was loaded from a "
                             "file)")
        unknown = sorted(set(kinds) - set(ROBOT_KINDS))
        if unknown:
            raise ValueError(f"kinds must be among {ROBOT_KINDS}, got {unknown}")
        check_positive("margin", margin)
        if margin > 1:
            raise ValueError(f"margin must be in (0, 1], got {margin}")
        self.map = torch.from_numpy(np.asarray(check.pan_map, dtype=np.float64))
        self.path = torch.from_numpy(np.asarray(check.joint_path, dtype=np.float64))
        self.pan_path = torch.from_numpy(np.asarray(check.pan_path, dtype=np.float64))
        self.pan_velocity = torch.from_numpy(np.asarray(check.pan_velocity, dtype=np.float64))
        self.speeds = torch.diff(self.path, dim=0) / dt  # the checked path's own q̇: the prediction is exact there
        self.dt, self.window = float(dt), max(1, int(check.accel_window))
        self.n_stop = round(float(check.decel_time) / dt)
        self.length = len(self.map) - self.n_stop  # the plan's K
        self.speed = self._limit("speed" in kinds, check.rated_speed, margin)
        self.accel = self._limit("acceleration" in kinds, check.rated_acceleration, max(margin, ACCEL_MARGIN))
        self.torque = None
        if check.torque_bias is not None and check.mass_path is not None:
            self.torque = self._limit("torque" in kinds, check.torque_limit, margin)
            self.bias = torch.from_numpy(np.asarray(check.torque_bias, dtype=np.float64))
            self.mass = torch.from_numpy(np.asarray(check.mass_path, dtype=np.float64))
        self.mid = self.half = None
        if "range" in kinds and check.range_ends is not None:
            lo, hi = np.asarray(check.range_ends, dtype=np.float64).T
            finite = np.isfinite(lo) & np.isfinite(hi)
            self.mid = torch.from_numpy(np.where(finite, (lo + hi) / 2, 0.0))
            self.half = torch.from_numpy(np.where(finite, (hi - lo) / 2 - RANGE_CLEARANCE, np.inf))

    @staticmethod
    def _limit(wanted: bool, rated: np.ndarray | None, margin: float) -> torch.Tensor | None:
        return torch.from_numpy(margin * np.asarray(rated, dtype=np.float64)) if wanted and rated is not None else None

    def pan_motion(self, states: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The pan's positions and velocities ``(B, N, 2)`` [m, m/s] for plan states ``(B, K, 8)``: the plan's, then
        the run's constant deceleration to rest (as :func:`seqmotion.sim.kinematics.pan_reference` builds it)."""
        if states.ndim != 3 or states.shape[1] != self.length or states.shape[-1] < 4:
            raise ValueError(f"PanJointLimits was built for plans of K = {self.length} samples, got states of shape "
                             f"{tuple(states.shape)}")
        pos, vel = states[..., 0:2], states[..., 2:4]
        if self.n_stop == 0:
            return pos, vel
        t = (torch.arange(1, self.n_stop + 1, dtype=states.dtype, device=states.device) * self.dt)[None, :, None]
        stop = self.n_stop * self.dt
        v_end, p_end = vel[:, -1:], pos[:, -1:]
        tail_v = v_end * (1 - t / stop)
        tail_p = p_end + v_end * t - 0.5 * v_end / stop * t**2
        return torch.cat([pos, tail_p], 1), torch.cat([vel, tail_v], 1)

    def shares(self, states: torch.Tensor) -> dict[str, torch.Tensor]:
        """Predicted shares of the (margined) limits: ``"speed"`` ``(B, N-1, n)``, ``"acceleration"`` and
        ``"torque"`` ``(B, N-1-W, n)``, ``"range"`` ``(B, N, n)``, for the kinds kept."""
        pos, vel = self.pan_motion(states)
        m = self.map.to(states.dtype)
        out: dict[str, torch.Tensor] = {}
        change = vel - self.pan_velocity.to(states.dtype)
        qd = self.speeds.to(states.dtype) + torch.einsum("knj,bkj->bkn", m[:-1], 0.5 * (change[:, 1:] + change[:, :-1]))
        if self.speed is not None:
            out["speed"] = qd.abs() / self.speed.to(states.dtype)
        if (self.accel is not None or self.torque is not None) and qd.shape[1] > self.window:
            w = self.window
            qdd = (qd[:, w:] - qd[:, :-w]) / (w * self.dt)  # the check's: speeds averaged over w, then differenced
            if self.accel is not None:
                out["acceleration"] = qdd.abs() / self.accel.to(states.dtype)
            if self.torque is not None and qdd.shape[1] == len(self.bias):
                tau = torch.einsum("kij,bkj->bki", self.mass.to(states.dtype), qdd) + self.bias.to(states.dtype)
                out["torque"] = tau.abs() / self.torque.to(states.dtype)
        if self.mid is not None and self.half is not None:
            q = self.path.to(states.dtype) + torch.einsum("knj,bkj->bkn", m, pos - self.pan_path.to(states.dtype))
            out["range"] = (q - self.mid.to(states.dtype)).abs() / self.half.to(states.dtype)
        return out

    def __call__(self, states: torch.Tensor, accel: torch.Tensor | None = None) -> torch.Tensor:
        """``(B,)`` ``Σ max(0, share − 1)²`` over samples, joints and the kinds kept."""
        total = torch.zeros(states.shape[0], dtype=states.dtype, device=states.device)
        for share in self.shares(states).values():
            total = total + (torch.relu(share - 1.0) ** 2).sum((1, 2))
        return total



def check_limit_kinds(limits: object) -> None:
    """``ValueError`` unless ``limits`` is a non-empty tuple or list of :data:`ROBOT_KINDS`."""
    if isinstance(limits, str) or not isinstance(limits, tuple | list) or not limits or not all(
            kind in ROBOT_KINDS for kind in limits):
        raise ValueError(f"limits must be a non-empty tuple of {ROBOT_KINDS}, got {limits!r}")



def pan_acceleration_reach(check: SlidingExecutionCheck) -> tuple[float, float] | None:
    """The least and the most pan acceleration [m/s²] the rated joint accelerations allow, over the directions of the
    pan's plane, at the plan's first sample (``|M_j d| a ≤ q̈_max,j`` for every joint j, ``M``: ``pan_map``), or None
    (no map, or no rated accelerations)."""
    if check.pan_map is None or check.rated_acceleration is None:
        return None
    angles = np.linspace(0.0, np.pi, 181)
    directions = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    per_joint = np.abs(directions @ np.asarray(check.pan_map[0]).T)  # (directions, n) [rad/m]
    reach = np.min(np.asarray(check.rated_acceleration) / np.maximum(per_joint, 1e-12), axis=1)
    return float(reach.min()), float(reach.max())

