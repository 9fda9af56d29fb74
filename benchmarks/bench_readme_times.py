"""Every time the README states, measured as a newcomer meets it: each in a fresh process, first call and warm.

    python benchmarks/bench_readme_times.py [--json out.json]
    python benchmarks/bench_readme_times.py --busy [--only NAME ...] [--json out.json]

Run it on a quiet machine (pause other jobs): torch threads beside a busy process run 5-40x slower.
Each claim runs in its own interpreter (``python -c``), so imports, model loading, numba's and IPOPT's first
calls are what a new user pays on the first call; the warm figure is the median of later calls.
The demo is timed as ``seqmotion demo`` end to end.

``--busy`` measures how much a busy machine changes them: each claim (``--only`` picks some; the demo is left out
unless named), and ``seqmotion plan --circle 0.05 --length 900 --refine`` (its own ``done in …`` line), as the
machine is, then again beside a CPU hog on one core (``python -c 'while True: pass'``), with the 1-minute load
average before each.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SNIPPETS = {
    "deform K=500": """
import time, statistics
import seqmotion as sm
t0 = time.perf_counter(); deformer = sm.load_pretrained("pancake"); load = time.perf_counter() - t0
sketch = sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 500)
t0 = time.perf_counter(); deformer.deform(sketch); first = time.perf_counter() - t0
warm = []
for _ in range(30):
    t0 = time.perf_counter(); deformer.deform(sketch); warm.append(time.perf_counter() - t0)
print({"load_s": load, "first_s": first, "warm_median_s": statistics.median(warm)})
""",
    "deform keep_end": """
import time, statistics
import numpy as np
import seqmotion as sm
deformer = sm.load_pretrained("pancake")
rng = np.random.default_rng(2027)
times = []
for i in range(21):
    end = (rng.uniform(-0.2, 0.2), rng.uniform(-0.1, 0.1), rng.uniform(-3.0, 3.0))
    sketch = sm.tasks.pancake.data.straight(end, 500)
    t0 = time.perf_counter(); deformer.deform(sketch, keep_end=True); times.append(time.perf_counter() - t0)
print({"first_s": times[0], "warm_median_s": statistics.median(times[1:]), "warm_max_s": max(times[1:])})
""",
    "refine_plan circle 900": """
import time
import seqmotion as sm
planner = sm.load_pretrained("sliding")
circle = sm.tasks.sliding.data.circle(0.05, 900)
t0 = time.perf_counter(); sm.refine_plan(planner, circle); first = time.perf_counter() - t0
t0 = time.perf_counter(); sm.refine_plan(planner, circle); warm = time.perf_counter() - t0
print({"first_s": first, "warm_s": warm})
""",
}


def run_snippet(code: str) -> dict:
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                          env={**os.environ, "PYTHONWARNINGS": "ignore"})
    return eval(done.stdout.strip().splitlines()[-1])  # noqa: S307 - our own snippet's printed dict


CLI = {"seqmotion plan --refine": ["plan", "--circle", "0.05", "--length", "900", "--refine", "--output", "plan.npz"]}
"""Commands timed by ``--busy`` through their own last line (``done in 12.3 s``) and from outside."""


def run_cli(argv: list[str]) -> dict:
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    with tempfile.TemporaryDirectory() as folder:
        t0 = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "seqmotion.cli", *argv], cwd=folder, capture_output=True,
                              text=True, check=True, env=env)
        wall = time.perf_counter() - t0
    return {"wall_s": wall, "last_line": done.stdout.strip().splitlines()[-1]}


def busy(names: list[str]) -> dict:
    """Each named claim and each :data:`CLI` command as the machine is, then beside one core's CPU hog."""
    out: dict = {}
    for label, hog in (("as_is", False), ("with_hog", True)):
        spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if hog else None
        try:
            if spinner is not None:
                time.sleep(5)  # let the hog reach its core before the timing starts
            rows: dict = {"load_average_1min": round(os.getloadavg()[0], 2)}
            for name in names:
                if name == "seqmotion demo":
                    rows[name] = run_cli(["demo", "--out", "demo"])
                else:
                    rows[name] = run_snippet(SNIPPETS[name])
                print(label, name, rows[name], flush=True)
            for name, argv in CLI.items():
                rows[name] = run_cli(argv)
                print(label, name, rows[name], flush=True)
        finally:
            if spinner is not None:
                spinner.kill()
                spinner.wait()
        out[label] = rows
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path)
    parser.add_argument("--no-demo", action="store_true")
    parser.add_argument("--busy", action="store_true", help="as the machine is, then beside a CPU hog on one core")
    parser.add_argument("--only", nargs="+", choices=[*SNIPPETS, "seqmotion demo"], help="with --busy: these claims")
    args = parser.parse_args()
    from seqmotion.training.provenance import machine_description

    results: dict = {"machine": machine_description()}
    if args.busy:
        results["busy"] = busy(args.only or list(SNIPPETS))
        if args.json:
            args.json.write_text(json.dumps(results, indent=1))
        return
    for name, code in SNIPPETS.items():
        results[name] = run_snippet(code)
        print(name, results[name], flush=True)
    if not args.no_demo:
        with tempfile.TemporaryDirectory() as folder:
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "seqmotion.cli", "demo", "--out", folder], check=True,
                           capture_output=True, env={**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")})
            results["seqmotion demo"] = {"wall_s": time.perf_counter() - t0}
        print("seqmotion demo", results["seqmotion demo"], flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
