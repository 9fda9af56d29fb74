"""Hostile LeRobot v3.0 folders for ``seqmotion.lfd.data.lerobot_import``: each refused by name, nothing read
outside the folder, nothing hangs or blows up memory, nothing written.

One tiny synthetic set (3 episodes of 10 frames at 50 fps, no simulation) is exported once as PNGs and as
H.264; every test copies it and edits one thing.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import struct
import subprocess
import types
import zlib
from collections.abc import Callable, Iterator
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
av = pytest.importorskip("av")
import pyarrow.parquet as pq  # noqa: E402

from seqmotion.cli import main  # noqa: E402
from seqmotion.lfd.data import lerobot, lerobot_import  # noqa: E402
from seqmotion.lfd.data.dataset import MOTION_KEYS, PushingDataset  # noqa: E402

DATA = "data/chunk-000/file-000.parquet"
EPISODES = "meta/episodes/chunk-000/file-000.parquet"
VIDEO = "videos/observation.images.webcam/chunk-000/file-000.mp4"
N, FRAMES = 3, 10


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """``{"images": folder, "videos": folder}``: the same 3 episodes, webcam as PNGs / as an H.264 mp4."""
    rng = np.random.default_rng(0)
    samples = FRAMES * 20  # 1 kHz recording, exported every 20th sample (50 fps)
    motions = {key: rng.normal(size=(N, samples, 3)) for key in MOTION_KEYS}
    motions["block_pose"] = rng.normal(size=(N, samples, 7))
    episodes = {"position_index": np.arange(N, dtype=np.int8), "success": np.array([True, False, True])}
    ramp = np.linspace(0, 200, 64)  # smooth images: H.264 keeps them close to the PNGs
    images = np.stack([np.stack([ramp[:, None] + 0 * ramp, ramp[None] + 0 * ramp[:, None], np.full((64, 64), 40 * e)],
                                -1) for e in range(N)]).astype(np.uint8)
    attrs = {"dt": 0.001, "set_name": "pairs_default", "camera": "default"}
    data = PushingDataset(Path("synthetic"), attrs, motions, episodes, {}, images)
    root = tmp_path_factory.mktemp("hostile_lerobot")
    return {"images": lerobot.export_set(data, root / "images"),
            "videos": lerobot.export_set(data, root / "videos", videos=True, codec="h264")}


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, symlinks=True)
    return dst


def _edit_info(root: Path, edit: Callable[[dict], None]) -> None:
    info = json.loads((root / lerobot.INFO_PATH).read_text())
    edit(info)
    (root / lerobot.INFO_PATH).write_text(json.dumps(info))


def _edit_episodes(root: Path, **columns: list) -> None:
    rows = pq.read_table(root / EPISODES).to_pylist()
    for name, values in columns.items():
        for row, value in zip(rows, values, strict=True):
            row[name] = value
    pq.write_table(pa.Table.from_pylist(rows), root / EPISODES)


def _set_column(root: Path, name: str, array: pa.Array, compression: str = "snappy") -> None:
    table = pq.read_table(root / DATA)
    pq.write_table(table.set_column(table.column_names.index(name), name, array), root / DATA,
                   compression=compression)


def _cli(capsys: pytest.CaptureFixture, *argv: str) -> tuple[int, str]:
    capsys.readouterr()
    rc = main(list(argv))
    return rc, capsys.readouterr().err


def _import_refused(capsys: pytest.CaptureFixture, root: Path, out: Path, *words: str) -> str:
    """``seqmotion lfd import-lerobot root out``: exit 2, one line naming ``words``, nothing written."""
    rc, err = _cli(capsys, "lfd", "import-lerobot", str(root), str(out))
    assert rc == 2 and err.count("\n") == 1 and err.startswith("seqmotion lfd: error: "), err
    for word in words:
        assert word in err, err
    assert not out.exists() or not any(out.iterdir())
    return err


def _mp4(path: Path, frames: int, size: tuple[int, int] = (64, 64), container: str = "mp4", fps: int = 50,
         options: dict[str, str] | None = None) -> None:
    """An H.264 video of ``frames`` grey frames ``size`` (width, height) at ``fps``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w", format=container, options=options or {}) as out:
        stream = out.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt = size[0], size[1], "yuv420p"
        stream.time_base = Fraction(1, fps)
        image = np.full((size[1], size[0], 3), 128, dtype=np.uint8)
        for i in range(frames):
            frame = av.VideoFrame.from_ndarray(image, format="rgb24")
            frame.pts, frame.time_base = i, Fraction(1, fps)
            out.mux(stream.encode(frame))
        out.mux(stream.encode())


@contextlib.contextmanager
def _no_parquet_reads(path: Path) -> Iterator[None]:
    """Fail if ``path``'s pages are read (by ``read_table`` or a ``ParquetFile``'s readers): only its footer may be."""
    def same(source: object) -> bool:
        return isinstance(source, str | os.PathLike) and Path(source).resolve() == path.resolve()

    real_table, real_init = pq.read_table, pq.ParquetFile.__init__

    def read_table(source, *args, **kwargs):  # noqa: ANN001, ANN202 - read_table's signature
        assert not same(source), f"{path} was read before its footer was checked"
        return real_table(source, *args, **kwargs)

    def init(self, source, *args, **kwargs):  # noqa: ANN001, ANN202
        real_init(self, source, *args, **kwargs)
        self._test_source = source

    def guarded(name: str) -> Callable:
        real = getattr(pq.ParquetFile, name)

        def method(self, *args, **kwargs):  # noqa: ANN001, ANN202
            assert not same(getattr(self, "_test_source", None)), f"{path} was read ({name}) before its footer"
            return real(self, *args, **kwargs)

        return method

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pq, "read_table", read_table)
        mp.setattr(pq.ParquetFile, "__init__", init)
        for name in ("read", "read_row_group", "read_row_groups", "iter_batches"):
            mp.setattr(pq.ParquetFile, name, guarded(name))
        yield


# ------------------------------------------------------------------------------------------------
# Paths: nothing outside the dataset folder is read
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("template", ["../elsewhere/private.mp4", "ABSOLUTE", "/proc/self/environ",
                                      "videos/{video_key}/../../../elsewhere/private.mp4"])
def test_video_path_outside_the_dataset_is_refused(base, tmp_path, capsys, template):
    """A video_path that leads out of the folder (``..``, absolute, /proc) is refused, not decoded."""
    private = tmp_path / "elsewhere" / "private.mp4"
    private.parent.mkdir()
    shutil.copy(base["videos"] / VIDEO, private)
    root = _copy(base["videos"], tmp_path / "d")
    template = str(private) if template == "ABSOLUTE" else template
    _edit_info(root, lambda info: info.update(video_path=template))
    _import_refused(capsys, root, tmp_path / "out", "video_path", "meta/info.json")


def test_symlinks_leading_out_of_the_dataset_are_refused(base, tmp_path, capsys):
    """A video, data or episodes file that is a symlink to a file outside the folder is not opened."""
    for rel in (VIDEO, DATA, EPISODES):
        outside = tmp_path / "outside" / rel
        outside.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(base["videos"] / rel, outside)
        root = _copy(base["videos"], tmp_path / f"d{len(rel)}")
        (root / rel).unlink()
        (root / rel).symlink_to(outside)
        _import_refused(capsys, root, tmp_path / "out", "outside the dataset", Path(rel).name)


def test_data_path_template_is_checked(base, tmp_path, capsys):
    root = _copy(base["images"], tmp_path / "d")
    _edit_info(root, lambda info: info.update(data_path="../x/{chunk_index}.parquet"))
    _import_refused(capsys, root, tmp_path / "out", "data_path", "meta/info.json")


def test_hub_cache_snapshot_symlinks_are_read(base, tmp_path):
    """A Hugging Face hub cache snapshot (every file a symlink to ../../blobs/<hash>) imports as the folder does."""
    repo = tmp_path / "datasets--me--push"
    snapshot = repo / "snapshots" / "0123abc"
    (repo / "blobs").mkdir(parents=True)
    for path in sorted(p for p in base["videos"].rglob("*") if p.is_file()):
        rel = path.relative_to(base["videos"])
        blob = repo / "blobs" / f"blob{len(list((repo / 'blobs').iterdir()))}"
        shutil.copy(path, blob)
        (snapshot / rel).parent.mkdir(parents=True, exist_ok=True)
        (snapshot / rel).symlink_to(Path(*[".."] * (len(rel.parts) + 1), "blobs", blob.name))
    back = lerobot_import.from_lerobot(snapshot, name="pairs_default")
    np.testing.assert_array_equal(back.motion(), lerobot_import.from_lerobot(base["videos"]).motion())


# ------------------------------------------------------------------------------------------------
# Parquet decompression bombs: refused from the footer, before the pages are read
# ------------------------------------------------------------------------------------------------
def test_list_column_bomb_is_refused_from_the_metadata(base, tmp_path, capsys):
    """``action`` a list of 200,000 zeros per row (zstd: a few KB) is refused by its value count, unread."""
    root = _copy(base["images"], tmp_path / "d")
    rows = N * FRAMES
    bomb = pa.ListArray.from_arrays(pa.array(np.arange(rows + 1) * 200_000, pa.int32()),
                                    pa.array(np.zeros(rows * 200_000, np.float32)))
    _set_column(root, "action", bomb, compression="zstd")
    assert (root / DATA).stat().st_size < 200_000
    with _no_parquet_reads(root / DATA):
        _import_refused(capsys, root, tmp_path / "out", DATA, "'action'", f"{rows * 200_000} values")


def test_episodes_tasks_bomb_is_refused(base, tmp_path, capsys):
    """One episode with 200,000 task strings: refused by the footer's value count."""
    root = _copy(base["images"], tmp_path / "d")
    _edit_episodes(root, tasks=[["x"] * 200_000, ["x"], ["x"]])
    with _no_parquet_reads(root / EPISODES):
        _import_refused(capsys, root, tmp_path / "out", EPISODES, "'tasks'")


def test_uncompressed_size_is_capped(base, tmp_path, monkeypatch):
    root = _copy(base["images"], tmp_path / "d")
    monkeypatch.setattr(lerobot_import, "MAX_PARQUET_BYTES", 1000)
    with pytest.raises(ValueError, match=r"file-000.parquet.*uncompressed"):
        lerobot_import.from_lerobot(root)


# ------------------------------------------------------------------------------------------------
# Videos: bounded before and while decoding
# ------------------------------------------------------------------------------------------------
def test_video_from_timestamp_beyond_the_data_is_refused(base, tmp_path, capsys):
    root = _copy(base["videos"], tmp_path / "d")
    key = "videos/observation.images.webcam"
    _edit_episodes(root, **{f"{key}/from_timestamp": [1e5] * N, f"{key}/to_timestamp": [1e5 + 0.2] * N})
    _import_refused(capsys, root, tmp_path / "out", "from_timestamp", "meta/episodes")


def test_video_with_more_frames_than_its_episodes_is_refused(base, tmp_path, capsys):
    root = _copy(base["videos"], tmp_path / "d")
    _mp4(root / VIDEO, 400)
    _import_refused(capsys, root, tmp_path / "out", VIDEO, "400 frames")


def test_video_dimensions_are_checked(base, tmp_path, capsys):
    root = _copy(base["videos"], tmp_path / "d")
    _mp4(root / VIDEO, 1, size=(1920, 1088))
    _import_refused(capsys, root, tmp_path / "out", VIDEO, "1920 x 1088")


class _CountingContainer:
    """An input container that counts the packets demuxed and the frames decoded through it."""

    def __init__(self, container: object, counted: list[int]) -> None:
        self._container, self._counted = container, counted

    def __enter__(self) -> _CountingContainer:
        return self

    def __exit__(self, *exc: object) -> None:
        self._container.close()

    def __getattr__(self, name: str) -> object:
        return getattr(self._container, name)

    def demux(self, *args: object, **kwargs: object) -> Iterator[object]:
        for packet in self._container.demux(*args, **kwargs):
            self._counted.append(1)
            yield packet

    def decode(self, *args: object, **kwargs: object) -> Iterator[object]:
        for frame in self._container.decode(*args, **kwargs):
            self._counted.append(1)
            yield frame


def test_video_decoding_is_bounded(base, tmp_path, monkeypatch):
    """3,000 frames that never reach the episodes' starts (stamped at 50 kHz), in a fragmented mp4 that does
    not say how many it holds: the decoder stops after the frames the episodes need plus a margin."""
    root = _copy(base["videos"], tmp_path / "d")
    _mp4(root / VIDEO, 3000, fps=50_000, options={"movflags": "frag_keyframe+empty_moov"})
    counted: list[int] = []
    fake = types.SimpleNamespace(**{name: getattr(av, name) for name in dir(av) if not name.startswith("__")})
    fake.open = lambda *args, **kwargs: _CountingContainer(av.open(*args, **kwargs), counted)
    monkeypatch.setattr(lerobot_import, "_av", lambda: fake)
    with pytest.raises(ValueError, match=r"no video frame at the start of episodes \[1, 2\]"):
        lerobot_import.from_lerobot(root)
    assert 0 < len(counted) < 200, len(counted)


# ------------------------------------------------------------------------------------------------
# Features without names are not copied into several fields
# ------------------------------------------------------------------------------------------------
def test_features_without_names_are_not_duplicated(base, tmp_path, capsys):
    """Three features 3 wide with ``names: null`` (another robot's layout): θ, θ̇ and τ cannot be told apart."""
    root = _copy(base["images"], tmp_path / "d")

    def unnamed(info: dict) -> None:
        for key in ("observation.state", "observation.effort", "action"):
            info["features"][key].update(names=None, shape=[3])

    _edit_info(root, unnamed)
    for key in ("observation.state", "action"):
        _set_column(root, key, pa.FixedSizeListArray.from_arrays(pa.array(np.ones(N * FRAMES * 3, np.float32)), 3))
    err = _import_refused(capsys, root, tmp_path / "out", "cannot map", "slave_theta", "slave_dtheta")
    assert "observation.state" in err
    # one feature for one field may be unnamed: it is taken whole
    root = _copy(base["images"], tmp_path / "e")
    _edit_info(root, lambda info: info["features"]["observation.effort"].update(names=None))
    back = lerobot_import.from_lerobot(root)
    np.testing.assert_array_equal(back.motions["slave_tau"],
                                  lerobot_import.from_lerobot(base["images"]).motions["slave_tau"])


# ------------------------------------------------------------------------------------------------
# Crafted metadata: one line, exit 2, never a traceback (import-lerobot and lfd train --data)
# ------------------------------------------------------------------------------------------------
def _png_header(width: int, height: int) -> bytes:
    """A PNG that declares ``width`` x ``height`` (no pixel data: PIL refuses it on opening)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IEND", b""))


def _craft(kind: str, root: Path) -> None:
    key = "videos/observation.images.webcam"
    if kind.startswith("video_path="):
        _edit_info(root, lambda info: info.update(video_path=kind.split("=", 1)[1]))
    elif kind.startswith("from_timestamp="):
        _edit_episodes(root, **{f"{key}/from_timestamp": [float(kind.split("=")[1])] * N})
    elif kind.startswith("position_index="):
        value = json.loads(kind.split("=")[1])
        _edit_episodes(root, **{"seqmotion/position_index": [value, 0, 1]})
    elif kind == "raw h264 as mp4":
        _mp4(root / VIDEO, N * FRAMES, container="h264")
    elif kind == "png 20000 x 20000":
        blob = {"bytes": _png_header(20_000, 20_000), "path": None}
        _set_column(root, "observation.images.webcam",
                    pa.array([blob] * N * FRAMES, pa.struct([("bytes", pa.binary()), ("path", pa.string())])))
    else:
        raise AssertionError(kind)


CRAFTED = ["video_path=videos/{foo}.mp4", "video_path=videos/{0}.mp4",
           "video_path=videos/{video_key.__class__.__init__.__globals__}.mp4", "video_path=videos/{chunk_index:{x}}",
           "video_path=videos/{video_key!r}.mp4", "video_path={", "from_timestamp=inf", "from_timestamp=nan",
           "position_index=1000", "position_index=null", "raw h264 as mp4", "png 20000 x 20000"]
WORDS = {"video_path": ("video_path", "meta/info.json"), "from_timestamp": ("from_timestamp", "meta/episodes"),
         "position_index": ("position_index", "meta/episodes"), "raw h264 as mp4": (VIDEO,),
         "png 20000 x 20000": (DATA, "observation.images.webcam")}


@pytest.mark.parametrize("kind", CRAFTED)
def test_crafted_metadata_is_one_line(base, tmp_path, capsys, kind):
    root = _copy(base["images" if kind.startswith(("png", "position")) else "videos"], tmp_path / "pairs_default")
    _craft(kind, root)
    words = WORDS[kind.split("=")[0]]
    _import_refused(capsys, root, tmp_path / "out", *words)
    rc, err = _cli(capsys, "lfd", "train", "--data", str(root), "--out", str(tmp_path / "run"), "--preset", "tiny",
                   "--quiet")
    assert rc == 2 and err.count("\n") == 1 and all(w in err for w in words), err


# ------------------------------------------------------------------------------------------------
# FIFOs and other non-regular files are not opened (an open would block forever)
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("rel", [DATA, EPISODES])
def test_fifo_is_refused_without_opening_it(base, tmp_path, capsys, rel):
    root = _copy(base["images"], tmp_path / "d")
    (root / rel).unlink()
    os.mkfifo(root / rel)
    # a writer that opens (and closes) the FIFO after a while, so that a reader that blocks on it fails
    # this test instead of hanging the suite
    writer = subprocess.Popen(["sh", "-c", f"sleep 5; : > '{root / rel}'"])
    try:
        _import_refused(capsys, root, tmp_path / "out", Path(rel).name, "not a regular file")
    finally:
        writer.kill()
        writer.wait()


# ------------------------------------------------------------------------------------------------
# Silent coercions refused by name
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("column, values, word", [
    ("seqmotion/success", ["no", "yes", "no"], "seqmotion/success"),
    ("seqmotion/success", [None, True, False], "seqmotion/success"),
    ("seqmotion/position_index", [0.5, 1.0, 2.0], "seqmotion/position_index"),
])
def test_episode_fields_are_not_coerced(base, tmp_path, capsys, column, values, word):
    root = _copy(base["images"], tmp_path / "d")
    _edit_episodes(root, **{column: values})
    _import_refused(capsys, root, tmp_path / "out", word, "meta/episodes")


def test_position_range_is_the_simulators():
    from seqmotion.lfd.env.pushing import POSITIONS

    assert lerobot_import.BLOCK_POSITIONS == len(POSITIONS)


def test_tiny_fps_is_refused(base, tmp_path, capsys):
    root = _copy(base["images"], tmp_path / "d")
    _edit_info(root, lambda info: info.update(fps=1e-300))
    _import_refused(capsys, root, tmp_path / "out", "'fps'", "meta/info.json")


def test_list_rows_of_unequal_length_are_refused(base, tmp_path, capsys):
    """Rows of 8 and 10 values (18 per pair, as two rows of 9 would hold) are not read across row boundaries."""
    root = _copy(base["images"], tmp_path / "d")
    rows = N * FRAMES
    offsets = np.cumsum([0] + [8 if r % 2 == 0 else 10 for r in range(rows)])
    _set_column(root, "action", pa.ListArray.from_arrays(pa.array(offsets, pa.int32()),
                                                         pa.array(np.ones(offsets[-1], np.float32))))
    _import_refused(capsys, root, tmp_path / "out", DATA, "'action'", "row 0", "8 values")


def test_struct_column_is_refused(base, tmp_path, capsys):
    root = _copy(base["images"], tmp_path / "d")
    values = np.ones((N * FRAMES, 9), np.float32)
    struct_array = pa.StructArray.from_arrays([pa.array(values[:, i]) for i in range(9)], [f"f{i}" for i in range(9)])
    _set_column(root, "action", struct_array)
    _import_refused(capsys, root, tmp_path / "out", DATA, "'action'", "struct")


# ------------------------------------------------------------------------------------------------
# Values: non-finite or absurd magnitudes refused with the file, feature and row
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("value", [np.inf, np.nan, 3e38, 1e20, -2e6])
def test_absurd_values_are_refused(base, tmp_path, capsys, value):
    root = _copy(base["images"], tmp_path / "d")
    action = np.ones((N * FRAMES, 9), np.float32)
    action[7, 4] = value
    _set_column(root, "action", pa.FixedSizeListArray.from_arrays(pa.array(action.reshape(-1)), 9))
    _import_refused(capsys, root, tmp_path / "out", DATA, "'action'", "row 7")


# ------------------------------------------------------------------------------------------------
# --set is a plain name
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["../../x", "ABSOLUTE", ".", "..", "a/b", "", "-x"])
def test_set_name_is_a_plain_name(base, tmp_path, capsys, name):
    out = tmp_path / "a" / "b" / "out"
    name = str(tmp_path / "abs") if name == "ABSOLUTE" else name
    rc, err = _cli(capsys, "lfd", "import-lerobot", str(base["images"]), str(out), f"--set={name}")
    assert rc == 2 and "--set" in err and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.rglob("*")) == [], "something was written"
    with pytest.raises(ValueError, match="set name"):
        lerobot_import.import_lerobot(base["images"], out, name=name)
    assert sorted(p.name for p in tmp_path.rglob("*")) == []


def test_plain_set_names_are_written(base, tmp_path, capsys):
    rc, err = _cli(capsys, "lfd", "import-lerobot", str(base["images"]), str(tmp_path), "--set", "my_set-1.v2")
    assert rc == 0 and (tmp_path / "my_set-1.v2.h5").is_file(), err


def test_clean_exports_still_import(base):
    """The checks above leave a dataset export-lerobot wrote (PNG and H.264) importable, images included."""
    images, videos = lerobot_import.from_lerobot(base["images"]), lerobot_import.from_lerobot(base["videos"])
    np.testing.assert_array_equal(images.motion(), videos.motion())
    assert images.images is not None and videos.images is not None
    assert np.abs(images.images.astype(int) - videos.images.astype(int)).mean() < 20
    np.testing.assert_array_equal(images.episodes["position_index"], np.arange(N))
    np.testing.assert_array_equal(images.episodes["success"], [True, False, True])
