"""Helpers shared by the benchmark scripts (run them from the repository root)."""

from __future__ import annotations

import json
import shutil
import tempfile
import time

from seqmotion.tasks import train
from seqmotion.training.config import TrainConfig
from seqmotion.training.provenance import machine_description


def time_training(config: TrainConfig, steps: int) -> dict:
    """Run ``steps`` optimiser steps of a configuration (no checkpoints) and project a full run."""
    config.checkpoint_every = 10**9  # time the optimisation, not the disk
    out = tempfile.mkdtemp(prefix="bench-train-")
    try:
        start = time.perf_counter()
        train(config, out, progress=False, stop_at_step=steps)
        seconds = time.perf_counter() - start
    finally:
        shutil.rmtree(out, ignore_errors=True)
    per_step = seconds / steps
    result = {"what": f"train {config.task} {config.preset}", "steps": steps, "seconds_per_step": per_step,
              "seconds_per_epoch": per_step * config.batches_per_epoch,
              "projected_hours_full_run": per_step * config.batches_per_epoch * config.epochs / 3600,
              "batch": config.batch_size, "machine": machine_description()}
    print(json.dumps(result))
    return result
