"""Sliding plans made for the Panda, executed on it in MuJoCo: do they stay within its limits, and how well does the
object still follow?

    python benchmarks/bench_sliding_robot_limits.py [--n 20] [--seed 0] [--configs run all]
                                                    [--out benchmarks/results_sliding_robot_limits.json]

The chapter-3 evaluation commands (``reproduce.ch3.eval_commands(n, seed)``, K = 1200), each planned at the arm's
friction (``ARM_PHYSICS``, μ = μ' = 0.5) three ways and run on robosuite's Panda with the ch. 3 gains
(``sim.run_sliding(plan, command, robot="panda")``):

* ``plain``: ``planner.plan(command)``, as ``bench_robots.py --sliding`` does (its ``sliding`` row is reused for the
  summary; the per-command runs here pair each command's plans);
* ``run``: ``planner.plan(command, robot="panda", limits=RUN_KINDS)``: refined to keep what a run's ``JointReport``
  judges (rated joint speeds, joint ranges and reach, torque limits);
* ``all``: ``planner.plan(command, robot="panda")``: every limit, the rated joint accelerations too.

Per configuration: runs within every limit the run judges (``JointReport.problem is None``), plans the check calls
executable (``plan.feasible``), plans called executable whose run broke a limit (must be 0), the object's RMSE on
the arm (mean, median; and the mean over the plain plans' on the same commands), and seconds per plan (planning
only; one torch thread). Writes ``--out`` (JSON) and prints JSON lines.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import warnings

import numpy as np
import torch
from bench_robots import sliding as plain_sliding_rows

import seqmotion as sm
from seqmotion import sim
from seqmotion.io import atomic_write_json
from seqmotion.reproduce.ch3 import eval_commands
from seqmotion.sim.sliding import ARM_PHYSICS
from seqmotion.tasks.sliding import ROBOT_KINDS, RUN_KINDS
from seqmotion.training.provenance import machine_description

ROBOT = "panda"
CONFIGS = {"plain": None, "run": RUN_KINDS, "all": ROBOT_KINDS}


def plan_for(planner, command: np.ndarray, limits: tuple[str, ...] | None):  # noqa: ANN001, ANN201
    """The plan of ``command`` (``limits`` None: the plain plan) and the warnings it gave."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if limits is None:
            plan = planner.plan(command, mu=ARM_PHYSICS.mu, mu_dyn=ARM_PHYSICS.mu_dyn)
        else:
            plan = planner.plan(command, mu=ARM_PHYSICS.mu, mu_dyn=ARM_PHYSICS.mu_dyn, robot=ROBOT, limits=limits)
    return plan, [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]


def row(planner, i: int, command: np.ndarray, limits: tuple[str, ...] | None) -> dict:  # noqa: ANN001
    started = time.perf_counter()
    plan, said = plan_for(planner, command, limits)
    seconds = time.perf_counter() - started
    r = sim.run_sliding(plan, command, robot=ROBOT)
    j = r.joints
    check = plan.robot_check
    out = {
        "command": i, "plan_s": seconds, "rmse_2d_mm": 1e3 * float(plan.errors["tracking_rmse_m"]),
        "object_rmse_mm": 1e3 * r.rmse, "fell_off": r.fell_off, "tipped": r.tipped,
        "run_within_limits": j.problem is None,
        "run_crossings": [[c.kind, c.joint, round(c.share, 3)] for c in j.crossings],
        "run_speed_share_max": float(np.max(j.speed_share)), "run_torque_share_max": float(np.max(j.torque_share)),
        "run_range_share_max": float(np.max(j.range_share)),
        "feasible": None if check is None else plan.feasible,
        "warnings": said,
    }
    if check is not None:
        out.update(check_worst_share={k: round(float(v), 4) for k, v in check.worst_share.items()},
                   binding=None if check.binding is None else [check.binding.kind, check.binding.joint,
                                                               round(check.binding.share, 3)])
    return out


def summary(name: str, rows: list[dict], plain: list[dict]) -> dict:
    get = lambda key: np.array([r[key] for r in rows], dtype=float)  # noqa: E731
    rmse, base = get("object_rmse_mm"), np.array([r["object_rmse_mm"] for r in plain], dtype=float)
    feasible = [r["feasible"] is True for r in rows]
    return {
        "config": name, "limits": None if CONFIGS[name] is None else list(CONFIGS[name]), "n": len(rows),
        "run_within_limits": int(sum(r["run_within_limits"] for r in rows)),
        "feasible": int(sum(feasible)),
        "feasible_but_run_broke_a_limit": int(sum(f and not r["run_within_limits"] for f, r in zip(feasible, rows,
                                                                                                    strict=True))),
        "acceleration_kept": int(sum(r.get("check_worst_share", {}).get("acceleration", np.inf) <= 1 for r in rows)),
        "fell_off": int(sum(r["fell_off"] for r in rows)),
        "object_rmse_mm_mean": float(rmse.mean()), "object_rmse_mm_median": float(np.median(rmse)),
        "plain_object_rmse_mm_mean": float(base.mean()),
        "rmse_ratio_of_means": float(rmse.mean() / base.mean()),
        "rmse_ratio_worst_command": float(np.max(rmse / base)),
        "plan_s_mean": float(get("plan_s").mean()), "plan_s_median": float(np.median(get("plan_s"))),
        "plan_s_max": float(get("plan_s").max()),
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--configs", nargs="+", default=["run", "all"], choices=["run", "all"])
    parser.add_argument("--out", default="benchmarks/results_sliding_robot_limits.json")
    args = parser.parse_args()
    torch.set_num_threads(1)
    planner = sm.load_pretrained("sliding")
    commands = eval_commands(args.n, args.seed)
    record: dict = {"machine": machine_description(), "load_average_start": os.getloadavg(), "robot": ROBOT,
                    "n": args.n, "seed": args.seed, "friction": ARM_PHYSICS.to_dict(), "summary": [], "rows": {}}
    started = time.perf_counter()
    if args.seed == 0:  # bench_robots.py's own sliding row: the baseline RESULTS_sim.md records
        record["bench_robots_sliding"] = plain_sliding_rows([ROBOT], args.n)
    for name in ["plain", *args.configs]:
        rows = []
        for i, command in enumerate(commands):
            rows.append(row(planner, i, command, CONFIGS[name]))
            print(json.dumps({"config": name, **{k: v for k, v in rows[-1].items() if k != "warnings"}}), flush=True)
        record["rows"][name] = rows
        record["summary"].append(summary(name, rows, record["rows"]["plain"]))
        print(json.dumps(record["summary"][-1]), flush=True)
        atomic_write_json(args.out, record)
    record["wall_s"] = time.perf_counter() - started
    record["load_average_end"] = os.getloadavg()
    atomic_write_json(args.out, record)


if __name__ == "__main__":
    main()
