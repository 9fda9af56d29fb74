"""The ``seqmotion`` command line: train, deform, plan, optimize, simulate, reproduce, demo.

Every subcommand is a thin layer over the Python API; heavy modules are imported only when
their subcommand runs, so ``seqmotion --help`` is instant.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import math
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

OUTPUT_HELP = ".npz (the result: seqmotion.load_result reads it back) or .csv (plain columns for other tools)"
PLUGIN_COMMANDS = ("seqmotion.sim.cli", "seqmotion.lfd.cli", "seqmotion.deploy.cli", "seqmotion.view.cli")
TIMED_COMMANDS = frozenset({"demo", "deform", "optimize", "plan", "simulate", "train", "reproduce"})
"""The long-running commands: each ends with ``done in …`` on stdout, since the README's times are a quiet machine's
and a busy one takes several times longer (their stdout is a report for people; their data goes to files)."""


def _trained_model(value: str, expected_task: str | None = None):  # noqa: ANN202 - a task's TrainedModel
    """``--model``: a shipped model's name or a model/run directory, a seq2seq model (of ``expected_task``)."""
    from seqmotion.api import resolve_model
    from seqmotion.tasks import TrainedModel

    model = resolve_model(value, expected_task)
    if not isinstance(model, TrainedModel):
        raise ValueError(f"{value} is a {type(model).__name__}, not a sequence-to-sequence motion model")
    return model


def result_columns(result: object, model) -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:  # noqa: ANN001
    """A result's arrays and, for CSV headers, the task's column names of each
    (:func:`seqmotion.core.results.columns_of` with ``model``'s layouts)."""
    from seqmotion.core.results import columns_of

    return columns_of(result, model.state_layout, model.accel_layout, model.uncertainty_names)


def write_result(path: str, result: object, columns: dict[str, np.ndarray], names: dict[str, list[str]]) -> None:
    """``--output``: an ``.npz`` through ``result.save`` (``sm.load_result`` reads it back; ``columns`` kept beside it
    for readers of plain arrays), a ``.csv`` as plain columns for other tools."""
    if Path(path).suffix.lower() == ".npz":
        result.save(path, extra=columns)
    else:
        from seqmotion.io import write_arrays

        write_arrays(path, columns, names)


# --- subcommands ---------------------------------------------------------------------------------


def cmd_train(args: argparse.Namespace) -> int:
    from seqmotion import tasks
    from seqmotion.errors import check_number
    from seqmotion.training.curriculum import Curriculum

    task = tasks.get(args.task)
    if not isinstance(task, tasks.Task):
        raise ValueError(
            f"task {args.task!r} is not trained by `seqmotion train`"
            + (f": {task.trained_by}" if getattr(task, "trained_by", None) else "")
        )
    for option, value in (("--max-steps", args.max_steps), ("--epochs", args.epochs)):
        if value is not None:
            check_number(option, value, minimum=1, integer=True)
    from seqmotion.training.device import resolve_device

    try:
        device = resolve_device(args.device)  # refused before anything is written
    except ValueError as exc:
        raise ValueError(f"--device: {exc}") from None
    config = task.train_config(args.config)
    if args.variant:
        if not hasattr(task, "apply_variant"):
            raise ValueError(f"task {args.task} has no variants")
        config = task.apply_variant(config, args.variant)
    if args.final_stage:  # fine-tuning: the schedule's end, held throughout (over --epochs if given)
        config.curriculum = Curriculum.from_dict(config.curriculum).at_final_stage(args.epochs).to_dict()
    elif args.epochs is not None:
        config.curriculum = Curriculum.from_dict(config.curriculum).scaled(args.epochs).to_dict()
    for name in ("seed", "batch_size", "batches_per_epoch", "lr", "lr_final_fraction", "checkpoint_every"):
        value = getattr(args, name)
        if value is not None:
            setattr(config, name, value)
    try:
        config.validate()  # the overrides, checked like the preset's values
    except ValueError as exc:
        setting = str(exc).split()[0]
        flag = f" (--{setting.replace('_', '-')})" if getattr(args, setting, None) is not None else ""
        raise ValueError(f"{exc}{flag}") from None
    options = task.options(config)
    changes = {}
    for item in args.set or []:
        key, equals, raw = item.partition("=")
        if not equals:
            raise ValueError(f"--set needs KEY=VALUE, got {item!r}")
        changes[key] = options.parse(key, raw)
    config.options = options.replace(**changes).to_dict()  # checked: unknown keys and bad values refused by name
    variant = f"-{args.variant}" if args.variant else ""
    out = Path(args.out if args.out is not None else f"runs/{args.task}{variant}-{args.config}-seed{config.seed}")
    check_writable_dir(out, "--out")
    init_from = args.init_from
    if init_from is not None and not Path(init_from).exists():  # a shipped model's name
        from seqmotion.api import pretrained_models

        shipped = pretrained_models()
        if init_from not in shipped:
            raise ValueError(f"--init-from {init_from}: neither a model/run directory nor a shipped model "
                             f"({sorted(shipped)})")
        init_from = shipped[init_from]
    tasks.train(config, out, resume=not args.no_resume, progress=not args.quiet, stop_at_step=args.max_steps,
                init_from=init_from, device=device)
    if int(os.environ.get("RANK", "0")) == 0:  # under torchrun, say it once
        print(f"model written to {out} (load it with seqmotion.load({str(out)!r}))")
    return 0


def cmd_deform(args: argparse.Namespace) -> int:
    from seqmotion.core.polish import ARM_MIN_DURATION
    from seqmotion.io import check_not_an_input, check_output, check_writable, read_trajectory
    from seqmotion.physics.integrator import DoubleIntegratorDynamics, implied_accel

    check_output(args.output)
    check_not_an_input(args.output, "--output", {"--input": args.input})
    if args.plot is not None:  # refused before the work, like --output
        check_writable(args.plot, (".png", ".pdf", ".svg"), "--plot")
        check_not_an_input(args.plot, "--plot", {"--input": args.input, "--output": args.output})
    model = _trained_model(args.model)
    if args.robot is not None:  # refused before the work: a task without a check, a robot not here
        from seqmotion.sim.registration import check_robot_option

        check_robot_option(model.task_def.name, args.robot)
    inputs = read_trajectory(args.input, columns=model.input_layout.names)
    with warnings.catch_warnings(record=True) as caught:  # the polish's failures: one line below, not Python's text
        warnings.simplefilter("always")
        result = model.generate(inputs, keep_end=args.keep_end, robot=args.robot)
    from seqmotion.errors import said_by

    robot_said = [w for w in caught if str(w.message).startswith("not executable on ")]
    polish_failures = said_by([w for w in caught if w not in robot_said], "keep_end: ")  # re-issues the rest
    not_executable = said_by(robot_said, "not executable on ")
    motion = result.motion()
    columns, names = result_columns(result, model)
    write_result(args.output, result, columns, names)
    message = f"{model.task_def.name}: generated {len(motion.states)} samples → {args.output}"
    if motion.violation is not None:
        message += f": max constraint violation {np.max(motion.violation):.4f}{violation_unit(model, ' ')}"
        message += at_physics(result.physics)
        # the input's own violation, where the model's outputs are what its velocities imply (a double integrator)
        if model.input_layout == model.state_layout and isinstance(model.dynamics(), DoubleIntegratorDynamics):
            import torch

            x = torch.from_numpy(np.asarray(inputs, dtype=np.float64))[None]
            before = model.violation_torch(x, torch.from_numpy(implied_accel(x.numpy())))
            if before is not None:
                message += f" (input: {float(before.max()):.4f})"
    print(message)
    if args.keep_end:
        rates = [i for i, unit in enumerate(model.state_layout.units) if unit.endswith("/s")]
        at_rest = bool(np.all(np.abs(np.asarray(motion.states)[result.length - 1, rates]) < 1e-6))
        if result.exact:
            print("ends exactly at the input's end pose, at rest (polished)")
        elif at_rest:  # the warning line on stderr says why; this says what was written instead
            print("not exact: no motion ends at the input's end pose within the task's constraint and the arm's "
                  "limits and reach; this one ends at rest as near it as they allow (end error below)")
        else:
            print("not exact: the learned motion, unpolished")
        if result.length > len(inputs) and args.robot:
            print(f"  it takes {result.length - len(inputs)} samples more than the input: on {args.robot}'s joints the "
                  f"polish plans at least {ARM_MIN_DURATION:g} s, and longer where its rated limits need it")
        elif result.length > len(inputs):
            print(f"  it takes {result.length - len(inputs)} samples more than the input: ending at rest within the "
                  f"arm's acceleration limits {model.exact_form().accel_limits} needs that time")
    for line in model.trust_lines(result):
        print(line)
    if not args.keep_end:
        print_not_executable(model, result)
    if args.plot:
        plot_deform(model, inputs, result, Path(args.plot))
        print(f"figure → {args.plot}")
    check = getattr(result, "robot_check", None)
    if check is not None:
        print(check.describe())
    from seqmotion.errors import report_made

    inexact = args.keep_end and not bool(np.all(result.exact))
    return report_made("deform", args.output,
                       ("--keep-end", "; ".join(polish_failures) or "the polish did not converge") if inexact else None,
                       not_executable[0] if not_executable else None)


def violation_unit(model, before: str = "") -> str:  # noqa: ANN001 - a task's TrainedModel
    """The unit of the task's constraint violation, from its tolerance's name (``max_violation_rad`` → ``rad``),
    with ``before`` in front; "" when the task names none."""
    key = next((k for k in model.task_def.tolerances(model.options) if k.startswith("max_violation")), "")
    unit = key.removeprefix("max_violation").removeprefix("_")
    return f"{before}{unit}" if unit else ""


def at_physics(physics: object) -> str:
    """`` at mu = 0.8`` — the physics a result was computed at (:attr:`TrustSignals.physics`) — or "" for a task
    without physics parameters."""
    if physics is None or not physics.to_dict():
        return ""
    return f" at {physics.describe()}"


def print_not_executable(model, result: object) -> None:  # noqa: ANN001 - a task's TrainedModel
    """Say when the learned motion misses the task's end tolerances (ends elsewhere, or still moving), so an arm
    cannot execute it as it is, and point to ``--keep-end`` where the task has an exact polish."""
    from seqmotion.core import trust

    tolerances = model.task_def.tolerances(model.options)
    ends = {k: v for k, v in tolerances.items() if k.startswith("end_")}
    missed = [m.split(" ", 1)[0] for m in trust.missed(getattr(result, "errors", None) or {}, ends)]
    if not missed:
        return
    fix = ("; --keep-end polishes it to end exactly at the input's end pose, at rest (about a second)"
           if model.task_def.exact_form(model.options) is not None else "")
    print(f"warning: not executable as is: the learned motion does not end where the input ends, at rest "
          f"({' and '.join(missed)} beyond tolerance, above){fix}")


def plot_deform(model, inputs: np.ndarray, result: object, path: Path) -> None:  # noqa: ANN001
    """``--plot``: the input and the deformed motion, each state field over time, and the violation with its
    limit (the task's tolerance), written atomically (:func:`~seqmotion.io.save_figure`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from seqmotion.io import save_figure

    motion = result.motion()
    states = np.asarray(motion.states)
    positions = [i for i, unit in enumerate(model.state_layout.units) if not unit.endswith("/s")]
    violation = motion.violation
    rows = len(positions) + (violation is not None)
    fig, axes = plt.subplots(rows, 1, figsize=(6.5, 1.8 * rows), sharex=True, squeeze=False)
    axes = axes[:, 0]
    same = model.input_layout.names == model.state_layout.names
    for ax, i in zip(axes, positions, strict=False):
        name, unit = model.state_layout.names[i], model.state_layout.units[i]
        if same:
            ax.plot(np.arange(len(inputs)), inputs[:, i], "--", color="0.4", label="input")
        ax.plot(np.arange(len(states)), states[:, i], "-", color="tab:blue", label="deformed")
        ax.set_ylabel(f"{name} [{unit}]")
    axes[0].legend(fontsize=8, loc="best")
    if violation is not None:
        tolerances = model.task_def.tolerances(model.options)
        limit = next((v for k, v in tolerances.items() if k.startswith("max_violation")), None)
        unit = violation_unit(model)
        ax = axes[-1]
        ax.plot(np.arange(len(violation)), np.asarray(violation), "-", color="tab:red", label="violation")
        if limit is not None:
            ax.axhline(limit, color="k", ls=":", lw=1, label=f"limit {limit:g}")
        ax.set_ylabel(f"violation [{unit}]" if unit else "violation")
        ax.legend(fontsize=8, loc="best")
    axes[-1].set_xlabel("sample (1 ms)")
    fig.suptitle(f"{model.task_def.name}: input and deformed motion")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def cmd_plan(args: argparse.Namespace) -> int:
    import numpy as np

    from seqmotion.errors import MAX_LENGTH, check_number
    from seqmotion.io import check_not_an_input, check_output, read_trajectory
    from seqmotion.tasks.sliding import data as commands

    check_output(args.output)
    check_not_an_input(args.output, "--output", {"--command": args.command_file})
    if args.tolerance is not None:
        check_number("--tolerance (RMS distance [m])", args.tolerance, minimum=0)
    if args.circle is not None:
        check_number("--circle (radius [m])", args.circle, minimum=0, strict_minimum=True, maximum=10.0)
        check_number("--length", args.length, minimum=2, maximum=MAX_LENGTH, integer=True)
    planner = _trained_model(args.model, "sliding")
    if args.int8:
        planner = planner.quantized()
    if args.circle is not None:
        command = commands.circle(args.circle, args.length)
    else:
        command = read_trajectory(args.command_file, columns=planner.input_layout.names)
    if args.robot_limits is not None and args.robot is None:
        raise ValueError("--robot-limits needs --robot NAME")
    robot = {} if args.robot is None else {"robot": args.robot, "limits": _robot_limits(args)}
    with warnings.catch_warnings(record=True) as caught:  # the robot's verdict: one line below, not Python's text
        warnings.simplefilter("always")
        if args.refine:  # ch. 4's machinery on the planner: refine z through the contact physics (seconds)
            from seqmotion.tasks.sliding.latent import refine_plan

            plan = refine_plan(planner, command, mu=args.mu, mu_dyn=args.mu_dyn, **robot)
        else:
            plan = planner.plan(command, mu=args.mu, mu_dyn=args.mu_dyn, **robot)
    from seqmotion.errors import report_made, said_by

    not_executable = said_by(caught, "not executable on ")  # re-issues the rest (e.g. what the limits cost)
    columns, names = result_columns(plan, planner)
    # The friction it was planned at travels with the plan: `seqmotion simulate sliding` compares it with the arm's.
    friction = np.array([plan.physics.mu, plan.physics.mu_dyn])
    mu, mu_dyn = plan.physics.mu, plan.physics.mu_dyn
    write_result(args.output, plan, {**columns, "command": command, "friction": friction},
                 {**names, "command": [f"command.{n}" for n in planner.input_layout.names]})
    rmse, reach = 1000 * plan.errors["tracking_rmse_m"], 1000 * plan.errors["pan_max_m"]
    print(f"planned {len(command)} samples → {args.output}: object RMSE {rmse:.1f} mm against the command, "
          f"pan within {reach:.0f} mm of its start (2-D physics, μ = {mu:g}, μ' = {mu_dyn:g})")
    tolerance = {} if args.tolerance is None else {"tracking_rmse_m": args.tolerance}
    for line in planner.trust_lines(plan, tolerance):
        print(line)
    from seqmotion.sim.sliding import ARM_PHYSICS  # constants only: MuJoCo is not imported

    arm = (ARM_PHYSICS.mu, ARM_PHYSICS.mu_dyn)
    if (mu, mu_dyn) != arm:  # a plan (a refined one above all) exploits the friction it was made at
        print(f"note: the simulated arm's object has μ = {arm[0]:g}, μ' = {arm[1]:g}; to execute this plan with "
              f"`seqmotion simulate sliding`, plan at that friction (--mu {arm[0]:g} --mu-dyn {arm[1]:g})")
    check = getattr(plan, "robot_check", None)
    if check is not None:
        print(check.describe())
    return report_made("plan", args.output, robot=not_executable[0] if not_executable else None)


def _robot_limits(args: argparse.Namespace) -> tuple[str, ...]:
    """``--robot-limits a,b``: the limit kinds ``plan --robot`` keeps (default: all of them)."""
    from seqmotion.sim.registration import check_robot_option
    from seqmotion.tasks.sliding import ROBOT_KINDS, check_limit_kinds

    check_robot_option("sliding", args.robot)  # refused before the work: a robot not here
    if args.robot_limits is None:
        return ROBOT_KINDS
    kinds = tuple(k.strip() for k in args.robot_limits.split(",") if k.strip())
    try:
        check_limit_kinds(kinds)
    except ValueError:
        raise ValueError(f"--robot-limits must be a comma-separated list of {', '.join(ROBOT_KINDS)}, got "
                         f"{args.robot_limits!r}") from None
    return kinds


def cmd_calibrate_trust(args: argparse.Namespace) -> int:
    from seqmotion.core import trust
    from seqmotion.io import check_writable_dir as check

    model = _trained_model(args.model)
    directory = Path(getattr(model, "source_dir", None) or args.model)
    check(directory, "model directory")
    path = trust.write_calibration(model, directory, n=args.n, seed=args.seed)
    cal = model.trust_calibration
    print(f"wrote {path}: {args.n} training inputs; in distribution: "
          + ", ".join(f"{k} ≤ {v:.4g}" for k, v in cal.upper.items()) + f", length ≥ {cal.lower['length']:.0f}")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    out = Path(args.out if args.out is not None else f"reproduce/{args.chapter}")
    check_writable_dir(out, "--out")
    if args.retrain and args.chapter != "ch5":
        raise ValueError(f"--retrain is for ch5 (its policies); {args.chapter} uses the shipped model or --model")
    module = importlib.import_module(f"seqmotion.reproduce.{args.chapter}")
    extra = {"retrain": args.retrain} if args.chapter == "ch5" else {}
    module.run(out, model=args.model, quick=args.quick, seed=args.seed, **extra)
    print(f"figures and tables written to {out}/")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    import seqmotion as sm
    from seqmotion import tasks
    from seqmotion.io import read_json
    from seqmotion.training.checkpoint import resolve_model_dir
    from seqmotion.training.pretrained import check_pretrained_name, export_pretrained

    check_pretrained_name(args.name)
    if args.to is not None:
        check_writable_dir(Path(args.to), "--to")
    metrics = read_json(args.metrics, "--metrics") if args.metrics is not None else None  # a JSON object
    source = resolve_model_dir(Path(args.run))
    model = sm.load(source)
    if hasattr(model, "check_finished"):
        model.check_finished()
    task = tasks.get(model.config_json()["task"])
    root = Path(args.to) if args.to is not None else tasks.registry.home_package(task) / "pretrained"
    target = export_pretrained(model, source, args.name, root, metrics, args.notes or "")
    from seqmotion.core import trust
    from seqmotion.core.trained import TrainedModel

    if isinstance(model, TrainedModel):  # the out-of-distribution bounds ship beside the weights
        trust.write_calibration(model, target)
    print(f"shipped {args.run} as {args.name!r} in {target} (with MODEL_CARD.md"
          + (f" and {trust.TRUST_FILE})" if isinstance(model, TrainedModel) else ")"))
    if root not in tasks.pretrained_roots():
        print(f"note: {root} is not where seqmotion looks for shipped models; add it to "
              f"{tasks.registry.PRETRAINED_PATH_ENV} for sm.load_pretrained({args.name!r})")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from seqmotion.reproduce.demo import run

    check_writable_dir(Path(args.out), "--out")
    run(Path(args.out), simulate=not args.no_sim)
    return 0


# --- seqmotion optimize: adjust a motion through the latent space (ch. 4) from the shell, for any task -----------
#
# seqmotion optimize --target 0.1 0.0 3.14 --output adjusted.npz          # J1 (pancake: y, z, θ), case 1
# seqmotion optimize --preset j2 --output slow_turn.csv --plot slow_turn.png
# seqmotion optimize --model runs/tray-tiny --target 0.1 0.05 --output tray.npz   # a plug-in task's end pose
#
# The default input is the task's sketch, as long as the longest motion the model trained on (the
# options' length range: pancake 500, tray-tiny 200), so it is not flagged out of distribution for
# its length. The task's constraint is a term of every objective: printed, and warned about when missed.

FIGURE_SUFFIXES = (".png", ".pdf", ".svg")
"""What ``--plot`` writes (matplotlib picks the format from the suffix)."""
DEFAULT_LENGTH = 500
"""K of the default input for a task whose options have no length range."""


def default_length(model: Any) -> int:
    """K of the default input: the longest motion ``model`` trained on (the upper end of its options'
    ``length`` range, as the online generator's default), else :data:`DEFAULT_LENGTH`."""
    lengths = getattr(model.options, "length", None)
    if isinstance(lengths, (tuple, list)) and len(lengths) == 2:
        return int(lengths[1])
    return DEFAULT_LENGTH


def add_optimize_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("optimize", help="adjust a motion by gradient descent on its latent (ch. 4)")
    p.add_argument("--model", default="pancake", help="shipped model name or model/run directory, of any task")
    goal = p.add_mutually_exclusive_group(required=True)
    goal.add_argument("--target", nargs="+", type=float, metavar="VALUE",
                      help="end pose for J1, one value per field of the task's end pose "
                           "(pancake: Y Z THETA [m, m, rad])")
    goal.add_argument("--preset", choices=["j2"],
                      help="j2: the pancake's velocity-limited turn of §4.4.2 (eq. 4.10; other tasks refuse it)")
    p.add_argument("--input", help="input motion (.npz 'states' or .csv, (K, input_dim)); default: the task's sketch "
                                   "to the target (pancake: an S-curve)")
    p.add_argument("--length", type=int, help="K of the default input (samples at 1 ms; default: the longest "
                                              "motion the model trained on, e.g. pancake 500, tray-tiny 200)")
    p.add_argument("--case", type=int, choices=[1, 2, 3], default=1, help="1 encoder z, 2 random z, 3 accelerations")
    p.add_argument("--steps", type=int, help="updates (default 100 for J1, 20 for J2)")
    p.add_argument("--lr", type=float, help="fixed step size η (default: chosen by a line search at every update)")
    p.add_argument("--optimizer", choices=["auto", "sgd", "lm"], default="auto",
                   help="auto (default): Levenberg–Marquardt with penalty continuation for --target, gradient "
                        "descent with a line search for J2 (no least-squares form); sgd: plain gradient descent "
                        "(eq. 4.2); lm: Levenberg–Marquardt")
    p.add_argument("--exact", action=argparse.BooleanOptionalAction, default=None,
                   help="polish the result so the objective's goal and the task's constraint hold exactly (IPOPT; "
                        "default: on for --preset j2, whose bands descent alone misses; off for --target). Where "
                        "the polish cannot make it exact, the latent stage's motion is still written, marked inexact "
                        "(a .npz holds exact False; a .csv has no place for the mark), one 'seqmotion optimize: "
                        "warning:' line says why (exit code 3)")
    p.add_argument("--robot", metavar="NAME",
                   help="the robot the motion is for (see `seqmotion robots`): with --exact the polish also keeps its "
                        "rated limits where the robot layer states them as constraints (the UR5e's joint speeds, "
                        "ranges and torques), and the result is judged on it either way. Where it cannot execute "
                        "the motion, what was made is still written (a .npz holds feasible False), one 'seqmotion "
                        "optimize: warning: not executable on …' line names the binding limit (exit code 3)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--output", required=True, help=".npz (the result: seqmotion.load_result reads it back) or .csv "
                   "(plain columns for other tools)")
    p.add_argument("--plot", help="PNG with the trajectory, the constraint and the objective's progress")
    p.set_defaults(func=cmd_optimize)


def cmd_optimize(args: argparse.Namespace) -> int:
    """``seqmotion optimize``: adjust a motion through the latent space (ch. 4), for any task."""
    from seqmotion.api import resolve_model
    from seqmotion.errors import MAX_LENGTH, check_number, report_made, said_by
    from seqmotion.io import check_not_an_input, check_output, check_writable, read_trajectory, write_arrays
    from seqmotion.latent import optimize_latent, optimize_trajectory
    from seqmotion.latent.objectives import EndPose, Ranges
    from seqmotion.tasks import TrainedModel

    check_output(args.output)
    if args.plot is not None:
        check_writable(args.plot, FIGURE_SUFFIXES, "--plot")
    for option, path in (("--output", args.output), ("--plot", args.plot)):
        check_not_an_input(path, option, {"--input": args.input})
    if args.exact is None:
        args.exact = args.preset == "j2"
    if args.steps is not None:
        check_number("--steps (0: no update, the input's own motion)", args.steps, minimum=0, integer=True)
    if args.lr is not None:
        check_number("--lr", args.lr, minimum=0, strict_minimum=True)
    if args.length is not None:
        if args.input:
            raise ValueError("--length is the default input's length; --input has its own (drop --length)")
        check_number("--length", args.length, minimum=2, maximum=MAX_LENGTH, integer=True)
    check_number("--seed", args.seed, minimum=0, integer=True)
    model = resolve_model(args.model)
    if not isinstance(model, TrainedModel):
        raise ValueError(f"{args.model} is a {type(model).__name__}, not a sequence-to-sequence motion model")
    if args.robot is not None:  # refused before the work: a task without a check, a robot not here
        from seqmotion.sim.registration import check_robot_option

        check_robot_option(model.task_def.name, args.robot)
    task = model.task_def
    if args.preset == "j2":
        objective = Ranges()
        sketch_end = (0.0, 0.0, -3 * math.pi / 4)
        steps = args.steps if args.steps is not None else 20
    else:
        objective = EndPose(args.target)
        sketch_end = tuple(args.target)
        steps = args.steps  # the method's default
    objective = objective.bind(model)  # refuses a model of another layout, an end pose of another size, by name
    if args.input:
        states = read_trajectory(args.input, columns=model.input_layout.names)
    else:
        length = args.length if args.length is not None else default_length(model)
        states = task.sketch(sketch_end, length, timing="linear" if args.preset == "j2" else "s_curve")
    if args.optimizer == "lm" and args.lr is not None:
        raise ValueError("--lr is the step size of gradient descent; Levenberg–Marquardt (--optimizer lm) takes none")
    method: dict = {"optimizer": args.optimizer, "lr": args.lr if args.lr is not None else "auto",
                    "exact": args.exact, "robot": args.robot}
    # a missed constraint is printed below, with the other terms; a failed polish in one line, not Python's text
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.filterwarnings("ignore", "the task's constraint is missed", RuntimeWarning)
        if args.case == 3:
            res = optimize_trajectory(model, states, objective, steps=steps, **method)
        else:
            res = optimize_latent(model, states, objective, steps=steps,
                                  init="encoder" if args.case == 1 else "random", seed=args.seed, **method)
    robot_said = [w for w in caught if str(w.message).startswith("not executable on ")]
    not_executable = said_by(robot_said, "not executable on ")
    polish_failures = said_by([w for w in caught if w not in robot_said], "exact polish failed on ")
    steps = len(res.history) - 1
    violation = res.violation
    columns = {"states": res.states, "accel": res.accel, "history": res.history}
    if violation is not None:
        columns["violation"] = violation
    if res.latent is not None:
        columns["latent"] = res.latent
    if Path(args.output).suffix.lower() == ".npz":  # a result file: sm.load_result reads it back
        res.save(args.output, extra=columns)
    else:  # plain columns for other tools
        write_arrays(args.output, columns, {"states": list(model.state_layout.names),
                                            "accel": list(model.accel_layout.names)})
    fields, _ = task.end_pose or ((), ())
    end = {f: round(float(res.states[-1, model.state_layout.index(f)]), 4) for f in fields}
    message = (f"{objective!r}: {res.history[0]:.3g} → {res.history[-1]:.3g} in {steps} updates "
               f"({1000 * res.seconds_per_update:.1f} ms each); end {end}")
    if violation is not None:
        physics = res.physics
        at = f" at {physics.describe()}" if physics is not None and physics.to_dict() else ""
        message += f", max violation {float(violation.max()):.4f}{at}"
    print(message + f" → {args.output}")
    for line in res.describe().splitlines():  # each stage, and each term of the objective: met or MISSED
        print(f"  {line}")
    missed = [name for name, term in res.terms.items() if not term.met]
    if missed:
        print(f"warning: the objective's {', '.join(missed)} not met" + ("" if args.exact else
              " (--exact polishes the motion so they hold exactly)"))
    if res.exact is False:  # the warning line on stderr says why; this says what was written instead
        print("not exact: the latent stage's motion, unpolished")
    # errors against the input, predicted std, out-of-distribution; where the motion ends is the objective's
    # business here (its terms above), not the input's: only the end speed and the constraint are judged
    for line in model.trust_lines(res, {"end_position_error_m": math.inf}):
        print(f"  {line}")
    if args.plot:
        plot_optimize(model, res, columns.get("violation"), Path(args.plot))
    if res.robot_check is not None:
        print(f"  {res.robot_check.describe()}")
    return report_made("optimize", args.output,
                       ("--exact", "; ".join(polish_failures) or "the polish did not converge") if res.exact is False
                       else None, not_executable[0] if not_executable else None)


def plot_optimize(model: Any, res: Any, violation: np.ndarray | None, path: Path) -> None:
    """``--plot``: the adjusted motion's position fields (by the task's layout), its constraint (the task's own
    panel where it has one, e.g. the pancake's ψ in the friction cone; else the violation with its limit) and the
    objective's progress, written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from seqmotion.io import save_figure

    layout = model.state_layout
    fig, axes = plt.subplots(1, 3, figsize=(14, 3.6))
    t = np.arange(len(res.states))
    for j, label in enumerate(layout.labels()):
        if not layout.units[j].endswith("/s"):  # positions: the rates would crowd them out
            axes[0].plot(t, res.states[:, j], label=label)
    axes[0].set(xlabel="time [ms]", title="adjusted motion")
    axes[0].legend(fontsize=8)
    panel = CONSTRAINT_PANELS.get(model.task_def.name)
    if panel is not None:
        panel(axes[1], model, res.states, res.accel)
    elif violation is not None:
        limit = next((v for k, v in model.task_def.tolerances(model.options).items() if k.startswith("max_violation")),
                     None)
        axes[1].plot(t[:-1], violation, color="tab:red", label="violation")
        if limit is not None:
            axes[1].axhline(limit, color="k", ls=":", lw=1, label=f"limit {limit:g}")
        axes[1].set(ylabel="constraint violation")
        axes[1].legend(fontsize=8)
    title = "constraint" if violation is None else f"constraint (max {violation.max():.3f})"
    axes[1].set(xlabel="time [ms]", title=title)
    axes[2].plot(res.history)
    axes[2].set(yscale="log", xlabel="update", ylabel="objective", title="progress")
    fig.tight_layout()
    save_figure(fig, path, close=True, dpi=120)


def _pancake_cone(ax: Any, model: Any, states: np.ndarray, accel: np.ndarray) -> None:
    """The pancake's constraint panel: ψ(t) against the cone ±atan μ of the model's own μ."""
    from seqmotion.tasks.pancake import physics

    cone = model.physics.cone_half_angle
    t = np.arange(len(accel))
    ax.axhspan(-cone, cone, color="tab:blue", alpha=0.15, label=f"cone ±atan μ, μ = {model.physics.mu:g}")
    ax.plot(t, physics.psi(states[:-1], accel), label="ψ")
    ax.set(ylabel="ψ [rad]", ylim=(-np.pi, np.pi))
    ax.legend(fontsize=8)


CONSTRAINT_PANELS = {"pancake": _pancake_cone}
"""Task name → its own constraint panel for ``--plot`` (others get their violation against its limit)."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="seqmotion", description=__doc__.splitlines()[0])
    from importlib.metadata import version  # the installed distribution's version, as pip reports it

    parser.add_argument("--version", action="version", version=f"seqmotion {version('seqmotion')}")
    sub = parser.add_subparsers(dest="command", required=True)

    from seqmotion.core.registry import declared_names

    known = ", ".join(declared_names())
    p = sub.add_parser("train", help=f"train a task's model through its curriculum (tasks: {known})",
                       description=f"Train a task's model. Tasks installed: {known} (plug-ins register through the "
                                   "entry-point group seqmotion.tasks). Options: --set KEY=VALUE, checked against the "
                                   "task's options dataclass.")
    p.add_argument("task", help=f"task name: {known}")
    p.add_argument("--config", default="small", help="preset: tiny | small | paper (or the task's own)")
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
    p.add_argument("--init-from", metavar="MODEL",
                   help="fine-tune: start from this model's weights (a shipped name, model or run directory; "
                        "same task and --config architecture) instead of fresh ones")
    p.add_argument("--final-stage", action="store_true",
                   help="hold the curriculum's final parameters for all --epochs (for fine-tuning with --init-from)")
    p.add_argument("--device", default="auto", metavar="auto|cpu|cuda|cuda:N",
                   help="where to train (default auto: the GPU if PyTorch sees one, else the CPU); under torchrun on "
                        "GPUs one process per GPU (nccl), on CPUs gloo; checkpoints resume on any device")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("deform", help="encode a motion and regenerate it through the model (pancake: keep it on)")
    p.add_argument("--model", default="pancake", help="shipped model name or model/run directory, of any task")
    p.add_argument("--input", required=True,
                   help=".npz (array 'states') or .csv: (K, input_dim) rows in the task's input layout "
                        "(pancake: y,z,θ,vy,vz,vθ)")
    p.add_argument("--output", required=True, help=OUTPUT_HELP)
    p.add_argument("--keep-end", action="store_true",
                   help="end exactly where the input ends, at rest, with the constraint held and within the arm's "
                        "acceleration limits (an IPOPT polish of the learned motion; tasks with an exact form, e.g. "
                        "pancake); an input too short for that gets the time it needs (the output is longer). Where "
                        "the polish cannot make that exact motion, what was made is still written, marked inexact "
                        "(a .npz holds exact False; a .csv has no place for the mark), one 'seqmotion deform: "
                        "warning:' line says why (exit code 3)")
    p.add_argument("--robot", metavar="NAME",
                   help="also judge whether this robot can execute the motion (see `seqmotion robots`): its joint "
                        "path by the simulator's IK against the rated joint speeds, accelerations, ranges and reach. "
                        "Where a limit is broken, what was made is still written (a .npz holds feasible False), one "
                        "'seqmotion deform: warning: not executable on …' line names the binding limit and the "
                        "duration it needs (exit code 3)")
    p.add_argument("--plot", metavar="PNG",
                   help="also write a figure: the input and the deformed motion over time, and the violation with "
                        "its limit")
    p.set_defaults(func=cmd_deform)

    p = sub.add_parser("plan", help="plan pan shaking that slides an object along a command (ch. 3)")
    p.add_argument("--model", default="sliding", help="shipped model name or model/run directory")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--command", dest="command_file",  # not `command`: that is the subcommand's name
                     help=".npz (array 'states') or .csv: (K, 4) object x, y, vx, vy relative to the pan")
    src.add_argument("--circle", type=float, metavar="RADIUS", help="a circle of this radius [m] as the command")
    p.add_argument("--length", type=int, default=1200, help="K of the --circle command")
    p.add_argument("--mu", type=float, help="static friction of the 2-D physics (default: the model's)")
    p.add_argument("--mu-dyn", type=float, help="dynamic friction of the 2-D physics (default: the model's)")
    p.add_argument("--int8", action="store_true", help="int8 weights for the big layers (faster on CPU, wide models)")
    p.add_argument("--refine", action="store_true",
                   help="refine the plan's latent through the contact physics (sm.refine_plan: seconds, not ms) for "
                        "commands the planner alone does not follow, e.g. circles")
    p.add_argument("--tolerance", type=float, metavar="METRES",
                   help="warn when the object's RMS distance from the command exceeds this (default 0.005)")
    p.add_argument("--robot", metavar="NAME",
                   help="plan for this robot (see `seqmotion robots`): the plan's joint path by the simulator's IK is "
                        "held against its rated joint speeds, ranges, torque limits and rated accelerations, and the "
                        "plan is refined until it keeps them (seconds). Where one is broken after all, what was made "
                        "is still written (a .npz holds feasible False), one 'seqmotion plan: warning: not executable "
                        "on …' line names the binding limit (exit code 3)")
    p.add_argument("--robot-limits", metavar="KINDS",
                   help="with --robot: the limits the plan is refined to keep, comma-separated of speed, range, "
                        "torque, acceleration (default all; every one is judged either way)")
    p.add_argument("--output", required=True, help=OUTPUT_HELP)
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("calibrate-trust",
                       help="(re)write a model's trust.json: the training-input bounds behind out_of_distribution")
    p.add_argument("model", help="shipped model name or model directory")
    p.add_argument("--n", type=int, default=2048, help="fresh training inputs to draw")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_calibrate_trust)

    p = sub.add_parser("reproduce", help="reproduce a chapter's figures and tables")
    p.add_argument("chapter", choices=["ch2", "ch3", "ch4", "ch5"])
    p.add_argument("--out", help="output directory (default reproduce/<chapter>)")
    p.add_argument("--model", help="model/run directory to use instead of the shipped one")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quick", action="store_true",
                   help="fewer samples (a smoke test of the pipeline: its tables say so, the numbers mean nothing)")
    p.add_argument("--retrain", action="store_true",
                   help="ch5: train the policies that are not shipped (the estimated time is printed first: about "
                        "an hour for the 7 x 64 SeqAE on a 2-core CPU); without it, the shipped policy is evaluated "
                        "and the rest are marked not evaluated")
    p.set_defaults(func=cmd_reproduce)

    p = sub.add_parser("export", help="ship a finished run with its task's package, with a model card")
    p.add_argument("run", help="training run directory")
    p.add_argument("--name", required=True, help="pretrained name (sm.load_pretrained(NAME))")
    p.add_argument("--to", help="folder of pretrained models (default: pretrained/ of the package defining the task)")
    p.add_argument("--metrics", help="JSON file of measured metrics for the card")
    p.add_argument("--notes", help="free text for the card")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("demo", help="deform motions with the shipped model and show what it does")
    p.add_argument("--out", default="seqmotion-demo", help="where figures go")
    p.add_argument("--no-sim", action="store_true", help="skip the MuJoCo robot")
    p.set_defaults(func=cmd_demo)

    add_optimize_parser(sub)
    # Subcommands that live beside their subsystem (simulate, lfd, export-onnx, view, ...).
    for module_name in PLUGIN_COMMANDS:
        try:
            found = importlib.util.find_spec(module_name) is not None
        except ModuleNotFoundError:  # its package is not there either
            found = False
        if found:
            importlib.import_module(module_name).add_parser(sub)
    return parser


def check_writable_dir(path: Path, what: str) -> Path:
    """An output folder that can be created and written (checked before the work; nothing is created)."""
    from seqmotion.io import check_writable_dir as check

    return check(path, what)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def main(argv: list[str] | None = None) -> int:
    """Run a subcommand. Exit codes: 0 done; 2 bad input (a ``ValueError``/``CheckpointError``: one line
    ``seqmotion <command>: error: …`` on stderr, never a traceback); 1 the work failed (an ``OSError``
    such as a full disk, a diverged training, a ``MemoryError``: one line too); 3 made, but not what was asked
    (:data:`seqmotion.errors.EXIT_INEXACT`: ``deform --keep-end`` or ``optimize --exact`` could not make the exact
    motion, or ``deform --robot``'s or ``plan --robot``'s robot cannot execute it; what was made is written, marked,
    and one ``seqmotion <command>: warning: …`` line on stderr says why); 130 interrupted."""
    parser = build_parser()
    args = parser.parse_args(argv)
    name = getattr(args, "command", None) or "?"
    start = time.perf_counter()
    try:
        code = int(args.func(args) or 0)
    except ValueError as exc:  # bad input: a clear message, no traceback
        print(f"seqmotion {name}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except (OSError, FloatingPointError) as exc:  # the work failed: say so in one line
        print(f"seqmotion {name}: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    except MemoryError as exc:  # an allocation failed during the work (inputs declaring too much are refused as
        # ValueError before they are read); its frames are unwound by now, so printing needs little memory
        print(f"seqmotion {name}: error: out of memory: {_one_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"seqmotion {name}: interrupted", file=sys.stderr)
        return 130
    if name in TIMED_COMMANDS and os.environ.get("RANK", "0") == "0":  # torchrun: one line, from the first rank
        print(f"done in {elapsed(time.perf_counter() - start)}", flush=True)
    return code


def elapsed(seconds: float) -> str:
    """``12.3 s`` below a minute, ``3 min 19 s`` from there."""
    if seconds < 59.95:
        return f"{seconds:.1f} s"
    minutes, rest = divmod(round(seconds), 60)
    return f"{minutes} min {rest} s"


if __name__ == "__main__":
    sys.exit(main())
