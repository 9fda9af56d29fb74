"""The pancake Deformer's own fast path (plain ``deform``, no polish): feasibility against end error.

For every model given (a shipped name or a model/run directory), deform the same fresh position-type
sketches one at a time (each at its own length, ``states[b, :lengths[b]]``) and report

* feasible share: max F_c ≤ 0.01 rad at the model's μ;
* end-position error (y, z) [mm]: median, p90, mean;
* end speed |(v_y, v_z)| of the deformed motion [m/s]: median, and the share still faster than 0.1 m/s
  (every sketch ends at rest);
* shape RMSE (y, z) over the whole motion [mm]: median;
* deformation time per trajectory [ms]: median wall time of one ``deform`` call.

Run from the repository root::

    python benchmarks/bench_fast_path.py pancake /tmp/finetune/ft_end100_rest10 --n 500 --seed 2027

(``--json PATH`` also writes the rows). Single-threaded torch, as the other benchmarks.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

import seqmotion as sm
from seqmotion.api import resolve_model
from seqmotion.training.provenance import machine_description

LENGTH_BINS = ((100, 200), (200, 300), (300, 400), (400, 501))
"""Sketch lengths K [samples at 1 ms] the results are also broken down by (short sketches move fastest)."""


def measure(model_ref: str, sketches: list[np.ndarray]) -> dict:
    model = resolve_model(model_ref, "pancake")
    model.deform(sketches[0])  # warm-up (first call builds caches)
    end_err, end_speed, shape, max_fc, seconds = [], [], [], [], []
    for states in sketches:
        start = time.perf_counter()
        result = model.deform(states)
        seconds.append(time.perf_counter() - start)
        out = result.states
        end_err.append(np.linalg.norm(out[-1, :2] - states[-1, :2]))
        end_speed.append(np.linalg.norm(out[-1, 3:5]))
        shape.append(np.sqrt((np.linalg.norm(out[:, :2] - states[:, :2], axis=-1) ** 2).mean()))
        max_fc.append(float(result.violation.max()))
    end_err, end_speed, shape, max_fc = (np.asarray(v) for v in (end_err, end_speed, shape, max_fc))
    lengths = np.array([len(s) for s in sketches])
    by_length = {}
    for lo, hi in LENGTH_BINS:
        sel = (lengths >= lo) & (lengths < hi)
        by_length[f"K {lo}-{hi - 1}"] = {
            "n": int(sel.sum()), "feasible_share": float((max_fc[sel] <= 0.01).mean()),
            "end_error_mm_median": float(np.median(end_err[sel]) * 1e3),
            "end_speed_m_s_median": float(np.median(end_speed[sel])),
        }
    return {
        "model": model_ref,
        "feasible_share": float((max_fc <= 0.01).mean()),
        "end_error_mm_median": float(np.median(end_err) * 1e3),
        "end_error_mm_p90": float(np.percentile(end_err, 90) * 1e3),
        "end_error_mm_mean": float(end_err.mean() * 1e3),
        "end_speed_m_s_median": float(np.median(end_speed)),
        "end_moving_share": float((end_speed > 0.1).mean()),
        "shape_rmse_mm_median": float(np.median(shape) * 1e3),
        "max_fc_rad_max": float(max_fc.max()),
        "ms_per_trajectory_median": float(np.median(seconds) * 1e3),
        "by_length": by_length,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+", help="shipped model names or model/run directories")
    parser.add_argument("--n", type=int, default=500, help="fresh position-type sketches")
    parser.add_argument("--seed", type=int, default=2027)
    parser.add_argument("--json", help="also write the rows here")
    args = parser.parse_args()
    torch.set_num_threads(1)

    batch = sm.tasks.pancake.data.position_type(args.n, np.random.default_rng(args.seed))
    sketches = [batch.states[b, : batch.lengths[b]] for b in range(args.n)]
    sketch_end_speed = np.array([np.linalg.norm(s[-1, 3:5]) for s in sketches])
    print(f"# {args.n} position-type sketches, position_type({args.n}, default_rng({args.seed})); "
          f"mean K {batch.lengths.mean():.0f}; sketches' max end speed {sketch_end_speed.max():.2g} m/s")
    print(f"# machine: {machine_description()}")
    rows = [measure(m, sketches) for m in args.models]
    header = ("model", "feasible", "end err med [mm]", "p90 [mm]", "mean [mm]", "end speed med [m/s]",
              "end > 0.1 m/s", "shape RMSE med [mm]", "ms/traj")
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for r in rows:
        print(f"| {r['model']} | {100 * r['feasible_share']:.1f} % | {r['end_error_mm_median']:.1f} | "
              f"{r['end_error_mm_p90']:.1f} | {r['end_error_mm_mean']:.1f} | {r['end_speed_m_s_median']:.3f} | "
              f"{100 * r['end_moving_share']:.1f} % | {r['shape_rmse_mm_median']:.1f} | "
              f"{r['ms_per_trajectory_median']:.1f} |")
    print("\nBy sketch length (feasible share / median end error [mm] / median end speed [m/s]):\n")
    bins = list(rows[0]["by_length"])
    print("| model | " + " | ".join(f"{b} (n={rows[0]['by_length'][b]['n']})" for b in bins) + " |")
    print("|" + "---|" * (len(bins) + 1))
    for r in rows:
        cells = [f"{100 * v['feasible_share']:.0f} % / {v['end_error_mm_median']:.0f} / {v['end_speed_m_s_median']:.2f}"
                 for v in r["by_length"].values()]
        print(f"| {r['model']} | " + " | ".join(cells) + " |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"n": args.n, "seed": args.seed, "machine": machine_description(), "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
