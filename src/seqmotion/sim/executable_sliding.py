"""Whether a robot can execute a sliding plan's pan motion, from its joint path alone: :func:`check_sliding_executable`.

The sliding counterpart of :func:`~seqmotion.sim.executable.check_executable`. The pan states become the pan command
of eq. 3.28 with the run's constant-deceleration tail (:func:`~seqmotion.sim.kinematics.pan_reference`, as
:func:`~seqmotion.sim.sliding.run_sliding` builds it), the simulator's own IK turns it into the robot's joint path
(:func:`~seqmotion.sim.control.solve_ik` to the first pose, then the
:class:`~seqmotion.sim.control.JointSpaceController`'s differential IK every period on a standard arm), and the path
is held against the robot's rated speeds, rated accelerations where published, joint ranges and reach, and the
torques it needs (MuJoCo's inverse dynamics on the same model) against the model's torque limits. Nothing is
simulated (no object sliding, no controller): a 1.2 s plan is judged in well under a second.

The verdict also carries the map a planner needs to keep the limits (:attr:`SlidingExecutionCheck.pan_map
<seqmotion.tasks.sliding.SlidingExecutionCheck.pan_map>`): per sample, the joint speeds one metre per second of pan
velocity costs, ``q̇ ≈ M_k v_pan`` (the translational columns of the arm's Jacobian pseudo-inverse along the path,
the pan's attitude held), with the path, its pan motion and its inverse dynamics. ``planner.plan(command, robot=…)``
maps the rated joint speeds and accelerations, the torque limits and the joint ranges through it onto the pan's
velocity, acceleration and position (:class:`~seqmotion.tasks.sliding.PanJointLimits`).
"""

from __future__ import annotations

import numpy as np

from ..errors import check_number
from ..tasks.sliding import SlidingExecutionCheck
from .backend import CONTROL_DT, import_mujoco
from .executable import ACCEL_WINDOW, _joint_path, judge_joint_path
from .kinematics import pan_reference
from .robot_models import Robot, built_in_limits, resolve_robot
from .scene import Scene, get_scene

DECEL_TIME = 0.1
"""The run's stop after the plan [s] (:func:`~seqmotion.sim.sliding.run_sliding`'s ``decel_time``): judged too."""


def pan_states_of(states: object) -> np.ndarray:
    """The pan states ``(K, 4)`` of a sliding plan's states ``(K, 8)`` (``PLAN_LAYOUT``) or of pan states ``(K, 4)``."""
    arr = np.asarray(states, dtype=np.float64) if not isinstance(states, np.ndarray) else states.astype(np.float64)
    if arr.ndim != 2 or arr.shape[1] not in (4, 8):
        raise ValueError(f"states must be a sliding plan's (K, 8) states or its (K, 4) pan states [x, y, vx, vy], got "
                         f"shape {np.shape(states)}")
    if arr.shape[0] < 2:
        raise ValueError(f"states need K >= 2 samples, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("states hold NaN or inf")
    return arr[:, :4]


def pan_velocity_map(scene: Scene, q: np.ndarray) -> np.ndarray:
    """``(N, n, 2)`` [rad/m]: per configuration ``q[k]`` ``(N, n)``, the joint velocities per unit pan velocity along
    the pan's x and y (the pan site's translational Jacobian columns of the arm's pseudo-inverse, attitude held)."""
    mujoco = import_mujoco()
    m = scene.model
    data = mujoco.MjData(m)
    jac = np.zeros((6, m.nv))
    out = np.zeros((len(q), len(scene.arm_dof), 2))
    for k, qk in enumerate(q):
        data.qpos[scene.arm_qpos] = qk
        mujoco.mj_kinematics(m, data)
        mujoco.mj_comPos(m, data)
        mujoco.mj_jacSite(m, data, jac[:3], jac[3:], scene.site)
        j = jac[:, scene.arm_dof]
        # x, y of the pan (its plane) are the world's x, y (eq. 3.28): the columns for a unit twist along them.
        out[k] = j.T @ np.linalg.solve(j @ j.T + 1e-9 * np.eye(6), np.eye(6)[:, :2])
    return out


def check_sliding_executable(states: object, robot: str | Robot | None, dt: float = CONTROL_DT, *,
                             decel_time: float = DECEL_TIME) -> SlidingExecutionCheck:
    """Judge whether ``robot`` can execute a sliding plan's pan motion, from the joint path its IK gives.

    The joint path comes from the simulator's placement and IK for the pan command of
    :func:`~seqmotion.sim.sliding.run_sliding` (kinematics only), its stop included. Its speeds
    ``q̇[k] = (q[k+1] - q[k]) / dt`` are held against the rated speeds; its accelerations (differences of the speeds
    averaged over :data:`~seqmotion.sim.executable.ACCEL_WINDOW`, as for the pancake) against the rated accelerations
    where published; the torques they need (:func:`~seqmotion.sim.executable.path_dynamics`) against the model's
    torque limits; its positions against the joint ranges; the IK residual against
    :data:`~seqmotion.sim.arm.IK_TOLERANCE`.

    Args:
        states: a sliding plan's ``(K, 8)`` states (``plan.states``: pan then object) or its ``(K, 4)`` pan states
            ``[x_p, y_p, vx_p, vy_p]`` [m, m/s], K ≥ 2.
        robot: a robot's name (``"panda"``, ``"ur5e"``, …; :func:`~seqmotion.sim.robot_models.robots`), a
            :class:`~seqmotion.sim.robot_models.Robot`, or ``None`` / ``"mh3f"`` for the built-in arm (whose limits
            are unknown: the verdict is then ``None`` unless a pose is out of reach).
        dt: the states' sample period [s] (the simulator runs at 1 ms).
        decel_time: the constant deceleration to rest after the plan that the run adds [s] (0: judge the plan alone).

    Returns:
        A :class:`~seqmotion.tasks.sliding.SlidingExecutionCheck` (an
        :class:`~seqmotion.core.execution.ExecutionCheck`): ``ok``, the binding limit, the duration the same joint
        paths would need, and ``pan_map`` (the joint speeds per unit pan velocity along the path; ``None`` where the
        rated speeds are unknown). Times are from the plan's first sample; the stop's samples follow its last.

    Raises:
        ValueError: bad states, a ``dt`` or ``decel_time`` out of range, or an unknown robot.
    """
    pan = pan_states_of(states)
    check_number("dt [s]", dt, minimum=1e-6, maximum=1.0)
    check_number("decel_time [s]", decel_time, minimum=0.0, maximum=10.0)
    standard = resolve_robot(robot)
    scene = get_scene("sliding", standard)
    ref = pan_reference(pan, decel_time=decel_time, hold_time=0.0, dt=dt)
    q, residual = _joint_path(scene, ref.pos, ref.quat, dt)
    limits = built_in_limits() if standard is None else standard.limits
    fields, candidates, (qd, qdd, tau, mass) = judge_joint_path(scene, limits, q, residual, dt, (len(pan) - 1) * dt)
    check = SlidingExecutionCheck(
        **fields,
        rated_speed=None if limits.velocity is None else np.array(limits.velocity),
        rated_acceleration=None if limits.acceleration is None else np.array(limits.acceleration),
        torque_limit=None if limits.torque is None else np.array(limits.torque),
        range_ends=None if limits.position is None else np.array(limits.position), decel_time=float(decel_time),
        accel_window=int(max(1, min(round(ACCEL_WINDOW / dt), len(qd)))),
        worst_share={c.kind: c.share for c in candidates})
    if limits.velocity is not None:  # what a planner needs to keep them: derived data, not saved with a plan
        object.__setattr__(check, "pan_map", pan_velocity_map(scene, q))
        object.__setattr__(check, "joint_path", q)
        object.__setattr__(check, "pan_path", ref.pos[:, :2] - ref.pos[:1, :2] + pan[:1, :2])
        object.__setattr__(check, "pan_velocity", ref.vel[:, :2].copy())
        if tau is not None and mass is not None:  # τ = H q̈ + c along the path: c, H
            object.__setattr__(check, "torque_bias", tau - np.einsum("kij,kj->ki", mass, qdd))
            object.__setattr__(check, "mass_path", mass)
    return check


__all__ = ["DECEL_TIME", "check_sliding_executable", "pan_states_of", "pan_velocity_map"]
