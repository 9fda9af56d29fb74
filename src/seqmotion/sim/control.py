"""Task-space PD control with a disturbance observer at 1 ms (Figs. 3.6 and 4.7 of the dissertation).

One control period, top to bottom (:meth:`TaskSpaceController.torque`):

1. Measure the tool site's pose ``(p, R)`` and velocity ``(v, ω) = J q̇`` (``mj_jacSite``).
2. Task-space PD with acceleration feedforward, per axis of the 6-D pose:
   ``ẍ_ref = a_cmd + K_d (ẋ_cmd - ẋ) + K_p (x_cmd - x)``, where the attitude error is the
   rotation vector of ``R_cmd Rᵀ`` (world frame) — never a difference of Euler angles, which
   are singular at the commands' pitch of π/2.
3. Joint acceleration reference through the Jacobian: ``q̈_ref = J⁻¹ (ẍ_ref - J̇ q̇)``
   (``mj_jacDot``; a tiny damping keeps the solve finite near singular poses).
4. Disturbance observer (:class:`~seqmotion.sim.observers.DisturbanceObserver`) and torque
   through the mass matrix: ``τ = M(q) (q̈_ref + â_dis)``.

The observer works on the mass-normalised joint space: the plant ``M q̈ + h + τ_ext = τ`` seen
through ``c = M⁻¹ τ`` is ``q̈ = c - a_dis`` with ``a_dis = M⁻¹ (h + τ_ext)``, i.e. the observer's
plant ``J_n θ̈ = τ_ref - τ_dis`` with unit nominal inertia. It estimates gravity, Coriolis,
joint friction and the load together (``τ̂_dis = M â_dis`` in torque units) and cancels them
below its cutoff, so the arm behaves like ``q̈ = q̈_ref`` there — what the dissertation states
the DOB does ("forced the robot to follow the acceleration reference in a frequency range
lower than the cutoff", §4.4.1). ``model_bias=True`` instead feeds MuJoCo's gravity and
Coriolis torques forward (computed torque); the observer then sees only what the model
lacks. With neither, the controller is plain PD on a mass-matrix feedforward.

Gains (SPEC §§3–5) are named presets in :data:`GAINS`; ``Kp`` in 1/s², ``Kd`` in 1/s, both on
the 6 axes ``[x, y, z, rx, ry, rz]`` (position, then attitude).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import check_finite_array, check_number
from .ik import damped_least_squares
from .observers import DisturbanceObserver
from .scene import CONTROL_DT, PANCAKE_ORIGIN, Scene, import_mujoco


@dataclass(frozen=True)
class Gains:
    """Task-space PD gains and observer cutoff.

    Attributes:
        kp: ``(6,)`` proportional gains [1/s²] for x, y, z, then the three attitude axes.
        kd: ``(6,)`` derivative gains [1/s].
        dob_cutoff: observer bandwidth g [rad/s]; ``None`` disables the observer.
        name: a label for reports.
    """

    kp: tuple[float, ...]
    kd: tuple[float, ...]
    dob_cutoff: float | None = 4 * np.pi
    name: str = "custom"

    def __post_init__(self) -> None:
        kp = check_finite_array("gains' kp", self.kp, minimum=0.0, strict_minimum=True)
        kd = check_finite_array("gains' kd", self.kd, minimum=0.0)
        if kp.shape != (6,) or kd.shape != (6,):
            raise ValueError(f"gains need 6 positive kp and 6 non-negative kd, got kp={self.kp}, kd={self.kd}")
        if self.dob_cutoff is not None:
            check_number("dob_cutoff [rad/s] (None: no observer)", self.dob_cutoff, minimum=0.0, strict_minimum=True)


def _split(position: float, attitude: float) -> tuple[float, ...]:
    return (position,) * 3 + (attitude,) * 3


GAINS: dict[str, Gains] = {
    # §2.3.3: Kp 350 (position) / 600 (attitude), Kd 60 / 90, DOB cutoff 12.57 rad/s.
    "ch2": Gains(_split(350.0, 600.0), _split(60.0, 90.0), 12.57, "ch2"),
    # §3.5.1: Kp diag(800, 800, 800, 1000, 1000, 1000), Kd diag(100, ..., 150, ...). The text
    # gives no DOB cutoff; we use the 2 Hz (12.57 rad/s) of the other two experiments.
    "ch3": Gains(_split(800.0, 1000.0), _split(100.0, 150.0), 4 * np.pi, "ch3"),
    # §4.4.1: Kp 450 / 700, Kd 60 / 90, DOB cutoff 2.0 Hz.
    "ch4": Gains(_split(450.0, 700.0), _split(60.0, 90.0), 2 * np.pi * 2.0, "ch4"),
}
"""Named presets of the dissertation's experiments."""


def resolve_gains(gains: str | Gains) -> Gains:
    """A preset name (``"ch2"``, ``"ch3"``, ``"ch4"``) or a :class:`Gains` → :class:`Gains`."""
    if isinstance(gains, Gains):
        return gains
    if isinstance(gains, str) and gains in GAINS:
        return GAINS[gains]
    raise ValueError(f"gains must be one of {sorted(GAINS)} or a Gains object, got {gains!r}")


def static_disturbance(
    scene: Scene, data, dof: slice, load: np.ndarray | None = None, include_bias: bool = True
) -> np.ndarray:
    """What a disturbance observer on ``c = M⁻¹ τ`` converges to at rest: ``M⁻¹ (h - Jᵀ f)`` [rad/s²].

    Args:
        scene: the scene (model and tool site).
        data: MuJoCo data with current kinematics, mass matrix and bias forces.
        dof: the arm's dofs (a slice of the model's).
        load: ``(3,)`` force [N] the carried object exerts on the tool at the site (its weight,
            ``(0, 0, -m g)``), or ``None``.
        include_bias: include the gravity/Coriolis torque ``h`` (not when it is fed forward).

    Returns:
        ``(n,)`` for the arm's n joints.
    """
    mj, m = import_mujoco(), scene.model
    full = np.zeros(m.nv)
    if include_bias:
        full[dof] = data.qfrc_bias[dof]
    if load is not None:
        jac = np.zeros((6, m.nv))
        mj.mj_jacSite(m, data, jac[:3], jac[3:], scene.site)
        full[dof] -= jac[:3, dof].T @ np.asarray(load, dtype=np.float64)
    out = np.zeros(m.nv)
    mj.mj_solveM(m, data, out.reshape(1, -1), full.reshape(1, -1))
    return out[dof].copy()


class ToolController:
    """What both controllers share: the observer's start, and measuring the tool site every period.

    A subclass sets ``_mj``, ``scene``, ``_dof`` (the arm's dof slice), ``dob``, ``_jac`` ``(6, nv)``,
    ``_twist`` ``(6,)``, ``_err`` ``(6,)`` and ``_err_rot`` ``(3,)``.
    """

    def _start_observer(self, data, start: np.ndarray) -> None:
        """The observer (and the command it was told of) at ``start`` [rad/s²], at the measured velocity."""
        if self.dob is not None:
            self.dob.reset(data.qvel[self._dof], start)
        self._command = start.copy()
        self.disturbance = start.copy()

    def _measure(self, data, pos: np.ndarray, quat: np.ndarray) -> None:
        """The site's Jacobian, twist ``J q̇`` and pose error toward ``(pos, quat)``, into ``_jac``, ``_twist``,
        ``_err`` (needs the kinematics of ``data``)."""
        mj, m, site = self._mj, self.scene.model, self.scene.site
        mj.mj_jacSite(m, data, self._jac[:3], self._jac[3:], site)
        np.dot(self._jac, data.qvel, out=self._twist)
        np.subtract(pos, data.site_xpos[site], out=self._err[:3])
        quat_now = data.site_xquat[site]
        mj.mju_subQuat(self._err_rot, quat, quat_now)  # R_now · exp(e) = R_cmd, e in the site frame
        mj.mju_rotVecQuat(self._err[3:], self._err_rot, quat_now)  # → world frame

    @property
    def last_error(self) -> np.ndarray:
        """``(6,)`` pose error ``[p_cmd - p, rotvec(R_cmd Rᵀ)]`` of the latest :meth:`torque` call [m, rad]."""
        return self._err

    @property
    def last_twist(self) -> np.ndarray:
        """``(6,)`` measured tool ``[v, ω]`` of the latest :meth:`torque` call [m/s, rad/s]."""
        return self._twist

    def tool_twist(self, data) -> np.ndarray:
        """The site's world-frame ``[v, ω]`` ``(6,)`` [m/s, rad/s] (needs current kinematics)."""
        self._mj.mj_jacSite(self.scene.model, data, self._jac[:3], self._jac[3:], self.scene.site)
        return self._jac @ data.qvel


@dataclass
class TaskSpaceController(ToolController):
    """Task-space PD + disturbance observer for one scene (see the module docstring).

    Call :meth:`reset` with the MuJoCo data at the start pose, then :meth:`torque` once per
    control period after ``mj_step1`` (kinematics, mass matrix and velocities current).

    Attributes:
        scene: the scene whose arm and tool site are controlled.
        gains: PD gains and observer cutoff.
        model_bias: feed MuJoCo's gravity + Coriolis torque forward (computed torque).
        damping: Tikhonov damping of the Jacobian solve [m or rad]; only matters near
            singular poses (the Jacobian's singular values are ~0.1–1 in the workspace).
    """

    scene: Scene
    gains: Gains
    model_bias: bool = False
    damping: float = 1e-3
    dt: float = CONTROL_DT
    _buffers: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        self._mj = import_mujoco()
        m = self.scene.model
        dof = np.asarray(self.scene.arm_dof)
        if not np.array_equal(dof, np.arange(dof[0], dof[0] + 6)):
            raise ValueError("the arm's six dofs must be contiguous in the model")
        self._dof = slice(int(dof[0]), int(dof[0]) + 6)  # a slice: no copies in the 1 ms loop
        self._kp = np.asarray(self.gains.kp, dtype=np.float64)
        self._kd = np.asarray(self.gains.kd, dtype=np.float64)
        self._body = int(m.site_bodyid[self.scene.site])
        # Work buffers, reused every period (the loop runs 1000 times per simulated second).
        self._jac = np.zeros((6, m.nv))
        self._jacdot = np.zeros((6, m.nv))
        self._twist = np.zeros(6)
        self._err = np.zeros(6)
        self._err_rot = np.zeros(3)
        self._rhs = np.zeros(6)
        self._y = np.zeros(6)
        self._jjt = np.zeros((6, 6))
        self._full = np.zeros(m.nv)
        self._mc = np.zeros(m.nv)
        self._damp = np.eye(6) * self.damping**2
        self.dob = (
            DisturbanceObserver(np.ones(6), self.gains.dob_cutoff, self.dt) if self.gains.dob_cutoff else None
        )
        self._command = np.zeros(6)  # c = q̈_ref + â applied during the last period [rad/s²]
        self.disturbance = np.zeros(6)  # latest â_dis [rad/s²]

    def static_disturbance(self, data, load: np.ndarray | None = None, include_bias: bool = True) -> np.ndarray:
        """What the observer converges to at rest here: ``M⁻¹ (h - Jᵀ f)`` [rad/s²].

        Args:
            data: MuJoCo data with current kinematics, mass matrix and bias forces.
            load: ``(3,)`` force [N] the carried object exerts on the tool at the site (its
                weight, ``(0, 0, -m g)``), or ``None``.
            include_bias: include the gravity/Coriolis torque ``h`` (not when it is fed forward).
        """
        return static_disturbance(self.scene, data, self._dof, load, include_bias)

    def reset(self, data, load: np.ndarray | None = None) -> None:
        """Start at rest at the current pose, the observer at the static disturbance.

        ``data`` must have current kinematics, mass matrix and bias forces (``mj_forward``);
        ``load`` as in :meth:`static_disturbance` (without it the arm sags by about a
        millimetre while the observer learns the object's weight).
        """
        self._start_observer(data, self.static_disturbance(data, load, include_bias=not self.model_bias))

    def torque(
        self,
        data,
        pos: np.ndarray,
        quat: np.ndarray,
        twist: np.ndarray,
        accel: np.ndarray,
    ) -> np.ndarray:
        """Joint torques ``(6,)`` [N m] for one period toward the commanded tool state.

        Args:
            data: ``mujoco.MjData`` after ``mj_step1`` (or ``mj_forward``).
            pos: ``(3,)`` commanded site position [m].
            quat: ``(4,)`` commanded attitude ``[w, x, y, z]``.
            twist: ``(6,)`` commanded ``[v, ω]`` [m/s, rad/s] (world frame).
            accel: ``(6,)`` fed-forward ``[a, α]`` [m/s², rad/s²] (world frame).
        """
        mj, m, site, dof = self._mj, self.scene.model, self.scene.site, self._dof
        qvel = data.qvel

        # 1. Observer: update with the command applied during the last period and the velocity now.
        if self.dob is not None:
            self.disturbance = self.dob.update(self._command, qvel[dof])

        # 2. Measure the tool; PD with feedforward gives the task-space acceleration reference.
        self._measure(data, pos, quat)
        xdd_ref = accel + self._kd * (twist - self._twist) + self._kp * self._err

        # 3. Through the Jacobian: J q̈ = ẍ_ref - J̇ q̇, solved as q̈ = Jᵀ (J Jᵀ + λ²I)⁻¹ (…).
        mj.mj_jacDot(m, data, self._jacdot[:3], self._jacdot[3:], data.site_xpos[site], self._body)
        np.subtract(xdd_ref, self._jacdot @ qvel, out=self._rhs)
        jac = self._jac[:, dof]
        np.dot(jac, jac.T, out=self._jjt)
        self._jjt += self._damp
        mj.mju_cholFactor(self._jjt, 0.0)
        mj.mju_cholSolve(self._y, self._jjt, self._rhs)
        qdd_ref = jac.T @ self._y

        # 4. Compensate the estimated disturbance; map to torques through the mass matrix.
        command = qdd_ref + self.disturbance if self.dob is not None else qdd_ref
        self._full[dof] = command
        mj.mj_mulM(m, data, self._mc, self._full)  # arm rows = M_arm c (the objects are separate trees)
        tau = self._mc[dof].copy()
        if self.model_bias:
            tau += data.qfrc_bias[dof]
        self._command = command
        return tau


POSTURE_COST = 1e-3
"""Weight of the joint posture relative to the tool pose in the differential IK (redundant arms:
a 7-DoF arm keeps its elbow near the start posture instead of drifting in the null space)."""
JOINT_GAINS = (1600.0, 80.0)
"""Joint-space PD gains ``(K_p [1/s²], K_d [1/s])`` of :class:`JointSpaceController`: 40 rad/s, critically
damped. The dissertation's presets are gains of its arm's task-space loop; held on the joints of a standard arm
(350 / 60 for ch. 2) they left the spatula's roll 2° behind at the motions' 17 rad/s, and the UR5e kept the
pancake in 22 of 24 motions (seed 7, not a benchmark set) against 24 with these (attitude RMSE 2.1° → 1.1°,
position 2.9 → 1.6 mm; 2500 / 100 gave the same 24)."""
IK_SOLVER = "daqp"
"""The QP solver mink hands the differential IK to (installed with mink ≥ 1.0)."""


class JointSpaceController(ToolController):
    """Differential IK at every period, then joint-space PD + disturbance observer, for a standard arm.

    One control period (:meth:`torque`, same arguments as :meth:`TaskSpaceController.torque`):

    1. **Differential IK** (mink): a reference configuration ``q_ref`` follows the commanded tool pose
       — ``solve_ik`` gives the joint velocity that moves the tool site onto this period's command
       within the joint position limits (``ConfigurationLimit``), a small posture task settles the
       null space of a redundant arm — and is integrated over the period. The published joint speed
       limits are judged, not enforced, by default (:class:`~seqmotion.sim.arm.JointReport` names the
       joint furthest over its limit): the pancake motions turn the spatula at up to ~25 rad/s about
       its own axis, several times what a Panda's or a UR5e's wrist is rated for, and an IK held to
       the rating lags the command by decimetres, so the run would judge the lag instead of the motion.
       ``enforce_velocity_limits=True`` adds mink's ``VelocityLimit``. ``ik_error`` is how far
       ``q_ref``'s tool is from the command it was solved for (large only where the limits or the reach
       forbid the pose).
    2. **Feedforward** through ``q_ref``'s Jacobian: ``q̇_ff = J⁺ ẋ_cmd``, ``q̈_ff = J⁺ (ẍ_cmd − J̇ q̇_ff)``
       (``mj_jacDot`` at ``q_ref`` moving at ``q̇_ff``).
    3. **Joint PD + DOB**: ``q̈_ref = q̈_ff + K_d (q̇_ff − q̇) + K_p (q_ref − q)``, ``τ = M(q) (q̈_ref + â_dis)``
       with the observer of :class:`TaskSpaceController` (unit nominal inertia on ``M⁻¹ τ``; its cutoff is the
       preset's), on the real model's inertias. ``K_p``, ``K_d``: :data:`JOINT_GAINS` on every joint.
    4. **Saturation** at the model's torque limits; the observer is told the torque actually applied
       (``c = M⁻¹ τ_sat``), so a saturated period is not mistaken for a disturbance.

    Attributes:
        ik_error: ``(2,)`` position [m] and attitude [rad] residual of the IK reference at the
            latest period.
        saturated: whether the latest torque hit a limit.
        q_ref: ``(n,)`` the IK reference configuration of the arm [rad].
    """

    def __init__(self, scene: Scene, gains: Gains, *, model_bias: bool = False, dt: float = CONTROL_DT,
                 enforce_velocity_limits: bool = False, joint_gains: tuple[float, float] = JOINT_GAINS) -> None:
        try:
            import mink
        except ImportError as err:  # pragma: no cover - the robots extra is missing
            raise ImportError("standard robot arms need mink: pip install 'seqmotion[robots]'") from err
        robot = scene.robot
        if robot is None:
            raise ValueError("JointSpaceController drives a standard robot scene (build_scene(kind, robot=...))")
        self._mj, self._mink = import_mujoco(), mink
        self.scene, self.gains, self.model_bias, self.dt = scene, gains, model_bias, dt
        m = scene.model
        dof = np.asarray(scene.arm_dof)
        n = dof.size
        if not np.array_equal(dof, np.arange(dof[0], dof[0] + n)):
            raise ValueError("the arm's dofs must be contiguous in the model")
        self._dof = slice(int(dof[0]), int(dof[0]) + n)
        self._qpos = np.asarray(scene.arm_qpos)
        self._kp, self._kd = float(joint_gains[0]), float(joint_gains[1])
        if not (self._kp > 0 and self._kd >= 0):
            raise ValueError(f"joint_gains must be (positive K_p, non-negative K_d), got {joint_gains}")
        self.torque_limit = np.asarray(robot.torque_limit, dtype=np.float64)
        self.config = mink.Configuration(m)
        site_name = m.site(scene.site).name
        self._frame = mink.FrameTask(site_name, "site", position_cost=1.0, orientation_cost=1.0, lm_damping=1e-6)
        cost = np.zeros(m.nv)
        cost[self._dof] = POSTURE_COST
        self._posture = mink.PostureTask(m, cost=cost)
        names = [m.joint(int(m.dof_jntid[i])).name for i in dof]
        limits = [mink.ConfigurationLimit(m)]
        if enforce_velocity_limits and robot.velocity_limit is not None:
            speeds = dict(zip(names, np.asarray(robot.velocity_limit, dtype=float).tolist(), strict=True))
            limits.append(mink.VelocityLimit(m, speeds))
        self._limits = limits
        self._jac = np.zeros((6, m.nv))
        self._jac_ref = np.zeros((6, m.nv))
        self._jacdot = np.zeros((6, m.nv))
        self._body = int(m.site_bodyid[scene.site])
        self._twist = np.zeros(6)
        self._err = np.zeros(6)
        self._err_rot = np.zeros(3)
        self._full = np.zeros(m.nv)
        self._mc = np.zeros(m.nv)
        self._damp = np.eye(6) * 1e-6
        self.dob = DisturbanceObserver(np.ones(n), gains.dob_cutoff, dt) if gains.dob_cutoff else None
        self._command = np.zeros(n)
        self.disturbance = np.zeros(n)
        self._q_ref_full = np.zeros(m.nq)
        self.ik_error = np.zeros(2)
        self.saturated = False
        self.ik_seconds, self.periods = 0.0, 0  # wall time spent in the differential IK, over this many periods
        self._chain = None
        if scene.kind == "pancake":  # an arm placed to turn the spatula with parallel joints follows them exactly
            from .planar_chain import planar_chain

            self._chain = planar_chain(robot)
        self._rot = np.zeros(9)

    @property
    def q_ref(self) -> np.ndarray:
        return self._q_ref_full[self._qpos]

    def reset(self, data, load: np.ndarray | None = None) -> None:
        """Start at rest at the current pose: ``q_ref`` = the measured configuration, the posture task's target
        there, the observer at the static disturbance of ``load`` (as :meth:`TaskSpaceController.reset`)."""
        self._q_ref_full[:] = data.qpos
        self.config.update(self._q_ref_full)
        self._posture.set_target(self._q_ref_full.copy())
        self._start_observer(data, static_disturbance(self.scene, data, self._dof, load,
                                                      include_bias=not self.model_bias))

    def follow(self, pos: np.ndarray, quat: np.ndarray) -> Any:
        """Step 1 alone: move ``q_ref`` one period of differential IK toward the tool pose ``pos`` ``(3,)`` [m],
        ``quat`` ``(4,)``, and set :attr:`ik_error`. Returns the ``MjData`` holding ``q_ref``'s kinematics.

        The run's torque loop and the kinematic check of a motion
        (:func:`seqmotion.sim.executable.check_executable`) both call it, so both judge the same joint path.
        """
        # The configuration holds the kinematics of the previous period's q_ref; solve from there, then update it.
        mj, m, site, cfg = self._mj, self.scene.model, self.scene.site, self.config
        started = time.perf_counter()
        target = np.concatenate([quat, pos])
        chain_q = None if self._chain is None else self._chain_reference(pos, quat)
        if chain_q is not None:
            self._q_ref_full[self._qpos] = chain_q
        else:
            self._frame.set_target(self._mink.SE3(wxyz_xyz=target))
            v = self._mink.solve_ik(cfg, [self._frame, self._posture], self.dt, IK_SOLVER, damping=1e-9,
                                    limits=self._limits)
            mj.mj_integratePos(m, self._q_ref_full, v, self.dt)
        cfg.update(self._q_ref_full)
        self.ik_seconds += time.perf_counter() - started
        self.periods += 1
        ref_data = cfg.data
        self.ik_error = _pose_error(mj, target, ref_data.site_xpos[site], ref_data.site_xquat[site])
        return ref_data

    def _chain_reference(self, pos: np.ndarray, quat: np.ndarray) -> np.ndarray | None:
        """The arm's posture for a planar spatula pose by the planar chain's closed-form IK
        (:func:`~seqmotion.sim.planar_chain.chain_joints`: the joint path the polish planned, every other joint at
        home), continuous with the previous ``q_ref``; ``None`` for a pose off the task plane (then mink's IK)."""
        from .planar_chain import chain_joints

        chain = self._chain
        self._mj.mju_quat2Mat(self._rot, np.asarray(quat, dtype=np.float64))
        turn = self._rot.reshape(3, 3) @ np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # · Ry(π/2)ᵀ
        if abs(pos[0] - PANCAKE_ORIGIN[0]) > 1e-9 or abs(turn[0, 0] - 1.0) > 1e-9:
            return None
        theta = float(np.arctan2(turn[2, 1], turn[1, 1]))
        q = chain.home.copy()
        planned = chain_joints(chain, np.array([[pos[1] - PANCAKE_ORIGIN[1], pos[2] - PANCAKE_ORIGIN[2], theta,
                                                 0.0, 0.0, 0.0]]))[0, :3]
        index = list(chain.index)
        previous = self._q_ref_full[self._qpos][index]
        q[index] = previous + np.remainder(planned - previous + np.pi, 2 * np.pi) - np.pi  # the nearest turn
        return q

    def torque(self, data, pos: np.ndarray, quat: np.ndarray, twist: np.ndarray, accel: np.ndarray) -> np.ndarray:
        """Joint torques ``(n,)`` [N m] for one period toward the commanded tool state (see the class docstring)."""
        mj, m, site, dof = self._mj, self.scene.model, self.scene.site, self._dof
        qvel = data.qvel
        if self.dob is not None:
            self.disturbance = self.dob.update(self._command, qvel[dof])

        self._measure(data, pos, quat)  # the tool as the run logs and judges it

        # 1. Differential IK of the reference configuration onto this period's command.
        ref_data = self.follow(pos, quat)

        # 2. Feedforward through the reference's Jacobian: q̇_ff = J⁺ ẋ, q̈_ff = J⁺ (ẍ − J̇ q̇_ff).
        mj.mj_jacSite(m, ref_data, self._jac_ref[:3], self._jac_ref[3:], site)
        jac = self._jac_ref[:, dof]
        jjt = jac @ jac.T + self._damp
        qd_ff = jac.T @ np.linalg.solve(jjt, twist)
        ref_data.qvel[:] = 0.0
        ref_data.qvel[dof] = qd_ff
        mj.mj_comVel(m, ref_data)
        mj.mj_jacDot(m, ref_data, self._jacdot[:3], self._jacdot[3:], ref_data.site_xpos[site], self._body)
        qdd_ff = jac.T @ np.linalg.solve(jjt, accel - self._jacdot[:, dof] @ qd_ff)

        # 3. Joint-space PD + observer, through the mass matrix.
        q = data.qpos[self._qpos]
        qdd_ref = qdd_ff + self._kd * (qd_ff - qvel[dof]) + self._kp * (self._q_ref_full[self._qpos] - q)
        command = qdd_ref + self.disturbance if self.dob is not None else qdd_ref
        self._full[:] = 0.0
        self._full[dof] = command
        mj.mj_mulM(m, data, self._mc, self._full)
        tau = self._mc[dof].copy()
        if self.model_bias:
            tau += data.qfrc_bias[dof]

        # 4. Saturate at the model's limits; the observer sees the torque applied.
        limit = self.torque_limit
        self.saturated = bool(np.any(np.abs(tau) > limit))
        if self.saturated:
            tau = np.clip(tau, -limit, limit)
            self._full[:] = 0.0
            self._full[dof] = tau - data.qfrc_bias[dof] if self.model_bias else tau
            out = np.zeros(m.nv)
            mj.mj_solveM(m, data, out.reshape(1, -1), self._full.reshape(1, -1))
            command = out[dof]
        self._command = command
        return tau


def _pose_error(mj, target: np.ndarray, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """``(2,)`` position [m] and attitude [rad] distance of ``(pos, quat)`` from ``target = [quat, pos]``."""
    rot = np.zeros(3)
    mj.mju_subQuat(rot, target[:4], quat)
    return np.array([np.linalg.norm(target[4:] - pos), np.linalg.norm(rot)])


def make_controller(
    scene: Scene, gains: Gains, *, model_bias: bool = False
) -> TaskSpaceController | JointSpaceController:
    """The scene's controller: task space on the built-in arm, differential IK + joint space on a standard arm."""
    if getattr(scene, "robot", None) is None:
        return TaskSpaceController(scene, gains, model_bias=model_bias)
    return JointSpaceController(scene, gains, model_bias=model_bias)


def solve_ik(
    scene: Scene,
    pos: np.ndarray,
    quat: np.ndarray,
    seed: np.ndarray | None = None,
    *,
    iterations: int = 300,
    tolerance: float = 1e-9,
) -> np.ndarray:
    """Joint angles ``(6,)`` that put the tool site at ``pos`` [m] with attitude ``quat``.

    Damped Gauss–Newton (:func:`~seqmotion.sim.ik.damped_least_squares`, at most 0.5 rad per iteration) from
    ``seed`` (default: elbow up, wrist bent down by ~1 rad, the branch every scene starts in; a standard arm's
    home). Raises ``ValueError`` if the pose is out of reach.
    """
    mujoco = import_mujoco()
    m = scene.model
    if seed is None:
        robot = getattr(scene, "robot", None)
        seed = DEFAULT_SEED if robot is None else robot.home
    q, err = damped_least_squares(m, mujoco.MjData(m), scene.site, scene.arm_qpos, scene.arm_dof, pos, quat, seed,
                                  iterations=iterations, tolerance=tolerance)
    if np.linalg.norm(err) > 1e-6:
        raise ValueError(f"tool pose {np.round(pos, 3).tolist()} is out of the arm's reach (residual {err})")
    return q


DEFAULT_SEED = np.array([0.0, 0.5, 0.5, 0.0, -1.0, 0.0])
"""Elbow-up, wrist-down joint angles near both tools' home poses [rad]."""
