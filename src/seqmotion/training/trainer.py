"""The training loop: curriculum → data → loss → Adam, with checkpoints, resume and data parallelism.

It reads top to bottom like the dissertation's procedure: for every mini-batch, look up the
curriculum's parameters, draw fresh trajectories from the task's generators, score the
model's free-running (or teacher-forced) rollout through the task's physics, step Adam.

**Determinism and exact resume.** Weights are initialised from ``seed``; the data and the
scheduled-sampling coin flips of step ``s`` are drawn from generators seeded by
``(seed, s)``, not from a running random state. A checkpoint therefore only needs the weights,
Adam's state and the step counter, and a resumed run continues bit for bit.

**Data parallelism.** Launched by ``torchrun --nproc_per_node=N``, every process draws the
same global batch, trains on its 1/N share, and the gradients are averaged with one
all-reduce per step (``gloo`` on CPU, ``nccl`` on GPUs), which equals the single-process
gradient of the whole batch. Rank 0 writes checkpoints and logs.
"""

from __future__ import annotations

import csv
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from tqdm import tqdm

from .. import tasks
from ..errors import CheckpointError
from ..tasks.base import TrainConfig
from . import checkpoint as ckpt
from .provenance import command_line, machine_description

METRICS = "metrics.csv"


def _distributed() -> tuple[int, int]:
    """Join the process group torchrun set up, if any; return ``(rank, world_size)``."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1
    if not dist.is_initialized():
        dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    return dist.get_rank(), dist.get_world_size()


def _average_gradients(params: list[torch.nn.Parameter], world: int) -> None:
    """All-reduce every gradient in one flat buffer and divide by the number of processes."""
    grads = [p.grad for p in params if p.grad is not None]
    flat = torch.cat([g.reshape(-1) for g in grads])
    dist.all_reduce(flat)
    flat /= world
    offset = 0
    for g in grads:
        g.copy_(flat[offset : offset + g.numel()].view_as(g))
        offset += g.numel()


def _same_run(saved: dict, current: TrainConfig) -> None:
    """Refuse to resume a run under a different configuration (only checkpoint cadence may differ)."""
    ignore = {"checkpoint_every", "keep_checkpoints"}
    a = {k: v for k, v in saved.items() if k not in ignore}
    b = {k: v for k, v in current.to_dict().items() if k not in ignore}
    if a != b:
        diff = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
        raise CheckpointError(f"cannot resume: the run was trained with a different configuration ({diff})")


def model_config(config: TrainConfig, extra: dict | None = None) -> dict:
    """The ``config.json`` of a trained model: task, architecture and how it was trained."""
    return {"task": config.task, "model": config.model, "training": config.to_dict(), **(extra or {})}


def learning_rate(config: TrainConfig, step: int, total: int) -> float:
    """Adam's learning rate at optimiser step ``step`` of ``total``: a cosine from ``lr`` to
    ``lr_final_fraction · lr`` (constant when the fraction is 1)."""
    low = config.lr * config.lr_final_fraction
    return low + (config.lr - low) * 0.5 * (1.0 + math.cos(math.pi * min(step, total) / total))


def train(
    config: TrainConfig,
    run_dir: str | Path,
    *,
    resume: bool = True,
    progress: bool = True,
    stop_at_step: int | None = None,
) -> Path:
    """Train (or continue training) a model; return the run directory.

    Args:
        config: the run's configuration.
        run_dir: where checkpoints (``checkpoints/``, ``latest``), the exported model
            (``model.safetensors`` + ``config.json``) and ``metrics.csv`` go.
        resume: continue from the run's latest checkpoint if there is one.
        progress: show a progress bar with the loss terms and the share of feasible outputs.
        stop_at_step: stop after this many optimiser steps in total (for timing and tests).
    """
    task = tasks.get(config.task)
    rank, world = _distributed()
    if config.batch_size % world:
        raise ValueError(f"batch_size {config.batch_size} is not divisible by {world} processes")
    run_dir = Path(run_dir)
    if rank == 0:
        run_dir.mkdir(parents=True, exist_ok=True)

    torch.manual_seed(config.seed)
    model = task.build_model(config)
    params = list(model.parameters())
    optimizer = torch.optim.Adam(params, lr=config.lr)
    curriculum = task.curriculum(config)
    bpe = config.batches_per_epoch
    total = curriculum.epochs * bpe
    every = config.checkpoint_every or bpe

    step, elapsed = 0, 0.0
    program = sys.argv[0]
    if program.endswith("seqmotion"):
        program = "seqmotion"
    elif program.endswith(os.path.join("seqmotion", "cli.py")):
        program = "python -m seqmotion.cli" if world == 1 else f"torchrun --nproc_per_node={world} -m seqmotion.cli"
    command = command_line(program)
    provenance = {"command": command, "machine": machine_description(), "world_size": world}
    latest = ckpt.latest_checkpoint(run_dir) if resume and run_dir.exists() else None
    if latest is not None:
        saved_config, tensors, opt_state, trainer_state = ckpt.read_training_checkpoint(latest)
        _same_run(saved_config["training"], config)
        ckpt.load_state_dict_strict(model, tensors, str(latest))
        optimizer.load_state_dict(opt_state)
        step, elapsed = int(trainer_state["step"]), float(trainer_state["elapsed_seconds"])
        provenance = {**trainer_state.get("provenance", {}), "resumed_with": provenance}

    log = _MetricsLog(run_dir / METRICS, keep_before=step) if rank == 0 else None
    bar = tqdm(total=total, initial=step, disable=not progress or rank != 0, desc=f"train {config.task}", unit="batch")
    end = total if stop_at_step is None else min(total, stop_at_step)

    def draw(s: int) -> tuple[dict, object]:
        """The curriculum parameters and this process's share of the data of step ``s``."""
        stage = curriculum.at(s // bpe + 1, (s % bpe) / bpe)
        batch = task.sample(config.batch_size, np.random.default_rng([config.seed, s]), stage, config)
        return stage, (batch.select(slice(rank, None, world)) if world > 1 else batch)

    # Data are drawn in the loop, not on a prefetch thread: on a 2-core CPU a second thread
    # fights PyTorch's own threads and made steps ~60 % slower (measured).
    started = time.perf_counter() - elapsed
    while step < end:
        epoch = step // bpe + 1
        stage, batch = draw(step)
        coins = torch.Generator().manual_seed(int(np.random.default_rng([config.seed, step, 1 + rank]).integers(2**62)))

        loss, terms = task.loss(model, batch, stage, config, coins)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"non-finite loss at step {step} (epoch {epoch}): {terms}")
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if world > 1:
            _average_gradients(params, world)
        if config.grad_clip:
            torch.nn.utils.clip_grad_norm_(params, config.grad_clip)
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(config, step, total)
        optimizer.step()
        step += 1

        terms = {"loss": float(loss.detach()), **terms}
        if world > 1:
            values = torch.tensor(list(terms.values()), dtype=torch.float64)
            dist.all_reduce(values)
            terms = dict(zip(terms, (values / world).tolist(), strict=True))
        if rank == 0:
            log.write(step, epoch, time.perf_counter() - started, terms, stage)
            bar.set_postfix({k: f"{v:.3g}" for k, v in terms.items()}, refresh=False)
        bar.update(1)

        if step % every == 0 or step == end:
            if rank == 0:
                elapsed = time.perf_counter() - started
                state = {"step": step, "epoch": epoch, "elapsed_seconds": elapsed, "provenance": provenance}
                extra = {"step": step, "elapsed_seconds": elapsed, "last_terms": terms, "provenance": provenance}
                cfg = model_config(config, extra)
                ckpt.write_training_checkpoint(
                    run_dir, f"step-{step:08d}", model.state_dict(), optimizer.state_dict(), cfg, state,
                    keep=config.keep_checkpoints,
                )
                ckpt.write_model(run_dir, model.state_dict(), cfg)
                log.flush()
            if world > 1:
                dist.barrier()
    bar.close()
    if log is not None:
        log.close()
    return run_dir


class _MetricsLog:
    """``metrics.csv``: one row per step (loss terms and curriculum parameters); resume-safe."""

    def __init__(self, path: Path, keep_before: int) -> None:
        self.path = path
        rows: list[dict] = []
        if path.exists() and keep_before > 0:
            with open(path, newline="") as f:
                rows = [r for r in csv.DictReader(f) if int(r["step"]) <= keep_before]
        self._fields: list[str] | None = list(rows[0].keys()) if rows else None
        self._file = open(path, "w", newline="")
        self._writer: csv.DictWriter | None = None
        if self._fields:
            self._writer = csv.DictWriter(self._file, fieldnames=self._fields)
            self._writer.writeheader()
            self._writer.writerows(rows)

    def write(self, step: int, epoch: int, seconds: float, terms: dict, stage: dict) -> None:
        row = {"step": step, "epoch": epoch, "seconds": f"{seconds:.3f}"}
        row.update({k: f"{v:.6g}" for k, v in terms.items()})
        row.update({f"param_{k}": f"{v:.6g}" for k, v in stage.items()})
        if self._writer is None:
            self._fields = list(row)
            self._writer = csv.DictWriter(self._file, fieldnames=self._fields, extrasaction="ignore")
            self._writer.writeheader()
        self._writer.writerow(row)

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        self._file.close()
