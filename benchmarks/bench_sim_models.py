"""The trained models on the simulated arm (issue 5's model-dependent numbers).

    python benchmarks/bench_sim_models.py pancake [--n 100] [--model DIR]   # deformed vs undeformed
    python benchmarks/bench_sim_models.py j2 [--model DIR]                  # the ch. 4 J2 motion turns it over
    python benchmarks/bench_sim_models.py sliding [--n 10] [--model DIR]    # model A in 3-D vs 2-D

``pancake``: fresh position-type inputs (a seed stream no training used), each executed twice
with the ch. 2 gains — as sketched and as deformed — counting how often the pancake loses
contact (``PancakeResult.contact_lost``: > 5 mm slip or > 2 mm lift during the motion). Inputs
whose command leaves the arm's workspace are set aside and counted. Prints JSON lines.
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

import seqmotion as sm
from seqmotion import sim
from seqmotion.tasks.pancake import data as inputs
from seqmotion.training.provenance import machine_description


def bench_pancake(model: str | None, n: int) -> None:
    deformer = sm.load(model) if model else sm.load_pretrained("pancake")
    batch = inputs.position_type(3 * n, np.random.default_rng(11_000_000))
    counts = {"run": 0, "set_aside": 0, "original_lost": 0, "deformed_lost": 0, "deformed_feasible_2d": 0}
    for b in range(len(batch)):
        if counts["run"] == n:
            break
        x = batch.states[b, : batch.lengths[b]]
        r = deformer.deform(x)
        try:
            original, deformed = sim.run_pancake(x, gains="ch2"), sim.run_pancake(r.states, gains="ch2")
        except ValueError:  # either command leaves the 0.53 m arm's workspace
            counts["set_aside"] += 1
            continue
        counts["run"] += 1
        counts["original_lost"] += original.contact_lost
        counts["deformed_lost"] += deformed.contact_lost
        counts["deformed_feasible_2d"] += bool(r.violation.max() <= 0.01)
    counts["deformed_kept_contact_share"] = 1 - counts["deformed_lost"] / max(counts["run"], 1)
    counts["original_lost_share"] = counts["original_lost"] / max(counts["run"], 1)
    print(json.dumps({**counts, "machine": machine_description()}))


def bench_j2(model: str | None) -> None:
    deformer = sm.load(model) if model else sm.load_pretrained("pancake")
    x = inputs.straight((0.0, 0.0, -3 * math.pi / 4), 500, timing="linear")
    res = sm.optimize_latent(deformer, x, sm.objectives.Ranges(), steps=20)  # as `seqmotion reproduce ch4`
    result = sim.run_pancake(res.states, gains="ch4")
    print(json.dumps({"j2_final": float(res.history[-1]), "end_pose": res.states[-1, :3].tolist(),
                      **result.summary(), "machine": machine_description()}, default=float))


def bench_sliding(model: str | None, n: int) -> None:
    from seqmotion.reproduce.ch3 import eval_commands, rmse_mm

    planner = sm.load(model) if model else sm.load_pretrained("sliding")
    cmds = eval_commands(n, 0)
    rows = []
    for command in cmds:
        plan = planner.plan(command)
        row = {"rmse_2d_mm": float(rmse_mm(plan.rel_states, command))}
        try:
            res = sim.run_sliding(plan, command)
        except ValueError as exc:
            row["not_executable"] = str(exc)
        else:
            row.update(rmse_3d_mm=1000 * res.rmse, pan_excursion_m=res.pan_excursion, fell_off=res.fell_off)
        rows.append(row)
        print(json.dumps(row))
    done = [r for r in rows if "rmse_3d_mm" in r]
    print(json.dumps({"n": n, "executed": len(done), "mean_rmse_2d_mm": float(np.mean([r["rmse_2d_mm"] for r in rows])),
                      "mean_rmse_3d_mm": float(np.mean([r["rmse_3d_mm"] for r in done])) if done else None,
                      "max_pan_excursion_m": max((r["pan_excursion_m"] for r in done), default=None),
                      "fell_off": sum(r["fell_off"] for r in done), "machine": machine_description()}))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("what", choices=["pancake", "j2", "sliding"])
    parser.add_argument("--model")
    parser.add_argument("--n", type=int)
    args = parser.parse_args()
    if args.what == "pancake":
        bench_pancake(args.model, args.n or 100)
    elif args.what == "j2":
        bench_j2(args.model)
    else:
        bench_sliding(args.model, args.n or 10)


if __name__ == "__main__":
    main()
