"""Exact latent adjustment against the strong IPOPT peer, and the default method's speed, in one run.

    python benchmarks/bench_latent.py peer [--fresh 50] [--seed 2026] [--model DIR] [--out FILE]
    python benchmarks/bench_latent.py timing [--model DIR]

``peer``: on the dissertation's 27 end-pose targets and on ``--fresh`` targets drawn uniformly
from y, z ∈ [−0.1, 0.1] m, θ ∈ [−π, π] (``--seed``), K = 500, S-curve inputs: per target, side by
side (order alternating), IPOPT with the friction cone as hard force-form constraints cold from
the S-curve, and ``optimize_latent(..., exact=True)``; plus the default call's J1 after 5
updates (``seqmotion.reproduce.ch4.peer``). Prints one JSON line per target set with the summary
and writes every row to ``--out`` (JSON).
``timing``: seconds per update per case and method, one K = 500 trajectory and 27 in a batch.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

import seqmotion as sm
from seqmotion.io import atomic_write_json
from seqmotion.reproduce import ch4
from seqmotion.training.provenance import machine_description


def fresh_targets(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.1, 0.1, n), rng.uniform(-0.1, 0.1, n), rng.uniform(-np.pi, np.pi, n)])


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("what", choices=["timing", "peer"])
    parser.add_argument("--model")
    parser.add_argument("--fresh", type=int, default=50)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--out", default="bench_latent_peer.json")
    args = parser.parse_args()
    torch.set_num_threads(1)
    deformer = sm.load(args.model) if args.model else sm.load_pretrained("pancake")
    if args.what == "timing":
        print(json.dumps({"timing": ch4.timing(deformer), "machine": machine_description()}))
        return
    record = {"machine": machine_description(), "seed": args.seed, "sets": {}}
    for name, targets in (("dissertation 27", ch4.TARGETS), (f"fresh {args.fresh}", fresh_targets(args.fresh,
                                                                                                  args.seed))):
        rows = ch4.peer(deformer, targets)
        summary = ch4.peer_summary(rows)
        record["sets"][name] = {"summary": summary, "rows": rows}
        print(json.dumps({"set": name, **summary}), flush=True)
    atomic_write_json(args.out, record)


if __name__ == "__main__":
    main()
