"""Chapter-5 training, evaluation, CLI and the shipped policy, on tiny datasets and tiny models."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
import torch

pushing = pytest.importorskip("seqmotion.lfd.env.pushing")
import seqmotion as sm  # noqa: E402
from seqmotion.lfd import cli, evaluate, fitting, train  # noqa: E402
from seqmotion.lfd.data import dataset  # noqa: E402
from seqmotion.lfd.policy.policy import PushingPolicy  # noqa: E402

FAST = train.SeqAETraining(epochs=2, batch_size=4)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    """6 motions, 6 + 6 image-motion pairs (default, position1) of 0.6 s: too short to push, fine to train on."""
    out = tmp_path_factory.mktemp("lfd_data")
    dataset.collect(
        out,
        ["motions", "pairs_default", "pairs_position1"],
        seed=5,
        duration=0.6,
        per_position={"motions": 1, "pairs_default": 1, "pairs_position1": 1},
        progress=False,
    )
    return out


@pytest.fixture(scope="module")
def trained(data_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("lfd_models")
    report = train.train(
        data_dir,
        out,
        "tiny",
        ("proposed", "end_to_end"),
        ("default",),
        seed=3,
        seqae_settings=train.SeqAETraining(epochs=2, batch_size=4),
        e2e_settings=train.SeqAETraining(epochs=2),
        cnn_settings=train.CNNTraining(epochs=2),
        progress=False,
        successful_only=False,
    )
    return out, report


def test_seqae_training_learns():
    """A 1 x 16 SeqAE fits two distinct motion families; the per-epoch loss falls by > 5x."""
    t = np.linspace(0, 1, 30)[:, None]
    base = np.concatenate([np.sin(2 * np.pi * t) * np.ones((1, 9)), np.sin(2 * np.pi * t - 0.2) * np.ones((1, 9))], 1)
    motions = np.stack([base * s for s in (1.0, -1.0, 0.9, -0.9)])
    model, history = train.train_seqae(
        motions,
        sm.lfd.SeqAEConfig(1, 16),
        train.SeqAETraining(epochs=150, batch_size=4, lr=1e-2, state_noise=0.0, latent_noise=0.0, seed=0),
    )
    assert history["loss"][-1] < history["loss"][0] / 5
    z = train.encode_motions(model, motions)
    assert np.linalg.norm(z[0] - z[1]) > 1e-3  # the two directions get different latents


def test_training_is_seeded():
    motions = np.random.default_rng(0).normal(size=(4, 10, 18))
    settings = train.SeqAETraining(epochs=2, batch_size=2, noise_correlation=3.0, seed=7)
    a, _ = train.train_seqae(motions, sm.lfd.SeqAEConfig(1, 8), settings)
    b, _ = train.train_seqae(motions, sm.lfd.SeqAEConfig(1, 8), settings)
    for key, value in a.state_dict().items():
        torch.testing.assert_close(b.state_dict()[key], value)


def test_train_writes_loadable_policies(trained, data_dir, tmp_path):
    out, report = trained
    assert set(report.policies) == {"proposed_default", "end_to_end_default"}
    assert set(report.seconds) == {"seqae", "cnn_default", "end_to_end_default"}
    proposed = sm.load(report.policies["proposed_default"])
    e2e = sm.load(report.policies["end_to_end_default"])
    assert isinstance(proposed, PushingPolicy) and proposed.config.kind == "proposed"
    assert e2e.config.kind == "end_to_end" and e2e.encoder is None
    log = json.loads((out / "train_log.json").read_text())["runs"][-1]
    assert log["preset"] == "tiny" and log["seed"] == 3 and "machine" in log
    assert proposed.config.training["cnn"]["pairs"] == 6
    assert proposed.config.training["cnn"]["settings"]["targets"] == "position_medoid"

    # Camera moved: the SeqAE is reused bit for bit, only a new CNN is trained.
    moved = train.train(
        data_dir,
        tmp_path,
        "tiny",
        ("proposed",),
        ("position1",),
        seed=3,
        cnn_settings=train.CNNTraining(epochs=2),
        seqae_from=report.policies["proposed_default"],
        progress=False,
        successful_only=False,
    )
    p1 = PushingPolicy.from_pretrained(moved.policies["proposed_position1"])
    assert p1.config.camera == "position1" and "seqae" not in moved.seconds
    for key, value in proposed.state_dict().items():
        if not key.startswith("cnn."):
            torch.testing.assert_close(p1.state_dict()[key], value)
    assert not torch.equal(p1.state_dict()["cnn.out.weight"], proposed.state_dict()["cnn.out.weight"])


def test_train_bad_arguments(data_dir, tmp_path):
    with pytest.raises(ValueError, match="unknown model preset"):
        train.train(data_dir, tmp_path, "gigantic")
    with pytest.raises(ValueError, match="methods"):
        train.train(data_dir, tmp_path, "tiny", ("imitation",))
    with pytest.raises(ValueError, match="cameras"):
        train.train(data_dir, tmp_path, "tiny", cameras=("ceiling",))
    with pytest.raises(ValueError, match="pairs_position2.h5 is missing"):
        train.train(data_dir, tmp_path, "tiny", cameras=("position2",))
    with pytest.raises(ValueError, match="usable demonstration"):  # 0.6 s demonstrations never succeed
        train.train(data_dir, tmp_path, "tiny", seqae_settings=FAST, progress=False)
    with pytest.raises(ValueError, match="epochs"):
        train.SeqAETraining(epochs=0)
    with pytest.raises(ValueError, match="state_noise"):
        train.SeqAETraining(state_noise=-1.0)
    with pytest.raises(ValueError, match="seed"):
        train.CNNTraining(seed=-1)
    with pytest.raises(ValueError, match="3 images but 2 motions"):
        train.train_end_to_end(np.zeros((3, 64, 64, 3), np.uint8), np.zeros((2, 5, 18)), sm.lfd.SeqAEConfig(1, 8))
    with pytest.raises(ValueError, match="targets"):
        train.train_cnn(np.zeros((3, 64, 64, 3), np.uint8), np.zeros((3, 5)))
    with pytest.raises(ValueError, match="CNN targets"):
        train.CNNTraining(targets="motion")


def test_mean_latent_per_position():
    """The CNN's position-wise targets: per block position, the mean (or medoid) z of the demonstrations there."""
    z = np.arange(14.0).reshape(7, 2)
    where = np.array([0, 1, 2, 3, 4, 5, 0])
    means = train.mean_latent_per_position(z, where)
    np.testing.assert_allclose(means[0], [6.0, 7.0])  # rows 0 and 6
    np.testing.assert_allclose(means[1:], z[1:6])
    # medoid: of (0, 1), (1, 1.5), (12, 13) (mean (4.3, 5.2)) the demonstration nearest the mean
    z_medoid = np.array([[0.0, 1.0], [1.0, 1.5], [12.0, 13.0], *z[1:6]])
    where_medoid = np.array([0, 0, 0, 1, 2, 3, 4, 5])
    medoids = train.mean_latent_per_position(z_medoid, where_medoid, medoid=True)
    np.testing.assert_allclose(medoids[0], [1.0, 1.5])
    np.testing.assert_allclose(medoids[1:], z[1:6])
    with pytest.raises(ValueError, match=r"block positions \[5\]"):
        train.mean_latent_per_position(z[:5], where[:5])


def test_evaluate_structure_and_determinism(trained):
    _, report = trained
    policy = PushingPolicy.from_pretrained(report.policies["proposed_default"])
    result = evaluate(policy, positions=[0, 4], trials=2, seed=11, duration=0.3)
    assert result.n_trials == 4 and result.camera == "default" and result.seed == 11
    assert list(result.per_position) == ["left_4.5cm", "right_8cm"]
    assert sum(ok for ok, _ in result.per_position.values()) == result.successes
    assert result.success_rate == pytest.approx(result.successes / 4)
    assert [(o.position_index, o.trial) for o in result.outcomes] == [(0, 0), (0, 1), (4, 0), (4, 1)]
    for o in result.outcomes:
        assert isinstance(o.success, bool) and o.latent.shape == (8,) and o.run is None
        assert o.seed_key == (11, sm.lfd.evaluation.EVAL_STREAM, o.position_index, o.trial)
    for o in result.outcomes:  # final_block_y is the block centre's lateral y: near its start after 0.3 s
        nominal = pushing.POSITIONS[o.position_index].xy[1]  # ±4.5 / 8 cm (not the 16 cm forward reach x)
        assert abs(o.final_block_y - nominal) < 0.01
    json.dumps(result.as_dict())  # JSON-serialisable
    again = evaluate(policy, positions=[0, 4], trials=2, seed=11, duration=0.3)
    assert [o.final_block_y for o in again.outcomes] == [o.final_block_y for o in result.outcomes]
    other = evaluate(policy, positions=[0], trials=1, seed=12, duration=0.3, keep_runs=True)
    assert other.outcomes[0].final_block_y != result.outcomes[0].final_block_y  # fresh placement
    assert other.outcomes[0].image.shape == (64, 64, 3) and other.outcomes[0].run is not None


def test_evaluate_bad_arguments(trained):
    _, report = trained
    policy = PushingPolicy.from_pretrained(report.policies["proposed_default"])
    with pytest.raises(ValueError, match="unknown camera 'ceiling'"):
        evaluate(policy, camera="ceiling")
    with pytest.raises(ValueError, match="block position index"):
        evaluate(policy, positions=[7])
    with pytest.raises(ValueError, match="positions is empty"):
        evaluate(policy, positions=[])
    with pytest.raises(ValueError, match="trials"):
        evaluate(policy, trials=0)
    with pytest.raises(ValueError, match="seed"):
        evaluate(policy, seed=-3)
    with pytest.raises(ValueError, match="PushingPolicy"):
        evaluate("not a policy")


def _parser():
    parser = argparse.ArgumentParser(prog="seqmotion")
    cli.add_parser(parser.add_subparsers(dest="command", required=True))
    return parser


def test_cli_train_and_evaluate(data_dir, tmp_path, capsys):
    args = _parser().parse_args(
        [
            "lfd",
            "train",
            "--data",
            str(data_dir),
            "--out",
            str(tmp_path / "m"),
            "--preset",
            "tiny",
            "--seqae-epochs",
            "1",
            "--cnn-epochs",
            "1",
            "--keep-failed",
            "--quiet",
        ]
    )
    assert args.func(args) == 0
    assert "proposed_default:" in capsys.readouterr().out
    args = _parser().parse_args(
        [
            "lfd",
            "evaluate",
            str(tmp_path / "m" / "proposed_default"),
            "--positions",
            "2",
            "--trials",
            "1",
            "--json",
            str(tmp_path / "ev.json"),
            "--quiet",
        ]
    )
    assert args.func(args) == 0
    assert "success " in capsys.readouterr().out
    saved = json.loads((tmp_path / "ev.json").read_text())
    assert saved["n_trials"] == 1 and len(saved["outcomes"]) == 1
    oracle = ["lfd", "evaluate", str(tmp_path / "m" / "proposed_default"), "--positions", "2", "--trials", "1"]
    args = _parser().parse_args([*oracle, "--quiet", "--oracle-latents", str(data_dir / "motions.h5")])
    with pytest.raises(ValueError, match=r"no \(successful\) demonstration"):  # 0.6 s demonstrations never succeed
        args.func(args)
    with pytest.raises(ValueError, match="usable demonstration"):
        args = _parser().parse_args(
            [
                "lfd",
                "train",
                "--data",
                str(data_dir),
                "--out",
                str(tmp_path / "n"),
                "--preset",
                "tiny",
                "--seqae-epochs",
                "1",
                "--quiet",
            ]
        )
        args.func(args)


def test_export_writes_a_model_card(trained, tmp_path):
    _, report = trained
    policy = PushingPolicy.from_pretrained(report.policies["proposed_default"])
    result = evaluate(policy, positions=[1], trials=1, seed=2, duration=0.3)
    (tmp_path / "ev.json").write_text(json.dumps(result.as_dict()))
    target = sm.lfd.export_policy(
        report.policies["proposed_default"],
        "pushing-test",
        [tmp_path / "ev.json"],
        notes="a tiny test model",
        root=tmp_path / "pretrained",
    )
    card = (target / "MODEL_CARD.md").read_text()
    assert "Seed: 3" in card and "a tiny test model" in card
    # the machine line is what provenance recorded when the policy was trained, not a fixed string
    from seqmotion.training.provenance import describe_machine

    machine = policy.config.training["machine"]
    assert f"- Machine: {describe_machine(machine)} ({machine['platform']})" in card
    assert "2-core CPU container" not in card
    assert json.loads((target / "evaluations.json").read_text())[0]["seed"] == 2
    assert "most typical demonstration without images at its block position" in card
    low, high = result.wilson_interval
    assert (
        f"proposed (tiny), default camera: **{result.success_rate:.1%}** ({result.successes}/1 trials, "
        f"95 % Wilson {low:.0%}–{high:.0%}, evaluation seed 2)"
    ) in card
    shipped = sm.load(target)
    for key, value in policy.state_dict().items():
        torch.testing.assert_close(shipped.state_dict()[key], value)


def test_shipped_policy_loads():
    policy = sm.load_pretrained("pushing")
    assert isinstance(policy, PushingPolicy) and policy.config.kind == "proposed"
    assert policy.config.preset == train.DEFAULT_PRESET and policy.config.camera == "default"
    assert policy.seqae_config == sm.lfd.PRESETS[train.DEFAULT_PRESET] and policy.seqae_config.latent == 8
    card = (sm.api.pretrained_dir("pushing") / "MODEL_CARD.md").read_text()
    assert "2-core CPU" in card and "success" in card
    scene = pushing.PushingScene()
    try:
        scene.reset(pushing.POSITIONS[0])
        z = policy.latent(scene.render("default"))
    finally:
        scene.close()
    assert z.shape == (8,) and np.all(np.isfinite(z))


def test_oracle_latents_bypass_the_cnn(trained, data_dir):
    """evaluate(latents=...) decodes the given z per position (the CNN's ẑ is not used)."""
    _, report = trained
    policy = PushingPolicy.from_pretrained(report.policies["proposed_default"])
    oracle = sm.lfd.position_latents(policy, data_dir / "motions.h5", successful_only=False)
    assert oracle.shape == (6, 8) and np.isfinite(oracle).all()
    medoids = sm.lfd.position_latents(policy, data_dir / "motions.h5", successful_only=False, medoid=True)
    demonstrations = policy.encode(dataset.load_dataset(data_dir / "motions.h5").motion())
    assert all(np.isclose(demonstrations, m).all(1).any() for m in medoids)  # each one a demonstration's z
    result = evaluate(policy, positions=[1, 3], trials=1, seed=2, duration=0.2, latents=oracle)
    for o in result.outcomes:
        np.testing.assert_array_equal(o.latent, oracle[o.position_index])
    cnn = evaluate(policy, positions=[1], trials=1, seed=2, duration=0.2)
    assert not np.allclose(cnn.outcomes[0].latent, oracle[1])
    with pytest.raises(ValueError, match="latents"):
        evaluate(policy, positions=[1], trials=1, duration=0.2, latents=oracle[:3])
    e2e = PushingPolicy.from_pretrained(report.policies["end_to_end_default"])
    with pytest.raises(ValueError, match="no motion encoder"):
        sm.lfd.position_latents(e2e, data_dir / "motions.h5", successful_only=False)


def test_interrupted_training_resumes_exactly(tmp_path, monkeypatch):
    """A SeqAE run killed mid-way and restarted ends with the weights of an uninterrupted one."""
    motions = np.random.default_rng(1).normal(size=(6, 10, 18))
    settings = train.SeqAETraining(epochs=5, batch_size=4, noise_correlation=2.0, latent_noise=0.1, seed=3)
    config = sm.lfd.SeqAEConfig(1, 8)
    straight, straight_history = train.train_seqae(motions, config, settings)

    real_loss = train._seqae_loss
    calls = {"n": 0}

    def dies_in_epoch_four(*args, **kwargs):  # 2 mini-batches per epoch: die in the 4th epoch
        calls["n"] += 1
        if calls["n"] == 8:
            raise KeyboardInterrupt
        return real_loss(*args, **kwargs)

    monkeypatch.setattr(fitting, "CHECKPOINT_EVERY", 1)
    monkeypatch.setattr(train, "_seqae_loss", dies_in_epoch_four)
    with pytest.raises(KeyboardInterrupt):
        train.train_seqae(motions, config, settings, checkpoint_dir=tmp_path / "ckpt")
    monkeypatch.setattr(train, "_seqae_loss", real_loss)
    resumed, history = train.train_seqae(motions, config, settings, checkpoint_dir=tmp_path / "ckpt")
    assert history["loss"] == straight_history["loss"]
    for key, value in straight.state_dict().items():
        torch.testing.assert_close(resumed.state_dict()[key], value, rtol=0, atol=0)
    # the per-epoch log holds every epoch once: the 3 before the kill kept, the last 2 appended
    rows = (tmp_path / "ckpt" / "metrics.csv").read_text().splitlines()
    assert rows[0].startswith("step,epoch,seconds,loss") and [r.split(",")[1] for r in rows[1:]] == list("12345")
    # a checkpoint of other settings is refused, not silently continued
    with pytest.raises(ValueError, match="another training"):
        train.train_seqae(motions, config, train.SeqAETraining(epochs=5, batch_size=2, seed=3),
                          checkpoint_dir=tmp_path / "ckpt")


def test_resume_keeps_the_learning_rate_when_a_short_batch_is_skipped(tmp_path, monkeypatch):
    """5 examples in batches of 4 with min_batch=2 (end-to-end's BatchNorm rule): one batch a epoch is skipped."""
    monkeypatch.setattr(fitting, "CHECKPOINT_EVERY", 2)
    settings = train.SeqAETraining(epochs=4, batch_size=4, seed=0)
    x = torch.linspace(-1, 1, 5).unsqueeze(1)

    def run(checkpoint_dir, die_at=None):
        torch.manual_seed(0)
        module = torch.nn.Linear(1, 1)
        gen = torch.Generator().manual_seed(0)
        calls = {"n": 0}

        def batch_loss(idx):
            calls["n"] += 1
            if calls["n"] == die_at:
                raise KeyboardInterrupt
            return ((module(x[idx]) - 2 * x[idx]) ** 2).mean()

        history = train.fit(module, list(module.parameters()), 5, settings, gen, batch_loss, "toy", False,
                             min_batch=2, checkpoint_dir=checkpoint_dir)
        return module, history

    straight, straight_history = run(None)
    with pytest.raises(KeyboardInterrupt):
        run(tmp_path / "ckpt", die_at=3)  # one step per epoch: dies in epoch 3, after the epoch-2 checkpoint
    resumed, history = run(tmp_path / "ckpt")
    assert history["loss"] == straight_history["loss"]
    for key, value in straight.state_dict().items():
        torch.testing.assert_close(resumed.state_dict()[key], value, rtol=0, atol=0)


@pytest.mark.parametrize("value", [3e38, 1e20, float("nan")])
def test_training_on_corrupt_motions_is_refused_and_writes_nothing(data_dir, tmp_path, capsys, value):
    """One action value of 3e38 trained a NaN policy and exited 0 (1e20: an infinite final loss, and that policy
    was used). The motions are checked before training: one line naming the file and the field, exit 2, no
    output folder."""
    import shutil

    import h5py

    from seqmotion.cli import main

    data = tmp_path / "d"
    data.mkdir()
    shutil.copy(data_dir / "motions.h5", data / "motions.h5")
    with h5py.File(data / "motions.h5", "r+") as f:
        f["motions/master_tau"][0, 40, 1] = value  # sample 40: taken at the decoder's 20 ms (every 20th)
    out = tmp_path / "t"
    rc = main(["lfd", "train", "--data", str(data), "--out", str(out), "--preset", "tiny", "--methods", "seqae",
               "--seqae-epochs", "2", "--keep-failed", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert "motions.h5: master_tau" in err and "episode 0, sample 2" in err, err
    assert not out.exists()
