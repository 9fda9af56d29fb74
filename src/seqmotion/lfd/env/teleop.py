"""Four-channel bilateral control at 1 ms (dissertation 5.3.2, Fig. 5.6, Table 5.1).

Each arm (master and slave) has an :class:`ArmServo`: the encoder angle θ, a velocity θ̇
from the 10 Hz pseudo-derivative, a disturbance observer (DOB) that makes the joint behave
like its nominal inertia ``J_n``, and a reaction-torque observer (RTOB) that estimates τ,
the torque the arm exerts on its surroundings (the hand on the master, the block on the
slave). Sign: with the plant written ``J_n θ̈ = τ_ref − τ_dis``, τ = τ_dis − (modelled
gravity and friction) = − (external torque acting on the joint). A hand turning the
master's joint in its positive direction therefore reads negative on the master, and the
slave pressing on the block in the same direction reads positive: in steady contact
``τ_m + τ_s ≈ 0`` (action = reaction).

Control law per joint (acceleration-based 4-channel bilateral control, Sakaino/Tsuji group;
position law on the difference, force law on the sum)::

    τ_m^ref = −(J_n/2)[K_p (θ_m − θ_s) + K_d (θ̇_m − θ̇_s)] − (K_f/2)(τ_m + τ_s) + τ̂_dis,m
    τ_s^ref = +(J_n/2)[K_p (θ_m − θ_s) + K_d (θ̇_m − θ̇_s)] − (K_f/2)(τ_m + τ_s) + τ̂_dis,s

The DOB cancels every low-frequency torque on the joint (gravity, friction and the hand or
the block); the ``K_f`` term puts the measured external torques back in the common mode, so
the operator moves a virtual inertia ``2 J_n / K_f`` (= 4 J_n) shared with the slave and feels
what the slave touches. ``K_p`` [1/s²] and ``K_d`` [1/s] are acceleration gains; ``K_f`` is
dimensionless (torque to torque).

With a learned policy in the master's place (Fig. 5.7) the slave keeps exactly its half of
the law, with the policy's (θ, θ̇, τ) standing in for the master's, refreshed every 20 ms
(:class:`TouchSlave`, driven by :func:`seqmotion.lfd.rollout.rollout`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...errors import check_number
from ...sim.observers import DisturbanceObserver, PseudoDerivative, ReactionTorqueObserver
from ..timing import COMMAND_INTERVAL
from . import pushing
from .pushing import ArmSim, BlockPosition, MasterArm, PushingScene, SceneVariation
from .state import ArmState


@dataclass(frozen=True)
class BilateralGains:
    """Control parameters of Table 5.1.

    Attributes:
        kp: position gain K_p [1/s²].
        kd: velocity gain K_d [1/s].
        kf: force gain K_f [-].
        cutoff_hz: cutoff g of the pseudo-derivative, DOB and RTOB filters [Hz].
        dt: control period Δt [s].
    """

    kp: float = 120.0
    kd: float = 10.0
    kf: float = 0.5
    cutoff_hz: float = 10.0
    dt: float = pushing.DT

    def __post_init__(self) -> None:
        for name in ("kp", "kd", "kf"):
            check_number(f"BilateralGains.{name}", getattr(self, name), minimum=0.0)
        for name in ("cutoff_hz", "dt"):
            check_number(f"BilateralGains.{name}", getattr(self, name), minimum=0.0, strict_minimum=True)

    @property
    def cutoff(self) -> float:
        """Filter cutoff g [rad/s]."""
        return 2.0 * math.pi * self.cutoff_hz


class ArmServo:
    """Sensing and torque interface of one arm: pseudo-derivative, DOB and RTOB at ``dt``.

    Call :meth:`sense` once per period (before computing the control), then :meth:`actuate`
    with the control torque; the servo adds the DOB compensation, saturates, remembers the
    torque for the observers' next update and returns it for the simulator.
    """

    def __init__(self, sim: ArmSim, gains: BilateralGains) -> None:
        self.sim, self.gains = sim, gains
        self.nominal_inertia = sim.nominal_inertia
        self._limit = np.asarray(sim.arm.torque_limit)
        self._damping = np.asarray(sim.arm.damping)
        self._coulomb = np.asarray(sim.arm.frictionloss)
        self.velocity_filter = PseudoDerivative(gains.cutoff, gains.dt, sim.q)
        self.dob = DisturbanceObserver(self.nominal_inertia, gains.cutoff, gains.dt)
        self.rtob = ReactionTorqueObserver(self.nominal_inertia, gains.cutoff, gains.dt)
        self.reset()

    def reset(self) -> None:
        """Start at rest in the current pose, as if the arm had been held there for a while.

        The observers are pre-charged with the holding torque (gravity), so the arm does
        not sag while they converge; the RTOB then starts at zero external torque.
        """
        q = self.sim.q
        self.velocity_filter.reset(q)
        hold = -pushing.gravity_torque(q, self.sim.arm)
        self.dob.reset(0.0)
        self.rtob.reset(0.0)
        zero = np.zeros(pushing.N_JOINTS)
        for _ in range(int(10.0 / (self.gains.cutoff * self.gains.dt))):  # 10 time constants
            self.dob.update(hold, zero)
            self.rtob.update_reaction(hold, zero, hold)
        self.torque_reference = hold
        self.state = ArmState(q, zero.copy(), self.rtob.estimate.copy())

    def internal_torque(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Modelled internal torque [N m] in the DOB's sign: −gravity + viscous + smoothed Coulomb friction."""
        return -pushing.gravity_torque(q, self.sim.arm) + self._damping * dq + self._coulomb * np.tanh(dq / 0.02)

    def sense(self) -> ArmState:
        """Read the encoders, update θ̇, τ̂_dis and τ with last period's torque; return the state."""
        q = self.sim.q
        dq = self.velocity_filter.update(q)
        self.dob.update(self.torque_reference, dq)
        tau = self.rtob.update_reaction(self.torque_reference, dq, self.internal_torque(q, dq))
        self.state = ArmState(q, dq, tau.copy())
        return self.state

    def actuate(self, control_torque: np.ndarray) -> np.ndarray:
        """Torque reference = control + τ̂_dis, saturated at the motor limits [N m] ``(3,)``."""
        self.torque_reference = np.clip(control_torque + self.dob.estimate, -self._limit, self._limit)
        return self.torque_reference


def bilateral_torques(
    master: ArmState, slave: ArmState, nominal_inertia: np.ndarray, gains: BilateralGains
) -> tuple[np.ndarray, np.ndarray]:
    """Control torques ``(τ_m, τ_s)`` [N m] of the 4-channel law (before DOB compensation)."""
    position = 0.5 * nominal_inertia * (
        gains.kp * (master.theta - slave.theta) + gains.kd * (master.dtheta - slave.dtheta)
    )
    force = 0.5 * gains.kf * (master.tau + slave.tau)
    return -position - force, position - force


def slave_torque(command: ArmState, slave: ArmState, nominal_inertia: np.ndarray, gains: BilateralGains) -> np.ndarray:
    """The slave's half of the law with a master *command* (e.g. a policy's output) [N m] ``(3,)``."""
    return bilateral_torques(command, slave, nominal_inertia, gains)[1]


# ----------------------------------------------------------------------------------------------
# Episode records
# ----------------------------------------------------------------------------------------------
@dataclass
class Demonstration:
    """One teleoperated episode sampled every ``dt`` (K samples, sample k at time ``k dt``).

    Arrays (float64): ``master_theta/dtheta/tau`` and ``slave_theta/dtheta/tau`` ``(K, 3)``
    [rad, rad/s, N m]; ``block_pose`` ``(K, 7)`` (centre [m], quaternion w x y z);
    ``hand_force`` ``(K, 3)`` [N], the operator's force on the master tip; ``master_tip`` and
    ``slave_tip`` ``(K, 3)`` [m]; ``phase`` ``(K,)`` int, the operator's phase code
    (see :data:`seqmotion.lfd.env.operator.PHASES`).
    """

    position: BlockPosition
    dt: float
    master_theta: np.ndarray
    master_dtheta: np.ndarray
    master_tau: np.ndarray
    slave_theta: np.ndarray
    slave_dtheta: np.ndarray
    slave_tau: np.ndarray
    block_pose: np.ndarray
    hand_force: np.ndarray
    master_tip: np.ndarray
    slave_tip: np.ndarray
    phase: np.ndarray
    success: bool
    crossed_time: float
    n_pushes: int
    variation: SceneVariation = field(default_factory=SceneVariation)
    operator: dict[str, float] = field(default_factory=dict)
    image: np.ndarray | None = None
    camera: str | None = None
    video: np.ndarray | None = None

    @property
    def length(self) -> int:
        return len(self.master_theta)

    def motion(self, every: int = 1) -> np.ndarray:
        """``(K', 18)`` master θ, θ̇, τ then slave θ, θ̇, τ, keeping every ``every``-th sample."""
        return motion_matrix(
            self.master_theta, self.master_dtheta, self.master_tau, self.slave_theta, self.slave_dtheta, self.slave_tau
        )[::every]


MOTION_COLUMNS = tuple(
    f"{side}_{var}_{j}" for side in ("master", "slave") for var in ("theta", "dtheta", "tau") for j in range(3)
)
"""Column names of :func:`motion_matrix` (18 columns)."""


def motion_matrix(*parts: np.ndarray) -> np.ndarray:
    """Concatenate ``(..., K, 3)`` arrays along the last axis (the order of :data:`MOTION_COLUMNS`)."""
    return np.concatenate(parts, axis=-1)


class _Recorder:
    """Preallocated per-sample buffers (cheaper than growing lists at 1 kHz)."""

    def __init__(self, steps: int, widths: dict[str, int]) -> None:
        self.buffers = {name: np.zeros((steps, w)) if w > 1 else np.zeros(steps) for name, w in widths.items()}

    def __getitem__(self, name: str) -> np.ndarray:
        return self.buffers[name]


def check_duration(duration: float, dt: float) -> int:
    steps = round(check_number("duration [s]", duration, minimum=0.0, strict_minimum=True) / dt)
    if steps < 2:
        raise ValueError(f"duration {duration} s is shorter than two control periods ({dt} s)")
    return steps


def _check_timestep(gains: BilateralGains, *sims: ArmSim) -> None:
    for sim in sims:
        if abs(sim.model.opt.timestep - gains.dt) > 1e-12:
            raise ValueError(f"gains.dt = {gains.dt} s but the simulation steps {sim.model.opt.timestep} s")


# ----------------------------------------------------------------------------------------------
# Loops
# ----------------------------------------------------------------------------------------------
class Operator:
    """What the teleoperation loop needs from an operator (see :class:`~seqmotion.lfd.env.operator.ScriptedOperator`).

    ``hand_force`` is called once per period with the master's tip position and velocity
    (what the hand feels), the slave's tip and the block pose (what the operator sees), and
    returns the force ``(3,)`` [N] the hand applies to the master's tip.
    """

    def reset(self, tip: np.ndarray, block_pose: np.ndarray, position: BlockPosition) -> None:  # pragma: no cover
        raise NotImplementedError

    def hand_force(
        self, tip: np.ndarray, tip_velocity: np.ndarray, slave_tip: np.ndarray, block_pose: np.ndarray
    ) -> np.ndarray:
        raise NotImplementedError  # pragma: no cover

    phase: int = 0
    n_pushes: int = 0

    def describe(self) -> dict[str, float]:
        return {}


def teleoperate(
    scene: PushingScene,
    master: MasterArm,
    operator: Operator,
    position: BlockPosition,
    duration: float = 4.0,
    variation: SceneVariation | None = None,
    camera: str | None = None,
    gains: BilateralGains | None = None,
    video_every: int = 0,
) -> Demonstration:
    """Run one demonstration: the operator's hand drives the master, the slave pushes the block.

    Args:
        scene: the slave world (reset here).
        master: the master arm (reset here to the same default pose).
        operator: the hand model; it sees the slave-side block through ``scene.block_pose``.
        position: where the block is placed.
        duration: recorded length [s]; ``round(duration / dt)`` samples.
        variation: block placement / lighting / colour variation (none if omitted).
        camera: if given, one 64×64 image from this camera is taken before the motion.
        gains: bilateral control parameters (Table 5.1 if omitted).
        video_every: with ``camera``, also film the episode: one image every ``video_every``
            samples from sample 0 (20 at 1 ms: the 50 fps a LeRobot policy such as ACT reads), in
            ``demo.video`` ``(ceil(K / video_every), 64, 64, 3)`` uint8.

    Returns:
        The recorded :class:`Demonstration` (success = block centre across the centre line at the end).
    """
    gains = gains or BilateralGains()
    steps = check_duration(duration, gains.dt)
    _check_timestep(gains, scene, master)
    variation = variation or SceneVariation()
    scene.reset(position, variation)
    master.reset()
    image = scene.render(camera) if camera is not None else None
    m_servo, s_servo = ArmServo(master, gains), ArmServo(scene, gains)
    nominal = s_servo.nominal_inertia
    operator.reset(master.tip, scene.block_pose, position)
    rec = _Recorder(
        steps,
        {"mt": 3, "mdt": 3, "mtau": 3, "st": 3, "sdt": 3, "stau": 3, "block": 7, "force": 3, "mtip": 3, "stip": 3,
         "phase": 1},
    )
    if video_every and camera is None:
        raise ValueError("video_every needs a camera to film with")
    video = np.zeros((-(-steps // video_every), *image.shape), np.uint8) if video_every else None
    crossed_time = math.nan
    for k in range(steps):
        t = k * gains.dt
        if video is not None and k % video_every == 0:
            video[k // video_every] = image if k == 0 else scene.render(camera)
        ms, ss = m_servo.sense(), s_servo.sense()
        block = scene.block_pose
        tip, tip_velocity, slave_tip = master.tip, master.tip_velocity(), scene.tip
        force = operator.hand_force(tip, tip_velocity, slave_tip, block)
        rec["mt"][k], rec["mdt"][k], rec["mtau"][k] = ms.theta, ms.dtheta, ms.tau
        rec["st"][k], rec["sdt"][k], rec["stau"][k] = ss.theta, ss.dtheta, ss.tau
        rec["block"][k], rec["force"][k], rec["mtip"][k], rec["stip"][k] = block, force, tip, slave_tip
        rec["phase"][k] = operator.phase
        if math.isnan(crossed_time) and position.sign * block[1] < 0:
            crossed_time = t
        tau_m, tau_s = bilateral_torques(ms, ss, nominal, gains)
        master.step(m_servo.actuate(tau_m), master.hand_torque(force))
        scene.step(s_servo.actuate(tau_s))
    return Demonstration(
        position=position,
        dt=gains.dt,
        master_theta=rec["mt"],
        master_dtheta=rec["mdt"],
        master_tau=rec["mtau"],
        slave_theta=rec["st"],
        slave_dtheta=rec["sdt"],
        slave_tau=rec["stau"],
        block_pose=rec["block"],
        hand_force=rec["force"],
        master_tip=rec["mtip"],
        slave_tip=rec["stip"],
        phase=rec["phase"].astype(np.int8),
        success=scene.success(),
        crossed_time=crossed_time,
        n_pushes=operator.n_pushes,
        variation=variation,
        operator=operator.describe(),
        image=image,
        camera=camera,
        video=video,
    )


class ReplayMaster:
    """Replays a demonstration's master side as a command source (motion copying).

    At time ``t`` it returns the recorded master state at ``t + lookahead`` — the same target
    a decoder is trained to predict (the next state, Δt_NN ahead).
    """

    def __init__(self, demo: Demonstration, lookahead: float = COMMAND_INTERVAL) -> None:
        self.demo, self.shift = demo, round(lookahead / demo.dt)

    def __call__(self, t: float, slave_state: ArmState) -> ArmState:
        k = min(round(t / self.demo.dt) + self.shift, self.demo.length - 1)
        d = self.demo
        return ArmState(d.master_theta[k], d.master_dtheta[k], d.master_tau[k])


class SceneBody:
    """What a body (:class:`seqmotion.lfd.rollout.Body`) reads off its world ``self.scene``: the object's pose, the
    pen tip, the webcam and the task's success — shared by :class:`TouchSlave` and the standard arm's
    :class:`~seqmotion.lfd.env.robot.PenRobot`."""

    scene: Any

    @property
    def block_pose(self) -> np.ndarray:
        """The object's pose ``(7,)`` now."""
        return self.scene.block_pose

    @property
    def tip(self) -> np.ndarray:
        """The pen tip ``(3,)`` [m]."""
        return self.scene.tip

    def render(self, camera: str) -> np.ndarray:
        """The webcam image ``(64, 64, 3)`` uint8."""
        return self.scene.render(camera)

    def success(self) -> bool:
        return self.scene.success()


class TouchSlave(SceneBody):
    """The Touch scene's slave arm under its half of the bilateral law (Fig. 5.7): what a controller commands.

    The body :func:`seqmotion.lfd.rollout.rollout` drives: :meth:`sense` reads the servo's state at the start of
    a 1 ms period, :meth:`act` applies the slave law toward the held master command for that period.

    Args:
        scene: the slave world, already reset to the episode's placement.
        gains: the bilateral control parameters (Table 5.1).
    """

    def __init__(self, scene: PushingScene, gains: BilateralGains) -> None:
        _check_timestep(gains, scene)
        self.scene, self.gains, self.dt = scene, gains, gains.dt
        self.servo = ArmServo(scene, gains)

    def sense(self) -> ArmState:
        """The slave's measured θ, θ̇, τ now (updates the servo's filters and observers)."""
        return self.servo.sense()

    def act(self, k: int, command: ArmState, state: ArmState, new_command: bool) -> None:
        """Period ``k``: the slave law toward ``command`` from ``state``, one physics step."""
        self.scene.step(self.servo.actuate(slave_torque(command, state, self.servo.nominal_inertia, self.gains)))
