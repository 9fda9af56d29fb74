"""Speed of the restructured code against the code before it, measured in one run, alternating.

The restructuring (typed options, task-generic model, one training loop, one arm layer) must not
slow anything down. This script times the same work with two source trees — ``--before DIR``
(a checkout of the commit before the change; its ``src/`` is put first on ``PYTHONPATH``) and the
current tree — in alternating subprocesses, so both see the same machine load, and prints the
medians and their ratio. Usage::

    git worktree add /tmp/before 1035cb7
    python benchmarks/bench_refactor.py --before /tmp/before --rounds 3
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

WORK = r'''
import json, math, sys, tempfile, time, csv
import numpy as np
import seqmotion as sm
from seqmotion import tasks

def median_time(fn, n):
    fn()
    times = []
    for _ in range(n):
        t = time.perf_counter(); fn(); times.append(time.perf_counter() - t)
    return float(np.median(times))

out = {}
d = sm.load_pretrained("pancake")
sketch = sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 500)
batch = np.repeat(sketch[None], 128, axis=0)
out["deform_k500_ms"] = 1000 * median_time(lambda: d.deform(sketch), 50)
out["deform_batch128_ms"] = 1000 * median_time(lambda: d.deform(batch), 5)
target = sm.objectives.EndPose((0.1, 0.0, math.pi))
res = sm.optimize_latent(d, sketch, target, steps=10, optimizer="lm", continuation=(1e-3, 4))
out["lm_update_ms"] = 1000 * res.seconds_per_update
res = sm.optimize_latent(d, sketch, target, steps=10)
out["line_search_update_ms"] = 1000 * res.seconds_per_update
p = sm.load_pretrained("sliding")
command = sm.tasks.sliding.data.circle(0.05, 1200)
out["plan_k1200_ms"] = 1000 * median_time(lambda: p.plan(command), 10)

def train_step(task_name, steps):
    cfg = tasks.get(task_name).train_config("small")
    with tempfile.TemporaryDirectory() as run:
        try:
            from seqmotion.tasks import train
            train(cfg, run, progress=False, stop_at_step=steps)
        except ImportError:
            from seqmotion.training.trainer import train
            train(cfg, run, progress=False, stop_at_step=steps)
        rows = list(csv.DictReader(open(run + "/metrics.csv")))
    seconds = [float(r["seconds"]) for r in rows]
    return (seconds[-1] - seconds[4]) / (len(seconds) - 5)  # per step, after 5 warm-up steps

out["train_pancake_small_s_per_step"] = train_step("pancake", 25)
out["train_sliding_small_s_per_step"] = train_step("sliding", 15)
print(json.dumps(out))
'''


def run(src: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src)}
    with tempfile.TemporaryDirectory() as cwd:
        done = subprocess.run([sys.executable, "-c", WORK], env=env, cwd=cwd, capture_output=True, text=True,
                              check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", required=True, help="checkout of the code before the change")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    here = Path(__file__).resolve().parents[1] / "src"
    trees = {"before": Path(args.before) / "src", "after": here}
    results: dict[str, list[dict]] = {"before": [], "after": []}
    for round_ in range(args.rounds):  # alternate which tree goes first, so warm-up favours neither
        order = list(trees) if round_ % 2 == 0 else list(reversed(trees))
        for name in order:
            results[name].append(run(trees[name]))
    keys = list(results["after"][0])
    print(f"load average at the end: {os.getloadavg()}")
    print("| measure | before (median; all rounds) | after (median; all rounds) | after / before |")
    print("|---|---|---|---|")
    for key in keys:
        before = [r[key] for r in results["before"]]
        after = [r[key] for r in results["after"]]
        b, a = statistics.median(before), statistics.median(after)
        spread = "; ".join(f"{v:.3g}" for v in before), "; ".join(f"{v:.3g}" for v in after)
        print(f"| {key} | {b:.4g} ({spread[0]}) | {a:.4g} ({spread[1]}) | {a / b:.3f} |")


if __name__ == "__main__":
    main()
