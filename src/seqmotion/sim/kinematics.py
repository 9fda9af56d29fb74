"""Tool-pose references for the controller: attitude convention, planar ↔ 3-D, deceleration tail.

Pure NumPy (no MuJoCo), vectorised over time.

**Attitude convention.** A 6-D pose ``q = [x, y, z, a, b, c]`` has the rotation
``R = Rx(a) · Ry(b) · Rz(c)`` (rotations about the fixed world axes applied right to left, i.e.
intrinsic x–y′–z″ angles). The commands of the dissertation use ``(a, b, c) = (θ, π/2, 0)``:
``Ry(π/2)`` turns the tool's axis (its z) to world +x and its down normal (its x) to world −z;
``Rx(θ)`` then rolls it about world x. So θ is a rotation about world +x, which tilts the
surface's up-normal toward −y: the planar model's θ (``seqmotion.tasks.pancake.physics``), whose
still spatula at tilt θ feels ``ψ = -θ``.

At ``b = π/2`` these angles are in gimbal lock (``Rx(a)`` and ``Ry(π/2)Rz(c)`` share an axis), so
the controller never differentiates or subtracts angles: it works on rotation matrices,
quaternions and world-frame angular velocities; the angles only say which rotation is meant.
For the planar task the angular velocity is exactly ``ω = (θ̇, 0, 0)``.

**Reference.** The controller tracks, per 1 ms sample, the tool's position, attitude (a
quaternion ``[w, x, y, z]``), linear and angular velocity, and linear and angular acceleration
(fed forward). Accelerations come from the states' velocities, ``u[k] = (v[k+1] - v[k]) / dt``,
which for the double integrator of SPEC §2 is exactly the generating input.

**Deceleration tail** (§4.4.3): after the last sample the command keeps its final acceleration
at ``-v_end / T`` for ``T = 0.1 s`` — a constant deceleration to rest — then holds still.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import CONTROL_DT, PAN_ORIGIN, PANCAKE_ORIGIN, TOOL_PITCH


def rot_x(angle: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` rotations about x by ``angle`` [rad]."""
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rot_y(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rot_z(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def attitude_matrix(angles: np.ndarray) -> np.ndarray:
    """``(..., 3)`` attitude angles (a, b, c) → ``(..., 3, 3)`` ``R = Rx(a) Ry(b) Rz(c)``."""
    angles = np.asarray(angles, dtype=np.float64)
    return rot_x(angles[..., 0]) @ rot_y(angles[..., 1]) @ rot_z(angles[..., 2])


def matrix_to_quat(rot: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` rotation matrices → ``(..., 4)`` unit quaternions ``[w, x, y, z]``, w ≥ 0."""
    rot = np.asarray(rot, dtype=np.float64)
    m = rot.reshape(-1, 3, 3)
    out = np.empty((m.shape[0], 4))
    trace = np.trace(m, axis1=1, axis2=2)
    # Shepperd's method: pick the largest of w², x², y², z² to divide by, for accuracy.
    diag = np.stack([trace, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], -1)
    pick = np.argmax(diag, axis=1)
    for i in range(4):
        sel = pick == i
        if not np.any(sel):
            continue
        r = m[sel]
        if i == 0:
            s = np.sqrt(1.0 + trace[sel]) * 2
            q = [0.25 * s, (r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s, (r[:, 1, 0] - r[:, 0, 1]) / s]
        elif i == 1:
            s = np.sqrt(1.0 + r[:, 0, 0] - r[:, 1, 1] - r[:, 2, 2]) * 2
            q = [(r[:, 2, 1] - r[:, 1, 2]) / s, 0.25 * s, (r[:, 0, 1] + r[:, 1, 0]) / s, (r[:, 0, 2] + r[:, 2, 0]) / s]
        elif i == 2:
            s = np.sqrt(1.0 + r[:, 1, 1] - r[:, 0, 0] - r[:, 2, 2]) * 2
            q = [(r[:, 0, 2] - r[:, 2, 0]) / s, (r[:, 0, 1] + r[:, 1, 0]) / s, 0.25 * s, (r[:, 1, 2] + r[:, 2, 1]) / s]
        else:
            s = np.sqrt(1.0 + r[:, 2, 2] - r[:, 0, 0] - r[:, 1, 1]) * 2
            q = [(r[:, 1, 0] - r[:, 0, 1]) / s, (r[:, 0, 2] + r[:, 2, 0]) / s, (r[:, 1, 2] + r[:, 2, 1]) / s, 0.25 * s]
        out[sel] = np.stack(q, -1)
    out *= np.where(out[:, :1] < 0, -1.0, 1.0)
    return out.reshape(rot.shape[:-2] + (4,))


def planar_tilt(rot: np.ndarray) -> np.ndarray:
    """The planar attitude θ of tool rotations ``(..., 3, 3)`` [rad], wrapped to (-π, π].

    The tool's x axis is its surface's down normal; θ is that normal's angle from straight
    down, positive toward +y (the ``arg`` of :mod:`seqmotion.tasks.pancake.physics`). For
    ``R = Rx(θ) Ry(π/2)`` it returns θ exactly.
    """
    rot = np.asarray(rot)
    return np.arctan2(rot[..., 1, 0], -rot[..., 2, 0])


@dataclass
class Reference:
    """A sampled tool-pose reference (all world frame, SI units).

    Attributes:
        pos: ``(N, 3)`` site position [m].
        quat: ``(N, 4)`` site attitude ``[w, x, y, z]``.
        vel: ``(N, 3)`` linear velocity [m/s].
        omega: ``(N, 3)`` angular velocity [rad/s].
        acc: ``(N, 3)`` linear acceleration fed forward [m/s²].
        alpha: ``(N, 3)`` angular acceleration fed forward [rad/s²].
        n_motion: samples that belong to the given trajectory (the rest is the deceleration
            tail and the final hold).
        dt: sample period [s].
    """

    pos: np.ndarray
    quat: np.ndarray
    vel: np.ndarray
    omega: np.ndarray
    acc: np.ndarray
    alpha: np.ndarray
    n_motion: int
    dt: float = CONTROL_DT

    def __len__(self) -> int:
        return self.pos.shape[0]


def _accel_from_velocity(vel: np.ndarray, dt: float) -> np.ndarray:
    """``u[k] = (v[k+1] - v[k]) / dt``; the last sample gets zero (the tail overwrites it)."""
    acc = np.zeros_like(vel)
    acc[:-1] = np.diff(vel, axis=0) / dt
    return acc


def stop_accelerations(vel: np.ndarray, decel_time: float, hold_time: float, dt: float) -> np.ndarray:
    """The robot's stop after a motion (§4.4.3): a constant deceleration from velocities ``vel`` ``(D,)`` to
    rest over ``decel_time`` [s], then a hold for ``hold_time`` [s].

    Returns:
        ``(N_dec + N_hold, D)`` accelerations, one per period ``dt`` from the motion's last sample on:
        ``-vel / decel_time`` for the ``N_dec = round(decel_time / dt)`` first, 0 for the
        ``N_hold = round(hold_time / dt)`` after them.
    """
    n_dec, n_hold = round(decel_time / dt), round(hold_time / dt)
    decel = -vel / decel_time if n_dec > 0 else np.zeros_like(vel)
    return np.concatenate([np.broadcast_to(decel, (n_dec, len(vel))), np.zeros((n_hold, len(vel)))])


def _tail(pos: np.ndarray, vel: np.ndarray, decel_time: float, hold_time: float, dt: float):
    """Positions, velocities, accelerations of :func:`stop_accelerations` from the last sample ``pos``, ``vel``
    ``(D,)``: three ``(N_tail, D)`` arrays, sample i at time ``(i + 1) dt`` after the last one, and the
    acceleration to use *at* the last sample."""
    accel = stop_accelerations(vel, decel_time, hold_time, dt)
    n_dec = round(decel_time / dt)
    decel = accel[0] if n_dec > 0 else np.zeros_like(vel)
    t = (np.arange(1, len(accel) + 1) * dt)[:, None]
    t_dec = np.minimum(t, n_dec * dt)
    p = pos + vel * t_dec + 0.5 * decel * t_dec**2
    v = np.where(t < n_dec * dt - 1e-12, vel + decel * t, 0.0)
    a = np.concatenate([accel[1:], np.zeros((min(len(accel), 1), len(vel)))])  # sample i holds input i + 1
    return p, v, a, decel


def _with_tail(
    pos: np.ndarray, vel: np.ndarray, decel_time: float, hold_time: float, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Task-space positions, velocities and accelerations ``(K + N_tail, D)`` of a trajectory and its tail.

    ``pos``, ``vel``: ``(K, D)`` at ``dt``. Accelerations are the velocity differences; the last
    sample's is the tail's constant deceleration (:func:`_tail`).
    """
    acc = _accel_from_velocity(vel, dt)
    tp, tv, ta, decel = _tail(pos[-1], vel[-1], decel_time, hold_time, dt)
    acc[-1] = decel
    return np.concatenate([pos, tp]), np.concatenate([vel, tv]), np.concatenate([acc, ta])


def planar_reference(
    states: np.ndarray,
    *,
    decel_time: float = 0.1,
    hold_time: float = 0.0,
    origin: np.ndarray = PANCAKE_ORIGIN,
    dt: float = CONTROL_DT,
) -> Reference:
    """The spatula command ``q = [0.5, y, z + 0.35, θ, π/2, 0]`` (eq. 4.9) for planar states.

    Args:
        states: ``(K, 6)`` ``[y, z, θ, v_y, v_z, v_θ]`` at ``dt``.
        decel_time: constant-deceleration tail [s] (§4.4.3: 0.1 s); 0 for none.
        hold_time: further time held at rest [s].
        origin: tool position of the planar origin [m].
    """
    p, v, a = _with_tail(states[:, :3], states[:, 3:], decel_time, hold_time, dt)  # (y, z, θ)
    n = p.shape[0]
    zeros = np.zeros(n)
    pos = np.stack([np.full(n, origin[0]), origin[1] + p[:, 0], origin[2] + p[:, 1]], -1)
    angles = np.stack([p[:, 2], np.full(n, TOOL_PITCH), zeros], -1)
    return Reference(
        pos=pos,
        quat=matrix_to_quat(attitude_matrix(angles)),
        vel=np.stack([zeros, v[:, 0], v[:, 1]], -1),
        omega=np.stack([v[:, 2], zeros, zeros], -1),
        acc=np.stack([zeros, a[:, 0], a[:, 1]], -1),
        alpha=np.stack([a[:, 2], zeros, zeros], -1),
        n_motion=states.shape[0],
        dt=dt,
    )


def pan_reference(
    pan_states: np.ndarray,
    *,
    decel_time: float = 0.1,
    hold_time: float = 0.0,
    origin: np.ndarray = PAN_ORIGIN,
    dt: float = CONTROL_DT,
) -> Reference:
    """The pan command ``q = [x_p + 0.65, y_p, 0.3, 0, π/2, 0]`` (eq. 3.28).

    Args:
        pan_states: ``(K, 4)`` ``[x_p, y_p, vx_p, vy_p]`` at ``dt``.
    """
    p, v, a = _with_tail(pan_states[:, :2], pan_states[:, 2:], decel_time, hold_time, dt)  # (x_p, y_p)
    n = p.shape[0]
    zeros = np.zeros((n, 1))
    quat = matrix_to_quat(attitude_matrix(np.array([0.0, TOOL_PITCH, 0.0])))
    return Reference(
        pos=np.concatenate([origin[:2] + p, np.full((n, 1), origin[2])], -1),
        quat=np.tile(quat, (n, 1)),
        vel=np.concatenate([v, zeros], -1),
        omega=np.zeros((n, 3)),
        acc=np.concatenate([a, zeros], -1),
        alpha=np.zeros((n, 3)),
        n_motion=pan_states.shape[0],
        dt=dt,
    )


def pose_command(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A 6-D pose ``[x, y, z, a, b, c]`` → position ``(3,)`` and quaternion ``(4,)``."""
    q = np.asarray(q, dtype=np.float64)
    return q[:3].copy(), matrix_to_quat(attitude_matrix(q[3:]))


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """``(..., 4)`` quaternions ``[w, x, y, z]`` → ``(..., 3, 3)`` rotation matrices."""
    q = np.asarray(quat, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def rotation_angle(quat_a: np.ndarray, quat_b: np.ndarray) -> np.ndarray:
    """Angle of the rotation between two attitudes ``(..., 4)`` [rad], in [0, π]."""
    dot = np.abs(np.sum(np.asarray(quat_a) * np.asarray(quat_b), axis=-1))
    return 2 * np.arccos(np.clip(dot, -1.0, 1.0))


__all__ = [
    "Reference",
    "attitude_matrix",
    "matrix_to_quat",
    "pan_reference",
    "planar_reference",
    "planar_tilt",
    "pose_command",
    "quat_to_matrix",
    "rot_x",
    "rot_y",
    "rot_z",
    "rotation_angle",
]
