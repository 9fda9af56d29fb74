"""The ACT convergence campaign: choose the configuration, then train ACT to convergence and evaluate along the way.

Run with the LeRobot venv's python (seqmotion installed there, see README.md), in the background; every
step is idempotent, so the same command resumes it after any stop::

    cd /work/main
    setsid nohup nice -n 19 /work/venvs/lerobot/bin/python benchmarks/peers/act/campaign.py run \
        >> runs/act_campaign/log.txt 2>&1 &
    /work/venvs/lerobot/bin/python benchmarks/peers/act/campaign.py status     # where it stands

Each job is locked while a worker runs it (``lock`` files beside its output), so a second ``run`` started the
same way works beside the first on the next free job: one worker per spare core (each trains or evaluates on one
thread). Trainings never wait for evaluations: a checkpoint's evaluation is a job of its own, which any free
worker takes, so one worker trains on while another evaluates what it has written.

Jobs (each skipped when done, resumed from its last checkpoint when interrupted):

1. **Configuration comparison** (``compare/<name>``): each candidate of :data:`CANDIDATES` trained on the
   first 100 successful demonstrations, seed 0, for ``--compare-steps`` steps, validation every 250. The
   choice (``choice.json``, written once) is the candidate with the lowest mean ``val_l1`` over its last
   three validations; candidates are listed cheapest first and one within 1 % of the lowest that comes
   earlier wins (a tie goes to the cheaper). Never evaluation success.
2. **Main trainings** (``train/hard_<N>_<seed>``) of :data:`PLAN`, with the chosen configuration: at least
   ``--min-steps``, until ``val_l1`` has not improved for ``--patience`` steps, at most ``--cap``. Each runs
   in slices of ``--eval-every`` steps (``train_act.py --resume --stop-at``; resuming is exact, so slicing
   changes nothing).
3. **Evaluations** of the main trainings' checkpoints (multiples of ``--eval-every`` and the final one) on the
   hard benchmark's held-out scenes (``eval_act.py --benchmark hard --trials 30 --seed 0``) into
   ``evals/hard_<N>_<seed>/<step>.json``, each locked by ``<step>.lock`` beside it.

A worker takes the first free job in plan order: for each training, one more slice of it if it is unfinished
and free, else one of its checkpoints' evaluations; so earlier trainings finish first and their
evaluations run beside the next training. When every remaining job is held by another worker it waits
for one to free or to appear (a training's next checkpoint), and it exits once nothing is left.

After every job ``results.json`` is rebuilt from what is on disk: the comparison, the choice, and for
each training its steps, wall time, validation log and one row per evaluated checkpoint (steps, wall
time, ``val_l1``, success). ``benchmarks/bench_lfd_hard.py merge --act-campaign runs/act_campaign/results.json``
turns the finished trainings into rows of ``benchmarks/results_lfd_act.json``.

Stop: ``kill -TERM -- -PGID`` (the trainer checkpoints and exits; the same ``run`` resumes). Pause:
``kill -STOP -- -PGID`` / ``kill -CONT -- -PGID`` (PGID = a worker's pid when started with ``setsid``;
``campaign.py workers`` lists them).
"""

from __future__ import annotations

import argparse
import datetime as dt
import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]

SMALL = ["--dim-model", "256", "--dim-feedforward", "1024", "--chunk-size", "50"]
CANDIDATES: dict[str, list[str]] = {
    # cheapest first: a candidate within 1 % of the best that comes earlier is chosen
    "d256_c50_enc2_vae2": [*SMALL, "--n-encoder-layers", "2", "--n-vae-encoder-layers", "2"],
    "d256_c50_enc2_vae2_lr1e-4": [*SMALL, "--n-encoder-layers", "2", "--n-vae-encoder-layers", "2", "--lr", "1e-4"],
    "d256_c50_enc4_vae4": [*SMALL],  # LeRobot's 4 encoder + 4 VAE-encoder layers
    "d256_c50_enc4_vae4_lr1e-4": [*SMALL, "--lr", "1e-4"],
}
"""All: LeRobot's ACT with dim 256 / feed-forward 1,024 / chunk 50 (1 s at 50 fps), one decoder layer
(LeRobot's default), the backbone at the main learning rate (LeRobot 0.4.4's defaults are 1e-5 for both):
2 x 2 of encoder depth (2 + 2 or LeRobot's 4 + 4 encoder + VAE-encoder layers) and learning rate (LeRobot's
1e-5 or 1e-4)."""
TIE = 0.01
"""A later (costlier) candidate must beat an earlier one by more than this fraction of val_l1."""

PLAN: list[tuple[int, int]] = [(100, 0), (25, 0), (100, 1), (25, 1), (10, 0), (50, 0), (10, 1), (50, 1)]
"""(demonstrations, training seed): both counts of the target with one seed first, then the second
seed, then 10 and 50 if the budget allows."""


# --------------------------------------------------------------------------------------------- helpers


def log(msg: str) -> None:
    print(f"[{dt.datetime.now().isoformat(timespec='seconds')}] {msg}", flush=True)


def _read(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None


class JobLock:
    """An exclusive ``flock`` on ``path`` for the life of a job, the holder's pid inside; ``held`` is False when
    another worker has it (that worker's job is skipped, not waited for)."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.file = open(path, "a+")
        try:
            fcntl.flock(self.file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.file.close()
            self.held = False
            return
        self.held = True
        self.file.seek(0)
        self.file.truncate()
        self.file.write(str(os.getpid()))
        self.file.flush()

    def release(self) -> None:
        if self.held:
            self.file.close()  # closing drops the flock; the file stays (its pid is stale, harmlessly)
            self.held = False


def holder(path: Path) -> str | None:
    """The pid in a job's lock file when a live worker holds it, else None."""
    if not path.is_file():
        return None
    with open(path, "a+") as f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            fcntl.flock(f, fcntl.LOCK_UN)
            return None
        except BlockingIOError:
            f.seek(0)
            return f.read().strip() or "?"


def job_locks(root: Path) -> list[Path]:
    return [root / "compare.lock", *sorted((root / "train").glob("*/lock")),
            *sorted((root / "evals").glob("*/*.lock"))]


def _write_json(path: Path, payload: Any) -> None:
    """Atomically, as the trainer writes its own files (``train_act.write_json``)."""
    sys.path.insert(0, str(HERE))
    from train_act import write_json

    write_json(path, payload)


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.update({"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "MUJOCO_GL": env.get("MUJOCO_GL", "egl"),
                "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "PYTHONUNBUFFERED": "1"})
    return env


class Stopped(Exception):
    """SIGTERM/SIGINT reached the campaign."""


_child: subprocess.Popen | None = None
_stopping = False


def _on_signal(signum: int, frame: Any) -> None:
    global _stopping
    _stopping = True
    if _child is not None and _child.poll() is None:
        _child.send_signal(signal.SIGTERM)  # train_act.py checkpoints and exits; an evaluation just stops


def _call(cmd: list[str]) -> int:
    """Run one job's process, its output into ours (the log); the campaign's signals reach it."""
    global _child
    if _stopping:
        raise Stopped
    log("$ " + " ".join(cmd))
    _child = subprocess.Popen(cmd, cwd=HERE, env=_env(), stdout=sys.stdout, stderr=sys.stderr)
    try:
        rc = _child.wait()
    finally:
        _child = None
    if _stopping:
        raise Stopped
    return rc


def _episodes(data: Path) -> tuple[int, dict[int, bool]]:
    sys.path.insert(0, str(HERE))
    from train_act import _episode_table

    return _episode_table(data)


def validation_spec(data: Path, train_demos: int = 100) -> tuple[str, list[int], list[int]]:
    """``--val-episodes`` for ``data``: the successful episodes after the ``train_demos``-th successful one
    (no training run, at any count up to ``train_demos``, sees them). Also (training pool, validation)."""
    total, success = _episodes(data)
    ok = sorted(e for e, s in success.items() if s)
    if len(ok) <= train_demos:
        raise SystemExit(f"{data}: {len(ok)} successful episodes; need more than {train_demos} (train + validation)")
    last_train = ok[train_demos - 1]
    val = [e for e in ok if e > last_train]
    return f"successful:{last_train + 1}-{total - 1}", ok[:train_demos], val


# --------------------------------------------------------------------------------------------- jobs


def train_cmd(args: argparse.Namespace, out: Path, demos: int, seed: int, config: list[str], steps: int,
              extra: list[str]) -> list[str]:
    return [sys.executable, str(HERE / "train_act.py"), "--data", str(args.data), "--out", str(out),
            "--episodes", str(demos), "--successful-only", "--val-episodes", args.val_spec, "--seed", str(seed),
            "--batch-size", "8", "--steps", str(steps), "--threads", "1", "--num-workers", "0",
            "--log-every", "100", *config, *extra, "--resume"]


def compare(args: argparse.Namespace) -> dict:
    """The configuration comparison; returns (and writes once) the choice."""
    choice_path = args.root / "choice.json"
    if (choice := _read(choice_path)) is not None:
        return choice
    lock = JobLock(args.root / "compare.lock")
    if not lock.held:  # the comparison runs once, in one worker; the others have nothing to do before it
        raise SystemExit(f"another worker is running the comparison (pid {holder(args.root / 'compare.lock')})")
    for name, config in CANDIDATES.items():
        out = args.root / "compare" / name
        if (_read(out / "train_log.json") or {}).get("finished"):
            continue
        for attempt in range(3):
            rc = _call(train_cmd(args, out, 100, 0, config, args.compare_steps,
                                 ["--val-every", str(args.compare_val_every), "--keep-every", "0"]))
            if rc == 0 and (_read(out / "train_log.json") or {}).get("finished"):
                break
            log(f"compare {name}: exit {rc} (attempt {attempt + 1}); retrying in 60 s")
            time.sleep(60)
        else:
            raise SystemExit(f"compare {name} failed three times; see the log")
    table = comparison_table(args.root)
    best = min(r["val_l1_last3"] for r in table)
    chosen = next(r for r in table if r["val_l1_last3"] <= best * (1 + TIE))
    rule = (f"lowest mean val_l1 over the last three validations at {args.compare_steps} steps (validation "
            f"every {args.compare_val_every}); candidates cheapest first, an earlier one within {TIE:.0%} of the "
            "lowest wins")
    choice = {"chosen": chosen["name"], "config": CANDIDATES[chosen["name"]], "rule": rule, "table": table,
              "decided": dt.datetime.now().isoformat(timespec="seconds")}
    _write_json(choice_path, choice)
    lock.release()
    log(f"chosen configuration: {chosen['name']} " + "; ".join(f"{r['name']} {r['val_l1_last3']:.4f}" for r in table))
    return choice


def comparison_table(root: Path) -> list[dict]:
    rows = []
    for name in CANDIDATES:
        tl = _read(root / "compare" / name / "train_log.json")
        if not tl:
            continue
        val = tl.get("val") or []
        last3 = [v["val_l1"] for v in val[-3:]]
        rows.append({"name": name, "args": CANDIDATES[name], "steps": tl["steps"], "finished": tl.get("finished"),
                     "val_l1_last3": sum(last3) / len(last3) if last3 else None,
                     "val_l1_final": val[-1]["val_l1"] if val else None,
                     "val_loss_vae_final": val[-1].get("val_loss_vae") if val else None,
                     "best_val_l1": tl.get("best_val_l1"), "best_step": tl.get("best_step"),
                     "s_per_step": tl.get("s_per_step"), "s_per_step_median": tl.get("s_per_step_median"),
                     "cpu_s_per_step": tl.get("cpu_s_per_step"), "train_seconds": tl["seconds"].get("train_loop"),
                     "val": [{k: v.get(k) for k in ("step", "val_l1", "val_loss_vae")} for v in val]})
    return rows


def pending_evals(args: argparse.Namespace, out: Path, name: str) -> list[int]:
    """Checkpoint steps with weights that should be evaluated and are not yet."""
    tl = _read(out / "train_log.json") or {}
    root = out / "checkpoints"
    steps = sorted(int(p.name) for p in root.iterdir() if p.name.isdigit()) if root.is_dir() else []
    final = tl.get("steps") if tl.get("finished") else None
    want = [s for s in steps if s > 0 and (s % args.eval_every == 0 or s == final)
            and (root / f"{s:06d}" / "pretrained_model" / "model.safetensors").is_file()]
    return [s for s in want if not (args.root / "evals" / name / f"{s:06d}.json").is_file()]


def evaluate(args: argparse.Namespace, out: Path, name: str, step: int) -> bool:
    """Evaluate one checkpoint into ``evals/<name>/<step>.json``; False when the evaluation failed."""
    target = args.root / "evals" / name / f"{step:06d}.json"
    tmp = target.with_name(f".{target.name}.tmp")
    target.parent.mkdir(parents=True, exist_ok=True)
    model = out / "checkpoints" / f"{step:06d}" / "pretrained_model"
    rc = _call([sys.executable, str(HERE / "eval_act.py"), str(model),
                "--benchmark", "hard", "--trials", str(args.trials), "--seed", str(args.eval_seed), "--threads", "1",
                "--json", str(tmp), "--quiet"])
    if rc != 0 or not tmp.is_file():
        log(f"evaluation of {name} step {step} failed (exit {rc})")
        return False
    # seqmotion runs from the working tree (pip install -e): record which, in case it changes mid-campaign
    ev = json.loads(tmp.read_text())
    ev["seqmotion_tree"] = _tree()
    _write_json(target, ev)
    tmp.unlink()
    return True


def _tree() -> dict:
    def git(*a: str) -> str:
        r = subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True)
        return r.stdout.strip()

    return {"commit": git("rev-parse", "HEAD"), "lfd_modified": git("status", "--porcelain", "src/seqmotion/lfd")}


def training_finished(args: argparse.Namespace, out: Path) -> bool:
    """Finished by the stop rule, or by the cap when the cap has not been raised since."""
    tl = _read(out / "train_log.json") or {}
    return bool(tl.get("finished")) and not (tl.get("stop_reason") == "steps" and args.cap > tl.get("steps", 0))


def train_slice(args: argparse.Namespace, config: list[str], name: str, out: Path, demos: int, seed: int) -> bool:
    """Train ``name`` up to its next multiple of ``--eval-every`` (or its stop); True when it made progress."""
    current = (_read(out / "train_log.json") or {}).get("steps", 0)
    stop_at = (current // args.eval_every + 1) * args.eval_every
    rc = _call(train_cmd(args, out, demos, seed, config, args.cap,
                         ["--min-steps", str(args.min_steps), "--patience", str(args.patience),
                          "--val-every", str(args.val_every), "--keep-every", str(args.eval_every),
                          "--stop-at", str(stop_at)]))
    now = _read(out / "train_log.json") or {}
    if now.get("steps", 0) <= current and not now.get("finished"):
        log(f"{name}: exit {rc} without progress")
        return False
    return True


def next_job(args: argparse.Namespace, config: list[str], failures: dict[str, int]) -> str:
    """Run the first free job in plan order. Returns 'ran', 'busy' (jobs remain, all held by other workers or
    waiting for a checkpoint) or 'done'. A job that fails three times is left to a later ``run``."""
    remaining = False
    for demos, seed in args.plan:
        name = f"hard_{demos}_{seed}"
        out = args.root / "train" / name
        if not training_finished(args, out) and failures.get(name, 0) < 3:
            remaining = True
            lock = JobLock(out / "lock")
            if lock.held:
                try:
                    if train_slice(args, config, name, out, demos, seed):
                        failures.pop(name, None)
                    else:
                        failures[name] = failures.get(name, 0) + 1
                        time.sleep(60)
                finally:
                    lock.release()
                return "ran"
        for step in pending_evals(args, out, name):
            key = f"{name}@{step}"
            if failures.get(key, 0) >= 3:
                continue
            remaining = True
            lock = JobLock(args.root / "evals" / name / f"{step:06d}.lock")
            if not lock.held:
                continue
            try:
                # another worker may have finished it between the listing and the lock
                if step in pending_evals(args, out, name) and not evaluate(args, out, name, step):
                    failures[key] = failures.get(key, 0) + 1
            finally:
                lock.release()
            return "ran"
    return "busy" if remaining else "done"


# --------------------------------------------------------------------------------------------- results


TRAIN_L1_WINDOW = 500
"""Steps before a checkpoint over which its training L1 is averaged (``train_l1``: the training objective's L1,
train mode, so dropout on and z from the posterior; beside the held-out ``val_l1`` it shows the gap between
fitting the demonstrations and predicting new ones)."""


def _window_mean(values: list[float | None], step: int, window: int) -> float | None:
    """Mean of ``values`` over steps ``step - window + 1 .. step`` (value of step k at index k - 1)."""
    if step <= 0:
        return None
    chunk = [v for v in values[max(0, step - window):step] if v is not None]
    return sum(chunk) / len(chunk) if len(chunk) == min(window, step) else None


def results(args: argparse.Namespace) -> dict:
    """``results.json`` from disk: the comparison, the choice, every training's log and evaluated checkpoints."""
    runs = []
    for demos, seed in args.plan:
        name = f"hard_{demos}_{seed}"
        out = args.root / "train" / name
        tl = _read(out / "train_log.json")
        if not tl:
            continue
        val = {v["step"]: v for v in tl.get("val") or []}
        train_l1 = [h.get("l1_loss") for h in tl.get("history") or []]  # step k at index k - 1
        checkpoints = []
        for path in sorted((args.root / "evals" / name).glob("[0-9]*.json")):
            ev = _read(path)
            if not ev:
                continue
            step = int(path.stem)
            v = val.get(step) or ev.get("val_at_step") or {}
            checkpoints.append({
                "step": step, "val_l1": v.get("val_l1"), "val_loss_vae": v.get("val_loss_vae"),
                "val_kld": v.get("val_kld"), "train_l1": _window_mean(train_l1, step, TRAIN_L1_WINDOW),
                "train_loop_s": v.get("train_loop_s"), "wall_s": v.get("wall_s"),
                "success_rate": ev["success_rate"], "successes": ev["successes"], "trials": ev["n_trials"],
                "wilson_95": ev["wilson_95"], "eval_seed": ev["seed"], "eval_seconds": round(ev["seconds"], 1),
                "select_action_ms": {k: ev["select_action_ms"].get(k) for k in ("p50", "p99")},
                "decision_ms": ev.get("decision_ms"), "model": ev["model_dir"],
                "per_shape": {k: list(v) for k, v in (ev.get("per_position") or {}).items()},
            })
        runs.append({
            "name": name, "demonstrations": demos, "seed": seed, "out": str(out),
            "episodes_used": tl.get("episodes_used"), "val_episodes_used": tl.get("val_episodes_used"),
            "val_frames": tl.get("val_frames"), "steps": tl.get("steps"), "epochs": tl.get("epochs"),
            "finished": tl.get("finished"), "stop_reason": tl.get("stop_reason"), "stop_rule": tl.get("stop_rule"),
            "best_val_l1": tl.get("best_val_l1"), "best_step": tl.get("best_step"),
            "seconds": tl.get("seconds"), "s_per_step": tl.get("s_per_step"),
            "s_per_step_median": tl.get("s_per_step_median"), "cpu_s_per_step": tl.get("cpu_s_per_step"),
            "batch_size": tl.get("batch_size"),
            "lerobot": tl.get("lerobot_version"), "policy_config": {k: tl.get("policy_config", {}).get(k) for k in (
                "dim_model", "dim_feedforward", "n_heads", "chunk_size", "n_encoder_layers", "n_decoder_layers",
                "n_vae_encoder_layers", "optimizer_lr", "optimizer_lr_backbone", "optimizer_weight_decay",
                "temporal_ensemble_coeff", "kl_weight", "dropout")},
            "val": [{**{k: v.get(k) for k in ("step", "val_l1", "val_loss_vae", "val_kld", "train_loop_s", "wall_s",
                                              "time")},
                     "train_l1": _window_mean(train_l1, v["step"], TRAIN_L1_WINDOW)} for v in tl.get("val") or []],
            "checkpoints": checkpoints,
        })
    payload = {"benchmark": "hard", "updated": dt.datetime.now().isoformat(timespec="seconds"),
               "data": str(args.data), "validation_episodes": args.val_spec,
               "eval": {"trials": args.trials, "seed": args.eval_seed, "every_steps": args.eval_every},
               "comparison": comparison_table(args.root), "choice": _read(args.root / "choice.json"),
               "runs": runs}
    _write_json(args.root / "results.json", payload)
    return payload


# --------------------------------------------------------------------------------------------- commands


def run(args: argparse.Namespace) -> int:
    args.root.mkdir(parents=True, exist_ok=True)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, _on_signal)
    log(f"campaign start, pid {os.getpid()}, pgid {os.getpgrp()}; validation {args.val_spec}")
    try:
        choice = compare(args)
        results(args)
        failures: dict[str, int] = {}
        waiting = False
        while (state := next_job(args, choice["config"], failures)) != "done":
            if state == "ran":
                results(args)
                waiting = False
                continue
            if not waiting:
                log("every remaining job is held by another worker or waits for a checkpoint; waiting")
                waiting = True
            if _stopping:
                raise Stopped
            time.sleep(30)
        results(args)
        left = sorted(k for k, n in failures.items() if n >= 3)
        log("campaign: every job done" if not left else f"campaign: done here; failed three times: {left}")
    except Stopped:
        log("campaign stopped by a signal (resume: the same `run` command)")
        results(args)
    return 0


def _r(x: float | None) -> float | None:
    return None if x is None else round(x, 3)


def status(args: argparse.Namespace) -> int:
    running = []
    for path in job_locks(args.root):
        if (pid := holder(path)) is None:
            continue
        state = ""
        try:  # the third field of /proc/PID/stat: R/S running or sleeping, T stopped (kill -STOP)
            stat = Path(f"/proc/{pid}/stat").read_text()
            state = ", paused" if stat.rsplit(")", 1)[1].split()[0] == "T" else ""
        except OSError:
            pass
        job = ("compare" if path.name == "compare.lock" else path.parent.name if path.name == "lock"
               else f"{path.parent.name} evaluation at {int(path.stem)}")
        running.append(f"{job} (pid {pid}{state})")
    print(f"campaign: {'running ' + ', '.join(running) if running else 'not running'}")
    choice = _read(args.root / "choice.json")
    for row in comparison_table(args.root):
        mark = " <- chosen" if choice and choice["chosen"] == row["name"] else ""
        print(f"compare {row['name']:28s} step {row['steps']:>6}  val_l1(last3) {row['val_l1_last3']}  "
              f"s/step {_r(row['s_per_step'])} (median {_r(row['s_per_step_median'])}){mark}")
    for demos, seed in args.plan:
        name = f"hard_{demos}_{seed}"
        tl = _read(args.root / "train" / name / "train_log.json")
        if not tl:
            continue
        evals = sorted((args.root / "evals" / name).glob("[0-9]*.json"))
        succ = [f"{int(p.stem)}:{(_read(p) or {}).get('successes')}/{(_read(p) or {}).get('n_trials')}" for p in evals]
        last = (tl.get("val") or [{}])[-1]
        print(f"train {name:12s} step {tl['steps']:>6}  finished {tl.get('stop_reason')}  val_l1 "
              f"{last.get('val_l1')} (best {tl.get('best_val_l1')} at {tl.get('best_step')})  "
              f"s/step {_r(tl.get('s_per_step'))} (median {_r(tl.get('s_per_step_median'))})  "
              f"success {' '.join(succ)}")
    logfile = args.root / "log.txt"
    if logfile.is_file():
        print("--- log tail ---")
        print("\n".join(logfile.read_text(errors="replace").splitlines()[-5:]))
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("command", choices=["run", "status", "results", "workers"])
    p.add_argument("--root", type=Path, default=REPO / "runs" / "act_campaign")
    p.add_argument("--data", type=Path, default=REPO / "runs" / "act_data_lr" / "hard",
                   help="the LeRobot export of the hard set (seqmotion lfd export-lerobot)")
    p.add_argument("--compare-steps", type=int, default=3000)
    p.add_argument("--compare-val-every", type=int, default=250)
    p.add_argument("--plan", default=",".join(f"{n}:{s}" for n, s in PLAN),
                   help="main trainings in order, DEMOS:SEED,... (default %(default)s)")
    p.add_argument("--min-steps", type=int, default=10000)
    p.add_argument("--patience", type=int, default=2000)
    p.add_argument("--cap", type=int, default=40000, help="the most steps of a main training (raise to continue)")
    p.add_argument("--val-every", type=int, default=500)
    p.add_argument("--eval-every", type=int, default=2000)
    p.add_argument("--trials", type=int, default=30)
    p.add_argument("--eval-seed", type=int, default=0)
    args = p.parse_args(argv)
    args.root, args.data = args.root.resolve(), args.data.resolve()
    args.plan = [tuple(int(x) for x in item.split(":")) for item in args.plan.split(",") if item]
    if args.command == "status":
        return status(args)
    if args.command == "workers":  # the process groups to pause, continue or stop (kill -STOP -- -PGID)
        print(" ".join(sorted({pid for p in job_locks(args.root) if (pid := holder(p))})))
        return 0
    args.val_spec, _, _ = validation_spec(args.data)
    if args.command == "results":
        results(args)
        return 0
    return run(args)


if __name__ == "__main__":
    raise SystemExit(main())
