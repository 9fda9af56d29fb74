"""``seqmotion lfd ...``: the chapter-5 pipeline from the command line.

``add_parser(subparsers)`` registers the ``lfd`` command on the main parser; its
subcommands are ``collect`` (record the datasets), ``info`` (summarise a file), ``train``
(SeqAE, CNNs and the end-to-end baseline), ``evaluate`` (closed-loop success rate),
``export`` (ship a policy with its model card) and ``export-lerobot`` / ``import-lerobot``
(LeRobot v3.0 datasets, :mod:`seqmotion.lfd.data.lerobot`, :mod:`seqmotion.lfd.data.lerobot_import`). Heavy
modules (MuJoCo, h5py, torch) are imported only when a subcommand runs.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

    from .policy.policy import PushingPolicy

_SET_NAMES = ("motions", "pairs_default", "pairs_position1", "pairs_position2", "hard", "hard_motions")


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``lfd`` (with ``collect`` and ``info``) to the main parser's subcommands."""
    parser = subparsers.add_parser("lfd", help="chapter 5: demonstrations of the pushing task")
    sub = parser.add_subparsers(dest="lfd_command", required=True)

    p = sub.add_parser("collect", help="record the datasets with the scripted operator (90 motions, 3 x 18 pairs)")
    p.add_argument("--out", required=True, help="output directory; one <set>.h5 per set")
    p.add_argument("--benchmark", choices=["chapter", "hard"], default="chapter",
                   help="chapter: the six block positions (the four sets of 5.3.3); hard: block anywhere in a wide "
                   "region, turned, box or cylinder, distractors, camera and lighting jitter (the 'hard' set)")
    p.add_argument("--sets", nargs="+", choices=_SET_NAMES, help="which sets (default: the benchmark's)")
    p.add_argument("--episodes", type=int, help="hard benchmark: episodes to record (default 140)")
    p.add_argument("--no-video", action="store_true",
                   help="hard benchmark: keep each episode's first image only, not its 50 fps film (what ACT needs); "
                   "about 10x faster to record (0.4 s against 4 s an episode), same episodes")
    p.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    p.add_argument("--duration", type=float,
                   help="seconds per demonstration (default: the benchmark's, 4 chapter, 6 hard)")
    p.add_argument("--per-position", type=int, default=None, help="episodes per block position for every set")
    p.add_argument("--overwrite", action="store_true", help="replace existing files")
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser("info", help="summarise a dataset file")
    p.add_argument("path", help="an .h5 file written by 'seqmotion lfd collect'")

    p = sub.add_parser("train", help="train the SeqAE + CNN policy (and/or the end-to-end baseline; or the SeqAE)")
    p.add_argument(
        "--data", required=True,
        help="dataset directory written by 'seqmotion lfd collect', LeRobot v3.0 dataset folders (<set>/, as "
        "'export-lerobot' writes them) or one LeRobot v3.0 dataset folder (any robot: the SeqAE takes its joint "
        "count)",
    )
    p.add_argument("--out", required=True, help="output directory; one <method>_<camera>/ model per policy")
    p.add_argument(
        "--preset",
        help="model size: original (7x64) | larger (10x128) | smaller (3x32) | "
        "wide64 (3x64, z in R^16) | tiny (1x16, for tests); default: seqmotion.lfd.train.DEFAULT_PRESET (smaller)",
    )
    p.add_argument(
        "--methods", nargs="+", default=["proposed"], choices=["proposed", "end_to_end", "seqae", "feedback"],
        help="proposed (SeqAE, then a CNN per camera; default), end_to_end (the baseline), seqae (the SeqAE alone, "
        "into OUT/seqae/: motions only, e.g. another robot's LeRobot dataset without 64x64 images or block "
        "positions), feedback (hard benchmark: a decoder that reads the object's pose, estimated from every webcam "
        "frame by a keypoint network, every 20 ms; into OUT/feedback_default/)",
    )
    p.add_argument(
        "--map", action="append", default=[], metavar="FIELD=KEY",
        help="LeRobot --data only: take FIELD from the dataset's feature KEY, as 'import-lerobot --map' does",
    )
    p.add_argument(
        "--cameras",
        nargs="+",
        default=["default"],
        choices=["default", "position1", "position2"],
        help="image-motion sets to train CNNs (or end-to-end models) on",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--benchmark", choices=["chapter", "hard"], default="chapter",
                   help="hard: train every method on the 'hard' set's demonstrations (collect --benchmark hard)")
    p.add_argument("--demos", type=int, help="hard benchmark: train on the first N successful demonstrations")
    p.add_argument("--extra-motions", action="store_true",
                   help="hard benchmark: the SeqAE also trains on the hard_motions set (motions without images)")
    p.add_argument(
        "--seqae-epochs", type=int,
        help="SeqAE (and feedback decoder) epochs (default 2000, as in the dissertation; tiny 200)"
    )
    p.add_argument("--e2e-epochs", type=int, help="end-to-end epochs (default 2000, as in the dissertation)")
    p.add_argument("--cnn-epochs", type=int, help="CNN epochs (default 100, as in the dissertation)")
    p.add_argument(
        "--cnn-targets",
        choices=["position_medoid", "position_mean", "pair"],
        help="what the CNN regresses per image: the z of the most typical motion at its block position (the one "
        "nearest their mean; default), their mean z, or its own demonstration's z (pair: the dissertation's eq. 5.2)",
    )
    p.add_argument("--pose-frames", type=int, default=60000,
                   help="feedback: frames rendered to train its pose network (default 60000)")
    p.add_argument("--pose-epochs", type=int, help="feedback: the pose network's epochs (default 12)")
    p.add_argument("--workers", type=int, default=2, help="feedback: processes rendering the frames (default 2)")
    p.add_argument("--state-noise", type=float, help="decoder input noise [normalised units] (default 0.3)")
    p.add_argument("--latent-noise", type=float, help="noise added to z in training (default 0.1)")
    p.add_argument("--latent-penalty", type=float, help="weight of the 1/2 |z|^2 bottleneck term (default 0)")
    p.add_argument("--seqae-from", help="reuse the SeqAE of this proposed-policy directory (retrain the CNN only)")
    p.add_argument("--keep-failed", action="store_true", help="train on failed demonstrations too")
    p.add_argument(
        "--no-resume", action="store_true", help="start over instead of continuing from OUT/checkpoints/"
    )
    p.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch threads (default 1: small LSTMs run fastest "
        "on one core, and results are reproducible per thread count)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")

    p = sub.add_parser("evaluate", help="closed-loop success rate: trials at each block position")
    p.add_argument(
        "model", nargs="?", default="pushing", help="a policy directory, or 'pushing' for the shipped one (default)"
    )
    p.add_argument("--camera", help="webcam pose (default: the one the policy was trained on)")
    p.add_argument("--positions", nargs="+", type=int, help="block position indices 0..5 (default all)")
    p.add_argument("--benchmark", choices=["chapter", "hard"], default="chapter",
                   help="chapter: trials at each of the six block positions; hard: every trial a fresh draw of the "
                   "hard benchmark (object anywhere, turned, box or cylinder, distractors, camera and light jitter)")
    p.add_argument("--trials", type=int,
                   help="chapter: trials per position (default 5: 30 in all); hard: trials in all (default 30)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", help="write the full result (every trial, success_rate, its 95%% Wilson interval) "
                   "to this JSON file")
    p.add_argument(
        "--oracle-latents",
        metavar="DATASET",
        help="diagnostic: decode, at each position, the z the CNN was trained to output (the medoid or mean z of "
        "this dataset's demonstrations there) instead of the CNN's (scores the decoder alone; proposed-method "
        "policies only)",
    )
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser(
        "export", help="ship a trained policy inside the package (seqmotion/pretrained/NAME) with a model card"
    )
    p.add_argument("policy", help="a <method>_<camera>/ directory written by 'seqmotion lfd train'")
    p.add_argument("--name", default="pushing", help="pretrained name (default pushing)")
    p.add_argument(
        "--evaluations",
        nargs="*",
        default=[],
        help="JSON files of 'seqmotion lfd evaluate --json' to quote on the card",
    )
    p.add_argument("--notes", default="", help="free text for the card")

    p = sub.add_parser(
        "export-lerobot", help="write every set of a collected dataset as a LeRobot v3.0 dataset (OUT/<set>/)"
    )
    p.add_argument("data_dir", help="dataset directory written by 'seqmotion lfd collect' (or one .h5 file)")
    p.add_argument("out", help="output directory; one LeRobot dataset folder per set")
    p.add_argument("--repo-id", default="seqmotion/pushing", help="Hub name for the dataset cards (<NAME>_<set>)")
    p.add_argument("--videos", action="store_true", help="the webcam as mp4 video instead of PNG images")
    p.add_argument("--codec", choices=["av1", "h264"], default="av1", help="video codec with --videos (default av1)")
    p.add_argument("--fps", type=int, default=50, help="frame rate; divides the 1 kHz recording (default 50: the "
                   "decoder's 20 ms period)")

    p = sub.add_parser("import-lerobot", help="read a LeRobot v3.0 dataset folder into OUT_DIR/<set>.h5")
    p.add_argument("lerobot_dir", help="a LeRobot v3.0 dataset folder (meta/info.json inside)")
    p.add_argument("out_dir", help="output directory for the .h5 file")
    p.add_argument(
        "--map", action="append", default=[], metavar="FIELD=KEY",
        help="take FIELD (master_theta, master_dtheta, master_tau, slave_theta, slave_dtheta, slave_tau, block_pose, "
        "image) from the dataset's feature KEY (default: action, observation.state, observation.effort, "
        "observation.environment_state, observation.images.webcam); 'image=' imports no camera",
    )
    p.add_argument("--set", dest="set_name", help="set name, i.e. the file name: letters, digits, '_', '.', '-' "
                   "(default: the folder's name if it is a seqmotion set, else pairs_default with a camera, motions "
                   "without)")
    p.add_argument("--trim", action="store_true", help="cut every episode to the shortest (else unequal lengths "
                   "are an error)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing file")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Execute the parsed ``lfd`` subcommand; bad arguments raise ``ValueError``."""
    from ..io import check_writable, check_writable_dir

    if args.lfd_command == "collect":
        from .data.dataset import collect

        check_writable_dir(args.out, "--out")

        from .data.dataset import CHAPTER_SETS

        sets = args.sets or (list(CHAPTER_SETS) if args.benchmark == "chapter" else ["hard"])  # hard_motions: by name
        per_position = {name: args.per_position for name in sets} if args.per_position is not None else None
        reports = collect(
            args.out,
            sets,
            seed=args.seed,
            duration=args.duration,
            per_position=per_position,
            progress=not args.quiet,
            overwrite=args.overwrite,
            episodes=args.episodes,
            video=not args.no_video,
        )
        for r in reports.values():
            per_pos = " ".join(f"{s}/{a}" for s, a in zip(r.successes, r.attempts, strict=True))
            print(
                f"{r.name}: {r.episodes} episodes -> {r.path}  success {r.success_rate:.0%} ({per_pos})  "
                f"{r.seconds:.0f} s"
            )
        return 0
    if args.lfd_command == "info":
        from .data.dataset import load_dataset
        from .env.pushing import POSITIONS

        data = load_dataset(args.path)
        a = data.attrs
        print(
            f"{data.path}: set {a['set_name']!r}, {len(data)} episodes of {a['samples']} samples "
            f"(dt {a['dt']} s), camera {a['camera'] or 'none'}, seed {a['seed']}"
        )
        if a.get("benchmark") == "hard":  # placements drawn from a region: summarise by object
            groups = {shape: data.episodes["shape"] == shape for shape in sorted(set(data.episodes["shape"]))}
            print(f"  hard benchmark{', filmed at 50 fps' if data.video is not None else ''}")
        else:
            groups = {pos.name: data.episodes["position_index"] == pos.index for pos in POSITIONS}
        for name, mask in groups.items():
            ok = int(data.episodes["success"][mask].sum())
            print(f"  {name:13s} {ok}/{int(mask.sum())} successful")
        return 0
    if args.lfd_command == "train":
        check_writable_dir(args.out, "--out")
        return _train(args)
    if args.lfd_command == "evaluate":
        if args.json is not None:
            from ..io import check_not_an_input

            check_writable(args.json, None, "--json")
            check_not_an_input(args.json, "--json", {"--oracle-latents": args.oracle_latents})
        return _evaluate(args)
    if args.lfd_command == "export":
        from .export import export_policy

        target = export_policy(args.policy, args.name, args.evaluations, args.notes)
        print(f"shipped {args.policy} as {args.name!r} in {target} (with MODEL_CARD.md)")
        return 0
    if args.lfd_command == "export-lerobot":
        from .data.lerobot import to_lerobot

        written = to_lerobot(args.data_dir, args.out, args.repo_id, args.videos, args.fps, args.codec)
        for name, path in written.items():
            print(f"{name}: LeRobot v3.0 dataset -> {path}")
        return 0
    if args.lfd_command == "import-lerobot":
        from .data.lerobot_import import check_set_name, import_lerobot, parse_map

        if args.set_name is not None:  # before the folder is made: a path here would write elsewhere
            check_set_name(args.set_name, "--set")
        check_writable_dir(args.out_dir, "OUT_DIR")
        path = import_lerobot(args.lerobot_dir, args.out_dir, parse_map(args.map), args.set_name, args.trim,
                              args.overwrite)
        print(f"{args.lerobot_dir} -> {path}")
        return 0
    raise ValueError(f"unknown lfd subcommand {args.lfd_command!r}")  # argparse prevents this


def _set_threads(threads: int) -> None:
    import torch

    from ..errors import check_number

    check_number("--threads", threads, minimum=1, integer=True)
    torch.set_num_threads(threads)


def _train(args: argparse.Namespace) -> int:
    from . import train as training
    from .data.lerobot_import import parse_map

    _set_threads(args.threads)
    preset_name = args.preset
    if preset_name is None and args.seqae_from is not None:  # the reused SeqAE fixes the size
        from .policy.policy import PushingPolicy

        preset_name = PushingPolicy.from_pretrained(args.seqae_from).config.preset
    preset_name = preset_name or training.DEFAULT_PRESET
    seqae, e2e, cnn = training.default_settings(preset_name, args.benchmark)
    pose = training.pose_training()
    noise = {"state_noise": args.state_noise, "latent_noise": args.latent_noise, "latent_penalty": args.latent_penalty}
    given = ((seqae, {**noise, "epochs": args.seqae_epochs}), (e2e, {**noise, "epochs": args.e2e_epochs}),
             (cnn, {"epochs": args.cnn_epochs, "targets": args.cnn_targets}), (pose, {"epochs": args.pose_epochs}))
    for settings, values in given:
        for name, value in values.items():  # what the command line gives replaces the preset's
            if value is not None:
                setattr(settings, name, value)
        settings.__post_init__()  # re-validate the overridden values
    from ..training.provenance import command_line

    command = command_line() if sys.argv[1:2] == ["lfd"] else None
    report = training.train(
        args.data,
        args.out,
        preset_name,
        tuple(args.methods),
        tuple(args.cameras),
        args.seed,
        seqae,
        e2e,
        cnn,
        args.seqae_from,
        progress=not args.quiet,
        command=command,
        successful_only=not args.keep_failed,
        resume=not args.no_resume,
        mapping=parse_map(args.map),
        benchmark=args.benchmark,
        demos=args.demos,
        extra_motions=args.extra_motions,
        pose_settings=pose,
        pose_frames=args.pose_frames,
        workers=args.workers,
    )
    for name, path in report.policies.items():
        print(f"{name}: {path}")
    print("wall time: " + ", ".join(f"{k} {v:.0f} s" for k, v in report.seconds.items()))
    return 0


def _oracle_latents(policy: PushingPolicy, dataset: str) -> np.ndarray:
    """``(6, latent)``: the targets the policy's CNN was trained on, per position (pair-trained CNNs: the mean)."""
    from .evaluation import position_latents

    targets = policy.config.training.get("cnn", {}).get("settings", {}).get("targets", "pair")
    return position_latents(policy, dataset, medoid=targets == "position_medoid")


def _evaluate(args: argparse.Namespace) -> int:
    from ..api import resolve_model
    from .evaluation import evaluate

    _set_threads(args.threads)
    policy = resolve_model(args.model, "pushing")
    result = evaluate(
        policy,
        camera=args.camera,
        positions=args.positions,
        trials=args.trials if args.trials is not None else (30 if args.benchmark == "hard" else 5),
        seed=args.seed,
        progress=not args.quiet,
        latents=None if args.oracle_latents is None else _oracle_latents(policy, args.oracle_latents),
        benchmark=args.benchmark,
    )
    if args.json:  # before printing: a closed stdout (e.g. piped into head) must not lose the result
        from ..io import atomic_write_bytes

        # keys in position order, not sorted
        atomic_write_bytes(Path(args.json), (json.dumps(result.as_dict(), indent=1) + "\n").encode())
    cells = "  ".join(f"{name} {ok}/{n}" for name, (ok, n) in result.per_position.items())
    low, high = result.wilson_interval
    print(
        f"success {result.successes}/{result.n_trials} = {result.success_rate:.1%} (95% {low:.0%}-{high:.0%}; "
        f"{result.benchmark} benchmark, camera {result.camera}, seed {result.seed}, {result.seconds:.0f} s)\n  {cells}"
    )
    return 0
