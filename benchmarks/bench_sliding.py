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

import numpy as np
import torch
from common import time_training

from seqmotion import tasks
from seqmotion.reproduce.ch3 import eval_commands, speed
from seqmotion.tasks.sliding import SlidingPlanner
from seqmotion.training.provenance import machine_description

LENGTH = 1200


def bench_generate(model: str | None) -> None:
    import seqmotion as sm

    task = tasks.get("sliding")
    torch.manual_seed(0)
    paper = SlidingPlanner(task.build_model(task.train_config("paper")), {})
    planners = {"paper-size (2x1024 + 500)": paper, "paper-size, int8 weights": paper.quantized()}
    try:
        planners["shipped/given"] = sm.load(model) if model else sm.load_pretrained("sliding")
    except ValueError as exc:
        print(json.dumps({"skipped": f"no trained model: {exc}"}))
    if "shipped/given" in planners:  # how far int8 weights move a trained model's plan
        planners["shipped/given, int8 (all layers)"] = planners["shipped/given"].quantized(min_features=16)
    float_of = {"paper-size, int8 weights": "paper-size (2x1024 + 500)",
                "shipped/given, int8 (all layers)": "shipped/given"}
    command = eval_commands(1, 123)[0]
    for name, planner in planners.items():
        result = speed(planner)  # the same measurement `seqmotion reproduce ch3` reports
        if name in float_of:  # the plan's object path with int8 weights against the float model's
            moved = planner.plan(command).rel_states[:, :2] - planners[float_of[name]].plan(command).rel_states[:, :2]
            result["object_path_change_vs_float_max_mm"] = 1000 * float(np.abs(moved).max())
        print(json.dumps({"model": name, **result, "dissertation_samples_per_s": 622,
                          "ratio_to_dissertation": result["single_samples_per_s"] / 622,
                          "machine": machine_description()}))


def bench_train(config_name: str, steps: int) -> None:
    from seqmotion.training.curriculum import Curriculum

    config = tasks.get("sliding").train_config(config_name)
    # time the stages that run L through the contact model (the slowest ones)
    config.curriculum = Curriculum(config.epochs, {"loss_prime_prob": 0.0, "bspline_prob": 0.5}).to_dict()
    time_training(config, steps)


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
