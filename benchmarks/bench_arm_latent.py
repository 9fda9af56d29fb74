"""The learned part alone on a real arm: how far the shipped pancake model's motions are from a robot's rated limits,
before and after latent updates with the limits as an objective (ch. 4's external order, ``sm.sim.ArmLimits``).

    python benchmarks/bench_arm_latent.py [--n 30] [--seed 2031] [--robots ur5e panda] [--steps 20]
                                          [--out benchmarks/results_arm_latent.json]

For each sketch (the README-style turns and the task generator's inputs of ``bench_robot_limits.py``, at their own
lengths) the learned motion ``deform(sketch)`` is judged on the robot's planar chain (:func:`seqmotion.sim.arm_limits
.arm_limit_shares`: the worst share of the rated joint speeds, accelerations and torque limits, and how far out of
reach), then ``optimize_latent(model, sketch, ArmLimits(robot) + EndPose(sketch's end), steps=STEPS)`` (gradient
descent with a line search) and judged again, with the friction cone's worst violation and how far the end pose moved.
No polish and no MuJoCo run: this measures where the learned part lands; ``bench_robot_limits.py`` measures the
motions that ``deform(..., keep_end=True, robot=...)`` makes exact and executes them.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import seqmotion as sm
from seqmotion.io import atomic_write_json
from seqmotion.sim.arm_limits import ArmLimits, arm_limit_shares
from seqmotion.training.provenance import machine_description

sys.path.insert(0, str(Path(__file__).parent))
from bench_robot_limits import generator_sketches, turn_sketches  # noqa: E402 - the same sketches


def one(model, sketch: np.ndarray, robot: str, steps: int) -> dict:
    learned = model.deform(sketch)
    before = arm_limit_shares(robot, learned.states)
    end = tuple(float(v) for v in sketch[-1, :3])
    started = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = sm.optimize_latent(model, sketch, ArmLimits(robot) + sm.objectives.EndPose(end), steps=steps)
    seconds = time.perf_counter() - started
    after = arm_limit_shares(robot, result.states)
    moved = result.states[-1, :3] - learned.states[-1, :3]
    return {"K": len(sketch), "before": before, "after": after, "seconds": seconds,
            "cone_violation_max": 0.0 if result.violation is None else float(np.max(result.violation)),
            "end_moved_m": float(np.hypot(moved[0], moved[1])), "end_moved_rad": float(abs(moved[2])),
            "end_error_rad_before": float(abs(learned.states[-1, 2] - end[2])),
            "end_error_rad_after": float(abs(result.states[-1, 2] - end[2]))}


def summarise(rows: list[dict]) -> dict:
    def within(part: str, share: float) -> int:
        return sum(all(v <= share for k, v in r[part].items() if k != "reach") and r[part].get("reach", 0.0) <= 1e-6
                   for r in rows)

    def median(part: str, name: str) -> float | None:
        values = [r[part][name] for r in rows if name in r[part]]
        return float(np.median(values)) if values else None

    names = sorted({name for r in rows for name in r["before"]})
    return {
        "n": len(rows),
        "within_rated_before": within("before", 1.0), "within_rated_after": within("after", 1.0),
        "within_1.1_before": within("before", 1.1), "within_1.1_after": within("after", 1.1),
        "median_share_before": {name: median("before", name) for name in names},
        "median_share_after": {name: median("after", name) for name in names},
        "cone_kept_after": sum(r["cone_violation_max"] <= 0.01 for r in rows),
        "end_attitude_error_rad_median_before": float(np.median([r["end_error_rad_before"] for r in rows])),
        "end_attitude_error_rad_median_after": float(np.median([r["end_error_rad_after"] for r in rows])),
        "end_moved_m_median": float(np.median([r["end_moved_m"] for r in rows])),
        "seconds_median": float(np.median([r["seconds"] for r in rows])),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=30)
    parser.add_argument("--seed", type=int, default=2031)
    parser.add_argument("--robots", nargs="+", default=["ur5e", "panda"])
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--out", default="benchmarks/results_arm_latent.json")
    args = parser.parse_args()
    model = sm.load_pretrained("pancake")
    sets = {"turns": turn_sketches(args.n, args.seed), "generator": generator_sketches(args.n, args.seed)}
    out: dict = {"machine": machine_description(), "n": args.n, "seed": args.seed, "steps": args.steps,
                 "results": {}}
    for robot in args.robots:
        for name, sketches in sets.items():
            rows = [one(model, sketch, robot, args.steps) for sketch in sketches]
            out["results"][f"{robot}/{name}"] = {"summary": summarise(rows), "rows": rows}
            print(robot, name, json.dumps(summarise(rows)), flush=True)
            atomic_write_json(args.out, out)


if __name__ == "__main__":
    main()
