"""Whether a robot can execute a planar pancake motion, from its joint path alone: :func:`check_executable`.

The simulator's own placement and IK turn the spatula states into the robot's joint path, exactly as
:func:`~seqmotion.sim.pancake.run_pancake` does (the command of eq. 4.9, :func:`~seqmotion.sim.control.solve_ik` to the
first pose, then the :class:`~seqmotion.sim.control.JointSpaceController`'s differential IK every period on a
standard arm), but nothing is simulated: no dynamics, no pancake, so a 0.5 s motion is judged in well under a second.
The path is differentiated and held against the robot's rated limits (:attr:`Robot.limits
<seqmotion.sim.robot_models.Robot.limits>`), and the torques it needs come from MuJoCo's inverse dynamics on the
same model (``mj_inverse``: the arm and the tool, without the pancake's contact).
"""

from __future__ import annotations

import numpy as np

from ..core.execution import BindingLimit, ExecutionCheck, fixable_by_timing, time_scale
from ..errors import check_number
from .arm import IK_TOLERANCE, single_trajectory
from .backend import CONTROL_DT, import_mujoco
from .control import JointSpaceController, resolve_gains, solve_ik
from .kinematics import planar_reference
from .limits import JointLimits
from .robot_models import Robot, built_in_limits, resolve_robot
from .scene import Scene, get_scene


def _joint_path(scene: Scene, pos: np.ndarray, quat: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The joint path ``(K, n)`` [rad] and IK residuals ``(K, 2)`` [m, rad] the simulator's IK gives for the tool
    poses ``pos`` ``(K, 3)`` [m], ``quat`` ``(K, 4)`` at period ``dt`` [s]."""
    mujoco = import_mujoco()
    m = scene.model
    data = mujoco.MjData(m)
    q0 = solve_ik(scene, pos[0], quat[0])  # where Arm.reset puts the arm
    k, n = len(pos), len(scene.arm_dof)
    path, residual = np.zeros((k, n)), np.zeros((k, 2))
    if scene.robot is None:
        # The built-in arm tracks in task space, with no IK in its loop; its one IK (Arm.reset's) solved at every
        # sample, warm-started from the previous one, is the path its joints follow.
        q = q0
        for i in range(k):
            try:
                q = solve_ik(scene, pos[i], quat[i], seed=q)
            except ValueError:  # out of reach: the residual of the nearest pose says by how much
                data.qpos[scene.arm_qpos] = q
                mujoco.mj_kinematics(m, data)
                residual[i, 0] = float(np.linalg.norm(pos[i] - data.site_xpos[scene.site]))
            path[i] = q
        return path, residual
    data.qpos[scene.arm_qpos] = q0
    mujoco.mj_forward(m, data)
    controller = JointSpaceController(scene, resolve_gains("ch2"), dt=dt)
    controller.reset(data)
    for i in range(k):
        controller.follow(pos[i], quat[i])
        path[i], residual[i] = controller.q_ref, controller.ik_error
    return path, residual


ACCEL_WINDOW = 0.01
"""The joint speeds are averaged over this long before they are differenced into accelerations [s]. The differential
IK steps one period at a time and its joint path jitters at that scale: on the Panda, second differences of it at
1 ms reached 2000 rad/s², ten times the spatula's own 209 rad/s², and 11–21 ms of averaging brought them back to the
spatula's (its accelerations change over tens of milliseconds, so the motion's own peaks are kept)."""


def _accelerations(qd: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Joint accelerations ``(M, n)`` [rad/s²] from joint speeds ``(K-1, n)`` [rad/s] at period ``dt`` [s] (speeds
    averaged over :data:`ACCEL_WINDOW` first), and their times ``(M,)`` [s] from the first sample."""
    window = max(1, min(round(ACCEL_WINDOW / dt), len(qd)))
    kernel = np.ones(window) / window
    smooth = np.stack([np.convolve(qd[:, j], kernel, mode="valid") for j in range(qd.shape[1])], axis=1)
    # Speed i is at (i + 1/2) dt, a window of them at its centre; a difference of two at their midpoint.
    return np.diff(smooth, axis=0) / dt, (np.arange(len(smooth) - 1) + (window + 1) / 2) * dt


def path_dynamics(scene: Scene, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The joint torques ``(M, n)`` [N m] the arm needs to follow the joint path ``q`` ``(N, n)`` with speeds ``qd``
    ``(N-1, n)`` and accelerations ``qdd`` ``(M, n)`` (at the times :func:`_accelerations` gives them), by MuJoCo's
    inverse dynamics (``mj_inverse``) on the scene's own model — the arm and its tool, gravity, joint damping and
    armature; the object rests where the model puts it — and the arm's mass matrices ``(M, n, n)`` [kg m²] there
    (``τ`` is affine in ``q̈``: ``τ = H q̈ + c``)."""
    mujoco = import_mujoco()
    m = scene.model
    data = mujoco.MjData(m)
    n, count = q.shape[1], len(qdd)
    tau, mass = np.zeros((count, n)), np.zeros((count, n, n))
    if count == 0:
        return tau, mass
    window = len(qd) - count  # qdd[i] sits at t = (i + (window + 1) / 2) dt: q and q̇ are taken there
    centre = np.arange(count) + (window + 1) / 2
    times = np.arange(len(q))
    pos = np.stack([np.interp(centre, times, q[:, j]) for j in range(n)], axis=1)
    vel = np.stack([np.interp(centre, times[:-1] + 0.5, qd[:, j]) for j in range(n)], axis=1)
    full = np.zeros((m.nv, m.nv))
    dof = np.asarray(scene.arm_dof)
    for i in range(count):
        data.qpos[scene.arm_qpos], data.qvel[dof], data.qacc[:] = pos[i], vel[i], 0.0
        data.qacc[dof] = qdd[i]
        mujoco.mj_inverse(m, data)
        tau[i] = data.qfrc_inverse[dof]
        mujoco.mj_fullM(m, data, full)
        mass[i] = full[np.ix_(dof, dof)]
    return tau, mass


def _worst(kind: str, names: tuple[str, ...], share: np.ndarray, needed: np.ndarray, rated: np.ndarray,
           times: np.ndarray) -> BindingLimit:
    """The sample and joint with the largest ``share`` ``(N, n)`` as a :class:`BindingLimit`."""
    k, j = np.unravel_index(int(np.argmax(share)), share.shape)
    return BindingLimit(kind, names[j], float(needed[k, j]), float(rated[k, j]), float(share[k, j]), float(times[k]))


def check_executable(states: object, robot: str | Robot | None, dt: float = CONTROL_DT) -> ExecutionCheck:
    """Judge whether ``robot`` can execute planar spatula states, from the joint path its IK gives.

    The joint path comes from the simulator's placement and IK (as in :func:`~seqmotion.sim.pancake.run_pancake`,
    kinematics only). Its speeds ``q̇[k] = (q[k+1] - q[k]) / dt`` (at t = (k + ½) dt) are held against the rated
    speeds; its accelerations (differences of the speeds averaged over :data:`ACCEL_WINDOW`) against the rated
    accelerations where published; the torques they need (``mj_inverse``) against the model's torque limits; its
    positions against the joint ranges; the IK residual against :data:`~seqmotion.sim.arm.IK_TOLERANCE`.

    Args:
        states: ``(K, 6)`` ``[y, z, θ, v_y, v_z, v_θ]`` [m, m, rad, m/s, m/s, rad/s], K ≥ 2.
        robot: a robot's name (``"ur5e"``, ``"panda"``, …; :func:`~seqmotion.sim.robot_models.robots`), a
            :class:`~seqmotion.sim.robot_models.Robot`, or ``None`` / ``"mh3f"`` for the built-in arm (whose limits
            are unknown: the verdict is then ``None`` unless a pose is out of reach).
        dt: the states' sample period [s] (the simulator runs at 1 ms).

    Returns:
        An :class:`~seqmotion.core.execution.ExecutionCheck`: ``ok``, the binding limit, and the duration the same
        joint paths need to keep every rated speed and acceleration.

    Raises:
        ValueError: bad states, a ``dt`` that is not a positive number, or an unknown robot.
    """
    arr = single_trajectory(states, 6, "states")
    check_number("dt [s]", dt, minimum=1e-6, maximum=1.0)
    standard = resolve_robot(robot)
    scene = get_scene("pancake", standard)
    ref = planar_reference(arr, decel_time=0.0, hold_time=0.0, dt=dt)
    q, residual = _joint_path(scene, ref.pos[: ref.n_motion], ref.quat[: ref.n_motion], dt)
    limits = built_in_limits() if standard is None else standard.limits
    return ExecutionCheck(**judge_joint_path(scene, limits, q, residual, dt, (len(q) - 1) * dt)[0])


def judge_joint_path(scene: Scene, limits: JointLimits, q: np.ndarray, residual: np.ndarray, dt: float,
                     duration: float) -> tuple[dict, list[BindingLimit], tuple[np.ndarray, ...]]:
    """Hold a joint path ``q`` ``(K, n)`` [rad] (IK residuals ``(K, 2)``) at period ``dt`` [s] against ``limits``.

    Returns the :class:`~seqmotion.core.execution.ExecutionCheck` fields of a motion of ``duration`` [s] (what a
    slower run needs is scaled from it), every limit judged (the candidates for the binding one), and the path's
    speeds, accelerations, torques and mass matrices ``(qd, qdd, tau, mass)`` (``tau`` and ``mass`` ``None`` on the
    built-in arm) for a caller that keeps more (the sliding check)."""
    names, k = limits.joints, len(q)
    qd = np.diff(q, axis=0) / dt
    qdd, accel_time = _accelerations(qd, dt)
    speed_peak = np.abs(qd).max(axis=0)
    accel_peak = np.abs(qdd).max(axis=0, initial=0.0)
    candidates: list[BindingLimit] = []
    unknown: dict[str, str] = {}

    speed_share = None
    if limits.velocity is not None:
        share = np.abs(qd) / limits.velocity
        speed_share = share.max(axis=0)
        candidates.append(_worst("speed", names, share, np.abs(qd), np.broadcast_to(limits.velocity, qd.shape),
                                 (np.arange(k - 1) + 0.5) * dt))
    else:
        unknown["speed"] = str(limits.unknown("velocity"))
    accel_share = None
    if limits.acceleration is not None and len(qdd):
        share = np.abs(qdd) / limits.acceleration
        accel_share = share.max(axis=0)
        candidates.append(_worst("acceleration", names, share, np.abs(qdd),
                                 np.broadcast_to(limits.acceleration, qdd.shape), accel_time))
    elif limits.acceleration is None:
        unknown["acceleration"] = str(limits.unknown("acceleration"))
    torque_peak = torque_share = tau = mass = None
    if scene.robot is not None and len(qdd):
        tau, mass = path_dynamics(scene, q, qd, qdd)
        torque_peak = np.abs(tau).max(axis=0)
        if limits.torque is not None:
            share = np.abs(tau) / limits.torque
            torque_share = share.max(axis=0)
            candidates.append(_worst("torque", names, share, np.abs(tau), np.broadcast_to(limits.torque, tau.shape),
                                     accel_time))
    if limits.torque is None:
        unknown["torque"] = str(limits.unknown("torque"))
    range_margin = None
    if limits.position is not None:
        lo, hi = limits.position.T
        finite = np.isfinite(lo) & np.isfinite(hi)
        # A continuous joint has no ends: no share of a range used, an infinite margin (no inf - inf, which is NaN).
        mid, half = np.where(finite, (lo + hi) / 2, 0.0), np.where(finite, (hi - lo) / 2, 1.0)
        share = np.where(finite, np.abs(q - mid) / half, 0.0)
        range_margin = np.min(np.minimum(q - lo, hi - q), axis=0)
        end = np.broadcast_to(np.where(q < mid, lo, hi), q.shape)
        candidates.append(_worst("range", names, share, q, end, np.arange(k) * dt))
    else:
        unknown["range"] = str(limits.unknown("position"))
    reach = (residual / np.array(IK_TOLERANCE)).max(axis=1)
    i = int(np.argmax(reach))
    candidates.append(BindingLimit("reach", None, float(residual[i, 0]), IK_TOLERANCE[0], float(reach[i]), i * dt))

    broken = [c for c in candidates if c.share > 1.0]
    if broken:
        ok: bool | None = False
        # A limit no timing can keep (range, reach, torque) binds before any a slower run would cure.
        untimed = [c for c in broken if not fixable_by_timing(c)]
        binding = max(untimed or broken, key=lambda c: c.share)
    else:
        ok = None if ("speed" in unknown or "range" in unknown) else True
        binding = max(candidates, key=lambda c: c.share) if ok else None
    scale = None if any(not fixable_by_timing(c) for c in broken) else time_scale(speed_share, accel_share)
    fields = dict(
        ok=ok, robot=limits.robot, joints=tuple(names), duration=duration, speed_peak=speed_peak,
        speed_share=speed_share, accel_peak=accel_peak, accel_share=accel_share, range_margin=range_margin,
        ik_error=residual.max(axis=0), torque_peak=torque_peak, torque_share=torque_share, binding=binding,
        time_scale=scale, needed_duration=None if scale is None else scale * duration, unknown=unknown)
    return fields, candidates, (qd, qdd, tau, mass)


__all__ = ["ACCEL_WINDOW", "check_executable", "judge_joint_path", "path_dynamics"]
