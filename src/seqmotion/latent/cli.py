"""``seqmotion optimize``: adjust a motion through the latent space (ch. 4) from the shell, for any task.

    seqmotion optimize --target 0.1 0.0 3.14 --output adjusted.npz          # J1 (pancake: y, z, θ), case 1
    seqmotion optimize --preset j2 --output slow_turn.csv --plot slow_turn.png
    seqmotion optimize --model runs/tray-tiny --target 0.1 0.05 --output tray.npz   # a plug-in task's end pose

The default input is the task's sketch, as long as the longest motion the model trained on (the
options' length range: pancake 500, tray-tiny 200), so it is not flagged out of distribution for
its length. The task's constraint is a term of every objective: printed, and warned about when missed.
"""

from __future__ import annotations

import argparse
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

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


def add_parser(subparsers: argparse._SubParsersAction) -> None:
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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..api import resolve_model
    from ..errors import MAX_LENGTH, check_number, report_made, said_by
    from ..io import check_not_an_input, check_output, check_writable, read_trajectory, write_arrays
    from ..tasks import TrainedModel
    from . import optimize_latent, optimize_trajectory
    from .objectives import EndPose, Ranges

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
        from ..sim.registration import check_robot_option

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
        _plot(model, res, columns.get("violation"), Path(args.plot))
    if res.robot_check is not None:
        print(f"  {res.robot_check.describe()}")
    return report_made("optimize", args.output,
                       ("--exact", "; ".join(polish_failures) or "the polish did not converge") if res.exact is False
                       else None, not_executable[0] if not_executable else None)



def _plot(model: Any, res: Any, violation: np.ndarray | None, path: Path) -> None:
    """``--plot``: the adjusted motion's position fields (by the task's layout), its constraint (the task's own
    panel where it has one, e.g. the pancake's ψ in the friction cone; else the violation with its limit) and the
    objective's progress, written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io import save_figure

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
    from ..physics import pancake as physics

    cone = model.physics.cone_half_angle
    t = np.arange(len(accel))
    ax.axhspan(-cone, cone, color="tab:blue", alpha=0.15, label=f"cone ±atan μ, μ = {model.physics.mu:g}")
    ax.plot(t, physics.psi(states[:-1], accel), label="ψ")
    ax.set(ylabel="ψ [rad]", ylim=(-np.pi, np.pi))
    ax.legend(fontsize=8)


CONSTRAINT_PANELS = {"pancake": _pancake_cone}
"""Task name → its own constraint panel for ``--plot`` (others get their violation against its limit)."""
