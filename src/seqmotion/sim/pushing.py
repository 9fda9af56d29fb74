"""Chapter-5 pushing scene: a Geomagic-Touch-like 3-joint arm, a table, a wooden block and a webcam.

Everything is simulated in MuJoCo at the control period ``dt = 1 ms``. Two models are built
from the same arm description:

* :class:`PushingScene` — the **slave** side: the arm, the table, the 10 × 5 × 5 cm block,
  the lights and three webcam poses. This is also the world a learned policy acts in.
* :class:`MasterArm` — the **master** side: the same arm alone on its stand (no block, no
  camera). The operator's hand pushes its stylus tip. Keeping it a separate model means a
  learned policy replaces it simply by not stepping it (dissertation Fig. 5.7).

Frames and geometry (all SI units: m, rad, kg, N, N m)
------------------------------------------------------
World frame: the table top is the plane ``z = 0``; the robot's yaw axis is the ``z`` axis;
``+x`` is the robot's forward direction and ``+y`` its **left**. The robot's **centre line**
is the ``x`` axis (``y = 0``).

Arm (Geomagic Touch, three active joints; the three passive gimbal joints are locked):

* ``yaw``      — about ``+z`` at the base; positive turns the arm to its left (+y).
* ``shoulder`` — pitch at height :data:`ARM.shoulder_height` above the table; the upper arm
  (length ``ARM.upper``) points along ``+x`` at zero angle and **rises** for positive angles.
* ``elbow``    — pitch at the end of the upper arm; at zero angle the forearm is perpendicular
  to the upper arm, pointing down; positive angles swing it forward.
* The locked gimbal holds the pen (length ``ARM.pen``) bent ``ARM.pen_bend`` back from the
  forearm axis, so that in every pushing pose the pen stands vertical or leans away from the
  block at the top (3°–22°): only its rounded end touches the block's face and it cannot
  catch the block's top edge. The **tip** is the centre of that rounded end.

Block (10 cm wide, 5 cm high, 5 cm deep, dissertation 5.3.1): its 10 cm side lies along the
robot's forward axis (``x``), so the face the robot pushes (10 × 5 cm) faces the centre line.
(Pushing it with one point still turns it unless the pusher steers — see the operator.) The six
positions of Fig. 5.5 are read as "left/right" = which side of the centre line the block lies
on, and "4.5 / 8.0 / 11.5 cm from the robot" = the lateral distance of the block's centre from
the robot's centre line, at a fixed reach ``BLOCK_REACH_X`` in front of the robot. The robot
pushes a block on its left to the right and vice versa; the task succeeds when the block's
centre crosses the centre line (``y`` changes sign). The other reading (distance along the
forward axis at a fixed lateral offset) was considered; it would spread the blocks over 7 cm of
the Touch's shallow (16.5 cm) depth workspace, close to the base, and is not used.

Friction: dry wood on a lacquered/laminated wooden table has a sliding coefficient of roughly
0.3–0.5 (static a little higher); MuJoCo has one coefficient per contact, so block–table uses
``BLOCK_TABLE_FRICTION`` = 0.4. The pen (hard plastic) on wood uses 0.3. With a beech-like
density of 600 kg/m³ the block weighs 0.15 kg, so sliding it needs ≈ 0.59 N — within the
continuous force of a real Touch (0.88 N).

Only the contacts that matter are simulated (explicit ``<pair>`` elements): block–table,
pen–block, pen–table and forearm–block. The links never reach the table in this task.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .backend import CONTROL_DT, PUSHING_GRAVITY, control_period, import_mujoco
from .render import Renderer, free_camera

mujoco = import_mujoco()  # this module's scenes are built at construction: import MuJoCo now

DT = CONTROL_DT
"""Simulation and control period [s] (Table 5.1): one physics step per control period."""

IMAGE_SIZE = 64
"""Webcam images are ``IMAGE_SIZE × IMAGE_SIZE`` RGB (dissertation 5.3.1)."""


# ----------------------------------------------------------------------------------------------
# Arm description
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ArmGeometry:
    """Kinematic and inertial parameters of the Touch-like arm (SI units).

    Link lengths follow the Phantom Omni / Touch (133 mm upper arm and forearm). Masses are
    those of light aluminium tubes plus the gimbal and pen; ``armature`` is the motor rotor
    inertia reflected through the capstan drive, which dominates the joint inertia of the
    real device. Viscous ``damping`` and Coulomb ``frictionloss`` model the drive friction.
    """

    shoulder_height: float = 0.12
    upper: float = 0.133
    forearm: float = 0.133
    pen: float = 0.05
    pen_bend: float = math.radians(50.0)
    pen_radius: float = 0.005
    link_radius: float = 0.006
    turret_mass: float = 0.08
    turret_inertia_z: float = 6e-5
    upper_mass: float = 0.035
    forearm_mass: float = 0.045
    forearm_com: float = 0.085
    armature: tuple[float, float, float] = (3e-4, 3e-4, 2e-4)
    damping: tuple[float, float, float] = (1.5e-3, 1.5e-3, 1e-3)
    frictionloss: tuple[float, float, float] = (2e-3, 2e-3, 1.5e-3)
    torque_limit: tuple[float, float, float] = (1.0, 1.0, 1.0)
    joint_range: tuple[tuple[float, float], ...] = ((-1.3, 1.3), (-0.3, 1.6), (-1.0, 1.5))

    @property
    def tip_link(self) -> tuple[float, float]:
        """Effective second link (elbow → tip): ``(length, backward offset angle)`` [m, rad]."""
        along = self.forearm + self.pen * math.cos(self.pen_bend)
        across = self.pen * math.sin(self.pen_bend)
        return math.hypot(along, across), math.atan2(across, along)


ARM = ArmGeometry()
JOINT_NAMES = ("yaw", "shoulder", "elbow")
N_JOINTS = 3
# Gravity is PUSHING_GRAVITY = 9.81 m/s², not the arm scenes' 9.8: the shipped policy and its
# evaluations were made at 9.81 (see seqmotion.sim.backend.PUSHING_GRAVITY).


def forward_kinematics(q: np.ndarray, arm: ArmGeometry = ARM) -> np.ndarray:
    """Tip position ``(3,)`` [m] in the world frame for joint angles ``q`` ``(3,)`` [rad]."""
    q = np.asarray(q, dtype=np.float64)
    l2, offset = arm.tip_link
    r = arm.upper * math.cos(q[1]) + l2 * math.cos(q[1] + q[2] - math.pi / 2 - offset)
    z = arm.shoulder_height + arm.upper * math.sin(q[1]) + l2 * math.sin(q[1] + q[2] - math.pi / 2 - offset)
    return np.array([r * math.cos(q[0]), r * math.sin(q[0]), z])


def inverse_kinematics(tip: np.ndarray, arm: ArmGeometry = ARM) -> np.ndarray:
    """Joint angles ``(3,)`` [rad] that put the tip at ``tip`` ``(3,)`` [m], elbow up.

    Raises:
        ValueError: if the point is outside the arm's reach.
    """
    x, y, z = np.asarray(tip, dtype=np.float64)
    l1 = arm.upper
    l2, offset = arm.tip_link
    r, dz = math.hypot(x, y), z - arm.shoulder_height
    cos_beta = (r * r + dz * dz - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    if not -1.0 <= cos_beta <= 1.0:
        raise ValueError(f"tip target {np.round(tip, 4).tolist()} m is outside the arm's reach")
    beta = -math.acos(cos_beta)  # elbow up: the tip link bends down from the upper arm
    shoulder = math.atan2(dz, r) - math.atan2(l2 * math.sin(beta), l1 + l2 * math.cos(beta))
    elbow = beta + math.pi / 2 + offset
    return np.array([math.atan2(y, x), shoulder, elbow])


def gravity_torque(q: np.ndarray, arm: ArmGeometry = ARM) -> np.ndarray:
    """Joint torques ``(3,)`` [N m] that gravity exerts on the arm at ``q`` (negative = pulls down).

    This is the arm's *modelled* internal torque used by the reaction-torque observer; it
    matches the inertial parameters written into the MJCF exactly.
    """
    q = np.asarray(q, dtype=np.float64)
    forearm_angle = q[1] + q[2] - math.pi / 2
    # Horizontal lever arms of the link centres of mass about the shoulder / elbow axes.
    upper_lever = 0.5 * arm.upper * math.cos(q[1])
    elbow_lever = arm.upper * math.cos(q[1])
    forearm_lever = arm.forearm_com * math.cos(forearm_angle)
    g = PUSHING_GRAVITY
    tau_elbow = -arm.forearm_mass * g * forearm_lever
    tau_shoulder = -arm.upper_mass * g * upper_lever - arm.forearm_mass * g * elbow_lever + tau_elbow
    return np.array([0.0, tau_shoulder, tau_elbow])


# ----------------------------------------------------------------------------------------------
# Task geometry
# ----------------------------------------------------------------------------------------------
BLOCK_SIZE = (0.10, 0.05, 0.05)
"""Block extent along (x, y, z) [m]: 10 cm wide (along the forward axis), 5 cm deep, 5 cm high."""

BLOCK_REACH_X = 0.16
"""Forward position of the block's centre [m] (its near face 6 cm in front of the base)."""

BLOCK_MASS = 0.15
"""Block mass [kg]: 0.25 L of wood at 600 kg/m³."""

BLOCK_TABLE_FRICTION = 0.4
PEN_BLOCK_FRICTION = 0.3
DISTANCES = (0.045, 0.080, 0.115)
"""Lateral distance of the block's centre from the robot's centre line [m] (dissertation Fig. 5.5)."""

SIDES = ("left", "right")


@dataclass(frozen=True)
class BlockPosition:
    """One of the six nominal block placements.

    Attributes:
        index: 0..5, ordered left 4.5, left 8.0, left 11.5, right 4.5, right 8.0, right 11.5.
        side: ``"left"`` (+y, pushed to the right) or ``"right"`` (−y, pushed to the left).
        distance: lateral distance of the block's centre from the robot's centre line [m].
    """

    index: int
    side: str
    distance: float

    @property
    def sign(self) -> float:
        """+1 on the robot's left (block at +y), −1 on its right."""
        return 1.0 if self.side == "left" else -1.0

    @property
    def xy(self) -> np.ndarray:
        """Nominal block-centre position ``(2,)`` [m] on the table."""
        return np.array([BLOCK_REACH_X, self.sign * self.distance])

    @property
    def name(self) -> str:
        return f"{self.side}_{round(self.distance * 1000) / 10:g}cm"


POSITIONS: tuple[BlockPosition, ...] = tuple(
    BlockPosition(i, side, d) for i, (side, d) in enumerate((s, d) for s in SIDES for d in DISTANCES)
)


def block_position(index: int) -> BlockPosition:
    """The nominal placement with this index (0..5); ``ValueError`` otherwise."""
    if isinstance(index, bool) or not isinstance(index, int | np.integer) or not 0 <= index < len(POSITIONS):
        raise ValueError(f"block position index must be an integer in 0..{len(POSITIONS) - 1}, got {index!r}")
    return POSITIONS[int(index)]


@dataclass(frozen=True)
class CameraPose:
    """A webcam pose: position and look-at point [m] in the world frame, vertical field of view [deg]."""

    pos: tuple[float, float, float]
    target: tuple[float, float, float]
    fovy: float = 50.0


CAMERAS: dict[str, CameraPose] = {
    # In front of the robot, looking back at it over the workspace (Fig. 5.3, default).
    "default": CameraPose((0.44, 0.0, 0.30), (0.14, 0.0, 0.02)),
    # Position 1: low and to the robot's right, an oblique view.
    "position1": CameraPose((0.36, -0.40, 0.20), (0.15, 0.0, 0.03)),
    # Position 2: high on the robot's left, looking down over its shoulder.
    "position2": CameraPose((-0.05, 0.32, 0.50), (0.16, 0.0, 0.0)),
}

OVERVIEW = {"lookat": (0.14, 0.0, 0.03), "distance": 0.5, "azimuth": 180.0, "elevation": -35.0}
"""A free camera in front of the robot looking down at the workspace (figures; not a webcam pose)."""

DEFAULT_TIP = np.array([0.15, 0.0, 0.10])
"""Tip position [m] of the default (start) pose: in front of the robot, above the centre line."""


def default_pose() -> np.ndarray:
    """Joint angles ``(3,)`` [rad] of the default pose (tip at :data:`DEFAULT_TIP`)."""
    return inverse_kinematics(DEFAULT_TIP)


# ----------------------------------------------------------------------------------------------
# MJCF
# ----------------------------------------------------------------------------------------------
def _look_at(pos: tuple[float, ...], target: tuple[float, ...]) -> str:
    """MJCF ``xyaxes`` of a camera at ``pos`` looking at ``target`` with the world z up."""
    forward = np.subtract(target, pos)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return " ".join(f"{v:.6f}" for v in (*right, *up))


def _arm_xml(arm: ArmGeometry) -> str:
    """The arm's body tree (base, turret, upper arm, forearm with the locked gimbal and pen)."""
    l1, l2, h = arm.upper, arm.forearm, arm.shoulder_height
    pen_end = np.array([-arm.pen * math.sin(arm.pen_bend), 0.0, -l2 - arm.pen * math.cos(arm.pen_bend)])
    tip = " ".join(f"{v:.6f}" for v in pen_end)

    def joint(i: int, axis: str) -> str:
        lo, hi = arm.joint_range[i]
        return (
            f'<joint name="{JOINT_NAMES[i]}" axis="{axis}" range="{lo} {hi}" armature="{arm.armature[i]}" '
            f'damping="{arm.damping[i]}" frictionloss="{arm.frictionloss[i]}"/>'
        )

    # Rod inertias about the link centres (m L² / 12), plus a thin-tube radial term.
    upper_i = arm.upper_mass * l1 * l1 / 12
    fore_i = arm.forearm_mass * (l2 + arm.pen) ** 2 / 12
    return f"""
    <body name="base">
      <geom name="base_shell" type="box" pos="-0.03 0 0.03" size="0.08 0.07 0.03" material="robot"/>
      <body name="turret" pos="0 0 0.06">
        {joint(0, "0 0 1")}
        <inertial pos="0 0 0.03" mass="{arm.turret_mass}" diaginertia="{arm.turret_inertia_z} {arm.turret_inertia_z}
          {arm.turret_inertia_z}"/>
        <geom name="turret" type="cylinder" pos="0 0 0.03" size="0.035 0.03" material="robot"/>
        <body name="upper_arm" pos="0 0 {h - 0.06}">
          {joint(1, "0 -1 0")}
          <inertial pos="{l1 / 2} 0 0" mass="{arm.upper_mass}" diaginertia="2e-6 {upper_i} {upper_i}"/>
          <geom name="upper_arm" type="capsule" fromto="0 0 0 {l1} 0 0" size="{arm.link_radius}" material="link"/>
          <body name="forearm" pos="{l1} 0 0">
            {joint(2, "0 -1 0")}
            <inertial pos="0 0 {-arm.forearm_com}" mass="{arm.forearm_mass}" diaginertia="{fore_i} {fore_i} 2e-6"/>
            <geom name="forearm" type="capsule" fromto="0 0 0 0 0 {-l2}" size="{arm.link_radius}" material="link"/>
            <geom name="gimbal" type="sphere" pos="0 0 {-l2}" size="0.011" material="robot"/>
            <geom name="pen" type="capsule" fromto="0 0 {-l2} {tip}" size="{arm.pen_radius}" material="pen"/>
            <site name="tip" pos="{tip}" size="0.002"/>
          </body>
        </body>
      </body>
    </body>"""


def _actuators_xml(arm: ArmGeometry) -> str:
    pairs = zip(JOINT_NAMES, arm.torque_limit, strict=True)
    return "\n".join(f'<motor name="{n}" joint="{n}" ctrlrange="{-lim} {lim}"/>' for n, lim in pairs)


_ASSETS = """
  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.82 0.84 0.86" rgb2="0.55 0.57 0.6" width="64"
      height="64"/>
    <texture name="tabletex" type="2d" builtin="checker" rgb1="0.78 0.76 0.72" rgb2="0.74 0.72 0.68" width="64"
      height="64"/>
    <material name="table" texture="tabletex" texrepeat="8 8" specular="0.15" shininess="0.1"/>
    <material name="wood" rgba="0.72 0.52 0.32 1"/>
    <material name="robot" rgba="0.15 0.15 0.17 1"/>
    <material name="link" rgba="0.75 0.75 0.78 1"/>
    <material name="pen" rgba="0.2 0.2 0.22 1"/>
  </asset>"""


def pushing_mjcf(with_environment: bool = True, arm: ArmGeometry = ARM) -> str:
    """MJCF text of the slave scene (``with_environment``) or of the bare master arm.

    Both use ``timestep = 1 ms`` and the implicit-fast integrator (stable with the joint
    damping at this step). Friction uses elliptic cones with ``impratio = 10``: MuJoCo's
    soft contacts otherwise let a block creep under a steady sub-threshold push (0.7 mm/s at
    70 % of μmg with the defaults, < 0.1 mm/s with these). Geoms collide only through the
    explicit ``<pair>`` list.
    """
    if with_environment:
        half = tuple(s / 2 for s in BLOCK_SIZE)
        x0, y0 = POSITIONS[0].xy
        cameras = "\n".join(
            f'<camera name="{name}" pos="{" ".join(map(str, c.pos))}" xyaxes="{_look_at(c.pos, c.target)}" '
            f'fovy="{c.fovy}"/>'
            for name, c in CAMERAS.items()
        )
        world = f"""
    <light name="key" pos="0.25 -0.3 0.9" dir="-0.25 0.3 -0.9" diffuse="0.7 0.7 0.7" castshadow="true"/>
    <light name="fill" pos="-0.2 0.4 0.8" dir="0.2 -0.4 -0.8" diffuse="0.3 0.3 0.3" castshadow="false"/>
    <geom name="table" type="plane" size="0.6 0.6 0.01" material="table"/>
    {cameras}
    <body name="block" pos="{x0} {y0} {half[2]}">
      <freejoint name="block"/>
      <geom name="block" type="box" size="{half[0]} {half[1]} {half[2]}" mass="{BLOCK_MASS}" material="wood"/>
    </body>"""
        wood, pen = BLOCK_TABLE_FRICTION, PEN_BLOCK_FRICTION  # sliding; torsional 5e-3 m, rolling 1e-4 m
        contacts = f"""
  <contact>
    <pair geom1="block" geom2="table" condim="3" friction="{wood} {wood} 0.005 1e-4 1e-4"/>
    <pair geom1="pen" geom2="block" condim="3" friction="{pen} {pen} 0.005 1e-4 1e-4"/>
    <pair geom1="forearm" geom2="block" condim="3" friction="{pen} {pen} 0.005 1e-4 1e-4"/>
    <pair geom1="pen" geom2="table" condim="3" friction="{pen} {pen} 0.005 1e-4 1e-4"/>
  </contact>"""
    else:
        world = '<light name="key" pos="0 0 1" dir="0 0 -1"/>'
        contacts = ""
    return f"""<mujoco model="pushing_{"slave" if with_environment else "master"}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{DT}" integrator="implicitfast" cone="elliptic" impratio="10" gravity="0 0 {-PUSHING_GRAVITY}"/>
  <visual>
    <global offwidth="{IMAGE_SIZE}" offheight="{IMAGE_SIZE}"/>
    <quality shadowsize="4096"/>
  </visual>
  <default>
    <geom contype="0" conaffinity="0"/>
  </default>
  {_ASSETS}
  <worldbody>
    {world}
    {_arm_xml(arm)}
  </worldbody>
  <actuator>
    {_actuators_xml(arm)}
  </actuator>
  {contacts}
</mujoco>"""


# ----------------------------------------------------------------------------------------------
# Simulated arms
# ----------------------------------------------------------------------------------------------
class ArmSim:
    """One MuJoCo model holding the Touch-like arm; the base of the master and slave sides.

    :meth:`step` applies motor torques (clipped to the torque limits, as a real amplifier
    would) plus any external joint torques and advances ``DT``.
    """

    def __init__(self, xml: str, arm: ArmGeometry = ARM) -> None:
        self.arm = arm
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        self.tip_site = self.model.site("tip").id
        # The arm's joints are consecutive hinges; locate them rather than assume they come first.
        yaw = self.model.joint(JOINT_NAMES[0]).id
        qadr, dadr = self.model.jnt_qposadr[yaw], self.model.jnt_dofadr[yaw]
        self._q = slice(qadr, qadr + N_JOINTS)
        self._dof = slice(dadr, dadr + N_JOINTS)
        self._jacp = np.zeros((3, self.model.nv))
        self._limit = np.asarray(arm.torque_limit)
        self.nominal_inertia = self._nominal_inertia()

    def _nominal_inertia(self) -> np.ndarray:
        """Diagonal of the joint-space inertia at the default pose [kg m²]: the DOB's ``J_n``."""
        self.set_joint_state(default_pose())
        full = np.zeros((self.model.nv, self.model.nv))
        mujoco.mj_fullM(self.model, self.data, full)
        return np.diag(full)[self._dof].copy()

    # -- state ---------------------------------------------------------------------------------
    @property
    def q(self) -> np.ndarray:
        """Joint angles ``(3,)`` [rad] (what the encoders read)."""
        return self.data.qpos[self._q].copy()

    @property
    def qvel(self) -> np.ndarray:
        """True joint velocities ``(3,)`` [rad/s] (not measured on the real device; for tests)."""
        return self.data.qvel[self._dof].copy()

    @property
    def tip(self) -> np.ndarray:
        """Tip position ``(3,)`` [m] in the world frame."""
        return self.data.site_xpos[self.tip_site].copy()

    def tip_velocity(self) -> np.ndarray:
        """Tip linear velocity ``(3,)`` [m/s] (``J_p q̇``)."""
        return self.tip_jacobian() @ self.data.qvel[self._dof]

    def tip_jacobian(self) -> np.ndarray:
        """Positional Jacobian ``(3, 3)`` of the tip w.r.t. the arm joints."""
        mujoco.mj_jacSite(self.model, self.data, self._jacp, None, self.tip_site)
        return self._jacp[:, self._dof].copy()

    def set_joint_state(self, q: np.ndarray, qvel: np.ndarray | None = None) -> None:
        """Put the arm at ``q`` (and ``qvel``, default rest) and recompute kinematics."""
        self.data.qpos[self._q] = q
        self.data.qvel[self._dof] = 0.0 if qvel is None else qvel
        mujoco.mj_forward(self.model, self.data)

    # -- dynamics ------------------------------------------------------------------------------
    def step(self, motor_torque: np.ndarray, external_torque: np.ndarray | None = None) -> np.ndarray:
        """Apply motor torques ``(3,)`` [N m] (saturated) and external torques, advance one ``DT``.

        The torques were computed from the state before the step (the encoders read it), so the
        period is the shared :func:`~seqmotion.sim.backend.control_period` with one physics step.
        External torques ``(3,)`` [N m] (e.g. :meth:`hand_torque`) stay applied until replaced.

        Returns the motor torques actually applied after saturation.
        """
        applied = np.clip(motor_torque, -self._limit, self._limit)
        if external_torque is not None:
            self.data.qfrc_applied[self._dof] = external_torque
        control_period(self.model, self.data, lambda: applied)
        return applied

    def hand_torque(self, force: np.ndarray) -> np.ndarray:
        """Joint torques ``(3,)`` [N m] produced by a force ``(3,)`` [N] pushing on the tip (``Jᵀ F``)."""
        return self.tip_jacobian().T @ force


class MasterArm(ArmSim):
    """The master side: the arm alone, pushed by the (scripted) operator's hand."""

    def __init__(self, arm: ArmGeometry = ARM) -> None:
        super().__init__(pushing_mjcf(with_environment=False, arm=arm), arm)

    def reset(self, q: np.ndarray | None = None) -> None:
        mujoco.mj_resetData(self.model, self.data)
        self.set_joint_state(default_pose() if q is None else q)


@dataclass
class SceneVariation:
    """Seeded nuisance variation of one episode (the "light variation" of the set-up).

    Attributes:
        block_offset: ``(dx, dy)`` [m] of the hand-placed block from its nominal position.
        block_yaw: block rotation about z [rad].
        light_scale: multiplier of the key light's intensity.
        light_shift: ``(3,)`` [m] displacement of the key light.
        block_tint: ``(3,)`` multiplier of the block's RGB.
        table_tint: ``(3,)`` multiplier of the table's RGB.
    """

    block_offset: np.ndarray = field(default_factory=lambda: np.zeros(2))
    block_yaw: float = 0.0
    light_scale: float = 1.0
    light_shift: np.ndarray = field(default_factory=lambda: np.zeros(3))
    block_tint: np.ndarray = field(default_factory=lambda: np.ones(3))
    table_tint: np.ndarray = field(default_factory=lambda: np.ones(3))

    @classmethod
    def sample(cls, rng: np.random.Generator) -> SceneVariation:
        """Small variation: ±4 mm / ±3° block placement, ±15 % light, ±5 cm light position, ±6 % colours."""
        return cls(
            block_offset=rng.uniform(-0.004, 0.004, size=2),
            block_yaw=float(rng.uniform(-math.radians(3), math.radians(3))),
            light_scale=float(rng.uniform(0.85, 1.15)),
            light_shift=rng.uniform(-0.05, 0.05, size=3),
            block_tint=rng.uniform(0.94, 1.06, size=3),
            table_tint=rng.uniform(0.96, 1.04, size=3),
        )


class PushingScene(ArmSim):
    """The slave side: arm, table, wooden block, lights and the webcam.

    Typical use::

        scene = PushingScene()
        scene.reset(block_position(2), SceneVariation.sample(rng))
        image = scene.render("default")           # (64, 64, 3) uint8, before the motion
        scene.step(motor_torque)                   # 1 ms
        scene.success()                            # has the block's centre crossed y = 0?
    """

    def __init__(self, arm: ArmGeometry = ARM) -> None:
        super().__init__(pushing_mjcf(with_environment=True, arm=arm), arm)
        m = self.model
        self.block_body = m.body("block").id
        self._block_qpos = m.jnt_qposadr[m.joint("block").id]
        self._block_geom = m.geom("block").id
        self._table_mat = m.mat("table").id
        self._key_light = m.light("key").id
        # Nominal appearance, restored before each episode's variation is applied.
        self._nominal_block_mat_rgba = m.mat_rgba[m.mat("wood").id].copy()
        self._nominal_table_rgba = m.mat_rgba[self._table_mat].copy()
        self._nominal_light_pos = m.light_pos[self._key_light].copy()
        self._nominal_light_diffuse = m.light_diffuse[self._key_light].copy()
        self._renderer: Renderer | None = None  # the webcam, opened on first use
        self.position: BlockPosition = POSITIONS[0]

    def reset(
        self, position: BlockPosition, variation: SceneVariation | None = None, q: np.ndarray | None = None
    ) -> None:
        """Place the arm at ``q`` (default pose) and the block at ``position`` (+ variation), all at rest."""
        variation = variation or SceneVariation()
        m = self.model
        mujoco.mj_resetData(m, self.data)
        self.position = position
        xy = position.xy + variation.block_offset
        adr = self._block_qpos
        self.data.qpos[adr : adr + 3] = (xy[0], xy[1], BLOCK_SIZE[2] / 2)
        half_yaw = variation.block_yaw / 2
        self.data.qpos[adr + 3 : adr + 7] = (math.cos(half_yaw), 0.0, 0.0, math.sin(half_yaw))
        wood = m.mat("wood").id
        m.mat_rgba[wood, :3] = np.clip(self._nominal_block_mat_rgba[:3] * variation.block_tint, 0, 1)
        m.mat_rgba[self._table_mat, :3] = np.clip(self._nominal_table_rgba[:3] * variation.table_tint, 0, 1)
        m.light_pos[self._key_light] = self._nominal_light_pos + variation.light_shift
        m.light_diffuse[self._key_light] = np.clip(self._nominal_light_diffuse * variation.light_scale, 0, 1)
        self.set_joint_state(default_pose() if q is None else q)

    # -- block ---------------------------------------------------------------------------------
    @property
    def block_pose(self) -> np.ndarray:
        """Block pose ``(7,)``: centre position [m] and orientation quaternion (w, x, y, z)."""
        adr = self._block_qpos
        return self.data.qpos[adr : adr + 7].copy()

    def set_state(self, q: np.ndarray, block_pose: np.ndarray) -> None:
        """Pose the arm at ``q`` ``(3,)`` [rad] and the block at ``block_pose`` ``(7,)``, at rest (for replaying
        a recorded run, e.g. to render it); does not step the physics."""
        adr = self._block_qpos
        self.data.qpos[adr : adr + 7] = block_pose
        self.data.qvel[:] = 0.0
        self.set_joint_state(q)

    def success(self) -> bool:
        """True once the block's centre lies on the other side of the robot's centre line."""
        return bool(self.position.sign * self.data.qpos[self._block_qpos + 1] < 0.0)

    # -- camera --------------------------------------------------------------------------------
    def render(self, camera: str = "default") -> np.ndarray:
        """One webcam image ``(64, 64, 3)`` uint8 from camera ``camera`` (a key of :data:`CAMERAS`)."""
        if camera not in CAMERAS:
            raise ValueError(f"unknown camera {camera!r}; choose one of {sorted(CAMERAS)}")
        if self._renderer is None:
            self._renderer = Renderer(self.model, IMAGE_SIZE, IMAGE_SIZE)
        return self._renderer.render(self.data, camera)

    def render_states(
        self, theta: Sequence[np.ndarray], block_pose: Sequence[np.ndarray], width: int = 320, height: int = 240
    ) -> list[np.ndarray]:
        """Frames ``(height, width, 3)`` uint8 of recorded states, seen from :data:`OVERVIEW` (for figures).

        Each arm pose ``theta[i]`` ``(3,)`` [rad] and block pose ``block_pose[i]`` ``(7,)`` is
        written into the scene (:meth:`set_state`, no physics) and rendered; the scene keeps its
        current lighting and colours (reset it with the run's variation first). Enlarges the
        model's offscreen buffer to the frame size if needed.
        """
        renderer = Renderer(self.model, width, height, grow_buffer=True)
        camera = free_camera(**OVERVIEW)
        frames = []
        try:
            for q, pose in zip(theta, block_pose, strict=True):
                self.set_state(q, pose)
                frames.append(renderer.render(self.data, camera))
        finally:
            renderer.close()
        return frames

    def close(self) -> None:
        """Release the offscreen rendering context (if one was opened)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
