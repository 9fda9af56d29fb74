"""Training the SeqAE on a LeRobot v3.0 dataset of another robot: its joint count J comes from the data.

A 6-joint robot's dataset (written with seqmotion.lfd.data.lerobot's own writer, one feature renamed so that
``--map`` has to name it) -> ``seqmotion lfd train --data <it> --methods seqae`` -> a SeqAE with J = 6 that
loads back and reconstructs its training motions better than at initialisation; the closed loop in
MuJoCo (the 3-joint arm's) refuses it by name. And the shipped 3-joint ``pushing`` policy is unchanged.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
import torch

pa = pytest.importorskip("pyarrow")
import pyarrow.parquet as pq  # noqa: E402

import seqmotion as sm  # noqa: E402
from seqmotion.lfd import cli, train  # noqa: E402
from seqmotion.lfd.data import lerobot, lerobot_import  # noqa: E402
from seqmotion.lfd.data.dataset import MOTION_KEYS, PushingDataset  # noqa: E402
from seqmotion.lfd.policy.networks import SeqAE, SeqAEConfig, motion_loss  # noqa: E402
from seqmotion.lfd.policy.policy import PushingPolicy  # noqa: E402

JOINTS, EPISODES, FRAMES, FPS = 6, 8, 40, 50
TORQUE_KEY = "observation.joint_torques"
"""The other robot's name for the slave's torques (seqmotion's writer calls it observation.effort)."""


def _motions() -> dict[str, np.ndarray]:
    """Smooth 6-joint motions ``{field: (EPISODES, FRAMES, 6)}``: each episode a sine of its own amplitude and
    phase per joint; the master leads the slave by one frame (as a leader arm leads its follower)."""
    rng = np.random.default_rng(0)
    t = np.arange(FRAMES + 1) / FPS
    amp = rng.uniform(0.2, 0.8, (EPISODES, 1, JOINTS))
    phase = rng.uniform(0, 2 * np.pi, (EPISODES, 1, JOINTS))
    theta = amp * np.sin(2 * np.pi * 1.5 * t[None, :, None] + phase)
    dtheta = np.gradient(theta, 1 / FPS, axis=1)
    tau = 0.3 * theta + 0.02 * dtheta
    lead = {"theta": theta[:, 1:], "dtheta": dtheta[:, 1:], "tau": tau[:, 1:]}
    lag = {"theta": theta[:, :-1], "dtheta": dtheta[:, :-1], "tau": tau[:, :-1]}
    return {f"{who}_{q}": (lead if who == "master" else lag)[q] for who in ("master", "slave")
            for q in ("theta", "dtheta", "tau")}


@pytest.fixture(scope="module")
def robot_dataset(tmp_path_factory) -> Path:
    """A LeRobot v3.0 folder of a 6-joint robot at 50 fps with 64 x 64 images but no block positions."""
    root = tmp_path_factory.mktemp("other_robot") / "arm6"
    motions = _motions()
    assert set(motions) == set(MOTION_KEYS)
    episodes = {"position_index": np.full(EPISODES, -1, dtype=np.int8), "success": np.ones(EPISODES, dtype=bool)}
    images = np.random.default_rng(1).integers(0, 256, (EPISODES, 64, 64, 3), dtype=np.uint8)
    attrs = {"set_name": "pairs_default", "dt": 1 / FPS, "camera": "wrist"}
    lerobot.export_set(PushingDataset(root, attrs, motions, episodes, {}, images), root, "someone/arm6")
    # the other robot's feature name: rename observation.effort in info.json and in the data
    info = json.loads((root / "meta/info.json").read_text())
    info["features"][TORQUE_KEY] = info["features"].pop(lerobot.EFFORT)
    (root / "meta/info.json").write_text(json.dumps(info))
    path = root / "data/chunk-000/file-000.parquet"
    table = pq.read_table(path)
    pq.write_table(table.rename_columns([TORQUE_KEY if n == lerobot.EFFORT else n for n in table.column_names]),
                   path)
    return root


def _run(*argv: str) -> int:
    parser = argparse.ArgumentParser()
    cli.add_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["lfd", *argv])
    return args.func(args)


def _reconstruction_loss(model: SeqAE, motions: np.ndarray) -> float:
    """Eq. 5.1 of the teacher-forced reconstruction of ``motions`` (no noise)."""
    with torch.no_grad():
        x = torch.as_tensor(motions, dtype=torch.float32)
        command, _ = model.eval()(x)
        return float(motion_loss(command, x[:, 1:, model.config.master], model.scaler.variance))


def test_train_seqae_on_a_six_joint_lerobot_dataset(robot_dataset, tmp_path, capsys):
    out = tmp_path / "models"
    torque = f"slave_tau={TORQUE_KEY}"
    assert _run("train", "--data", str(robot_dataset), "--out", str(out), "--methods", "seqae", "--preset", "tiny",
                "--seqae-epochs", "400", "--seed", "3", "--map", torque, "--quiet") == 0
    assert "seqae:" in capsys.readouterr().out

    policy = PushingPolicy.from_pretrained(out / "seqae")
    assert policy.config.kind == "seqae" and policy.cnn is None
    assert policy.seqae_config.joints == JOINTS
    assert json.loads((out / "seqae/config.json").read_text())["policy"]["seqae"]["joints"] == JOINTS
    assert "motion of 6 joints" in policy.model_card("arm6-seqae")
    assert json.loads((robot_dataset / "meta/info.json").read_text())["robot_type"] == "seqmotion_6dof"
    seqae = policy.seqae()
    assert seqae.scaler.mean.shape == (6 * JOINTS,) and seqae.scaler.variance.shape == (3 * JOINTS,)

    motions = lerobot_import.from_lerobot(robot_dataset, lerobot_import.parse_map([torque])).motion()
    assert motions.shape == (EPISODES, FRAMES, 6 * JOINTS)
    assert policy.encode(motions).shape == (EPISODES, 8)
    torch.manual_seed(3)  # the initial weights training started from (same seed, same config)
    initial = SeqAE(policy.seqae_config)
    initial.scaler.fit(motions)
    before, after = _reconstruction_loss(initial, motions), _reconstruction_loss(seqae, motions)
    assert after < 0.25 * before, (before, after)

    # the 6-joint SeqAE's model cannot drive the simulated 3-joint arm: refused by name
    with pytest.raises(ValueError, match="3-joint arm; this model's SeqAE has joints=6"):
        sm.lfd.evaluate(policy, latents=np.zeros((6, 8)))
    with pytest.raises(ValueError, match="3-joint arm"):
        policy.source(np.zeros(8))
    with pytest.raises(ValueError, match="has no CNN"):
        policy.latent(np.zeros((64, 64, 3), np.uint8))

    # its SeqAE trains the CNN of the proposed method on the dataset's images (targets: each pair's own z)
    assert _run("train", "--data", str(robot_dataset), "--out", str(out), "--seqae-from", str(out / "seqae"),
                "--cnn-targets", "pair", "--cnn-epochs", "1", "--map", torque, "--quiet") == 0
    proposed = PushingPolicy.from_pretrained(out / "proposed_default")
    assert proposed.seqae_config.joints == JOINTS and proposed.latent(np.zeros((64, 64, 3), np.uint8)).shape == (8,)
    torch.testing.assert_close(proposed.decoder.state_dict(), seqae.decoder.state_dict())


def test_other_robot_refusals_name_the_way_out(robot_dataset, tmp_path):
    torque = {"slave_tau": TORQUE_KEY}
    with pytest.raises(ValueError, match=r"no block position .*--cnn-targets pair, or --methods seqae"):
        train.train(robot_dataset, tmp_path / "m", "tiny", ("proposed",), mapping=torque, progress=False)
    with pytest.raises(ValueError, match="cannot map slave_tau.*observation.effort"):
        train.train(robot_dataset, tmp_path / "m", "tiny", ("seqae",), progress=False)
    with pytest.raises(ValueError, match="'seqae' trains a SeqAE and seqae_from"):
        train.train(robot_dataset, tmp_path / "m", "tiny", ("seqae",), seqae_from=tmp_path, mapping=torque)
    with pytest.raises(ValueError, match="joints must be a positive integer"):
        SeqAEConfig(joints=0)


def test_shipped_pushing_policy_is_the_three_joint_arm_unchanged():
    """The shipped policy's config has no ``joints`` (it predates it): it loads as J = 3 and computes exactly
    what it computed before J existed (reference values recorded from that code)."""
    config = json.loads((sm.api.pretrained_dir("pushing") / "config.json").read_text())
    assert "joints" not in config["policy"]["seqae"]
    policy = sm.load_pretrained("pushing")
    assert policy.seqae_config.joints == 3 and policy.scaler.mean.shape == (18,)
    rng = np.random.default_rng(0)
    motions = (rng.normal(size=(4, 50, 18)) * np.tile(np.repeat([0.3, 1.0, 0.2], 3), 2)
               + np.tile([0.0, 0.75, -0.06] + [0.0] * 6, 2))
    z = policy.encode(motions)
    np.testing.assert_allclose(z[0], [0.49403322, -1.65072453, -0.22762373, 2.10852289, -0.30130839, 1.83977580,
                                      1.74223375, -2.89319324], rtol=1e-4, atol=1e-5)
    with torch.no_grad():
        command, _ = policy.seqae()(torch.as_tensor(motions, dtype=torch.float32))
    np.testing.assert_allclose(command[0, -1].numpy(), [-0.19510636, 0.55002505, -0.17103486, -0.43799648,
                                                        -0.31942675, -0.29427081, 0.04087700, 0.07659189, 0.00735331],
                               rtol=1e-4, atol=1e-5)
