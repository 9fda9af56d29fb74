"""``seqmotion view [MODEL]``: the interactive viewer in the browser (:mod:`seqmotion.view`)."""

from __future__ import annotations

import argparse
import sys
import time


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``view`` to the main parser's subcommands."""
    p = subparsers.add_parser("view", help="interactive viewer in the browser: deform, plan, adjust, replay (viser)",
                              description="Start a local web app (viser) and print its address: the pancake "
                                          "deformer, the sliding planner and the latent space, live, with the "
                                          "MuJoCo arm in 3-D. Any other task's model gets a panel built from its "
                                          "state layout.")
    p.add_argument("model", nargs="?", default="pancake",
                   help="shipped model name or model/run directory, of any task (default: pancake)")
    p.add_argument("--sliding-model", default="sliding",
                   help="with the pancake model: the planner of the Sliding panel ('none': no Sliding panel)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1: this machine only; 0.0.0.0: reachable from "
                        "elsewhere, with no authentication). A WebSocket from a page of any other origin than the "
                        "served host is refused either way")
    p.add_argument("--port", type=int, default=8080, help="port (0: any free one)")
    p.add_argument("--out", default="seqmotion-view", help="folder for exported motions and videos")
    p.add_argument("--no-sim", action="store_true", help="no MuJoCo arm in the 3-D scene (and no replay/video)")
    p.add_argument("--robot", default=None,
                   help="the arm of the 3-D scene, its replays and videos: a standard arm ('panda', 'ur5e', "
                        "'robosuite:<name>', 'menagerie:<name>'; seqmotion.sim.robots() lists those here) "
                        "(default: the built-in arm, 'mh3f')")
    p.add_argument("--threads", type=int, default=1,
                   help="torch CPU threads (default 1: on a small machine the server's own threads need the rest)")
    p.add_argument("--seconds", type=float, help="stop after this many seconds (default: until Ctrl-C)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    try:
        import viser  # noqa: F401
    except ImportError:
        raise ValueError("the viewer needs viser: pip install 'seqmotion[view]'") from None
    import torch

    from ..errors import check_number

    check_number("--threads", args.threads, minimum=1, integer=True)
    check_number("--port", args.port, minimum=0, maximum=65535, integer=True)
    from .app import ViewerApp, check_robot

    robot = check_robot(args.robot, not args.no_sim)  # an unknown robot: refused before anything starts
    torch.set_num_threads(args.threads)

    sliding = None if args.sliding_model.lower() == "none" else args.sliding_model
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"seqmotion view: warning: --host {args.host} makes the viewer reachable from other machines, and "
              "the page has no authentication: anyone who can reach the port can use every control and write "
              f"exports into {args.out}", file=sys.stderr, flush=True)
    app = ViewerApp(args.model, sliding_model=sliding, host=args.host, port=args.port, out=args.out,
                    simulate=not args.no_sim, robot=robot)
    print(f"seqmotion view: open {app.url} in a browser (Ctrl-C stops)", flush=True)
    try:
        end = None if args.seconds is None else time.monotonic() + args.seconds
        while end is None or time.monotonic() < end:
            time.sleep(0.2)
    finally:
        app.stop()
    return 0
