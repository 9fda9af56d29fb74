"""``seqmotion lfd ...``: collect and inspect the chapter-5 demonstration datasets.

``add_parser(subparsers)`` registers the ``lfd`` command on the main parser; its
subcommands are ``collect`` (record the datasets) and ``info`` (summarise a file). Heavy
modules (MuJoCo, h5py) are imported only when a subcommand runs.
"""

from __future__ import annotations

import argparse

_SET_NAMES = ("motions", "pairs_default", "pairs_position1", "pairs_position2")


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``lfd`` (with ``collect`` and ``info``) to the main parser's subcommands."""
    parser = subparsers.add_parser("lfd", help="chapter 5: demonstrations of the pushing task")
    sub = parser.add_subparsers(dest="lfd_command", required=True)

    p = sub.add_parser("collect", help="record the datasets with the scripted operator (90 motions, 3 x 18 pairs)")
    p.add_argument("--out", required=True, help="output directory; one <set>.h5 per set")
    p.add_argument("--sets", nargs="+", choices=_SET_NAMES, default=list(_SET_NAMES), help="which sets (default all)")
    p.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    p.add_argument("--duration", type=float, default=4.0, help="seconds per demonstration (default 4)")
    p.add_argument("--per-position", type=int, default=None, help="episodes per block position for every set")
    p.add_argument("--overwrite", action="store_true", help="replace existing files")
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser("info", help="summarise a dataset file")
    p.add_argument("path", help="an .h5 file written by 'seqmotion lfd collect'")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Execute the parsed ``lfd`` subcommand; bad arguments raise ``ValueError``."""
    if args.lfd_command == "collect":
        from .dataset import collect

        per_position = {name: args.per_position for name in args.sets} if args.per_position is not None else None
        reports = collect(
            args.out, args.sets, seed=args.seed, duration=args.duration, per_position=per_position,
            progress=not args.quiet, overwrite=args.overwrite,
        )
        for r in reports.values():
            per_pos = " ".join(f"{s}/{a}" for s, a in zip(r.successes, r.attempts, strict=True))
            print(f"{r.name}: {r.episodes} episodes -> {r.path}  success {r.success_rate:.0%} ({per_pos})  "
                  f"{r.seconds:.0f} s")
        return 0
    if args.lfd_command == "info":
        from ..sim.pushing import POSITIONS
        from .dataset import load_dataset

        data = load_dataset(args.path)
        a = data.attrs
        print(f"{data.path}: set {a['set_name']!r}, {len(data)} episodes of {a['samples']} samples "
              f"(dt {a['dt']} s), camera {a['camera'] or 'none'}, seed {a['seed']}")
        for pos in POSITIONS:
            mask = data.episodes["position_index"] == pos.index
            ok = int(data.episodes["success"][mask].sum())
            print(f"  {pos.name:13s} {ok}/{int(mask.sum())} successful")
        return 0
    raise ValueError(f"unknown lfd subcommand {args.lfd_command!r}")  # argparse prevents this
