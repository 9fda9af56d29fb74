"""Joint limits as data: what a robot's joints may do, each kind with the document or file it comes from.

:class:`JointLimits` holds one robot's ranges, rated speeds, rated accelerations and torque limits (a kind that is not
known says why, and is never taken as unlimited); :data:`RATED_LIMITS` is the table of the makers' published speeds
and accelerations, which the model files do not carry. :mod:`.robot_models` builds a robot's ``JointLimits`` from
its model file and this table; :mod:`.arm` and :mod:`.executable` judge motions against them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np


def _deg(*values: float) -> tuple[float, ...]:
    return tuple(math.radians(v) for v in values)


@dataclass(frozen=True)
class RatedLimits:
    """A maker's published joint limits for one arm, base → flange, and the documents they come from.

    Attributes:
        velocity: ``(n,)`` rated joint speeds [rad/s].
        source: where the speeds are published.
        acceleration: ``(n,)`` rated joint accelerations [rad/s²], or ``None`` (none found published).
        acceleration_source: where the accelerations are published (``None`` without them).
    """

    velocity: tuple[float, ...]
    source: str
    acceleration: tuple[float, ...] | None = None
    acceleration_source: str | None = None


_PANDA_RATED = RatedLimits(
    (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61),
    "Franka Emika FCI documentation, Panda 'Robot and interface specifications' (q̇_max)",
    (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0),
    "Franka Emika FCI documentation, Panda 'Robot and interface specifications' (q̈_max; libfranka's "
    "include/franka/rate_limiting.h kMaxJointAcceleration)",
)
_UR5E_RATED = RatedLimits(_deg(180, 180, 180, 180, 180, 180),
                          "Universal Robots UR5e technical specification (joint speeds ±180°/s)")
_KINOVA3_RATED = RatedLimits((1.39, 1.39, 1.39, 1.39, 1.22, 1.22, 1.22),
                             "Kinova Gen3 (7 DoF) user guide (large actuators 1–4 1.39 rad/s, small 5–7 1.22 rad/s)")
_XARM7_RATED = RatedLimits(_deg(180, 180, 180, 180, 180, 180, 180),
                           "UFACTORY xArm7 user manual (maximum joint speed 180°/s)")
_SAWYER_RATED = RatedLimits((1.74, 1.328, 1.957, 1.957, 3.485, 3.485, 4.545),
                            "Rethink Robotics Sawyer: the maker's URDF (sawyer_description) joint velocity limits")

RATED_LIMITS: dict[str, RatedLimits] = {
    "robosuite:panda": _PANDA_RATED,
    "menagerie:franka_emika_panda": _PANDA_RATED,
    "menagerie:franka_fr3": RatedLimits((2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26),
                                        "Franka Research 3 FCI documentation, 'Limits for Franka Research 3' (q̇_max)"),
    "robosuite:ur5e": _UR5E_RATED,
    "menagerie:universal_robots_ur5e": _UR5E_RATED,
    "menagerie:universal_robots_ur10e": RatedLimits(
        _deg(120, 120, 180, 180, 180, 180),
        "Universal Robots UR10e technical specification (base and shoulder ±120°/s, elbow and wrists ±180°/s)"),
    # robosuite's iiwa (torque limits 176/176/110/110/110/40/40 N m) is the KUKA LBR iiwa 7 R800.
    "robosuite:iiwa": RatedLimits(_deg(98, 98, 100, 130, 140, 180, 180),
                                  "KUKA LBR iiwa specification, LBR iiwa 7 R800 (A1–A7 98, 98, 100, 130, 140, 180, "
                                  "180°/s)"),
    "menagerie:kuka_iiwa_14": RatedLimits(_deg(85, 85, 100, 75, 130, 135, 135),
                                          "KUKA LBR iiwa specification, LBR iiwa 14 R820 (A1–A7 85, 85, 100, 75, 130, "
                                          "135, 135°/s)"),
    "robosuite:kinova3": _KINOVA3_RATED,
    "menagerie:kinova_gen3": _KINOVA3_RATED,
    "robosuite:xarm7": _XARM7_RATED,
    "menagerie:ufactory_xarm7": _XARM7_RATED,
    "robosuite:jaco": RatedLimits(_deg(36, 36, 36, 36, 48, 48, 48),
                                  "Kinova JACO² 7-DoF spherical (j2s7s300) specifications (36°/s joints 1–4, 48°/s "
                                  "joints 5–7)"),
    "robosuite:sawyer": _SAWYER_RATED,
    "menagerie:rethink_robotics_sawyer": _SAWYER_RATED,
}
"""The makers' published joint limits per ``"source:name"`` (speeds, and accelerations where published); an arm
not listed has ``velocity_limit=None``: its rated speeds are unknown, and reported as such, never as unlimited."""

VELOCITY_LIMITS: dict[str, tuple[float, ...]] = {key: rated.velocity for key, rated in RATED_LIMITS.items()}
"""The rated joint speeds [rad/s] of :data:`RATED_LIMITS`, per ``"source:name"``."""


LIMIT_KINDS = ("position", "velocity", "acceleration", "torque")
"""The kinds of joint limit :class:`JointLimits` carries: ranges [rad], speeds [rad/s], accelerations [rad/s²],
torques [N m]."""

_LIMIT_NAMES = {"position": "joint ranges", "velocity": "rated speeds", "acceleration": "rated accelerations",
                "torque": "torque limits"}


@dataclass(frozen=True, eq=False)
class JointLimits:
    """A robot's joint limits, base → flange, each kind with where it comes from.

    A kind that is not known is ``None`` with a source that starts with ``"unknown: "`` and says why: a caller reports
    it as unknown and never treats it as unlimited (a continuous joint, whose range *is* known to have no ends, is
    ``±inf`` in ``position``).

    Attributes:
        robot: the robot, ``"name (source)"``.
        joints: the joint names, base → flange (``n`` of them).
        position: ``(n, 2)`` joint ranges [rad] (``±inf`` for a continuous joint), or ``None``.
        velocity: ``(n,)`` rated joint speeds [rad/s], or ``None``.
        acceleration: ``(n,)`` rated joint accelerations [rad/s²], or ``None``.
        torque: ``(n,)`` torque limits [N m], or ``None``.
        sources: kind (:data:`LIMIT_KINDS`) → the document or model file it comes from, or ``"unknown: <why>"``.
    """

    robot: str
    joints: tuple[str, ...]
    position: np.ndarray | None
    velocity: np.ndarray | None
    acceleration: np.ndarray | None
    torque: np.ndarray | None
    sources: dict[str, str]

    def __post_init__(self) -> None:
        n = len(self.joints)
        if set(self.sources) != set(LIMIT_KINDS):
            raise ValueError(f"{self.robot}: limit sources must name exactly {LIMIT_KINDS}, got {sorted(self.sources)}")
        for kind in LIMIT_KINDS:
            value, source = getattr(self, kind), self.sources[kind]
            if not isinstance(source, str) or not source:
                raise ValueError(f"{self.robot}: the source of its {_LIMIT_NAMES[kind]} must be a non-empty string")
            if value is None:
                if not source.startswith("unknown: "):
                    raise ValueError(f"{self.robot}: {_LIMIT_NAMES[kind]} are None but their source {source!r} does "
                                     "not start with 'unknown: '")
                continue
            arr = np.array(value, dtype=np.float64)
            shape = (n, 2) if kind == "position" else (n,)
            if arr.shape != shape:
                raise ValueError(f"{self.robot}: {_LIMIT_NAMES[kind]} must have shape {shape}, got {arr.shape}")
            bad = np.isnan(arr).any() or (np.any(arr[:, 0] >= arr[:, 1]) if kind == "position"
                                          else not np.all(np.isfinite(arr) & (arr > 0)))
            if bad:
                raise ValueError(f"{self.robot}: {_LIMIT_NAMES[kind]} must be " + (
                    "ranges with lower < upper" if kind == "position" else "finite and positive") + f", got {arr}")
            arr.setflags(write=False)
            object.__setattr__(self, kind, arr)
        object.__setattr__(self, "sources", dict(self.sources))

    def known(self, kind: str) -> bool:
        """Whether the limits of ``kind`` (one of :data:`LIMIT_KINDS`) are known."""
        if kind not in LIMIT_KINDS:
            raise ValueError(f"limit kind must be one of {LIMIT_KINDS}, got {kind!r}")
        return getattr(self, kind) is not None

    def unknown(self, kind: str) -> str | None:
        """Why the limits of ``kind`` are unknown (``"rated speeds unknown for mh3f (seqmotion): …"``), or ``None``
        where they are known."""
        if self.known(kind):
            return None
        return f"{_LIMIT_NAMES[kind]} unknown for {self.robot}: {self.sources[kind].removeprefix('unknown: ')}"

    def summary(self) -> dict[str, Any]:
        """The limits as a JSON-friendly dict: lists (``None`` for an unknown kind, and for a continuous joint's
        range ends) and ``sources``."""
        out: dict[str, Any] = {"robot": self.robot, "joints": list(self.joints)}
        for kind in LIMIT_KINDS:
            value = getattr(self, kind)
            out[kind] = None if value is None else [
                (None if not np.isfinite(x) else float(x)) if np.ndim(x) == 0 else
                [None if not np.isfinite(v) else float(v) for v in x] for x in value]
        out["sources"] = dict(self.sources)
        return out
