"""The hard pushing benchmark's data-efficiency curve: success against the number of demonstrations.

    # every method on the first N successful demonstrations of the hard set, 2 training seeds each
    python benchmarks/bench_lfd_hard.py run --data runs/hard --out runs/curve --demos 10 25 50 100 --seeds 0 1
    # the chapter-5 policy (six positions) on the same held-out trials
    python benchmarks/bench_lfd_hard.py chapter --out runs/curve
    # rows of every finished job (and of ACT's, benchmarks/peers/act/) into one JSON and a plot
    python benchmarks/bench_lfd_hard.py merge --out runs/curve --act runs/act/*/eval.json \
        --json benchmarks/results_lfd_act.json --plot benchmarks/figures/lfd_hard_curve.png
    # ACT trained to convergence (benchmarks/peers/act/campaign.py), replacing kept rows of the same N and seed;
    # --act-past-stop: evaluations of a copy trained on past the stop rule, shown beside (never replacing) its row
    python benchmarks/bench_lfd_hard.py merge --out runs/curve_fb --keep benchmarks/results_lfd_act.json \
        --act-campaign runs/act_campaign/results.json --act-past-stop runs/act_past_stop/eval_*.json \
        --json benchmarks/results_lfd_act.json

    # the object-feedback policy (the shipped pushing-hard's kind) on the same trials: 3 x 64 decoder, 700 epochs,
    # a pose network on 15,000 rendered frames of the N demonstrations' states
    python benchmarks/bench_lfd_hard.py run --data runs/v2big --out runs/curve_fb --methods feedback \
        --demos 10 25 50 100 --seeds 0 1
    # ... merged with the rows already in the JSON (--keep) whose jobs are not in --out
    python benchmarks/bench_lfd_hard.py merge --out runs/curve_fb --keep benchmarks/results_lfd_act.json \
        --json benchmarks/results_lfd_act.json --plot benchmarks/figures/lfd_hard_curve.png

``run`` trains each method (``proposed``: SeqAE + CNN; ``end_to_end``: the baseline; ``feedback``: the
decoder reading the object's pose every 20 ms, with its keypoint pose network) with
``seqmotion.lfd.train.train(..., benchmark="hard", demos=N)`` and evaluates it on the same
held-out trials (``seqmotion.lfd.evaluation.evaluate(..., benchmark="hard")``, evaluation seed
``--eval-seed``: the trials' seeds never coincide with the demonstrations'). One JSON per job,
``OUT/jobs/<method>_<N>_<seed>.json``, written when the job is done, so several ``run`` processes
(one per core) can share an ``--out``, and a stopped run skips the jobs it finished.

Rows: method, demonstrations, seed, success_rate, successes, trials, wilson_95, train_seconds,
train_steps (optimiser updates), decision_ms (the policy's wall time per 20 ms control step:
the decoder step, median over trials), and the machine's load while training.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

METHODS = ("proposed", "end_to_end", "feedback")
PARTS = {"proposed": ("seqae", "cnn"), "end_to_end": ("end_to_end",), "feedback": ("feedback_decoder", "pose")}
"""The training parts of each method whose optimiser updates a row counts."""


def _write(path: Path, payload: dict) -> None:
    from seqmotion.io import atomic_write_bytes

    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, (json.dumps(payload, indent=1) + "\n").encode())


def _row(method: str, demos: int | None, seed: int | None, result, train_seconds: float | None,
         train_steps: int | None, extra: dict) -> dict:
    low, high = result.wilson_interval
    return {
        "method": method, "demonstrations": demos, "seed": seed, "success_rate": result.success_rate,
        "successes": result.successes, "trials": result.n_trials, "wilson_95": [low, high],
        "train_seconds": train_seconds, "train_steps": train_steps, "decision_ms": result.decision_ms,
        "per_shape": {k: list(v) for k, v in result.per_position.items()}, "eval_seed": result.seed,
        "eval_seconds": round(result.seconds, 1), "episode_seconds": _episode_seconds(), **extra,
    }


def _episode_seconds() -> float:
    """The hard benchmark's episode length [s] (demonstrations and trials): 6 s since v2, 4 s before."""
    from seqmotion.lfd.env.pushing import EPISODE_SECONDS

    return EPISODE_SECONDS["hard"]


def _steps(policy_dir: Path, part: str) -> int | None:
    """Optimiser updates of one training part, from the policy's recorded settings and data size."""
    config = json.loads((policy_dir / "config.json").read_text())
    record = config["policy"].get("training", {}).get(part, {})
    settings = record.get("settings", {})
    n = record.get("motions") or record.get("pairs") or record.get("demos") or record.get("frames")
    if not settings or not n:
        return None
    batches = -(-int(n) // int(settings["batch_size"]))
    return int(settings["epochs"]) * batches


def run(args: argparse.Namespace) -> int:
    from seqmotion.lfd.evaluation import evaluate
    from seqmotion.lfd.fitting import default_settings
    from seqmotion.lfd.policy.policy import PushingPolicy
    from seqmotion.lfd.train import SeqAETraining, train
    from seqmotion.training.provenance import command_line

    out = Path(args.out)
    for demos in args.demos:
        for seed in args.seeds:
            for method in args.methods:
                job = out / "jobs" / f"{method}_{demos}_{seed}.json"
                if job.is_file():
                    continue
                model_dir = out / "models" / f"{method}_{demos}_{seed}"
                load = os.getloadavg()[0]
                start = time.perf_counter()
                feedback = {"seqae_settings": SeqAETraining(epochs=args.feedback_epochs), "pose_frames":
                            args.pose_frames, "workers": args.workers} if method == "feedback" else {}
                if args.epochs_scale != 1.0 and method != "feedback":  # the convergence check: a longer budget
                    seqae, e2e, cnn = default_settings(args.preset, "hard")
                    feedback = {"seqae_settings": replace(seqae, epochs=round(seqae.epochs * args.epochs_scale)),
                                "e2e_settings": replace(e2e, epochs=round(e2e.epochs * args.epochs_scale)),
                                "cnn_settings": replace(cnn, epochs=round(cnn.epochs * args.epochs_scale))}
                report = train(args.data, model_dir, args.feedback_preset if feedback else args.preset, (method,),
                               ("default",), seed, progress=False,
                               command=command_line("python benchmarks/bench_lfd_hard.py"), benchmark="hard",
                               demos=demos, **feedback)
                seconds = time.perf_counter() - start
                policy_dir = report.policies[f"{method}_default"]
                steps = sum(s for part in PARTS[method] if (s := _steps(Path(policy_dir), part)) is not None)
                result = evaluate(PushingPolicy.from_pretrained(policy_dir), trials=args.trials, seed=args.eval_seed,
                                  benchmark="hard")
                row = _row(method, demos, seed, result, round(seconds, 1), steps,
                           {"train_load": [round(load, 2), round(os.getloadavg()[0], 2)], "model": str(policy_dir),
                            **({"epochs_scale": args.epochs_scale} if args.epochs_scale != 1.0 else {})})
                _write(job, {"row": row, "evaluation": result.as_dict()})
                print(f"{method} N={demos} seed={seed}: {result.successes}/{result.n_trials} "
                      f"({seconds:.0f} s training)", flush=True)
    return 0


def chapter(args: argparse.Namespace) -> int:
    """The shipped chapter-5 policy (trained on the six positions) on the hard benchmark's trials."""
    import seqmotion as sm
    from seqmotion.lfd.evaluation import evaluate

    result = evaluate(sm.load_pretrained("pushing"), trials=args.trials, seed=args.eval_seed, benchmark="hard")
    row = _row("chapter5_pushing", None, None, result, None, None, {"model": "pretrained:pushing"})
    _write(Path(args.out) / "jobs" / "chapter5_pushing.json", {"row": row, "evaluation": result.as_dict()})
    print(f"chapter-5 policy: {result.successes}/{result.n_trials}")
    return 0


def merge(args: argparse.Namespace) -> int:
    rows = [json.loads(p.read_text())["row"] for p in sorted((Path(args.out) / "jobs").glob("*.json"))]
    for path in args.act or []:
        rows.append(_act_row(Path(path)))
    for path in args.act_campaign or []:
        rows.extend(_act_campaign_rows(Path(path)))
    _attach_past_stop(rows, [Path(p) for p in args.act_past_stop or []])
    if args.keep:  # rows measured earlier, into another --out, unless measured again here
        ran = {(r["method"], r["demonstrations"], r["seed"]) for r in rows}
        kept = json.loads(Path(args.keep).read_text())["rows"]
        rows = [r for r in kept if (r["method"], r["demonstrations"], r["seed"]) not in ran] + rows
    from seqmotion.training.provenance import machine_record

    payload = {"benchmark": "hard", "machine": machine_record(), "rows": rows}
    _write(Path(args.json), payload)
    if args.plot:
        _plot(rows, Path(args.plot))
    for r in sorted(rows, key=lambda r: (r["method"], r["demonstrations"] or 0, r["seed"] or 0)):
        low, high = r["wilson_95"]
        print(f"{r['method']:18s} N={r['demonstrations']!s:>4} seed={r['seed']!s:>2}  {r['successes']:>3}/{r['trials']}"
              f"  ({low:.0%}-{high:.0%})  train {r['train_seconds']} s")
    return 0


def _attach_past_stop(rows: list[dict], paths: list[Path]) -> None:
    """Evaluations of a converged ACT run trained on past its stop rule (``train_act.py --resume --past-stop`` on a
    copy), as ``past_stop`` points of the converged row with the same demonstrations and seed. They show whether
    success was still rising when the rule stopped; they never replace the rule's final checkpoint."""
    for path in paths:
        ev = json.loads(path.read_text())
        demos, seed = len(ev["train"]["episodes_used"]), ev["train"]["seed"]
        row = next((r for r in rows if r["method"] == "act" and r.get("stop_reason") == "patience"
                    and r["demonstrations"] == demos and r["seed"] == seed), None)
        if row is None:
            raise SystemExit(f"{path}: no converged ACT row with {demos} demonstrations and seed {seed}")
        if ev["train"]["steps"] <= row["train_steps"]:
            raise SystemExit(f"{path}: step {ev['train']['steps']} is not past the rule's stop at {row['train_steps']}")
        row.setdefault("past_stop", [])
        row["past_stop"] = sorted([p for p in row["past_stop"] if p["step"] != ev["train"]["steps"]] + [{
            "step": ev["train"]["steps"], "val_l1": (ev.get("val_at_step") or {}).get("val_l1"),
            "successes": ev["successes"], "trials": ev["n_trials"], "success_rate": ev["success_rate"],
            "wilson_95": ev["wilson_95"], "model": ev["model_dir"]}], key=lambda p: p["step"])


def _act_row(path: Path) -> dict:
    """A row from ``benchmarks/peers/act/eval_act.py --json`` output (its training log beside the model)."""
    result = json.loads(path.read_text())
    log = json.loads((Path(result["model_dir"]) / "train_log.json").read_text())
    select = result["select_action_ms"]
    return {
        "method": "act", "demonstrations": len(log["episodes_used"]), "seed": log["seed"],
        "success_rate": result["success_rate"], "successes": result["successes"], "trials": result["n_trials"],
        "wilson_95": result["wilson_95"], "train_seconds": round(log["seconds"]["train"], 1),
        "train_steps": log["steps"], "batch_size": log["batch_size"],
        "decision_ms": {"p50": select.get("p50"), "p99": select.get("p99"), "what": "select_action"},
        "per_shape": result["per_position"], "eval_seed": result["seed"], "eval_seconds": round(result["seconds"], 1),
        "final_loss": log["final_loss_mean_last10"], "lerobot": log["lerobot_version"], "model": result["model_dir"],
        # evaluations before eval_act.py recorded it ran the hard benchmark's v1 episodes (4 s, on 4 s demonstrations)
        "episode_seconds": result.get("duration", 4.0),
    }


def _act_campaign_rows(path: Path) -> list[dict]:
    """Rows of ``benchmarks/peers/act/campaign.py``'s ``results.json``: each finished training's final
    checkpoint, with every evaluated checkpoint as its ``curve`` (steps, wall time, held-out val_l1, training L1,
    success)."""
    rows = []
    for run in json.loads(path.read_text())["runs"]:
        final = next((c for c in run["checkpoints"] if c["step"] == run["steps"]), None)
        if not run["finished"] or final is None:
            continue
        low, high = final["wilson_95"]
        rows.append({
            "method": "act", "demonstrations": run["demonstrations"], "seed": run["seed"],
            "success_rate": final["success_rate"], "successes": final["successes"], "trials": final["trials"],
            "wilson_95": [low, high], "train_seconds": round(run["seconds"]["train_loop"], 1),
            "train_steps": run["steps"], "batch_size": run["batch_size"],
            "decision_ms": {**final["select_action_ms"], "what": "select_action"},
            "per_shape": final.get("per_shape"), "eval_seed": final["eval_seed"], "eval_seconds": final["eval_seconds"],
            "stop_reason": run["stop_reason"], "val_l1": final["val_l1"], "best_val_l1": run["best_val_l1"],
            "policy_config": run["policy_config"], "lerobot": run["lerobot"], "model": final["model"],
            "episode_seconds": _episode_seconds(),
            "val_log": [{k: v.get(k) for k in ("step", "val_l1", "train_l1")} for v in run.get("val") or []],
            "curve": [{k: c.get(k) for k in ("step", "train_loop_s", "wall_s", "val_l1", "train_l1", "val_kld",
                                             "success_rate", "successes", "trials", "wilson_95")}
                      for c in run["checkpoints"]],
        })
    return rows


def _series(rows: list[dict]) -> dict[str, list[dict]]:
    """The plotted series: each method's rows, LeRobot ACT's split into the runs trained to convergence (the campaign's
    stop rule) and the budget-limited ones, never pooled together."""
    out: dict[str, list[dict]] = {}
    for r in rows:
        if not r["demonstrations"]:
            continue
        key = r["method"]
        if key == "act":
            key = "act, to convergence" if r.get("stop_reason") == "patience" else "act, budget-limited"
        out.setdefault(key, []).append(r)
    return out


def _success_by_step(points: list[dict]) -> tuple:
    """Steps, success rates and their 95 % Wilson intervals ``(n, 2)`` of evaluated checkpoints, as arrays."""
    import numpy as np

    from seqmotion.lfd.evaluation import wilson_interval

    steps = np.array([p["step"] for p in points])
    rate = np.array([p["successes"] / p["trials"] for p in points])
    ci = np.array([wilson_interval(p["successes"], p["trials"]) for p in points])
    return steps, rate, ci


def _plot(rows: list[dict], path: Path) -> None:
    """Left: success against demonstrations (seeds pooled, Wilson 95 %). Then, one panel per number of
    demonstrations at which ACT was trained to convergence: ACT's success against training steps at each evaluated
    checkpoint (one curve per seed), beside the other methods' pooled success at that number; below each, ACT's
    held-out ``val_l1`` and training L1 against the same steps."""
    import matplotlib.pyplot as plt
    import numpy as np

    from seqmotion.io import save_figure
    from seqmotion.lfd.evaluation import wilson_interval

    series = _series(rows)
    converged = series.get("act, to convergence", [])
    counts_converged = sorted({r["demonstrations"] for r in converged})
    panels = 1 + len(counts_converged)
    rows_of_panels = 2 if counts_converged else 1  # below each ACT panel: its losses against the same steps
    fig, axes = plt.subplots(rows_of_panels, panels, figsize=(6 * panels, 4 * rows_of_panels), squeeze=False)
    if counts_converged:
        axes[1, 0].axis("off")
    ax = axes[0, 0]
    for i, (name, mine) in enumerate(sorted(series.items())):
        counts = sorted({r["demonstrations"] for r in mine})
        # pool the seeds' trials at each count; the interval is the pooled Wilson interval
        ok = [sum(r["successes"] for r in mine if r["demonstrations"] == n) for n in counts]
        total = [sum(r["trials"] for r in mine if r["demonstrations"] == n) for n in counts]
        rate = np.array(ok) / np.array(total)
        ci = np.array([wilson_interval(k, t) for k, t in zip(ok, total, strict=True)])
        shifted = np.array(counts) * (1 + 0.04 * i)  # side by side, not on top of each other
        steps = sorted({r["train_steps"] for r in mine})
        label = name
        if name == "act, to convergence":
            label = f"LeRobot ACT, to convergence ({', '.join(map(str, steps))} steps)"
        elif name == "act, budget-limited":
            label = f"LeRobot ACT ({', '.join(map(str, steps))} steps: budget-limited)"
        older = sorted({r["episode_seconds"] for r in mine} - {_episode_seconds()})
        if older:  # trained and scored on an earlier version of the benchmark: say so on the plot
            label += f", on {'/'.join(f'{s:g}' for s in older)} s episodes (v1)"
        ax.errorbar(shifted, rate, yerr=[rate - ci[:, 0], ci[:, 1] - rate], marker="o", capsize=3, label=label)
    for r in rows:
        if not r["demonstrations"]:
            ax.axhline(r["success_rate"], ls=":", color="grey", label=f"{r['method']} (six positions)")
    ax.set_xscale("log")
    ax.set_xlabel("demonstrations")
    ax.set_ylabel("success on held-out trials")
    ax.set_ylim(-0.02, 1.02)
    ax.legend(fontsize=7)
    ax.set_title(f"hard pushing benchmark, {_episode_seconds():g} s episodes (95 % Wilson, seeds pooled)", fontsize=10)
    colours = {name: f"C{i}" for i, name in enumerate(sorted(series))}  # as in the left panel
    # ACT's seeds: the first in ACT's colour of the left panel, the others in colours no method uses there
    seed_colours = [colours.get("act, to convergence", "C1"), "C5", "C7", "C8"]
    for panel, n in enumerate(counts_converged, start=1):
        ax = axes[0, panel]
        for k, r in enumerate(sorted((r for r in converged if r["demonstrations"] == n), key=lambda r: r["seed"])):
            steps, rate, ci = _success_by_step([c for c in r.get("curve") or [] if c.get("trials")])
            ax.errorbar(steps, rate, yerr=[rate - ci[:, 0], ci[:, 1] - rate], marker="os^v"[k % 4], capsize=3,
                        color=seed_colours[k % 4],
                        label=f"LeRobot ACT, seed {r['seed']} ({r['train_steps']} steps)")
            if r.get("past_stop") and len(steps):  # trained on past the rule, on a copy: hollow, dotted
                p_steps, p_rate, p_ci = _success_by_step([{**r["curve"][-1], "step": steps[-1]}, *r["past_stop"]])
                ax.errorbar(p_steps[1:], p_rate[1:], yerr=[p_rate[1:] - p_ci[1:, 0], p_ci[1:, 1] - p_rate[1:]],
                            marker="os^v"[k % 4], mfc="none", capsize=3, ls="none", color=seed_colours[k % 4])
                ax.plot(p_steps, p_rate, ls=":", color=seed_colours[k % 4],
                        label=f"seed {r['seed']} trained on past the stop rule (a copy)")
        for name, mine in sorted((k, v) for k, v in series.items() if not k.startswith("act")):
            at_n = [r for r in mine if r["demonstrations"] == n]
            if at_n:
                pooled = sum(r["successes"] for r in at_n) / sum(r["trials"] for r in at_n)
                ax.axhline(pooled, ls="--", lw=1, color=colours[name], label=f"{name} ({len(at_n)} seeds pooled)")
        ax.set_xlabel("ACT training steps (batch 8)")
        ax.set_ylabel("success on held-out trials")
        ax.set_ylim(-0.02, 1.02)
        ax.legend(fontsize=7)
        ax.set_title(f"{n} demonstrations: ACT's checkpoints (the same 30 scenes, 95 % Wilson)", fontsize=10)
        ax = axes[1, panel]
        for k, r in enumerate(sorted((r for r in converged if r["demonstrations"] == n), key=lambda r: r["seed"])):
            log = [v for v in r.get("val_log") or [] if v.get("step")]
            colour = seed_colours[k % 4]
            ax.plot([v["step"] for v in log], [v["val_l1"] for v in log], color=colour,
                    label=f"seed {r['seed']}: held-out L1 (val_l1, the stop rule's)")
            fitted = [v for v in log if v.get("train_l1") is not None]
            ax.plot([v["step"] for v in fitted], [v["train_l1"] for v in fitted], ls="--", color=colour,
                    label=f"seed {r['seed']}: training L1 (the 500 steps before)")
        ax.set_xlabel("ACT training steps (batch 8)")
        ax.set_ylabel("L1 of the action chunk (normalised)")
        ax.legend(fontsize=7)
        ax.set_title(f"{n} demonstrations: ACT's training and held-out L1", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, close=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("run")
    p.add_argument("--data", required=True, help="directory with hard.h5 (seqmotion lfd collect --benchmark hard)")
    p.add_argument("--out", required=True)
    p.add_argument("--demos", type=int, nargs="+", default=[10, 25, 50, 100])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    p.add_argument("--preset", default="smaller")
    p.add_argument("--feedback-preset", default="wide64", help="feedback: the decoder's layers and width (3 x 64)")
    p.add_argument("--feedback-epochs", type=int, default=700, help="feedback: the decoder's epochs")
    p.add_argument("--pose-frames", type=int, default=15000, help="feedback: frames its pose network trains on")
    p.add_argument("--workers", type=int, default=1, help="feedback: processes rendering the frames")
    p.add_argument("--trials", type=int, default=30)
    p.add_argument("--eval-seed", type=int, default=0)
    p.add_argument("--epochs-scale", type=float, default=1.0,
                   help="proposed, end_to_end: this multiple of the default epochs (SeqAE, CNN, end-to-end), into its "
                        "own --out: whether the default budget has converged")
    p.set_defaults(func=run)
    p = sub.add_parser("chapter")
    p.add_argument("--out", required=True)
    p.add_argument("--trials", type=int, default=30)
    p.add_argument("--eval-seed", type=int, default=0)
    p.set_defaults(func=chapter)
    p = sub.add_parser("merge")
    p.add_argument("--out", required=True)
    p.add_argument("--act", nargs="*", help="ACT's evaluations (eval_act.py --json files, benchmarks/peers/act/)")
    p.add_argument("--json", required=True)
    p.add_argument("--act-campaign", nargs="*",
                   help="results.json of benchmarks/peers/act/campaign.py (finished trainings, with their curves)")
    p.add_argument("--act-past-stop", nargs="*",
                   help="eval_act.py --json files of converged ACT runs trained on past their stop (--past-stop)")
    p.add_argument("--keep", help="a results JSON whose rows stay, except those the jobs in --out measured again")
    p.add_argument("--plot")
    p.set_defaults(func=merge)
    args = parser.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
