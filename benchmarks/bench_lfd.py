"""Time the chapter-5 default pipeline: collect the demonstrations, train the default models, evaluate.

    python benchmarks/bench_lfd.py --out runs/lfd/bench            # everything (~10 min, smaller preset)
    python benchmarks/bench_lfd.py --out runs/lfd/bench --skip-train

Parts: collect 90 motions and 18 pairs per camera (3 cameras); train the SeqAE and the three
CNNs (default camera and the two moved ones, SeqAE reused); train the end-to-end baseline on
the default camera's 18 pairs; evaluate the proposed policy (30 trials, default camera).

Runs the same code as ``seqmotion lfd collect`` / ``train`` / ``evaluate`` (one torch thread),
records each part's wall time and CPU time with the machine's load average (other jobs share
the CPU), and writes ``bench_lfd.json`` in ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path


def _cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _timed(parts: dict, name: str, fn, *args, **kwargs):  # noqa: ANN001, ANN202 - a small timing helper
    load_before = os.getloadavg()[0]
    wall, cpu = time.perf_counter(), _cpu_seconds()
    result = fn(*args, **kwargs)
    parts[name] = {
        "wall_s": round(time.perf_counter() - wall, 1),
        "cpu_s": round(_cpu_seconds() - cpu, 1),
        "load_before": round(load_before, 2),
        "load_after": round(os.getloadavg()[0], 2),
    }
    print(f"{name}: {parts[name]}", file=sys.stderr, flush=True)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--preset", help="default: seqmotion.lfd.train.DEFAULT_PRESET")
    parser.add_argument("--seqae-epochs", type=int, help="default: seqmotion lfd train's")
    parser.add_argument("--skip-train", action="store_true")
    args = parser.parse_args()

    import torch

    torch.set_num_threads(1)
    from seqmotion.lfd import evaluate, train
    from seqmotion.lfd.data import dataset
    from seqmotion.lfd.policy.policy import PushingPolicy
    from seqmotion.training.provenance import machine_record

    out = Path(args.out)
    parts: dict[str, dict] = {}
    data = out / "data"
    _timed(
        parts, "collect_motions_90", dataset.collect, data, ["motions"], seed=args.seed, progress=False, overwrite=True
    )
    for camera in ("default", "position1", "position2"):
        _timed(
            parts,
            f"collect_pairs_{camera}_18",
            dataset.collect,
            data,
            [f"pairs_{camera}"],
            seed=args.seed,
            progress=False,
            overwrite=True,
        )
    preset = args.preset or train.DEFAULT_PRESET
    if not args.skip_train:
        settings, e2e_settings, cnn_settings = train.default_settings(preset)
        if args.seqae_epochs:
            settings.epochs = args.seqae_epochs
        report = _timed(
            parts,
            "train_seqae_and_3_cnns",
            train.train,
            data,
            out / "models",
            preset,
            ("proposed",),
            ("default", "position1", "position2"),
            args.seed,
            settings,
            e2e_settings,
            cnn_settings,
            progress=False,
        )
        parts["train_seqae_and_3_cnns"]["split_s"] = {k: round(v, 1) for k, v in report.seconds.items()}
        e2e = _timed(
            parts,
            "train_end_to_end_default",
            train.train,
            data,
            out / "models",
            preset,
            ("end_to_end",),
            ("default",),
            args.seed,
            settings,
            e2e_settings,
            cnn_settings,
            progress=False,
        )
        parts["train_end_to_end_default"]["split_s"] = {k: round(v, 1) for k, v in e2e.seconds.items()}
        policy = PushingPolicy.from_pretrained(report.policies["proposed_default"])
        result = _timed(parts, "evaluate_30_trials", evaluate, policy, trials=5, seed=args.seed)
        parts["evaluate_30_trials"]["success_rate"] = result.success_rate
    total = sum(p["wall_s"] for k, p in parts.items() if not k.startswith("evaluate"))
    summary = {
        "parts": parts,
        "collect_and_train_wall_s": round(total, 1),
        "machine": machine_record(),
        "preset": preset,
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_lfd.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
