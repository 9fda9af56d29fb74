"""Latency of the decoder as a real-time controller: PyTorch vs onnxruntime (issue 18).

    python benchmarks/bench_deploy.py [--steps 10000] [--quick]

For ``pancake``, ``sliding`` (shipped) and the paper-size sliding planner (2 × 1024 + 500, C = 100,
built untrained with seed 0: speed does not depend on the weights) in float32 and int8:

* one decoder step (batch 1: ``decode_step`` in PyTorch, ``decoder_step.onnx`` in onnxruntime),
  p50 / p99 / max over ``--steps`` calls after a warm-up;
* the stepper's own calls (``model.generator`` vs ``sm.deploy.OnnxStepper``) in a 1 kHz loop fed
  one measured state per call: at chunk boundaries (a decoder step, the plan's prediction) and
  between them (the replanning correction: two decoder runs);
* ``deform`` K = 500 end to end (encode + decode + physics + constraint) for the pancake.

Both runtimes use one thread (a control loop steps a batch of one). int8: ``TrainedModel.quantized()``
in PyTorch, ``onnxruntime.quantization.quantize_dynamic`` (per channel, layers ≥ 256 wide) for ONNX.
Prints JSON lines and a Markdown table, with the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

import seqmotion as sm
from seqmotion import tasks
from seqmotion.deploy import OnnxModel, OnnxStepper, export_onnx
from seqmotion.deploy.numpy_physics import NumpyDynamics
from seqmotion.models.seq2seq import ChunkedSeq2Seq
from seqmotion.tasks.sliding import SlidingOptions, model_config
from seqmotion.training.provenance import machine_description


def latencies(fn, steps: int, warmup: int = 200) -> dict[str, float]:  # noqa: ANN001
    """p50 / p99 / max of ``fn()`` in milliseconds over ``steps`` calls."""
    for _ in range(warmup):
        fn()
    times = np.empty(steps)
    clock = time.perf_counter_ns
    for i in range(steps):
        start = clock()
        fn()
        times[i] = clock() - start
    times /= 1e6
    return {"p50_ms": float(np.percentile(times, 50)), "p99_ms": float(np.percentile(times, 99)),
            "max_ms": float(times.max()), "calls": steps}


def paper_size_planner():  # noqa: ANN201
    torch.manual_seed(0)
    cfg = model_config(2, 1024, 500)
    config = {"task": "sliding", "model": cfg.to_dict(), "training": {"options": SlidingOptions().to_dict()}}
    return tasks.get("sliding").wrap(ChunkedSeq2Seq(cfg), config)


def motion_for(model, k: int) -> np.ndarray:  # noqa: ANN001
    if model.task_def.name == "pancake":
        return sm.data.pancake.straight((0.2, 0.0, 2.5), k)
    return sm.data.sliding.circle(0.05, k)


def bench_decoder_step(name: str, model, onnx_model: OnnxModel, steps: int) -> list[dict]:  # noqa: ANN001
    c, s = model.model.chunk, model.state_layout.dim
    rng = np.random.default_rng(0)
    window = (0.01 * rng.standard_normal((1, c, s))).astype(np.float32)
    z = (0.1 * rng.standard_normal((1, model.model.latent_dim))).astype(np.float32)
    state = model.model.initial_state(torch.from_numpy(z))
    inputs = torch.from_numpy(window)

    def torch_step() -> None:
        with torch.inference_mode():
            model.model.decode_step(state, inputs, need_cov=False)

    onnx_state = onnx_model.initial_state(z)
    feeds = {"h": onnx_state[0], "c": onnx_state[1], "window": window}
    session = onnx_model.decoder

    def ort_step() -> None:
        session.run(None, feeds)

    return [{"model": name, "what": "decoder step", "runtime": "pytorch", **latencies(torch_step, steps)},
            {"model": name, "what": "decoder step", "runtime": "onnxruntime", **latencies(ort_step, steps)}]


def bench_stepper(name: str, model, folder: Path, calls: int, boundary_calls: int,  # noqa: ANN001
                  int8: bool) -> list[dict]:
    """The stepper in a 1 kHz loop, one measured state per call, closed through the task's NumPy dynamics
    (outside the timing): boundary calls (a decoder step) and calls between boundaries (the replanning
    correction: two decoder runs) timed separately."""
    k = int(model.options.length[1])  # the longest motion the model trained on
    motion = motion_for(model, k)
    out = []
    for runtime, gen in (("pytorch", model.generator(motion)),
                         ("onnxruntime", OnnxStepper(folder, motion, int8=int8))):
        dynamics = NumpyDynamics(gen.contract()["dynamics"])
        times: dict[bool, list[float]] = {True: [], False: []}
        clock = time.perf_counter_ns
        while len(times[False]) < calls or len(times[True]) < boundary_calls:
            gen.reset()
            u, x = gen.step(), motion_start(model, motion)
            for _ in range(k - 1):
                measured = dynamics.predict(x[None], u[None, :1])[0]
                x = measured[-1]
                start = clock()
                u = gen.step(measured)
                times[gen.time % gen.chunk == 0].append((clock() - start) / 1e6)
        for boundary, label in ((True, "stepper call at a chunk boundary (decoder step)"),
                                (False, "stepper call between boundaries (replan: 2 decoder runs)")):
            t = np.asarray(times[boundary][100 if not boundary else 2:])
            out.append({"model": name, "what": label, "runtime": runtime, "p50_ms": float(np.percentile(t, 50)),
                        "p99_ms": float(np.percentile(t, 99)), "max_ms": float(t.max()), "calls": int(t.size)})
    return out


def motion_start(model, motion: np.ndarray) -> np.ndarray:  # noqa: ANN001
    return model.start_state(torch.from_numpy(motion[None])).double().numpy()[0]


def bench_end_to_end(name: str, model, onnx_model: OnnxModel, runs: int) -> list[dict]:  # noqa: ANN001
    sketch = motion_for(model, 500)
    verb = model.deform if model.task_def.name == "pancake" else model.generate
    return [{"model": name, "what": "deform K = 500 end to end", "runtime": "pytorch",
             **latencies(lambda: verb(sketch), runs, warmup=10)},
            {"model": name, "what": "deform K = 500 end to end", "runtime": "onnxruntime",
             **latencies(lambda: onnx_model.generate(sketch), runs, warmup=10)}]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=10_000, help="decoder steps timed per model and runtime")
    parser.add_argument("--quick", action="store_true", help="1,000 steps, no paper-size model (a smoke test)")
    args = parser.parse_args()
    steps = 1000 if args.quick else args.steps
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="bench-deploy-") as tmp:
        models = {"pancake": sm.load_pretrained("pancake"), "sliding": sm.load_pretrained("sliding")}
        if not args.quick:
            models["paper-size sliding (2x1024 + 500)"] = paper_size_planner()
        for name, model in models.items():
            folder = Path(tmp) / name.split()[0]
            export_onnx(model, folder, int8=name.startswith("paper"))
            variants = [(name, model, OnnxModel(folder), False)]
            if name.startswith("paper"):
                variants.append((f"{name}, int8", model.quantized(), OnnxModel(folder, int8=True), True))
            for label, torch_model, onnx_model, int8 in variants:
                new = bench_decoder_step(label, torch_model, onnx_model, steps)
                boundary_calls = 50 if name.startswith("paper") else max(steps // 20, 50)
                new += bench_stepper(label, torch_model, folder, max(steps // 10, 500), boundary_calls, int8)
                if torch_model.task_def.name == "pancake":
                    new += bench_end_to_end(label, torch_model, onnx_model, max(steps // 10, 100))
                for row in new:
                    print(json.dumps(row), flush=True)
                rows += new
    load_after = os.getloadavg()
    context = {"machine": machine_description(), "threads": 1, "load_average_before": load_before,
               "load_average_after": load_after, "torch": torch.__version__,
               "onnxruntime": __import__("onnxruntime").__version__}
    print(json.dumps(context))
    print("\n| model | what | runtime | p50 ms | p99 ms | max ms | calls |\n|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['model']} | {r['what']} | {r['runtime']} | {r['p50_ms']:.3f} | {r['p99_ms']:.3f} | "
              f"{r['max_ms']:.2f} | {r['calls']} |")
    print(f"\nload average (1, 5, 15 min) before {load_before}, after {load_after}; {context['machine']}")


if __name__ == "__main__":
    main()
