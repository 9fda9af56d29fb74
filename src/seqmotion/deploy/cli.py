"""``seqmotion export-onnx MODEL OUT/``: the encoder, decoder step and contract for deployment; ``seqmotion export-c
MODEL OUT/``: the decoder step, dynamics and online generator as C99; ``seqmotion bench-step MODEL``: the ONNX
stepper in a paced 1 kHz loop, measured.

    seqmotion export-onnx pancake pancake-onnx/            # a shipped model by name
    seqmotion export-onnx runs/tray-tiny tray-onnx/ --int8  # a run folder, plus an int8 decoder step
    seqmotion export-c pancake pancake-c/                  # C99: seqmotion_model.{h,c}, seqmotion_generator.{h,c}
    seqmotion bench-step pancake --calls 10000 --rt --json out.json

The parity check (``--no-check`` skips it) runs on the new bundle, written beside OUT, before it
replaces OUT: a bundle that fails it, or a task whose example inputs cannot be checked (NaN, another
width), leaves the previous bundle byte for byte.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("export-onnx", help="export a model's encoder and decoder step as ONNX with a JSON "
                                                  "contract and a NumPy + onnxruntime runner")
    p.add_argument("model", help="shipped model name or model/run directory")
    p.add_argument("out", help="output folder: new, empty, or a previous export (replaced whole; a folder holding "
                               "anything else is refused)")
    p.add_argument("--int8", action="store_true",
                   help="also write an int8 decoder step (layers >= 256 wide, like TrainedModel.quantized)")
    p.add_argument("--no-check", action="store_true", help="skip the parity check against PyTorch")
    p.set_defaults(func=run)

    p = subparsers.add_parser("export-c", help="write a model's decoder step, dynamics and online generator as "
                                               "dependency-free C99 (no heap; the contract's constants baked in)")
    p.add_argument("model", help="shipped model name or model/run directory")
    p.add_argument("out", help="output folder (created; the four files PREFIX_model.{h,c}, PREFIX_generator.{h,c} "
                               "in it are replaced)")
    p.add_argument("--prefix", default="seqmotion", help="the prefix of every C name (default seqmotion)")
    p.add_argument("--no-check", action="store_true",
                   help="skip the parity check (compiles the source with the system's C compiler and compares its "
                        "generate with PyTorch's on the task's example inputs)")
    p.set_defaults(func=run_export_c)

    p = subparsers.add_parser("bench-step", help="run the ONNX stepper in a paced 1 kHz loop and report late "
                                                 "wake-ups and call latencies (p50/p99/p99.9/max), normal and "
                                                 "real-time scheduling")
    p.add_argument("model", help="shipped model name, model/run directory, or a folder export-onnx wrote")
    p.add_argument("--calls", type=int, default=5000, help="timed calls per run (default 5000: 5 s at 1 kHz)")
    p.add_argument("--rt", action="store_true",
                   help="also run pinned to a core with SCHED_FIFO where permitted (says so when not)")
    p.add_argument("--cpu", type=int, default=-1, help="the core --rt pins to (default: the last one)")
    p.add_argument("--priority", type=int, default=80, help="SCHED_FIFO priority for --rt (1-99, default 80)")
    p.add_argument("--json", type=Path, help="also write the figures here")
    p.set_defaults(func=run_bench_step)


def run(args: argparse.Namespace) -> int:

    from ..api import resolve_model
    from . import export

    export.bundle_target(args.out)  # a folder that may not be replaced is refused before the model is loaded
    model = resolve_model(args.model)
    inputs = None if args.no_check else export.example_inputs(model)  # a plug-in's own code: checked before the work
    gap: dict[str, float] = {}

    def parity(folder: Path) -> None:
        # run on the new bundle beside OUT, before the swap: a refusal here leaves the old bundle as it was
        try:
            gap.update(export.check_parity(model, folder, inputs))
        except (RuntimeError, TypeError, IndexError, ArithmeticError) as exc:  # the task's own torch code failing
            raise ValueError(f"the parity check of the {model.task_def.name!r} model failed in PyTorch with "
                             f"{type(exc).__name__}: {exc}") from exc
        if not all(np.isfinite(v) for v in gap.values()):
            raise ValueError(f"the {model.task_def.name!r} model's exported bundle differs from PyTorch by {gap} on "
                             "its task's example inputs: not written")

    contract = export.export_onnx(model, args.out, int8=args.int8, source=args.model,
                                  check=None if inputs is None else parity)
    files = ", ".join(v for v in contract["files"].values() if v)
    print(f"wrote {args.out}: {files}, contract.json (sealed), onnx_stepper.py (+ hot_path.py, bundle.py, stepper.py, "
          "numpy_physics.py)")
    print(f"task {contract['task']}: C = {contract['chunk']}, state {', '.join(contract['state_layout']['names'])}; "
          f"outputs {', '.join(contract['accel_layout']['names'])}; dt = {contract['dt']} s")
    physics = contract["dynamics"]["physics"]
    values = ", ".join(f"{k} = {v:g}" for k, v in physics["values"].items()) or "none"
    reads = f"a runner may set {', '.join(physics['inputs'])}" if physics["inputs"] else "the graph reads none"
    print(f"dynamics {contract['dynamics']['graph']} at {values} ({reads})")
    if inputs is not None:
        print(f"parity with PyTorch on {len(inputs)} example inputs of K = {inputs.shape[1]}: max |difference| "
              f"{gap['accel']:.2e} in outputs, {gap['states']:.2e} in states")
    return 0


def run_export_c(args: argparse.Namespace) -> int:
    import shutil

    from ..api import resolve_model
    from . import c_export
    from . import export as onnx_export

    model = resolve_model(args.model)
    inputs = None if args.no_check else onnx_export.example_inputs(model)
    info = c_export.export_c(model, args.out, prefix=args.prefix, source=args.model)
    contract = info["contract"]
    print(f"wrote {args.out}: {', '.join(info['files'])}")
    print(f"task {contract['task']}: C = {contract['chunk']}, S = {len(contract['state_layout']['names'])}, "
          f"d = {len(contract['accel_layout']['names'])}, dt = {contract['dt']} s; functions "
          f"{', '.join(info['functions'])}")
    if inputs is None:
        return 0
    compiler = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if compiler is None:
        print("parity check skipped: no C compiler (cc, gcc or clang) on the PATH")
        return 0
    gap = c_export.check_parity(model, args.out, inputs, prefix=args.prefix, compiler=compiler)
    print(f"parity with PyTorch on {len(inputs)} example inputs of K = {inputs.shape[1]} ({Path(compiler).name} "
          f"-O2): states within {gap['states']:.2e} of their magnitude, outputs within {gap['accel']:.2e} of the "
          "output scale")
    return 0


def run_bench_step(args: argparse.Namespace) -> int:
    import json
    import tempfile

    from . import realtime
    from .onnx_stepper import OnnxModel

    if args.calls < 1:
        raise ValueError(f"--calls must be at least 1, got {args.calls}")
    with tempfile.TemporaryDirectory(prefix="seqmotion-bench-step-") as scratch:
        folder = Path(args.model)
        if not (folder / "contract.json").is_file():
            from ..api import resolve_model
            from .export import example_inputs, export_onnx

            model = resolve_model(args.model)
            motion = example_inputs(model, n=1)[0]
            folder = Path(scratch) / "bundle"
            export_onnx(model, folder, source=args.model)
        else:
            motion = None
        onnx = OnnxModel(folder)
        if motion is None:  # a bundle alone: a motion of the default length from its start state at rest
            k = int(onnx.contract["default_length"] or 4 * onnx.chunk)
            motion = np.zeros((k, onnx.input_dim))
        runs = {}
        trivial = realtime.trivial_call()
        for mode in ("normal", "realtime") if args.rt else ("normal",):
            rt = mode == "realtime"
            with realtime.realtime(cpu=args.cpu if rt else None, fifo=rt, priority=args.priority) as setup:
                floor = realtime.paced(lambda _: trivial(), min(args.calls, 2000))
                report = realtime.bench_stepper(onnx, motion, args.calls)
            stats = report.stats()
            stats["trivial_onnxruntime_call"] = floor.stats()["call"]
            runs[mode] = {"setup": setup.to_dict(), **stats}
            print(f"{mode}: {setup.describe()}")
            print("  trivial onnxruntime call: p50 {p50_us:.1f}  p99 {p99_us:.1f} µs".format(**floor.stats()["call"]))
            print("\n".join("  " + line for line in report.summary().splitlines()))
    if args.json is not None:
        args.json.write_text(json.dumps({"model": args.model, "task": onnx.contract["task"], "runs": runs},
                                        indent=1) + "\n")
    return 0
