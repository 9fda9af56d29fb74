"""Hardening (issue 19) of training runs: metrics survive, run directories are complete or absent and
locked, settings are checked after every override, data-parallel coins do not depend on the rank."""

from __future__ import annotations

import csv
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import torch

import seqmotion as sm
from seqmotion import io, tasks
from seqmotion.errors import RunInUseError
from seqmotion.tasks import train
from seqmotion.training import checkpoint as ckpt
from seqmotion.training.curriculum import Curriculum
from seqmotion.training.loop import MetricsLog


def tiny(epochs: int | None = None, **changes):
    """The pancake's tiny preset (2 steps per epoch), squeezed to ``epochs`` epochs if given."""
    cfg = tasks.get("pancake").train_config("tiny")
    if epochs is not None:
        cfg.curriculum = Curriculum.from_dict(cfg.curriculum).scaled(epochs).to_dict()
    for k, v in changes.items():
        setattr(cfg, k, v)
    return cfg


def steps_logged(run: Path) -> list[int]:
    with open(run / "metrics.csv", newline="") as f:
        return [int(r["step"]) for r in csv.DictReader(f)]


# --- item 2: metrics.csv ------------------------------------------------------------------------------


class Stop(Exception):
    pass


def test_metrics_survive_a_crash_before_the_next_checkpoint(tmp_path, monkeypatch):
    """Item 2: a resumed run reopened metrics.csv with "w" and flushed at checkpoints only: killed before its
    next checkpoint, the log was 0 bytes and the history gone for good."""
    run = tmp_path / "run"
    train(tiny(5, checkpoint_every=4), run, progress=False, stop_at_step=6)
    assert steps_logged(run) == list(range(1, 7))
    task = tasks.get("pancake")
    loss = task.loss
    calls = []

    def crash_at_step_9(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:  # steps 7, 8 done (no checkpoint until 12), the process dies in step 9
            raise Stop
        return loss(*args, **kwargs)

    monkeypatch.setattr(task, "loss", crash_at_step_9)
    with pytest.raises(Stop):
        train(tiny(5, checkpoint_every=4), run, progress=False)
    assert steps_logged(run) == list(range(1, 9))
    monkeypatch.setattr(task, "loss", loss)
    train(tiny(5, checkpoint_every=4), run, progress=False)
    assert steps_logged(run) == list(range(1, 11))


def test_metrics_log_drops_rows_a_kill_cut_short(tmp_path):
    path = tmp_path / "metrics.csv"
    path.write_text("step,epoch,loss\n1,1,0.5\n2,1,0.4\n2,1,0.4\n3,1,0.3\n1")  # a duplicate; "1" of "15,1,…"
    MetricsLog(path, keep_before=3).close()
    assert path.read_text().splitlines() == ["step,epoch,loss", "1,1,0.5", "2,1,0.4", "3,1,0.3"]


# --- item 3: run directories --------------------------------------------------------------------------


def test_a_kill_between_weights_and_config_leaves_a_loadable_run_that_the_rerun_repairs(tmp_path, monkeypatch):
    """Item 3: a kill between the run's model.safetensors and config.json left `sm.load(run)` failing for
    good (hash mismatch), and rerunning the command exited 0 without repairing it."""
    run = tmp_path / "run"
    cfg = tiny(3, checkpoint_every=4)
    total = cfg.epochs * cfg.batches_per_epoch
    real = ckpt.atomic_write_bytes

    def die_before_the_config(path, data):
        if Path(path) == run / ckpt.CONFIG and b'"step": %d' % total in data:
            raise Stop  # the weights of the last step are in place, the config is not
        real(path, data)

    monkeypatch.setattr(ckpt, "atomic_write_bytes", die_before_the_config)
    with pytest.raises(Stop):
        train(cfg, run, progress=False)
    monkeypatch.setattr(ckpt, "atomic_write_bytes", real)
    assert not ckpt.model_is_complete(run)
    model = sm.load(run)  # the run's latest checkpoint: complete by construction
    assert model.config["step"] == total
    train(cfg, run, progress=False)  # nothing left to train: the rerun repairs the top level
    assert ckpt.model_is_complete(run) and ckpt.resolve_model_dir(run) == run
    assert ckpt.read_config(run)["step"] == total
    latest = ckpt.latest_checkpoint(run)
    assert (run / ckpt.WEIGHTS).read_bytes() == (latest / ckpt.WEIGHTS).read_bytes()


def test_loading_a_run_while_it_trains_never_fails(tmp_path):
    """Item 3: `sm.load(run)` polled while a run trained failed transiently (307 hash-mismatch errors).

    The training runs in a thread (PyTorch releases the GIL in its kernels) and writes a checkpoint and the
    run's model at every step; the test polls `sm.load(run)` as fast as it can meanwhile."""
    run = tmp_path / "run"
    cfg = tiny(4, checkpoint_every=1)
    errors = []

    def training():
        try:
            train(cfg, run, progress=False)
        except Exception as exc:  # pragma: no cover - reported below
            errors.append(exc)

    worker = threading.Thread(target=training)
    worker.start()
    loads, failures = 0, []
    while worker.is_alive():
        if not (run / ckpt.LATEST).exists():
            time.sleep(0.001)
            continue
        try:
            sm.load(run)
            loads += 1
        except (sm.CheckpointError, ValueError) as exc:
            failures.append(str(exc))
    worker.join()
    assert not errors and loads > 5 and not failures, (loads, failures[:3])


def test_a_second_training_into_a_run_is_refused_by_name(tmp_path, capsys):
    """Item 3: two trainings into one run directory raced (one crashed deleting the other's checkpoints)."""
    run = tmp_path / "run"
    run.mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c", "import fcntl, os, sys, time; fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT);"
         "fcntl.flock(fd, fcntl.LOCK_EX); os.write(fd, b'4242'); print('locked', flush=True); time.sleep(60)",
         str(run / ckpt.LOCK)], stdout=subprocess.PIPE)
    try:
        assert holder.stdout.readline().strip() == b"locked"
        with pytest.raises(RunInUseError, match="another training"):
            train(tiny(), run, progress=False)
        from seqmotion.cli import main

        assert main(["train", "pancake", "--config", "tiny", "--out", str(run), "--quiet"]) == 2
        assert "being written by another training" in capsys.readouterr().err
    finally:
        holder.kill()
        holder.wait()
    assert not (run / "checkpoints").exists()
    train(tiny(), run, progress=False, stop_at_step=2)  # the holder is gone: the lock went with it
    with ckpt.RunLock(run):  # and in one process, a lock is a lock too
        with pytest.raises(RunInUseError):
            train(tiny(), run, progress=False)
    train(tiny(), run, progress=False, stop_at_step=3)  # a refused or failed training leaves no lock behind


def test_leftovers_of_a_killed_run_are_removed(tmp_path):
    """Item 3: `.step-*.tmp-PID` directories of killed runs were never cleaned."""
    run = tmp_path / "run"
    train(tiny(), run, progress=False, stop_at_step=2)
    stale = [run / "checkpoints" / f".step-00000003{io.TEMP_MARK}99999999",
             run / f".model{io.TEMP_MARK}1-ab.safetensors", run / f".metrics{io.TEMP_MARK}99999999-cd.csv"]
    stale[0].mkdir()
    (stale[0] / "model.safetensors").write_bytes(b"half")
    stale[1].write_bytes(b"half")
    stale[2].write_bytes(b"half")
    train(tiny(), run, progress=False, stop_at_step=3)
    assert not any(p.exists() for p in stale)
    assert not [p for p in run.rglob("*") if io.TEMP_MARK in p.name]


def test_no_resume_starts_over_without_old_checkpoints(tmp_path):
    run = tmp_path / "run"
    train(tiny(checkpoint_every=2), run, progress=False, stop_at_step=4)
    train(tiny(checkpoint_every=2), run, progress=False, stop_at_step=2, resume=False)
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["step-00000002"]
    assert steps_logged(run) == [1, 2] and sm.load(run).config["step"] == 2


def test_a_new_model_directory_appears_whole(tmp_path, monkeypatch):
    """save_pretrained into a new directory: complete or absent, whatever fails."""
    model = sm.load_pretrained("pancake")
    real = ckpt.write_durable

    def fail_on_config(path, data):
        if path.name == ckpt.CONFIG:
            raise OSError(28, "No space left on device")
        real(path, data)

    monkeypatch.setattr(ckpt, "write_durable", fail_on_config)
    with pytest.raises(OSError):
        model.save_pretrained(tmp_path / "new")
    assert not (tmp_path / "new").exists() and not list(tmp_path.iterdir())


# --- item 8: settings checked after overrides ----------------------------------------------------------


@pytest.mark.parametrize("changes", [{"lr": 0.0}, {"lr": float("nan")}, {"lr_final_fraction": 5.0},
                                     {"batches_per_epoch": 0}, {"batch_size": -1}, {"batch_size": 2.5},
                                     {"checkpoint_every": 0}, {"seed": -3}, {"keep_checkpoints": 0},
                                     {"grad_clip": float("inf")}, {"curriculum": {"epochs": 0}}])
def test_settings_changed_after_construction_are_checked(tmp_path, changes):
    """Item 8: values set after __post_init__ (as the CLI did) skipped the checks."""
    with pytest.raises(ValueError):
        train(tiny(**changes), tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("stop", [0, -5, 1.5])
def test_max_steps_must_be_positive(tmp_path, stop):
    with pytest.raises(ValueError, match="stop_at_step"):
        train(tiny(), tmp_path / "run", progress=False, stop_at_step=stop)


# --- item 13: data-parallel coins ----------------------------------------------------------------------


def test_rank_slices_of_the_coins_are_the_single_process_coins():
    """Item 13 (the mechanism; tests/test_training.py runs 2 gloo ranks against one process): a rank that holds
    trajectories r, r + N, … of the batch gets exactly their single-process scheduled-sampling coins."""
    from seqmotion.models.seq2seq import ChunkedSeq2Seq, Seq2SeqConfig, rollout
    from seqmotion.physics.integrator import DoubleIntegratorDynamics
    from seqmotion.training.trainer import _RankSlice

    torch.manual_seed(0)
    model = ChunkedSeq2Seq(Seq2SeqConfig(6, 6, 3, chunk=5, layers=1, hidden=8))
    teacher = torch.randn(4, 31, 6, dtype=torch.float64) * 0.01
    z = torch.randn(4, 8)

    def run(index, rank=None):
        coins = torch.Generator().manual_seed(1234)
        args = (model, z[index], teacher[index, 0], DoubleIntegratorDynamics(3), 6)
        kwargs = {"teacher": teacher[index], "teacher_forcing_prob": 0.5, "generator": coins}
        if rank is None:
            return rollout(*args, **kwargs).states
        with _RankSlice(coins, rank, 2):
            return rollout(*args, **kwargs).states

    with torch.no_grad():
        whole = run(slice(None))
        for rank in (0, 1):  # equal up to float32 rounding of the smaller batch's kernels
            torch.testing.assert_close(run(slice(rank, None, 2), rank), whole[rank::2], rtol=1e-5, atol=1e-9)
        # without the slice a rank's own draws are other coins: other states
        assert float((run(slice(1, None, 2)) - whole[1::2]).abs().max()) > 1e-5


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_a_non_finite_loss_stops_the_loop_before_it_reaches_the_weights(bad):
    """Every training runs on the one loop, which refuses a non-finite loss (FloatingPointError, which the CLI
    reports in one line, exit 1) before its backward pass: the weights stay as they were, never NaN."""
    from seqmotion.training.loop import TrainingLoop

    layer = torch.nn.Linear(3, 2)
    before = {k: v.clone() for k, v in layer.state_dict().items()}
    loop = TrainingLoop(layer, layer.parameters(), lr=1e-2, total_steps=4)
    loop.step(layer(torch.ones(1, 3)).pow(2).mean())  # a finite step moves the weights
    moved = {k: v.clone() for k, v in layer.state_dict().items()}
    assert any(not torch.equal(before[k], moved[k]) for k in before)
    with pytest.raises(FloatingPointError, match="non-finite loss at step 1 .epoch 3."):
        loop.step(layer(torch.ones(1, 3)).sum() * bad, about=" (epoch 3)")
    assert all(torch.equal(moved[k], v) for k, v in layer.state_dict().items())
    assert loop.steps == 1
