"""Latency of the decoder as a real-time controller: PyTorch vs onnxruntime.

    python benchmarks/bench_deploy.py [--steps 10000] [--quick] [--models pancake sliding] [--json OUT.json]

For ``pancake``, ``sliding`` (shipped) and the paper-size sliding planner (2 × 1024 + 500, C = 100,
built untrained with seed 0: speed does not depend on the weights) in float32 and int8:

* one decoder step (batch 1: ``decode_step`` in PyTorch, ``decoder_step.onnx`` in onnxruntime),
  p50 / p99 / max over ``--steps`` calls after a warm-up;
* one chunk of the task's dynamics (batch 1: ``ChunkDynamics.step`` in PyTorch, ``dynamics.onnx`` in
  onnxruntime, and the closed form the runner uses where the contract names one, in NumPy);
* the stepper's own calls (``model.generator`` vs ``sm.deploy.OnnxStepper``) in a 1 kHz loop fed
  one measured state per call, the robot being the model's PyTorch dynamics (outside the timing): at
  chunk boundaries (a decoder step and the plan's prediction through the dynamics) and between them
  (the replanning correction: two decoder runs); the calls in the chunk where the motion ends (which
  also plan the stop through the dynamics and the constraint) are also reported on their own;
* ``deform`` K = 500 end to end (encode + decode + physics + constraint) for the pancake.

Both runtimes use one thread (a control loop steps a batch of one). int8: ``TrainedModel.quantized()``
in PyTorch, ``onnxruntime.quantization.quantize_dynamic`` (per channel, layers ≥ 256 wide) for ONNX.
Every latency is wall-clock (``perf_counter``); the stepper's calls are also timed in the thread's CPU time
(``thread_time``: what the call itself computes, without the time other processes take the core away —
the fairer comparison on a loaded machine). Prints JSON lines and a Markdown table, with the load average
before and after; ``--json`` also writes them to a file. Only the public deploy API is used
(``export_onnx``, ``OnnxModel``, ``OnnxStepper``), so the same script times an earlier version of the
package too (``PYTHONPATH=old/src``).
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
from seqmotion.models.seq2seq import ChunkedSeq2Seq
from seqmotion.tasks.sliding import SlidingOptions, model_config
from seqmotion.training.provenance import machine_description


def summary(times_ns: np.ndarray) -> dict[str, float]:
    """p50 / p99 / max in milliseconds of call times in nanoseconds."""
    t = np.asarray(times_ns, dtype=np.float64) / 1e6
    return {"p50_ms": float(np.percentile(t, 50)), "p99_ms": float(np.percentile(t, 99)), "max_ms": float(t.max()),
            "calls": int(t.size)}


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
    return summary(times)


def paper_size_planner():  # noqa: ANN201
    torch.manual_seed(0)
    cfg = model_config(2, 1024, 500)
    config = {"task": "sliding", "model": cfg.to_dict(), "training": {"options": SlidingOptions().to_dict()}}
    return tasks.get("sliding").wrap(ChunkedSeq2Seq(cfg), config)


def motion_for(model, k: int) -> np.ndarray:  # noqa: ANN001
    if model.task_def.name == "pancake":
        return sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), k)
    return sm.tasks.sliding.data.circle(0.05, k)


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


def bench_dynamics(name: str, model, onnx_model: OnnxModel, steps: int) -> list[dict]:  # noqa: ANN001
    """One chunk of the task's dynamics, batch 1, at the model's physics: PyTorch, the bundle's graph, and (where the
    contract names a closed form) what the runner predicts with, in NumPy. Only where the bundle has the graph."""
    if not hasattr(onnx_model, "predict_graph"):
        return []
    c, s, d = model.model.chunk, model.state_layout.dim, model.accel_layout.dim
    rng = np.random.default_rng(0)
    x = 0.01 * rng.standard_normal((1, s))
    accel = np.asarray(model.model.cfg.output_scale) * rng.standard_normal((1, c, d))
    dynamics, xt, at = model.dynamics(), torch.from_numpy(x), torch.from_numpy(accel)

    def torch_step() -> None:
        with torch.inference_mode():
            dynamics.step(dynamics.start(xt), at, None)

    rows = [{"model": name, "what": "dynamics, one chunk", "runtime": "pytorch", **latencies(torch_step, steps)},
            {"model": name, "what": "dynamics, one chunk", "runtime": "onnxruntime",
             **latencies(lambda: onnx_model.predict_graph(x, accel), steps)}]
    if onnx_model.closed_form is not None:
        rows.append({"model": name, "what": f"dynamics, one chunk ({onnx_model.closed_form} in closed form)",
                     "runtime": "numpy", **latencies(lambda: onnx_model.predict(x, accel), steps)})
    return rows


STEPPER_KINDS = {
    "boundary": "stepper call at a chunk boundary (decoder step + the plan's prediction)",
    "between": "stepper call between boundaries (replan: 2 decoder runs)",
    "boundary_end": "of the boundary calls, the one in the chunk where the motion ends (+ planning the stop)",
    "between_end": "of the calls between, those in the chunk where the motion ends (+ planning the stop)",
}
"""The kinds of stepper call timed; the last two are subsets of the first two (the stop is planned through the
dynamics and the task's constraint at every call in the chunk where the motion ends)."""


def bench_stepper(name: str, model, folder: Path, calls: int, boundary_calls: int,  # noqa: ANN001
                  int8: bool) -> list[dict]:
    """The stepper in a 1 kHz loop, one measured state per call, closed through the model's PyTorch dynamics
    (outside the timing): boundary calls and calls between boundaries timed separately (wall and thread time),
    and those in the chunk where the motion ends (where each call also plans the stop) on their own."""
    k = int(model.options.length[1])  # the longest motion the model trained on
    motion = motion_for(model, k)
    robot = model.dynamics()
    x0 = model.start_state(torch.from_numpy(motion[None])).double().numpy()[0]
    out = []
    for runtime, gen in (("pytorch", model.generator(motion)),
                         ("onnxruntime", OnnxStepper(folder, motion, int8=int8))):
        c = gen.chunk
        last = (k - 2) // c  # the chunk holding the motion's last output u[K-2]
        times: dict[str, list[tuple[int, int]]] = {kind: [] for kind in STEPPER_KINDS}
        wall, cpu = time.perf_counter_ns, time.thread_time_ns
        motions = 0
        while len(times["between"]) < calls or len(times["boundary"]) < boundary_calls:
            gen.reset()
            u, x = gen.step(), torch.from_numpy(x0[None])
            motions += 1
            for _ in range(k - 1):
                with torch.inference_mode():
                    x = robot.step(robot.start(x), torch.from_numpy(np.ascontiguousarray(u[None, :1])), None)[1][
                        "states"][:, -1]
                measured = x.numpy()
                start_wall, start_cpu = wall(), cpu()
                u = gen.step(measured)
                took = (wall() - start_wall, cpu() - start_cpu)
                if motions == 1:
                    continue  # warm-up
                t = gen.time
                boundary = t % c == 0
                kind = "boundary" if boundary else "between"
                times[kind].append(took)
                if (t // c if boundary else (t - 1) // c) == last:
                    times[kind + "_end"].append(took)
        for kind, label in STEPPER_KINDS.items():
            t = np.asarray(times[kind])
            row = {"model": name, "what": label, "kind": kind, "runtime": runtime, **summary(t[:, 0])}
            row["thread_time"] = summary(t[:, 1])
            out.append(row)
    return out


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
    parser.add_argument("--models", nargs="+", default=["pancake", "sliding", "paper"],
                        help="which of pancake, sliding, paper (the paper-size planner) to time")
    parser.add_argument("--json", type=Path, help="also write the rows and the context to this file")
    args = parser.parse_args()
    steps = 1000 if args.quick else args.steps
    wanted = [m for m in args.models if not (args.quick and m == "paper")]
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="bench-deploy-") as tmp:
        models = {name: sm.load_pretrained(name) for name in ("pancake", "sliding") if name in wanted}
        if "paper" in wanted:
            models["paper-size sliding (2x1024 + 500)"] = paper_size_planner()
        for name, model in models.items():
            folder = Path(tmp) / name.split()[0]
            export_onnx(model, folder, int8=name.startswith("paper"))
            variants = [(name, model, OnnxModel(folder), False)]
            if name.startswith("paper"):
                variants.append((f"{name}, int8", model.quantized(), OnnxModel(folder, int8=True), True))
            for label, torch_model, onnx_model, int8 in variants:
                new = bench_decoder_step(label, torch_model, onnx_model, steps)
                new += bench_dynamics(label, torch_model, onnx_model, steps)
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
               "onnxruntime": __import__("onnxruntime").__version__, "seqmotion": str(Path(sm.__file__).parent)}
    print(json.dumps(context))
    print("\n| model | what | runtime | p50 ms | p99 ms | max ms | calls |\n|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['model']} | {r['what']} | {r['runtime']} | {r['p50_ms']:.3f} | {r['p99_ms']:.3f} | "
              f"{r['max_ms']:.2f} | {r['calls']} |")
    print(f"\nload average (1, 5, 15 min) before {load_before}, after {load_after}; {context['machine']}")
    if args.json is not None:
        args.json.write_text(json.dumps({"context": context, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
