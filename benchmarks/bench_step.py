"""One training step of a shipped configuration, old code against new, side by side in one process.

    python benchmarks/bench_step.py                      # pancake and sliding "small", old = git HEAD
    python benchmarks/bench_step.py --old-rev 5f06a00 --tasks pancake --rounds 5 --steps 5

The old code is the package as committed at ``--old-rev``, extracted with ``git archive`` into a temporary
directory (the working tree and the repository's state are left alone) and imported under another name
(``seqmotion_old``: its imports are relative), so both run in this process on the same data, alternating
round by round (old, new, old, new, …) so that a change in the machine's load hits both alike. A step is
what :func:`seqmotion.training.trainer.train` does per batch: the task's loss on a fresh batch of the
shipped preset at one curriculum stage, backward, gradient clipping and Adam. Each round times ``--steps``
steps after ``--warmup`` untimed ones; the table gives the median over rounds.

Prints a markdown table (and ``--out`` writes it with the machine's description).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import io
import platform
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]


def load_old(rev: str, into: Path):  # noqa: ANN201 - a module
    """The package as committed at ``rev``, imported as ``seqmotion_old``."""
    blob = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "src/seqmotion"], check=True,
                          capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(blob)) as tar:
        tar.extractall(into, filter="data")
    init = into / "src" / "seqmotion" / "__init__.py"
    spec = importlib.util.spec_from_file_location("seqmotion_old", init, submodule_search_locations=[str(init.parent)])
    module = importlib.util.module_from_spec(spec)
    sys.modules["seqmotion_old"] = module
    spec.loader.exec_module(module)
    return module


class Stepper:
    """A model, its Adam and one fixed batch of ``task`` from package ``pkg`` (``seqmotion`` or the old one)."""

    def __init__(self, pkg_name: str, task_name: str, stage_epoch: int, seed: int = 0) -> None:
        task_module = importlib.import_module(f"{pkg_name}.tasks.{task_name}")
        loop_module = importlib.import_module(f"{pkg_name}.training.loop")
        self.task = task_module.TASK
        self.cfg = self.task.train_config("small")
        torch.manual_seed(seed)
        self.model = self.task.build_model(self.cfg)
        self.loop = loop_module.TrainingLoop(self.model, list(self.model.parameters()), lr=self.cfg.lr,
                                             total_steps=10_000, grad_clip=self.cfg.grad_clip, run_dir=None)
        curriculum = self.task.curriculum(self.cfg)
        self.stage = curriculum.at(stage_epoch, 0.5)
        trainer = importlib.import_module(f"{pkg_name}.training.trainer")
        self.step_loss = getattr(trainer, "step_loss", None)  # None: a version before the typed task contract
        typed = self.step_loss is not None
        self.batch = self.task.sample(self.cfg.batch_size, np.random.default_rng([seed, 1]),
                                      self.task.params(self.stage) if typed else self.stage,
                                      self.task.options(self.cfg) if typed else self.cfg)
        self.k_max = int(self.batch.states.shape[1])

    def step(self, s: int) -> float:
        coins = torch.Generator().manual_seed(1000 + s)
        if self.step_loss is not None:
            loss, _ = self.step_loss(self.task, self.model, self.batch, self.stage, self.cfg, coins)
        else:
            loss, _ = self.task.loss(self.model, self.batch, self.stage, self.cfg, coins)
        self.loop.step(loss)
        return float(loss.detach())


def time_steps(stepper: Stepper, steps: int, warmup: int, start: int) -> float:
    for i in range(warmup):
        stepper.step(start + i)
    t = time.perf_counter()
    for i in range(steps):
        stepper.step(start + warmup + i)
    return (time.perf_counter() - t) / steps


def learning_curves(steps: int, task: str, into: Path) -> list[str]:
    """Train ``task`` small from the same seed for ``steps`` steps with the old and the new code (the real
    trainer: curriculum, fresh data, coins); compare the logged losses."""
    import csv

    curves = {}
    for name in ("seqmotion_old", "seqmotion"):
        trainer = importlib.import_module(f"{name}.training.trainer")
        task_def = importlib.import_module(f"{name}.tasks.{task}").TASK
        run = into / f"curve-{name}"
        t = time.perf_counter()
        trainer.train(task_def, task_def.train_config("small"), run, progress=False, stop_at_step=steps)
        seconds = time.perf_counter() - t
        with open(run / "metrics.csv") as f:
            curves[name] = (np.array([float(r["loss"]) for r in csv.DictReader(f)]), seconds)
    old, new = curves["seqmotion_old"][0], curves["seqmotion"][0]
    lines = [f"Learning curve, `{task}` small, seed 0, the first {steps} steps of the real training (trainer, "
             "curriculum, fresh data per step):", "",
             "| steps | old mean loss | new mean loss |", "|---|---|---|"]
    for a in range(0, steps, max(steps // 5, 1)):
        b = min(a + max(steps // 5, 1), steps)
        lines.append(f"| {a + 1}–{b} | {old[a:b].mean():.4f} | {new[a:b].mean():.4f} |")
    lines += ["", f"Loss at step 1: old {old[0]:.6f}, new {new[0]:.6f}; at step {steps}: old {old[-1]:.4f}, new "
              f"{new[-1]:.4f}; largest |old − new| over the {steps} steps {np.abs(old - new).max():.3g}, "
              f"largest relative {np.max(np.abs(old - new) / np.abs(old)):.3g}. Wall time of the {steps} steps: old "
              f"{curves['seqmotion_old'][1]:.0f} s, new {curves['seqmotion'][1]:.0f} s."]
    return lines


def machine() -> str:
    try:
        lscpu = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
        name = next((line.split(":", 1)[1].strip() for line in lscpu.splitlines() if line.startswith("Model name")),
                    platform.processor())
    except OSError:
        name = platform.processor()
    import os

    return f"{name}, {os.cpu_count()} cores, torch {torch.__version__} ({torch.get_num_threads()} threads)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--old-rev", default="HEAD", help="git revision of the old code (default HEAD)")
    parser.add_argument("--tasks", nargs="+", default=["pancake", "sliding"])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--steps", type=int, default=5, help="timed steps per round")
    parser.add_argument("--warmup", type=int, default=1, help="untimed steps per round")
    parser.add_argument("--epoch", type=int, default=15,
                        help="curriculum epoch of the batch (15: scheduled sampling under way)")
    parser.add_argument("--out", type=Path, help="also write the table here (markdown)")
    parser.add_argument("--curve", type=int, default=0, metavar="N",
                        help="also train the first task N steps with old and new code and compare the losses")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        load_old(args.old_rev, Path(tmp))
        import seqmotion

        rows = []
        for task in args.tasks if args.rounds > 0 else []:  # --rounds 0: only the learning curve
            old = Stepper("seqmotion_old", task, args.epoch)
            new = Stepper("seqmotion", task, args.epoch)
            times: dict[str, list[float]] = {"old": [], "new": []}
            for r in range(args.rounds):
                for name, stepper in (("old", old), ("new", new)):
                    times[name].append(time_steps(stepper, args.steps, args.warmup, r * (args.steps + args.warmup)))
            t_old, t_new = statistics.median(times["old"]), statistics.median(times["new"])
            rows.append((task, old.cfg.batch_size, old.k_max, t_old, t_new, min(times["old"]), min(times["new"])))
            print(f"{task}: old {t_old:.4f} s, new {t_new:.4f} s per step ({t_old / t_new:.2f}x)", file=sys.stderr)
        curve = learning_curves(args.curve, args.tasks[0], Path(tmp)) if args.curve else []

    lines = [f"Machine: {machine()}. Old: `git {args.old_rev}`; new: the working tree "
             f"({Path(seqmotion.__file__).parent})."]
    if rows:
        lines += [
            f"{args.rounds} alternating rounds × {args.steps} timed steps (+{args.warmup} warm-up) each; "
            f"one batch of the `small` preset at curriculum epoch {args.epoch}.",
            "",
            "| task (small) | batch × K_max | old s/step (median) | new s/step (median) | speed-up | old best "
            "| new best |",
            "|---|---|---|---|---|---|---|",
        ]
    for task, b, k, t_old, t_new, best_old, best_new in rows:
        lines.append(f"| {task} | {b} × {k} | {t_old:.4f} | {t_new:.4f} | {t_old / t_new:.2f}× | {best_old:.4f} | "
                     f"{best_new:.4f} |")
    if curve:
        lines += [""] + curve
    text = "\n".join(lines)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
