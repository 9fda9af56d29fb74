"""The ``seqmotion`` command line: train, deform, plan, optimize, simulate, reproduce, demo.

Every subcommand is a thin layer over the Python API; heavy modules are imported only when
their subcommand runs, so ``seqmotion --help`` is instant.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import os
import sys
from pathlib import Path

import numpy as np

PLUGIN_COMMANDS = ("seqmotion.sim.cli", "seqmotion.lfd.cli", "seqmotion.latent.cli")


def _model_arg(value: str, expected_task: str | None = None):  # noqa: ANN202 - the task's user-facing object
    """A shipped model name (``pancake``...) or a path to a model/run directory, of ``expected_task`` if given."""
    import seqmotion as sm
    from seqmotion.api import PRETRAINED

    if value in PRETRAINED and not Path(value).exists():
        if expected_task is not None and PRETRAINED[value] != expected_task:
            raise ValueError(f"the shipped model {value!r} is not a {expected_task!r} model")
        return sm.load_pretrained(value)
    return sm.load(value, expected_task=expected_task)


def read_trajectory(path: str | Path, key: str = "states") -> np.ndarray:
    """Read ``(K, dim)`` samples from ``.npz`` (array ``key``) or ``.csv`` (one sample per row)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path} does not exist")
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as data:
            if key not in data:
                raise ValueError(f"{path} has no array {key!r} (has {sorted(data.files)})")
            return data[key]
    if path.suffix == ".csv":
        try:
            return np.loadtxt(path, delimiter=",", ndmin=2)
        except ValueError:  # a header row
            return np.loadtxt(path, delimiter=",", ndmin=2, skiprows=1)
    raise ValueError(f"unsupported trajectory file {path} (use .npz or .csv)")


def write_arrays(path: str | Path, columns: dict[str, np.ndarray]) -> None:
    """Write named per-sample arrays to ``.npz``, or side by side to ``.csv`` (one row per sample).

    In a CSV, arrays with one sample fewer (inputs ``u[0..K-2]``) get a NaN last row, and
    arrays that are not per-sample (a latent) are left out: use ``.npz`` to keep them.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".npz":
        np.savez(path, **columns)
        return
    if path.suffix != ".csv":
        raise ValueError(f"unsupported output {path} (use .npz or .csv)")
    rows = len(next(iter(columns.values())))
    blocks, header = [], []
    for name, value in columns.items():
        value = np.asarray(value, dtype=np.float64)
        if value.ndim == 0 or len(value) not in (rows, rows - 1):
            continue
        value = value.reshape(len(value), -1)
        if len(value) == rows - 1:
            value = np.vstack([value, np.full((1, value.shape[1]), np.nan)])
        blocks.append(value)
        header += [f"{name}{i}" if value.shape[1] > 1 else name for i in range(value.shape[1])]
    np.savetxt(path, np.hstack(blocks), delimiter=",", header=",".join(header), comments="")


# --- subcommands ---------------------------------------------------------------------------------


def cmd_train(args: argparse.Namespace) -> int:
    from seqmotion import tasks
    from seqmotion.training.trainer import train

    task = tasks.get(args.task)
    config = task.train_config(args.config)
    if args.variant:
        if not hasattr(task, "apply_variant"):
            raise ValueError(f"task {args.task} has no variants")
        config = task.apply_variant(config, args.variant)
    if args.epochs:
        from seqmotion.training.curriculum import Curriculum

        config.curriculum = Curriculum.from_dict(config.curriculum).scaled(args.epochs).to_dict()
    for name in ("seed", "batch_size", "batches_per_epoch", "lr", "lr_final_fraction", "checkpoint_every"):
        value = getattr(args, name)
        if value is not None:
            setattr(config, name, value)
    for item in args.set or []:
        key, equals, raw = item.partition("=")
        if not equals:
            raise ValueError(f"--set needs KEY=VALUE, got {item!r}")
        if key not in config.options:
            raise ValueError(f"unknown option {key!r}; options of {args.task}: {sorted(config.options)}")
        try:
            config.options[key] = json.loads(raw)
        except json.JSONDecodeError:
            if not isinstance(config.options[key], str):  # only text options take bare words
                raise ValueError(f"--set {key}=...: {raw!r} is not a JSON value") from None
            config.options[key] = raw  # --set pan_shaking=velocity
    variant = f"-{args.variant}" if args.variant else ""
    out = Path(args.out or f"runs/{args.task}{variant}-{args.config}-seed{config.seed}")
    train(config, out, resume=not args.no_resume, progress=not args.quiet, stop_at_step=args.max_steps)
    if int(os.environ.get("RANK", "0")) == 0:  # under torchrun, say it once
        print(f"model written to {out} (load it with seqmotion.load({str(out)!r}))")
    return 0


def cmd_deform(args: argparse.Namespace) -> int:
    deformer = _model_arg(args.model, "pancake")
    states = read_trajectory(args.input)
    result = deformer.deform(states)
    write_arrays(
        args.output,
        {"states": result.states, "accel": result.accel, "violation": result.violation, "psi": result.psi,
         "latent": result.latent},
    )
    from seqmotion.physics import pancake

    fc_in = pancake.violation_of_states(states).max()
    print(f"deformed {len(states)} samples → {args.output}: max F_c {result.violation.max():.4f} rad "
          f"(input: {fc_in:.4f} rad)")
    return 0


def cmd_plan(args: argparse.Namespace) -> int:
    import numpy as np

    from seqmotion.data import sliding as commands

    planner = _model_arg(args.model, "sliding")
    if args.int8:
        planner = planner.quantized()
    command = commands.circle(args.circle, args.length) if args.circle else read_trajectory(args.command)
    plan = planner.plan(command, mu=args.mu, mu_dyn=args.mu_dyn)
    write_arrays(args.output, {"pan_states": plan.pan_states, "rel_states": plan.rel_states,
                               "pan_accel": plan.pan_accel, "command": command, "latent": plan.latent})
    rmse = 1000 * np.sqrt(((plan.rel_states[:, :2] - command[:, :2]) ** 2).sum(1).mean())
    reach = 1000 * np.linalg.norm(plan.pan_states[:, :2], axis=1).max()
    print(f"planned {len(command)} samples → {args.output}: object RMSE {rmse:.1f} mm against the command, "
          f"pan within {reach:.0f} mm of its start (2-D physics, μ = {args.mu}, μ' = {args.mu_dyn})")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    module = importlib.import_module(f"seqmotion.reproduce.{args.chapter}")
    out = Path(args.out or f"reproduce/{args.chapter}")
    module.run(out, model=args.model, quick=args.quick, seed=args.seed)
    print(f"figures and tables written to {out}/")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from seqmotion.training.export import export_pretrained

    metrics = json.loads(Path(args.metrics).read_text()) if args.metrics else None
    target = export_pretrained(Path(args.run), args.name, metrics, args.notes or "")
    print(f"shipped {args.run} as {args.name!r} in {target} (with MODEL_CARD.md)")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from seqmotion.reproduce.demo import run

    run(Path(args.out), simulate=not args.no_sim)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="seqmotion", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("train", help="train a task's model through its curriculum")
    p.add_argument("task", help="task name (pancake, sliding, ...)")
    p.add_argument("--config", default="small", help="preset: tiny | small | paper")
    p.add_argument("--variant", help="task variant (sliding: A | B | C)")
    p.add_argument("--out", help="run directory (default runs/<task>-<config>-seed<seed>)")
    p.add_argument("--seed", type=int)
    p.add_argument("--epochs", type=int, help="squeeze/stretch the curriculum to this many epochs")
    p.add_argument("--batch-size", type=int)
    p.add_argument("--batches-per-epoch", type=int)
    p.add_argument("--lr", type=float)
    p.add_argument("--lr-final-fraction", type=float, help="cosine-decay the learning rate to this fraction of --lr")
    p.add_argument("--checkpoint-every", type=int, help="steps between checkpoints (default: every epoch)")
    p.add_argument("--max-steps", type=int, help="stop after this many steps (for timing)")
    p.add_argument("--set", action="append", metavar="KEY=JSON",
                   help="override a task option (a JSON value; text options also take bare words)")
    p.add_argument("--no-resume", action="store_true", help="start over even if the run has checkpoints")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("deform", help="deform a pancake-turning motion so the pancake stays on")
    p.add_argument("--model", default="pancake", help="shipped model name or model/run directory")
    p.add_argument("--input", required=True, help=".npz (array 'states') or .csv: (K, 6) rows y,z,θ,vy,vz,vθ")
    p.add_argument("--output", required=True, help=".npz or .csv")
    p.set_defaults(func=cmd_deform)

    p = sub.add_parser("plan", help="plan pan shaking that slides an object along a command (ch. 3)")
    p.add_argument("--model", default="sliding", help="shipped model name or model/run directory")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--command", help=".npz (array 'states') or .csv: (K, 4) object x, y, vx, vy relative to the pan")
    src.add_argument("--circle", type=float, metavar="RADIUS", help="a circle of this radius [m] as the command")
    p.add_argument("--length", type=int, default=1200, help="K of the --circle command")
    p.add_argument("--mu", type=float, default=1.0, help="static friction of the 2-D physics")
    p.add_argument("--mu-dyn", type=float, default=0.5, help="dynamic friction of the 2-D physics")
    p.add_argument("--int8", action="store_true", help="int8 weights for the big layers (faster on CPU, wide models)")
    p.add_argument("--output", required=True, help=".npz or .csv")
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("reproduce", help="reproduce a chapter's figures and tables")
    p.add_argument("chapter", choices=["ch2", "ch3", "ch4", "ch5"])
    p.add_argument("--out", help="output directory (default reproduce/<chapter>)")
    p.add_argument("--model", help="model/run directory to use instead of the shipped one")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quick", action="store_true", help="fewer samples (a smoke test of the pipeline)")
    p.set_defaults(func=cmd_reproduce)

    p = sub.add_parser("export", help="ship a finished run inside the package, with a model card")
    p.add_argument("run", help="training run directory")
    p.add_argument("--name", required=True, help="pretrained name (see seqmotion.api.PRETRAINED)")
    p.add_argument("--metrics", help="JSON file of measured metrics for the card")
    p.add_argument("--notes", help="free text for the card")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("demo", help="deform motions with the shipped model and show what it does")
    p.add_argument("--out", default="seqmotion-demo", help="where figures go")
    p.add_argument("--no-sim", action="store_true", help="skip the MuJoCo robot")
    p.set_defaults(func=cmd_demo)

    # Subcommands that live beside their subsystem (simulate, lfd, plan, optimize).
    for module_name in PLUGIN_COMMANDS:
        if importlib.util.find_spec(module_name) is not None:
            importlib.import_module(module_name).add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ValueError as exc:  # bad input: a clear message, no traceback
        print(f"seqmotion {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
