"""Deformed motions that end where the sketch ends, at rest: ``deform(..., keep_end=True)`` against the
plain fast path, and executed on the MuJoCo arm.

    python benchmarks/bench_keep_end.py [--n 500] [--arm 100] [--seed 2027] [--out FILE]
    python benchmarks/bench_keep_end.py --readme 20 [--seed 2027] [--out FILE]

On ``--n`` fresh position-type sketches (the ch. 2 generator, K = 100–500, rest to rest; seeded):

* plain ``deform``: feasible share (max F_c ≤ 0.01 rad), end-position error, end speed;
* the closed-form end correction alone (``physics.integrator.reach_end``: the inputs nearest the
  learned ones that end at the sketch's end at rest, ignoring the cone — ~1 ms): the other end of
  the fast path's trade-off;
* ``deform(keep_end=True)``: the same, plus the share within 2 mm / 0.5° / 0.05 m/s / 0.5 rad/s, the
  time per motion (deformation + correction + IPOPT polish) and how many motions needed more time than
  their sketch to stop within the arm's acceleration limits (and how much: 1 sample = 1 ms).

Then the first ``--arm`` keep_end motions run on the simulated arm (PD + DOB, ch. 2 gains, the
model's μ): how many keep the pancake through the motion, and whether any leaves the workspace.

``--readme N`` measures instead how many IPOPT iterations the README's polishes take: the README's own three
(``deform(straight((0.2, 0, 2.5), 500), keep_end=True)``, ``optimize_latent(..., EndPose((0.1, 0, π)),
exact=True)`` from that sketch, ``seqmotion optimize --target 0.1 0.0 3.14 --exact``), then for N seeded end poses
(y, z ∈ ±0.2, ±0.1 m, θ ∈ ±π) a ``keep_end`` deform of the straight 500-sample sketch to it and the command
line's ``--exact`` optimize toward it (``result.polish_iterations``; the optimize's ``polish`` stage), with the
time each took and the machine's load average.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
import warnings

import numpy as np
import torch

import seqmotion as sm
from seqmotion.io import atomic_write_json
from seqmotion.physics.integrator import integrate_numpy, reach_end
from seqmotion.tasks.pancake import data as sketches
from seqmotion.tasks.pancake import physics
from seqmotion.training.provenance import machine_description


def end_metrics(x: np.ndarray, states: np.ndarray, accel: np.ndarray, mu: float) -> dict:
    return {
        "max_fc": float(physics.violation(states[:-1], accel, mu).max()),
        "end_position_mm": 1000 * float(np.linalg.norm(states[-1, :2] - x[-1, :2])),
        "end_attitude_deg": float(np.degrees(abs(states[-1, 2] - x[-1, 2]))),
        "end_speed": float(np.linalg.norm(states[-1, 3:5])),
        "end_rate": float(abs(states[-1, 5])),
    }


def summarise(rows: list[dict]) -> dict:
    get = lambda key: np.array([r[key] for r in rows])  # noqa: E731
    pos = get("end_position_mm")
    return {
        "n": len(rows),
        "feasible_share": float(np.mean(get("max_fc") <= 0.01)),
        "end_position_mm_median": float(np.median(pos)),
        "end_position_mm_p95": float(np.percentile(pos, 95)),
        "end_attitude_within_0.5deg": float(np.mean(get("end_attitude_deg") <= 0.5)),
        "at_rest_share": float(np.mean((get("end_speed") <= 0.05) & (get("end_rate") <= 0.5))),
        "end_speed_median": float(np.median(get("end_speed"))),
    }


def distribution(values: list[float]) -> dict:
    v = np.asarray(values, dtype=float)
    return {"n": len(v), "min": float(v.min()), "median": float(np.median(v)), "p90": float(np.percentile(v, 90)),
            "max": float(v.max()), "values": [round(float(x), 3) for x in v]}


def readme_polishes(deformer: sm.tasks.TrainedModel, n: int, seed: int) -> dict:
    """IPOPT iterations and seconds of the README's polishes and of ``n`` more like them (see the docstring)."""
    from seqmotion.cli import default_length

    rng = np.random.default_rng(seed)
    ends = [(0.2, 0.0, 2.5)] + [(rng.uniform(-0.2, 0.2), rng.uniform(-0.1, 0.1), rng.uniform(-math.pi, math.pi))
                                for _ in range(n)]
    targets = [((0.2, 0.0, 2.5), (0.1, 0.0, math.pi)), ((0.1, 0.0, 3.14), (0.1, 0.0, 3.14))]
    targets += [(end, end) for end in ends[1:]]  # the command line sketches toward its target
    load = [os.getloadavg()[0]]
    keep = {"iterations": [], "seconds": [], "exact": []}
    for end in ends:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            start = time.perf_counter()
            r = deformer.deform(sketches.straight(end, 500), keep_end=True)
        keep["seconds"].append(time.perf_counter() - start)
        keep["iterations"].append(int(r.polish_iterations))
        keep["exact"].append(bool(r.exact))
    load.append(os.getloadavg()[0])
    opt = {"iterations": [], "seconds": [], "exact": []}
    for sketch_end, target in targets:
        length = 500 if sketch_end != target else default_length(deformer)
        sketch = deformer.task_def.sketch(sketch_end, length)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = sm.optimize_latent(deformer, sketch, sm.objectives.EndPose(target), exact=True)
        polish = next(stage for stage in res.stages if stage.name == "polish")
        opt["iterations"].append(int(np.asarray(polish.steps).reshape(-1)[0]))
        opt["seconds"].append(float(polish.seconds))
        opt["exact"].append(bool(res.exact))
    load.append(os.getloadavg()[0])
    # keep_end's seconds are the whole deform (network + polish), the optimize's its polish stage alone
    summary = {name: {"iterations": distribution(rows["iterations"]), "seconds": distribution(rows["seconds"]),
                      "exact_share": float(np.mean(rows["exact"]))}
               for name, rows in (("keep_end", keep), ("optimize_exact_polish", opt))}
    summary["readme_cases"] = {"keep_end (0.2, 0, 2.5)": keep["iterations"][0],
                               "optimize_latent to (0.1, 0, pi) from it": opt["iterations"][0],
                               "seqmotion optimize --target 0.1 0.0 3.14 --exact": opt["iterations"][1]}
    summary["load_average_1min"] = [round(v, 2) for v in load]
    return summary


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=500)
    parser.add_argument("--arm", type=int, default=100)
    parser.add_argument("--seed", type=int, default=2027)
    parser.add_argument("--out", default="bench_keep_end.json")
    parser.add_argument("--skip", type=int, default=0, help="run the arm on motions skip .. skip + arm")
    parser.add_argument("--readme", type=int, default=0, help="the README's polishes and N like them (only)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    deformer = sm.load_pretrained("pancake")
    if args.readme:
        deformer.deform(sketches.straight((0.1, 0.0, 1.0), 500), keep_end=True)  # warm up outside the timing
        record = {"machine": machine_description(), "seed": args.seed,
                  "polish_iterations": readme_polishes(deformer, args.readme, args.seed)}
        print(json.dumps(record["polish_iterations"]), flush=True)
        atomic_write_json(args.out, record)
        return
    mu = deformer.options.mu
    batch = sketches.position_type(args.n, np.random.default_rng(args.seed))
    inputs = [batch.states[b, : batch.lengths[b]] for b in range(args.n)]
    deformer.deform(inputs[0], keep_end=True)  # warm up: compile and build once, outside the timing
    plain, corrected, kept, seconds, exact, motions, iterations = [], [], [], [], [], [], []
    weights = np.array(deformer.exact_form().accel_weights)
    for x in inputs:
        start = time.perf_counter()
        fast = deformer.deform(x)
        fast_seconds = time.perf_counter() - start
        plain.append(end_metrics(x, fast.states, fast.accel, mu) | {"seconds": fast_seconds})
        accel = reach_end(fast.states[0], fast.accel, [0, 1, 2, 3, 4, 5], np.r_[x[-1, :3], np.zeros(3)], weights)
        corrected.append(end_metrics(x, integrate_numpy(fast.states[0], accel), accel, mu))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            start = time.perf_counter()
            r = deformer.deform(x, keep_end=True)
            seconds.append(time.perf_counter() - start)
        kept.append(end_metrics(x, r.states, r.accel, mu) | {"added_samples": int(r.length - len(x))})
        exact.append(bool(r.exact))
        iterations.append(int(r.polish_iterations))
        motions.append(r.states)
    record = {
        "machine": machine_description(), "seed": args.seed,
        "plain": summarise(plain) | {"seconds_median": float(np.median([r["seconds"] for r in plain]))},
        "end_correction_only": summarise(corrected),
        "keep_end": summarise(kept) | {"exact_share": float(np.mean(exact)),
                                       "seconds_median": float(np.median(seconds)),
                                       "seconds_p95": float(np.percentile(seconds, 95)),
                                       "seconds_max": float(np.max(seconds)),
                                       "extended_share": float(np.mean([r["added_samples"] > 0 for r in kept])),
                                       "added_ms_median_of_extended": float(np.median(
                                           [r["added_samples"] for r in kept if r["added_samples"] > 0] or [0])),
                                       "added_ms_max": float(max(r["added_samples"] for r in kept)),
                                       "iterations_median": float(np.median(iterations)),
                                       "iterations_p95": float(np.percentile(iterations, 95)),
                                       "iterations_max": int(max(iterations))},
    }
    print(json.dumps({k: record[k] for k in ("plain", "end_correction_only", "keep_end")}), flush=True)
    if args.arm:
        from seqmotion import sim

        arm = {"runs": 0, "kept_during_motion": 0, "on_spatula_at_end": 0, "left_workspace": 0, "diverged": 0,
               "executed_max_fc": []}
        for states in motions[args.skip : args.skip + args.arm]:
            arm["runs"] += 1
            try:
                result = sim.run_pancake(states, gains="ch2", mu=mu)
            except ValueError as exc:
                if "workspace" not in str(exc):
                    raise
                arm["left_workspace"] += 1
                continue
            arm["kept_during_motion"] += int(not result.contact_lost)
            arm["on_spatula_at_end"] += int(result.on_spatula)
            arm["diverged"] += int(result.diverged is not None)
            arm["executed_max_fc"].append(float(result.executed_violation.max(initial=0.0)))
        arm["executed_max_fc_median"] = float(np.median(arm.pop("executed_max_fc") or [0.0]))
        record["arm"] = arm
        print(json.dumps({"arm": arm}), flush=True)
    atomic_write_json(args.out, record)


if __name__ == "__main__":
    main()
