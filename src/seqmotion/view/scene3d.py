"""The MuJoCo arm as triangle meshes, and replays of it executing a motion — no browser needed.

:func:`scene_geoms` reads every visible geom of a scene (:func:`seqmotion.sim.scene.build_scene`:
boxes, spheres, capsules, cylinders, and the meshes of a standard robot's links) into a mesh in its
body's frame; :func:`replay` runs the same controller the simulation runners use
(:class:`seqmotion.sim.arm.Arm`: PD + disturbance observer at 1 ms — in joint space behind a
differential IK on a standard robot — the object placed at rest on the tool) and records every body's
pose every ``stride`` periods, so the page only moves a few body frames per displayed frame. The
metrics come from the runners themselves (:func:`seqmotion.sim.run_pancake` /
:func:`~seqmotion.sim.run_sliding`, on the same ``robot``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

GEOM_SPHERE, GEOM_CAPSULE, GEOM_ELLIPSOID, GEOM_CYLINDER, GEOM_BOX, GEOM_MESH = 2, 3, 4, 5, 6, 7
HIDDEN_GROUP = 3
"""MuJoCo's convention (and the scenes'): geoms of group 3 are collision shapes, not drawn."""
MESH_FACE_BUDGET = 40_000
"""Triangles all of a scene's mesh geoms may send to the page together. A robot's published visual meshes
are far finer than a browser view needs (robosuite's Panda: ~127 000 triangles; its iiwa: ~250 000), and
software WebGL redraws every triangle on every camera move; the largest meshes are simplified until the
scene fits (:func:`fit_budget`), small ones stay exact."""
DECIMATE_TRIES = 8
"""Clusterings :func:`decimate` tries per mesh before it keeps the finest that fit."""
DEFAULT_RGBA = (0.5, 0.5, 0.5, 1.0)
"""MuJoCo's default geom colour: a geom left at it shows its material's colour instead."""
TEXTURE_RGB_ROLE = 1
"""Index of the colour (RGB) texture in ``model.mat_texid``'s roles (``mjTEXROLE_RGB``)."""


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


def geom_rgb(model: object, g: int) -> tuple[tuple[int, int, int], float]:
    """Geom ``g``'s colour as MuJoCo draws it: 0–255 RGB and alpha.

    Its material's colour where it has a material and its own ``rgba`` is left at :data:`DEFAULT_RGBA`
    (MuJoCo's rule), else its ``rgba``; a material's colour texture is drawn as its mean texel colour (the
    page gets plain colours, no textures)."""
    rgba = np.asarray(model.geom_rgba[g], dtype=np.float64)
    mat = int(model.geom_matid[g])
    if mat >= 0 and np.allclose(rgba, DEFAULT_RGBA):
        rgba = np.asarray(model.mat_rgba[mat], dtype=np.float64).copy()
        texid = np.atleast_1d(model.mat_texid[mat])
        tex = int(texid[TEXTURE_RGB_ROLE] if len(texid) > TEXTURE_RGB_ROLE else texid[0])
        if tex >= 0:
            rgba[:3] *= _mean_texel(model, tex)
    rgb = tuple(int(255 * float(np.clip(c, 0.0, 1.0))) for c in rgba[:3])
    return rgb, float(rgba[3])


def _mean_texel(model: object, tex: int) -> np.ndarray:
    """``(3,)`` mean colour of texture ``tex`` in [0, 1] (white if it has fewer than 3 channels)."""
    channels = int(model.tex_nchannel[tex])
    if channels < 3:
        return np.ones(3)
    size = int(model.tex_width[tex]) * int(model.tex_height[tex]) * channels
    adr = int(model.tex_adr[tex])
    texels = np.asarray(model.tex_data[adr : adr + size], dtype=np.float64).reshape(-1, channels)
    return texels[:, :3].mean(axis=0) / 255.0


def mesh_of(model: object, g: int) -> tuple[np.ndarray, np.ndarray]:
    """The mesh of mesh geom ``g`` in the geom's frame: vertices ``(V, 3)`` [m], faces ``(F, 3)`` (indices into
    them). MuJoCo stores a mesh recentred at its centroid and turned to its principal axes; the compiled geom
    pose (``geom_pos``, ``geom_quat``) already includes that shift, so these vertices go through it unchanged."""
    mesh = int(model.geom_dataid[g])
    if int(model.geom_type[g]) != GEOM_MESH or mesh < 0:
        raise ValueError(f"geom {g} is not a mesh geom")
    vadr, nv = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    fadr, nf = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
    return (np.asarray(model.mesh_vert[vadr : vadr + nv], dtype=np.float64),
            np.asarray(model.mesh_face[fadr : fadr + nf], dtype=np.int64))


def decimate(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``max_faces`` triangles approximating the mesh ``vertices`` ``(V, 3)``, ``faces`` ``(F, 3)``.

    Vertex clustering on a uniform grid: vertices in one cell merge into their mean, triangles whose
    corners merge collapse and go, duplicates go. The cell is searched (at most :data:`DECIMATE_TRIES`
    clusterings) from a surface's law, triangles ∝ cell⁻², for the finest that leaves at most
    ``max_faces``. Crude next to quadric simplification, but with no dependency and a few milliseconds
    per link; at the budget's resolution (millimetres on an arm's link) the shape a viewer shows is kept.
    A mesh already within ``max_faces`` is returned as is.
    """
    if max_faces < 1:
        raise ValueError(f"max_faces must be at least 1, got {max_faces}")
    if len(faces) <= max_faces:
        return vertices, faces
    lo = vertices.min(axis=0)
    extent = float((vertices.max(axis=0) - lo).max())
    if not extent > 0 or not np.isfinite(extent):
        return vertices[:0], faces[:0]

    def cluster(cell: float) -> tuple[np.ndarray, np.ndarray]:
        idx = np.floor((vertices - lo) / cell).astype(np.int64)
        dims = idx.max(axis=0) + 1
        _, inverse = np.unique((idx[:, 0] * dims[1] + idx[:, 1]) * dims[2] + idx[:, 2], return_inverse=True)
        f = inverse.ravel()[faces]
        f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
        n = int(inverse.max()) + 1
        s = np.sort(f, axis=1)
        if n < 2**20:  # a face's three indices as one int64 key (fast); rows otherwise
            _, first = np.unique((s[:, 0] * n + s[:, 1]) * n + s[:, 2], return_index=True)  # a face twice: once
        else:
            _, first = np.unique(s, axis=0, return_index=True)
        f = f[np.sort(first)]
        counts = np.bincount(inverse.ravel(), minlength=n).astype(np.float64)
        v = np.stack([np.bincount(inverse.ravel(), vertices[:, i], minlength=n) for i in range(3)], axis=1)
        v /= np.maximum(counts, 1.0)[:, None]
        used = np.unique(f)  # drop vertices no face refers to any more
        remap = np.full(n, -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        return v[used], remap[f]

    target = 0.9 * max_faces  # aim a little under: the law is rough, an overshoot costs a try
    cell = extent * math.sqrt(2.0 / max_faces)
    best: tuple[np.ndarray, np.ndarray] | None = None
    for _ in range(DECIMATE_TRIES):
        trial = cluster(cell)
        n = len(trial[1])
        if n <= max_faces and (best is None or n > len(best[1])):
            best = trial
        if target <= n <= max_faces:
            break
        cell *= min(max(math.sqrt(max(n, 1) / target), 0.5), 3.0) * (1.0 if n <= max_faces else 1.02)
    while best is None:  # the law missed every try: coarser until it fits (one cell of the whole keeps none)
        cell *= 2.0
        trial = cluster(cell)
        best = trial if len(trial[1]) <= max_faces else None
    return best


def fit_budget(counts: list[int], budget: int) -> int:
    """The per-mesh triangle cap ``c`` such that meshes of ``counts`` triangles, each cut to ``min(n, c)``, fit
    in ``budget`` together (water filling: the small meshes stay whole, the large ones share the rest)."""
    if budget < 1:
        raise ValueError(f"the triangle budget must be at least 1, got {budget}")
    if sum(counts) <= budget:
        return max(counts, default=0)
    ordered = sorted(counts)
    left = budget
    for i, n in enumerate(ordered):
        share = left // (len(ordered) - i)
        if n > share:
            return max(share, 1)
        left -= n
    return ordered[-1]


def scene_geoms(model: object, max_mesh_faces: int = MESH_FACE_BUDGET) -> list[GeomMesh]:
    """Every drawn geom of a compiled MuJoCo model as a mesh in its body's frame (group-3 collision shapes and
    transparent geoms left out).

    Primitive geoms are tessellated; mesh geoms (a robot's links) are read from the model, the largest
    simplified (:func:`decimate`) so that all mesh geoms together send at most ``max_mesh_faces`` triangles.
    Colours: :func:`geom_rgb`.
    """
    import mujoco

    drawn = []
    for g in range(model.ngeom):
        rgb, alpha = geom_rgb(model, g)
        if model.geom_group[g] == HIDDEN_GROUP or alpha == 0:
            continue
        drawn.append((g, rgb))
    meshes = [g for g, _ in drawn if int(model.geom_type[g]) == GEOM_MESH and model.geom_dataid[g] >= 0]
    cap = fit_budget([int(model.mesh_facenum[model.geom_dataid[g]]) for g in meshes], max_mesh_faces)
    out = []
    for g, rgb in drawn:
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
        elif kind == GEOM_MESH and model.geom_dataid[g] >= 0:
            v, f = decimate(*mesh_of(model, g), cap)
            if len(f) == 0:
                continue
        else:  # planes, height fields, signed-distance fields: none in these scenes
            continue
        v = v @ quat_matrix(model.geom_quat[g]).T + model.geom_pos[g]
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}"
        out.append(GeomMesh(name, int(model.geom_bodyid[g]), v.astype(np.float32), f.astype(np.uint32), rgb))
    return out


@dataclass
class Replay:
    """Body poses over an execution: ``time`` ``(N,)`` [s from the motion's start], ``pos`` ``(N, nbody, 3)``,
    ``quat`` ``(N, nbody, 4)`` (``[w, x, y, z]``); ``summary``: the runner's one-line verdict; ``realtime``:
    simulated over wall time of the recording run; ``robot``: the arm that ran it, ``"name (source)"``."""

    kind: str
    time: np.ndarray
    pos: np.ndarray
    quat: np.ndarray
    summary: str
    realtime: float
    n_motion: int
    robot: str = "mh3f (seqmotion)"


def rest_poses(kind: str, start: np.ndarray | None = None,
               robot: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every body's pose ``(nbody, 3)``, ``(nbody, 4)`` with the tool at the scene's home (or at the first
    planar state ``start``), the object on it; ``robot``: a standard arm's name
    (:func:`seqmotion.sim.robot_models.robots`), ``None`` the built-in arm."""
    from ..sim.arm import Arm, get_scene, place_on_tool
    from ..sim.control import resolve_gains
    from ..sim.kinematics import pan_reference, planar_reference
    from ..sim.scene import OBJECT_HALF_HEIGHT

    scene = get_scene(kind, robot)
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
           settle_time: float = 0.2, tail: float = 0.5, robot: str | None = None) -> Replay:
    """Execute ``motion`` on the arm and record every body's pose every ``stride`` ms.

    Args:
        kind: ``"pancake"`` (``motion``: planar spatula states ``(K, 6)``) or ``"sliding"`` (pan states
            ``(K, 4)``; ``command``: the object path ``(K, 4)``, whose start is where the object is placed).
        stride: record every this many 1 ms periods.
        settle_time: held at the first pose first (not recorded), as the runners do.
        tail: deceleration (0.1 s) plus hold after the motion [s].
        robot: a standard arm's name (``"panda"``, ``"ur5e"``, ``"menagerie:<name>"``; see
            :func:`seqmotion.sim.robot_models.robots`), tracked by differential IK + joint-space PD + DOB as in the
            runners; ``None``: the built-in arm. The summary then names a joint, speed or torque limit the
            run broke, or a pose out of the robot's reach.
    """
    from ..sim import run_pancake, run_sliding
    from ..sim.backend import CONTROL_DT

    times: list[float] = []
    poses: list[np.ndarray] = []
    quats: list[np.ndarray] = []

    def observe(k: int, data: object) -> None:
        """The runner's own run, through the control step's recording hook: every ``stride``-th period."""
        if k % stride == 0:
            times.append(k * CONTROL_DT)
            poses.append(data.xpos.copy())
            quats.append(data.xquat.copy())

    hold = max(tail - 0.1, 0.0)
    if kind == "pancake":
        result = run_pancake(motion, settle_time=settle_time, hold_time=hold, robot=robot, observe=observe)
    else:
        result = run_sliding(motion, command, settle_time=settle_time, hold_time=hold, robot=robot, observe=observe)
    return Replay(kind, np.array(times), np.array(poses), np.array(quats), result.describe(),
                  result.realtime_factor, len(motion), result.robot)


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
