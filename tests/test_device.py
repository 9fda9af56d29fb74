"""The device path (issue 21): ``--device`` / ``device=`` for training, inference and latent optimisation;
device-independent checkpoints; devices refused by name. CUDA-only checks skip on a machine without one."""

import subprocess
import sys

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion import tasks
from seqmotion.tasks import train
from seqmotion.training import checkpoint as ckpt
from seqmotion.training.device import backend_for, process_device, resolve_device

needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


def tiny_config(**changes):
    cfg = tasks.get("pancake").train_config("tiny")
    for k, v in changes.items():
        setattr(cfg, k, v)
    return cfg


def test_resolve_device_names_and_refusals():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device(torch.device("cpu")) == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    assert resolve_device(None) == resolve_device("auto")
    for bad in ("gpu", "cuda:x", "cuda:-1", "tpu", "", "cpu:0x"):
        with pytest.raises(ValueError, match="unknown device"):
            resolve_device(bad)
    with pytest.raises(ValueError, match="device must be one of"):
        resolve_device(3)
    if not torch.cuda.is_available():
        for name in ("cuda", "cuda:0", "CUDA:1"):
            with pytest.raises(ValueError, match="needs a CUDA GPU"):
                resolve_device(name)
    else:
        with pytest.raises(ValueError, match="does not exist"):
            resolve_device(f"cuda:{torch.cuda.device_count()}")


def test_backend_follows_the_device_not_the_machine():
    assert backend_for(torch.device("cpu")) == "gloo"
    assert backend_for(torch.device("cuda", 0)) == "nccl"
    assert process_device(torch.device("cpu"), 4) == torch.device("cpu")


def test_explicit_cpu_run_is_the_default_run_and_checkpoints_are_cpu_tensors(tmp_path):
    train(tiny_config(), tmp_path / "auto", progress=False, stop_at_step=3)
    train(tiny_config(), tmp_path / "cpu", progress=False, stop_at_step=3, device="cpu")
    _, a = ckpt.read_model(tmp_path / "auto")
    _, b = ckpt.read_model(tmp_path / "cpu")
    if not torch.cuda.is_available():  # auto is the CPU here: the same run bit for bit
        assert all(torch.equal(a[k], b[k]) for k in a)
    latest = ckpt.latest_checkpoint(tmp_path / "cpu")
    _, tensors, optimizer, _ = ckpt.read_training_checkpoint(latest)
    assert all(t.device.type == "cpu" for t in tensors.values())
    assert all(t.device.type == "cpu" for slots in optimizer["state"].values() for t in slots.values()
               if torch.is_tensor(t))


def test_cli_device_cpu_trains_and_resumes(tmp_path):
    out = tmp_path / "run"
    base = [sys.executable, "-m", "seqmotion.cli", "train", "pancake", "--config", "tiny", "--out", str(out),
            "--quiet", "--device", "cpu"]
    subprocess.run(base + ["--max-steps", "2"], check=True, capture_output=True, text=True)
    subprocess.run(base + ["--max-steps", "4"], check=True, capture_output=True, text=True)
    config = ckpt.read_config(out)
    assert config["step"] == 4 and config["provenance"]["resumed_with"]["world_size"] == 1
    # the same four steps in one go: resuming with --device cpu continued exactly
    train(tiny_config(), tmp_path / "straight", progress=False, stop_at_step=4, device="cpu")
    _, a = ckpt.read_model(out)
    _, b = ckpt.read_model(tmp_path / "straight")
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_cli_refuses_a_bad_device_by_name(tmp_path):
    run = subprocess.run([sys.executable, "-m", "seqmotion.cli", "train", "pancake", "--config", "tiny", "--out",
                          str(tmp_path / "x"), "--quiet", "--device", "gpu0"], capture_output=True, text=True)
    assert run.returncode != 0 and "--device" in run.stderr and "unknown device 'gpu0'" in run.stderr
    assert not (tmp_path / "x" / "checkpoints").exists()


def test_api_refuses_bad_devices(tmp_path):
    with pytest.raises(ValueError, match="unknown device"):
        train(tiny_config(), tmp_path / "a", progress=False, stop_at_step=1, device="tpu")
    with pytest.raises(ValueError, match="unknown device"):
        sm.load_pretrained("pancake", device="npu")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="needs a CUDA GPU"):
            train(tiny_config(), tmp_path / "b", progress=False, stop_at_step=1, device="cuda")
        with pytest.raises(ValueError, match="needs a CUDA GPU"):
            sm.load_pretrained("pancake").to("cuda")


def test_checkpoint_loads_device_independently(tmp_path):
    train(tiny_config(), tmp_path / "run", progress=False, stop_at_step=2, device="cpu")
    model = sm.load(tmp_path / "run", device="cpu")
    assert model.device == torch.device("cpu")
    sketch = sm.tasks.pancake.data.straight((0.1, 0.0, 1.0), 40)
    plain = sm.load(tmp_path / "run").deform(sketch)
    moved = model.deform(sketch)
    np.testing.assert_array_equal(plain.states, moved.states)
    copy = model.on_device("cpu")
    assert copy is model  # already there: no copy


def test_latent_optimisation_takes_a_device():
    model = sm.load_pretrained("pancake")
    sketch = sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 200)
    target = sm.objectives.EndPose((0.1, 0.0, 3.0))
    a = sm.optimize_latent(model, sketch, target, steps=2)
    b = sm.optimize_latent(model, sketch, target, steps=2, device="cpu")
    np.testing.assert_array_equal(a.states, b.states)
    with pytest.raises(ValueError, match="unknown device"):
        sm.optimize_trajectory(model, sketch, target, steps=1, device="gpu")


@needs_cuda
def test_cuda_training_resumes_on_the_cpu(tmp_path):
    train(tiny_config(), tmp_path / "run", progress=False, stop_at_step=2, device="cuda")
    latest = ckpt.latest_checkpoint(tmp_path / "run")
    _, tensors, _, _ = ckpt.read_training_checkpoint(latest)
    assert all(t.device.type == "cpu" for t in tensors.values())
    assert ckpt.read_config(tmp_path / "run")["provenance"]["device"].startswith("cuda")
    train(tiny_config(), tmp_path / "run", progress=False, stop_at_step=4, device="cpu")
    assert ckpt.read_config(tmp_path / "run")["step"] == 4


@needs_cuda
def test_cuda_inference_matches_the_cpu():
    sketch = sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 300)
    cpu = sm.load_pretrained("pancake").deform(sketch)
    gpu_model = sm.load_pretrained("pancake", device="cuda")
    assert gpu_model.device.type == "cuda"
    gpu = gpu_model.deform(sketch)
    np.testing.assert_allclose(gpu.states, cpu.states, atol=1e-3)
    res = sm.optimize_latent(sm.load_pretrained("pancake"), sketch, sm.objectives.EndPose((0.1, 0.0, 3.0)), steps=2,
                             device="cuda")
    assert np.isfinite(res.states).all()
