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

from dataclasses import dataclass, field

import numpy as np

from .observers import DisturbanceObserver
from .scene import CONTROL_DT, Scene, import_mujoco


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
        kp, kd = np.asarray(self.kp, dtype=np.float64), np.asarray(self.kd, dtype=np.float64)
        if kp.shape != (6,) or kd.shape != (6,) or np.any(kp <= 0) or np.any(kd < 0):
            raise ValueError(f"gains need 6 positive kp and 6 non-negative kd, got kp={self.kp}, kd={self.kd}")
        if self.dob_cutoff is not None and not self.dob_cutoff > 0:
            raise ValueError(f"dob_cutoff must be positive or None, got {self.dob_cutoff}")


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


@dataclass
class TaskSpaceController:
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
        m = self.scene.model
        self._full[:] = 0.0
        if include_bias:
            self._full[self._dof] = data.qfrc_bias[self._dof]
        if load is not None:
            self._mj.mj_jacSite(m, data, self._jac[:3], self._jac[3:], self.scene.site)
            self._full[self._dof] -= self._jac[:3, self._dof].T @ np.asarray(load, dtype=np.float64)
        out = np.zeros(m.nv)
        self._mj.mj_solveM(m, data, out.reshape(1, -1), self._full.reshape(1, -1))
        self._full[:] = 0.0
        return out[self._dof].copy()

    def reset(self, data, load: np.ndarray | None = None) -> None:
        """Start at rest at the current pose, the observer at the static disturbance.

        ``data`` must have current kinematics, mass matrix and bias forces (``mj_forward``);
        ``load`` as in :meth:`static_disturbance` (without it the arm sags by about a
        millimetre while the observer learns the object's weight).
        """
        start = self.static_disturbance(data, load, include_bias=not self.model_bias)
        if self.dob is not None:
            self.dob.reset(data.qvel[self._dof], start)
        self._command = start.copy()
        self.disturbance = start.copy()

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
        mj.mj_jacSite(m, data, self._jac[:3], self._jac[3:], site)
        np.dot(self._jac, qvel, out=self._twist)
        np.subtract(pos, data.site_xpos[site], out=self._err[:3])
        quat_now = data.site_xquat[site]
        mj.mju_subQuat(self._err_rot, quat, quat_now)  # R_now · exp(e) = R_cmd, e in the site frame
        mj.mju_rotVecQuat(self._err[3:], self._err_rot, quat_now)  # → world frame
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

    Damped Gauss–Newton from ``seed`` (default: elbow up, wrist bent down by ~1 rad, the
    branch every scene starts in). Raises ``ValueError`` if the pose is out of reach.
    """
    mujoco = import_mujoco()
    m = scene.model
    data = mujoco.MjData(m)
    q = np.array(DEFAULT_SEED if seed is None else seed, dtype=np.float64)
    jac = np.zeros((6, m.nv))
    err_rot = np.zeros(3)
    err = np.full(6, np.inf)
    for _ in range(iterations):
        data.qpos[scene.arm_qpos] = q
        mujoco.mj_kinematics(m, data)
        mujoco.mj_comPos(m, data)
        site = scene.site
        mujoco.mju_subQuat(err_rot, quat, data.site_xquat[site])
        err = np.concatenate([pos - data.site_xpos[site], data.site_xmat[site].reshape(3, 3) @ err_rot])
        if np.linalg.norm(err) < tolerance:
            break
        mujoco.mj_jacSite(m, data, jac[:3], jac[3:], site)
        j = jac[:, scene.arm_dof]
        step = j.T @ np.linalg.solve(j @ j.T + 1e-6 * np.eye(6), err)
        q += step * min(1.0, 0.5 / max(np.abs(step).max(), 1e-12))  # at most 0.5 rad per iteration
    if np.linalg.norm(err) > 1e-6:
        raise ValueError(f"tool pose {np.round(pos, 3).tolist()} is out of the arm's reach (residual {err})")
    return q


DEFAULT_SEED = np.array([0.0, 0.5, 0.5, 0.0, -1.0, 0.0])
"""Elbow-up, wrist-down joint angles near both tools' home poses [rad]."""
