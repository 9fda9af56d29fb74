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

from ...errors import check_number
from ...sim.backend import CONTROL_DT, PUSHING_GRAVITY, control_period, import_mujoco
from ...sim.render import Renderer, free_camera

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

SHAPES = ("box", "cylinder")
"""Objects the robot pushes: the chapter's wooden block (``box``) and, on the hard benchmark, a
smaller, lighter painted-wood ``cylinder`` standing on its end."""

CYLINDER_RADIUS = 0.03
CYLINDER_HEIGHT = 0.05
CYLINDER_MASS = 600.0 * math.pi * CYLINDER_RADIUS**2 * CYLINDER_HEIGHT
"""[m], [m], [kg]: 6 cm across, 5 cm high, 0.085 kg at the block's 600 kg/m³."""


def object_half_height(shape: str) -> float:
    """Height of the object's centre above the table when it stands as placed [m]."""
    return (BLOCK_SIZE[2] if shape == "box" else CYLINDER_HEIGHT) / 2


def face_offset(shape: str, yaw: float) -> float:
    """Lateral (y) distance [m] from the object's centre to its outer boundary at the centre's x.

    Where the pen meets the object when it pushes along y through the centre: for the box turned
    by ``yaw`` its long face (half-depth ``BLOCK_SIZE[1] / 2``) crosses the line at
    ``half / cos(yaw)``; a cylinder's at its radius.
    """
    if shape == "cylinder":
        return CYLINDER_RADIUS
    return BLOCK_SIZE[1] / 2 / max(math.cos(yaw), 0.5)


def lateral_extent(shape: str, yaw: float) -> float:
    """Half the object's width along y [m] (the box's corners when turned): what a pen must clear."""
    if shape == "cylinder":
        return CYLINDER_RADIUS
    return abs(BLOCK_SIZE[0] / 2 * math.sin(yaw)) + abs(BLOCK_SIZE[1] / 2 * math.cos(yaw))


@dataclass(frozen=True)
class BlockPosition:
    """Where the object is placed: one of the chapter's six positions, or a hard-benchmark draw.

    Attributes:
        index: 0..5, ordered left 4.5, left 8.0, left 11.5, right 4.5, right 8.0, right 11.5;
            −1 for a placement drawn from the hard benchmark's continuous region.
        side: ``"left"`` (+y, pushed to the right) or ``"right"`` (−y, pushed to the left).
        distance: lateral distance of the object's centre from the robot's centre line [m].
        reach: forward position of the object's centre [m].
        shape: one of :data:`SHAPES`.
    """

    index: int
    side: str
    distance: float
    reach: float = BLOCK_REACH_X
    shape: str = "box"

    @property
    def sign(self) -> float:
        """+1 on the robot's left (block at +y), −1 on its right."""
        return 1.0 if self.side == "left" else -1.0

    @property
    def xy(self) -> np.ndarray:
        """Nominal block-centre position ``(2,)`` [m] on the table."""
        return np.array([self.reach, self.sign * self.distance])

    @property
    def name(self) -> str:
        if self.index >= 0:
            return f"{self.side}_{round(self.distance * 1000) / 10:g}cm"
        return f"{self.shape}_{self.side}_{self.distance * 100:.1f}cm_x{self.reach * 100:.1f}cm"


POSITIONS: tuple[BlockPosition, ...] = tuple(
    BlockPosition(i, side, d) for i, (side, d) in enumerate((s, d) for s in SIDES for d in DISTANCES)
)


BENCHMARKS = ("chapter", "hard")
"""``chapter``: the six positions of Fig. 5.5 with small placement noise (dissertation 5.3.5);
``hard``: see :func:`sample_hard_placement`."""

HARD_DISTANCE = (0.02, 0.14)
"""Hard benchmark: lateral distance of the object's centre from the centre line [m], the chapter's
span 4.5–11.5 cm (centre 8 cm) widened to 8 ± 6 cm."""
HARD_REACH = (0.14, 0.18)
"""Hard benchmark: forward position of the object's centre [m] (the chapter's 16 cm ± 2 cm; the
Touch's workspace is 16.5 cm deep)."""
HARD_YAW = math.radians(30.0)
"""Hard benchmark: the object's rotation about z is uniform in ± this [rad]."""
GOAL_PAST = 0.035
GOAL_TOLERANCE = 0.02
"""Hard benchmark success: the goal line is the chapter's (the robot's centre line, which the block
must cross) moved ``GOAL_PAST`` [m] on, to where the demonstrators leave the object (they aim 1–3 cm
past the centre line and it slides on; median 4.0 cm over 40 hard demonstrations), and the object's
centre must end within ``GOAL_TOLERANCE`` [m] of it: across the centre line by 1.5–5.5 cm. Pushing
the object across is not enough; it must be put down there."""
EPISODE_SECONDS = {"chapter": 4.0, "hard": 6.0}
"""Length of one episode [s] (demonstration or closed-loop trial) on each benchmark: the chapter's 4 s
(5.3.3). The hard benchmark's pushes are up to 17.5 cm long and a demonstrator often needs a second
push to put the object on the goal line; 4 s leaves no time for it (in 600 hard episodes of 4 s the
scripted operator put 78.5 % of the objects on the goal line, running out of time short of it at far
placements; in 300 of 6 s, 93 %)."""
TABLE_HALF = 0.6
"""The table's half-size [m] (the plane's extent): beyond it the object has left the table."""


def sample_hard_placement(rng: np.random.Generator) -> tuple[BlockPosition, SceneVariation]:
    """One episode of the hard benchmark: placement, object, distractors, camera and lighting.

    * the object: box or cylinder (equally likely), its centre anywhere in :data:`HARD_DISTANCE` ×
      :data:`HARD_REACH` on either side, turned uniformly within ± :data:`HARD_YAW`;
    * 0, 1 or 2 distractors (small boxes and cylinders of random colour) on the table in front of the
      workspace, where neither pen nor object goes, in view of the webcam;
    * the webcam moved by up to ±1 cm along each axis and turned by up to ±2° about each axis;
    * lighting ×U(0.6, 1.4), the key light moved ±15 cm, colours of object and table ±20 % / ±10 %.
    """
    side = SIDES[int(rng.integers(2))]
    position = BlockPosition(
        -1, side, float(rng.uniform(*HARD_DISTANCE)), float(rng.uniform(*HARD_REACH)), SHAPES[int(rng.integers(2))]
    )
    count = int(rng.integers(3))
    poses = np.zeros((MAX_DISTRACTORS, 3))
    poses[:, 0] = rng.uniform(0.26, 0.33, size=MAX_DISTRACTORS)
    # one distractor on each half of the table, so two never overlap
    poses[:, 1] = rng.uniform(0.02, 0.16, size=MAX_DISTRACTORS) * np.array([1.0, -1.0])
    poses[:, 2] = rng.uniform(-math.pi, math.pi, size=MAX_DISTRACTORS)
    variation = SceneVariation(
        block_offset=np.zeros(2),
        block_yaw=float(rng.uniform(-HARD_YAW, HARD_YAW)),
        light_scale=float(rng.uniform(0.6, 1.4)),
        light_shift=rng.uniform(-0.15, 0.15, size=3),
        block_tint=rng.uniform(0.8, 1.2, size=3),
        table_tint=rng.uniform(0.9, 1.1, size=3),
        camera_shift=rng.uniform(-0.01, 0.01, size=3),
        camera_turn=rng.uniform(-math.radians(2), math.radians(2), size=3),
        distractors=np.arange(MAX_DISTRACTORS) < count,
        distractor_pose=poses,
        distractor_rgb=rng.uniform(0.1, 0.95, size=(MAX_DISTRACTORS, 3)),
    )
    return position, variation


def block_position(index: int) -> BlockPosition:
    """The nominal placement with this index (0..5); ``ValueError`` otherwise."""
    return POSITIONS[check_number(f"block position index (0..{len(POSITIONS) - 1})", index, minimum=0,
                                  maximum=len(POSITIONS) - 1, integer=True)]


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


PARKED_XY = (-2.0, 0.0)
"""Where the hard scene keeps the object not in use [m]: on the table far behind the robot, out of
every webcam's view (and the distractors not shown, below the table)."""


def _hard_objects_xml() -> str:
    """The hard scene's cylinder (parked until an episode uses it) and its distractors (visual only)."""
    distractors = "\n".join(
        f'<geom name="distractor{i}" type="{kind}" pos="{PARKED_XY[0]} {0.3 * i} -0.5" size="{size}" '
        f'material="distractor{i}"/>'
        for i, (kind, size) in enumerate((("box", "0.014 0.02 0.016"), ("cylinder", "0.013 0.022")))
    )
    return f"""
    <body name="cylinder" pos="{PARKED_XY[0]} {PARKED_XY[1]} {CYLINDER_HEIGHT / 2}">
      <freejoint name="cylinder"/>
      <geom name="cylinder" type="cylinder" size="{CYLINDER_RADIUS} {CYLINDER_HEIGHT / 2}" mass="{CYLINDER_MASS}"
        material="paint"/>
    </body>
    {distractors}"""


_HARD_ASSETS = """  <material name="paint" rgba="0.70 0.22 0.18 1"/>
    <material name="distractor0" rgba="0.2 0.5 0.8 1"/>
    <material name="distractor1" rgba="0.8 0.8 0.2 1"/>
  </asset>"""


def pushing_mjcf(with_environment: bool = True, arm: ArmGeometry = ARM, benchmark: str = "chapter") -> str:
    """MJCF text of the slave scene (``with_environment``) or of the bare master arm.

    ``benchmark="hard"`` adds the hard benchmark's cylinder and distractors to the slave scene
    (the chapter's scene is unchanged by it).

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
    </body>{_hard_objects_xml() if benchmark == "hard" else ""}"""
        wood, pen = BLOCK_TABLE_FRICTION, PEN_BLOCK_FRICTION  # sliding; torsional 5e-3 m, rolling 1e-4 m
        objects = ("block", "cylinder") if benchmark == "hard" else ("block",)
        pairs = "\n    ".join(
            f'<pair geom1="{a}" geom2="{b}" condim="3" friction="{mu} {mu} 0.005 1e-4 1e-4"/>'
            for name in objects
            for a, b, mu in ((name, "table", wood), ("pen", name, pen), ("forearm", name, pen))
        )
        contacts = f"""
  <contact>
    {pairs}
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
    <quality shadowsize="{4096 if benchmark == "chapter" else 1024}"/>
  </visual>
  <default>
    <geom contype="0" conaffinity="0"/>
  </default>
  {_ASSETS if benchmark != "hard" else _ASSETS.replace("</asset>", _HARD_ASSETS)}
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


MAX_DISTRACTORS = 2
"""Distractor objects the hard scene holds (each episode shows 0 to this many)."""


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
        camera_shift: ``(3,)`` [m] displacement of every webcam (hard benchmark).
        camera_turn: ``(3,)`` [rad] rotation vector turning every webcam about its own axes (hard).
        distractors: ``(MAX_DISTRACTORS,)`` bool, which distractors stand on the table (hard).
        distractor_pose: ``(MAX_DISTRACTORS, 3)`` their ``x, y`` [m] and yaw [rad].
        distractor_rgb: ``(MAX_DISTRACTORS, 3)`` their colours.

    The hard benchmark's fields are neutral by default and only the hard scene has distractors.
    """

    block_offset: np.ndarray = field(default_factory=lambda: np.zeros(2))
    block_yaw: float = 0.0
    light_scale: float = 1.0
    light_shift: np.ndarray = field(default_factory=lambda: np.zeros(3))
    block_tint: np.ndarray = field(default_factory=lambda: np.ones(3))
    table_tint: np.ndarray = field(default_factory=lambda: np.ones(3))
    camera_shift: np.ndarray = field(default_factory=lambda: np.zeros(3))
    camera_turn: np.ndarray = field(default_factory=lambda: np.zeros(3))
    distractors: np.ndarray = field(default_factory=lambda: np.zeros(MAX_DISTRACTORS, dtype=bool))
    distractor_pose: np.ndarray = field(default_factory=lambda: np.zeros((MAX_DISTRACTORS, 3)))
    distractor_rgb: np.ndarray = field(default_factory=lambda: np.full((MAX_DISTRACTORS, 3), 0.5))

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


def _axis_angle(rotation: np.ndarray) -> tuple[np.ndarray, float]:
    """``(unit axis (3,), angle [rad])`` of a rotation vector (any axis for no rotation)."""
    angle = float(np.linalg.norm(rotation))
    return (np.asarray(rotation, dtype=np.float64) / angle if angle > 0 else np.array([0.0, 0.0, 1.0])), angle


class PushingScene(ArmSim):
    """The slave side: arm, table, wooden block, lights and the webcam.

    Typical use::

        scene = PushingScene()
        scene.reset(block_position(2), SceneVariation.sample(rng))
        image = scene.render("default")           # (64, 64, 3) uint8, before the motion
        scene.step(motor_torque)                   # 1 ms
        scene.success()                            # has the block's centre crossed y = 0?
    """

    def __init__(self, arm: ArmGeometry = ARM, benchmark: str = "chapter") -> None:
        if benchmark not in BENCHMARKS:
            raise ValueError(f"unknown benchmark {benchmark!r}; choose one of {BENCHMARKS}")
        super().__init__(pushing_mjcf(with_environment=True, arm=arm, benchmark=benchmark), arm)
        self.benchmark = benchmark
        m = self.model
        self.block_body = m.body("block").id
        # qpos address of each object's free joint; the one in use is the episode's "block"
        self._object_qpos = {
            shape: int(m.jnt_qposadr[m.joint(name).id])
            for shape, name in (("box", "block"), ("cylinder", "cylinder"))
            if benchmark == "hard" or shape == "box"
        }
        self._block_qpos = self._object_qpos["box"]
        self._block_geom = m.geom("block").id
        self._nominal_cameras = (m.cam_pos.copy(), m.cam_quat.copy())
        self._distractors = [m.geom(f"distractor{i}").id for i in range(MAX_DISTRACTORS)] if benchmark == "hard" else []
        self._distractor_parked = m.geom_pos[self._distractors].copy() if self._distractors else None
        self._table_mat = m.mat("table").id
        self._key_light = m.light("key").id
        # Nominal appearance, restored before each episode's variation is applied.
        self._nominal_block_mat_rgba = m.mat_rgba[m.mat("wood").id].copy()
        self._nominal_paint_rgba = m.mat_rgba[m.mat("paint").id].copy() if benchmark == "hard" else None
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
        if position.shape not in self._object_qpos:
            raise ValueError(
                f"the {self.benchmark} scene has no {position.shape!r}; it holds {sorted(self._object_qpos)}"
            )
        m = self.model
        mujoco.mj_resetData(m, self.data)  # (every object back at its MJCF position: the unused one parked)
        self.position = position
        xy = position.xy + variation.block_offset
        adr = self._block_qpos = self._object_qpos[position.shape]
        self.data.qpos[adr : adr + 3] = (xy[0], xy[1], object_half_height(position.shape))
        half_yaw = variation.block_yaw / 2
        self.data.qpos[adr + 3 : adr + 7] = (math.cos(half_yaw), 0.0, 0.0, math.sin(half_yaw))
        if position.shape != "box":  # the block is parked where the cylinder waited
            box = self._object_qpos["box"]
            self.data.qpos[box : box + 3] = (*PARKED_XY, BLOCK_SIZE[2] / 2)
            self.data.qpos[box + 1] += 0.5
        material = m.mat("wood" if position.shape == "box" else "paint").id
        nominal = self._nominal_block_mat_rgba if position.shape == "box" else self._nominal_paint_rgba
        m.mat_rgba[material, :3] = np.clip(nominal[:3] * variation.block_tint, 0, 1)
        if self._distractors:
            self._place_distractors(variation)
        self._place_cameras(variation)
        m.mat_rgba[self._table_mat, :3] = np.clip(self._nominal_table_rgba[:3] * variation.table_tint, 0, 1)
        m.light_pos[self._key_light] = self._nominal_light_pos + variation.light_shift
        m.light_diffuse[self._key_light] = np.clip(self._nominal_light_diffuse * variation.light_scale, 0, 1)
        self.set_joint_state(default_pose() if q is None else q)

    def _place_distractors(self, variation: SceneVariation) -> None:
        m = self.model
        for i, geom in enumerate(self._distractors):
            if variation.distractors[i]:
                x, y, yaw = variation.distractor_pose[i]
                m.geom_pos[geom] = (x, y, m.geom_size[geom][2 if m.geom_type[geom] == mujoco.mjtGeom.mjGEOM_BOX else 1])
                m.geom_quat[geom] = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
            else:
                m.geom_pos[geom] = self._distractor_parked[i]
            m.mat_rgba[m.geom_matid[geom], :3] = variation.distractor_rgb[i]

    def _place_cameras(self, variation: SceneVariation) -> None:
        """Every webcam at its nominal pose moved by ``camera_shift`` and turned by ``camera_turn``."""
        m = self.model
        pos, quat = self._nominal_cameras
        m.cam_pos[:] = pos + variation.camera_shift
        turn = np.zeros(4)
        mujoco.mju_axisAngle2Quat(turn, *_axis_angle(variation.camera_turn))
        for i in range(m.ncam):
            mujoco.mju_mulQuat(m.cam_quat[i], quat[i], turn)  # about the camera's own axes

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
        """Has the task succeeded, as the object lies now?

        ``chapter``: the block's centre lies on the other side of the robot's centre line.
        ``hard``: the object's centre lies within :data:`GOAL_TOLERANCE` of the goal line
        (:data:`GOAL_PAST` beyond the centre line) and the object is still on the table, standing
        as it was placed (centre within 1 cm of its resting height).
        """
        x, y, z = self.data.qpos[self._block_qpos : self._block_qpos + 3]
        past = -self.position.sign * y  # how far past the centre line [m]
        if self.benchmark == "chapter":
            return bool(past > 0.0)
        on_table = max(abs(x), abs(y)) < TABLE_HALF and abs(z - object_half_height(self.position.shape)) < 0.01
        return bool(on_table and abs(past - GOAL_PAST) <= GOAL_TOLERANCE)

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
