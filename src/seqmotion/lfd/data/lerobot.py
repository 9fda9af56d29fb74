"""LeRobotDataset v3.0: the format (layout, features, frame rate) and the export of the pushing demonstrations.

No ``lerobot`` import needed. :func:`to_lerobot` turns every set of a dataset directory written by
``seqmotion lfd collect`` (``<set>.h5``) into one LeRobot v3.0 dataset folder ``OUT/<set>/``;
:func:`~seqmotion.lfd.data.lerobot_import.from_lerobot` reads a LeRobot v3.0 folder back into a
:class:`~seqmotion.lfd.data.dataset.PushingDataset` (in memory;
:func:`~seqmotion.lfd.data.lerobot_import.import_lerobot` writes it as ``<set>.h5``), so that
``seqmotion lfd train --data`` takes either. Writers and readers are pyarrow (parquet) and PyAV (mp4), the
``lerobot`` extra.

On disk (LeRobot's v3.0 layout, one file of each kind: the sets are small)::

    meta/info.json                 codebase_version "v3.0", fps, features, totals, path templates
    meta/stats.json                per feature: min, max, mean, std, count, q01 q10 q50 q90 q99
    meta/tasks.parquet             task_index, task (the pandas index)
    meta/episodes/chunk-000/file-000.parquet
                                   per episode: episode_index, tasks, length, data/chunk_index,
                                   data/file_index, dataset_from_index, dataset_to_index,
                                   videos/<key>/chunk_index|file_index|from_timestamp|to_timestamp,
                                   meta/episodes/chunk_index|file_index, stats/<feature>/<stat>,
                                   seqmotion/position_index, seqmotion/success
    data/chunk-000/file-000.parquet one row per frame, one row group per episode
    videos/observation.images.webcam/chunk-000/file-000.mp4   (``videos=True`` only)

Features (J joints: the arm's 3 named ``yaw``, ``shoulder``, ``elbow``, another count ``joint0``,
``joint1``, ...; float32):

* ``observation.state`` ``(2J,)``: the slave's joint angles [rad] then velocities [rad/s]
  (``yaw.pos`` ... ``elbow.vel``).
* ``observation.effort`` ``(J,)``: the slave's reaction torques τ_s [N m] (``yaw.effort`` ...);
  the decoder reads them with θ and θ̇.
* ``action`` ``(3J,)``: **the master's θ, θ̇, τ** (``.pos``, ``.vel``, ``.effort``). This is
  what the chapter-5 controller takes from the policy: the decoder stands in for the master
  (Fig. 5.7) and the slave's half of the 4-channel bilateral law is driven by the master's
  angle, velocity and torque (:func:`seqmotion.lfd.rollout.run_autonomous`). ``action[t]`` is
  the master at the same frame, LeRobot's teleoperation convention (the leader arm at t), i.e.
  the command the slave's controller received at t. seqmotion's decoder, trained on these
  frames, predicts one frame ahead (it reads ``state[t]`` and emits ``action[t+1]``, which the
  controller then holds for a frame); a LeRobot policy (ACT, Diffusion Policy) learns
  ``action[t]`` from ``observation[t]`` and its output goes into the same slot.
* ``observation.environment_state`` ``(7,)``: the block's centre [m] and quaternion (w, x, y, z).
* ``observation.images.webcam`` ``(64, 64, 3)``: the chapter's sets take one webcam image per
  episode, just before the motion; it is stored on every frame of the episode (LeRobot wants one
  per frame; the scene in front of the camera is what the policy sees when it starts). The hard
  set films every episode at 50 fps (``/video``): each frame then holds what the camera saw at
  that frame, as a policy that watches the scene (ACT, Diffusion Policy) trains on. ``image``
  dtype (PNG in the parquet) by default, an mp4 (AV1 or H.264) with ``videos=True``. The
  import takes each episode's first frame.
* ``timestamp``, ``frame_index``, ``episode_index``, ``index``, ``task_index`` as LeRobot has them;
  one task string, :data:`TASK`.

Frame rate: :data:`DEFAULT_FPS` = 50 Hz, every 20th sample of the 1 kHz recording, the decoder's
period Δt_NN (what the policy trains on and what LeRobot users record at, 10-50 Hz); ``fps``
may be any divisor of the recording's rate (1000 for the full recording). Export then import is
exact (float32) at the exported rate.

The import, which reads such a folder as untrusted input, is :mod:`seqmotion.lfd.data.lerobot_import`; this module
holds what both sides share (file paths, feature keys, :data:`IMAGE_SHAPE`, the pyarrow and PyAV imports).
"""

from __future__ import annotations

import io
import json
import re
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import check_number
from .dataset import MOTION_KEYS, SETS, PushingDataset

CODEBASE_VERSION = "v3.0"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
CHUNKS_SIZE = 1000
"""LeRobot's defaults for files per chunk folder and file sizes [MB], recorded in ``info.json``."""

STATE, EFFORT, ACTION, ENVIRONMENT, WEBCAM = (
    "observation.state", "observation.effort", "action", "observation.environment_state", "observation.images.webcam"
)
TASK = "Push the block across the robot's centre line."
DEFAULT_FPS = 50
DEFAULT_REPO_ID = "seqmotion/pushing"
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
"""The quantiles LeRobot's stats carry (``q01`` ... ``q99``)."""
CODECS = {"av1": "libsvtav1", "h264": "libx264"}
"""``videos=True`` encoders (LeRobot's default is AV1 via SVT-AV1), GOP 2 and CRF 30 as LeRobot's."""
BLOCK_NAMES = ("x", "y", "z", "qw", "qx", "qy", "qz")
IMAGE_SHAPE = (64, 64, 3)


def _pyarrow() -> Any:
    try:
        import pyarrow
        import pyarrow.parquet  # noqa: F401 - the submodule is used as pyarrow.parquet
    except ImportError:
        raise ValueError("LeRobot datasets need pyarrow: pip install 'seqmotion[lerobot]'") from None
    return pyarrow


def _av() -> Any:
    try:
        import av
    except ImportError:
        raise ValueError("LeRobot videos need PyAV: pip install 'seqmotion[lerobot]'") from None
    return av


# ----------------------------------------------------------------------------------------------
# Export
# ----------------------------------------------------------------------------------------------
def to_lerobot(
    data_dir: str | Path,
    out: str | Path,
    repo_id: str = DEFAULT_REPO_ID,
    videos: bool = False,
    fps: int = DEFAULT_FPS,
    codec: str = "av1",
) -> dict[str, Path]:
    """Export every ``<set>.h5`` of ``data_dir`` as a LeRobot v3.0 dataset ``out/<set>/``.

    Args:
        data_dir: a directory written by ``seqmotion lfd collect`` (or one ``.h5`` file).
        out: output directory; each ``out/<set>`` must not exist yet (or be empty).
        repo_id: the Hub name the dataset card suggests (``<repo_id>_<set>``); nothing is uploaded.
        videos: store the webcam as an mp4 per dataset instead of PNGs in the parquet.
        fps: frame rate [Hz]; must divide the recording's rate (1 kHz).
        codec: ``"av1"`` (LeRobot's default) or ``"h264"`` (with ``videos``).

    Returns:
        ``{set name: dataset folder}``. Each folder is written whole or not at all.
    """
    from ...io import check_writable_dir
    from .dataset import load_dataset

    data_dir, out = Path(data_dir), Path(out)
    if not re.fullmatch(r"[A-Za-z0-9][\w.-]*/[\w.-]+", str(repo_id)):
        raise ValueError(f"repo id must look like 'owner/name', got {repo_id!r}")
    if codec not in CODECS:
        raise ValueError(f"codec must be one of {sorted(CODECS)}, got {codec!r}")
    if data_dir.is_file():
        files = [data_dir]
    elif data_dir.is_dir():
        files = [data_dir / f"{name}.h5" for name in SETS if (data_dir / f"{name}.h5").is_file()]
        if not files:
            raise ValueError(f"{data_dir} holds no dataset ({', '.join(f'{n}.h5' for n in SETS)}): "
                             f"run 'seqmotion lfd collect --out {data_dir}' first")
    else:
        raise ValueError(f"{data_dir} does not exist")
    targets = {f: out / f.stem for f in files}
    for target in targets.values():  # refused before any work: nothing is replaced
        if target.exists() and (not target.is_dir() or any(target.iterdir())):
            raise ValueError(f"{target} already exists: remove it or export into another folder")
    check_writable_dir(out, "LeRobot output directory")
    written = {}
    for path, target in targets.items():
        data = load_dataset(path)
        written[path.stem] = export_set(data, target, f"{repo_id}_{path.stem}", videos, fps, codec)
    return written


def export_set(
    data: PushingDataset, target: str | Path, repo_id: str = DEFAULT_REPO_ID, videos: bool = False,
    fps: int = DEFAULT_FPS, codec: str = "av1",
) -> Path:
    """Write one :class:`PushingDataset` as the LeRobot v3.0 folder ``target`` (atomically: a temporary sibling
    renamed when complete); see the module docstring for the layout."""
    from ...io import atomic_path

    frames = _frames(data, fps)
    has_images = data.images is not None
    features = _features(frames["joints"], ENVIRONMENT in frames, has_images, videos)
    with atomic_path(Path(target), directory=True) as tmp:
        _write_data(tmp, frames, data.images if has_images and not videos else None, features)
        video_rows = _write_video(tmp, frames, data.images, fps, codec) if has_images and videos else None
        if video_rows is not None:
            features[WEBCAM]["info"] = _video_info(tmp / VIDEO_PATH.format(video_key=WEBCAM, chunk_index=0,
                                                                             file_index=0))
        stats = _write_episodes(tmp, frames, data, features, video_rows)
        _write_tasks(tmp)
        _write_json(tmp / STATS_PATH, stats)
        _write_json(tmp / INFO_PATH, _info(frames, features, fps, videos))
        (tmp / "README.md").write_text(_card(repo_id, data, fps, videos))
    return Path(target)


def _frames(data: PushingDataset, fps: int) -> dict[str, Any]:
    """The per-frame columns ``{name: (total_frames, ...)}`` at ``fps``, plus ``lengths`` per episode."""
    check_number("fps", fps, minimum=1, integer=True)
    rate = 1.0 / data.dt
    every = round(rate / fps)
    if every < 1 or abs(every * fps - rate) > 1e-6 * rate:
        raise ValueError(f"fps must divide the recording's rate of {rate:g} Hz (e.g. 50: every 20th sample), "
                         f"got {fps}")
    m = {k: np.asarray(data.motions[k][:, ::every], dtype=np.float32) for k in (*MOTION_KEYS, "block_pose")
         if k in data.motions}  # block_pose: absent from an imported dataset that had none
    n, length, joints = m["slave_theta"].shape

    def flat(*parts: np.ndarray) -> np.ndarray:
        return np.concatenate(parts, axis=-1).reshape(n * length, -1)

    webcam = {}
    if data.video is not None:  # filmed episodes: each frame's own image
        filmed_every = round(data.motions["slave_theta"].shape[1] / data.video.shape[1])
        if every % filmed_every or data.video[:, :: every // filmed_every].shape[1] != length:
            raise ValueError(f"the episodes are filmed at {rate / filmed_every:g} fps; export them at a rate that "
                             f"divides it, got {fps}")
        webcam = {"webcam": data.video[:, :: every // filmed_every].reshape(n * length, *IMAGE_SHAPE)}

    episode = np.repeat(np.arange(n, dtype=np.int64), length)
    frame = np.tile(np.arange(length, dtype=np.int64), n)
    return {
        STATE: flat(m["slave_theta"], m["slave_dtheta"]),
        EFFORT: flat(m["slave_tau"]),
        ACTION: flat(m["master_theta"], m["master_dtheta"], m["master_tau"]),
        **({ENVIRONMENT: flat(m["block_pose"])} if "block_pose" in m else {}),
        "timestamp": (frame / fps).astype(np.float32),
        "frame_index": frame,
        "episode_index": episode,
        "index": np.arange(n * length, dtype=np.int64),
        "task_index": np.zeros(n * length, dtype=np.int64),
        "lengths": np.full(n, length, dtype=np.int64),
        "joints": joints,
        **webcam,
    }


def _joint_names(joints: int) -> list[str]:
    from ..env.pushing import JOINT_NAMES

    return list(JOINT_NAMES) if joints == len(JOINT_NAMES) else [f"joint{j}" for j in range(joints)]


def _features(joints: int, block_pose: bool, images: bool, videos: bool) -> dict[str, dict]:
    names = _joint_names(joints)

    def named(*quantities: str) -> list[str]:
        return [f"{joint}.{q}" for q in quantities for joint in names]

    features: dict[str, dict] = {
        STATE: {"dtype": "float32", "shape": [2 * joints], "names": named("pos", "vel")},
        EFFORT: {"dtype": "float32", "shape": [joints], "names": named("effort")},
        ACTION: {"dtype": "float32", "shape": [3 * joints], "names": named("pos", "vel", "effort")},
    }
    if block_pose:
        features[ENVIRONMENT] = {"dtype": "float32", "shape": [7], "names": list(BLOCK_NAMES)}
    if images:
        features[WEBCAM] = {"dtype": "video" if videos else "image", "shape": list(IMAGE_SHAPE),
                            "names": ["height", "width", "channels"]}
    for key, dtype in (("timestamp", "float32"), ("frame_index", "int64"), ("episode_index", "int64"),
                       ("index", "int64"), ("task_index", "int64")):
        features[key] = {"dtype": dtype, "shape": [1], "names": None}
    return features


def _png(image: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8)).save(buffer, format="PNG")
    return buffer.getvalue()


def _write_data(root: Path, frames: dict, images: np.ndarray | None, features: dict) -> None:
    """``data/chunk-000/file-000.parquet``: one row per frame, one row group per episode."""
    pa = _pyarrow()
    columns: dict[str, Any] = {}
    for key, feature in features.items():
        if feature["dtype"] == "video":
            continue
        if feature["dtype"] == "image":
            image_type = pa.struct([("bytes", pa.binary()), ("path", pa.string())])
            if "webcam" in frames:  # a filmed episode: a PNG per frame
                rows = [{"bytes": _png(image), "path": None} for image in frames["webcam"]]
            else:  # one PNG per episode, referenced by each of its frames
                png = [_png(image) for image in images]
                rows = [{"bytes": png[e], "path": None} for e in frames["episode_index"]]
            columns[key] = pa.array(rows, type=image_type)
        elif feature["shape"] == [1]:
            columns[key] = pa.array(frames[key])
        else:  # a fixed-size list, as the Hugging Face `datasets` library stores a sequence of known length
            values = frames[key]
            columns[key] = pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1)), values.shape[1])
    table = pa.table(columns)
    path = root / DATA_PATH.format(chunk_index=0, file_index=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    with pa.parquet.ParquetWriter(path, table.schema, compression="snappy") as writer:
        start = 0
        for length in frames["lengths"]:
            writer.write_table(table.slice(start, int(length)))
            start += int(length)


def _write_video(root: Path, frames: dict, images: np.ndarray, fps: int, codec: str) -> list[dict]:
    """One mp4 of all episodes back to back (each frame's image if filmed, else the episode's image on each
    of its frames); its per-episode rows for the episodes table (``videos/<key>/...``)."""
    av = _av()
    path = root / VIDEO_PATH.format(video_key=WEBCAM, chunk_index=0, file_index=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    rows, pts = [], 0
    with av.open(str(path), "w") as container:
        stream = container.add_stream(CODECS[codec], rate=fps)
        stream.width, stream.height = IMAGE_SHAPE[1], IMAGE_SHAPE[0]
        stream.pix_fmt = "yuv420p"
        stream.time_base = Fraction(1, fps)
        stream.options = {"g": "2", "crf": "30"}
        for e, length in enumerate(frames["lengths"]):
            rows.append({"chunk_index": 0, "file_index": 0, "from_timestamp": pts / fps,
                         "to_timestamp": (pts + int(length)) / fps})
            for _ in range(int(length)):
                image = frames["webcam"][pts] if "webcam" in frames else images[e]
                frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image, dtype=np.uint8), format="rgb24")
                frame.pts, frame.time_base = pts, Fraction(1, fps)
                container.mux(stream.encode(frame))
                pts += 1
        container.mux(stream.encode())
    return rows


def _video_info(path: Path) -> dict[str, Any]:
    """The ``info`` of a video feature as LeRobot records it (probed from the file)."""
    av = _av()
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        return {"video.height": stream.height, "video.width": stream.width,
                "video.codec": stream.codec.canonical_name, "video.pix_fmt": stream.pix_fmt,
                "video.fps": int(stream.base_rate), "video.channels": 3, "video.g": 2, "video.crf": 30,
                "is_depth_map": False, "has_audio": False}


def _stats(values: np.ndarray, image: bool = False) -> dict[str, np.ndarray]:
    """LeRobot's per-feature statistics of ``values`` ``(frames, ...)``: per column, or per colour channel
    ``(3, 1, 1)`` in [0, 1] for images ``(frames, H, W, 3)``."""
    if image:
        x = values.reshape(-1, 3).astype(np.float64) / 255.0
        shape: tuple[int, ...] = (3, 1, 1)
    else:
        x = values.reshape(len(values), -1).astype(np.float64)
        shape = (x.shape[1],)
    stats = {"min": x.min(0), "max": x.max(0), "mean": x.mean(0), "std": x.std(0)}
    for q in QUANTILES:
        stats[f"q{round(q * 100):02d}"] = np.quantile(x, q, axis=0)
    stats = {k: v.reshape(shape) for k, v in stats.items()}
    stats["count"] = np.array([len(values)], dtype=np.int64)
    return stats


def _all_stats(frames: dict, images: np.ndarray | None, features: dict, rows: slice,
               episodes: slice) -> dict[str, dict[str, np.ndarray]]:
    out = {}
    for key, feature in features.items():
        if feature["dtype"] in ("image", "video") and "webcam" in frames:
            out[key] = _stats(frames["webcam"][rows], image=True)
        elif feature["dtype"] in ("image", "video"):
            # every frame of an episode shows its one image and the episodes are equally long, so the
            # statistics of the per-episode images are those of the frames
            out[key] = _stats(images[episodes], image=True)
            out[key]["count"] = np.array([rows.stop - rows.start], dtype=np.int64)
        else:
            out[key] = _stats(frames[key][rows])
    return out


def _write_episodes(root: Path, frames: dict, data: PushingDataset, features: dict,
                    video_rows: list[dict] | None) -> dict:
    """``meta/episodes/chunk-000/file-000.parquet``; returns the whole dataset's stats."""
    pa = _pyarrow()
    rows, start = [], 0
    for e, length in enumerate(frames["lengths"]):
        stop = start + int(length)
        row: dict[str, Any] = {
            "episode_index": e, "tasks": [TASK], "length": int(length),
            "data/chunk_index": 0, "data/file_index": 0, "dataset_from_index": start, "dataset_to_index": stop,
        }
        if video_rows is not None:
            row.update({f"videos/{WEBCAM}/{k}": v for k, v in video_rows[e].items()})
        row.update({"meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0})
        for key, stats in _all_stats(frames, data.images, features, slice(start, stop), slice(e, e + 1)).items():
            row.update({f"stats/{key}/{name}": value.tolist() for name, value in stats.items()})
        # seqmotion's own per-episode facts (LeRobot ignores extra columns): what the CNN targets need
        row["seqmotion/position_index"] = int(data.episodes["position_index"][e])
        row["seqmotion/success"] = bool(data.episodes["success"][e])
        rows.append(row)
        start = stop
    path = root / EPISODES_PATH.format(chunk_index=0, file_index=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    pa.parquet.write_table(pa.Table.from_pylist(rows), path)
    total = _all_stats(frames, data.images, features, slice(0, len(frames["index"])), slice(None))
    return {key: {name: value.tolist() for name, value in stats.items()} for key, stats in total.items()}


def _write_tasks(root: Path) -> None:
    """``meta/tasks.parquet``: ``task_index`` with the task string as the pandas index (how LeRobot reads it)."""
    pa = _pyarrow()
    table = pa.table({"task_index": pa.array([0], pa.int64()), "task": pa.array([TASK], pa.string())})
    pandas_meta = {
        "index_columns": ["task"],
        "column_indexes": [{"name": None, "field_name": None, "pandas_type": "unicode", "numpy_type": "object",
                            "metadata": {"encoding": "UTF-8"}}],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64",
             "metadata": None},
            {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object", "metadata": None},
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.3",
    }
    table = table.replace_schema_metadata({"pandas": json.dumps(pandas_meta)})
    pa.parquet.write_table(table, root / TASKS_PATH)


def _info(frames: dict, features: dict, fps: int, videos: bool) -> dict[str, Any]:
    n = len(frames["lengths"])
    return {
        "codebase_version": CODEBASE_VERSION, "robot_type": _robot_type(frames["joints"]), "fps": int(fps),
        "total_episodes": n, "total_frames": int(frames["lengths"].sum()), "total_tasks": 1,
        "chunks_size": CHUNKS_SIZE, "data_files_size_in_mb": 100, "video_files_size_in_mb": 200,
        "data_path": DATA_PATH, "video_path": VIDEO_PATH if videos and WEBCAM in features else None,
        "splits": {"train": f"0:{n}"}, "features": features,
    }


def _robot_type(joints: int) -> str:
    """``info.json``'s ``robot_type``: seqmotion's 3-joint Touch-like arm, or a J-joint robot's motions that
    were imported (from another robot's dataset) and are exported again."""
    return "seqmotion_touch_3dof" if joints == 3 else f"seqmotion_{joints}dof"


def _write_json(path: Path, data: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2) + "\n")


def _card(repo_id: str, data: PushingDataset, fps: int, videos: bool) -> str:
    camera = data.attrs.get("camera") or "none"
    return (
        "---\nlicense: mit\ntask_categories:\n- robotics\ntags:\n- LeRobot\n- seqmotion\n"
        "configs:\n- config_name: default\n  data_files: data/*/*.parquet\n---\n\n"
        f"# {repo_id}\n\nPushing demonstrations of seqmotion (set `{data.attrs.get('set_name', '?')}`, "
        f"{len(data)} episodes, webcam `{camera}`, {'mp4' if videos else 'PNG'} images) at {fps} Hz, exported "
        "by `seqmotion lfd export-lerobot`. `action` is the master arm's joint angle, velocity and torque "
        "(the bilateral controller's command to the slave); `observation.state` the slave's angles and "
        "velocities, `observation.effort` its torques.\n"
    )
