"""Speed of the chapter-2 model: deformation latency/throughput and training time per epoch.

    python benchmarks/bench_pancake.py deform [--model DIR]
    python benchmarks/bench_pancake.py train --config small|paper [--steps N]

Prints one JSON line per measurement; results go into benchmarks/RESULTS.md by hand, with
the machine they were measured on. Nothing here is asserted: speed is measured, not tested.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch  # noqa: F401
from common import time_training

from seqmotion.training.provenance import machine_description


def bench_deform(model: str | None) -> None:
    import seqmotion as sm
    from seqmotion.tasks.pancake import data as inputs

    deformer = sm.load_pretrained("pancake") if model is None else sm.load(model)
    one = inputs.position_type(1, np.random.default_rng(0), length=500).states[0]
    for _ in range(5):
        deformer.deform(one)
    times = []
    for _ in range(50):
        start = time.perf_counter()
        deformer.deform(one)
        times.append(time.perf_counter() - start)
    print(json.dumps({"what": "deform one K=500", "median_ms": 1000 * float(np.median(times)),
                      "p90_ms": 1000 * float(np.percentile(times, 90)), "samples_per_s": 500 / float(np.median(times)),
                      "machine": machine_description()}))
    for batch in (16, 128, 512):
        x = inputs.position_type(batch, np.random.default_rng(1), length=500).states
        deformer.deform(x)
        start = time.perf_counter()
        reps = 3
        for _ in range(reps):
            deformer.deform(x)
        seconds = (time.perf_counter() - start) / reps
        print(json.dumps({"what": f"deform batch of {batch} x K=500", "seconds": seconds,
                          "trajectories_per_s": batch / seconds, "samples_per_s": batch * 500 / seconds}))


def bench_train(config_name: str, steps: int) -> None:
    from seqmotion import tasks

    time_training(tasks.get("pancake").train_config(config_name), steps)


def main() -> None:
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("deform")
    p.add_argument("--model")
    p = sub.add_parser("train")
    p.add_argument("--config", default="small")
    p.add_argument("--steps", type=int, default=64)
    args = parser.parse_args()
    if args.what == "deform":
        bench_deform(args.model)
    else:
        bench_train(args.config, args.steps)


if __name__ == "__main__":
    main()
