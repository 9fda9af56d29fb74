"""Write a motion's latent, start state and length for ``loop.cpp`` (one line each, space separated).

    python examples/realtime/latent.py pancake build/latent.txt        # the task's first example input
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

import seqmotion as sm
from seqmotion.deploy.export import example_inputs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", help="shipped model name or model/run directory")
    parser.add_argument("out", type=Path, help="the file to write")
    args = parser.parse_args()
    model = sm.api.resolve_model(args.model)
    motion = example_inputs(model, n=1)
    with torch.inference_mode():
        x = torch.from_numpy(motion)
        z, x0 = model.encode_torch(x)[0].numpy(), model.start_state(x).double()[0].numpy()
    lines = [str(motion.shape[1]), " ".join(repr(float(v)) for v in x0),
             " ".join(repr(float(v)) for v in z.astype(np.float32))]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}: K = {motion.shape[1]}, x0 of {x0.size}, z of {z.size} ({model.task_def.name})")


if __name__ == "__main__":
    main()
