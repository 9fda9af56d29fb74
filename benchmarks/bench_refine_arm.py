"""Do refined sliding plans survive execution on the simulated arm? (issue 32, item 4)

    python benchmarks/bench_refine_arm.py            # the README's plan examples, plain and refined
    python benchmarks/bench_refine_arm.py --dither   # also the refinement with accelerations + 50 Hz dither

For each README plan example (a 5 cm line in 0.5 s, the 5 cm circle at K = 900 and at the default
K = 1200) the shipped planner plans, and :func:`seqmotion.refine_plan` refines, at two frictions:
the planner's nominal μ = 1.0, μ' = 0.5 (what ``seqmotion plan`` uses by default) and the arm's
μ = μ' = 0.5 (:data:`seqmotion.sim.sliding.ARM_FRICTION`). Each plan is executed by
:func:`seqmotion.sim.run_sliding` (ch. 3 gains, PD + DOB). Printed per row: the object's RMSE
against the command in the 2-D physics and on the arm [mm], the arm's RMSE against the plan's own
2-D prediction, the object's largest lift off the pan [mm] and where the command was placed on
the pan. One MuJoCo run at a time; ~1 min on 2 cores. Prints a Markdown table and JSON lines.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import seqmotion as sm
from seqmotion.sim.sliding import ARM_FRICTION, run_sliding

NOMINAL = {"mu": 1.0, "mu_dyn": 0.5}
"""The planner's nominal friction (its ``options``; the default of ``plan`` and ``refine_plan``)."""


def examples() -> dict[str, np.ndarray]:
    """The README's plan commands, ``(K, 4)`` each."""
    return {
        "line 5 cm, K = 500": sm.tasks.sliding.data.line(0.05, 500),
        "circle 5 cm, K = 900": sm.tasks.sliding.data.circle(0.05, 900),
        "circle 5 cm, K = 1200": sm.tasks.sliding.data.circle(0.05, 1200),
    }


def rmse_mm(rel_states: np.ndarray, command: np.ndarray) -> float:
    """Object RMSE against the command in the 2-D physics [mm]."""
    return float(1e3 * np.sqrt(((rel_states[:, :2] - command[:, :2]) ** 2).sum(1).mean()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dither", action="store_true", help="also refine with accelerations and the 50 Hz dither")
    args = parser.parse_args()
    planner = sm.load_pretrained("sliding")
    rows = []
    for name, command in examples().items():
        for label, friction in (("μ 1.0 / 0.5 (nominal)", NOMINAL), ("μ 0.5 / 0.5 (arm)", ARM_FRICTION)):
            start = time.perf_counter()
            plans = {"plain": planner.plan(command, **friction),
                     "refined": sm.refine_plan(planner, command, **friction)}
            if args.dither:
                plans["refined + accel + dither"] = sm.refine_plan(planner, command, accel_steps=100, dither=1.2,
                                                                   **friction)
            seconds = time.perf_counter() - start
            for kind, plan in plans.items():
                result = run_sliding(plan, command)
                row = {"example": name, "friction": label, "plan": kind,
                       "rmse_2d_mm": rmse_mm(plan.rel_states, command),
                       "rmse_arm_mm": 1e3 * result.rmse, "arm_vs_plan_mm": 1e3 * result.rmse_plan,
                       "lift_max_mm": 1e3 * float(result.object_height[: result.n_motion].max()),
                       "origin_mm": (1e3 * result.origin).round(1).tolist(), "fell_off": result.fell_off,
                       "tipped": result.tipped, "pan_rmse_mm": 1e3 * result.pan_rmse, "plan_seconds": seconds}
                rows.append(row)
                print(json.dumps(row), flush=True)
    print("\n| example | planned at | plan | 2-D RMSE [mm] | arm RMSE [mm] | arm vs plan [mm] | lift [mm] |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['example']} | {r['friction']} | {r['plan']} | {r['rmse_2d_mm']:.1f} | {r['rmse_arm_mm']:.1f} | "
              f"{r['arm_vs_plan_mm']:.1f} | {r['lift_max_mm']:.2f} |")


if __name__ == "__main__":
    main()
