"""LeRobotDataset v3.0 export and import (seqmotion.lfd.data.lerobot, .lerobot_import) on a tiny collected set.

Export -> the third-party validator lerobot-doctor (no FAIL) -> import round trip (states and actions
exact in float32, images within codec loss) -> training; and every kind of bad input refused by name.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("seqmotion.lfd.env.pushing")
pa = pytest.importorskip("pyarrow")
import pyarrow.parquet as pq  # noqa: E402

from seqmotion.lfd import cli, train  # noqa: E402
from seqmotion.lfd.data import dataset, lerobot, lerobot_import  # noqa: E402
from seqmotion.lfd.policy.policy import PushingPolicy  # noqa: E402


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    """6 motions and 6 image-motion pairs (default camera) of 0.6 s, collected once."""
    out = tmp_path_factory.mktemp("lerobot_data")
    dataset.collect(out, ["motions", "pairs_default"], seed=5, duration=0.6,
                    per_position={"motions": 1, "pairs_default": 1}, progress=False)
    return out


@pytest.fixture(scope="module")
def exported(data_dir, tmp_path_factory):
    """``{"images": OUT, "videos": OUT}``, each with motions/ and pairs_default/ LeRobot datasets."""
    root = tmp_path_factory.mktemp("lerobot_out")
    return {
        "images": Path(lerobot.to_lerobot(data_dir, root / "images")["pairs_default"]).parent,
        "videos": Path(lerobot.to_lerobot(data_dir, root / "videos", videos=True)["pairs_default"]).parent,
    }


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    cli.add_parser(parser.add_subparsers(dest="command"))
    return parser


def _run(*argv: str) -> int:
    args = _parser().parse_args(["lfd", *argv])
    return args.func(args)


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


# ------------------------------------------------------------------------------------------------
# Export
# ------------------------------------------------------------------------------------------------
def test_export_layout_and_features(exported):
    """v3.0 files where LeRobot looks for them, the features named per joint, fps 50 (every 20th sample)."""
    root = exported["images"] / "pairs_default"
    for rel in ("meta/info.json", "meta/stats.json", "meta/tasks.parquet", "meta/episodes/chunk-000/file-000.parquet",
                "data/chunk-000/file-000.parquet"):
        assert (root / rel).is_file(), rel
    info = json.loads((root / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == 50
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (6, 180, 1)
    f = info["features"]
    assert f["observation.state"]["names"] == ["yaw.pos", "shoulder.pos", "elbow.pos", "yaw.vel", "shoulder.vel",
                                               "elbow.vel"]
    assert f["action"]["shape"] == [9] and f["action"]["names"][-1] == "elbow.effort"
    assert f["observation.environment_state"]["shape"] == [7]
    assert f["observation.images.webcam"]["dtype"] == "image"
    assert info["video_path"] is None
    data = pq.read_table(root / "data/chunk-000/file-000.parquet")
    assert data.num_rows == 180 and pq.ParquetFile(root / "data/chunk-000/file-000.parquet").num_row_groups == 6
    assert data.column("observation.images.webcam").type.field("bytes").type == pa.binary()
    episodes = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [(e["dataset_from_index"], e["dataset_to_index"]) for e in episodes] == [(30 * i, 30 * i + 30)
                                                                                    for i in range(6)]
    assert episodes[0]["tasks"] == [lerobot.TASK]
    assert len(episodes[0]["stats/action/q99"]) == 9 and episodes[0]["stats/action/count"] == [30]
    stats = json.loads((root / "meta/stats.json").read_text())
    assert set(stats["action"]) == {"min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99"}
    assert np.shape(stats["observation.images.webcam"]["mean"]) == (3, 1, 1)
    tasks = pq.read_table(root / "meta/tasks.parquet")
    assert tasks.column("task").to_pylist() == [lerobot.TASK]


def test_export_columns_are_the_recorded_signals(exported, data_dir):
    """``action`` is the master's angle, velocity and torque at the frame, ``observation.state`` the slave's."""
    root = exported["images"] / "pairs_default"
    data = pq.read_table(root / "data/chunk-000/file-000.parquet")
    src = dataset.load_dataset(data_dir / "pairs_default.h5")
    action = np.asarray(data.column("action").to_pylist(), dtype=np.float32).reshape(6, 30, 9)
    state = np.asarray(data.column("observation.state").to_pylist(), dtype=np.float32).reshape(6, 30, 6)
    m = {k: v[:, ::20].astype(np.float32) for k, v in src.motions.items()}
    np.testing.assert_array_equal(action, np.concatenate([m["master_theta"], m["master_dtheta"], m["master_tau"]], -1))
    np.testing.assert_array_equal(state, np.concatenate([m["slave_theta"], m["slave_dtheta"]], -1))
    np.testing.assert_allclose(np.asarray(data.column("timestamp").to_pylist())[:3], [0, 0.02, 0.04], atol=1e-7)


def test_video_export(exported):
    root = exported["videos"] / "pairs_default"
    info = json.loads((root / "meta/info.json").read_text())
    webcam = info["features"]["observation.images.webcam"]
    assert webcam["dtype"] == "video" and webcam["info"]["video.codec"] == "av1"
    assert webcam["info"]["video.fps"] == 50 and webcam["info"]["video.pix_fmt"] == "yuv420p"
    assert (root / "videos/observation.images.webcam/chunk-000/file-000.mp4").is_file()
    episodes = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert episodes[1]["videos/observation.images.webcam/from_timestamp"] == pytest.approx(0.6)
    assert "observation.images.webcam" not in pq.read_schema(root / "data/chunk-000/file-000.parquet").names
    # the motion-only set has no camera and no video path
    assert json.loads((exported["videos"] / "motions/meta/info.json").read_text())["video_path"] is None


@pytest.mark.parametrize("kind", ["images", "videos"])
def test_lerobot_doctor_finds_no_failure(exported, kind):
    """The third-party validator lerobot-doctor (PyPI, the dev extra) reports no FAIL on the exports."""
    doctor = shutil.which("lerobot-doctor") or (Path(sys.executable).parent / "lerobot-doctor")
    if not Path(doctor).is_file():
        pytest.skip("lerobot-doctor is not installed (pip install -e '.[dev]' installs it)")
    for name in ("motions", "pairs_default"):
        # --ci: a JSON report, exit status 1 on any FAIL
        result = subprocess.run([str(doctor), str(exported[kind] / name), "--ci"], capture_output=True, text=True,
                                timeout=300)
        report = json.loads(result.stdout[result.stdout.index("{"):])
        failed = [m for c in report["checks"] for m in c["messages"] if m["severity"] == "FAIL"]
        assert report["overall_severity"] != "FAIL" and not failed, failed
        assert result.returncode == 0, result.stderr


def test_export_refuses_bad_arguments(data_dir, exported, tmp_path):
    with pytest.raises(ValueError, match="fps must divide"):
        lerobot.to_lerobot(data_dir, tmp_path / "a", fps=30)
    with pytest.raises(ValueError, match="already exists"):
        lerobot.to_lerobot(data_dir, exported["images"])
    with pytest.raises(ValueError, match="owner/name"):
        lerobot.to_lerobot(data_dir, tmp_path / "b", repo_id="no slash")
    with pytest.raises(ValueError, match="holds no dataset"):
        lerobot.to_lerobot(tmp_path, tmp_path / "c")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_export_is_all_or_nothing(data_dir, tmp_path, monkeypatch):
    """A failure while writing leaves no dataset folder, not a partial one."""

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(lerobot, "_write_tasks", boom)
    with pytest.raises(OSError, match="disk full"):
        lerobot.to_lerobot(data_dir / "motions.h5", tmp_path / "out")
    assert not (tmp_path / "out" / "motions").exists()
    assert [p.name for p in (tmp_path / "out").iterdir()] == []  # no temporary left behind


# ------------------------------------------------------------------------------------------------
# Import
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["images", "videos"])
def test_round_trip(exported, data_dir, kind):
    """States and actions come back exactly (float32) at the exported rate; images within the codec's loss."""
    for name in ("motions", "pairs_default"):
        src = dataset.load_dataset(data_dir / f"{name}.h5")
        back = lerobot_import.from_lerobot(exported[kind] / name)
        assert back.dt == pytest.approx(0.02) and back.attrs["set_name"] == name
        np.testing.assert_array_equal(back.motion(), src.motion())  # float32 in the h5, float32 in the parquet
        np.testing.assert_array_equal(back.motions["block_pose"], src.motions["block_pose"][:, ::20])
        np.testing.assert_array_equal(back.episodes["position_index"], src.episodes["position_index"])
        np.testing.assert_array_equal(back.episodes["success"], src.episodes["success"])
        if name == "motions":
            assert back.images is None
        elif kind == "images":
            np.testing.assert_array_equal(back.images, src.images)  # PNG is lossless
        else:
            err = np.abs(back.images.astype(int) - src.images.astype(int))
            assert err.mean() < 6 and back.images.shape == src.images.shape, err.mean()  # AV1 at CRF 30


def test_import_cli_writes_a_seqmotion_dataset(exported, data_dir, tmp_path):
    assert _run("import-lerobot", str(exported["images"] / "pairs_default"), str(tmp_path)) == 0
    back = dataset.load_dataset(tmp_path / "pairs_default.h5")
    src = dataset.load_dataset(data_dir / "pairs_default.h5")
    np.testing.assert_array_equal(back.motion(), src.motion())
    np.testing.assert_array_equal(back.images, src.images)
    assert back.attrs["camera"] == "default"
    with pytest.raises(ValueError, match="already exists"):
        _run("import-lerobot", str(exported["images"] / "pairs_default"), str(tmp_path))


def test_export_cli(data_dir, tmp_path, capsys):
    assert _run("export-lerobot", str(data_dir), str(tmp_path / "x"), "--repo-id", "me/push", "--fps", "100") == 0
    assert "pairs_default: LeRobot v3.0 dataset" in capsys.readouterr().out
    info = json.loads((tmp_path / "x/motions/meta/info.json").read_text())
    assert info["fps"] == 100 and info["total_frames"] == 6 * 60
    assert "me/push_motions" in (tmp_path / "x/motions/README.md").read_text()
    back = lerobot_import.from_lerobot(tmp_path / "x/motions")  # exact at 100 Hz too
    src = dataset.load_dataset(data_dir / "motions.h5")
    np.testing.assert_array_equal(back.motion(every=1), src.motion(every=10))


def test_train_accepts_lerobot_folders(exported, tmp_path):
    """``lfd train --data`` on export-lerobot's output, and on one LeRobot dataset folder (both sets in one)."""
    fast = train.SeqAETraining(epochs=1, batch_size=4)
    for data in (exported["images"], exported["videos"] / "pairs_default"):
        report = train.train(data, tmp_path / data.name, "tiny", ("proposed",), ("default",), seed=0,
                             seqae_settings=fast, cnn_settings=train.CNNTraining(epochs=1, targets="pair"),
                             progress=False, successful_only=False)
        assert (report.policies["proposed_default"] / "model.safetensors").is_file()


# ------------------------------------------------------------------------------------------------
# Bad input: each refused by name, nothing written
# ------------------------------------------------------------------------------------------------
def _edit_info(root: Path, **changes) -> None:
    info = json.loads((root / "meta/info.json").read_text())
    info.update(changes)
    (root / "meta/info.json").write_text(json.dumps(info))


def test_not_a_dataset(tmp_path):
    with pytest.raises(ValueError, match="not a LeRobot dataset: it has no meta/info.json"):
        lerobot_import.from_lerobot(tmp_path)
    with pytest.raises(ValueError, match="Hub ids are not downloaded"):
        lerobot_import.from_lerobot("lerobot/pusht")
    (tmp_path / "meta").mkdir()
    (tmp_path / "meta/info.json").write_text("{not json")
    with pytest.raises(ValueError, match="info.json is not valid JSON"):
        lerobot_import.from_lerobot(tmp_path)


def test_v21_dataset_names_version_and_conversion(exported, tmp_path):
    root = _copy(exported["images"] / "motions", tmp_path / "d")
    _edit_info(root, codebase_version="v2.1")
    with pytest.raises(ValueError, match=r"codebase_version is 'v2.1'.*convert_dataset_v21_to_v30"):
        lerobot_import.from_lerobot(root)


def test_missing_feature_is_named(exported, tmp_path):
    root = _copy(exported["images"] / "motions", tmp_path / "d")
    info = json.loads((root / "meta/info.json").read_text())
    del info["features"]["observation.effort"]
    (root / "meta/info.json").write_text(json.dumps(info))
    with pytest.raises(ValueError, match="cannot map slave_tau: the dataset has no feature 'observation.effort'"):
        lerobot_import.from_lerobot(root)
    with pytest.raises(ValueError, match="unknown fields"):
        lerobot_import.from_lerobot(exported["images"] / "motions", {"gripper": "action"})


def test_map_takes_other_keys(exported, tmp_path):
    """Another robot's keys: rename the features, then map them back with --map."""
    root = _copy(exported["images"] / "motions", tmp_path / "d")
    info = json.loads((root / "meta/info.json").read_text())
    info["features"]["observation.torque"] = info["features"].pop("observation.effort")
    (root / "meta/info.json").write_text(json.dumps(info))
    path = root / "data/chunk-000/file-000.parquet"
    table = pq.read_table(path)
    pq.write_table(table.rename_columns(["observation.torque" if n == "observation.effort" else n
                                         for n in table.column_names]), path)
    back = lerobot_import.from_lerobot(root, lerobot_import.parse_map(["slave_tau=observation.torque"]))
    np.testing.assert_array_equal(back.motion(), lerobot_import.from_lerobot(exported["images"] / "motions").motion())
    with pytest.raises(ValueError, match="--map needs FIELD=KEY"):
        lerobot_import.parse_map(["slave_tau"])


def test_mismatched_lengths(exported, tmp_path):
    root = _copy(exported["images"] / "motions", tmp_path / "d")
    path = root / "meta/episodes/chunk-000/file-000.parquet"
    rows = pq.read_table(path).to_pylist()
    rows[2]["length"] = 31
    pq.write_table(pa.Table.from_pylist(rows), path)
    with pytest.raises(ValueError, match="episode 2 has 30 frames in data/ but length 31 in meta/episodes"):
        lerobot_import.from_lerobot(root)
    root = _copy(exported["images"] / "motions", tmp_path / "e")
    _edit_info(root, total_frames=179)
    with pytest.raises(ValueError, match="more frames than total_frames = 179"):
        lerobot_import.from_lerobot(root)


def test_unequal_episodes_need_trim(exported, tmp_path):
    root = _copy(exported["images"] / "motions", tmp_path / "d")
    data_path = root / "data/chunk-000/file-000.parquet"
    table = pq.read_table(data_path)
    keep = [i for i in range(table.num_rows) if i != 29]  # episode 0 loses its last frame
    pq.write_table(table.take(keep), data_path)
    path = root / "meta/episodes/chunk-000/file-000.parquet"
    rows = pq.read_table(path).to_pylist()
    rows[0]["length"] = 29
    pq.write_table(pa.Table.from_pylist(rows), path)
    _edit_info(root, total_frames=179)
    with pytest.raises(ValueError, match="different lengths.*--trim"):
        lerobot_import.from_lerobot(root)
    assert lerobot_import.from_lerobot(root, trim=True).motion().shape == (6, 29, 18)


def test_huge_declared_counts_refused_before_reading(exported, tmp_path):
    root = _copy(exported["images"] / "motions", tmp_path / "d")
    _edit_info(root, total_frames=10**12)
    with pytest.raises(ValueError, match="total_frames"):
        lerobot_import.from_lerobot(root)
    _edit_info(root, total_frames=180, total_episodes=10**9)
    with pytest.raises(ValueError, match="total_episodes"):
        lerobot_import.from_lerobot(root)
    _edit_info(root, total_episodes=6, features={"action": {"dtype": "float32", "shape": [10**9]}})
    with pytest.raises(ValueError, match="feature 'action' has no valid 'shape'"):
        lerobot_import.from_lerobot(root)


def test_import_failure_writes_nothing(exported, tmp_path):
    root = _copy(exported["images"] / "motions", tmp_path / "d")
    (root / "data/chunk-000/file-000.parquet").write_bytes(b"PAR1 truncated")
    with pytest.raises(ValueError, match="not a readable parquet file"):
        _run("import-lerobot", str(root), str(tmp_path / "out"))
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_train_refuses_a_dataset_without_images_for_the_cnn(exported, tmp_path):
    """A motions-only dataset cannot train the CNN (the error names the way out); the SeqAE alone trains on it."""
    with pytest.raises(ValueError, match="has no camera images.*--methods seqae"):
        train.train(exported["images"] / "motions", tmp_path / "m", "tiny", ("proposed",), ("default",),
                    progress=False)
    report = train.train(exported["images"] / "motions", tmp_path / "m", "tiny", ("seqae",), progress=False,
                         seqae_settings=train.SeqAETraining(epochs=1, batch_size=4), successful_only=False)
    assert set(report.policies) == {"seqae"} and report.policies["seqae"] == tmp_path / "m" / "seqae"
    assert PushingPolicy.from_pretrained(report.policies["seqae"]).seqae_config.joints == 3


def test_wrong_column_type_is_named(exported, tmp_path):
    root = _copy(exported["images"] / "motions", tmp_path / "d")
    path = root / "data/chunk-000/file-000.parquet"
    table = pq.read_table(path)
    i = table.column_names.index("observation.effort")
    pq.write_table(table.set_column(i, "observation.effort", pa.array(["x"] * table.num_rows)), path)
    with pytest.raises(ValueError, match="column 'observation.effort' is not numeric"):
        lerobot_import.from_lerobot(root)


def test_imported_dataset_exports_again(exported, tmp_path):
    """An import (no block pose mapped, no camera) exports again to an equal dataset."""
    back = lerobot_import.from_lerobot(exported["images"] / "pairs_default", {"image": "", "block_pose": ""})
    assert back.images is None and "block_pose" not in back.motions
    again = lerobot.export_set(back, tmp_path / "again")
    np.testing.assert_array_equal(lerobot_import.from_lerobot(again).motion(), back.motion())
