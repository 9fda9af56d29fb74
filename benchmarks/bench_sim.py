"""Measure the simulated robot layer (issue 5); prints the tables of ``benchmarks/RESULTS_sim.md``.

(a) The 3-D sim agrees with the 2-D friction-cone model: acceleration-type trajectories at
    φ_max = π/4 (feasible) should never lose contact; those at φ_max = π whose F_c exceeds
    0.2 rad somewhere should lose it in ≥ 90 %. Trajectories are drawn with a fixed seed;
    those the arm cannot execute (``workspace_problem``: out of reach, into the table) are
    set aside and counted, the next ones drawn, until 100 of each set have run.
(b) Simulation speed of the 1 ms control loop, rendering off (simulated / wall-clock time).
(c) Sliding scene: the pan shaken on circles at constant |u_p| around μg, and with a growing
    amplitude to find the breakaway acceleration.
(d) Calibration of the spatula: the pancake on a still spatula tilted 40–60°: holds below
    atan μ = 45°, and slides with the incline's acceleration g (sin θ - μ cos θ) above.

Usage: ``python benchmarks/bench_sim.py [--n 100] [--seed 0] [--json out.json]`` (≈ 1–2 min on 2 cores).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time

import numpy as np

from seqmotion.sim import GAP_LIMIT, SLIP_LIMIT, run_pancake, run_sliding, workspace_problem
from seqmotion.sim.kinematics import planar_reference
from seqmotion.sim.motions import pan_circle, pan_ramp, still
from seqmotion.tasks.pancake.data import acceleration_type
from seqmotion.tasks.pancake.physics import violation
from seqmotion.training.provenance import machine_record

MU_G = 0.5 * 9.8


def draw_set(phi_max: float, n: int, seed: int, min_violation: float | None):
    """``n`` executable acceleration-type trajectories (and how many were set aside, and why)."""
    rng = np.random.default_rng(seed)
    chosen, skipped_reach, skipped_fc, drawn = [], 0, 0, 0
    while len(chosen) < n:
        batch = acceleration_type(256, rng, phi_max=phi_max)
        for i in range(len(batch)):
            drawn += 1
            k = batch.lengths[i]
            states, accel = batch.states[i, :k], batch.accel[i, : k - 1]
            fc = float(violation(states, accel).max())
            if min_violation is not None and fc <= min_violation:
                skipped_fc += 1
                continue
            if workspace_problem(planar_reference(states), "pancake") is not None:
                skipped_reach += 1
                continue
            chosen.append((states, fc))
            if len(chosen) == n:
                break
    return chosen, {"drawn": drawn, "set_aside_out_of_workspace": skipped_reach, "set_aside_fc_small": skipped_fc}


def agreement(phi_max: float, n: int, seed: int, min_violation: float | None) -> dict:
    trajectories, counts = draw_set(phi_max, n, seed, min_violation)
    rows = []
    for states, fc in trajectories:
        r = run_pancake(states, gains="ch2", hold_time=0.0)
        rows.append({
            "K": len(states), "max_fc": fc, "lost": r.contact_lost, "lost_in_tail": r.contact_lost_in_tail,
            "max_slip": r.max_slip, "max_gap": r.max_gap, "pos_rmse": r.position_rmse, "att_rmse": r.attitude_rmse,
            "executed_fc": float(r.executed_violation.max(initial=0.0)), "diverged": r.diverged,
            "rt": r.realtime_factor, "wall": None,
        })
    lost = np.array([x["lost"] for x in rows])
    slip, gap = np.array([x["max_slip"] for x in rows]), np.array([x["max_gap"] for x in rows])
    # Sensitivity of the count to the (fixed) thresholds: halved and doubled.
    sens = {f"x{f}": float(np.mean((slip > f * SLIP_LIMIT) | (gap > f * GAP_LIMIT))) for f in (0.5, 2.0)}
    return {
        "phi_max": phi_max, "min_violation": min_violation, **counts, "n": len(rows),
        "lost_fraction": float(lost.mean()),
        "lost_or_lost_in_tail_fraction": float(np.mean([x["lost"] or x["lost_in_tail"] for x in rows])),
        "threshold_sensitivity": sens,
        "diverged": int(sum(x["diverged"] is not None for x in rows)),
        "max_slip_mm_percentiles_50_90_100": (np.percentile(slip, [50, 90, 100]) * 1e3).round(3).tolist(),
        "max_gap_mm_percentiles_50_90_100": (np.percentile(gap, [50, 90, 100]) * 1e3).round(3).tolist(),
        "position_rmse_mm_median_max": [float(np.median([x["pos_rmse"] for x in rows]) * 1e3),
                                        float(max(x["pos_rmse"] for x in rows) * 1e3)],
        "attitude_rmse_deg_median_max": [float(np.degrees(np.median([x["att_rmse"] for x in rows]))),
                                         float(np.degrees(max(x["att_rmse"] for x in rows)))],
        "executed_max_fc_rad_max": float(max(x["executed_fc"] for x in rows)),
        "not_lost": [{k: x[k] for k in ("K", "max_fc", "max_slip", "max_gap", "executed_fc")}
                     for x in rows if not x["lost"]][:10],
        "lost_list": [{k: x[k] for k in ("K", "max_fc", "max_slip", "max_gap", "executed_fc")}
                      for x in rows if x["lost"]][:10],
        "realtime_factor_median": float(np.median([x["rt"] for x in rows])),
    }


def speed(seed: int, repeats: int = 20) -> dict:
    """Control-loop speed (simulated time / wall time) over feasible trajectories, rendering off."""
    trajectories, _ = draw_set(math.pi / 4, repeats, seed + 1, None)
    sim_time = loop_wall = call_wall = 0.0
    factors = []
    for states, _ in trajectories:
        start = time.perf_counter()
        r = run_pancake(states, hold_time=0.5)
        call_wall += time.perf_counter() - start
        sim = (len(r.time) + 200) * 1e-3  # + the 0.2 s settling hold
        sim_time += sim
        loop_wall += sim / r.realtime_factor
        factors.append(r.realtime_factor)
    return {
        "runs": repeats, "simulated_s": sim_time, "loop_wall_s": loop_wall,
        "realtime_factor_aggregate": sim_time / loop_wall,
        "realtime_factor_min_median": [float(min(factors)), float(np.median(factors))],
        "realtime_factor_including_setup": sim_time / call_wall,
    }


def shaking() -> dict:
    """The object on the pan: steady circles at fractions of μg, and an amplitude ramp."""
    circles = []
    for frac in (0.6, 0.8, 0.9, 0.95, 1.05, 1.1, 1.25, 1.5):
        r = run_sliding(pan_circle(frac * MU_G, freq=3.0, duration=2.0, ramp=1.0), hold_time=0.0)
        steady = slice(1100, r.n_motion)
        moved = np.linalg.norm(r.object_path[steady] - r.object_path[steady][0], axis=1).max()
        speed_rel = np.linalg.norm(np.diff(r.object_path[steady], axis=0), axis=1).mean() / 1e-3
        circles.append({
            "commanded_over_mu_g": frac,
            "measured_accel_over_mu_g": float(np.linalg.norm(r.pan_accel[steady], axis=1).mean() / MU_G),
            "object_moved_in_steady_0.9s_mm": float(moved * 1e3),
            "mean_slip_speed_mm_s": float(speed_rel * 1e3),
            "fell_off": r.fell_off, "tipped": r.tipped,
        })
    r = run_sliding(pan_ramp(1.6 * MU_G, freq=4.0, duration=3.0), hold_time=0.0)
    rel_speed = np.linalg.norm(np.diff(r.object_path, axis=0), axis=1) / 1e-3
    accel = np.abs(r.pan_accel[:, 0])
    ramp = {}
    for threshold in (2e-3, 5e-3):  # relative speed that counts as sliding [m/s]; sticking creeps < 0.1 mm/s
        onset = int(np.flatnonzero(rel_speed > threshold)[0])
        peak_start = max(0, onset - 62)  # the acceleration peak that started it lies within ¼ period (62 ms)
        ramp[f"onset_{threshold * 1e3:g}mm_s"] = {
            "time_s": onset * 1e-3,
            "breakaway_peak_over_mu_g": float(accel[peak_start : onset + 1].max() / MU_G),
            "largest_earlier_peak_over_mu_g": float(accel[:peak_start].max() / MU_G),
        }
    return {"circles": circles, "ramp": ramp}


def incline() -> list[dict]:
    """Pancake on a still tilted spatula: slip after 0.4 s and the fitted sliding acceleration."""
    rows = []
    for deg in (40, 44, 46, 50, 60):
        r = run_pancake(still(math.radians(deg), 0.4), hold_time=0.0, settle_time=0.0)
        t, s = r.time[: r.n_motion], r.slip[: r.n_motion]
        sliding = (s > 1e-3) & (s < 0.06)  # after the 0.1 mm drop onto the blade, before the edge
        fitted = float(np.polyfit(t[sliding], np.gradient(s, 1e-3)[sliding], 1)[0]) if sliding.sum() > 20 else 0.0
        theory = max(0.0, 9.8 * (math.sin(math.radians(deg)) - math.cos(math.radians(deg))))
        rows.append({"tilt_deg": deg, "slip_after_0.4s_mm": float(s[-1] * 1e3), "contact_lost": r.contact_lost,
                     "fitted_accel_m_s2": fitted, "coulomb_accel_m_s2": theory})
    return rows


def machine() -> str:
    """The project's machine record in one line, with the MuJoCo version these timings depend on."""
    import mujoco

    m = machine_record()
    load = m["load_average"][0] if m["load_average"] else float("nan")
    return f"{m['processor']} × {m['cpus']} logical cores; {platform.system()} {platform.release()}; " \
           f"Python {m['python']}; MuJoCo {mujoco.__version__}; load average at start {load:.1f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100, help="trajectories per agreement set")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", help="write all numbers here")
    args = parser.parse_args()
    start = time.perf_counter()
    results = {"machine": machine()}
    results["feasible"] = agreement(math.pi / 4, args.n, args.seed, None)
    results["infeasible"] = agreement(math.pi, args.n, args.seed, 0.2)
    results["speed"] = speed(args.seed)
    results["sliding"] = shaking()
    results["incline"] = incline()
    results["bench_wall_s"] = time.perf_counter() - start
    print(json.dumps(results, indent=2))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2)


if __name__ == "__main__":
    main()
