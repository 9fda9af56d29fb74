"""MuJoCo scenes: a MOTOMAN-MH3F-like 6-DOF arm on a table holding a spatula or a frying pan.

Read this file top to bottom to see the whole robot. Everything is written here as MJCF text
(no asset files), from the named constants below, so the geometry a test or a figure refers
to is the geometry simulated.

World frame: z up, the robot's base (joint 1 axis) at the origin on a 0.2 m riser, facing +x;
the table top at z = :data:`TABLE_TOP` = -0.2 m, so the blade clears it everywhere the
position-type inputs go (z ≥ -0.3 in planar coordinates) and a pancake that leaves the
spatula lands on it. The task-space commands of the dissertation (SPEC §§4–5) are poses of the
**tool control site**:

* spatula (chs. 2, 4): ``q = [0.5, y, z + 0.35, θ, π/2, 0]``; the site is the resting centre of
  mass of the pancake on the blade, so the planar state ``(y, z, θ)`` is the pancake's centre
  and the blade's tilt, exactly as in the 2-D model.
* frying pan (ch. 3): ``q = [x_p + 0.65, y_p, 0.3, 0, π/2, 0]``; the site is the centre of the
  pan's cooking surface.

Tool frame (both tools, the site's frame): **z** along the tool away from the flange, **x** the
surface's *down* normal (into the blade / pan), **y = z × x**. With the attitude convention of
:mod:`seqmotion.sim.kinematics` (``R = Rx(a) Ry(b) Rz(c)``), ``(a, b, c) = (0, π/2, 0)`` points
the tool along world +x with its surface facing up, and ``a = θ`` rolls it about world x.

Arm (MH3F-like, reach ≈ 0.54 m from the joint-1 axis to the wrist centre; the MH3F datasheet
gives 532 mm): S (z), L (y), U (y), R (forearm axis), B (y), T (flange axis), all torque
driven without torque limits; joint ranges are not modelled (the tasks stay well inside the
MH3F's ±170°…±360° axes, and :func:`seqmotion.sim.arm.workspace_problem` keeps commands
inside the reach). Arm links do not collide with anything; only the tool surfaces, the table
and the manipulated objects do.

Contact model (chosen so that MuJoCo's friction is the Coulomb friction of the 2-D models;
the calibration is in ``benchmarks/RESULTS_sim.md``):

* ``cone="elliptic"``: an isotropic Coulomb cone ``|f_t| ≤ μ f_n``, the cone of eq. 2.6 and of
  the sliding model (a pyramidal cone would make friction direction dependent).
* ``condim=3``: sliding friction only. The pancake and the object touch their tool through
  several contact points (below), so rotation about the normal is resisted by sliding friction
  at the points, as for a real flat contact, without MuJoCo's torsional-friction parameter.
* ``impratio=10`` (MuJoCo's advice for manipulation): friction rows stiffer than normal rows,
  so a loaded contact inside the cone barely creeps (measured: 3 µm in 1.5 s held at 40°).
* ``solref="0.004 1"`` (stiff, critically damped normal contact: the pancake rests ~25 µm deep)
  with ``solimp="0.95 0.99 0.001"``; physics time step :data:`PHYSICS_DT` = 0.5 ms (2 substeps
  per 1 ms control period), so ``solref[0] ≥ 2 × timestep`` holds with margin.
* friction rows of the object–tool contacts use ``solreffriction`` with damping
  :data:`FRICTION_DAMPING` = 1 / timestep: a slip velocity is removed in one step, i.e. sticking
  is a hard velocity constraint. Why: MuJoCo's friction rows relax slip velocity with the
  contact time constant, and on an articulated arm the tool's velocity-product acceleration
  ``J̇ q̇`` re-injects slip every step, giving a steady slip ``≈ J̇ q̇ / b`` (~1 cm/s with the
  default ``b`` at 2 m/s tool speeds: the pancake crept 3 mm over feasible motions; a free
  blade replaying the same motion did not). The NoSlip post-solver cannot remove it (it keeps
  the reference acceleration). With ``b = 1/h`` the creep is ≤ 0.6 mm over such motions.
  NoSlip is then left off (:data:`NOSLIP_ITERATIONS` = 0): with it, creep at 40° fell from
  3 µm to 0 over 1.5 s and nothing else changed, at 20–40 % more time per step. The
  frying pan's object does **not** get this damping (:data:`OBJECT_FRICTION_DAMPING`): its
  friction rows use the contact's own ``solref``. Why: the pan stays level (no ``J̇ q̇`` tilt
  creep to remove: 0.1 mm in 0.6 s held at 0.85 μg without it), and with it an object that
  slides for long stretches rocks and hops on its rim (the solver raises the normal force to
  buy the friction that the stiff rows ask for): on a pan circle at 2 μg it tilted 7.7° and
  rose 3.8 mm (0.9° and 0.6 mm without), and the refined 5 cm circle plan of the README
  was airborne 85 % of its motion, 23° tilted (benchmarks/bench_refine_arm.py). The
  object–tool contacts are explicit ``<pair>`` elements (tool surfaces have ``contype="2"
  conaffinity="0"`` so they are not also generated dynamically); their friction coefficient
  is the pair's.
* friction coefficients: pancake and blade 1.0 (μ of ch. 2); object and pan 0.5 (μ = μ' of the
  ch.-3 3-D check; MuJoCo has one coefficient for static and dynamic friction), set on the
  pairs; the geoms carry the same values for their other contacts (the table).
* ``jacobian="dense"``: the model is small (nv = 12), and MuJoCo 4.0.0's sparse Cholesky has a
  known bug (fixed in 4.0.1, issue #3767) that dense avoids.

Objects: the pancake is a rigid disc (radius :data:`PANCAKE_RADIUS`, 1 cm thick) whose
collision shape is a centre sphere plus a ring of spheres of radius = half its thickness — a
flat disc with a rounded ("soft") edge; the frying-pan object is a cylinder whose base is a
ring of small spheres (its real contact is its rim) and whose side is a cylinder geom for
impacts with the pan's wall. Sphere–box and sphere–cylinder contacts are analytic in MuJoCo,
so a flat object rests on several exact contact points instead of one convex-collision point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..tasks.pancake.physics import MU as MU_PANCAKE
from .backend import CONTROL_DT, GRAVITY, import_mujoco
from .robot_models import Robot, placed_for, resolve_robot, tool_mount

# CONTROL_DT (from .backend): the control period [s], 1 ms everywhere (SPEC §2).
PHYSICS_DT = 5e-4
"""MuJoCo time step [s]; the torque is held for ``CONTROL_DT / PHYSICS_DT`` steps."""
SUBSTEPS = round(CONTROL_DT / PHYSICS_DT)
NOSLIP_ITERATIONS = 0
"""NoSlip post-solver sweeps per step: not needed with :data:`FRICTION_DAMPING` (module docstring)."""
# GRAVITY (from .backend) is the 2-D models' 9.8 m/s², not MuJoCo's default 9.81.

ARM_JOINTS = ("s", "l", "u", "r", "b", "t")
"""Joint names, base to flange (Yaskawa's S, L, U, R, B, T axes)."""
SHOULDER_HEIGHT = 0.35
"""Height of the L axis above the table [m] (the nominal tool height of chs. 2 and 4)."""
SHOULDER_OFFSET = 0.03
"""Forward offset of the L axis from the S axis [m]."""
UPPER_ARM = 0.25
"""L axis to U axis [m]."""
FOREARM = 0.26
"""U axis to the wrist centre (B axis) [m]."""
WRIST_TO_FLANGE = 0.05
"""B axis to the flange [m]."""

# Spatula and pancake (chs. 2, 4).
SPATULA_HANDLE = 0.085
"""Flange to the blade's near edge [m]."""
BLADE_HALF = (0.0015, 0.075, 0.075)
"""Blade box half sizes along the tool (x: thickness, y: width, z: length) [m]."""
BLADE_CENTRE = SPATULA_HANDLE + BLADE_HALF[2]
"""Flange to the blade centre along the tool axis [m]."""
PANCAKE_RADIUS = 0.055
"""Outer radius of the pancake's contact shape [m]."""
PANCAKE_HALF_THICKNESS = 0.005
"""[m]; also the radius of its edge spheres."""
PANCAKE_MASS = 0.08
"""[kg] (a rubber plate of this size, as in §4.4.1)."""
PANCAKE_RING = 8
"""Number of edge spheres (plus one at the centre)."""
# MU_PANCAKE (imported above): friction between pancake and spatula, the 2-D model's μ (SPEC §3).

# Frying pan and object (ch. 3).
PAN_HANDLE = 0.18
"""Flange to the pan's rim along the tool axis [m]."""
PAN_RADIUS = 0.12
"""Radius of the pan's flat cooking surface [m]."""
PAN_CENTRE = PAN_HANDLE + PAN_RADIUS
"""Flange to the pan centre along the tool axis [m]."""
PAN_WALL_HEIGHT = 0.035
"""[m]"""
PAN_WALL_SEGMENTS = 24
OBJECT_RADIUS = 0.03
"""[m]"""
OBJECT_HALF_HEIGHT = 0.03
"""[m]; tipping needs a/g > radius / half-height = 1 > μ = 0.5, so it slides before it tips."""
OBJECT_MASS = 0.2
"""[kg]"""
OBJECT_FOOT_RADIUS = 0.003
"""Radius of the spheres forming the object's base rim [m]."""
OBJECT_FEET = 8
MU_OBJECT = 0.5
"""Friction between object and pan: μ = μ' = 0.5 (§3.5.1)."""

TABLE_TOP = -0.2
TABLE_CLEARANCE = 0.11
"""[m] The tool's control site stays this far above the table top (the blade and the pancake clear it): the
simulator refuses a command below (:func:`seqmotion.sim.arm.workspace_problem`)."""
"""Height of the table surface [m]."""

# Where the tasks put the tool (SPEC §§4–5).
PANCAKE_ORIGIN = np.array([0.5, 0.0, 0.35])
"""Tool position for the planar state (y, z) = (0, 0) [m]."""
PAN_ORIGIN = np.array([0.65, 0.0, 0.3])
"""Tool position for the pan state (x_p, y_p) = (0, 0) [m]."""
TOOL_PITCH = math.pi / 2
"""The fixed second attitude angle of both commands."""

CONTACT_SOLREF = "0.004 1"
CONTACT_SOLIMP = "0.95 0.99 0.001"
CONTACT_DEFAULTS = f'condim="3" solref="{CONTACT_SOLREF}" solimp="{CONTACT_SOLIMP}"'
"""Contact parameters shared by every colliding geom (see the module docstring)."""
FRICTION_DAMPING = 1.0 / PHYSICS_DT
"""Damping of the friction rows of the pancake–spatula contacts [1/s]: slip removed within one step."""
OBJECT_FRICTION_DAMPING: float | None = None
"""The object–pan contacts' friction-row damping: none (their own ``solref``; module docstring)."""
TOOL_SURFACE = 'contype="2" conaffinity="0"'
"""Tool surfaces touch the object only through explicit pairs (see the module docstring)."""

_VISUAL = 'contype="0" conaffinity="0" group="1" density="0"'


def _arm_xml(tool: str) -> str:
    """The arm's kinematic chain with ``tool`` (MJCF of the tool body's children) on the flange.

    At zero joint angles the upper arm is vertical and the forearm and flange point along +x.
    The tool body is rotated by Ry(π/2) from the flange so that its z axis is the flange axis
    and its x axis points down: the arm's zero pose holds the tool at attitude (0, π/2, 0).
    """
    q_tool = f"{math.cos(math.pi / 4):.12f} 0 {math.sin(math.pi / 4):.12f} 0"
    return f"""
    <body name="base" pos="0 0 0">
      <geom type="cylinder" size="0.09 0.05" pos="0 0 0.05" rgba="0.2 0.3 0.6 1" {_VISUAL}/>
      <body name="link1" pos="0 0 0.1">
        <joint name="s" axis="0 0 1" armature="0.1" damping="1.0"/>
        <inertial pos="0.01 0 0.12" mass="6" diaginertia="0.06 0.06 0.03"/>
        <geom type="cylinder" size="0.075 0.12" pos="0 0 0.12" rgba="0.2 0.3 0.6 1" {_VISUAL}/>
        <body name="link2" pos="{SHOULDER_OFFSET} 0 {SHOULDER_HEIGHT - 0.1}">
          <joint name="l" axis="0 1 0" armature="0.1" damping="1.0"/>
          <inertial pos="0 0 {UPPER_ARM / 2}" mass="4" diaginertia="0.03 0.03 0.006"/>
          <geom type="capsule" fromto="0 0 0 0 0 {UPPER_ARM}" size="0.05" rgba="0.85 0.85 0.9 1" {_VISUAL}/>
          <body name="link3" pos="0 0 {UPPER_ARM}">
            <joint name="u" axis="0 1 0" armature="0.08" damping="0.8"/>
            <inertial pos="0.05 0 0" mass="2.5" diaginertia="0.005 0.01 0.01"/>
            <geom type="capsule" fromto="-0.03 0 0 0.1 0 0" size="0.045" rgba="0.85 0.85 0.9 1" {_VISUAL}/>
            <body name="link4" pos="0 0 0">
              <joint name="r" axis="1 0 0" armature="0.02" damping="0.2"/>
              <inertial pos="{FOREARM * 0.6} 0 0" mass="1.5" diaginertia="0.002 0.008 0.008"/>
              <geom type="capsule" fromto="0.1 0 0 {FOREARM - 0.03} 0 0" size="0.035" rgba="0.85 0.85 0.9 1"
                    {_VISUAL}/>
              <body name="link5" pos="{FOREARM} 0 0">
                <joint name="b" axis="0 1 0" armature="0.02" damping="0.2"/>
                <inertial pos="0.02 0 0" mass="0.8" diaginertia="0.0008 0.0008 0.0008"/>
                <geom type="cylinder" size="0.035 0.03" quat="0.7071068 0.7071068 0 0" rgba="0.2 0.3 0.6 1"
                      {_VISUAL}/>
                <body name="link6" pos="{WRIST_TO_FLANGE} 0 0">
                  <joint name="t" axis="1 0 0" armature="0.01" damping="0.05"/>
                  <inertial pos="-0.01 0 0" mass="0.2" diaginertia="0.0002 0.0002 0.0002"/>
                  <geom type="cylinder" size="0.03 0.01" pos="-0.01 0 0" quat="0.7071068 0 0.7071068 0"
                        rgba="0.3 0.3 0.3 1" {_VISUAL}/>
                  <site name="flange" size="0.005"/>
                  <body name="tool" quat="{q_tool}">
{tool}
                  </body>
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>"""


def _spatula_xml() -> str:
    """Spatula in the tool frame (z along it, x down); the site is the pancake's resting centre."""
    bx, by, bz = BLADE_HALF
    site_x = -bx - PANCAKE_HALF_THICKNESS  # above the blade's top face by half a pancake
    return f"""
                    <geom name="spatula_handle" type="capsule" fromto="0 0 0 0 0 {SPATULA_HANDLE}" size="0.007"
                          rgba="0.4 0.3 0.2 1" contype="0" conaffinity="0" group="1" mass="0.05"/>
                    <geom name="blade" type="box" size="{bx} {by} {bz}" pos="0 0 {BLADE_CENTRE}" mass="0.1"
                          rgba="0.75 0.75 0.78 1" {TOOL_SURFACE}/>
                    <site name="tool" pos="{site_x} 0 {BLADE_CENTRE}" size="0.004" rgba="1 0 0 1"/>"""


def _pan_xml() -> str:
    """Frying pan in the tool frame; the site is the centre of its cooking surface."""
    bottom_half = 0.004
    wall_half_len = math.pi * PAN_RADIUS / PAN_WALL_SEGMENTS * 1.05
    walls = []
    for i in range(PAN_WALL_SEGMENTS):
        phi = 2 * math.pi * i / PAN_WALL_SEGMENTS
        y, z = (PAN_RADIUS + 0.003) * math.sin(phi), PAN_CENTRE + (PAN_RADIUS + 0.003) * math.cos(phi)
        # Box axes: x along the pan normal, y tangential, z radial (rotate about x by -phi).
        quat = f"{math.cos(-phi / 2):.9f} {math.sin(-phi / 2):.9f} 0 0"
        walls.append(
            f'<geom type="box" size="{PAN_WALL_HEIGHT / 2} {wall_half_len:.5f} 0.003" '
            f'pos="{-PAN_WALL_HEIGHT / 2} {y:.6f} {z:.6f}" quat="{quat}" friction="{MU_OBJECT} 0.005 0.0001" '
            f'mass="0.01" rgba="0.15 0.15 0.15 1" {CONTACT_DEFAULTS}/>'
        )
    wall_xml = "\n                    ".join(walls)
    return f"""
                    <geom name="pan_handle" type="capsule" fromto="0 0 0 -0.01 0 {PAN_HANDLE}" size="0.01"
                          rgba="0.1 0.1 0.1 1" contype="0" conaffinity="0" group="1" mass="0.15"/>
                    <geom name="pan" type="cylinder" size="{PAN_RADIUS + 0.006} {bottom_half}"
                          pos="{bottom_half} 0 {PAN_CENTRE}" quat="0.7071068 0 0.7071068 0" mass="0.6"
                          rgba="0.2 0.2 0.2 1" {TOOL_SURFACE}/>
                    {wall_xml}
                    <site name="tool" pos="0 0 {PAN_CENTRE}" size="0.004" rgba="1 0 0 1"/>"""


def _pancake_xml() -> str:
    """The pancake: a free rigid disc whose body z axis is its top face's normal."""
    r, h, n = PANCAKE_RADIUS, PANCAKE_HALF_THICKNESS, PANCAKE_RING
    spheres = [f'<geom name="pancake_0" type="sphere" size="{h}" pos="0 0 0" friction="{MU_PANCAKE} 0.005 0.0001" '
               f'{CONTACT_DEFAULTS} rgba="0.9 0.7 0.3 0" group="3"/>']
    for i in range(n):
        phi = 2 * math.pi * i / n
        spheres.append(
            f'<geom name="pancake_{i + 1}" type="sphere" size="{h}" '
            f'pos="{(r - h) * math.cos(phi):.6f} {(r - h) * math.sin(phi):.6f} 0" '
            f'friction="{MU_PANCAKE} 0.005 0.0001" {CONTACT_DEFAULTS} rgba="0.9 0.7 0.3 0" group="3"/>'
        )
    # A thin disc has Ixx = Iyy = m(3r² + t²)/12 and Izz = m r²/2.
    ixx = PANCAKE_MASS * (3 * r**2 + (2 * h) ** 2) / 12
    izz = PANCAKE_MASS * r**2 / 2
    sphere_xml = "\n      ".join(spheres)
    return f"""
    <body name="pancake" pos="0 0 1">
      <freejoint name="pancake"/>
      <inertial pos="0 0 0" mass="{PANCAKE_MASS}" diaginertia="{ixx:.4e} {ixx:.4e} {izz:.4e}"/>
      <geom type="cylinder" size="{r} {h}" rgba="0.93 0.75 0.4 1" {_VISUAL}/>
      <geom type="cylinder" size="{r * 0.6} {h * 1.02}" rgba="0.75 0.5 0.2 1" {_VISUAL}/>
      {sphere_xml}
    </body>"""


def _object_xml() -> str:
    """The cylinder on the pan: a ring of feet below, a side cylinder for impacts with the wall."""
    r, hh, fr = OBJECT_RADIUS, OBJECT_HALF_HEIGHT, OBJECT_FOOT_RADIUS
    feet = []
    for i in range(OBJECT_FEET):
        phi = 2 * math.pi * i / OBJECT_FEET
        feet.append(
            f'<geom name="foot_{i}" type="sphere" size="{fr}" '
            f'pos="{(r - fr) * math.cos(phi):.6f} {(r - fr) * math.sin(phi):.6f} {-hh + fr}" '
            f'friction="{MU_OBJECT} 0.005 0.0001" {CONTACT_DEFAULTS} rgba="0.8 0.2 0.2 0" group="3"/>'
        )
    feet_xml = "\n      ".join(feet)
    side_half = hh - 0.005
    return f"""
    <body name="object" pos="0 0 1">
      <freejoint name="object"/>
      <inertial pos="0 0 0" mass="{OBJECT_MASS}" diaginertia="{OBJECT_MASS * (3 * r**2 + 4 * hh**2) / 12:.4e}
                {OBJECT_MASS * (3 * r**2 + 4 * hh**2) / 12:.4e} {OBJECT_MASS * r**2 / 2:.4e}"/>
      <geom type="cylinder" size="{r} {hh}" rgba="0.8 0.2 0.15 1" {_VISUAL}/>
      <geom type="cylinder" size="{r} {side_half}" pos="0 0 0.005" friction="{MU_OBJECT} 0.005 0.0001"
            {CONTACT_DEFAULTS} rgba="0.8 0.2 0.15 0" group="3"/>
      {feet_xml}
    </body>"""


def _pairs_xml(objects: list[str], surface: str, mu: float, friction_damping: float | None) -> str:
    """Explicit contact pairs between the object's contact geoms and the tool surface.

    ``friction_damping`` [1/s]: the friction rows' damping ``b`` (``solreffriction="-1 -b"``), or
    ``None`` for MuJoCo's default (the friction rows follow ``solref``).
    """
    damping = "" if friction_damping is None else f' solreffriction="-1 {-friction_damping:g}"'
    rows = [
        f'    <pair geom1="{g}" geom2="{surface}" condim="3" friction="{mu} {mu} 0.005 0.0001 0.0001" '
        f'solref="{CONTACT_SOLREF}" solimp="{CONTACT_SOLIMP}"{damping}/>'
        for g in objects
    ]
    return "  <contact>\n" + "\n".join(rows) + "\n  </contact>"


def _riser_xml(base: np.ndarray | None) -> str:
    """The riser the arm's base stands on (under the built-in arm at the origin, or under ``base`` [m])."""
    if base is None:
        return (f'<geom name="riser" type="box" size="0.13 0.13 {-TABLE_TOP / 2}" pos="0 0 {TABLE_TOP / 2}" '
                f'rgba="0.35 0.35 0.38 1"\n          {_VISUAL}/>')
    height = float(base[2]) - TABLE_TOP
    if height <= 1e-6:  # the base stands on the table
        return ""
    return (f'<geom name="riser" type="box" size="0.13 0.13 {height / 2:.6g}" '
            f'pos="{base[0]:.6g} {base[1]:.6g} {TABLE_TOP + height / 2:.6g}" rgba="0.35 0.35 0.38 1"\n          '
            f'{_VISUAL}/>')


def _tool_and_object(kind: str) -> tuple[str, str, str]:
    """The tool (MJCF of the tool body's children), the object body and the contact pairs of scene ``kind``."""
    if kind == "pancake":
        pairs = _pairs_xml([f"pancake_{i}" for i in range(PANCAKE_RING + 1)], "blade", MU_PANCAKE,
                           FRICTION_DAMPING)
        return _spatula_xml(), _pancake_xml(), pairs
    if kind == "sliding":
        pairs = _pairs_xml([f"foot_{i}" for i in range(OBJECT_FEET)], "pan", MU_OBJECT, OBJECT_FRICTION_DAMPING)
        return _pan_xml(), _object_xml(), pairs
    raise ValueError(f"scene kind must be 'pancake' or 'sliding', got {kind!r}")


CAMERAS = {
    "pancake": """
    <camera name="front" pos="1.4 0 0.4" xyaxes="0 1 0 0 0 1" fovy="42"/>
    <camera name="oblique" pos="1.25 -0.75 0.75" xyaxes="0.64 0.77 0 -0.3 0.25 0.92" fovy="45"/>""",
    "sliding": """
    <camera name="front" pos="1.5 -0.75 0.95" xyaxes="0.45 0.89 0 -0.45 0.23 0.86" fovy="45"/>
    <camera name="top" pos="0.65 0 0.95" xyaxes="0 1 0 -1 0 0" fovy="40"/>""",
}
"""The named cameras of each scene (MJCF); the same names and views on every robot."""


def scene_xml(kind: str, robot: Robot | None = None) -> str:
    """The full MJCF text of the ``"pancake"`` or ``"sliding"`` scene on the built-in arm (``robot=None``).

    With a :class:`~seqmotion.sim.robot_models.Robot`: the same world (options, table, lights, cameras, the
    object, the contact pairs) without the built-in arm and its actuators, the riser under the
    robot's base; :func:`build_scene` adds the robot and the tool with ``MjSpec``.
    """
    tool, obj, pairs = _tool_and_object(kind)
    cameras = CAMERAS[kind]
    if robot is None:
        riser, arm = _riser_xml(None), _arm_xml(tool)
        actuators = ("\n  <actuator>\n"
                     + "".join(f'    <motor name="{j}" joint="{j}" gear="1"/>{chr(10)}' for j in ARM_JOINTS)
                     + "  </actuator>")
    else:
        riser, arm, actuators = _riser_xml(robot.base_pos), "", ""
    return f"""<mujoco model="seqmotion-{kind}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{PHYSICS_DT}" gravity="0 0 {-GRAVITY}" integrator="implicitfast" cone="elliptic"
          impratio="10" noslip_iterations="{NOSLIP_ITERATIONS}" jacobian="dense" solver="Newton"
          tolerance="1e-10"/>
  <visual>
    <global offwidth="1280" offheight="960"/>
    <quality shadowsize="2048"/>
  </visual>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.82 0.78 0.7" rgb2="0.76 0.72 0.64" width="256"
             height="256"/>
    <material name="table" texture="grid" texrepeat="6 6"/>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.95 0.96 0.98" rgb2="0.7 0.75 0.82" width="256"
             height="256"/>
  </asset>
  <worldbody>
    <light name="key" pos="0.8 -0.6 2.0" dir="-0.3 0.3 -1" diffuse="0.8 0.8 0.8" castshadow="true"/>
    <light name="fill" pos="1.5 1.0 1.5" dir="-1 -0.6 -0.8" diffuse="0.35 0.35 0.35" castshadow="false"/>
    <geom name="table" type="box" size="1.0 0.9 0.02" pos="0.35 0 {TABLE_TOP - 0.02}" material="table"
          friction="1 0.005 0.0001" {CONTACT_DEFAULTS}/>
    {riser}
{cameras}
{arm}
{obj}
  </worldbody>
{pairs}{actuators}
</mujoco>
"""


SITE_IN_TOOL = {
    # The control site in the tool frame (z along the tool, x the surface's down normal) [m].
    "pancake": np.array([-BLADE_HALF[0] - PANCAKE_HALF_THICKNESS, 0.0, BLADE_CENTRE]),
    "sliding": np.array([0.0, 0.0, PAN_CENTRE]),
}
"""Where each tool's control site (``"tool"``) sits in the tool frame [m] (the same on every arm)."""


@dataclass(frozen=True)
class Scene:
    """A compiled scene and the indices a controller and a runner need.

    Attributes:
        kind: ``"pancake"`` or ``"sliding"``.
        model: the compiled ``mujoco.MjModel``.
        site: id of the tool control site.
        arm_qpos: ``(n,)`` qpos addresses of the arm joints (base to flange; n = 6 on the built-in arm).
        arm_dof: ``(n,)`` dof addresses of the arm joints.
        body: id of the manipulated body (pancake or object).
        body_qpos: qpos address of its free joint (position 3, then quaternion 4).
        body_dof: dof address of its free joint (linear 3, then angular 3).
        robot: the standard arm the scene is built on, or ``None`` for the built-in arm (its limits,
            home posture and placement are the robot's fields).
        arm_joints: ``(n,)`` the arm joints' names in ``model`` (a robot's carry its name as a
            prefix, ``"panda/joint1"``; :attr:`Robot.joints` has them as in its file).
        flange: id of the site at the tool mount (``"flange"``; the robot's prefixed on a robot).
    """

    kind: str
    model: object
    site: int
    arm_qpos: np.ndarray
    arm_dof: np.ndarray
    body: int
    body_qpos: int
    body_dof: int
    robot: Robot | None = None
    arm_joints: tuple[str, ...] = ARM_JOINTS
    flange: int = -1


def robot_prefix(robot: Robot) -> str:
    """The prefix a robot's element names carry in a scene (``"panda/"``): MuJoCo attaches a model under one."""
    return f"{robot.name}/"


def tool_site_in_flange(kind: str, robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """The tool control site of scene ``kind`` in the robot's flange body: position ``(3,)`` [m], quaternion
    ``(4,)``."""
    if kind not in SITE_IN_TOOL:
        raise ValueError(f"scene kind must be 'pancake' or 'sliding', got {kind!r}")
    mujoco = import_mujoco()
    pos, quat = tool_mount(robot)
    site = np.zeros(3)
    mujoco.mju_rotVecQuat(site, SITE_IN_TOOL[kind], quat)
    return pos + site, quat


# What the tool's geoms and site carry over from their MJCF into the robot's flange (every attribute the
# tool MJCF sets; the others keep MuJoCo's defaults, as in the built-in scene).
_GEOM_FIELDS = ("name", "type", "size", "pos", "quat", "fromto", "rgba", "contype", "conaffinity", "condim", "group",
                "mass", "density", "friction", "solref", "solimp", "solmix", "margin", "gap", "priority",
                "typeinertia", "material")
_SITE_FIELDS = ("name", "type", "size", "pos", "quat", "fromto", "rgba", "group")


def _add_tool(body: object, kind: str) -> None:
    """Build the tool of scene ``kind`` (the same MJCF as on the built-in arm) as children of ``body`` (an MjsBody).

    The tool's geoms and site are copied element by element rather than attached: MuJoCo's attach
    would prefix their names (the contact pairs and the runners refer to ``"blade"``, ``"pan"``,
    ``"tool"``).
    """
    mujoco = import_mujoco()
    tool_xml, _, _ = _tool_and_object(kind)
    source = mujoco.MjSpec.from_string(
        f'<mujoco><compiler angle="radian" autolimits="true"/><worldbody><body name="tool">{tool_xml}'
        "</body></worldbody></mujoco>"
    ).body("tool")
    for geom in source.geoms:
        copy = body.add_geom()
        for name in _GEOM_FIELDS:
            setattr(copy, name, getattr(geom, name))
    for site in source.sites:
        copy = body.add_site()
        for name in _SITE_FIELDS:
            setattr(copy, name, getattr(site, name))


_SIZE_FIELDS = ("memory", "nstack", "njmax", "nconmax", "nemax", "nuserdata")


def _adopt_settings(child: object, parent: object) -> None:
    """Give ``child`` (a robot's MjSpec) ``parent``'s physics options and ``<size>`` allocations before it is
    attached.

    The scene keeps its own options and sizes either way (the world is the root: MuJoCo keeps the parent's
    values), but MuJoCo reports every difference as an attach conflict (a Python warning and a line in
    ``MUJOCO_LOG.TXT``); a robot file's own options (e.g. Menagerie's ``integrator="implicit"``) and sizes are
    meant for its own scenes, not ours.
    """
    for name in dir(parent.option):
        if not name.startswith("_") and not callable(getattr(parent.option, name)):
            setattr(child.option, name, getattr(parent.option, name))
    for name in _SIZE_FIELDS:
        setattr(child, name, getattr(parent, name))


def attach_robot(world: object, robot: Robot) -> object:
    """Attach ``robot``'s arm to the world spec ``world`` (a ``mujoco.MjSpec``, modified in place); return its
    flange body (an ``MjsBody``; a tool goes at :func:`~seqmotion.sim.robot_models.tool_mount` in it).

    The arm (:meth:`Robot.spec <seqmotion.sim.robot_models.Robot.spec>`: its file's bodies, joints and torque
    motors) is attached under the prefix :func:`robot_prefix` at a frame at ``robot.base_pos`` ``(3,)`` [m],
    turned by ``robot.base_yaw`` [rad] about the world's z axis. The world's physics options and ``<size>``
    allocations stay in force (the robot's are set to the world's first, so the attach reports no conflict).
    The arm scenes (:func:`build_scene`) and the standard-arm pushing world
    (:class:`seqmotion.lfd.env.robot.RobotPushingScene`) both attach their robot here.
    """
    mujoco = import_mujoco()
    if not isinstance(world, mujoco.MjSpec):
        raise ValueError(f"world must be a mujoco.MjSpec, got {type(world).__name__}")
    yaw = float(robot.base_yaw)
    frame = world.worldbody.add_frame(pos=np.asarray(robot.base_pos, dtype=np.float64).tolist(),
                                      quat=[math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    arm = robot.spec()
    _adopt_settings(arm, world)
    world.attach(arm, prefix=robot_prefix(robot), frame=frame)
    return world.body(robot_prefix(robot) + robot.flange)


def _robot_model(kind: str, robot: Robot) -> object:
    """Compile scene ``kind`` on ``robot``: our world (options, table, cameras, object, pairs) as the root, the
    robot's arm attached at its base (:func:`attach_robot`), the tool built on its flange."""
    mujoco = import_mujoco()
    world = mujoco.MjSpec.from_string(scene_xml(kind, robot))
    flange = attach_robot(world, robot)
    pos, quat = tool_mount(robot)
    _add_tool(flange.add_body(name="tool", pos=pos.tolist(), quat=quat.tolist()), kind)
    try:
        return world.compile()
    except Exception as exc:  # MuJoCo's compiler errors name the element
        raise ValueError(f"the {kind} scene on {robot.label} does not compile: {exc}") from exc


def build_scene(kind: str, robot: str | Robot | None = None) -> Scene:
    """Compile the ``"pancake"`` (spatula) or ``"sliding"`` (frying pan) scene.

    Args:
        kind: ``"pancake"`` or ``"sliding"``.
        robot: ``None`` (or ``"mh3f"``) for the built-in arm, exactly as it always was; a standard
            arm's name (``"panda"``, ``"menagerie:universal_robots_ur5e"``; see
            :func:`seqmotion.sim.robot_models.robots`) or a :class:`~seqmotion.sim.robot_models.Robot`: the same
            world and options with that robot where it stands for this task
            (:func:`~seqmotion.sim.robot_models.placed_for`: its ``base_pos``, or the task's own placement) and the
            tool on its flange; ``scene.robot`` is the robot as placed.

    Raises:
        ValueError: an unknown kind, an unknown or unavailable robot.
    """
    mujoco = import_mujoco()
    if kind not in SITE_IN_TOOL:
        raise ValueError(f"scene kind must be 'pancake' or 'sliding', got {kind!r}")
    arm = placed_for(resolve_robot(robot), kind)  # where the arm stands for this task
    if arm is None:
        model = mujoco.MjModel.from_xml_string(scene_xml(kind))
        joints: tuple[str, ...] = ARM_JOINTS
        flange = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "flange")
    else:
        model = _robot_model(kind, arm)
        joints = tuple(robot_prefix(arm) + j for j in arm.joints)
        flange = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, robot_prefix(arm) + "flange")
    joint_ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in joints]
    body_name = "pancake" if kind == "pancake" else "object"
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body_name)
    free = model.body_jntadr[body]
    return Scene(
        kind=kind,
        model=model,
        site=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "tool"),
        arm_qpos=np.array([model.jnt_qposadr[j] for j in joint_ids]),
        arm_dof=np.array([model.jnt_dofadr[j] for j in joint_ids]),
        body=body,
        body_qpos=int(model.jnt_qposadr[free]),
        body_dof=int(model.jnt_dofadr[free]),
        robot=arm,
        arm_joints=joints,
        flange=flange,
    )


def get_scene(kind: str, robot: str | Robot | None = None) -> Scene:
    """:func:`build_scene`, compiled once per process per (kind, robot); runs never modify the model."""
    return _cached_scene(kind, resolve_robot(robot))


@lru_cache(maxsize=8)
def _cached_scene(kind: str, robot: Robot | None) -> Scene:
    return build_scene(kind, robot)
