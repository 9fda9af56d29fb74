"""The MuJoCo arm as triangle meshes, and replays of it executing a motion — no browser needed.

:func:`scene_geoms` reads every visible geom of a scene (:func:`seqmotion.sim.scene.build_scene`:
boxes, spheres, capsules, cylinders) into a mesh in its body's frame; :func:`replay` runs the same
controller the simulation runners use (:class:`seqmotion.sim.arm.Arm`: PD + disturbance observer at
1 ms, the object placed at rest on the tool) and records every body's pose every ``stride`` periods,
so the page only moves a few body frames per displayed frame. The metrics come from the runners
themselves (:func:`seqmotion.sim.run_pancake` / :func:`~seqmotion.sim.run_sliding`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

GEOM_SPHERE, GEOM_CAPSULE, GEOM_ELLIPSOID, GEOM_CYLINDER, GEOM_BOX = 2, 3, 4, 5, 6
HIDDEN_GROUP = 3
"""MuJoCo's convention (and the scenes'): geoms of group 3 are collision shapes, not drawn."""
TABLE_RGB = (205, 195, 175)


@dataclass
class GeomMesh:
    """One geom as a mesh: ``vertices`` ``(V, 3)`` in its body's frame, ``faces`` ``(F, 3)``, ``rgb`` 0–255."""

    name: str
    body: int
    vertices: np.ndarray
    faces: np.ndarray
    rgb: tuple[int, int, int]


def _sphere(radius: float, n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    return _capsule(radius, 0.0, n)


def _capsule(radius: float, half: float, n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """A capsule along z (a sphere for ``half = 0``): a lower hemisphere at -half, an upper one at +half."""
    m = n // 2
    lower = [(radius * math.cos(a), radius * math.sin(a) - half) for a in np.linspace(-math.pi / 2, 0, m + 1)]
    upper = [(radius * math.cos(a), radius * math.sin(a) + half) for a in np.linspace(0, math.pi / 2, m + 1)]
    return _lathe(lower + upper[1:] if half == 0 else lower + upper, 2 * n)


def _cylinder(radius: float, half: float, n: int = 24) -> tuple[np.ndarray, np.ndarray]:
    return _lathe([(0.0, -half), (radius, -half), (radius, half), (0.0, half)], n)


def _lathe(profile: list[tuple[float, float]], n: int) -> tuple[np.ndarray, np.ndarray]:
    """Revolve ``(r, z)`` points about z into a closed mesh."""
    angles = np.linspace(0, 2 * math.pi, n, endpoint=False)
    verts = np.array([(r * math.cos(a), r * math.sin(a), z) for r, z in profile for a in angles])
    faces = []
    for i in range(len(profile) - 1):
        for j in range(n):
            a, b = i * n + j, i * n + (j + 1) % n
            c, d = a + n, b + n
            faces += [(a, b, d), (a, d, c)]
    return verts, np.array(faces)


def _box(half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float) * half
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return corners, faces


def quat_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``[w, x, y, z]``."""
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def scene_geoms(model: object) -> list[GeomMesh]:
    """Every drawn geom of a compiled MuJoCo model as a mesh in its body's frame (group-3 collision shapes and
    transparent geoms left out)."""
    import mujoco

    out = []
    for g in range(model.ngeom):
        rgba = model.geom_rgba[g]
        if model.geom_group[g] == HIDDEN_GROUP or rgba[3] == 0:
            continue
        kind, size = int(model.geom_type[g]), model.geom_size[g]
        if kind == GEOM_BOX:
            v, f = _box(size)
        elif kind == GEOM_SPHERE:
            v, f = _sphere(size[0])
        elif kind == GEOM_CAPSULE:
            v, f = _capsule(size[0], size[1])
        elif kind == GEOM_CYLINDER:
            v, f = _cylinder(size[0], size[1])
        elif kind == GEOM_ELLIPSOID:
            v, f = _sphere(1.0)
            v = v * size
        else:  # planes, height fields, meshes: none in these scenes
            continue
        v = v @ quat_matrix(model.geom_quat[g]).T + model.geom_pos[g]
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}"
        rgb = TABLE_RGB if model.geom_matid[g] >= 0 else tuple(int(255 * c) for c in rgba[:3])
        out.append(GeomMesh(name, int(model.geom_bodyid[g]), v.astype(np.float32), f.astype(np.uint32), rgb))
    return out


@dataclass
class Replay:
    """Body poses over an execution: ``time`` ``(N,)`` [s from the motion's start], ``pos`` ``(N, nbody, 3)``,
    ``quat`` ``(N, nbody, 4)`` (``[w, x, y, z]``); ``summary``: the runner's one-line verdict; ``realtime``:
    simulated over wall time of the recording run."""

    kind: str
    time: np.ndarray
    pos: np.ndarray
    quat: np.ndarray
    summary: str
    realtime: float
    n_motion: int


def rest_poses(kind: str, start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every body's pose ``(nbody, 3)``, ``(nbody, 4)`` with the tool at the scene's home (or at the first
    planar state ``start``), the object on it."""
    from ..sim.arm import Arm, get_scene, place_on_tool
    from ..sim.control import resolve_gains
    from ..sim.kinematics import pan_reference, planar_reference
    from ..sim.scene import OBJECT_HALF_HEIGHT

    scene = get_scene(kind)
    if kind == "pancake":
        ref = planar_reference(np.zeros((2, 6)) if start is None else np.tile(start, (2, 1)))
        height = 0.0
    else:
        ref = pan_reference(np.zeros((2, 4)))
        height = OBJECT_HALF_HEIGHT
    arm = Arm(scene, resolve_gains("ch2"))
    arm.reset(ref.pos[0], ref.quat[0], place_on_tool(scene, height, np.zeros(2)), np.zeros(3))
    return arm.data.xpos.copy(), arm.data.xquat.copy()


def replay(kind: str, motion: np.ndarray, command: np.ndarray | None = None, stride: int = 10,
           settle_time: float = 0.2, tail: float = 0.5) -> Replay:
    """Execute ``motion`` on the arm and record every body's pose every ``stride`` ms.

    Args:
        kind: ``"pancake"`` (``motion``: planar spatula states ``(K, 6)``) or ``"sliding"`` (pan states
            ``(K, 4)``; ``command``: the object path ``(K, 4)``, whose start is where the object is placed).
        stride: record every this many 1 ms periods.
        settle_time: held at the first pose first (not recorded), as the runners do.
        tail: deceleration (0.1 s) plus hold after the motion [s].
    """
    import time as _time

    from ..sim import run_pancake, run_sliding
    from ..sim.arm import Arm, get_scene, place_on_tool, prepare_reference, weight
    from ..sim.control import resolve_gains
    from ..sim.kinematics import pan_reference, planar_reference
    from ..sim.scene import OBJECT_HALF_HEIGHT, OBJECT_MASS, PANCAKE_MASS

    scene = get_scene(kind)
    hold = max(tail - 0.1, 0.0)
    if kind == "pancake":
        ref = planar_reference(motion, decel_time=0.1, hold_time=hold)
        gains, height, offset, mass = resolve_gains("ch2"), 0.0, np.zeros(2), PANCAKE_MASS
    else:
        ref = pan_reference(motion, decel_time=0.1, hold_time=hold)
        start = np.zeros(2) if command is None else np.asarray(command)[0, :2]
        gains, height, offset, mass = resolve_gains("ch3"), OBJECT_HALF_HEIGHT, start, OBJECT_MASS
    prepare_reference(ref, kind, accel_feedforward=True, check_workspace=True)
    arm = Arm(scene, gains)
    arm.reset(ref.pos[0], ref.quat[0], place_on_tool(scene, height, offset), weight(mass))
    still = np.zeros(6)
    twist = np.concatenate([ref.vel, ref.omega], axis=1)
    accel = np.concatenate([ref.acc, ref.alpha], axis=1)
    times, poses, quats = [], [], []
    began = _time.perf_counter()
    for k in range(-round(settle_time / ref.dt), len(ref)):
        if k < 0:
            arm.step(ref.pos[0], ref.quat[0], still, still)
            continue
        if k % stride == 0:
            times.append(k * ref.dt)
            poses.append(arm.data.xpos.copy())
            quats.append(arm.data.xquat.copy())
        arm.step(ref.pos[k], ref.quat[k], twist[k], accel[k])
        if k % 50 == 0 and arm.diverged():
            break
    wall = _time.perf_counter() - began
    if kind == "pancake":
        summary = run_pancake(motion, hold_time=hold).describe()
    else:
        summary = run_sliding(motion, command, hold_time=hold).describe()
    return Replay(kind, np.array(times), np.array(poses), np.array(quats), summary,
                  (len(ref) + settle_time / ref.dt) * ref.dt / max(wall, 1e-9), len(motion))


def planar_to_world(states: np.ndarray) -> np.ndarray:
    """Pancake planar ``(y, z)`` → world points ``(K, 3)`` of the tool site (eq. 4.9)."""
    from ..sim.scene import PANCAKE_ORIGIN

    pts = np.empty((len(states), 3))
    pts[:, 0] = PANCAKE_ORIGIN[0]
    pts[:, 1] = PANCAKE_ORIGIN[1] + states[:, 0]
    pts[:, 2] = PANCAKE_ORIGIN[2] + states[:, 1]
    return pts


def pan_to_world(pan: np.ndarray, rel: np.ndarray | None = None, lift: float = 0.004) -> np.ndarray:
    """Pan ``(x, y)`` (plus an object ``(x, y)`` relative to it) → world points ``(K, 3)`` just above the pan
    surface (eq. 3.28)."""
    from ..sim.scene import PAN_ORIGIN

    xy = pan[:, :2] + (0 if rel is None else rel[:, :2])
    return np.column_stack([PAN_ORIGIN[0] + xy[:, 0], PAN_ORIGIN[1] + xy[:, 1], np.full(len(xy), PAN_ORIGIN[2] + lift)])
