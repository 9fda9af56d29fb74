"""Curriculum, loss, checkpoints, exact resume and data-parallel training on tiny configs."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion import tasks
from seqmotion.tasks import train
from seqmotion.tasks.pancake import chapter2_curriculum
from seqmotion.training import checkpoint as ckpt
from seqmotion.training.curriculum import Curriculum, Stage
from seqmotion.training.loop import cosine_learning_rate
from seqmotion.training.losses import gaussian_nll_1d, gaussian_nll_2d


def test_chapter2_schedule_matches_the_dissertation():
    c = chapter2_curriculum()
    assert c.at(1) == {"teacher_forcing_prob": 1.0, "phi_max": math.pi / 4, "accel_type_prob": 1.0}
    assert c.at(10, 0.99)["teacher_forcing_prob"] == 1.0
    assert c.at(16)["teacher_forcing_prob"] == pytest.approx(0.5)  # ramp runs from start of 11 to end of 20
    assert c.at(21)["teacher_forcing_prob"] == 0.0
    assert c.at(36)["phi_max"] == pytest.approx(math.pi / 4 + 0.5 * (3 * math.pi / 4))
    assert c.at(55)["phi_max"] == pytest.approx(math.pi)  # 51–60 continues 41–50
    assert c.at(60, 0.99)["accel_type_prob"] == 1.0
    assert c.at(70)["accel_type_prob"] == pytest.approx(0.55)
    assert c.at(85)["accel_type_prob"] == 0.0  # 81–90 continues 91–100
    assert Curriculum.from_dict(json.loads(json.dumps(c.to_dict()))) == c


def test_curriculum_scaling_keeps_order_and_end_values():
    c = chapter2_curriculum().scaled(10)
    assert c.epochs == 10
    assert c.at(1)["teacher_forcing_prob"] == 1.0
    assert c.at(10, 0.99) == {"teacher_forcing_prob": 0.0, "phi_max": math.pi, "accel_type_prob": 0.0}


def test_curriculum_rejects_bad_stages():
    with pytest.raises(ValueError, match="start"):
        Stage(5, 3)
    with pytest.raises(ValueError, match="initial"):
        Curriculum(10, {"a": 1.0}, [Stage(1, 2, {"b": 1.0})])
    with pytest.raises(ValueError, match="after the last"):
        Curriculum(10, {"a": 1.0}, [Stage(1, 12, {"a": 1.0})])


def test_nll_matches_reference_and_is_finite_at_zero_covariance():
    rng = np.random.default_rng(0)
    diff = torch.tensor(rng.normal(size=(50, 2)))
    l = torch.tensor(rng.normal(size=(50, 2, 2)))
    cov = l @ l.transpose(1, 2)
    ref = torch.distributions.MultivariateNormal(torch.zeros(2, dtype=torch.float64), cov + 1e-8 * torch.eye(2))
    torch.testing.assert_close(gaussian_nll_2d(diff, cov), -ref.log_prob(diff))
    zero = torch.zeros(3, 2, 2, dtype=torch.float32)
    assert torch.isfinite(gaussian_nll_2d(torch.full((3, 2), 0.3), zero)).all()
    assert torch.isfinite(gaussian_nll_1d(torch.full((3,), 0.3), torch.zeros(3))).all()


def tiny_config(**changes):
    cfg = tasks.get("pancake").train_config("tiny")
    for k, v in changes.items():
        setattr(cfg, k, v)
    return cfg


@pytest.mark.parametrize("lr_final_fraction", [1.0, 0.1])
def test_resume_continues_exactly(tmp_path, lr_final_fraction):
    cfg = tiny_config(lr_final_fraction=lr_final_fraction)
    train(cfg, tmp_path / "straight", progress=False)
    train(cfg, tmp_path / "split", progress=False, stop_at_step=9)
    train(cfg, tmp_path / "split", progress=False)
    _, a = ckpt.read_model(tmp_path / "straight")
    _, b = ckpt.read_model(tmp_path / "split")
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    rows = (tmp_path / "split" / "metrics.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + cfg.epochs * cfg.batches_per_epoch


def test_learning_rate_schedule():
    constant = tiny_config()
    assert {cosine_learning_rate(constant.lr, 1.0, s, 100) for s in (0, 37, 99, 100, 150)} == {constant.lr}
    rates = [cosine_learning_rate(1e-3, 0.1, s, 100) for s in range(101)]
    assert rates[0] == pytest.approx(1e-3) and rates[50] == pytest.approx(5.5e-4) and rates[100] == pytest.approx(1e-4)
    assert all(a >= b for a, b in zip(rates, rates[1:], strict=False))
    with pytest.raises(ValueError, match="lr_final_fraction"):
        tiny_config(lr_final_fraction=0.0).__post_init__()


def test_same_seed_same_model_other_seed_differs(tmp_path):
    train(tiny_config(), tmp_path / "a", progress=False, stop_at_step=3)
    train(tiny_config(), tmp_path / "b", progress=False, stop_at_step=3)
    train(tiny_config(seed=1), tmp_path / "c", progress=False, stop_at_step=3)
    _, a = ckpt.read_model(tmp_path / "a")
    _, b = ckpt.read_model(tmp_path / "b")
    _, c = ckpt.read_model(tmp_path / "c")
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)


def test_resume_refuses_a_different_configuration(tmp_path):
    train(tiny_config(), tmp_path, progress=False, stop_at_step=2)
    with pytest.raises(sm.CheckpointError, match="different configuration"):
        train(tiny_config(lr=0.5), tmp_path, progress=False)


def test_learning_reduces_the_loss(tmp_path):
    """A tiny autoencoder phase (teacher forcing on feasible inputs) must learn something."""
    cfg = tiny_config(batches_per_epoch=30, batch_size=16, lr=3e-3)
    initial = {"teacher_forcing_prob": 1.0, "phi_max": math.pi / 4, "accel_type_prob": 1.0}
    cfg.curriculum = Curriculum(2, initial).to_dict()
    train(cfg, tmp_path, progress=False)
    import csv

    with open(tmp_path / "metrics.csv") as f:
        losses = [float(r["loss"]) for r in csv.DictReader(f)]
    assert np.mean(losses[-10:]) < np.mean(losses[:10]) - 1.0


def test_checkpoint_errors(tmp_path):
    train(tiny_config(), tmp_path / "run", progress=False, stop_at_step=2)
    model_dir = tmp_path / "run"
    from seqmotion.tasks.pancake import Deformer

    assert isinstance(sm.load(model_dir), Deformer)
    with pytest.raises(sm.CheckpointError, match="not 'sliding'"):
        sm.load(model_dir, expected_task="sliding")
    # corrupt weights
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "config.json").write_text((model_dir / "config.json").read_text())
    (bad / "model.safetensors").write_bytes(b"\x00" * 64)
    with pytest.raises(sm.CheckpointError, match="hash mismatch|safetensors"):
        sm.load(bad)
    # corrupt config
    (bad / "config.json").write_text("{not json")
    with pytest.raises(sm.CheckpointError, match="JSON"):
        sm.load(bad)
    # weights that do not fit the architecture in the config
    cfg = json.loads((model_dir / "config.json").read_text())
    cfg["model"]["hidden"] = 32
    (bad / "config.json").write_text(json.dumps(cfg))
    (bad / "model.safetensors").write_bytes((model_dir / "model.safetensors").read_bytes())
    with pytest.raises(sm.CheckpointError, match="config_sha256"):  # the config is covered by its own hash
        sm.load(bad)
    cfg["config_sha256"] = ckpt.config_digest(cfg)  # re-hashed after the edit: the shapes are what refuses it
    (bad / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(sm.CheckpointError, match="do not fit"):
        sm.load(bad)
    with pytest.raises(sm.CheckpointError, match="does not exist"):
        sm.load(tmp_path / "nowhere")
    assert issubclass(sm.CheckpointError, ValueError)


def test_checkpoint_files_are_not_pickles(tmp_path):
    train(tiny_config(), tmp_path, progress=False, stop_at_step=2)
    latest = ckpt.latest_checkpoint(tmp_path)
    for name in ("model.safetensors", "optimizer.safetensors"):
        blob = (latest / name).read_bytes()
        header_len = int.from_bytes(blob[:8], "little")  # safetensors: u64 length, JSON header, raw data
        header = json.loads(blob[8 : 8 + header_len])
        assert all("dtype" in v for k, v in header.items() if k != "__metadata__")
    assert not list(tmp_path.rglob("*.tmp-*")), "temporary files left behind"


@pytest.mark.slow
def test_torchrun_two_processes_matches_one(tmp_path):
    """Data-parallel training over 2 gloo processes equals single-process training of the same batches,
    scheduled-sampling coins included (issue 19, item 13: the coins were seeded per rank, and the weights
    differed by 4e-3 after one epoch; now by float32 rounding, ~6e-8)."""
    import socket

    cfg = tiny_config(batch_size=8)
    initial = {"teacher_forcing_prob": 0.5, "phi_max": math.pi / 2, "accel_type_prob": 0.5}
    cfg.curriculum = Curriculum(1, initial).to_dict()
    config_path = tmp_path / "cfg.json"
    config_path.write_text(json.dumps(cfg.to_dict()))
    script = tmp_path / "run.py"
    script.write_text(
        "import json, sys\n"
        "from seqmotion.training.config import TrainConfig\n"
        "from seqmotion.tasks import train\n"
        "train(TrainConfig.from_dict(json.load(open(sys.argv[1]))), sys.argv[2], progress=False)\n"
    )
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(Path(sm.__file__).parents[1])}
    with socket.socket() as probe:  # a free port: a fixed one collides with other test runs on the machine
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node=2", f"--master_port={port}",
           str(script), str(config_path), str(tmp_path / "ddp")]
    subprocess.run(cmd, check=True, env=env, timeout=300, capture_output=True)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as the ranks (OMP_NUM_THREADS=1)
    try:
        train(cfg, tmp_path / "single", progress=False)
    finally:
        torch.set_num_threads(threads)
    _, a = ckpt.read_model(tmp_path / "ddp")
    _, b = ckpt.read_model(tmp_path / "single")
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-4, atol=1e-5)


def test_metrics_log_keeps_what_it_logged(tmp_path):
    """On resume the rows up to the checkpoint are on disk at once (not after the next checkpoint),
    and every new row is on disk as soon as it is written: a kill loses nothing already logged."""
    from seqmotion.training.loop import MetricsLog

    path = tmp_path / "metrics.csv"
    path.write_text("step,epoch,loss\n" + "".join(f"{s},1,{s / 10}\n" for s in range(1, 6)))
    log = MetricsLog(path, keep_before=3)  # resumed from the step-3 checkpoint
    assert path.read_text().splitlines() == ["step,epoch,loss", "1,1,0.1", "2,1,0.2", "3,1,0.3"]
    log.write({"step": 4, "epoch": 1, "loss": "0.45", "new_column": "ignored"})
    assert path.read_text().splitlines()[-1] == "4,1,0.45"  # flushed, not waiting for close()
    log.close()
    fresh = MetricsLog(path, keep_before=0)  # a run started over replaces the old log
    assert path.read_text() == ""
    fresh.write({"step": 1, "loss": "1"})
    fresh.close()
    assert path.read_text().splitlines() == ["step,loss", "1,1"]
