"""Which commands the shipped sliding planner follows, where it stops, and latent refinement (issue 17).

    python benchmarks/bench_planner_limits.py shapes [--refine]      # circles, lines, figure-eights vs speed
    python benchmarks/bench_planner_limits.py training [--n 2000]   # training commands vs those shapes
    python benchmarks/bench_planner_limits.py ch3 [--refine]         # reproduce-ch3 commands x unseen friction

All at μ = 1, μ' = 0.5 unless the friction grid says otherwise; K samples at dt = 1 ms.

* ``shapes``: a circle (``sm.tasks.sliding.data.circle``) of radius 2 and 5 cm, a straight line of
  2, 5 and 10 cm, a figure-eight (Gerono lemniscate, half-width 2 and 5 cm), each traversed
  once rest to rest along an S-curve in K samples — K sets the speed. Per command: mean speed
  (path length / duration) [m/s], the object's RMSE [mm], travel share (object path length /
  command path length), reach share (farthest distance from the start, object / command), the
  pan's farthest excursion [m]; and per shape the fastest speed tracked within 5 mm.
  ``--refine`` adds :func:`seqmotion.tasks.sliding.latent.refine_plan` (Adam on the latent, through
  the contact physics; ``refined+accel``: then Adam on the pan accelerations; ``refined+dither``:
  the same from the plan plus a 1.2 μg, 50 Hz rotating vibration) and its wall time.
* ``training``: mean speed, peak speed, reach, path length, turning (∫|dθ| along the path) of
  the commands the shipped model was trained on (B-spline type; physics type with the
  "position" shaking) — percentiles — beside the same numbers for the shapes.
* ``ch3``: the 10 commands of ``seqmotion reproduce ch3`` (``eval_commands(10, 0)``) over
  ``FRICTION_GRID`` (and the training friction): RMSE [mm] and as % of the command's extent
  (its farthest distance from the start), reach share (the ``table3_qualitative`` measure),
  travel share, pan excursion; ``--refine`` adds the refined plans.

Seeded; prints JSON lines (one per row) and the machine; nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

import seqmotion as sm
from seqmotion.reproduce.ch3 import FRICTION_GRID, eval_commands, farthest_m, rmse_mm
from seqmotion.tasks.sliding import data as commands
from seqmotion.tasks.sliding.latent import Tracking, refine_plan
from seqmotion.training.provenance import machine_description

DT = 1e-3
TOLERANCE_MM = 5.0
CIRCLES = {0.02: (300, 450, 600, 900, 1200, 2000, 4000), 0.05: (300, 450, 600, 900, 1200, 2000, 4000)}
LINES = {0.02: (300, 500, 1000, 2000, 4000), 0.05: (300, 500, 1000, 2000, 4000), 0.1: (300, 500, 1000, 2000, 4000)}
EIGHTS = {0.02: (450, 600, 1200, 2400, 4000), 0.05: (450, 600, 1200, 2400, 4000)}
REFINE = {"steps": 300, "lr": 0.05, "alpha_end": 0.3, "alpha_jerk": 10.0, "pan_limit": 0.2, "gains": (1.0, 1.2, 1.4),
          "accel_steps": 2000, "accel_lr": 0.3, "dither": 1.2, "dither_hz": 50.0}
"""The refinement measured here (see benchmarks/results_planner_limits.md for the alternatives tried)."""
VARIANTS = (("refined", False, False), ("refined+accel", True, False), ("refined+dither", True, True))
"""(name, acceleration polish?, dither before it?) of the refinements measured with ``--refine``."""


def line(length_m: float, k: int) -> np.ndarray:
    return commands.line(length_m, k)


def figure_eight(half_width: float, k: int) -> np.ndarray:
    return commands.figure_eight(half_width, k)


def path_length(states: np.ndarray) -> np.ndarray:
    """Length of the path of ``states[..., :2]`` [m], per trajectory."""
    return np.linalg.norm(np.diff(states[..., :2], axis=-2), axis=-1).sum(-1)


def command_stats(cmd: np.ndarray, lengths: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Mean and peak speed [m/s], reach and path length [m], turning [rad] of commands ``(B, K, 4)``."""
    b, k = cmd.shape[:2]
    lengths = np.full(b, k) if lengths is None else lengths
    valid = np.arange(k)[None, :] < lengths[:, None]
    speed = np.where(valid, np.linalg.norm(cmd[..., 2:], axis=-1), 0.0)
    step = np.linalg.norm(np.diff(cmd[..., :2], axis=1), axis=-1) * valid[:, 1:]
    heading = np.arctan2(cmd[..., 3], cmd[..., 2])
    turn = np.abs((np.diff(heading, axis=1) + np.pi) % (2 * np.pi) - np.pi)
    moving = (speed[:, 1:] > 0.05 * speed.max(1, keepdims=True)) & valid[:, 1:]
    return {
        "duration_s": (lengths - 1) * DT,
        "mean_speed": step.sum(1) / ((lengths - 1) * DT),
        "peak_speed": speed.max(1),
        "reach_m": np.linalg.norm(np.where(valid[..., None], cmd[..., :2], 0.0), axis=-1).max(1),
        "path_m": step.sum(1),
        "turning_rad": (turn * moving).sum(1),
    }


def tracking_row(command: np.ndarray, plan: sm.tasks.sliding.SlidingPlan) -> dict[str, float]:
    """RMSE [mm], travel and reach share, pan excursion [m] of one plan for one ``(K, 4)`` command."""
    return {
        "rmse_mm": float(rmse_mm(plan.rel_states, command)),
        "travel_share": float(path_length(plan.rel_states) / path_length(command)),
        "reach_share": float(farthest_m(plan.rel_states) / farthest_m(command)),
        "pan_max_m": float(farthest_m(plan.pan_states)),
        "peak_pan_accel": float(np.linalg.norm(plan.pan_accel, axis=-1).max()),
    }


def shape_commands() -> list[tuple[str, float, int, np.ndarray]]:
    out = [("circle", r, k, commands.circle(r, k)) for r, ks in CIRCLES.items() for k in ks]
    out += [("line", length, k, line(length, k)) for length, ks in LINES.items() for k in ks]
    out += [("figure-eight", a, k, figure_eight(a, k)) for a, ks in EIGHTS.items() for k in ks]
    return out


def refine(planner: object, cmd: np.ndarray, mu: float, mu_dyn: float, polish: bool = False,
           dither: bool = False) -> tuple[object, float]:
    """The refined plan of ``cmd`` at the given friction (``polish``: then its accelerations too;
    ``dither``: from the plan plus a vibration), and its wall time [s]."""
    start = time.perf_counter()
    objective = Tracking(cmd, alpha_end=REFINE["alpha_end"], alpha_jerk=REFINE["alpha_jerk"],
                         pan_limit=REFINE["pan_limit"])
    plan = refine_plan(planner, cmd, mu=mu, mu_dyn=mu_dyn, steps=REFINE["steps"], lr=REFINE["lr"],
                       objective=objective, gains=REFINE["gains"], accel_steps=REFINE["accel_steps"] if polish else 0,
                       accel_lr=REFINE["accel_lr"], dither=REFINE["dither"] if dither else 0.0,
                       dither_hz=REFINE["dither_hz"])
    return plan, time.perf_counter() - start


def bench_shapes(do_refine: bool) -> None:
    planner = sm.load_pretrained("sliding")
    best: dict[str, dict] = {}
    for shape, size, k, cmd in shape_commands():
        stats = command_stats(cmd[None])
        row = {"shape": shape, "size_m": size, "K": k, "mean_speed": float(stats["mean_speed"][0]),
               "peak_speed": float(stats["peak_speed"][0]), "plan": tracking_row(cmd, planner.plan(cmd))}
        if do_refine:
            for which, polish, dither in VARIANTS:
                plan, seconds = refine(planner, cmd, 1.0, 0.5, polish, dither)
                row[which] = {**tracking_row(cmd, plan), "seconds": seconds}
        print(json.dumps(row), flush=True)
        for which in ("plan", *(v[0] for v in VARIANTS)):
            if which in row and row[which]["rmse_mm"] <= TOLERANCE_MM:
                key = f"{which}: {shape} {100 * size:g} cm"
                if row["mean_speed"] > best.get(key, {"mean_speed": -1.0})["mean_speed"]:
                    best[key] = {"K": k, "mean_speed": row["mean_speed"], "rmse_mm": row[which]["rmse_mm"]}
    print(json.dumps({"fastest_within_5mm": best, "refine": {**REFINE, "gains": list(REFINE["gains"])},
                      "machine": machine_description()}))


def percentiles(values: np.ndarray) -> list[float]:
    return [float(v) for v in np.percentile(values, [5, 50, 95])]


def bench_training(n: int) -> None:
    rng = np.random.default_rng(12_000_000)
    bspline = commands.bspline_type(n, rng)
    physics = commands.physics_type(n, rng)
    for name, batch in (("training B-spline type", bspline), ("training physics type (position shaking)", physics)):
        stats = command_stats(batch.states, batch.lengths)
        print(json.dumps({"commands": name, "n": n, "percentiles": "5/50/95",
                          **{key: percentiles(v) for key, v in stats.items()}}))
    for shape, size, k, cmd in shape_commands():
        stats = command_stats(cmd[None])
        print(json.dumps({"commands": f"{shape} {100 * size:g} cm, K={k}",
                          **{key: float(v[0]) for key, v in stats.items()}}))
    cmds = eval_commands(10, 0)
    stats = command_stats(cmds)
    print(json.dumps({"commands": "reproduce ch3 eval_commands(10, 0)", "percentiles": "5/50/95",
                      **{key: percentiles(v) for key, v in stats.items()}, "machine": machine_description()}))


def bench_ch3(do_refine: bool) -> None:
    planner = sm.load_pretrained("sliding")
    cmds = eval_commands(10, 0)
    reach = farthest_m(cmds)
    rows: dict[str, list] = {"plan": [], **{v[0]: [] for v in VARIANTS}}
    for mu, mu_dyn in [(1.0, 0.5), *FRICTION_GRID]:
        for which in rows if do_refine else ("plan",):
            start = time.perf_counter()
            if which == "plan":
                plan = planner.plan(cmds, mu=mu, mu_dyn=mu_dyn)
            else:
                _, polish, dither = next(v for v in VARIANTS if v[0] == which)
                plan = refine(planner, cmds, mu, mu_dyn, polish, dither)[0]
            seconds = time.perf_counter() - start
            r = rmse_mm(plan.rel_states, cmds)
            pct = 100 * r / (1000 * reach)
            share = farthest_m(plan.rel_states) / reach
            row = {"which": which, "mu": mu, "mu_dyn": mu_dyn, "rmse_mm": float(r.mean()),
                   "rmse_pct_extent_mean": float(pct.mean()), "rmse_pct_extent_max": float(pct.max()),
                   "reach_share_mean": float(share.mean()), "reach_share_min": float(share.min()),
                   "travel_share_mean": float((path_length(plan.rel_states) / path_length(cmds)).mean()),
                   "pan_max_m": float(farthest_m(plan.pan_states).max()), "seconds_10_commands": seconds,
                   "peak_pan_accel": float(np.linalg.norm(plan.pan_accel, axis=-1).max()),
                   "meets_target_per_command": int(((share >= 0.9) & (pct <= 10)).sum())}
            if (mu, mu_dyn) != (1.0, 0.5):
                rows[which].append(row)
            print(json.dumps(row), flush=True)
    for which, cells in rows.items():
        if cells:
            print(json.dumps({"which": which, "grid_cells": len(cells),
                              **{f"grid_mean_{key}": float(np.mean([c[key] for c in cells]))
                                 for key in ("rmse_mm", "rmse_pct_extent_mean", "reach_share_mean",
                                             "travel_share_mean", "seconds_10_commands")},
                              "grid_min_reach_share_mean": float(min(c["reach_share_mean"] for c in cells)),
                              "grid_max_rmse_pct_extent_mean": float(max(c["rmse_pct_extent_mean"] for c in cells)),
                              "commands_meeting_target": int(sum(c["meets_target_per_command"] for c in cells)),
                              "of": 10 * len(cells), "machine": machine_description()}))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("what", choices=["shapes", "training", "ch3"])
    parser.add_argument("--refine", action="store_true", help="also refine the plans' latents (Adam)")
    parser.add_argument("--n", type=int, default=2000, help="training commands per type (training)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    if args.what == "shapes":
        bench_shapes(args.refine)
    elif args.what == "training":
        bench_training(args.n)
    else:
        bench_ch3(args.refine)


if __name__ == "__main__":
    main()
