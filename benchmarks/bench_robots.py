"""Generated motions executed on standard arm models: the built-in arm against robosuite's Panda and UR5e.

    python benchmarks/bench_robots.py [--n 100] [--seed 2028] [--robots panda ur5e] [--sliding 20]
                                      [--out benchmarks/results_robots.json] [--speed-only N]

Pancake: ``--n`` fresh position-type sketches (the ch. 2 generator, seeded), deformed by the shipped ``pancake``
model with ``keep_end=True``; each motion and its undeformed sketch run on every arm (ch. 2 gains, the model's μ).
Per arm: how many keep the pancake through the motion, how many stay within the joint position, velocity and
torque limits, the tool-tracking RMSE (median, max), the IK residual, the real-time factor and the differential
IK's time per control period. A motion an arm refuses (``ValueError``: out of its workspace) is counted as such.

Sliding: the chapter-3 evaluation commands (``reproduce.ch3.eval_commands``), planned by the shipped ``sliding``
model at the arm's friction (``ARM_PHYSICS``), each run on the built-in arm and on the Panda: the object RMSE.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

import numpy as np
import torch

import seqmotion as sm
from seqmotion.io import atomic_write_json
from seqmotion.tasks.pancake import data as sketches
from seqmotion.training.provenance import machine_description


def run_set(name: str, motions: list[np.ndarray], robot: str | None, mu: float) -> dict:
    from seqmotion import sim

    rows = []
    for states in motions:
        started = time.perf_counter()
        try:
            r = sim.run_pancake(states, gains="ch2", mu=mu, robot=robot)
        except ValueError as exc:
            rows.append({"refused": str(exc)})
            continue
        j = r.joints
        rows.append({
            "kept": not r.contact_lost, "on_spatula": r.on_spatula, "diverged": r.diverged is not None,
            "rmse_mm": 1e3 * r.position_rmse, "attitude_rmse_deg": float(np.degrees(r.attitude_rmse)),
            "limits_ok": j.problem is None, "joint_limits_ok": j.joint_limits_ok,
            "velocity_limits_ok": j.velocity_limits_ok, "torque_limits_ok": j.torque_limits_ok,
            "torque_share_max": None if j.torque_share is None else float(np.max(j.torque_share)),
            "ik_error_mm": 1e3 * j.ik_error[0], "realtime_factor": r.realtime_factor,
            "simulated_s": float(r.time[-1]) if len(r.time) else 0.0, "wall_s": time.perf_counter() - started,
        })
    ran = [r for r in rows if "refused" not in r]
    get = lambda key: np.array([r[key] for r in ran], dtype=float)  # noqa: E731
    out = {
        "set": name, "robot": robot or "mh3f", "n": len(rows), "refused": len(rows) - len(ran),
        "kept": int(sum(r["kept"] for r in ran)), "diverged": int(sum(r["diverged"] for r in ran)),
        "kept_share_of_all": float(sum(r["kept"] for r in ran) / max(len(rows), 1)),
    }
    if ran:
        out.update(
            limits_ok=int(sum(r["limits_ok"] for r in ran)),
            rmse_mm_median=float(np.median(get("rmse_mm"))), rmse_mm_max=float(np.max(get("rmse_mm"))),
            ik_error_mm_max=float(np.max(get("ik_error_mm"))),
            realtime_factor_median=float(np.median(get("realtime_factor"))),
        )
        if robot is not None:
            out.update(
                joint_limits_ok=int(sum(bool(r["joint_limits_ok"]) for r in ran)),
                velocity_limits_ok=int(sum(bool(r["velocity_limits_ok"]) for r in ran)),
                torque_limits_ok=int(sum(bool(r["torque_limits_ok"]) for r in ran)),
                torque_share_max=float(np.max(get("torque_share_max"))),
            )
    first_refusals = [r["refused"] for r in rows if "refused" in r][:3]
    if first_refusals:
        out["refusals"] = first_refusals
    return out


def speed(robot: str | None, motions: list[np.ndarray]) -> dict:
    """Real-time factor of whole runs (the control loop: IK + control + physics, every 1 ms period) and the
    differential IK's share, median over ``motions`` (timed in process; run it on a quiet machine)."""
    from seqmotion.sim import arm as arm_module

    seen: list = []
    original = arm_module.make_controller

    def spy(*args, **kwargs):
        ctl = original(*args, **kwargs)
        seen.append(ctl)
        return ctl

    arm_module.make_controller = spy
    factors, ik_ms = [], []
    try:
        for states in motions:
            r = sm.sim.run_pancake(states, gains="ch2", robot=robot)
            factors.append(r.realtime_factor)
            ctl = seen[-1]
            if hasattr(ctl, "ik_seconds"):
                ik_ms.append(1e3 * ctl.ik_seconds / max(ctl.periods, 1))
    finally:
        arm_module.make_controller = original
    return {"robot": robot or "mh3f", "runs": len(motions), "realtime_factor_median": float(np.median(factors)),
            "realtime_factor_min": float(np.min(factors)),
            "ik_ms_per_period_median": float(np.median(ik_ms)) if ik_ms else None}


def sliding(robots: list[str | None], n: int) -> list[dict]:
    from seqmotion import sim
    from seqmotion.reproduce.ch3 import eval_commands
    from seqmotion.sim.sliding import ARM_PHYSICS

    planner = sm.load_pretrained("sliding")
    out = []
    commands = eval_commands(n, 0)
    plans = [planner.plan(c, mu=ARM_PHYSICS.mu, mu_dyn=ARM_PHYSICS.mu_dyn) for c in commands]
    for robot in robots:
        rmse, refused, limits_ok, fell = [], 0, 0, 0
        for plan, command in zip(plans, commands, strict=True):
            try:
                r = sim.run_sliding(plan, command, robot=robot)
            except ValueError:
                refused += 1
                continue
            rmse.append(1e3 * r.rmse)
            limits_ok += int(r.joints.problem is None)
            fell += int(r.fell_off)
        out.append({"robot": robot or "mh3f", "n": n, "refused": refused, "fell_off": fell, "limits_ok": limits_ok,
                    "object_rmse_mm_mean": float(np.mean(rmse)) if rmse else None,
                    "object_rmse_mm_median": float(np.median(rmse)) if rmse else None})
        print(json.dumps(out[-1]), flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=100)
    parser.add_argument("--seed", type=int, default=2028)
    parser.add_argument("--robots", nargs="+", default=["panda", "ur5e"])
    parser.add_argument("--no-builtin", action="store_true", help="skip the built-in arm's runs")
    parser.add_argument("--sliding", type=int, default=20, help="chapter-3 commands to run (0: none)")
    parser.add_argument("--out", default="benchmarks/results_robots.json")
    parser.add_argument("--speed-only", type=int, default=0, metavar="N",
                        help="only time N runs per arm (quiet machine) and add them to --out's record")
    args = parser.parse_args()
    torch.set_num_threads(1)
    deformer = sm.load_pretrained("pancake")
    mu = deformer.options.mu
    batch = sketches.position_type(args.n, np.random.default_rng(args.seed))
    inputs = [batch.states[b, : batch.lengths[b]] for b in range(args.n)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        motions = [deformer.deform(x, keep_end=True).states for x in inputs]
    arms: list[str | None] = ([] if args.no_builtin else [None]) + list(args.robots)
    if args.speed_only:
        import os
        from pathlib import Path

        record = json.loads(Path(args.out).read_text()) if Path(args.out).exists() else {}
        record["speed_quiet"] = {"machine": machine_description(), "load_average": os.getloadavg(),
                                 "rows": [speed(robot, motions[: args.speed_only]) for robot in arms]}
        print(json.dumps(record["speed_quiet"]), flush=True)
        atomic_write_json(args.out, record)
        return
    record: dict = {"machine": machine_description(), "seed": args.seed, "n": args.n, "pancake": [], "speed": []}
    for robot in arms:
        for name, states in (("keep_end", motions), ("sketch", inputs)):
            row = run_set(name, states, robot, mu)
            record["pancake"].append(row)
            print(json.dumps(row), flush=True)
            atomic_write_json(args.out, record)
    for robot in arms:  # under whatever load the run had: see --speed-only for the quiet figure
        record["speed"].append(speed(robot, motions[:5]))
        print(json.dumps(record["speed"][-1]), flush=True)
    if args.sliding:
        record["sliding"] = sliding([None, *args.robots[:1]], args.sliding)
    atomic_write_json(args.out, record)


if __name__ == "__main__":
    main()
