"""Measure the Gymnasium environments and the closed loop through them (issue 18, item 3).

(a) What the environments declare: ``dt``, ``metadata["render_fps"]``, observation fields, action
    spaces; whether ``import seqmotion`` registers the ids without importing MuJoCo; the wall time
    of one 1 kHz step.
(b) Random actions (uniform over the action space, ``frame_skip=10``): how many of N episodes end
    within 60 steps, per action mode.
(c) The closed loop (:func:`seqmotion.sim.closed_loop.run_episode`): the shipped pancake
    Deformer's online generator drives ``seqmotion/PancakeArm-v0`` (``action="accel"``,
    ``frame_skip=1``: one decoder output per 1 ms step) through ``--n`` pancake-turning sketches
    (:func:`~seqmotion.sim.closed_loop.turning_sketch`, drawn with ``--seed``; sketches whose
    deformed motion is infeasible or leaves the arm's workspace are set aside, counted, and the
    next drawn). Episode i uses seed i for the pancake's placement (±5 mm) and the measurement
    noise σ = (1 mm, 1 mm, 10 mrad, 2 cm/s, 2 cm/s, 0.2 rad/s). Configurations:

    * ``open``   — the generator fed its own reference (no measurement): ``deform`` executed;
    * ``exact``  — fed the measured state without noise, whole-chunk replanning;
    * ``chunk``  — measured + noise, whole-chunk replanning (every C = 50 samples);
    * ``sample`` — measured + noise, per-sample replanning (falls back to whole chunks, and says
      so, where the stepper accepts only whole chunks).

    "Kept on": the pancake never lost contact during the motion (slip ≤ 5 mm, gap ≤ 2 mm, as
    ``run_pancake``'s ``contact_lost``). End-pose error: the executed spatula at the motion's last
    sample against the noise-free ``deform`` output's last sample (position norm of y, z; |θ|).

Usage: ``python benchmarks/bench_envs.py [--n 100] [--seed 0] [--json out.json]`` (torch on one
thread; ≈ 4 min on 2 idle cores).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import gymnasium as gym
import numpy as np
import torch

import seqmotion as sm
from seqmotion.sim.closed_loop import PANCAKE_NOISE, draw_turning_episodes, run_episode
from seqmotion.training.provenance import machine_description

CONFIGS = {
    "open": {"feedback": "reference", "noise": None, "replan_every": "chunk"},
    "exact": {"feedback": "measured", "noise": None, "replan_every": "chunk"},
    "chunk": {"feedback": "measured", "noise": PANCAKE_NOISE, "replan_every": "chunk"},
    "sample": {"feedback": "measured", "noise": PANCAKE_NOISE, "replan_every": "sample"},
}

IMPORT_CHECK = """
import sys, time
t = time.perf_counter()
import seqmotion
import gymnasium as gym
seconds = time.perf_counter() - t
light = "mujoco" not in sys.modules and "seqmotion.sim.envs" not in sys.modules
env = gym.make("seqmotion/PancakeArm-v0")
print(seconds, light, type(env.unwrapped).__name__)
"""


def declared() -> dict:
    out = subprocess.run([sys.executable, "-c", IMPORT_CHECK], capture_output=True, text=True, check=True)
    seconds, light, cls = out.stdout.split()
    rows = {"import_seqmotion_s": float(seconds), "registered_without_mujoco": light == "True", "made": cls}
    for env_id in ("seqmotion/PancakeArm-v0", "seqmotion/SlidingArm-v0"):
        for kwargs in ({}, {"frame_skip": 1, "action": "accel"}):
            env = gym.make(env_id, **kwargs)
            base = env.unwrapped
            rows[f"{env_id} {kwargs}"] = {
                "dt_s": base.dt, "render_fps": env.metadata["render_fps"],
                "observation": {name: [f.slice.start, f.slice.stop, list(f.names), list(f.units)]
                                for name, f in base.fields.items()},
                "model_layout": str(base.model_layout),
                "action": str(base.action_layout),
                "action_low_high": [base.physical_action_space.low.tolist(), base.physical_action_space.high.tolist()],
            }
            env.close()
    return rows


def step_speed(steps: int = 2000) -> dict:
    """Wall time of one ``step`` at 1 kHz (``action="accel"``, ``frame_skip=1``), holding still."""
    out = {}
    for env_id in ("seqmotion/PancakeArm-v0", "seqmotion/SlidingArm-v0"):
        env = gym.make(env_id, action="accel", frame_skip=1, time_limit=None)
        env.reset(seed=0)
        hold = np.zeros(env.action_space.shape)
        times = []
        for _ in range(steps):
            t = time.perf_counter()
            env.step(hold)
            times.append(time.perf_counter() - t)
        out[env_id] = {"steps": steps, "us_p50_p99": (np.percentile(times, [50, 99]) * 1e6).tolist(),
                       "realtime_factor": 1e-3 / float(np.mean(times))}
        env.close()
    return out


def random_actions(n: int, steps: int = 60) -> dict:
    """How many of ``n`` episodes of uniformly random actions end within ``steps`` steps (frame_skip 10).

    Runs in a temporary directory: MuJoCo logs an unstable simulation to ``MUJOCO_LOG.TXT`` in the
    working directory.
    """
    here = os.getcwd()
    with tempfile.TemporaryDirectory() as scratch:
        os.chdir(scratch)
        try:
            return _random_actions(n, steps)
        finally:
            os.chdir(here)


def _random_actions(n: int, steps: int) -> dict:
    out = {}
    for mode in ("planar", "accel", "pose"):
        env = gym.make("seqmotion/PancakeArm-v0", action=mode, normalize_actions=True)
        env.action_space.seed(0)
        ended, why = 0, {}
        for episode in range(n):
            env.reset(seed=episode)
            for _ in range(steps):
                _, _, terminated, _, info = env.step(env.action_space.sample())
                if terminated:
                    ended += 1
                    reason = "out_of_workspace" if "out_of_workspace" in info else (
                        "unstable" if "unstable" in info else "pancake off")
                    why[reason] = why.get(reason, 0) + 1
                    break
        out[mode] = {"episodes": n, "ended_within_steps": ended, "steps": steps, "why": why}
        env.close()
    return out


def closed_loop(n: int, seed: int, configs: list[str]) -> dict:
    deformer = sm.load_pretrained("pancake")
    start = time.perf_counter()
    sketches, counts = draw_turning_episodes(deformer, n, seed)
    counts["draw_s"] = time.perf_counter() - start
    env = gym.make("seqmotion/PancakeArm-v0", action="accel", frame_skip=1)
    results: dict = {"sketches": counts, "n": n, "seed": seed,
                     "sketch_end_theta_abs_rad_min_max": [float(min(abs(s[-1, 2]) for s in sketches)),
                                                          float(max(abs(s[-1, 2]) for s in sketches))],
                     "sketch_lengths_min_max": [min(len(s) for s in sketches), max(len(s) for s in sketches)]}
    for name in configs:
        rows = []
        start = time.perf_counter()
        for i, sketch in enumerate(sketches):
            rows.append(run_episode(env, deformer, sketch, seed=i, **CONFIGS[name]).summary())
        wall = time.perf_counter() - start
        pos = np.array([r["end_position_error"] for r in rows]) * 1e3
        att = np.degrees([r["end_attitude_error"] for r in rows])
        pos_sk = np.array([r["end_position_error_sketch"] for r in rows]) * 1e3
        results[name] = {
            **CONFIGS[name], "noise": CONFIGS[name]["noise"],
            "replanning": sorted({r["replanning"] for r in rows}),
            "kept_on": int(sum(r["kept_on"] for r in rows)),
            "kept_on_share": float(np.mean([r["kept_on"] for r in rows])),
            "lost_in_tail": int(sum(r["lost_in_tail"] for r in rows)),
            "ended_early": [r["ended"] for r in rows if r["ended"]],
            "lost": [{"episode": i, "lost_time_s": r["lost_time"], "max_slip_mm": 1e3 * r["max_slip"]}
                     for i, r in enumerate(rows) if not r["kept_on"]],
            "max_slip_mm_p50_p90_max": np.percentile([1e3 * r["max_slip"] for r in rows], [50, 90, 100]).tolist(),
            "end_position_error_mm_mean_p50_p90_max": [float(np.nanmean(pos)), *np.nanpercentile(pos, [50, 90, 100])],
            "end_attitude_error_deg_mean_p50_p90_max": [float(np.nanmean(att)), *np.nanpercentile(att, [50, 90, 100])],
            "end_position_error_vs_sketch_mm_mean": float(np.nanmean(pos_sk)),
            "tracking_rmse_mm_p50_max": [float(np.median([1e3 * r["tracking_rmse"] for r in rows])),
                                         float(max(1e3 * r["tracking_rmse"] for r in rows))],
            "plan_rmse_mm_p50_max": [float(np.median([1e3 * r["plan_rmse"] for r in rows])),
                                     float(max(1e3 * r["plan_rmse"] for r in rows))],
            "generator_calls_mean": float(np.mean([r["generator_calls"] for r in rows])),
            "generator_ms_p50_of_medians_max": [float(np.median([r["generator_ms_p50_max"][0] for r in rows])),
                                                float(max(r["generator_ms_p50_max"][1] for r in rows))],
            "wall_s": wall,
        }
        print(json.dumps({name: {k: v for k, v in results[name].items() if k not in ("lost",)}}, default=str),
              flush=True)
    env.close()
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100, help="closed-loop episodes")
    parser.add_argument("--seed", type=int, default=0, help="of the sketches")
    parser.add_argument("--configs", default=",".join(CONFIGS), help=f"comma-separated subset of {list(CONFIGS)}")
    parser.add_argument("--random", type=int, default=100, help="random-action episodes per action mode (0: skip)")
    parser.add_argument("--json", help="write all numbers here")
    args = parser.parse_args()
    torch.set_num_threads(1)  # a 2 × 64 decoder step is fastest on one thread; no oversubscription
    configs = [c for c in args.configs.split(",") if c]
    unknown = sorted(set(configs) - set(CONFIGS))
    if unknown:
        parser.error(f"unknown configs {unknown}; choose from {list(CONFIGS)}")
    start = time.perf_counter()
    results = {"machine": machine_description(), "declared": declared()}
    print(json.dumps({"declared": results["declared"]}, default=str), flush=True)
    results["step_speed"] = step_speed()
    print(json.dumps({"step_speed": results["step_speed"]}), flush=True)
    if args.random:
        results["random_actions"] = random_actions(args.random)
        print(json.dumps({"random_actions": results["random_actions"]}), flush=True)
    if args.n:
        results["closed_loop"] = closed_loop(args.n, args.seed, configs)
    results["bench_wall_s"] = time.perf_counter() - start
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2, default=str)


if __name__ == "__main__":
    main()
