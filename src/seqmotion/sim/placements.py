"""Where each standard arm stands in the scene's world and how it holds the tool: :class:`Placement`, one per arm
(:data:`PLACEMENTS`) and per arm and task where a task needs another (:data:`TASK_PLACEMENTS`); the robot layer
(:mod:`.robot_models`) places each arm it loads by these tables.

Placements (where each arm stands in the scene's world, whose tasks put the tool site at
``(0.5, y, 0.35 + z)`` m with attitude ``Rx(θ) Ry(π/2)`` for the pancake, ``(0.65 + x_p, y_p, 0.3)`` m
level for the frying pan; table top at z = -0.2 m). ``base`` is where the robot's base frame stands in
the world [m], ``yaw`` its turn about the vertical [rad] (on top of any turn its file makes); ``roll`` is
the tool's rotation about the flange axis [rad] (it puts the last joint mid-range when the blade is level);
``home`` is the posture used as the IK seed and posture target, with the tool at the pancake's origin pose.
Per robot (:data:`PLACEMENTS`):

==============================  =====================  =====  =========  ========================================
robot                           base [m]               yaw    roll       home [rad]
==============================  =====================  =====  =========  ========================================
panda (robosuite)               (0.34, -0.6, -0.2)     π/2    -0.7849    (0, 0.1191, 0, -1.6301, 0, 1.7492, 0)
                                                              (pitch
                                                              -π/2)
ur5e (robosuite)                (0.206, -0.45, 0.087)  -π/2   0 (pitch   (0, -2.361, -1.666, 2.457, π/2, 0)
                                                              π/2)
franka_emika_panda (menagerie)  as robosuite's Panda   π/2    -0.7849-π  as robosuite's Panda
universal_robots_ur5e (men.)    (0.206, -0.45, 0.087)  -π     0 (pitch   IK from the robosuite UR5e's home
                                                              π/2)
iiwa (robosuite)                (-0.3, 0, -0.2)        0      0          IK (not checked along the motions)
any other arm                   (-0.15, 0, 0)          0      0          IK from the file's ``home`` key, else the
                                                                         middle of its ranges, else random seeds
==============================  =====================  =====  =========  ========================================

Both turn the spatula with three parallel joints about world x, the pancake's θ axis (:mod:`.planar_chain`): the
UR5e its shoulder lift, elbow and wrist 1; the Panda, its joints 1, 3 and 5 at 0 so that it moves in the task plane,
its joints 2, 4 and 6. A task may place an arm elsewhere (:data:`TASK_PLACEMENTS`, :func:`placed_for`): the
Panda shakes the frying pan from the table 0.3 m to the right of it, turned 45° toward it (base (0, -0.3, -0.2),
yaw π/4, roll -1.0458), where every joint shares the pan's motion; from there it reaches every pose of the pan's
square ``x_p, y_p ∈ [-0.15, 0.15]`` with a joint at its range. Motions as the learned model makes them exceed the rated
joint speeds on either arm (their tilt rates, median peak 17 rad/s); ``deform(..., keep_end=True, robot=...)``
makes them within them (``benchmarks/RESULTS_sim.md``).

Velocity limits are not in the files: :data:`.limits.RATED_LIMITS` holds the manufacturers' published
values (and accelerations where published) for the arms named there, each with its document; any other arm gets
``velocity_limit=None`` ("unknown"), which a caller reports as such rather than checking. :attr:`Robot.limits` is
every limit of an arm as one :class:`JointLimits`, each kind with its source (the model file for ranges and torques);
:func:`built_in_limits` is the built-in arm's (all unknown: the MOTOMAN-MH3F's published axis limits were not
found).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Placement:
    """Where an arm stands in the scene and how it holds the tool.

    Attributes:
        base: ``(3,)`` position of the robot's base frame in the world [m].
        yaw: rotation of the base frame about the world's z axis [rad].
        roll: rotation of the tool about the flange's z axis [rad] (which way the blade's face turns
            relative to the flange; chosen to centre the last joint's range on the tasks' tilts).
        pitch: then a rotation about the turned frame's y axis [rad]: 0 holds the tool straight out of
            the flange, -π/2 bends it to the flange's side (a handle held by a hand that points down, so
            the spatula's roll is the wrist's bend rather than the last joint's spin).
        home: ``(n,)`` posture [rad] near the tasks' workspace (IK seed, posture target), or ``None``
            to compute it by IK at the pancake's origin pose from ``seed``.
        seed: ``(n,)`` IK seed for ``home`` when it is computed, or ``None`` for the file's ``home``
            keyframe (else the middle of each joint's range, 0 for unlimited joints).
    """

    base: tuple[float, float, float] = (-0.15, 0.0, 0.0)
    yaw: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    home: tuple[float, ...] | None = None
    seed: tuple[float, ...] | None = None


_PANDA_HOME = (0.0, 0.11907327, 0.0, -1.63014838, 0.0, 1.74922165, 0.0)
_UR5E_HOME = (0.0, -2.361047, -1.666286, 2.456537, math.pi / 2, 0.0)

PLACEMENTS: dict[str, Placement] = {
    # The Panda stands on the table top beside the task plane, turned so that its arm moves in that plane: with joints
    # 1, 3 and 5 at 0, its joints 2, 4 and 6 turn about world x, the pancake's θ axis, and their rated speeds add up
    # about one axis (2.175 + 2.175 + 2.61 rad/s), as the UR5e's three pitch joints do (``sim.planar_chain``). The tool
    # is bent to the flange's side (pitch -π/2): the handle runs along +x out of the arm's plane and joint 7's axis
    # lies in it. The shoulder's axis is 0.6 m to the side of the pancake's origin and 0.22 m below it; this home is
    # the one farthest from the ranges of joints 2, 4 and 6 (1.44 rad or more) of the bases tried on a 5 cm grid.
    "robosuite:panda": Placement(base=(0.34, -0.6, -0.2), yaw=math.pi / 2, roll=-0.78490554, pitch=-math.pi / 2,
                                 home=_PANDA_HOME),
    # Menagerie's Panda is the same arm; its mount frame is robosuite's turned by π about the flange axis.
    "menagerie:franka_emika_panda": Placement(base=(0.34, -0.6, -0.2), yaw=math.pi / 2, roll=-0.78490554 - math.pi,
                                              pitch=-math.pi / 2, home=_PANDA_HOME),
    # The UR5e stands on a pedestal beside the task plane, its base turned so that its three parallel pitch joints
    # (shoulder lift, elbow, wrist 1) turn about world x, the pancake's θ axis: the arm moves in the task plane and
    # their rated speeds add up about one axis (3 × π rad/s), which a pancake turn needs (``sim.planar_chain``). The
    # wrist 2 joint at π/2 and the tool bent to the flange's side (pitch π/2) hold the handle along +x with wrist 3
    # out of the plane; the shoulder's axis lies 0.45 m to the side of the pancake's origin and 0.1 m below it, the
    # elbow up, wrist 1 0.1 m below the blade and 0.1 m ahead of it (the side the turn's loop needs).
    "robosuite:ur5e": Placement(base=(0.206, -0.45, 0.087), yaw=-math.pi / 2, pitch=math.pi / 2, home=_UR5E_HOME),
    # The iiwa's joint-4 range does not let it hold the tool level at its shoulder height 0.15 m ahead of the
    # origin; from the table top 0.3 m back it can (home by IK; reach along the motions not measured).
    "robosuite:iiwa": Placement(base=(-0.3, 0.0, -0.2)),
    # Menagerie's UR5e turns its base by +90° in its file; turned back, it is robosuite's arm.
    "menagerie:universal_robots_ur5e": Placement(base=(0.206, -0.45, 0.087), yaw=-math.pi, pitch=math.pi / 2,
                                                 seed=_UR5E_HOME),
}
"""Per ``"source:name"``; any other arm gets :data:`DEFAULT_PLACEMENT` (home by IK from its file's posture)."""

_PANDA_PAN_HOME = (-1.500511, 1.522837, 2.103322, -2.54637, -2.747437, 1.247156, -0.000102)

TASK_PLACEMENTS: dict[tuple[str, str], Placement] = {
    # The frying pan is shaken level, not turned: standing in the pancake's plane the Panda would move the pan
    # sideways with joint 1 alone and along y with joints 2 and 4 (the pan could accelerate at 11.8 m/s² along x but
    # only 2.3 m/s² along y within the rated accelerations). Standing on the table 0.3 m to the right, turned 45°
    # toward the pan, every joint shares the pan's motion: the 20 chapter-3 commands then ran 20/20 within the rated
    # speeds, ranges and torques (19/20 from the pancake's placement). Home: the tool at the pancake's origin pose
    # there, the IK seed of the pan's start pose.
    ("robosuite:panda", "sliding"): Placement(base=(0.0, -0.3, -0.2), yaw=math.pi / 4, roll=-1.0458,
                                              home=_PANDA_PAN_HOME),
    ("menagerie:franka_emika_panda", "sliding"): Placement(base=(0.0, -0.3, -0.2), yaw=math.pi / 4,
                                                           roll=-1.0458 - math.pi, seed=_PANDA_PAN_HOME),
}
"""Per ``("source:name", task kind)``: where an arm stands for that task instead of its :data:`PLACEMENTS` entry
(:func:`placed_for`); the scenes of that task (``get_scene(kind, robot)``) put it there."""

DEFAULT_PLACEMENT = Placement()


__all__ = ["DEFAULT_PLACEMENT", "PLACEMENTS", "TASK_PLACEMENTS", "Placement"]
