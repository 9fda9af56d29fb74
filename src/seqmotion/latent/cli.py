"""``seqmotion optimize``: adjust a pancake motion through the latent space (ch. 4) from the shell.

    seqmotion optimize --target 0.1 0.0 3.14 --output adjusted.npz          # J1, case 1
    seqmotion optimize --preset j2 --output slow_turn.csv --plot slow_turn.png
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("optimize", help="adjust a motion by gradient descent on its latent (ch. 4)")
    p.add_argument("--model", default="pancake", help="shipped model name or model/run directory")
    goal = p.add_mutually_exclusive_group(required=True)
    goal.add_argument("--target", nargs=3, type=float, metavar=("Y", "Z", "THETA"), help="end pose for J1 [m, m, rad]")
    goal.add_argument("--preset", choices=["j2"], help="j2: the velocity-limited turn of §4.4.2 (eq. 4.10)")
    p.add_argument("--input", help="input motion (.npz 'states' or .csv, (K, 6)); default: S-curve to the target")
    p.add_argument("--length", type=int, default=500, help="K of the default input (samples at 1 ms)")
    p.add_argument("--case", type=int, choices=[1, 2, 3], default=1, help="1 encoder z, 2 random z, 3 accelerations")
    p.add_argument("--steps", type=int, help="updates (default 100 for J1, 20 for J2)")
    p.add_argument("--lr", type=float, help="fixed step size η (default: chosen by a line search at every update)")
    p.add_argument("--optimizer", choices=["sgd", "lm"],
                   help="sgd: plain gradient descent (eq. 4.2); lm: Levenberg–Marquardt with penalty continuation "
                        "(default for --target; J2 has no least-squares form, so sgd)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--output", required=True, help=".npz or .csv for the adjusted trajectory")
    p.add_argument("--plot", help="PNG with the trajectory, ψ and the objective's progress")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..cli import _model_arg, read_trajectory, write_arrays
    from ..data import pancake as inputs
    from ..physics import pancake as physics
    from . import optimize_latent, optimize_trajectory
    from .objectives import EndPose, Ranges

    model = _model_arg(args.model, "pancake")  # J1/J2 are pancake objectives
    if args.preset == "j2":
        objective = Ranges()
        default_input = inputs.straight((0.0, 0.0, -3 * math.pi / 4), args.length, timing="linear")
        steps, lr = args.steps or 20, args.lr or "auto"
    else:
        objective = EndPose(args.target)
        default_input = inputs.straight(args.target, args.length)
        steps, lr = args.steps or 100, args.lr or "auto"
    states = read_trajectory(args.input) if args.input else default_input
    optimizer = args.optimizer or ("sgd" if args.preset == "j2" or args.lr else "lm")
    method: dict = {"lr": lr} if optimizer == "sgd" else {"optimizer": "lm", "continuation": (1e-3, 4)}
    if args.case == 3:
        res = optimize_trajectory(model, states, objective, steps=steps, **method)
    else:
        res = optimize_latent(model, states, objective, steps=steps, init="encoder" if args.case == 1 else "random",
                              seed=args.seed, **method)
    fc = physics.violation(res.states[:-1], res.accel)
    columns = {"states": res.states, "accel": res.accel, "violation": fc, "history": res.history}
    if res.latent is not None:
        columns["latent"] = res.latent
    write_arrays(args.output, columns)
    print(f"{objective!r}: {res.history[0]:.3g} → {res.history[-1]:.3g} in {steps} updates "
          f"({1000 * res.seconds_per_update:.1f} ms each); end pose {np.round(res.states[-1, :3], 4).tolist()}, "
          f"max F_c {fc.max():.4f} rad → {args.output}")
    if args.plot:
        _plot(res, fc, Path(args.plot))
    return 0


def _plot(res, fc: np.ndarray, path: Path) -> None:  # noqa: ANN001
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..physics import pancake as physics

    fig, axes = plt.subplots(1, 3, figsize=(14, 3.6))
    t = np.arange(len(res.states))
    for j, name in enumerate(("y [m]", "z [m]", "θ [rad]")):
        axes[0].plot(t, res.states[:, j], label=name)
    axes[0].set(xlabel="time [ms]", title="adjusted motion")
    axes[0].legend(fontsize=8)
    axes[1].axhspan(-np.pi / 4, np.pi / 4, color="tab:blue", alpha=0.15)
    axes[1].plot(t[:-1], physics.psi(res.states[:-1], res.accel))
    axes[1].set(xlabel="time [ms]", ylabel="ψ [rad]", ylim=(-np.pi, np.pi), title=f"cone (max F_c {fc.max():.3f} rad)")
    axes[2].plot(res.history)
    axes[2].set(yscale="log", xlabel="update", ylabel="objective", title="progress")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
