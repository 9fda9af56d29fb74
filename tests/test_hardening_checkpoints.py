"""Hardening (issue 31) of checkpoints and run directories: both integrity hashes are required, the run lock
opens no symlink or special file, and a config's scales agree with the weights' buffers."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file, save_file

import seqmotion as sm
from seqmotion import tasks
from seqmotion.cli import main
from seqmotion.tasks import train
from seqmotion.training import checkpoint as ckpt


def _saved(deformer, directory: Path) -> Path:
    """The shipped pancake model saved afresh (sealed with both hashes) into ``directory``."""
    return deformer.save_pretrained(directory)


def _rewrite(directory: Path, config: dict) -> None:
    (directory / ckpt.CONFIG).write_text(json.dumps(config))


# --- item 11: both hashes required --------------------------------------------------------------------


def test_an_edited_config_without_its_config_hash_is_refused(tmp_path, deformer):
    """Item 11: deleting config_sha256 and editing μ loaded the model with the edited μ."""
    saved = _saved(deformer, tmp_path / "m")
    config = json.loads((saved / ckpt.CONFIG).read_text())
    config["training"]["options"]["mu"] = 0.1  # valid, but not what the model was trained with
    del config["config_sha256"]
    _rewrite(saved, config)
    with pytest.raises(sm.CheckpointError, match="no config_sha256"):
        sm.load(saved)


def test_swapped_weights_without_their_hash_are_refused(tmp_path, deformer):
    """Item 11: another model's weights with weights_sha256 deleted (and the config re-hashed) loaded."""
    saved = _saved(deformer, tmp_path / "m")
    other = {k: v.clone() for k, v in deformer.weights().items()}
    other["head.net.0.bias"] += 0.5  # a different model of the same architecture
    save_file(other, saved / ckpt.WEIGHTS)
    config = json.loads((saved / ckpt.CONFIG).read_text())
    del config["weights_sha256"]
    config["config_sha256"] = ckpt.config_digest(config)  # the config's own hash still holds
    _rewrite(saved, config)
    with pytest.raises(sm.CheckpointError, match="no weights_sha256"):
        sm.load(saved)
    with pytest.raises(sm.CheckpointError, match="no weights_sha256"):
        ckpt.read_config(saved)
    assert not ckpt.model_is_complete(saved)


@pytest.mark.parametrize("name", sm.pretrained_models())
def test_every_shipped_model_carries_both_hashes(name):
    """Item 11: the shipped models are re-sealed (both hashes) and still load; their weights are untouched."""
    directory = sm.api.pretrained_dir(name)
    config = json.loads((directory / ckpt.CONFIG).read_text())
    assert config["config_sha256"] == ckpt.config_digest(config)
    assert config["weights_sha256"] == hashlib.sha256((directory / ckpt.WEIGHTS).read_bytes()).hexdigest()
    sm.load_pretrained(name)


def test_training_writes_both_hashes(tmp_path):
    """Item 11: a run's model and its training checkpoints carry both hashes (so they load under the rule)."""
    run = tmp_path / "run"
    train(tasks.get("pancake").train_config("tiny"), run, progress=False, stop_at_step=2)
    for directory in (run, ckpt.latest_checkpoint(run)):
        config = ckpt.read_config(directory)
        assert config["config_sha256"] and config["weights_sha256"]
    sm.load(run)


# --- item 12: the run lock ----------------------------------------------------------------------------


def _special_lock(kind: str, lock: Path, victim: Path) -> None:
    if kind == "symlink":
        lock.symlink_to(victim)
    elif kind == "hard link":
        os.link(victim, lock)
    elif kind == "fifo":
        os.mkfifo(lock)
    else:
        lock.mkdir()


@pytest.mark.parametrize("kind", ["symlink", "hard link", "fifo", "directory"])
def test_a_lock_that_is_not_a_plain_file_is_refused_and_left_alone(tmp_path, capsys, kind):
    """Item 12: `ln -s victim.txt runs/x/.lock` then `seqmotion train … --out runs/x` truncated victim.txt."""
    run = tmp_path / "run"
    run.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_bytes(b"precious bytes\n")
    _special_lock(kind, run / ckpt.LOCK, victim)
    with pytest.raises(sm.CheckpointError, match=r"\.lock is not a regular file"):
        ckpt.RunLock(run).acquire()
    assert main(["train", "pancake", "--config", "tiny", "--out", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert ".lock is not a regular file" in err and len(err.strip().splitlines()) == 1
    assert victim.read_bytes() == b"precious bytes\n"
    assert not (run / "checkpoints").exists()


def test_a_plain_lock_left_behind_is_reused(tmp_path):
    """A regular .lock a finished (or killed) training left is taken again, and holds this process's pid."""
    run = tmp_path / "run"
    run.mkdir()
    (run / ckpt.LOCK).write_text("12345\n")
    with ckpt.RunLock(run):
        assert (run / ckpt.LOCK).read_text() == f"{os.getpid()}\n"


# --- item 14: config scales vs the weights' buffers -------------------------------------------------------


SCALES = {  # config field → buffer (the tensor in model.safetensors)
    "output_scale": "head.scale",
    "output_offset": "head.offset",
    "encoder_input_scale": "encoder_scale",
    "decoder_input_scale": "decoder_scale",
}


@pytest.mark.parametrize("field", list(SCALES))
def test_config_scales_that_disagree_with_the_buffers_are_refused(tmp_path, deformer, field):
    """Item 14: output_scale ×1000 in a re-hashed config loaded; the stop's accel_limit said 1e4/1e5 while the
    model computed with the buffer's 10/100."""
    saved = _saved(deformer, tmp_path / "m")
    config = json.loads((saved / ckpt.CONFIG).read_text())
    buffer = deformer.weights()[SCALES[field]].tolist()
    config["model"][field] = [v * 1000 + (1.0 if field == "output_offset" else 0.0) for v in buffer]
    config["config_sha256"] = ckpt.config_digest(config)  # hashed properly: only the scales are wrong
    _rewrite(saved, config)
    with pytest.raises(sm.CheckpointError, match=f"{field}.*{SCALES[field]}"):
        sm.load(saved)


def test_buffers_that_disagree_with_the_config_are_refused(tmp_path, deformer):
    """Item 14, the other way round: weights whose scale buffer was changed (and re-hashed) are refused too."""
    saved = _saved(deformer, tmp_path / "m")
    tensors = load_file(saved / ckpt.WEIGHTS)
    tensors["head.scale"] = tensors["head.scale"] * 1000
    save_file(tensors, saved / ckpt.WEIGHTS)
    config = json.loads((saved / ckpt.CONFIG).read_text())
    config["weights_sha256"] = hashlib.sha256((saved / ckpt.WEIGHTS).read_bytes()).hexdigest()
    config["config_sha256"] = ckpt.config_digest(config)
    _rewrite(saved, config)
    with pytest.raises(sm.CheckpointError, match="output_scale.*head.scale"):
        sm.load(saved)


def test_the_stop_limit_is_the_scale_the_model_computes_with(deformer):
    """Item 14: what the contract reports is what the network uses (the shipped model agrees with itself)."""
    limit = deformer.generator(sm.tasks.pancake.data.straight((0.1, 0.0, 1.0), 200)).contract()["stop"]["accel_limit"]
    assert limit == pytest.approx(deformer.model.head.scale.tolist())


def test_the_scale_check_allows_float_rounding():
    """A model in float64 holds the float32-rounded config scales: that is agreement, not a mismatch."""
    from seqmotion.models.seq2seq import ChunkedSeq2Seq, Seq2SeqConfig

    cfg = Seq2SeqConfig(6, 6, 3, chunk=5, layers=1, hidden=8, output_scale=[0.1, 0.3, 7.7])
    state = ChunkedSeq2Seq(cfg).double().state_dict()
    fresh = ChunkedSeq2Seq(cfg)
    fresh.load_state_dict(state)
    assert torch.equal(fresh.head.scale, state["head.scale"].float())
