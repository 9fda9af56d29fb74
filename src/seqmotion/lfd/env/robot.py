"""The chapter-5 pushing policy's closed loop on a standard arm (a Franka Panda in place of the Touch-like arm).

The shipped pushing policy (``sm.load_pretrained("pushing")``) decodes the **Touch arm's** joint state
(θ, θ̇, τ of its three joints, every 20 ms). To run it on another arm, this module keeps the Touch as a
*kinematic twin* and lets the real arm do the physical work:

* **World**: the pushing scene of :mod:`seqmotion.lfd.env.pushing` (table top at ``z = 0``, the 10 × 5 × 5 cm
  block at the six positions, the lights, the three webcams, the same options: 1 ms, implicit-fast,
  elliptic cones), read into ``mujoco.MjSpec`` with the Touch's bodies, motors and contact pairs removed; the
  robot's arm (:meth:`~seqmotion.sim.robot_models.Robot.spec`: its file's inertias, ranges and torque motors)
  attached at :data:`BASE` as the arm scenes attach theirs (:func:`~seqmotion.sim.scene.attach_robot`), and a pen
  on its flange — the Touch's pen (capsule of radius ``ARM.pen_radius``,
  the tip the centre of its rounded end, pen–block and pen–table friction :data:`~pushing.PEN_BLOCK_FRICTION`),
  :data:`PEN_LENGTH` long so the flange housing stays above the block. The pen is held vertical (pointing
  down), a fixed attitude: the Touch's pen stands vertical or leans 3°–22° while pushing.
* **Command** (every period, 1 ms), two modes (:data:`MODES`):

  - ``"command"`` (default): the decoder's Touch joint command θ_m, taken every 20 ms, puts the Touch's tip at
    ``forward_kinematics(θ_m)``; the pen tip follows that point, linearly interpolated across each 20 ms
    interval (the decoder predicts the master's state one interval ahead) and smoothed by :class:`TipFilter`.
    This is position control of the master's tip: the Touch's slave also moves under the bilateral law's force
    channel, ``−½ K_f (τ_m + τ_s)``, where the decoder's τ_m (the operator's hand torque) *drives* the slave;
    here nothing does, and the decoder's θ_m stays only a small lead over the slave state it reads back, so the
    pen creeps where the Touch's moves.
  - ``"twin"``: a simulated Touch slave (:class:`~seqmotion.lfd.env.pushing.PushingScene` with
    :class:`~seqmotion.lfd.env.teleop.ArmServo` and the slave's half of the law) is driven by the decoder exactly as
    in :func:`~seqmotion.lfd.rollout.run_autonomous`, except that its block is put, every period, where the
    robot's block is; the decoder reads the Touch servo's (θ, θ̇, τ) and the robot's pen tip follows the
    Touch's tip. The robot does the physical pushing of its own block; the Touch twin feels that block.

  Either way the tip reference never goes below :data:`TIP_FLOOR`, and it reaches the arm through
  :class:`~seqmotion.sim.control.JointSpaceController` (mink differential IK within the joint ranges, joint
  PD + disturbance observer on the arm's own inertias, torques saturated at its limits) with the pen's fixed
  vertical attitude. Being position control, where the reference lies inside the block the robot presses far
  harder than the Touch's 1 N m motors could.
* **Sensing** in mode ``"command"`` (what the decoder reads back as "the slave"): the Touch's joint angles
  that put its tip where the pen tip is (:func:`~seqmotion.lfd.env.pushing.inverse_kinematics`), their velocity
  from the same 10 Hz pseudo-derivative as the Touch's servo, and its reaction torques ``τ = −J_touchᵀ F``
  from the force ``F`` the block and table exert on the pen (a wrist force sensor's reading: the pen's
  contact forces of the previous period), low-passed at the Touch's 10 Hz observer cutoff. ``τ``'s sign is
  the Touch's (:mod:`seqmotion.lfd.env.teleop`): positive when the pen presses in the joint's positive direction.
* **Webcam**: rendered from this world (the Panda in view instead of the Touch), with the episode's
  lighting and colour variation, as :class:`~seqmotion.lfd.env.pushing.PushingScene` does.

Placement (:data:`BASE`, :data:`PEN_YAW`): the Panda stands on the table 0.45 m behind the Touch's base,
facing +x; with the pen vertical its home posture (tip at ``pushing.DEFAULT_TIP``) is
``(0, 0.494, 0, -2.030, 0, 2.525, 0.786)`` rad, the Panda's usual "ready" pose, and every tip position on the
grid x ∈ {0.08, 0.16, 0.24}, y ∈ {-0.18, 0, 0.18}, z ∈ {0.01, 0.06, 0.12} m is reached with every joint
≥ 0.77 rad inside its range.

Entry points: :class:`RobotPushingScene` (the world), :class:`PenRobot` (the slave body the one rollout loop,
:func:`seqmotion.lfd.rollout.run_trial`, drives; the 30-trial protocol is
:func:`seqmotion.lfd.evaluation.run_on_robot`), :func:`track_tip` (the tip following a given path, no policy).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...errors import check_finite_array, check_number
from ...sim.arm import Arm, JointReport, joint_report
from ...sim.backend import import_mujoco
from ...sim.control import GAINS, Gains
from ...sim.observers import LowPass, PseudoDerivative
from ...sim.render import Renderer
from ...sim.robot_models import Robot, resolve_robot, solve_pose, tool_mount
from ...sim.scene import Scene, attach_robot, robot_prefix
from . import pushing
from .state import RunRecord
from .teleop import ArmServo, ArmState, BilateralGains, SceneBody, slave_torque

PEN_LENGTH = 0.10
"""Flange to the pen tip [m]: the Touch's 5 cm pen would leave the Panda's flange housing (≈ 9 cm across)
3–5 cm above the table, beside the 5 cm block; at 10 cm it stays above the block's top."""

BASE = (-0.45, 0.0, 0.0)
"""Where the robot's base frame stands [m] (on the table, 0.45 m behind the Touch's base, facing +x)."""

PEN_YAW = 0.0
"""Heading of the flange's x axis about the vertical [rad] while the pen points down (the Panda's ready pose)."""

GAINS_PUSHING: Gains = GAINS["ch3"]
"""Joint PD gains and observer cutoff on the robot (the ch.-3 preset: K_p 800 1/s², K_d 100 1/s, DOB 2 Hz)."""

TIP_FLOOR = pushing.ARM.pen_radius + 0.001
"""Lowest tip target [m]: 1 mm above where the pen's rounded end touches the table. The Touch's 1 N m motors
can only lean on the table (its pen sinks ~3 mm into MuJoCo's soft table contact where the decoder lowers it);
the Panda's 80 N m under position control would press such a target with hundreds of newtons."""

TIP_FILTER_HZ = 10.0
"""Natural frequency of the critically damped filter on the tip path [Hz] (:class:`TipFilter`)."""

SENSE_CUTOFF_HZ = 10.0
"""Cutoff of the twin's velocity filter and force low-pass [Hz] (the Touch servo's ``BilateralGains.cutoff_hz``)."""


def pen_down_rotation(yaw: float = PEN_YAW) -> np.ndarray:
    """The pen's frame ``(3, 3)`` (columns x, y, z; z along the pen toward the tip) pointing straight down."""
    c, s = math.cos(yaw), math.sin(yaw)
    x, z = np.array([c, s, 0.0]), np.array([0.0, 0.0, -1.0])
    return np.column_stack([x, np.cross(z, x), z])


def _down_quat(yaw: float) -> np.ndarray:
    mujoco = import_mujoco()
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, pen_down_rotation(yaw).ravel())
    return quat


class TipFilter:
    """Critically damped second-order filter ``ω² / (s + ω)²`` on the tip path: a smooth reference.

    The decoder's commands change the tip path's slope every 20 ms (by up to ~1 m/s at the start of an
    episode). The Touch's light, soft slave smooths that out by itself; fed raw to a stiff controller on a Panda,
    each kink is a step in the velocity feedforward that saturates its 80 N m joints. Filtered, the reference
    has a continuous velocity and a bounded acceleration, both fed forward (lag ``2 / ω`` = 32 ms at 10 Hz).
    """

    def __init__(self, start: np.ndarray, dt: float, hz: float = TIP_FILTER_HZ) -> None:
        self.omega, self.dt = 2 * math.pi * float(hz), float(dt)
        self.pos = np.array(start, dtype=np.float64)
        self.vel = np.zeros(3)

    def update(self, target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance one period toward ``target`` ``(3,)`` [m]; return position [m], velocity [m/s], accel [m/s²]."""
        w = self.omega
        accel = w * w * (np.asarray(target, dtype=np.float64) - self.pos) - 2 * w * self.vel
        self.vel = self.vel + accel * self.dt
        self.pos = self.pos + self.vel * self.dt
        return self.pos.copy(), self.vel.copy(), accel


def touch_jacobian(q: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """``(3, 3)`` derivative of the Touch's tip position [m] w.r.t. its joint angles ``q`` ``(3,)`` [rad]
    (central differences of :func:`~seqmotion.lfd.env.pushing.forward_kinematics`)."""
    q = np.asarray(q, dtype=np.float64)
    jac = np.empty((3, 3))
    for j in range(3):
        dq = np.zeros(3)
        dq[j] = step
        jac[:, j] = (pushing.forward_kinematics(q + dq) - pushing.forward_kinematics(q - dq)) / (2 * step)
    return jac


def touch_angles(tip: np.ndarray, fallback: np.ndarray) -> tuple[np.ndarray, bool]:
    """The Touch's joint angles ``(3,)`` [rad] that put its tip at ``tip`` ``(3,)`` [m], elbow up.

    A point beyond the Touch's reach is pulled toward its shoulder onto 99.9 % of the reach first
    (the returned flag is then True); ``fallback`` is returned if even that fails.
    """
    try:
        return pushing.inverse_kinematics(tip), False
    except ValueError:
        pass
    arm = pushing.ARM
    shoulder = np.array([0.0, 0.0, arm.shoulder_height])
    rel = np.asarray(tip, dtype=np.float64) - shoulder
    reach = arm.upper + arm.tip_link[0]
    norm = float(np.linalg.norm(rel))
    if norm > 0:
        try:
            return pushing.inverse_kinematics(shoulder + rel * (0.999 * reach / norm)), True
        except ValueError:
            pass
    return np.asarray(fallback, dtype=np.float64).copy(), True


# ----------------------------------------------------------------------------------------------------------------
# The world
# ----------------------------------------------------------------------------------------------------------------
class RobotPushingScene:
    """The pushing world with a standard arm holding the pen (see the module docstring).

    Typical use::

        scene = RobotPushingScene("panda")
        scene.reset(pushing.block_position(2), variation)
        image = scene.render("default")    # (64, 64, 3) uint8
        ...                                 # run_trial / track_tip step it with the controller
        scene.success()

    Attributes:
        robot: the arm (:class:`~seqmotion.sim.robot_models.Robot`), placed at :data:`BASE`.
        model, data: the compiled ``mujoco.MjModel`` and its ``MjData``.
        control_scene: the :class:`~seqmotion.sim.scene.Scene` view the controller reads (``site`` = the pen tip,
            ``body`` = the block).
        home: ``(n,)`` the arm's start posture [rad]: the pen tip at ``pushing.DEFAULT_TIP``, pointing down.
        pen_quat: ``(4,)`` the pen's fixed attitude ``[w, x, y, z]``.
    """

    def __init__(self, robot: str | Robot = "panda", *, pen_length: float = PEN_LENGTH,
                 base: Sequence[float] = BASE, yaw: float = PEN_YAW) -> None:
        from dataclasses import replace

        mujoco = import_mujoco()
        arm = resolve_robot(robot)
        if arm is None:
            raise ValueError("RobotPushingScene needs a standard arm (e.g. 'panda'); the Touch-like arm's own scene "
                             "is seqmotion.lfd.env.pushing.PushingScene")
        check_number("pen_length [m]", pen_length, minimum=0.02, maximum=0.5)
        base_arr = check_finite_array("base [m]", base)
        if base_arr.shape != (3,):
            raise ValueError(f"base must be 3 finite coordinates [m], got {base!r}")
        # The pen hangs straight out of the flange: no tool roll or pitch; the base as given, facing +x.
        self.robot = replace(arm, base_pos=base_arr, base_yaw=0.0, tool_roll=0.0, tool_pitch=0.0)
        self.pen_length = float(pen_length)
        self.pen_quat = _down_quat(yaw)
        self.model = self._compile(mujoco)
        self.data = mujoco.MjData(self.model)
        m = self.model
        prefix = robot_prefix(self.robot)
        joint_ids = [m.joint(prefix + j).id for j in self.robot.joints]
        self.tip_site = m.site("tip").id
        self.pen_geom = m.geom("pen").id
        self.block_body = m.body("block").id
        block_joint = m.joint("block").id
        self._block_qpos = int(m.jnt_qposadr[block_joint])
        self.control_scene = Scene(
            kind="pushing", model=m, site=self.tip_site,
            arm_qpos=np.array([m.jnt_qposadr[j] for j in joint_ids]),
            arm_dof=np.array([m.jnt_dofadr[j] for j in joint_ids]),
            body=self.block_body, body_qpos=self._block_qpos, body_dof=int(m.jnt_dofadr[block_joint]),
            robot=self.robot, arm_joints=tuple(prefix + j for j in self.robot.joints),
            flange=m.site(prefix + "flange").id,
        )
        self.home = self._home(yaw)
        self._table_mat, self._wood_mat, self._key_light = m.mat("table").id, m.mat("wood").id, m.light("key").id
        self._nominal = (m.mat_rgba[self._wood_mat].copy(), m.mat_rgba[self._table_mat].copy(),
                         m.light_pos[self._key_light].copy(), m.light_diffuse[self._key_light].copy())
        self._renderer: Renderer | None = None
        self._force = np.zeros(6)
        self.position: pushing.BlockPosition = pushing.POSITIONS[0]

    def _compile(self, mujoco: Any) -> Any:
        """The pushing world without the Touch, the robot attached at its base, the pen on its flange."""
        spec = mujoco.MjSpec.from_string(pushing.pushing_mjcf(with_environment=True))
        spec.delete(spec.body("base"))  # the Touch-like arm's whole body tree
        for element in list(spec.actuators) + list(spec.pairs):
            spec.delete(element)
        flange = attach_robot(spec, self.robot)  # at base_pos, facing +x (base_yaw 0)
        pos, quat = tool_mount(self.robot)
        holder = flange.add_body(name="pen_holder", pos=pos.tolist(), quat=quat.tolist())
        holder.add_geom(name="pen", type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0, 0, 0, 0, 0, self.pen_length],
                        size=[pushing.ARM.pen_radius, 0, 0], material="pen", contype=0, conaffinity=0)
        holder.add_site(name="tip", pos=[0.0, 0.0, self.pen_length], size=[0.002, 0.002, 0.002])
        wood, pen = pushing.BLOCK_TABLE_FRICTION, pushing.PEN_BLOCK_FRICTION
        for a, b, mu in (("block", "table", wood), ("pen", "block", pen), ("pen", "table", pen)):
            spec.add_pair(geomname1=a, geomname2=b, condim=3, friction=[mu, mu, 0.005, 1e-4, 1e-4])
        try:
            return spec.compile()
        except Exception as exc:  # MuJoCo's compiler errors name the element
            raise ValueError(f"the pushing scene on {self.robot.label} does not compile: {exc}") from exc

    def _home(self, yaw: float) -> np.ndarray:
        """IK posture with the tip at ``pushing.DEFAULT_TIP``, pen down, 0.1 rad inside the ranges."""
        mujoco = import_mujoco()
        data = mujoco.MjData(self.model)
        target = pushing.DEFAULT_TIP - self.robot.base_pos
        q, err = solve_pose(self.model, data, self.robot, target + self.robot.base_pos, pen_down_rotation(yaw),
                            self._seed(), site="tip", margin=0.1)
        if err > 1e-6:
            raise ValueError(f"{self.robot.label} at base {self.robot.base_pos.tolist()} m cannot hold the pen "
                             f"down at {pushing.DEFAULT_TIP.tolist()} m (IK residual {err:.2e})")
        return q

    def _seed(self) -> np.ndarray:
        lo, hi = np.clip(self.robot.joint_range[:, 0], -np.pi, None), np.clip(self.robot.joint_range[:, 1], None, np.pi)
        seed = np.where(np.isfinite(self.robot.home), self.robot.home, 0.5 * (lo + hi))
        if self.robot.name == "panda":  # the Panda's ready pose: elbow up, flange down
            seed = np.array([0.0, 0.3, 0.0, -2.2, 0.0, 2.5, 0.785])
        return seed

    # -- episode -----------------------------------------------------------------------------------------------
    def reset(self, position: pushing.BlockPosition, variation: pushing.SceneVariation | None = None,
              q: np.ndarray | None = None) -> None:
        """Arm at ``q`` (default :attr:`home`) at rest, the block at ``position`` (+ variation), the
        episode's lighting and colours (as :meth:`seqmotion.lfd.env.pushing.PushingScene.reset`)."""
        mujoco = import_mujoco()
        variation = variation or pushing.SceneVariation()
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        self.position = position
        xy = position.xy + variation.block_offset
        adr = self._block_qpos
        d.qpos[adr: adr + 3] = (xy[0], xy[1], pushing.BLOCK_SIZE[2] / 2)
        half = variation.block_yaw / 2
        d.qpos[adr + 3: adr + 7] = (math.cos(half), 0.0, 0.0, math.sin(half))
        wood, table, light_pos, light_diffuse = self._nominal
        m.mat_rgba[self._wood_mat, :3] = np.clip(wood[:3] * variation.block_tint, 0, 1)
        m.mat_rgba[self._table_mat, :3] = np.clip(table[:3] * variation.table_tint, 0, 1)
        m.light_pos[self._key_light] = light_pos + variation.light_shift
        m.light_diffuse[self._key_light] = np.clip(light_diffuse * variation.light_scale, 0, 1)
        d.qpos[self.control_scene.arm_qpos] = self.home if q is None else q
        mujoco.mj_forward(m, d)
        self._force[:] = 0.0

    @property
    def q(self) -> np.ndarray:
        """The arm's joint angles ``(n,)`` [rad]."""
        return self.data.qpos[self.control_scene.arm_qpos].copy()

    @property
    def tip(self) -> np.ndarray:
        """Pen tip position ``(3,)`` [m] (world)."""
        return self.data.site_xpos[self.tip_site].copy()

    @property
    def block_pose(self) -> np.ndarray:
        """Block pose ``(7,)``: centre [m] and quaternion (w, x, y, z)."""
        return self.data.qpos[self._block_qpos: self._block_qpos + 7].copy()

    def success(self) -> bool:
        """True once the block's centre lies on the other side of the robot's centre line (y = 0)."""
        return bool(self.position.sign * self.data.qpos[self._block_qpos + 1] < 0.0)

    def pen_force(self) -> np.ndarray:
        """Force ``(3,)`` [N] the block and the table exert on the pen, world frame, from the contacts of the
        last physics step (call after a step, not between ``mj_step1`` and ``mj_step2``)."""
        mujoco = import_mujoco()
        m, d = self.model, self.data
        total = np.zeros(3)
        for i in range(d.ncon):
            contact = d.contact[i]
            if self.pen_geom not in (contact.geom1, contact.geom2):
                continue
            mujoco.mj_contactForce(m, d, i, self._force)
            on_geom2 = contact.frame.reshape(3, 3).T @ self._force[:3]  # the normal points from geom1 to geom2
            total += on_geom2 if contact.geom2 == self.pen_geom else -on_geom2
        return total

    def render(self, camera: str = "default") -> np.ndarray:
        """One webcam image ``(64, 64, 3)`` uint8 from ``camera`` (a key of ``pushing.CAMERAS``)."""
        if camera not in pushing.CAMERAS:
            raise ValueError(f"unknown camera {camera!r}; choose one of {sorted(pushing.CAMERAS)}")
        if self._renderer is None:
            self._renderer = Renderer(self.model, pushing.IMAGE_SIZE, pushing.IMAGE_SIZE)
        return self._renderer.render(self.data, camera)

    def close(self) -> None:
        """Release the offscreen rendering context (if one was opened)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


# ----------------------------------------------------------------------------------------------------------------
# The loop
# ----------------------------------------------------------------------------------------------------------------
class TouchTwin:
    """The Touch's joint state computed from the robot's pen tip and pen force (see the module docstring)."""

    def __init__(self, tip: np.ndarray, dt: float = pushing.DT, cutoff_hz: float = SENSE_CUTOFF_HZ) -> None:
        g = 2 * math.pi * cutoff_hz
        theta, _ = touch_angles(tip, pushing.default_pose())
        self.velocity = PseudoDerivative(g, dt, theta)
        self.force = LowPass(g, dt, np.zeros(3))
        self.state = ArmState(theta, np.zeros(3), np.zeros(3))
        self.clamped = 0  # periods whose tip was beyond the Touch's reach

    def sense(self, tip: np.ndarray, pen_force: np.ndarray) -> Any:
        """Update with the tip ``(3,)`` [m] and the force on the pen ``(3,)`` [N]; return the state (an
        :class:`seqmotion.lfd.env.teleop.ArmState`: θ, θ̇, τ)."""
        theta, clamped = touch_angles(tip, self.state.theta)
        self.clamped += clamped
        dtheta = self.velocity.update(theta)
        force = self.force.update(pen_force)
        tau = -touch_jacobian(theta).T @ force
        self.state = type(self.state)(theta, np.asarray(dtheta, dtype=np.float64).copy(), tau)
        return self.state


@dataclass
class RobotRun(RunRecord):
    """One closed-loop episode on the robot, sampled every ``dt`` (K samples).

    Arrays: ``slave_theta/dtheta/tau`` ``(K, 3)`` the Touch twin's state [rad, rad/s, N m];
    ``command_theta/dtheta/tau`` ``(K, 3)`` the decoder's held command (:class:`~.state.RunRecord`); ``tip`` and
    ``tip_target`` ``(K, 3)`` [m];
    ``block_pose`` ``(K, 7)``; ``joint_pos``/``joint_vel``/``torque`` ``(K, n)`` the arm's [rad, rad/s, N m];
    ``ik_error`` ``(K, 2)`` [m, rad]; ``saturated`` ``(K,)``; ``pen_force`` ``(K, 3)`` [N]. ``twin_clamped``:
    periods whose tip was beyond the Touch's reach; ``floored``: periods whose reference tip was below
    :data:`TIP_FLOOR` (held there).
    """

    tip: np.ndarray
    tip_target: np.ndarray
    block_pose: np.ndarray
    joint_pos: np.ndarray
    joint_vel: np.ndarray
    torque: np.ndarray
    ik_error: np.ndarray
    saturated: np.ndarray
    pen_force: np.ndarray
    success: bool
    crossed_time: float
    twin_clamped: int
    floored: int = 0
    joints: JointReport | None = None
    seconds: float = 0.0
    ik_seconds_per_period: float = 0.0

    @property
    def steps(self) -> int:
        return len(self.tip)

    @property
    def tracking_rmse(self) -> float:
        """RMS distance of the pen tip from its target [m]."""
        return float(np.sqrt(np.mean(np.sum((self.tip - self.tip_target) ** 2, axis=1))))

    @property
    def tracking_max(self) -> float:
        """Largest distance of the pen tip from its target [m]."""
        return float(np.max(np.linalg.norm(self.tip - self.tip_target, axis=1)))


class _Loop:
    """The robot's controller over one episode (shared by :class:`PenRobot` and :func:`track_tip`): the
    simulator's :class:`~seqmotion.sim.arm.Arm` on the world's own ``MjData``, its one control step recording
    every period through the step's hook."""

    def __init__(self, scene: RobotPushingScene, steps: int, gains: Gains) -> None:
        self.scene = scene
        self.arm = Arm(scene.control_scene, gains, data=scene.data)
        self.arm.start()
        self.controller = self.arm.controller
        n = scene.robot.dof
        self.rec = {name: np.zeros((steps, w)) for name, w in (
            ("tip", 3), ("target", 3), ("block", 7), ("q", n), ("qd", n), ("tau", n), ("ik", 2), ("force", 3))}
        self.rec["sat"] = np.zeros(steps, dtype=bool)
        self._accel = np.zeros(6)
        self._twist = np.zeros(6)

    def step(self, k: int, target: np.ndarray, velocity: np.ndarray, accel: np.ndarray) -> np.ndarray:
        """One control period toward tip ``target`` ``(3,)`` [m] moving at ``velocity`` ``(3,)`` [m/s] with
        ``accel`` ``(3,)`` [m/s²]; returns the force on the pen after the step ``(3,)`` [N]."""
        scene, ctrl, rec = self.scene, self.controller, self.rec
        d = scene.data
        cs = scene.control_scene
        self._twist[:3] = velocity
        self._accel[:3] = accel

        def record(tau: np.ndarray) -> None:
            rec["tip"][k], rec["target"][k] = d.site_xpos[scene.tip_site], target
            rec["block"][k] = d.qpos[cs.body_qpos: cs.body_qpos + 7]
            rec["q"][k], rec["qd"][k] = d.qpos[cs.arm_qpos], d.qvel[cs.arm_dof]
            rec["tau"][k], rec["ik"][k], rec["sat"][k] = tau, ctrl.ik_error, ctrl.saturated

        self.arm.step(target, scene.pen_quat, self._twist, self._accel, record)
        force = scene.pen_force()
        rec["force"][k] = force
        return force

    def report(self, upto: int) -> JointReport:
        """The arm's joints over the first ``upto`` periods, judged against the robot's limits."""
        rec = self.rec
        return joint_report(self.scene.control_scene, self.scene.model.opt.timestep, joint_pos=rec["q"][:upto],
                            joint_vel=rec["qd"][:upto], torque=rec["tau"][:upto], saturated=rec["sat"][:upto],
                            ik_error=rec["ik"][:upto])


MODES = ("command", "twin")
"""How the decoder's commands reach the robot (:func:`run_trial`)."""


class _TouchSlave:
    """A simulated Touch slave under the bilateral law, whose block is the robot world's (mode ``"twin"``).

    Every period the Touch scene's block is put where the robot's pen has pushed the real one (at rest), so the
    Touch's pen meets it there, with the Touch's own contact, 1 N m motors, disturbance and reaction-torque
    observers; the decoder reads the Touch servo's state, and the robot's pen tip follows the Touch's tip.
    """

    def __init__(self, scene: RobotPushingScene, position: pushing.BlockPosition,
                 variation: pushing.SceneVariation | None, gains: Any) -> None:
        self.touch = pushing.PushingScene()
        self.touch.reset(position, variation)
        m = self.touch.model
        joint = m.joint("block").id
        self._qpos, self._dof = int(m.jnt_qposadr[joint]), int(m.jnt_dofadr[joint])
        self.servo = ArmServo(self.touch, gains)
        self.gains = gains
        self.state = self.servo.state
        self._velocity = np.zeros(3)

    def sense(self, block_pose: np.ndarray) -> Any:
        """Put the Touch's block at ``block_pose`` ``(7,)`` at rest; read the Touch servo's state."""
        d = self.touch.data
        d.qpos[self._qpos: self._qpos + 7] = block_pose
        d.qvel[self._dof: self._dof + 6] = 0.0
        self.state = self.servo.sense()
        return self.state

    def step(self, command: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One period of the slave law under ``command``; the Touch's tip position [m], velocity [m/s] and
        acceleration [m/s²] ``(3,)`` each (the acceleration from successive velocities)."""
        torque = slave_torque(command, self.state, self.servo.nominal_inertia, self.gains)
        self.touch.step(self.servo.actuate(torque))
        velocity = self.touch.tip_velocity()
        accel = (velocity - self._velocity) / self.gains.dt
        self._velocity = velocity
        return self.touch.tip, velocity, accel

    def close(self) -> None:
        self.touch.close()


class PenRobot(SceneBody):
    """A standard arm holding the pen, as the slave body a controller commands (:func:`seqmotion.lfd.rollout.rollout`).

    Every period it senses the Touch's joint state (the twin of the pen tip and pen force, mode ``"command"``;
    or a simulated Touch slave's, mode ``"twin"``), and acts by moving the pen tip: toward the decoded command's
    tip along a filtered path (``"command"``), or after the Touch slave's tip (``"twin"``), never below
    :data:`TIP_FLOOR`, by the simulator's control step (:class:`_Loop`).

    Args:
        scene: the world, already reset to the episode's placement.
        position, variation: the placement (mode ``"twin"`` places the Touch scene's block alike).
        steps: periods the episode runs (the records' length).
        every: control periods per decision (the controller's interval / the period).
        gains: the robot's joint PD gains and observer cutoff.
        touch_gains: the Touch servo's :class:`~seqmotion.lfd.env.teleop.BilateralGains`.
        mode: one of :data:`MODES`.
    """

    def __init__(self, scene: RobotPushingScene, position: pushing.BlockPosition,
                 variation: pushing.SceneVariation | None, steps: int, every: int, gains: Gains,
                 touch_gains: BilateralGains, mode: str) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        self.scene, self.every = scene, every
        self.dt = float(scene.model.opt.timestep)
        self.loop = _Loop(scene, steps, gains)
        self.twin = TouchTwin(scene.tip, self.dt, touch_gains.cutoff_hz)
        self.slave = _TouchSlave(scene, position, variation, touch_gains) if mode == "twin" else None
        self.force = np.zeros(3)
        self.previous = self.next = scene.tip
        self.smooth = TipFilter(self.previous, self.dt)
        self.floored = 0

    def sense(self) -> ArmState:
        """The Touch's θ, θ̇, τ now: the twin of the pen tip and force, or the Touch slave's servo."""
        scene = self.scene
        return self.twin.sense(scene.tip, self.force) if self.slave is None else self.slave.sense(scene.block_pose)

    def act(self, k: int, command: ArmState, state: ArmState, new_command: bool) -> None:
        """Period ``k``: the pen tip one control step toward where ``command`` puts the Touch's tip."""
        if new_command:
            self.previous, self.next = self.next, pushing.forward_kinematics(command.theta)
            self.next[2] = max(self.next[2], TIP_FLOOR)
        if self.slave is None:
            # The command is the master's state one interval ahead: the path reaches it at the interval's end.
            every = self.every
            target, velocity, accel = self.smooth.update(
                self.previous + (k % every + 1) / every * (self.next - self.previous))
        else:
            target, velocity, accel = self.slave.step(command)
        if target[2] < TIP_FLOOR:  # never below the floor, nor heading further down
            target[2], velocity[2], accel[2] = TIP_FLOOR, max(velocity[2], 0.0), max(accel[2], 0.0)
            self.floored += 1
        self.force = self.loop.step(k, target, velocity, accel)
        if not np.all(np.isfinite(self.scene.data.qpos)):
            raise ValueError(f"the simulation diverged at t = {k * self.dt:.3f} s (non-finite state)")

    def close(self) -> None:
        if self.slave is not None:
            self.slave.close()


@dataclass
class TipTracking:
    """The pen tip following a given path (:func:`track_tip`): ``tip``, ``target`` ``(K, 3)`` [m], the arm's
    :class:`~seqmotion.sim.arm.JointReport`, and the IK's wall time per period [s]."""

    tip: np.ndarray
    target: np.ndarray
    joints: JointReport
    ik_seconds_per_period: float

    @property
    def errors(self) -> np.ndarray:
        """``(K,)`` distance of the tip from its target [m]."""
        return np.linalg.norm(self.tip - self.target, axis=1)


def track_tip(scene: RobotPushingScene, path: np.ndarray, position: pushing.BlockPosition | None = None,
              gains: Gains = GAINS_PUSHING) -> TipTracking:
    """Drive the pen tip along ``path`` ``(K, 3)`` [m] (one point per 1 ms period), pen down, no policy.

    Its velocity and acceleration (finite differences) are fed forward, so the path should be smooth and
    start at rest. The scene is reset first (block at
    ``position``, default the first; arm at home). The path's first point
    should be the home tip (``pushing.DEFAULT_TIP``) or near it.
    """
    path = check_finite_array("path [m]", path)
    if path.ndim != 2 or path.shape[1] != 3 or len(path) < 2:
        raise ValueError(f"path must be a finite (K >= 2, 3) array of tip positions [m], got shape {path.shape}")
    dt = float(scene.model.opt.timestep)
    scene.reset(position or pushing.POSITIONS[0])
    loop = _Loop(scene, len(path), gains)
    velocity = np.gradient(path, dt, axis=0)
    accel = np.gradient(velocity, dt, axis=0)
    for k in range(len(path)):
        loop.step(k, path[k], velocity[k], accel[k])
    ctrl = loop.controller
    return TipTracking(loop.rec["tip"].copy(), path.copy(), loop.report(len(path)),
                       ctrl.ik_seconds / max(ctrl.periods, 1))


