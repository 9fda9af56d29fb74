"""Speed of latent-space adjustment (ch. 4) and the IPOPT peer, measured in one run.

    python benchmarks/bench_latent.py timing [--model DIR]
    python benchmarks/bench_latent.py peer [--model DIR] [--targets 0,4,13]

``timing``: seconds per update for one K = 500 trajectory and for all 27 targets in one batch,
per case (the dissertation: 1.21 s per update for cases 1 and 2, 1.05 s for case 3, i7-8700).
``peer``: per target, the wall time until J1 < 1e-3 for case 1 (a fresh run that stops at the
first update below the threshold, encoding included) and for IPOPT by direct transcription
(CasADi, from the same S-curve), with final J1 and max F_c. Prints JSON lines.
"""

from __future__ import annotations

import argparse
import json

import seqmotion as sm
from seqmotion.reproduce import ch4
from seqmotion.training.provenance import machine_description


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("what", choices=["timing", "peer"])
    parser.add_argument("--model")
    parser.add_argument("--targets", help="comma-separated indices into the 27 targets (default: all)")
    args = parser.parse_args()
    deformer = sm.load(args.model) if args.model else sm.load_pretrained("pancake")
    if args.what == "timing":
        print(json.dumps({"timing": ch4.timing(deformer), "machine": machine_description()}))
        return
    idx = [int(i) for i in args.targets.split(",")] if args.targets else range(len(ch4.TARGETS))
    for row in ch4.peer(deformer, ch4.TARGETS[list(idx)]):
        print(json.dumps({**row, "machine": machine_description()}))


if __name__ == "__main__":
    main()
