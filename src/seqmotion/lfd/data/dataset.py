"""Demonstration datasets of the pushing task (dissertation 5.3.3) in HDF5.

Sets (all seeded and deterministic; the chapter's episodes cycle through the six block positions,
the hard set's draw their placement from ``seqmotion.lfd.env.pushing.sample_hard_placement``):

=====================  ==========  =========  ======================================
name                   episodes    images     purpose
=====================  ==========  =========  ======================================
``motions``            90 (15×6)   none       SeqAE training (motions without images)
``pairs_default``      18 (3×6)    default    CNN training (image–motion pairs)
``pairs_position1``    18 (3×6)    position1  CNN retraining after the camera moved
``pairs_position2``    18 (3×6)    position2  CNN retraining after the camera moved
``hard``               140         default    the hard benchmark: every method trains on its first
                                              N successful episodes (images and 50 fps video)
``hard_motions``       400         none       the hard benchmark's motions without images (cheap to
                                              record: what the proposed method's SeqAE can add)
=====================  ==========  =========  ======================================

File layout (format ``seqmotion.lfd.pushing``, version 1). N episodes of K samples at
``dt = 1 ms``; float arrays are float32, gzip-compressed, chunked per episode::

    /                       attrs: format, version, set_name, seed, dt [s], duration [s],
                                   n_episodes, samples (K), camera ("" if no images),
                                   image_size, complete (False until the last episode is
                                   written), motion_columns, phases, scene, gains (JSON)
    /motions/master_theta   (N, K, 3)  master joint angles θ_m [rad]
    /motions/master_dtheta  (N, K, 3)  master velocities θ̇_m (10 Hz pseudo-derivative) [rad/s]
    /motions/master_tau     (N, K, 3)  master reaction torque τ_m (RTOB) [N m]
    /motions/slave_theta    (N, K, 3)  slave θ_s [rad]
    /motions/slave_dtheta   (N, K, 3)  slave θ̇_s [rad/s]
    /motions/slave_tau      (N, K, 3)  slave τ_s [N m]
    /motions/block_pose     (N, K, 7)  block centre [m] and quaternion (w, x, y, z)
    /motions/hand_force     (N, K, 3)  operator's force on the master tip [N]
    /motions/master_tip     (N, K, 3)  master tip position [m]
    /motions/slave_tip      (N, K, 3)  slave tip position [m]
    /motions/phase          (N, K)     int8 operator phase (index into attrs["phases"])
    /episodes/position_index (N,) int8 block position 0..5 (seqmotion.lfd.env.pushing.POSITIONS); -1 on the hard set
    /episodes/side          (N,)  str  "left" / "right"
    /episodes/distance      (N,)  block centre's distance from the centre line [m]
    /episodes/seed_key      (N, 3) int64 (seed, set id, episode): np.random.SeedSequence(seed,
                                   spawn_key=(set id, episode)) regenerates the episode
    /episodes/reach         (N,)  block centre's forward position [m]
    /episodes/shape         (N,)  str  "box" / "cylinder"
    /episodes/success       (N,)  bool: block centre across the centre line at the end (hard: at
                                   its goal, ``PushingScene.success``)
    /episodes/crossed_time  (N,)  first time the centre crossed [s] (NaN if never)
    /episodes/n_pushes      (N,)  int8 pushes the operator made
    /episodes/block_initial_pose (N, 7)
    /episodes/variation/<name>   scene variation (block offset/yaw, light, tints)
    /operator/<name>        (N,)  operator parameters (seqmotion.lfd.env.operator.OperatorParams)
    /images                 (N, 64, 64, 3) uint8, only in image sets: the webcam image
                                   taken just before the motion
    /video                  (N, F, 64, 64, 3) uint8, hard sets: the webcam every 20 ms from t = 0
    /cameras/<name>         attrs pos, target [m], fovy [deg] of every webcam pose

Phase 2 reads 20 ms motions with :meth:`PushingDataset.motion` (by default every 20th sample).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...errors import check_number

FORMAT = "seqmotion.lfd.pushing"
VERSION = 1
MOTION_KEYS = ("master_theta", "master_dtheta", "master_tau", "slave_theta", "slave_dtheta", "slave_tau")
"""The six recorded variables, in the column order of :meth:`PushingDataset.motion`."""
EXTRA_KEYS = ("block_pose", "hand_force", "master_tip", "slave_tip")
_WIDTH = {"block_pose": 7}


@dataclass(frozen=True)
class SetSpec:
    """A dataset to collect: ``per_position`` episodes at each of the 6 block positions (chapter),
    or ``episodes`` placements drawn from the hard benchmark (``benchmark="hard"``).

    ``camera`` names the webcam pose the image is taken from, or ``None`` for motion-only sets.
    ``set_id`` keeps seeds of different sets apart (it enters the episode's seed key). A hard set
    also films every episode at 50 fps (``/video``): what a policy that watches the scene, such as
    ACT, trains on.
    """

    per_position: int
    camera: str | None
    set_id: int
    benchmark: str = "chapter"
    episodes: int = 0


SETS: dict[str, SetSpec] = {
    "motions": SetSpec(15, None, 1),
    "pairs_default": SetSpec(3, "default", 2),
    "pairs_position1": SetSpec(3, "position1", 3),
    "pairs_position2": SetSpec(3, "position2", 4),
    "hard": SetSpec(0, "default", 5, "hard", 140),
    "hard_motions": SetSpec(0, None, 6, "hard", 400),
}
"""The dissertation's sets (5.3.3 and Table 5.3) and the hard benchmark's (``seqmotion.lfd.env.pushing.
sample_hard_placement``: 140 episodes, of which the first 10/25/50/100 successful ones make the
data-efficiency curve's training sets)."""
CHAPTER_SETS = tuple(name for name, spec in SETS.items() if spec.benchmark == "chapter")
"""The dissertation's four sets: what :func:`collect` records by default."""

DEFAULT_DURATION = 4.0
"""Recorded length of one chapter demonstration [s] (4000 samples at 1 ms, 200 at 20 ms); the hard
benchmark's are 6 s (:data:`seqmotion.lfd.env.pushing.EPISODE_SECONDS`)."""


@dataclass
class SetReport:
    """What :func:`collect_set` did: the file, success per position (6,; hard: one entry), wall time [s]."""

    name: str
    path: Path
    episodes: int
    successes: np.ndarray
    attempts: np.ndarray
    seconds: float

    @property
    def success_rate(self) -> float:
        return float(self.successes.sum() / max(self.attempts.sum(), 1))


def episode_rng(seed: int, set_id: int, episode: int) -> np.random.Generator:
    """The random generator of one episode (operator, scene variation, perception, tremor)."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(set_id, episode)))


def _scene_description(benchmark: str = "chapter") -> dict:
    from ..env import pushing

    hard = {
        "benchmark": "hard", "distance_range_m": list(pushing.HARD_DISTANCE), "reach_range_m": list(pushing.HARD_REACH),
        "yaw_range_rad": pushing.HARD_YAW, "shapes": list(pushing.SHAPES), "cylinder_radius_m": pushing.CYLINDER_RADIUS,
        "cylinder_height_m": pushing.CYLINDER_HEIGHT, "cylinder_mass_kg": pushing.CYLINDER_MASS,
        "goal_past_m": pushing.GOAL_PAST, "goal_tolerance_m": pushing.GOAL_TOLERANCE,
        "max_distractors": pushing.MAX_DISTRACTORS,
    } if benchmark == "hard" else {}
    return {
        **hard,
        "block_size_m": list(pushing.BLOCK_SIZE),
        "block_mass_kg": pushing.BLOCK_MASS,
        "block_table_friction": pushing.BLOCK_TABLE_FRICTION,
        "pen_block_friction": pushing.PEN_BLOCK_FRICTION,
        "block_reach_x_m": pushing.BLOCK_REACH_X,
        "distances_m": list(pushing.DISTANCES),
        "positions": [p.name for p in pushing.POSITIONS],
        "arm": {k: v for k, v in dataclasses.asdict(pushing.ARM).items()},
        "default_tip_m": pushing.DEFAULT_TIP.tolist(),
    }


def collect_set(
    path: str | Path,
    name: str = "motions",
    seed: int = 0,
    per_position: int | None = None,
    camera: str | None | bool = True,
    duration: float | None = None,
    progress: bool = False,
    overwrite: bool = False,
    episodes: int | None = None,
    video: bool = True,
) -> SetReport:
    """Record one dataset of scripted-operator demonstrations into an HDF5 file.

    Args:
        path: the ``.h5`` file to write.
        name: a key of :data:`SETS` (sets the default size, camera and seed stream).
        seed: base seed; the same seed gives the same file.
        per_position: episodes per block position (default: the set's, e.g. 15 for ``motions``).
        camera: ``True`` for the set's camera, ``None``/``False`` for no images, or a camera name.
        duration: recorded length of each episode [s] (default: the benchmark's,
            :data:`seqmotion.lfd.env.pushing.EPISODE_SECONDS`: 4 s chapter, 6 s hard).
        progress: print a progress line to stderr.
        overwrite: replace an existing file (otherwise an existing file is an error).
        episodes: a hard set's number of episodes (default: the set's, 140).
        video: film a hard set with a camera at 50 fps (``/video``, what ACT trains on; about 4 s of
            rendering per episode). ``False`` keeps only each episode's first image, which is all the
            proposed policy and the end-to-end baseline read (about 0.4 s per episode); the episodes
            themselves are the same either way.

    Returns:
        A :class:`SetReport`.
    """
    import h5py

    from ...io import atomic_path, check_writable
    from ..env import pushing
    from ..env.operator import PHASES, OperatorParams, ScriptedOperator
    from ..env.teleop import BilateralGains, teleoperate
    from ..timing import samples_per_command

    if name not in SETS:
        raise ValueError(f"unknown dataset {name!r}; choose one of {sorted(SETS)}")
    spec = SETS[name]
    hard = spec.benchmark == "hard"
    seed = check_number("seed", seed, minimum=0, integer=True)
    if hard:
        if per_position is not None:
            raise ValueError(f"the {name!r} set has no block positions to count per position: pass episodes")
        n = check_number("episodes", spec.episodes if episodes is None else episodes, minimum=1, integer=True)
    else:
        if episodes is not None:
            raise ValueError(f"the {name!r} set counts episodes per block position: pass per_position")
        per_position = spec.per_position if per_position is None else per_position
        per_position = check_number("per_position", per_position, minimum=1, integer=True)
        n = per_position * len(pushing.POSITIONS)
    if camera is True:
        camera = spec.camera
    elif camera is False:
        camera = None
    if camera is not None and camera not in pushing.CAMERAS:
        raise ValueError(f"unknown camera {camera!r}; choose one of {sorted(pushing.CAMERAS)} or None")
    if duration is None:
        duration = pushing.EPISODE_SECONDS[spec.benchmark]
    duration = check_number("duration [s]", duration, minimum=0.5, maximum=60.0)
    path = Path(path)
    if path.exists() and not overwrite:
        raise ValueError(f"{path} already exists (pass overwrite=True to replace it)")
    check_writable(path, (".h5",), "dataset")

    gains = BilateralGains()
    steps = round(duration / gains.dt)
    video_every = samples_per_command(gains.dt) if hard and camera is not None and video else 0
    frames = -(-steps // video_every) if video_every else 0
    scene, master = pushing.PushingScene(benchmark=spec.benchmark), pushing.MasterArm()
    slots = 1 if hard else len(pushing.POSITIONS)
    successes, attempts = np.zeros(slots, dtype=int), np.zeros(slots, dtype=int)
    start = time.perf_counter()
    float_opts = {"dtype": "f4", "compression": "gzip", "compression_opts": 4, "shuffle": True}
    # Written under a temporary name and renamed when complete: a killed collection leaves the old file
    # (or none), never a truncated one.
    writing = atomic_path(path)
    try:
        with writing as tmp, h5py.File(tmp, "w") as f:
            f.attrs.update(
                format=FORMAT, version=VERSION, set_name=name, seed=seed, dt=gains.dt, duration=float(duration),
                n_episodes=n, samples=steps, camera=camera or "", image_size=pushing.IMAGE_SIZE, complete=False,
                motion_columns=json.dumps(list(_motion_columns())), phases=json.dumps(list(PHASES)),
                scene=json.dumps(_scene_description(spec.benchmark)), gains=json.dumps(dataclasses.asdict(gains)),
                benchmark=spec.benchmark,
            )
            for cam_name, cam in pushing.CAMERAS.items():
                g = f.create_group(f"cameras/{cam_name}")
                g.attrs.update(pos=cam.pos, target=cam.target, fovy=cam.fovy)
            motions = f.create_group("motions")
            for key in (*MOTION_KEYS, *EXTRA_KEYS):
                width = _WIDTH.get(key, 3)
                motions.create_dataset(key, shape=(n, steps, width), chunks=(1, steps, width), **float_opts)
            motions.create_dataset("phase", shape=(n, steps), dtype="i1", chunks=(1, steps), compression="gzip")
            images = (
                f.create_dataset("images", shape=(n, 64, 64, 3), dtype="u1", chunks=(1, 64, 64, 3))
                if camera is not None
                else None
            )
            video = (
                f.create_dataset("video", shape=(n, frames, 64, 64, 3), dtype="u1", chunks=(1, frames, 64, 64, 3),
                                 compression="gzip", compression_opts=4)
                if video_every
                else None
            )
            rows: list[dict] = []
            for episode in range(n):
                rng = episode_rng(seed, spec.set_id, episode)
                if hard:
                    position, variation = pushing.sample_hard_placement(rng)
                    params = OperatorParams.sample(rng)
                else:
                    position = pushing.POSITIONS[episode % len(pushing.POSITIONS)]
                    params = OperatorParams.sample(rng)
                    variation = pushing.SceneVariation.sample(rng)
                demo = teleoperate(
                    scene, master, ScriptedOperator(params, rng), position, duration, variation, camera, gains,
                    video_every,
                )
                for key in (*MOTION_KEYS, *EXTRA_KEYS):
                    motions[key][episode] = getattr(demo, key)
                motions["phase"][episode] = demo.phase
                if images is not None:
                    images[episode] = demo.image
                if video is not None:
                    video[episode] = demo.video
                rows.append(
                    {
                        "position_index": position.index, "side": position.side, "distance": position.distance,
                        "reach": position.reach, "shape": position.shape,
                        "seed_key": (seed, spec.set_id, episode), "success": demo.success,
                        "crossed_time": demo.crossed_time, "n_pushes": demo.n_pushes,
                        "block_initial_pose": demo.block_pose[0], "variation": dataclasses.asdict(variation),
                        "operator": params.as_dict(),
                    }
                )
                slot = max(position.index, 0)
                attempts[slot] += 1
                successes[slot] += int(demo.success)
                if progress:
                    elapsed = time.perf_counter() - start
                    print(
                        f"\r[{name}] {episode + 1}/{n} episodes, {successes.sum()} successful, {elapsed:.0f} s",
                        end="" if episode + 1 < n else "\n", file=sys.stderr, flush=True,
                    )
            _write_episode_table(f, rows)
            f.attrs["complete"] = True
    finally:
        scene.close()
    return SetReport(name, path, n, successes, attempts, time.perf_counter() - start)


def _motion_columns() -> tuple[str, ...]:
    from ..env.teleop import MOTION_COLUMNS

    return MOTION_COLUMNS


def _write_episode_table(f, rows: list[dict]) -> None:  # noqa: ANN001 - an open h5py.File
    """Per-episode scalars into /episodes and /operator."""
    ep = f.create_group("episodes")
    ep["position_index"] = np.array([r["position_index"] for r in rows], dtype=np.int8)
    ep["side"] = np.array([r["side"] for r in rows], dtype="S5")
    ep["distance"] = np.array([r["distance"] for r in rows])
    ep["reach"] = np.array([r["reach"] for r in rows])
    ep["shape"] = np.array([r["shape"] for r in rows], dtype="S8")
    ep["seed_key"] = np.array([r["seed_key"] for r in rows], dtype=np.int64)
    ep["success"] = np.array([r["success"] for r in rows], dtype=bool)
    ep["crossed_time"] = np.array([r["crossed_time"] for r in rows])
    ep["n_pushes"] = np.array([r["n_pushes"] for r in rows], dtype=np.int8)
    ep["block_initial_pose"] = np.array([r["block_initial_pose"] for r in rows])
    var = ep.create_group("variation")
    for key in rows[0]["variation"]:
        var[key] = np.array([np.asarray(r["variation"][key], dtype=np.float64) for r in rows])
    op = f.create_group("operator")
    for key in rows[0]["operator"]:
        op[key] = np.array([r["operator"][key] for r in rows])


def collect(
    out_dir: str | Path,
    sets: Iterable[str] = CHAPTER_SETS,
    seed: int = 0,
    duration: float | None = None,
    per_position: dict[str, int] | None = None,
    progress: bool = True,
    overwrite: bool = False,
    episodes: int | None = None,
    video: bool = True,
) -> dict[str, SetReport]:
    """Collect the chapter-5 datasets into ``out_dir/<name>.h5``.

    Args:
        out_dir: output directory (created).
        sets: which of :data:`SETS` to collect (default the chapter's four, :data:`CHAPTER_SETS`: 90
            motions and 3 × 18 pairs).
        seed: base seed of every set.
        duration: recorded length of each episode [s] (default: each set's benchmark's, 4 s or 6 s).
        per_position: optional ``{set name: episodes per position}`` overrides (for quick runs).
        progress: print progress lines to stderr.
        overwrite: replace existing files.
        episodes: episodes of the hard set (default its 140).
        video: film the hard set at 50 fps (see :func:`collect_set`).

    Returns:
        ``{set name: SetReport}`` in collection order.
    """
    sets = list(sets) if not isinstance(sets, str) else [sets]
    if not sets:
        raise ValueError("no dataset named; choose from " + ", ".join(SETS))
    unknown = [s for s in sets if s not in SETS]
    if unknown:
        raise ValueError(f"unknown dataset(s) {unknown}; choose from {sorted(SETS)}")
    per_position = per_position or {}
    bad = [k for k in per_position if k not in sets]
    if bad:
        raise ValueError(f"per_position names sets that are not being collected: {bad}")
    out_dir = Path(out_dir)
    reports = {}
    for name in sets:
        hard = SETS[name].benchmark == "hard"
        reports[name] = collect_set(
            out_dir / f"{name}.h5", name, seed, per_position.get(name), True, duration, progress, overwrite,
            episodes if hard else None, video,
        )
    return reports


# ----------------------------------------------------------------------------------------------
# Reading
# ----------------------------------------------------------------------------------------------
@dataclass
class PushingDataset:
    """A dataset read back into memory (float64 arrays).

    Attributes:
        attrs: the file's root attributes (JSON ones decoded).
        motions: ``{key: (N, K, w)}`` for every ``/motions`` array (``phase`` is int8 ``(N, K)``).
        episodes: ``{key: (N, ...)}`` per-episode values (``side`` as str).
        operator: ``{parameter: (N,)}``.
        images: ``(N, 64, 64, 3)`` uint8 or ``None``.
        video: ``(N, F, 64, 64, 3)`` uint8, the webcam every 20 ms of each episode (hard sets), or ``None``.
    """

    path: Path
    attrs: dict
    motions: dict[str, np.ndarray]
    episodes: dict[str, np.ndarray]
    operator: dict[str, np.ndarray]
    images: np.ndarray | None
    video: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.episodes["success"])

    @property
    def dt(self) -> float:
        return float(self.attrs["dt"])

    def motion(self, every: int | None = None, episodes: Sequence[int] | None = None) -> np.ndarray:
        """``(N, ceil(K / every), 18)``: master θ, θ̇, τ, slave θ, θ̇, τ, every ``every``-th sample.

        The default ``every`` samples at the decoder's Δt_NN
        (:data:`~seqmotion.lfd.timing.COMMAND_INTERVAL`, 20 ms: every 20th sample of a 1 ms
        recording), what the networks train on. Samples are picked, not averaged: θ̇ and τ are
        already low-passed at 10 Hz by the pseudo-derivative and the RTOB.
        """
        if every is None:
            from ..timing import samples_per_command

            every = samples_per_command(self.dt)
        check_number("every", every, minimum=1, integer=True)
        index = slice(None) if episodes is None else np.asarray(episodes)
        parts = [np.asarray(self.motions[k][index, ::every]) for k in MOTION_KEYS]
        for key, values in zip(MOTION_KEYS, parts, strict=True):
            check_motion_values(values, f"{self.path}: {key}", None if episodes is None else np.asarray(episodes))
        return np.concatenate(parts, axis=-1)


MAX_MOTION_VALUE = 1e6
"""The largest magnitude a recorded value may have (angles [rad], velocities [rad/s], torques [N m], positions
[m]), checked before training and on a LeRobot import. A real arm's values are below 1e4; a larger one (1e20,
3e38) is a corrupt or crafted file, and its square overflows float32 into an infinite loss."""


def check_motion_values(values: np.ndarray, where: str, episodes: np.ndarray | None = None) -> None:
    """``ValueError`` naming ``where`` and the first bad entry if ``values`` ``(N, K, ...)`` hold a NaN, an
    infinity or a magnitude above :data:`MAX_MOTION_VALUE`: training on them would write a NaN policy.
    ``episodes`` ``(N,)``: the episode numbers of the rows (default ``0..N-1``), for the message."""
    values = np.asarray(values)
    bad = ~np.isfinite(values) | (np.abs(values) > MAX_MOTION_VALUE)
    if bad.any():
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        episode = first[0] if episodes is None else int(episodes[first[0]])
        raise ValueError(f"{where} holds {float(values[first])!r} at episode {episode}, sample {first[1]} "
                         f"(values must be finite and within ±{MAX_MOTION_VALUE:g}): the data are corrupt")


def load_dataset(path: str | Path) -> PushingDataset:
    """Read a file written by :func:`collect_set`; ``ValueError`` if it is not one or is incomplete."""
    import h5py

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path} does not exist")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(f"{path} is not a readable HDF5 file: {exc}") from None
    try:
        return _read_open_dataset(path, f)
    except (KeyError, TypeError, AttributeError, json.JSONDecodeError) as exc:  # a group or attribute missing
        raise ValueError(f"{path} is not a complete {FORMAT} dataset: {type(exc).__name__}: {exc}") from None
    except OSError as exc:  # h5py reports corrupt chunks as OSError
        raise ValueError(f"{path} is corrupt: {exc}") from None


def _read_open_dataset(path: Path, f: object) -> PushingDataset:  # f: an open h5py.File
    import h5py

    with f:
        if f.attrs.get("format") != FORMAT:
            raise ValueError(f"{path} is not a {FORMAT} dataset (format={f.attrs.get('format')!r})")
        if int(f.attrs.get("version", -1)) != VERSION:
            raise ValueError(f"{path} has format version {f.attrs.get('version')}, this code reads {VERSION}")
        if not bool(f.attrs.get("complete", False)):
            raise ValueError(f"{path} is incomplete (its collection was interrupted)")
        for group in ("motions", "episodes", "episodes/variation", "operator"):
            if group not in f or not isinstance(f[group], h5py.Group):
                raise ValueError(f"{path} has no {group!r} group: not a complete {FORMAT} dataset")
        missing = [k for k in MOTION_KEYS if k not in f["motions"]]
        if missing:
            raise ValueError(f"{path} has no motions {missing}")
        _check_sizes(path, f)
        attrs = {k: _decode_attr(k, v) for k, v in f.attrs.items()}
        motions = {
            k: (f["motions"][k][()].astype(np.float64) if k != "phase" else f["motions"][k][()])
            for k in f["motions"]
        }
        episodes = {k: f["episodes"][k][()] for k in f["episodes"] if isinstance(f["episodes"][k], h5py.Dataset)}
        episodes["side"] = episodes["side"].astype(str)
        if "shape" in episodes:
            episodes["shape"] = episodes["shape"].astype(str)
        episodes["variation"] = {k: v[()] for k, v in f["episodes/variation"].items()}
        operator = {k: v[()] for k, v in f["operator"].items()}
        images = f["images"][()] if "images" in f else None
        video = f["video"][()] if "video" in f else None
    return PushingDataset(path, attrs, motions, episodes, operator, images, video)


def _check_sizes(path: Path, f: object) -> None:  # f: an open h5py.File
    """Refuse, before anything is read, datasets whose declared shapes are too large.

    A file of a few kilobytes can declare a chunked dataset of any shape (HDF5 allocates chunks
    lazily), and reading it allocates all of it: every dataset :func:`_read_open_dataset` reads
    is checked by its ``.shape`` (:func:`~seqmotion.io.trajectories.check_declared_size`: no axis
    over ``MAX_LENGTH``), and together they must fit in ``MAX_FILE_BYTES`` once read.
    """
    import h5py

    from ...io.trajectories import MAX_FILE_BYTES, check_declared_size

    groups = [f[name] for name in ("motions", "episodes", "episodes/variation", "operator")]
    datasets = [item for group in groups for item in group.values() if isinstance(item, h5py.Dataset)]
    datasets += [f[name] for name in ("images", "video") if name in f and isinstance(f[name], h5py.Dataset)]
    total = 0
    for dataset in datasets:
        # floats are read as float64 (motions: astype below); other kinds as they are stored
        itemsize = max(dataset.dtype.itemsize, 8) if dataset.dtype.kind == "f" else dataset.dtype.itemsize
        total += check_declared_size(dataset.shape or (), itemsize, f"{path}: dataset {dataset.name}")
    if total > MAX_FILE_BYTES:
        raise ValueError(f"{path}: its datasets take {total / 2**30:.1f} GiB once read, more than an input may "
                         f"take ({MAX_FILE_BYTES / 2**30:.0f} GiB)")


def save_dataset(data: PushingDataset, path: str | Path, overwrite: bool = False) -> Path:
    """Write a :class:`PushingDataset` held in memory (e.g. one read from a LeRobot dataset by
    :func:`seqmotion.lfd.data.lerobot_import.from_lerobot`) in this module's format, atomically.

    Writes the attributes, every ``/motions`` array it has (float32), the per-episode values (a
    missing ``side`` as ``""``), ``/operator`` and the images; :func:`load_dataset` reads it back.
    """
    import h5py

    from ...io import atomic_path, check_writable

    path = Path(path)
    if path.exists() and not overwrite:
        raise ValueError(f"{path} already exists (pass overwrite=True to replace it)")
    check_writable(path, (".h5",), "dataset")
    n = len(data)
    json_attrs = ("motion_columns", "phases", "scene", "gains")
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        for key, value in data.attrs.items():
            f.attrs[key] = json.dumps(value) if key in json_attrs else value
        f.attrs.update(format=FORMAT, version=VERSION, n_episodes=n, complete=True)
        motions = f.create_group("motions")
        for key, value in data.motions.items():
            dtype = "i1" if key == "phase" else "f4"
            motions.create_dataset(key, data=np.asarray(value).astype(dtype), compression="gzip")
        episodes = f.create_group("episodes")
        for key, value in data.episodes.items():
            if key == "variation":
                continue
            text = {"side": "S5", "shape": "S8"}  # h5py stores bytes, not numpy's unicode
            episodes[key] = np.asarray(value, dtype=text[key]) if key in text else np.asarray(value)
        if "side" not in data.episodes:
            episodes["side"] = np.full(n, b"", dtype="S5")
        variation = episodes.create_group("variation")
        for key, value in data.episodes.get("variation", {}).items():
            variation[key] = np.asarray(value)
        operator = f.create_group("operator")
        for key, value in data.operator.items():
            operator[key] = np.asarray(value)
        if data.images is not None:
            f.create_dataset("images", data=np.asarray(data.images, dtype=np.uint8))
        if data.video is not None:
            f.create_dataset("video", data=np.asarray(data.video, dtype=np.uint8), compression="gzip")
    return path


def _decode_attr(key: str, value: object) -> object:
    if key in ("motion_columns", "phases", "scene", "gains"):
        return json.loads(value)
    if isinstance(value, np.generic):
        return value.item()
    return value
