"""HDF5 datasets of demonstrations: layout, round trip, determinism, argument checks, CLI."""

from __future__ import annotations

import argparse

import h5py
import numpy as np
import pytest

pushing = pytest.importorskip("seqmotion.lfd.env.pushing")
from seqmotion.lfd import cli  # noqa: E402
from seqmotion.lfd.data import dataset  # noqa: E402
from seqmotion.lfd.env import teleop  # noqa: E402
from seqmotion.lfd.env.operator import OperatorParams, ScriptedOperator  # noqa: E402


@pytest.fixture(scope="module")
def pairs_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("lfd") / "pairs_default.h5"
    report = dataset.collect_set(path, "pairs_default", seed=3, per_position=1, duration=1.0)
    assert report.episodes == 6 and report.attempts.tolist() == [1] * 6
    return path


def test_layout_and_round_trip(pairs_file):
    data = dataset.load_dataset(pairs_file)
    assert len(data) == 6 and data.dt == pytest.approx(1e-3)
    assert data.attrs["set_name"] == "pairs_default" and data.attrs["camera"] == "default"
    assert data.attrs["complete"] and data.attrs["seed"] == 3 and data.attrs["samples"] == 1000
    assert data.attrs["gains"]["kp"] == 120.0 and data.attrs["gains"]["kf"] == 0.5
    for key in dataset.MOTION_KEYS:
        assert data.motions[key].shape == (6, 1000, 3)
    assert data.motions["block_pose"].shape == (6, 1000, 7)
    assert data.images.shape == (6, 64, 64, 3) and data.images.dtype == np.uint8
    assert data.episodes["position_index"].tolist() == [0, 1, 2, 3, 4, 5]
    assert data.episodes["side"].tolist() == ["left"] * 3 + ["right"] * 3
    assert set(data.operator) >= {"stiffness", "push_speed", "hesitant"}
    assert data.motion(every=20).shape == (6, 50, 18)
    np.testing.assert_array_equal(data.motion(every=1)[..., 9:12], data.motions["slave_theta"])

    # The file holds exactly what the episode's seed regenerates (determinism, float32 storage).
    episode = 4
    seed_key = data.episodes["seed_key"][episode]
    rng = dataset.episode_rng(*(int(v) for v in seed_key))
    params = OperatorParams.sample(rng)
    variation = pushing.SceneVariation.sample(rng)
    scene, master = pushing.PushingScene(), pushing.MasterArm()
    try:
        demo = teleop.teleoperate(
            scene, master, ScriptedOperator(params, rng), pushing.POSITIONS[episode], 1.0, variation, "default"
        )
    finally:
        scene.close()
    for key in (*dataset.MOTION_KEYS, "block_pose", "hand_force"):
        np.testing.assert_allclose(data.motions[key][episode], getattr(demo, key), rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(data.images[episode], demo.image)
    assert data.operator["stiffness"][episode] == pytest.approx(params.stiffness)
    np.testing.assert_allclose(data.episodes["block_initial_pose"][episode], demo.block_pose[0])


def test_images_differ_between_episodes(pairs_file):
    images = dataset.load_dataset(pairs_file).images.astype(int)
    for i in range(6):
        for j in range(i + 1, 6):
            assert np.abs(images[i] - images[j]).mean() > 1.0


def test_motion_only_set_and_collect(tmp_path):
    reports = dataset.collect(tmp_path, ["motions"], seed=1, duration=0.5, per_position={"motions": 1}, progress=False)
    data = dataset.load_dataset(reports["motions"].path)
    assert data.images is None and data.attrs["camera"] == "" and len(data) == 6
    # Sets draw from separate seed streams: same seed, different set, different operators.
    with h5py.File(reports["motions"].path) as f:
        assert f["episodes/seed_key"][0].tolist() == [1, dataset.SETS["motions"].set_id, 0]


def test_bad_arguments(tmp_path, pairs_file):
    with pytest.raises(ValueError, match="unknown dataset"):
        dataset.collect_set(tmp_path / "a.h5", "pairs_sideways")
    with pytest.raises(ValueError, match="seed"):
        dataset.collect_set(tmp_path / "a.h5", seed=-1)
    with pytest.raises(ValueError, match="per_position"):
        dataset.collect_set(tmp_path / "a.h5", per_position=0)
    with pytest.raises(ValueError, match="unknown camera"):
        dataset.collect_set(tmp_path / "a.h5", camera="ceiling")
    with pytest.raises(ValueError, match="duration"):
        dataset.collect_set(tmp_path / "a.h5", duration=0.0)
    with pytest.raises(ValueError, match="already exists"):
        dataset.collect_set(pairs_file, "pairs_default", per_position=1)
    with pytest.raises(ValueError, match="unknown dataset"):
        dataset.collect(tmp_path, ["motions", "everything"])
    with pytest.raises(ValueError, match="not being collected"):
        dataset.collect(tmp_path, ["motions"], per_position={"pairs_default": 1})
    assert not (tmp_path / "a.h5").exists()

    with pytest.raises(ValueError, match="does not exist"):
        dataset.load_dataset(tmp_path / "missing.h5")
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(b"not an hdf5 file")
    with pytest.raises(ValueError, match="not a readable HDF5"):
        dataset.load_dataset(garbage)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["format"] = "something else"
    with pytest.raises(ValueError, match="is not a seqmotion.lfd.pushing dataset"):
        dataset.load_dataset(other)
    partial = tmp_path / "partial.h5"
    partial.write_bytes(pairs_file.read_bytes())
    with h5py.File(partial, "r+") as f:
        f.attrs["complete"] = False
    with pytest.raises(ValueError, match="incomplete"):
        dataset.load_dataset(partial)
    with pytest.raises(ValueError, match="every"):
        dataset.load_dataset(pairs_file).motion(every=0)


def _parser():
    parser = argparse.ArgumentParser(prog="seqmotion")
    cli.add_parser(parser.add_subparsers(dest="command", required=True))
    return parser


def test_cli(tmp_path, pairs_file, capsys):
    args = _parser().parse_args(["lfd", "info", str(pairs_file)])
    assert args.func(args) == 0
    assert "6 episodes" in capsys.readouterr().out
    args = _parser().parse_args(
        ["lfd", "collect", "--out", str(tmp_path), "--sets", "pairs_position1", "--per-position", "1",
         "--duration", "0.5", "--quiet"]
    )
    assert args.func(args) == 0
    assert "pairs_position1: 6 episodes" in capsys.readouterr().out
    assert dataset.load_dataset(tmp_path / "pairs_position1.h5").attrs["camera"] == "position1"
    with pytest.raises(ValueError, match="seed"):
        args = _parser().parse_args(["lfd", "collect", "--out", str(tmp_path / "x"), "--seed", "-2"])
        args.func(args)
    with pytest.raises(SystemExit):
        _parser().parse_args(["lfd", "collect", "--out", str(tmp_path), "--sets", "pairs_sideways"])
