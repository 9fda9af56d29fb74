"""Standard robot arms from the MuJoCo ecosystem, read from their published MJCF files.

Where the models come from (nothing is downloaded unless a user asks for a Menagerie arm that is
not on disk yet):

* **robosuite** (PyPI ``robosuite``, MIT): its wheel ships ``models/assets/robots/<name>/robot.xml``
  with meshes and torque ``motor`` actuators whose ``ctrlrange`` is the arm's torque limit. Only the
  files are read (the package is never imported; robosuite pins old versions of its dependencies,
  so install it with ``pip install --no-deps "robosuite>=1.5,<1.6"``).
* **MuJoCo Menagerie** through PyPI ``mujoco-menagerie`` (``mm.get(name).xml(entry)``): downloads a
  model on first use into its cache, or reads it from ``MENAGERIE_ROOT`` (a directory holding one
  folder per Menagerie robot name, e.g. ``$MENAGERIE_ROOT/franka_emika_panda/panda_nohand.xml``).
  Menagerie arms are driven by position servos; :meth:`Robot.spec` replaces them by torque motors
  limited to the servo's ``forcerange`` (or the joint's ``actuatorfrcrange``).

Entry points: :func:`robots` lists what is available here without a download (by name: it reads no model file),
:func:`get_robot` resolves a name (``"panda"``, ``"robosuite:ur5e"``, ``"menagerie:franka_emika_panda"``) to a
:class:`Robot`, and :meth:`Robot.spec` is the arm alone as a ``mujoco.MjSpec`` (what
:func:`seqmotion.sim.scene.build_scene` puts on the table with the tool at its flange). The built-in
MH3F-like arm (``"mh3f"``) is not a :class:`Robot`: it is the scene's own MJCF and stays the default.
Every model file is checked by :func:`~seqmotion.sim.model_files.check_model_file` before MuJoCo parses it: sizes
that bound the parse's time and memory, and, for robosuite's and Menagerie's arms, every file it names inside the
robot's own folder.

Where each arm stands and how it holds the tool: :mod:`.placements`.
"""

from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import check_finite_array
from .backend import import_mujoco
from .ik import damped_least_squares
from .limits import LIMIT_KINDS, RATED_LIMITS, VELOCITY_LIMITS, JointLimits
from .model_files import check_model_file
from .placements import DEFAULT_PLACEMENT, PLACEMENTS, TASK_PLACEMENTS, Placement

BUILT_IN = "mh3f"
"""Name of the built-in MH3F-like arm (the scene's own MJCF; ``robot=None`` everywhere)."""

ROBOSUITE_ARMS = ("panda", "ur5e", "iiwa", "kinova3", "xarm7", "jaco", "sawyer")
"""The single arms robosuite ships (``models/assets/robots/<name>/robot.xml``)."""

ROBOSUITE_FLANGE = "right_hand"
"""The body robosuite mounts its grippers on (its z axis points out of the flange)."""

MENAGERIE_ARMS: dict[str, tuple[str, str]] = {
    # short name → (Menagerie registry name, entry point without a gripper where the model has one)
    "panda": ("franka_emika_panda", "panda_nohand"),
    "ur5e": ("universal_robots_ur5e", "ur5e"),
    "iiwa": ("kuka_iiwa_14", "iiwa14"),
    "kinova3": ("kinova_gen3", "gen3"),
    "xarm7": ("ufactory_xarm7", "xarm7_nohand"),
    "sawyer": ("rethink_robotics_sawyer", "sawyer"),
    "fr3": ("franka_fr3", "fr3"),
    "ur10e": ("universal_robots_ur10e", "ur10e"),
}
"""Menagerie's models of the same arms (robosuite's ``iiwa`` is the LBR iiwa 7, Menagerie's the iiwa 14)."""

MENAGERIE_MOUNT = "attachment_site"
"""The site Menagerie arms carry at their tool flange (z out of the flange)."""

MENAGERIE_FLANGE_FALLBACK: dict[str, tuple[str, tuple[float, ...], tuple[float, ...]]] = {
    # Older Menagerie releases without an attachment site: (flange body, mount pos [m], mount quat).
    "universal_robots_ur5e": ("wrist_3_link", (0.0, 0.1, 0.0), (-1.0, 1.0, 0.0, 0.0)),
    "universal_robots_ur10e": ("wrist_3_link", (0.0, 0.1, 0.0), (-1.0, 1.0, 0.0, 0.0)),
    "franka_emika_panda": ("link7", (0.0, 0.0, 0.107), (0.3826834, 0.0, 0.0, 0.9238795)),
}





HOME_TOOL_POSE = ((0.5, 0.0, 0.35), ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (-1.0, 0.0, 0.0)))
"""The tool site's pose at ``home``: position [m] and rotation ``Ry(π/2)`` (the pancake's origin: the tool along
+x, its surface facing up)."""

HOME_SITE_IN_TOOL = (-0.0065, 0.0, 0.16)
"""The spatula's control site in the tool frame [m]: :data:`seqmotion.sim.scene.SITE_IN_TOOL` ``["pancake"]``,
written out because the scene module builds on this one (tests/test_robots.py keeps the two equal)."""


@dataclass(frozen=True)
class RobotInfo:
    """One available robot (a row of :func:`robots`).

    Attributes:
        name: what :func:`get_robot` takes (``"panda"``, ``"menagerie:kinova_gen3"``, ``"mh3f"``).
        source: ``"robosuite"``, ``"menagerie"`` or ``"seqmotion"`` (the built-in arm).
        dof: number of arm joints, or ``None`` where it is not known without reading the file (the listing reads
            none: :func:`get_robot` does, with its checks).
        path: the robot's MJCF file (``None`` for the built-in arm).
    """

    name: str
    source: str
    dof: int | None
    path: Path | None


MH3F_NOT_FOUND = ("the MOTOMAN-MH3F's published axis limits were not found (seqmotion's built-in MH3F-like arm models "
                  "none)")
"""Why the built-in arm's limits are unknown."""


def built_in_limits(joints: tuple[str, ...] = ("s", "l", "u", "r", "b", "t")) -> JointLimits:
    """The built-in MH3F-like arm's limits (its joints ``joints``, base → flange): every kind unknown.

    The built-in arm is the dissertation's arm rebuilt from its reach, not the maker's model: it has no joint ranges
    and no torque limits, and the MOTOMAN-MH3F's own published axis ranges, speeds and torques were not found, so
    none of them is checked (and none is assumed unlimited).
    """
    return JointLimits(f"{BUILT_IN} (seqmotion)", tuple(joints), None, None, None, None,
                       {kind: f"unknown: {MH3F_NOT_FOUND}" for kind in LIMIT_KINDS})


@dataclass(frozen=True, eq=False)
class Robot:
    """A standard arm read from its MJCF file, and where it stands in the scenes.

    Attributes:
        name: the arm's name in its source (``"panda"``; ``"franka_emika_panda"`` for Menagerie).
        source: ``"robosuite"`` or ``"menagerie"``.
        path: the robot's MJCF file.
        joints: the arm joints base → flange, named as in the file.
        flange: the body the tool is mounted on.
        mount_pos: ``(3,)`` the mount frame in the flange body [m] (z out of the flange).
        mount_quat: ``(4,)`` its orientation ``[w, x, y, z]`` in the flange body.
        torque_limit: ``(n,)`` the model's torque limits [N m] (robosuite motors' ``ctrlrange``;
            Menagerie servos' ``forcerange`` or the joints' ``actuatorfrcrange``).
        joint_range: ``(n, 2)`` the model's joint ranges [rad] (``±inf`` for a continuous joint).
        velocity_limit: ``(n,)`` the manufacturer's joint speed limits [rad/s], or ``None`` if unknown.
        home: ``(n,)`` posture near the tasks' workspace [rad] (IK seed and posture target).
        base_pos: ``(3,)`` where its base frame sits in the scene's world [m].
        tool_roll: the tool's rotation about the mount frame's z axis [rad].
        tool_pitch: then its rotation about the turned frame's y axis [rad] (:class:`Placement`).
        base_yaw: the base frame's rotation about the world's z axis [rad] (0: as in its file).
        folder: the directory every file the model reads must lie in (its Menagerie folder, resolved), or ``None``
            (not checked): :meth:`spec` checks the file again before MuJoCo reads it (:func:`check_model_file`).
    """

    name: str
    source: str
    path: Path
    joints: tuple[str, ...]
    flange: str
    mount_pos: np.ndarray
    mount_quat: np.ndarray
    torque_limit: np.ndarray
    joint_range: np.ndarray
    velocity_limit: np.ndarray | None
    home: np.ndarray
    base_pos: np.ndarray
    tool_roll: float = 0.0
    base_yaw: float = 0.0
    tool_pitch: float = 0.0
    folder: Path | None = None
    _key: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        n = len(self.joints)
        shapes = {"mount_pos": (3,), "mount_quat": (4,), "torque_limit": (n,), "joint_range": (n, 2),
                  "home": (n,), "base_pos": (3,)}
        if self.velocity_limit is not None:
            shapes["velocity_limit"] = (n,)
        for name, shape in shapes.items():
            value = np.array(getattr(self, name), dtype=np.float64)
            if value.shape != shape:
                raise ValueError(f"robot {self.name!r}: {name} must have shape {shape}, got {value.shape}")
            if name != "joint_range":
                check_finite_array(f"robot {self.name!r}: {name}", value)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        if self.source not in ("robosuite", "menagerie"):
            raise ValueError(f"robot source must be 'robosuite' or 'menagerie', got {self.source!r}")
        check_finite_array(f"robot {self.name!r}: torque limits", self.torque_limit, minimum=0.0, strict_minimum=True)
        key = (self.name, self.source, str(self.path), self.joints, self.flange, float(self.tool_roll),
               float(self.base_yaw), float(self.tool_pitch)) + tuple(
            tuple(np.asarray(getattr(self, f)).ravel().tolist())
            for f in ("mount_pos", "mount_quat", "torque_limit", "joint_range", "home", "base_pos")
        ) + (None if self.velocity_limit is None else tuple(self.velocity_limit.tolist()),)
        object.__setattr__(self, "_key", key)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Robot) and self._key == other._key

    def __hash__(self) -> int:
        return hash(self._key)

    @property
    def dof(self) -> int:
        """Number of arm joints."""
        return len(self.joints)

    @property
    def label(self) -> str:
        """``"name (source)"``, e.g. ``"panda (robosuite)"``."""
        return f"{self.name} ({self.source})"

    @property
    def limits(self) -> JointLimits:
        """Every joint limit of the arm with its source (:class:`JointLimits`): ranges and torques from its model
        file, rated speeds (and accelerations where published) from :data:`RATED_LIMITS`, unknown otherwise."""
        key = f"{self.source}:{self.name}"
        rated = RATED_LIMITS.get(key)
        file = f"model file {self.source}:{self.name} ({self.path.name})"
        how = "motor ctrlrange" if self.source == "robosuite" else "actuator forcerange or joint actuatorfrcrange"
        if self.velocity_limit is None:
            speed_source = f"unknown: no published joint speeds for {key} in seqmotion's table (RATED_LIMITS)"
        elif rated is not None and np.allclose(rated.velocity, self.velocity_limit):
            speed_source = rated.source
        else:
            speed_source = "given when this Robot was made"
        accel = None
        accel_source = f"unknown: no published joint accelerations for {key} in seqmotion's table (RATED_LIMITS)"
        if rated is not None and rated.acceleration is not None and len(rated.acceleration) == self.dof:
            accel, accel_source = np.array(rated.acceleration), str(rated.acceleration_source)
        return JointLimits(self.label, self.joints, self.joint_range, self.velocity_limit, accel, self.torque_limit,
                           {"position": f"{file}: joint ranges", "velocity": speed_source,
                            "acceleration": accel_source, "torque": f"{file}: {how}"})

    def spec(self) -> Any:
        """The arm alone as a fresh ``mujoco.MjSpec``, ready to be attached to a scene.

        From the robot's file: grippers and anything else mounted beyond the flange removed, with
        every tendon, equality, sensor, keyframe, light, world-level geom (floors) and skybox;
        every actuator replaced by one torque ``motor`` per arm joint, named after the joint,
        ``gear`` 1, ``ctrlrange = ±torque_limit`` (``ctrllimited``; MuJoCo clamps a command beyond
        it); every geom non-colliding (``contype = conaffinity = 0``: the arm never touches the
        table, the tool or the object — only the tool does), and the file's collision geoms moved
        to group 3 (hidden by default) where a body also has visual geoms, so renders show the
        visual meshes only. A site ``"flange"`` marks the mount frame (z out of the flange).
        Inertias, joint damping, armature and ranges are the file's, but for robosuite's gripper-mount
        placeholder: its ``right_hand`` body stands in for a gripper with 0.5 kg and 0.05 kg m² about
        every axis (a 0.32 m radius of gyration: no part of a hand); the tool replaces the gripper, so
        the placeholder goes with it (on the Panda it alone needed 15 N m to turn the flange at the
        pancake motions' 300 rad/s², past joint 7's 12 N m).
        """
        mujoco = import_mujoco()
        check_model_file(self.path, self.folder)  # the file may have changed since load_robot read it
        spec = mujoco.MjSpec.from_file(str(self.path))
        _strip(spec, set(self.joints), self.flange)
        flange = spec.body(self.flange)
        if self.source == "robosuite" and flange.explicitinertial:
            flange.explicitinertial = False
            flange.mass, flange.inertia = 0.0, [0.0, 0.0, 0.0]
        flange.add_site(name="flange", pos=self.mount_pos.tolist(), quat=self.mount_quat.tolist(), size=[0.005] * 3,
                        group=3)
        for name, limit in zip(self.joints, self.torque_limit, strict=True):
            _add_motor(spec, name, float(limit))
        return spec


# --- reading the files ------------------------------------------------------------------------------------------


def robosuite_root() -> Path | None:
    """robosuite's bundled robot models (``.../robosuite/models/assets/robots``), or ``None`` if not installed.

    Found without importing robosuite (its package import pulls in its pinned dependencies).
    """
    try:
        spec = importlib.util.find_spec("robosuite")
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    for location in spec.submodule_search_locations:
        root = Path(location) / "models" / "assets" / "robots"
        if root.is_dir():
            return root
    return None


def _menagerie() -> Any | None:
    try:
        import mujoco_menagerie
    except ImportError:
        return None
    return mujoco_menagerie


def _limited(flag: Any, lo: float, hi: float, autolimits: bool) -> bool:
    """MuJoCo's rule for ``limited`` attributes: true, false, or auto (limited iff a range was given)."""
    mujoco = import_mujoco()
    if flag == mujoco.mjtLimited.mjLIMITED_TRUE:
        return True
    if flag == mujoco.mjtLimited.mjLIMITED_FALSE:
        return False
    return bool(autolimits) and lo < hi


def _chain(spec: Any, flange: str) -> list[Any]:
    """The bodies from the world's child down to ``flange`` (root first)."""
    body = spec.body(flange)
    if body is None:
        raise ValueError(f"the robot's file has no body {flange!r}")
    path = []
    while body is not None and body.name != "world":
        path.append(body)
        body = body.parent
    return path[::-1]


def _strip(spec: Any, keep_joints: set[str], flange: str) -> None:
    """Remove from ``spec`` everything :meth:`Robot.spec` says it removes (in place)."""
    mujoco = import_mujoco()
    for collection in (spec.keys, spec.actuators, spec.sensors, spec.tendons, spec.equalities, spec.lights):
        for element in list(collection):
            spec.delete(element)
    for element in list(spec.worldbody.geoms) + list(spec.worldbody.sites):
        spec.delete(element)
    for texture in list(spec.textures):
        if texture.type == mujoco.mjtTexture.mjTEXTURE_SKYBOX:
            spec.delete(texture)
    for child in list(spec.body(flange).bodies):  # whatever was mounted on the flange (a gripper)
        spec.delete(child)
    # Any other subtree that moves on joints not in the arm (a second gripper, a head pan joint).
    for body in list(spec.bodies):
        if body.name == "world" or spec.body(body.name) is None:
            continue
        if any(j.name not in keep_joints for j in body.joints):
            spec.delete(body)
    for body in spec.bodies:
        geoms = list(body.geoms)
        visual = any(g.contype == 0 and g.conaffinity == 0 for g in geoms)
        for geom in geoms:
            if visual and (geom.contype != 0 or geom.conaffinity != 0):
                geom.group = 3
            geom.contype, geom.conaffinity = 0, 0


def _add_motor(spec: Any, joint: str, limit: float) -> None:
    """A torque motor on ``joint``: ``τ = ctrl`` clamped to ``±limit`` [N m]; every field set (no class defaults)."""
    mujoco = import_mujoco()
    act = spec.add_actuator(name=joint, target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    act.set_to_motor()
    act.gear = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    act.ctrlrange = [-limit, limit]
    act.forcelimited = mujoco.mjtLimited.mjLIMITED_FALSE
    act.actlimited = mujoco.mjtLimited.mjLIMITED_FALSE
    for name in ("damping", "armature"):
        if hasattr(act, name):  # MuJoCo ≥ 4 actuators may carry their own; a motor has none
            value = getattr(act, name)
            setattr(act, name, np.zeros_like(value) if isinstance(value, np.ndarray) else 0.0)


def _joint_limits(spec: Any, joints: list[str]) -> np.ndarray:
    """``(n, 2)`` joint ranges [rad] (``±inf`` where the joint is not limited)."""
    autolimits, degree = spec.compiler.autolimits, spec.compiler.degree
    out = np.empty((len(joints), 2))
    for i, name in enumerate(joints):
        joint = spec.joint(name)
        lo, hi = (float(x) for x in joint.range)
        if _limited(joint.limited, lo, hi, autolimits):
            out[i] = np.radians([lo, hi]) if degree else (lo, hi)
        else:
            out[i] = (-np.inf, np.inf)
    return out


def _torque_limits(spec: Any, joints: list[str], source: str) -> np.ndarray:
    """``(n,)`` the model's torque limit per joint [N m], from its actuators or the joints' ``actuatorfrcrange``."""
    mujoco = import_mujoco()
    autolimits = spec.compiler.autolimits
    limits = np.full(len(joints), np.inf)
    for i, name in enumerate(joints):
        joint = spec.joint(name)
        lo, hi = (float(x) for x in joint.actfrcrange)
        if _limited(joint.actfrclimited, lo, hi, autolimits):
            limits[i] = max(abs(lo), abs(hi))
    for act in spec.actuators:
        if act.trntype != mujoco.mjtTrn.mjTRN_JOINT or act.target not in joints:
            continue
        i = joints.index(act.target)
        gear = abs(float(act.gear[0])) or 1.0
        lo, hi = (float(x) for x in act.forcerange)
        if _limited(act.forcelimited, lo, hi, autolimits):
            limits[i] = min(limits[i], max(abs(lo), abs(hi)))
        is_motor = act.biastype == mujoco.mjtBias.mjBIAS_NONE and act.dyntype == mujoco.mjtDyn.mjDYN_NONE
        lo, hi = (float(x) for x in act.ctrlrange)
        if is_motor and _limited(act.ctrllimited, lo, hi, autolimits):  # a torque motor: τ = gear · ctrl
            limits[i] = min(limits[i], gear * max(abs(lo), abs(hi)))
    missing = [name for name, limit in zip(joints, limits, strict=True) if not np.isfinite(limit)]
    if missing:
        raise ValueError(f"the {source} model gives no torque limit for joint(s) {missing} (no actuator forcerange, "
                         "motor ctrlrange or joint actuatorfrcrange)")
    return limits


def _arm_joints_on_chain(spec: Any, flange: str) -> list[str]:
    """The hinge and slide joints on the path from the root to ``flange``, base first."""
    mujoco = import_mujoco()
    moving = (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)
    return [j.name for body in _chain(spec, flange) for j in body.joints if j.type in moving]


def _robosuite_layout(spec: Any, path: Path) -> tuple[list[str], str, np.ndarray, np.ndarray]:
    """robosuite: the arm joints are its motors' joints (in order); the tool goes on ``right_hand``."""
    mujoco = import_mujoco()
    joints = [a.target for a in spec.actuators if a.trntype == mujoco.mjtTrn.mjTRN_JOINT]
    if spec.body(ROBOSUITE_FLANGE) is None or not joints:
        raise ValueError(f"{path} is not a robosuite arm (no motors or no {ROBOSUITE_FLANGE!r} body)")
    chain = _arm_joints_on_chain(spec, ROBOSUITE_FLANGE)
    if chain != joints:
        raise ValueError(f"{path}: the motors' joints {joints} are not the chain to the flange {chain}")
    return joints, ROBOSUITE_FLANGE, np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])


def _menagerie_layout(spec: Any, name: str, path: Path) -> tuple[list[str], str, np.ndarray, np.ndarray]:
    """Menagerie: the tool goes on the ``attachment_site``'s frame; the arm joints are the chain to its body.

    Without that site: a known arm's flange from :data:`MENAGERIE_FLANGE_FALLBACK`, else the body of
    the last actuated joint (mount frame = that body's frame).
    """
    mujoco = import_mujoco()
    site = spec.site(MENAGERIE_MOUNT)
    if site is not None:
        flange, pos, quat = site.parent.name, np.array(site.pos, dtype=float), np.array(site.quat, dtype=float)
    elif name in MENAGERIE_FLANGE_FALLBACK:
        flange, pos, quat = (np.asarray(x, dtype=float) if i else x
                             for i, x in enumerate(MENAGERIE_FLANGE_FALLBACK[name]))
    else:
        actuated = [a.target for a in spec.actuators if a.trntype == mujoco.mjtTrn.mjTRN_JOINT]
        hinges = [j for j in spec.joints if j.name in actuated and j.type == mujoco.mjtJoint.mjJNT_HINGE]
        if not hinges:
            raise ValueError(f"{path}: no actuated hinge joints, not an arm")
        # The deepest actuated hinge: the one with the longest chain of bodies above it.
        deepest = max(hinges, key=lambda j: len(_chain(spec, j.parent.name)))
        flange, pos, quat = deepest.parent.name, np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])
    if spec.body(flange) is None:
        raise ValueError(f"{path}: no flange body {flange!r}")
    joints = _arm_joints_on_chain(spec, flange)
    if not joints:
        raise ValueError(f"{path}: no joints between the base and the flange {flange!r}")
    return joints, flange, pos, quat / np.linalg.norm(quat)


def _file_home(spec: Any, joints: list[str], ranges: np.ndarray) -> np.ndarray:
    """A start posture for IK: the file's ``home`` keyframe if it sets these joints, else mid-range (0 if free)."""
    finite = np.isfinite(ranges).all(axis=1)
    seed = np.where(finite, np.where(finite[:, None], ranges, 0.0).mean(axis=1), 0.0)
    keys = [k for k in spec.keys if k.name == "home"]
    if keys:
        qpos = np.asarray(keys[0].qpos, dtype=float)
        # Keyframe qpos follows the joints' order in the file; the arm joints come first in every
        # arm model read here (the root chain is declared before any gripper).
        order = [j.name for j in spec.joints]
        if qpos.size >= len(order) and all(j in order for j in joints):
            seed = np.array([qpos[order.index(j)] for j in joints])
    return np.clip(seed, ranges[:, 0], ranges[:, 1])


def load_robot(
    path: str | Path,
    source: str,
    name: str,
    placement: Placement | None = None,
    *,
    folder: str | Path | None = None,
    root: str | Path | None = None,
) -> Robot:
    """Read a robot from its MJCF file (no scene, no download).

    Args:
        path: the robot's MJCF (a robosuite ``robot.xml`` or a Menagerie entry point).
        source: ``"robosuite"`` or ``"menagerie"`` (how its actuators and flange are read).
        name: the robot's name in that source (keys :data:`RATED_LIMITS`, :data:`PLACEMENTS`).
        placement: where it stands; default: :data:`PLACEMENTS` or :data:`DEFAULT_PLACEMENT`.
        folder: the directory every file the model reads must lie in (the robot's Menagerie folder); ``None``:
            any (the sizes are checked all the same).
        root: the directory ``folder`` must lie in (``MENAGERIE_ROOT`` or the cache's models).

    Raises:
        ValueError: the file is missing, fails :func:`check_model_file`, or is not an arm this module can read
            (named).
    """
    mujoco = import_mujoco()
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"robot file {path} does not exist")
    check_model_file(path, folder, root)  # before MuJoCo's parser, which trusts its input
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except Exception as exc:  # MuJoCo's parser raises its own error types
        raise ValueError(f"cannot read robot file {path}: {exc}") from exc
    if source == "robosuite":
        joints, flange, pos, quat = _robosuite_layout(spec, path)
    elif source == "menagerie":
        joints, flange, pos, quat = _menagerie_layout(spec, name, path)
    else:
        raise ValueError(f"robot source must be 'robosuite' or 'menagerie', got {source!r}")
    key = f"{source}:{name}"
    place = placement or PLACEMENTS.get(key, DEFAULT_PLACEMENT)
    ranges = _joint_limits(spec, joints)
    speeds = VELOCITY_LIMITS.get(key)
    if speeds is not None and len(speeds) != len(joints):
        raise ValueError(f"{key}: {len(speeds)} published speed limits for {len(joints)} joints {joints}")
    robot = Robot(
        name=name, source=source, path=path, joints=tuple(joints), flange=flange, mount_pos=pos, mount_quat=quat,
        torque_limit=_torque_limits(spec, joints, f"{source}:{name}"), joint_range=ranges,
        velocity_limit=None if speeds is None else np.array(speeds),
        home=np.zeros(len(joints)) if place.home is None else np.array(place.home),
        base_pos=np.array(place.base), tool_roll=place.roll, base_yaw=place.yaw, tool_pitch=place.pitch,
        folder=None if folder is None else Path(folder).resolve(),
    )
    if place.home is None:
        seed = _file_home(spec, joints, ranges) if place.seed is None else np.asarray(place.seed, dtype=float)
        robot = _with_home(robot, seed)
    return robot


HOME_MARGIN = 0.1
"""A computed home posture stays this far inside every joint range [rad] (a posture target at a limit would
leave the IK no room)."""


def _with_home(robot: Robot, seed: np.ndarray, tries: int = 24) -> Robot:
    """``robot`` with ``home`` = an IK solution that puts the tool at :data:`HOME_TOOL_POSE` at least
    :data:`HOME_MARGIN` inside the joint ranges: the one reached from ``seed`` if any, else, of the solutions from
    ``tries`` seeds drawn uniformly in the ranges (a fixed generator: the same home every time), the one farthest
    from its limits."""
    from dataclasses import replace

    mujoco = import_mujoco()
    spec = robot.spec()
    mount_pos, mount_quat = tool_mount(robot)
    offset = np.zeros(3)
    mujoco.mju_rotVecQuat(offset, np.array(HOME_SITE_IN_TOOL), mount_quat)
    spec.body(robot.flange).add_site(name="tool_point", pos=(mount_pos + offset).tolist(), quat=mount_quat.tolist())
    model = spec.compile()
    data = mujoco.MjData(model)
    pos, rot = HOME_TOOL_POSE
    local_pos, local_rot = in_base_frame(robot, np.asarray(pos), np.asarray(rot))
    lo, hi = np.clip(robot.joint_range[:, 0], -np.pi, None), np.clip(robot.joint_range[:, 1], None, np.pi)
    seeds = [np.asarray(seed, dtype=float)] + list(np.random.default_rng(0).uniform(lo, hi, (tries, robot.dof)))
    best, best_margin = None, -np.inf
    for i, start in enumerate(seeds):
        q, err = solve_pose(model, data, robot, local_pos, local_rot, start, margin=HOME_MARGIN)
        if err > 1e-7:
            continue
        if i == 0:
            return replace(robot, home=q)
        margin = np.min(np.minimum(q - robot.joint_range[:, 0], robot.joint_range[:, 1] - q))
        if margin > best_margin:
            best, best_margin = q, margin
    if best is None:
        raise ValueError(f"{robot.label}: no posture puts the tool at {pos} m, pointing +x, {HOME_MARGIN} rad inside "
                         "the joint ranges; give it a Placement with another base or a home")
    return replace(robot, home=best)


def placed_for(robot: Robot | None, kind: str) -> Robot | None:
    """``robot`` where it stands for the task ``kind`` (``"pancake"``, ``"sliding"``): moved to its
    :data:`TASK_PLACEMENTS` entry where it has one and stands at its default placement (a robot a user placed
    elsewhere stays where they put it); the built-in arm (``None``) as it is."""
    if robot is None:
        return None
    key = f"{robot.source}:{robot.name}"
    place = TASK_PLACEMENTS.get((key, kind))
    default = PLACEMENTS.get(key, DEFAULT_PLACEMENT)
    at_default = (np.allclose(robot.base_pos, default.base) and robot.base_yaw == default.yaw
                  and robot.tool_roll == default.roll and robot.tool_pitch == default.pitch)
    return robot if place is None or not at_default else _placed(robot, place)


@lru_cache(maxsize=8)
def _placed(robot: Robot, place: Placement) -> Robot:
    from dataclasses import replace

    moved = replace(robot, base_pos=np.array(place.base), base_yaw=place.yaw, tool_roll=place.roll,
                    tool_pitch=place.pitch, home=np.array(place.home if place.home is not None else robot.home))
    return moved if place.home is not None else _with_home(moved, np.asarray(place.seed, dtype=np.float64))


def tool_mount(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """The tool frame in the robot's flange body: position ``(3,)`` [m] and quaternion ``(4,)``.

    The robot's mount frame (z out of the flange) turned by ``robot.tool_roll`` about its z axis, then by
    ``robot.tool_pitch`` about the turned y axis; the tool's z runs along the tool away from the flange, as on
    the built-in arm.
    """
    mujoco = import_mujoco()
    roll = np.array([math.cos(robot.tool_roll / 2), 0.0, 0.0, math.sin(robot.tool_roll / 2)])
    pitch = np.array([math.cos(robot.tool_pitch / 2), 0.0, math.sin(robot.tool_pitch / 2), 0.0])
    turned, quat = np.zeros(4), np.zeros(4)
    mujoco.mju_mulQuat(turned, np.asarray(robot.mount_quat, dtype=np.float64), roll)
    mujoco.mju_mulQuat(quat, turned, pitch)
    return np.array(robot.mount_pos, dtype=np.float64), quat


def in_base_frame(robot: Robot, pos: np.ndarray, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A world pose (position ``(3,)`` [m], rotation ``(3, 3)``) in the robot's base frame (at ``base_pos``, turned
    by ``base_yaw``)."""
    c, s = math.cos(robot.base_yaw), math.sin(robot.base_yaw)
    yaw_t = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # Rz(yaw)ᵀ
    return yaw_t @ (np.asarray(pos, dtype=float) - robot.base_pos), yaw_t @ np.asarray(rot, dtype=float)


def solve_pose(
    model: Any,
    data: Any,
    robot: Robot,
    pos: np.ndarray,
    rot: np.ndarray,
    seed: np.ndarray,
    *,
    site: str = "tool_point",
    iterations: int = 300,
    margin: float = 0.0,
) -> tuple[np.ndarray, float]:
    """Joint angles ``(n,)`` that put ``site`` at ``pos`` ``(3,)`` [m] with rotation ``rot`` ``(3, 3)``, within
    the joint ranges shrunk by ``margin`` [rad]: damped least squares from ``seed``, clamped to the ranges
    (:func:`~seqmotion.sim.ik.damped_least_squares`, at most 0.3 rad per iteration).

    Returns:
        The angles and the final residual ``|[Δp, Δθ]|`` [m, rad mixed].
    """
    mujoco = import_mujoco()
    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site)
    if sid < 0:
        raise ValueError(f"the model has no site {site!r}")
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, _compiled_name(model, j)) for j in robot.joints]
    target = np.zeros(4)
    mujoco.mju_mat2Quat(target, np.asarray(rot, dtype=float).ravel())
    bounds = (robot.joint_range[:, 0] + margin, robot.joint_range[:, 1] - margin)
    q, err = damped_least_squares(model, data, sid, np.array([model.jnt_qposadr[i] for i in ids]),
                                  np.array([model.jnt_dofadr[i] for i in ids]), pos, target, seed,
                                  iterations=iterations, tolerance=1e-10, max_step=0.3, bounds=bounds,
                                  attitude_from_matrix=True)
    return q, float(np.linalg.norm(err))


def _compiled_name(model: Any, joint: str) -> str:
    """``joint``'s name in ``model``: as in the file, or with the scene's robot prefix."""
    mujoco = import_mujoco()
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint) >= 0:
        return joint
    for i in range(model.njnt):
        name = model.joint(i).name
        if name.endswith("/" + joint):
            return name
    raise ValueError(f"the model has no joint {joint!r}")


# --- what is available, by name ---------------------------------------------------------------------------------


def _menagerie_present(mm: Any, registry_name: str) -> Path | None:
    """The Menagerie model directory if it is on disk (cache or ``MENAGERIE_ROOT``), else ``None``; no download."""
    robot = mm.get(registry_name)
    cache = mm.Cache()
    if cache.root is not None:
        path = cache.root / robot.name
        return path if path.is_dir() else None
    return cache.model_path(robot) if cache.is_cached(robot) else None


def _menagerie_entry(mm: Any, registry_name: str) -> str:
    robot = mm.get(registry_name)
    for short, (name, entry) in MENAGERIE_ARMS.items():
        del short
        if name == registry_name and entry in robot.entry_names:
            return entry
    return robot.default_model


def _known_dof(key: str) -> int | None:
    """The joint count of a known arm (``"source:name"``), without reading its file: the published speed table
    holds one limit per joint, and :func:`load_robot` checks it against the file's joints."""
    speeds = VELOCITY_LIMITS.get(key)
    return None if speeds is None else len(speeds)


def robots() -> list[RobotInfo]:
    """The robots available here without a download: the built-in arm, robosuite's bundled arms (if its files
    are installed) and the Menagerie arms already on disk (its cache or ``MENAGERIE_ROOT``).

    Lists the files on disk by name and reads none of them: a model file may be slow or hostile to parse (a
    Menagerie tree is anyone's folder), and this listing is also what an unknown robot's error message shows.
    The joint count comes from :data:`VELOCITY_LIMITS` for the arms named there, else it is ``None``
    (unknown until :func:`get_robot` reads the file, with :func:`check_model_file`'s checks).
    """
    out = [RobotInfo(BUILT_IN, "seqmotion", 6, None)]
    root = robosuite_root()
    if root is not None:
        for name in ROBOSUITE_ARMS:
            path = root / name / "robot.xml"
            if path.is_file():
                out.append(RobotInfo(name, "robosuite", _known_dof(f"robosuite:{name}"), path))
    mm = _menagerie()
    if mm is not None:
        for info in mm.robots("arm"):
            if _menagerie_present(mm, info.name) is None:
                continue
            entry = _menagerie_entry(mm, info.name)
            try:
                path = info.xml(entry)
            except Exception:  # noqa: BLE001 - an incomplete local tree: not available
                continue
            if path.is_file():
                out.append(RobotInfo(f"menagerie:{info.name}", "menagerie", _known_dof(f"menagerie:{info.name}"),
                                     path))
    return out


def resolve_robot(robot: str | Robot | None) -> Robot | None:
    """``None`` or ``"mh3f"`` → ``None`` (the built-in arm); a name → :func:`get_robot`; a :class:`Robot` → itself."""
    if robot is None or isinstance(robot, Robot):
        return robot
    if isinstance(robot, str):
        return None if robot == BUILT_IN else get_robot(robot)
    raise ValueError(f"robot must be a robot's name (see seqmotion.sim.robots()) or a Robot, got {robot!r}")


@lru_cache(maxsize=32)
def get_robot(name: str) -> Robot:
    """The standard arm called ``name``.

    * ``"panda"``, ``"ur5e"``, ``"iiwa"``, ``"kinova3"``, ``"xarm7"``, ``"jaco"``, ``"sawyer"``: robosuite's file if
      robosuite's models are installed, else Menagerie's model of the same arm if it is on disk.
    * ``"robosuite:<name>"``: robosuite's ``models/assets/robots/<name>/robot.xml``.
    * ``"menagerie:<name>"`` (a Menagerie registry name, or one of the short names above): through
      ``mujoco_menagerie`` — downloaded on first use unless ``MENAGERIE_ROOT`` points at a local tree.

    Raises:
        ValueError: an unknown name, or a robot that is not available here (with what would provide it).
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"robot name must be a non-empty string, got {name!r}")
    if name == BUILT_IN:
        raise ValueError(f"{BUILT_IN!r} is the built-in arm, not a file model: pass robot=None (or use resolve_robot)")
    source, _, arm = name.partition(":") if ":" in name else ("", "", name)
    if source == "robosuite":
        return _robosuite_robot(arm)
    if source == "menagerie":
        return _menagerie_robot(arm, download=True)
    if source:
        raise ValueError(f"unknown robot source {source!r} in {name!r}: use 'robosuite:<name>' or 'menagerie:<name>'")
    if arm not in ROBOSUITE_ARMS and arm not in MENAGERIE_ARMS:
        raise ValueError(f"unknown robot {name!r}; known arms: {sorted(set(ROBOSUITE_ARMS) | set(MENAGERIE_ARMS))} "
                         f"(or 'robosuite:<name>' / 'menagerie:<name>'); available here: {_available_names()}")
    root = robosuite_root()
    if arm in ROBOSUITE_ARMS and root is not None and (root / arm / "robot.xml").is_file():
        return _robosuite_robot(arm)
    if arm in MENAGERIE_ARMS:
        robot = _menagerie_robot(arm, download=False)
        if robot is not None:
            return robot
    ways = []
    if arm in ROBOSUITE_ARMS:
        ways.append('robosuite\'s model files (pip install --no-deps "robosuite>=1.5,<1.6")')
    if arm in MENAGERIE_ARMS:
        ways.append(f"Menagerie's {MENAGERIE_ARMS[arm][0]!r} (robot='menagerie:{arm}' downloads it; or set "
                    "MENAGERIE_ROOT to a local Menagerie checkout; pip install 'seqmotion[robots]')")
    raise ValueError(f"robot {name!r} is not available here; it needs " + " or ".join(ways)
                     + f". Available here: {_available_names()}")


def _available_names() -> list[str]:
    return [r.name for r in robots()]


def _robosuite_robot(arm: str) -> Robot:
    root = robosuite_root()
    if root is None:
        raise ValueError(f"robot 'robosuite:{arm}' needs robosuite's model files: "
                         'pip install --no-deps "robosuite>=1.5,<1.6"')
    if arm not in ROBOSUITE_ARMS:
        raise ValueError(f"unknown robosuite arm {arm!r}; robosuite's arms: {list(ROBOSUITE_ARMS)}")
    path = root / arm / "robot.xml"
    if not path.is_file():
        raise ValueError(f"robosuite's file for {arm!r} is missing ({path})")
    return load_robot(path, "robosuite", arm, folder=root / arm, root=root)


def _menagerie_robot(arm: str, *, download: bool) -> Robot | None:
    """Menagerie's arm ``arm`` (registry name or short name); ``None`` if absent and ``download`` is false."""
    mm = _menagerie()
    if mm is None:
        if not download:
            return None
        raise ValueError(f"robot 'menagerie:{arm}' needs the mujoco-menagerie package: pip install 'seqmotion[robots]'")
    registry_name = MENAGERIE_ARMS[arm][0] if arm in MENAGERIE_ARMS else arm
    try:
        info = mm.get(registry_name)
    except mm.UnknownRobotError as exc:
        arms = [r.name for r in mm.robots("arm")]
        raise ValueError(f"unknown Menagerie robot {arm!r} ({exc}); Menagerie's arms: {arms}") from None
    if not download and _menagerie_present(mm, registry_name) is None:
        return None
    entry = _menagerie_entry(mm, registry_name)
    try:
        path = info.xml(entry)
    except mm.MenagerieError as exc:
        raise ValueError(f"Menagerie's {registry_name!r} is not available: {exc}. It is downloaded on first use "
                         "(needs internet), or set MENAGERIE_ROOT to a directory holding a "
                         f"{registry_name}/ folder from a Menagerie checkout") from None
    # The files must stay in the robot's own folder, and that folder in the tree (a model from MENAGERIE_ROOT is
    # anyone's file: MuJoCo would follow its absolute or ../ paths anywhere).
    cache = mm.Cache()
    if cache.root is not None:
        tree = Path(cache.root)
        folder = tree / info.name
    else:
        folder = Path(cache.model_path(info))
        tree = folder.parent
    return load_robot(path, "menagerie", registry_name, folder=folder, root=tree)
