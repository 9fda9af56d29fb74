"""Outputs of every shipped model on fixed inputs, to check that a change leaves them as they were.

    python benchmarks/check_shipped_outputs.py save before.npz      # on the code before the change
    python benchmarks/check_shipped_outputs.py compare before.npz   # on the code after it

It deforms a sketch and a batch with `pancake`, runs five LM and three line-search updates of
latent optimisation and the first step of the online generator, plans two circles at two
frictions with every shipped sliding model and encodes three images with `pushing`, and prints
the largest absolute difference per output (WORST: over all).
"""

from __future__ import annotations

import math
import sys

import numpy as np

import seqmotion as sm

SLIDING = ["sliding", "sliding-A-nominal", "sliding-A-velocity", "sliding-B", "sliding-C"]


def outputs() -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    d = sm.load_pretrained("pancake")
    sketch = sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 500)
    r = d.deform(sketch)
    out.update({"pancake.states": r.states, "pancake.accel": r.accel, "pancake.violation": r.violation,
                "pancake.latent": r.latent})
    rng = np.random.default_rng(0)
    ends = [(rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(-3, 3)) for _ in range(4)]
    out["pancake.batch"] = d.deform(np.stack([sm.tasks.pancake.data.straight(e, 300) for e in ends])).states
    target = sm.objectives.EndPose((0.1, 0.0, math.pi))
    out["pancake.lm"] = sm.optimize_latent(d, sketch, target, steps=5, optimizer="lm", continuation=(1e-3, 4)).states
    out["pancake.j2"] = sm.optimize_latent(d, sketch, sm.objectives.Ranges(), steps=3).states
    out["pancake.gen0"] = d.generator(sketch).step()
    for name in SLIDING:
        planner = sm.load_pretrained(name)
        plan = planner.plan(sm.tasks.sliding.data.circle(0.05, 1200))
        out[f"{name}.pan"], out[f"{name}.rel"] = plan.pan_states, plan.rel_states
        out[f"{name}.pan2"] = planner.plan(sm.tasks.sliding.data.circle(0.03, 800), mu=0.6, mu_dyn=0.3).pan_states
    images = np.random.default_rng(1).uniform(0, 1, (3, 64, 64, 3)).astype(np.float32)
    out["pushing.latent"] = sm.load_pretrained("pushing").latent(images)
    return out


def main() -> None:
    if len(sys.argv) != 3 or sys.argv[1] not in ("save", "compare"):
        raise SystemExit(__doc__)
    current = outputs()
    if sys.argv[1] == "save":
        np.savez(sys.argv[2], **current)
        print(f"saved {len(current)} outputs to {sys.argv[2]}")
        return
    worst = 0.0
    with np.load(sys.argv[2]) as before:
        for key in before.files:
            diff = float(np.max(np.abs(before[key] - current[key]))) if key in current else math.inf
            worst = max(worst, diff)
            print(f"{key:28s} max|diff| {diff:.2e}")
    print("WORST", worst)


if __name__ == "__main__":
    main()
