"""Trust signals (issue 17): does ``out_of_distribution`` flag what it should, and does the predicted
uncertainty say how far a result strays?

    python benchmarks/bench_trust.py [--n 400] [--out benchmarks/results_trust.md]

For the shipped ``pancake`` and ``sliding`` models, with the calibration they ship (``trust.json``):

* **fresh in-distribution inputs** (seeds the calibration never used) — the share flagged (target ≤ 5 %):
  pancake position-type sketches and the whole training curriculum's mixture at the trained lengths;
  sliding physics- and B-spline-type commands and the curriculum's mixture;
* **clearly out-of-distribution inputs** — the share flagged (target ≥ 90 %), and by which feature:
  lengths 2–4× the longest trained; lengths a fifth to a half of the shortest; held-out inputs scaled
  in space to 3× the largest extent met in training; to 3× the highest peak speed;
* **natural extrapolations** (no target; how often they are flagged and how far they stray): pancake
  sketches whose waypoints reach 3× as far, sliding B-spline commands reaching 3× as far;
* **correlation** (Spearman, Pearson) between the predicted uncertainty and the realised error on the
  held-out in-distribution inputs: the predicted end-position std vs the end-position error, and the
  RMS predicted std vs the shape / tracking RMSE;
* the cost: time of ``generate`` per call (covariance, errors, flag included) vs the bare decode.

Writes a Markdown report (machine and date included) and prints it.
"""

from __future__ import annotations

import argparse
import datetime
import time
from pathlib import Path

import numpy as np
import torch

import seqmotion as sm
from seqmotion.core import trust
from seqmotion.core.results import Motion
from seqmotion.tasks.pancake import data as pancake_data
from seqmotion.tasks.sliding import data as sliding_data
from seqmotion.training.provenance import machine_description


def rank(x: np.ndarray) -> np.ndarray:
    order = np.argsort(x, kind="stable")
    r = np.empty(len(x))
    r[order] = np.arange(len(x))
    return r


def correlations(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(Spearman, Pearson) of two samples."""
    return float(np.corrcoef(rank(a), rank(b))[0, 1]), float(np.corrcoef(a, b)[0, 1])


def unpad(states: np.ndarray, lengths: np.ndarray) -> list[np.ndarray]:
    return [s[:k] for s, k in zip(states, lengths, strict=True)]


def scaled(motion: np.ndarray, factor: float) -> np.ndarray:
    """The same motion ``factor`` times as large in space (positions and velocities; same timing)."""
    return motion * factor


def judge(model, motions: list[np.ndarray]) -> dict[str, np.ndarray | list]:  # noqa: ANN001
    """Generate every motion one at a time (the user's call): flags, reasons, errors, predicted std summaries."""
    flags, reasons, errs, end_std, rms_std, warned = [], [], [], [], [], []
    tolerances = model.task_def.tolerances(model.options)
    for m in motions:
        r = model.generate(m)
        warned.append(bool(trust.missed(r.errors, tolerances)))
        flags.append(bool(r.out_of_distribution))
        reasons.append(r.ood_reasons)
        errs.append(r.errors)
        metres = [i for i, u in enumerate(model.uncertainty_units) if u == "m"]
        end_std.append(float(np.linalg.norm(r.uncertainty[-1, metres])))
        rms_std.append(float(np.sqrt((np.linalg.norm(r.uncertainty[:, metres], axis=-1) ** 2).mean())))
    errors = {k: np.array([e[k] for e in errs]) for k in errs[0]}
    return {"flags": np.array(flags), "reasons": reasons, "errors": errors, "end_std": np.array(end_std),
            "rms_std": np.array(rms_std), "warned": np.array(warned)}


def feature_shares(reasons: list[list[str]]) -> str:
    counts: dict[str, int] = {}
    for rs in reasons:
        for r in rs:
            name = r.split()[0]
            counts[name] = counts.get(name, 0) + 1
    return ", ".join(f"{k} {100 * v / len(reasons):.3g} %" for k, v in sorted(counts.items(), key=lambda kv: -kv[1]))


def sets_for(name: str, model, n: int) -> tuple[dict, dict, dict]:  # noqa: ANN001
    """(in-distribution, clearly out-of-distribution, natural extrapolation) inputs: name → list of (K, D)."""
    cal = trust.calibration_for(model)
    lo, hi = int(cal.lower["length"]), int(cal.upper["length"])
    rng = np.random.default_rng(1234)
    ind, ood, nat = {}, {}, {}
    if name == "pancake":
        b = pancake_data.position_type(n, rng, length=(lo, hi))
        ind["position-type sketches, K 100–500"] = unpad(b.states, b.lengths)
        x, k = trust.training_inputs(model, n, seed=99)
        ind["training curriculum mixture (accel- + position-type)"] = unpad(x, k)
        b = pancake_data.position_type(n, rng, length=(2 * hi, 4 * hi))
        ood[f"position-type, K {2 * hi}–{4 * hi} (2–4× the longest trained)"] = unpad(b.states, b.lengths)
        b = pancake_data.position_type(n, rng, length=(lo // 5, lo // 2))
        ood[f"position-type, K {lo // 5}–{lo // 2} (≤ half the shortest)"] = unpad(b.states, b.lengths)
        b = pancake_data.position_type(n, rng, length=(lo, hi))
        held = unpad(b.states, b.lengths)
        nat_b = pancake_data.position_type(n, rng, length=(lo, hi))
        nat["position-type, waypoints ×3 (reach up to 0.9 m)"] = [scaled(s, 3.0) for s in unpad(nat_b.states,
                                                                                                 nat_b.lengths)]
        nat["position-type, waypoints ×1.5"] = [scaled(s, 1.5) for s in unpad(nat_b.states, nat_b.lengths)]
    else:
        b = sliding_data.physics_type(n // 2, rng, length=(lo, hi))
        c = sliding_data.bspline_type(n - n // 2, rng, length=(lo, hi))
        ind["physics- and B-spline-type commands, K 500–1500"] = unpad(b.states, b.lengths) + unpad(c.states,
                                                                                                   c.lengths)
        x, k = trust.training_inputs(model, n, seed=99)
        ind["training curriculum mixture"] = unpad(x, k)
        b = sliding_data.bspline_type(n, rng, length=(2 * hi, 4 * hi))
        ood[f"B-spline commands, K {2 * hi}–{4 * hi} (2–4× the longest trained)"] = unpad(b.states, b.lengths)
        b = sliding_data.bspline_type(n, rng, length=(lo // 5, lo // 2))
        ood[f"B-spline commands, K {lo // 5}–{lo // 2} (≤ half the shortest)"] = unpad(b.states, b.lengths)
        b = sliding_data.bspline_type(n, rng, length=(lo, hi))
        held = unpad(b.states, b.lengths)
        nat_b = sliding_data.bspline_type(n, rng, length=(lo, hi))
        nat["B-spline commands reaching 3× as far (30–240 mm)"] = [scaled(s, 3.0) for s in unpad(nat_b.states,
                                                                                                  nat_b.lengths)]
        nat["B-spline commands reaching 1.5× as far"] = [scaled(s, 1.5) for s in unpad(nat_b.states, nat_b.lengths)]
        nat["circles of radius 20–80 mm, K 500–1500"] = [
            sliding_data.circle(float(r), int(k)) for r, k in zip(rng.uniform(0.02, 0.08, n // 4),
                                                                  rng.integers(lo, hi + 1, n // 4), strict=True)]
    feats = [model.task_def.input_features(s[None]) for s in held]
    extent_key = "extent_m"
    speed_key = next(k for k in cal.upper if k.startswith("peak_speed_m"))
    ood["held-out inputs scaled in space to 3× the largest trained extent"] = [
        scaled(s, 3 * cal.upper[extent_key] / max(float(f[extent_key][0]), 1e-9)) for s, f in zip(held, feats,
                                                                                                  strict=True)]
    ood["held-out inputs scaled in space to 3× the highest trained peak speed"] = [
        scaled(s, 3 * cal.upper[speed_key] / max(float(f[speed_key][0]), 1e-9)) for s, f in zip(held, feats,
                                                                                                 strict=True)]
    return ind, ood, nat


def uncertainty_only(cal: trust.TrustCalibration, end_std: np.ndarray) -> float:
    return float((end_std > cal.upper[trust.UNCERTAINTY_FEATURE]).mean())


def timing(model, motion: np.ndarray, rounds: int = 9, repeats: int = 10) -> tuple[float, float]:  # noqa: ANN001
    """(ms per ``generate`` call, ms per call of the same work without the trust signals: encode, decode
    without covariance, violation, result) for one motion; interleaved rounds, the fastest of each (the
    machine is shared)."""
    x = torch.from_numpy(motion[None])

    def plain() -> None:
        with torch.inference_mode():
            z = model.encode_torch(x)
            states, accel = model.decode_torch(z, model.start_state(x).double(), len(motion))
            violation = model.violation_torch(states, accel)
            model.task_def.make_result(Motion(states.numpy(), accel.numpy(), z.numpy(),
                                              None if violation is None else violation.numpy()), model)

    best = {"generate": np.inf, "plain": np.inf}
    for _ in range(rounds):
        for key, call in (("generate", lambda: model.generate(motion)), ("plain", plain)):
            t = time.perf_counter()
            for _ in range(repeats):
                call()
            best[key] = min(best[key], (time.perf_counter() - t) / repeats)
    return 1000 * best["generate"], 1000 * best["plain"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=400, help="inputs per set")
    parser.add_argument("--out", default="benchmarks/results_trust.md")
    args = parser.parse_args()
    torch.set_num_threads(1)
    lines = ["# Trust signals: out-of-distribution flag and predicted uncertainty (issue 17)", "",
             f"`python benchmarks/bench_trust.py --n {args.n}` on {machine_description()}, "
             f"{datetime.date.today().isoformat()}. Each input generated one at a time, as a user would.", ""]
    for name in ("pancake", "sliding"):
        model = sm.load_pretrained(name)
        cal = trust.calibration_for(model)
        err_key = "end_position_error_m" if name == "pancake" else "end_error_m"
        rmse_key = "shape_rmse_m" if name == "pancake" else "tracking_rmse_m"
        lines += [f"## `{name}` (calibration: {cal.source}, n = {cal.n}, percentiles {cal.percentiles})", "",
                  "Bounds: " + ", ".join(f"{k} ≤ {v:.4g}" for k, v in cal.upper.items())
                  + f"; length ≥ {cal.lower['length']:.0f}.", "",
                  "| inputs | n | flagged | by the uncertainty alone | flagged by | median end error [mm] | "
                  "median RMSE [mm] | median RMSE flagged / not [mm] | a tolerance missed |",
                  "|---|---|---|---|---|---|---|---|---|"]
        ind, ood, nat = sets_for(name, model, args.n)
        held_out = None
        for group, sets in (("in-distribution", ind), ("clearly out-of-distribution", ood),
                            ("natural extrapolation", nat)):
            for label, motions in sets.items():
                j = judge(model, motions)
                if held_out is None:
                    held_out = j
                rmse = j["errors"][rmse_key]
                split = " / ".join(f"{1000 * np.median(rmse[sel]):.1f}" if sel.any() else "—"
                                   for sel in (j["flags"], ~j["flags"]))
                lines.append(
                    f"| {group}: {label} | {len(motions)} | {100 * j['flags'].mean():.1f} % | "
                    f"{100 * uncertainty_only(cal, j['end_std']):.1f} % | {feature_shares(j['reasons']) or '—'} | "
                    f"{1000 * np.median(j['errors'][err_key]):.1f} | {1000 * np.median(rmse):.1f} | {split} | "
                    f"{100 * j['warned'].mean():.1f} % |")
                print(lines[-1], flush=True)
        s_end, p_end = correlations(held_out["end_std"], held_out["errors"][err_key])
        s_rms, p_rms = correlations(held_out["rms_std"], held_out["errors"][rmse_key])
        lines += ["", f"Correlation on the held-out in-distribution inputs (first set, n = {len(held_out['flags'])}): "
                  f"predicted end-position std vs realised {err_key}: Spearman {s_end:.2f}, Pearson {p_end:.2f}; "
                  f"RMS predicted std vs realised {rmse_key}: Spearman {s_rms:.2f}, Pearson {p_rms:.2f}. "
                  f"Median predicted end std {1000 * np.median(held_out['end_std']):.1f} mm vs median realised "
                  f"{1000 * np.median(held_out['errors'][err_key]):.1f} mm.", ""]
        motion = ind[next(iter(ind))][0]
        full, bare = timing(model, motion)
        lines += [f"Cost: `generate` of one K = {len(motion)} input {full:.2f} ms (predicted std, errors and flag "
                  f"included) vs {bare:.2f} ms for the same call without them (fastest of 9 interleaved rounds).", ""]
        print("\n".join(lines[-4:]), flush=True)
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"written to {args.out}")


if __name__ == "__main__":
    main()
