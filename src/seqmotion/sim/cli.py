"""``seqmotion simulate pancake|sliding --trajectory FILE [--video out.mp4]``.

``add_parser(subparsers)`` registers the ``simulate`` command on the main parser and
``run(args)`` executes it (``seqmotion robots`` lists the arms ``--robot`` takes: standard arm models,
:mod:`seqmotion.sim.robot_models`). ``--video``, ``--snapshots`` and ``--json`` are checked before the
simulation starts and written atomically. MuJoCo is imported only when a simulation runs. ``--mu`` sets the
friction coefficient a pancake run's executed friction cone is judged with
(:func:`~seqmotion.sim.pancake.run_pancake`'s ``mu``).

Trajectory files:

* pancake — ``.npz`` with an array ``states`` ``(K, 6)``, or ``.csv`` with one sample per row
  ``y, z, θ, v_y, v_z, v_θ`` (a first row of names only is a header; text anywhere else is an
  error naming its line); 1 ms per sample.
* sliding — ``.npz`` with ``pan_states`` ``(K, 4)`` and optionally ``rel_states`` (the plan's
  predicted object path), ``command`` (the object path asked for) and ``friction`` ``(μ, μ')``
  (what ``seqmotion plan`` planned at: a warning names a friction other than the arm's), or
  ``.csv`` with rows ``x_p, y_p, vx_p, vy_p``.

With ``--robot NAME`` every kind of joint limit the run broke (rated speed, torque, range, reach) is one line
``seqmotion simulate: warning: …`` on stderr naming its worst joint, peak, limit, share and time, and every limit
that is unknown for that robot one line ``seqmotion simulate: note: … unknown … (not checked)``.

Exit codes (:func:`seqmotion.cli.main`'s contract): 0 when the simulation ran, whatever it found (a pancake lost, a
run cut short, a limit broken: results, said on stdout, in ``--json`` and in the warnings); 2 bad input (one line
``seqmotion simulate: error: …``); 1 the work failed (e.g. an output that cannot be written).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

SCENES = ("pancake", "sliding")
"""The simulated scenes, named after the task whose motions they execute."""


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``simulate`` (with ``pancake`` and ``sliding``) to the main parser's subcommands."""
    parser = subparsers.add_parser("simulate", help="execute a motion on the simulated MuJoCo arm")
    parser.add_argument("scene", nargs="?", choices=SCENES,
                        help="spatula + pancake, or frying pan + object (default: the scene of --model's task)")
    parser.add_argument("--trajectory", required=True, help=".npz or .csv at 1 ms (see `seqmotion.sim.cli`)")
    parser.add_argument("--video", help="write an MP4 here")
    parser.add_argument("--snapshots", help="write a PNG strip of snapshots here")
    parser.add_argument("--gains", choices=["ch2", "ch3", "ch4"],
                        help="controller preset (default: ch2 for pancake, ch3 for sliding)")
    parser.add_argument("--camera", help="scene camera (pancake: oblique | front; sliding: front | top)")
    parser.add_argument("--mu", type=float, default=None,
                        help="pancake: friction coefficient the executed motion's friction cone is judged with "
                             "(default: --model's μ, else 1; the simulated contact keeps μ = 1)")
    parser.add_argument("--model", help="the model (shipped name or directory) that generated the motion: its "
                                        "options (μ) judge the execution")
    parser.add_argument("--robot", help="run on a standard arm model (panda, ur5e, robosuite:<name>, menagerie:<name>; "
                                        "list: seqmotion robots) instead of the built-in MH3F-like arm")
    parser.add_argument("--json", help="also write the metrics (and the logged paths) here as JSON")
    parser.set_defaults(func=run)
    listing = subparsers.add_parser("robots", help="list the robot arms available here (for simulate --robot NAME)")
    listing.add_argument("--json", action="store_true", help="print the list as JSON")
    listing.set_defaults(func=list_robots)
    return parser


def list_robots(args: argparse.Namespace) -> int:
    """Print the robots :func:`seqmotion.sim.robots` finds here (no download)."""
    from .robot_models import robots

    found = robots()
    if args.json:
        print(json.dumps([{"name": r.name, "source": r.source, "dof": r.dof,
                           "path": None if r.path is None else str(r.path)} for r in found]))
        return 0
    width = max(len(r.name) for r in found)
    for r in found:
        dof = "?" if r.dof is None else r.dof  # not known without reading the file, which the listing never does
        print(f"{r.name:<{width}}  {r.source:<9}  {dof} joints  {r.path or 'built in (the default arm)'}")
    if any(r.dof is None for r in found):
        print("? joints: read (and checked) when the robot is used, e.g. seqmotion simulate --robot NAME")
    if not any(r.source != "seqmotion" for r in found):
        print("no standard arms here: pip install 'seqmotion[robots]' && pip install --no-deps 'robosuite>=1.5,<1.6'")
    return 0


def _read(path: Path, keys: tuple[str, ...], dim: int) -> dict[str, np.ndarray]:
    """Arrays from an ``.npz`` (the first key required, the rest optional) or a ``.csv`` (first key; a first
    row of names only is a header, any other text is an error naming its line)."""
    from ..io import read_arrays

    return read_arrays(path, keys)


def _check_outputs(args: argparse.Namespace) -> None:
    """Refuse unwritable outputs, and outputs that are the trajectory file itself, before the simulation runs
    (``ValueError`` naming the option)."""
    from ..io import check_not_an_input, check_writable

    for option, suffixes in (("video", (".mp4",)), ("snapshots", (".png",)), ("json", None)):
        value = getattr(args, option)
        if value is not None:
            check_writable(value, suffixes, f"--{option}")
            check_not_an_input(value, f"--{option}", {"--trajectory": args.trajectory})


def _warn_limits(joints: object) -> None:
    """On stderr: ``seqmotion simulate: warning: …`` for each kind of limit the run broke (its worst joint: peak,
    limit, share, time), and ``seqmotion simulate: note: …`` for each limit that is unknown (not checked)."""
    import sys

    if joints is None:
        return
    for crossing in joints.crossings:
        print(f"seqmotion simulate: warning: {crossing.kind} limit broken on {joints.robot}: {crossing.describe()}",
              file=sys.stderr)
    for why in joints.unknown.values():
        print(f"seqmotion simulate: note: {why} (not checked)", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    """Run the simulation named by the parsed arguments; print and optionally save the metrics.

    Returns 0 whenever the simulation ran, whatever it found: a pancake lost, a run cut short or a robot's limit
    broken is a result, said in the printed line, in ``--json`` and (limits, with ``--robot``) in warnings on stderr.
    Bad input raises ``ValueError`` (exit code 2 through :func:`seqmotion.cli.main`)."""
    from ..io import atomic_write_bytes
    from .pancake import run_pancake
    from .sliding import run_sliding

    _check_outputs(args)
    model = None
    if args.model:
        from ..api import resolve_model

        model = resolve_model(args.model)
        task = model.config_json().get("task")
        if args.scene is None and task not in SCENES:
            raise ValueError(f"the {task!r} model's task has no simulated scene (scenes: {', '.join(SCENES)})")
        if args.scene is not None and args.scene != task:
            raise ValueError(f"--model is a {task!r} model, but the scene is {args.scene!r}")
        args.scene = args.scene or task
    if args.scene is None:
        raise ValueError(f"name the scene ({' | '.join(SCENES)}) or give --model")
    path = Path(args.trajectory)
    common = {"video": args.video, "snapshots": args.snapshots, "robot": args.robot}
    if args.camera:
        common["camera"] = args.camera
    if args.scene == "pancake":
        arrays = _read(path, ("states",), 6)
        if args.mu is not None:
            common["mu"] = args.mu
        elif model is not None:  # the μ the model was trained and is judged at
            common["mu"] = model.options.mu
        result = run_pancake(arrays["states"], gains=args.gains or "ch2", **common)
        logged = {"time": result.time, "command": result.command, "response": result.response,
                  "slip": result.slip, "gap": result.gap}
    else:
        if args.mu is not None:
            raise ValueError("--mu applies to the pancake scene only (the sliding measurements use no friction cone)")
        from .sliding import ARM_PHYSICS

        arrays = _read(path, ("pan_states", "rel_states", "command", "friction"), 4)
        pan = arrays["pan_states"]
        planned = np.asarray(arrays.get("friction", []), dtype=np.float64).ravel()
        arm = ARM_PHYSICS.vector()  # (mu, mu_dyn)
        if planned.shape == (2,) and not np.allclose(planned, arm):
            print(f"warning: {path} was planned at μ = {planned[0]:g}, μ' = {planned[1]:g}, the arm's object has "
                  f"μ = {arm[0]:g}, μ' = {arm[1]:g}: plan at the arm's friction (seqmotion plan --mu {arm[0]:g} "
                  f"--mu-dyn {arm[1]:g}) for a plan that holds here")
        if "rel_states" in arrays:
            plan = argparse.Namespace(pan_states=pan, rel_states=arrays["rel_states"])
            result = run_sliding(plan, arrays.get("command"), gains=args.gains or "ch3", **common)
        else:
            result = run_sliding(pan, arrays.get("command"), gains=args.gains or "ch3", **common)
        logged = {"time": result.time, "pan_command": result.pan_command, "pan_response": result.pan_response,
                  "object_path": result.object_path}
    print(f"{args.scene} on {result.robot}: {result.describe()}")
    if args.robot is not None:
        _warn_limits(result.joints)
    print(f"simulated {result.time[-1] if len(result.time) else 0:.3f} s at {result.realtime_factor:.1f}x real time")
    for name in ("video", "snapshots"):
        if getattr(args, name):
            print(f"{name}: {getattr(args, name)}")
    if args.json:
        out = Path(args.json)
        payload = {"metrics": result.summary(), **{k: np.asarray(v).tolist() for k, v in logged.items()}}
        atomic_write_bytes(out, json.dumps(payload).encode())  # never a half-written file at out
        print(f"metrics: {out}")
    return 0
