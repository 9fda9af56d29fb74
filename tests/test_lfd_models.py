"""Chapter-5 networks: shapes, the eq.-5.1 loss, checkpoints, a CNN that learns, the decoder in the loop."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from seqmotion import CheckpointError
from seqmotion.lfd.policy import networks
from seqmotion.lfd.policy.networks import (
    CNNConfig,
    ImageEncoder,
    SeqAE,
    SeqAEConfig,
    motion_loss,
)
from seqmotion.lfd.policy.policy import PolicyConfig, PushingPolicy
from seqmotion.training.checkpoint import config_digest

TINY = SeqAEConfig(layers=2, hidden=8)


def _motions(n: int = 4, k: int = 12, seed: int = 0) -> np.ndarray:
    """Random motions (N, K, 18) with the scales of the real data (rad, rad/s, N m)."""
    rng = np.random.default_rng(seed)
    scale = np.tile(np.repeat([0.3, 0.8, 0.03], 3), 2)
    return rng.normal(size=(n, k, 18)) * scale + np.tile([0.0, 0.75, -0.06] + [0.0] * 6, 2)


def _policy(kind: str = "proposed", config: SeqAEConfig = TINY) -> PushingPolicy:
    torch.manual_seed(0)
    seqae = SeqAE(config)
    seqae.scaler.fit(_motions())
    cnn = {"channels": (4, 4, 8, 8, 8), "latent": 8, "image_size": 64}
    cfg = PolicyConfig(kind, "tiny", dataclasses.asdict(config), cnn)
    return PushingPolicy(cfg, seqae, ImageEncoder(CNNConfig(channels=(4, 4, 8, 8, 8))))


def test_shapes():
    model = SeqAE(TINY)
    x = torch.as_tensor(_motions(3, 10), dtype=torch.float32)
    command, z = model(x)
    assert command.shape == (3, 9, 9) and z.shape == (3, 8)
    out, (h, c) = model.decode(z, x[:, :4, 9:])
    assert out.shape == (3, 4, 9) and h.shape == (2, 3, 8) and c.shape == (2, 3, 8)
    cnn = ImageEncoder(CNNConfig())
    assert cnn(torch.zeros(5, 64, 64, 3, dtype=torch.uint8)).shape == (5, 8)
    policy = _policy()
    image = np.random.default_rng(1).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    assert policy.latent(image).shape == (8,) and policy.latent(np.stack([image] * 2)).shape == (2, 8)
    assert policy.encode(_motions(1, 10)[0]).shape == (8,) and policy.encode(_motions(2, 10)).shape == (2, 8)
    assert {k.split(".")[0] for k in policy.state_dict()} == {"scaler", "encoder", "decoder", "cnn"}
    assert "encoder" not in {k.split(".")[0] for k in _policy("end_to_end").state_dict()}


def test_step_by_step_decoding_equals_the_sequence():
    """Closed-loop decoding (one step at a time, carried state) is the teacher-forced pass."""
    model = SeqAE(TINY).eval()
    model.scaler.fit(_motions())
    x = torch.as_tensor(_motions(1, 8), dtype=torch.float32)
    with torch.no_grad():
        z = model.encode(x)
        whole, _ = model.decode(z, x[:, :, 9:])
        state, steps = None, []
        for k in range(8):
            out, state = model.decode(z, x[:, k : k + 1, 9:], state)
            steps.append(out)
    torch.testing.assert_close(torch.cat(steps, 1), whole)


def test_scaler_and_variance_scaled_loss():
    motions = _motions(5, 20)
    scaler = networks.MotionScaler().fit(motions)
    flat = motions.reshape(-1, 18)
    np.testing.assert_allclose(scaler.mean.numpy(), flat.mean(0), rtol=1e-5, atol=1e-6)
    # eq. 5.1: one σ² per variable (θ, θ̇, τ of the master), pooled over the three joints
    for v in range(3):
        expected = flat[:, 3 * v : 3 * v + 3].var(ddof=1)
        np.testing.assert_allclose(scaler.variance.numpy()[3 * v : 3 * v + 3], expected, rtol=1e-5)

    variance = torch.tensor([4.0] * 3 + [1.0] * 3 + [0.01] * 3)
    target = torch.zeros(2, 3, 9)
    command = target.clone()
    command[0, 0, 0] = 2.0  # θ error 2 rad:  4 / 4 = 1
    command[1, 2, 4] = 1.0  # θ̇ error 1 rad/s: 1 / 1 = 1
    command[1, 1, 8] = 0.1  # τ error 0.1 N m: 0.01 / 0.01 = 1
    assert motion_loss(command, target, variance).item() == pytest.approx(3.0 / 6.0)  # mean over B·K = 6
    with pytest.raises(ValueError, match="equal shape"):
        motion_loss(command[:, :, :8], target[:, :, :8], variance)


def test_save_load_round_trip(tmp_path):
    policy = _policy()
    policy.config.training = {"note": "round trip"}
    policy.save_pretrained(tmp_path / "p")
    config = json.loads((tmp_path / "p" / "config.json").read_text())
    assert config["task"] == "pushing" and config["policy"]["kind"] == "proposed"
    assert {k: config["policy"]["seqae"][k] for k in ("layers", "hidden", "latent")} == {
        "layers": 2,
        "hidden": 8,
        "latent": 8,
    }
    loaded = PushingPolicy.from_pretrained(tmp_path / "p")
    assert loaded.config.training == {"note": "round trip"}
    for key, value in policy.state_dict().items():
        torch.testing.assert_close(loaded.state_dict()[key], value)
    image = np.random.default_rng(2).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    np.testing.assert_array_equal(loaded.latent(image), policy.latent(image))
    import seqmotion as sm

    assert isinstance(sm.load(tmp_path / "p"), PushingPolicy)
    _policy("end_to_end").save_pretrained(tmp_path / "e")
    assert PushingPolicy.from_pretrained(tmp_path / "e").encoder is None


def test_corrupt_or_mismatched_checkpoints(tmp_path):
    _policy().save_pretrained(tmp_path / "p")
    weights = tmp_path / "p" / "model.safetensors"
    blob = bytearray(weights.read_bytes())
    blob[-5] ^= 0xFF
    weights.write_bytes(bytes(blob))
    with pytest.raises(CheckpointError, match="hash mismatch"):
        PushingPolicy.from_pretrained(tmp_path / "p")
    weights.unlink()
    with pytest.raises(CheckpointError, match="no model.safetensors"):
        PushingPolicy.from_pretrained(tmp_path / "p")

    _policy().save_pretrained(tmp_path / "q")
    cfg_path = tmp_path / "q" / "config.json"
    config = json.loads(cfg_path.read_text())
    config["policy"]["seqae"]["hidden"] = 9  # weights no longer fit
    cfg_path.write_text(json.dumps(config))
    with pytest.raises(CheckpointError, match="config_sha256"):  # an edited config no longer matches its hash
        PushingPolicy.from_pretrained(tmp_path / "q")

    def resealed() -> None:  # re-hashed after each edit, so what is behind the hash is what refuses it
        config["config_sha256"] = config_digest(config)
        cfg_path.write_text(json.dumps(config))

    resealed()  # the shapes refuse it
    with pytest.raises(CheckpointError, match="do not fit"):
        PushingPolicy.from_pretrained(tmp_path / "q")
    config["policy"]["kind"] = "telepathy"
    resealed()
    with pytest.raises(CheckpointError, match="does not describe a pushing policy"):
        PushingPolicy.from_pretrained(tmp_path / "q")
    config["task"] = "pancake"
    resealed()
    with pytest.raises(CheckpointError, match="not 'pushing'"):
        PushingPolicy.from_pretrained(tmp_path / "q")
    cfg_path.write_text("{not json")
    with pytest.raises(CheckpointError, match="not valid JSON"):
        PushingPolicy.from_pretrained(tmp_path / "q")
    assert issubclass(CheckpointError, ValueError)


def test_joint_count_comes_from_the_config(tmp_path):
    """J = 2: 12 motion columns, 6 decoder inputs and outputs, σ² pooled over the 2 joints; saved and loaded as
    a SeqAE-only model; a config without ``joints`` (every model saved before it existed) is the 3-joint arm."""
    two = dataclasses.replace(TINY, joints=2)
    motions = _motions(4, 10)[..., np.r_[0:2, 3:5, 6:8, 9:11, 12:14, 15:17]]  # (4, 10, 12): joints 0, 1
    torch.manual_seed(0)
    model = SeqAE(two)
    model.scaler.fit(motions)
    command, z = model(torch.as_tensor(motions, dtype=torch.float32))
    assert command.shape == (4, 9, 6) and z.shape == (4, 8) and two.slave == slice(6, 12)
    flat = motions.reshape(-1, 12)
    for v in range(3):  # θ, θ̇, τ of the master: columns 2v, 2v + 1
        np.testing.assert_allclose(model.scaler.variance.numpy()[2 * v : 2 * v + 2],
                                   flat[:, 2 * v : 2 * v + 2].var(ddof=1), rtol=1e-5)
    with pytest.raises(ValueError, match=r"\(K, 12\) or \(B, K, 12\) \(2 joints\)"):
        networks.check_motions(_motions(1, 10), joints=2)

    policy = PushingPolicy(PolicyConfig("seqae", "tiny", dataclasses.asdict(two)), model)
    assert policy.cnn is None and policy.encode(motions).shape == (4, 8)
    policy.save_pretrained(tmp_path / "two")
    loaded = PushingPolicy.from_pretrained(tmp_path / "two")
    assert loaded.seqae_config == two and loaded.config.kind == "seqae"
    np.testing.assert_array_equal(loaded.encode(motions), policy.encode(motions))
    with pytest.raises(ValueError, match="takes no CNN"):
        PushingPolicy(PolicyConfig("seqae", "tiny", dataclasses.asdict(two)), model, ImageEncoder(CNNConfig()))

    _policy().save_pretrained(tmp_path / "old")  # the 3-joint arm, its config.json as an older version wrote it
    cfg_path = tmp_path / "old" / "config.json"
    config = json.loads(cfg_path.read_text())
    assert config["policy"]["seqae"].pop("joints") == 3
    config["config_sha256"] = config_digest(config)
    cfg_path.write_text(json.dumps(config))
    old = PushingPolicy.from_pretrained(tmp_path / "old")
    assert old.seqae_config.joints == 3
    np.testing.assert_array_equal(old.encode(_motions(2, 10)), _policy().encode(_motions(2, 10)))

def test_cnn_learns_a_tiny_image_to_latent_mapping():
    """Six images of a bright square at six places → six distinct latents, fitted by train_cnn."""
    from seqmotion.lfd.train import CNNTraining, train_cnn

    images = np.full((6, 64, 64, 3), 60, dtype=np.uint8)
    for i in range(6):
        images[i, 24:40, 4 + 9 * i : 14 + 9 * i] = (230, 160, 90)
    targets = np.random.default_rng(0).normal(size=(6, 8))
    cnn, history = train_cnn(
        images, targets, CNNConfig(channels=(8, 8, 16, 16, 16)), CNNTraining(epochs=150, batch_size=6, lr=3e-3, seed=0)
    )
    assert history["loss"][-1] < 0.02 * history["loss"][0]
    with torch.no_grad():
        predicted = cnn(torch.as_tensor(images)).numpy()
    error = np.linalg.norm(predicted - targets, axis=1)
    assert error.max() < 0.35 * np.linalg.norm(targets, axis=1).min()


def test_decoder_drives_the_slave():
    pushing = pytest.importorskip("seqmotion.lfd.env.pushing")
    from seqmotion.lfd.rollout import run_autonomous

    policy = _policy()
    scene = pushing.PushingScene()
    try:
        source = policy.source(np.zeros(8))
        run = run_autonomous(scene, source, pushing.POSITIONS[1], duration=0.2)
        assert source.calls == 10  # one decoder step per 20 ms
        assert np.all(np.isfinite(run.slave_theta)) and np.all(np.isfinite(run.command_theta))
        # the commands are the decoder's (not the initial hold), and the slave responds
        assert np.abs(run.command_theta[-1] - run.command_theta[0]).max() > 0 or np.any(run.command_tau != 0)
        from seqmotion.lfd.rollout import run_episode

        run2, image, z = run_episode(scene, policy, pushing.POSITIONS[4], duration=0.1)
        assert image.shape == (64, 64, 3) and z.shape == (8,) and len(run2.slave_theta) == 100
        np.testing.assert_array_equal(z, policy.latent(image))  # the CNN's ẑ of the first image
        # the same episode by select_action, one decision at a time, as any controller is driven
        again, _, z_again = run_episode(scene, policy, pushing.POSITIONS[4], duration=0.1, latent=z)
        np.testing.assert_array_equal(again.command_theta, run2.command_theta)
        np.testing.assert_array_equal(z_again, z)
    finally:
        scene.close()
    with pytest.raises(ValueError, match="expected 0.0200 s"):
        s = policy.source(np.zeros(8))
        from seqmotion.lfd.env.teleop import ArmState

        state = ArmState(np.zeros(3), np.zeros(3), np.zeros(3))
        s(0.0, state)
        s(0.04, state)


def test_all_layers_readout_reaches_z_from_a_deep_stack():
    """At its initial weights a 10-layer encoder's top barely varies with the motion; reading every layer does."""
    motions = np.cumsum(_motions(n=32, k=50), axis=1)
    spread = {}
    for readout in networks.READOUTS:
        torch.manual_seed(0)
        seqae = SeqAE(SeqAEConfig(layers=10, hidden=16, readout=readout))
        seqae.scaler.fit(motions)
        with torch.no_grad():
            spread[readout] = seqae.encode(torch.as_tensor(motions, dtype=torch.float32)).std(0).mean().item()
    assert spread["top"] < 1e-4  # below any latent noise of training: z would carry nothing
    assert spread["all_layers"] > 1e-2
    assert networks.preset("larger").readout == "all_layers"


def test_bad_arguments():
    with pytest.raises(ValueError, match="layers"):
        SeqAEConfig(layers=0)
    with pytest.raises(ValueError, match="readout"):
        SeqAEConfig(readout="middle")
    with pytest.raises(ValueError, match="unknown model preset 'huge'"):
        networks.preset("huge")
    with pytest.raises(ValueError, match="channels"):
        CNNConfig(channels=(8, 8))
    with pytest.raises(ValueError, match="unknown policy kind"):
        PolicyConfig(kind="mystery")
    policy = _policy()
    with pytest.raises(ValueError, match=r"images must be \(64, 64, 3\)"):
        policy.latent(np.zeros((32, 32, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match=r"\[0, 255\]"):
        policy.latent(np.full((64, 64, 3), 300.0))
    with pytest.raises(ValueError, match="NaN"):
        policy.encode(np.full((5, 18), np.nan))
    with pytest.raises(ValueError, match="K = 2"):
        policy.encode(np.zeros((1, 18)))
    with pytest.raises(ValueError, match=r"\(K, 18\)"):
        policy.encode(np.zeros((5, 17)))
    with pytest.raises(ValueError, match="z must be 8 finite"):
        policy.source(np.zeros(3))
    with pytest.raises(ValueError, match="no motion encoder"):
        _policy("end_to_end").encode(_motions(1, 5)[0])


def test_policy_follows_the_model_contract(tmp_path):
    """PushingPolicy is a PretrainedModel; the pushing task comes from seqmotion's own entry point."""
    import seqmotion as sm
    from seqmotion import tasks
    from seqmotion.lfd.task import TASK
    from seqmotion.training.pretrained import PretrainedModel

    policy = _policy("end_to_end")
    assert isinstance(policy, PretrainedModel) and PushingPolicy.task == "pushing"
    assert PushingPolicy.config_class is PolicyConfig
    expected = {"task": "pushing", "model": "PushingPolicy", "policy": dataclasses.asdict(policy.config)}
    assert policy.config_json() == expected
    policy.config.training = {
        "command": "seqmotion lfd train --methods end_to_end",
        "seed": 4,
        "machine": {"processor": "Test CPU", "cpus": 3, "torch_threads": 1, "torch": "x", "platform": "Plan9"},
        "end_to_end": {"settings": {"epochs": 2}, "pairs": 5, "of": 6, "dataset": "d.h5", "seconds": 12.0,
                       "final_loss": 0.5},
    }
    card = policy.model_card("e2e-test", None, "", 1.25)
    assert "kind `end_to_end`" in card and "every 20 ms" in card and "Weights: 1.25 MB" in card
    assert "sm.load_pretrained('e2e-test')" in card
    assert "- End to end: CNN and decoder trained together on 5 of 6" in card
    assert "- Machine: Test CPU, 3 cores, 1 torch threads; torch x (Plan9)" in card
    assert tasks.get("pushing") is TASK and TASK.model_class is PushingPolicy
    policy.save_pretrained(tmp_path / "e")
    assert isinstance(sm.load(tmp_path / "e"), PushingPolicy)
    with pytest.raises(ValueError, match="seqmotion lfd train"):
        tasks.train(dataclasses.replace(tasks.get("pancake").train_config("tiny"), task="pushing"), tmp_path / "x")
