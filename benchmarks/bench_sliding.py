"""Speed of chapter-3 planning (contact physics included) and training time per epoch.

    python benchmarks/bench_sliding.py generate [--model DIR]     # shipped/given model, and the paper-size one
    python benchmarks/bench_sliding.py train --config small|paper [--steps N]

Generation: one K = 1200 command at a time (the dissertation: 1.93 s per trajectory, 622
samples/s, on an i7-6700), and batched throughput. The paper-size model (2 × 1024 + 500, C = 100)
is timed with its initialised weights: speed does not depend on what the weights are.
Prints JSON lines; nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time

import numpy as np
import torch

from seqmotion import tasks
from seqmotion.data import sliding as commands
from seqmotion.tasks.sliding import SlidingPlanner
from seqmotion.training.trainer import machine_description

LENGTH = 1200


def time_plan(planner: SlidingPlanner, command: np.ndarray, repeats: int = 10) -> float:
    planner.plan(command)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        planner.plan(command)
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def bench_generate(model: str | None) -> None:
    import seqmotion as sm

    one = commands.bspline_type(1, np.random.default_rng(0), length=LENGTH).states[0]
    batch = commands.bspline_type(64, np.random.default_rng(1), length=LENGTH).states
    task = tasks.get("sliding")
    torch.manual_seed(0)
    planners = {"paper-size (2x1024 + 500)": SlidingPlanner(task.build_model(task.train_config("paper")), {})}
    try:
        planners["shipped/given"] = sm.load(model) if model else sm.load_pretrained("sliding")
    except ValueError as exc:
        print(json.dumps({"skipped": f"no trained model: {exc}"}))
    for name, planner in planners.items():
        single = time_plan(planner, one)
        batched = time_plan(planner, batch, repeats=2)
        print(json.dumps({"model": name, "single_seconds": single, "single_samples_per_s": LENGTH / single,
                          "batch64_samples_per_s": 64 * LENGTH / batched, "dissertation_samples_per_s": 622,
                          "ratio_to_dissertation": LENGTH / single / 622, "machine": machine_description()}))


def bench_train(config_name: str, steps: int) -> None:
    from seqmotion.training.trainer import train

    task = tasks.get("sliding")
    config = task.train_config(config_name)
    config.checkpoint_every = 10**9
    # time the contact-model stages (L through the contact model: the slowest ones)
    from seqmotion.training.curriculum import Curriculum

    config.curriculum = Curriculum(config.epochs, {"loss_prime_prob": 0.0, "bspline_prob": 0.5}).to_dict()
    out = tempfile.mkdtemp(prefix="bench-sliding-")
    try:
        start = time.perf_counter()
        train(config, out, progress=False, stop_at_step=steps)
        seconds = time.perf_counter() - start
    finally:
        shutil.rmtree(out, ignore_errors=True)
    per_step = seconds / steps
    print(json.dumps({"what": f"train sliding {config_name}", "steps": steps, "seconds_per_step": per_step,
                      "seconds_per_epoch": per_step * config.batches_per_epoch,
                      "projected_hours_full_run": per_step * config.batches_per_epoch * config.epochs / 3600,
                      "batch": config.batch_size, "machine": machine_description()}))


def main() -> None:
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("generate")
    p.add_argument("--model")
    p = sub.add_parser("train")
    p.add_argument("--config", default="small")
    p.add_argument("--steps", type=int, default=4)
    args = parser.parse_args()
    if args.what == "generate":
        bench_generate(args.model)
    else:
        bench_train(args.config, args.steps)


if __name__ == "__main__":
    main()
