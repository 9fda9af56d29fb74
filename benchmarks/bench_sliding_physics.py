"""The sliding contact model's backends on this machine: numba kernel vs batched torch (issue 21).

    python benchmarks/bench_sliding_physics.py physics [--repeats N] [--device cuda]   # contact model alone
    python benchmarks/bench_sliding_physics.py train [--repeats N] [--device cuda]     # a whole training step

``physics``: forward and forward+backward of :func:`seqmotion.tasks.sliding.physics.contact_chunk` on one
decoder chunk (C = 100 samples) of the shipped ``small`` training batch (B = 64, float32 pan
accelerations as the decoder emits them, per-trajectory friction), for ``numba``, ``torch`` (hand-derived
backward in torch) and ``torch_autograd`` (the same forward differentiated by autograd), and per
training batch (15 chunks: K_max = 1500).

``train``: one optimiser step (the same batch every time) of the ``small`` model on the ``small``
batch, loss + backward + Adam, with the contact model on each backend (``sliding.CPU_BACKEND`` /
``sliding.DEVICE_BACKEND``), in the curriculum's first stage (L': the contact model runs without a
graph) and its third (L: the gradient passes through the contact model).

``--device cuda``: the same with the tensors (and the model) on the GPU, where ``numba`` means the
kernel on the CPU with a copy each way per chunk (what ``backend="numba"`` does with CUDA tensors)
and ``torch`` the batched torch path on the GPU (the default there).

Timings: the fastest (``min``, the headline: what the code costs when nothing else interferes) and the
median of ``--repeats`` runs, the backends interleaved, on a machine shared with other jobs.
Prints JSON lines; nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from seqmotion import tasks
from seqmotion.tasks.sliding import physics as sliding
from seqmotion.training.provenance import machine_description
from seqmotion.training.trainer import step_loss

CHUNKS_PER_BATCH = 15  # K_max = 1500 samples, C = 100


def small_batch_shape() -> tuple[int, int]:
    cfg = tasks.get("sliding").train_config("small")
    return cfg.batch_size, int(cfg.model["chunk"])


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def bench_physics(repeats: int, device: torch.device) -> None:
    b, c = small_batch_shape()
    rng = np.random.default_rng(0)
    rel0 = torch.zeros(b, 4)
    rel0[::2, 2:] = torch.tensor(rng.normal(scale=0.2, size=(len(rel0[::2]), 2)), dtype=torch.float32)  # half slide
    u = torch.tensor(rng.normal(scale=12, size=(b, c, 2)), dtype=torch.float32)  # sticks, slides, stops
    mu = torch.tensor(rng.uniform(0.5, 1.5, b))
    mu_dyn = mu * 0.5
    rel0, u, mu, mu_dyn = (t.to(device) for t in (rel0, u, mu, mu_dyn))
    times: dict[tuple[str, str], list[float]] = {}
    for _ in range(repeats):
        for backend in sliding.BACKENDS:
            for grad in (False, True):
                u_in = u.clone().requires_grad_(grad)
                sync(device)
                start = time.perf_counter()
                states, _, branch = sliding.contact_chunk(rel0, u_in, mu, mu_dyn, backend=backend)
                if grad:
                    states.sum().backward()
                sync(device)
                times.setdefault((backend, "fwd+bwd" if grad else "fwd"), []).append(time.perf_counter() - start)
                del states  # free this run's graph outside the next run's timing
    shares = np.bincount(branch.flatten().cpu().numpy(), minlength=4) / branch.numel()
    for (backend, what), ts in times.items():
        chunk_ms, median_ms = 1e3 * min(ts[1:]), 1e3 * float(np.median(ts[1:]))  # the first run warms up
        print(json.dumps({
            "bench": "contact_chunk", "device": str(device), "backend": backend, "pass": what, "batch": b, "chunk": c,
            "ms_per_chunk": round(chunk_ms, 3), "median_ms_per_chunk": round(median_ms, 3),
            "ms_per_batch_of_15_chunks": round(CHUNKS_PER_BATCH * chunk_ms, 1),
            "branch_shares_stick_break_slide_stop": [round(float(s), 3) for s in shares],
            "threads": torch.get_num_threads(), "machine": machine_description(),
        }))


def bench_train(repeats: int, device: torch.device) -> None:
    task = tasks.get("sliding")
    cfg = task.train_config("small")
    stages = {"stage 1 (L', contact without graph)": {"loss_prime_prob": 1.0, "bspline_prob": 0.0},
              "stage 3 (L through contact)": {"loss_prime_prob": 0.0, "bspline_prob": 0.0}}
    times: dict[tuple[str, str], list[float]] = {}
    for stage, params in stages.items():
        batch = task.sample(cfg.batch_size, np.random.default_rng(0), task.params(params), task.options(cfg))
        for _ in range(repeats):
            for backend in ("numba", "torch"):
                torch.manual_seed(0)
                model = task.build_model(cfg).to(device)
                optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
                sliding.CPU_BACKEND = sliding.DEVICE_BACKEND = backend
                try:
                    sync(device)
                    start = time.perf_counter()
                    loss, _ = step_loss(task, model, batch, params, cfg, torch.Generator().manual_seed(0))
                    optimizer.zero_grad()
                    loss.backward()
                    optimizer.step()
                    sync(device)
                    times.setdefault((stage, backend), []).append(time.perf_counter() - start)
                    del loss  # free the graph outside the next step's timing
                finally:
                    sliding.CPU_BACKEND, sliding.DEVICE_BACKEND = "numba", "torch"
        k_max = int(batch.lengths.max())
        for backend in ("numba", "torch"):
            ts = times[(stage, backend)]
            print(json.dumps({
                "bench": "train_step", "device": str(device), "stage": stage, "backend": backend,
                "batch": cfg.batch_size, "k_max": k_max,
                "s_per_step": round(min(ts), 3), "median_s_per_step": round(float(np.median(ts)), 3),
                "runs": [round(t, 3) for t in ts],
                "threads": torch.get_num_threads(), "machine": machine_description(),
            }))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=("physics", "train"))
    parser.add_argument("--repeats", type=int, default=None)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    device = torch.device(args.device)
    if args.what == "physics":
        bench_physics(max(args.repeats or 30, 3), device)
    else:
        bench_train(args.repeats or 3, device)


if __name__ == "__main__":
    main()
