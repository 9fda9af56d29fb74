"""``seqmotion export-onnx MODEL OUT/``: the encoder, decoder step and contract for deployment.

    seqmotion export-onnx pancake pancake-onnx/            # a shipped model by name
    seqmotion export-onnx runs/tray-tiny tray-onnx/ --int8  # a run folder, plus an int8 decoder step

The parity check (``--no-check`` skips it) runs on the new bundle, written beside OUT, before it
replaces OUT: a bundle that fails it, or a task whose example inputs cannot be checked (NaN, another
width), leaves the previous bundle byte for byte.
"""

from __future__ import annotations

import argparse

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


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

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
    print(f"wrote {args.out}: {files}, contract.json (sealed), onnx_stepper.py (+ bundle.py, stepper.py, "
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
