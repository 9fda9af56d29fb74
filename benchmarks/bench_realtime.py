"""The 1 kHz control step at the machine's floor: the ONNX stepper and the C generator, measured.

    python benchmarks/bench_realtime.py --json benchmarks/results_step_realtime.json     # ~2 min
    python benchmarks/bench_realtime.py --calls 2000 --models pancake                      # a quick look

For the shipped pancake and sliding models and the cup arm (``examples/cup_arm``, the ``small`` preset built
untrained with seed 0: a call's time does not depend on the weights), each exported with ``export-onnx``:

* **the ONNX stepper** (``OnnxStepper.step_into``, one measured state per call, then ``prepare()`` timed apart —
  the work a loop does once its command went out —, the robot the bundle's own dynamics between calls, untimed)
  in five loops: ``tight, shared code`` (no sleep, every call through ``StepperCore``: the general path, in the
  same run), ``tight, no prepare`` (the call doing the predicted window's decoder run itself), ``tight`` (no
  sleep, as ``bench_deploy.py`` measured), ``normal`` (paced
  at 1 kHz to absolute deadlines, normal scheduling) and ``realtime`` (the same, pinned to one core with
  ``SCHED_FIFO`` where permitted: ``seqmotion.deploy.realtime``); p50 / p99 / p99.9 / max per kind of call
  (``between`` chunk boundaries, ``boundary``, ``final_chunk`` — the chunk where the motion ends, which also plans
  the stop — and ``stop``), with late wake-ups;
* **the floor**: the smallest onnxruntime call (an ``Identity`` of one float through I/O binding, one thread) in
  the same loop, the same run; every stepper figure is also given as a ratio to it (p50 to its p50, p99 to its
  p99), which carries over between machines better than microseconds;
* **the C generator** (``export-c``, ``cc -O2``): ``PREFIX_decoder_step`` in a tight loop and
  ``PREFIX_generator_step`` per kind of call (with ``PREFIX_generator_prepare`` after each, timed apart, and
  without), tight and paced at 1 kHz, normal and real-time.

A busy machine inflates every tail: give the load averages (printed, and in the JSON) with the figures, and
measure on a quiet machine for the record.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

import seqmotion as sm
from seqmotion.deploy import OnnxModel, export_onnx
from seqmotion.deploy.c_export import export_c
from seqmotion.deploy.export import example_inputs
from seqmotion.deploy.realtime import bench_stepper, paced, realtime, trivial_call
from seqmotion.training.provenance import machine_description

ROOT = Path(__file__).resolve().parents[1]

C_BENCH = r"""
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "seqmotion_generator.h"
#define C SEQMOTION_CHUNK
#define S SEQMOTION_STATE_DIM
#define D SEQMOTION_ACCEL_DIM
static long now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec * 1000000000L + t.tv_nsec;
}
static void sleep_until(long ns) { struct timespec t = {ns / 1000000000L, ns % 1000000000L};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &t, NULL)) {} }
static int cmp(const void *a, const void *b)
{
    long x = *(const long *)a, y = *(const long *)b;
    return (x > y) - (x < y);
}
static void report(const char *name, long *t, int n, int last) {
    qsort(t, (size_t)n, sizeof *t, cmp);
    printf("\"%s\": {\"p50_us\": %.3f, \"p99_us\": %.3f, \"p99.9_us\": %.3f, \"max_us\": %.3f, \"calls\": %d}%s\n",
           name, t[n / 2] / 1e3, t[(int)(n * 0.99)] / 1e3, t[(int)(n * 0.999)] / 1e3, t[n - 1] / 1e3, n,
           last ? "" : ",");
}
static seqmotion_generator g;
static long td[20000], tb[20000], tm[200000], tm0[200000], tpr[200000], tp[200000], tpp[200000], tpb[20000],
    late[200000];
int main(int argc, char **argv) {
    static float z[SEQMOTION_LATENT_DIM], h[SEQMOTION_LATENT_DIM], c[SEQMOTION_LATENT_DIM];
    static float ho[SEQMOTION_LATENT_DIM], co[SEQMOTION_LATENT_DIM];
    static float w[C * S], a[C * D];
    double x0[S] = {0}, out[C * D], meas[S];
    const int calls = argc > 1 ? atoi(argv[1]) : 5000;
    const long length = SEQMOTION_DEFAULT_LENGTH > 4 * C ? SEQMOTION_DEFAULT_LENGTH : 4 * C;
    int nb = 0, nm = 0, nm0 = 0, npr = 0, np_ = 0, npp = 0, npb = 0;
    for (int i = 0; i < SEQMOTION_LATENT_DIM; ++i) z[i] = 0.1f * (float)((i * 7919) % 13 - 6);
    memcpy(c, z, sizeof c);
    for (int i = 0; i < 2000; ++i) seqmotion_decoder_step(h, c, w, ho, co, a);
    for (int i = 0; i < 20000; ++i) { long s = now(); seqmotion_decoder_step(h, c, w, ho, co, a); td[i] = now() - s; }
    /* tight: the motion's calls, fed the plan's own states (plus a little); without prepare, then with it after
     * each call (timed apart: the work once the command went out) */
    for (int with_prepare = 0; with_prepare < 2; ++with_prepare) {
        int *count = with_prepare ? &nm : &nm0;
        long *times = with_prepare ? tm : tm0;
        while (*count < calls) {
            seqmotion_generator_start(&g, z, x0, length, NULL, 1);
            seqmotion_generator_step(&g, NULL, 0, out);
            for (long t = 0; t < length - 1 - C && *count < calls; ++t) {
                memcpy(meas, g.pred + (t % C) * S, sizeof meas);
                meas[0] += 1e-5;
                long s = now(); int n = seqmotion_generator_step(&g, meas, 1, out); long d = now() - s;
                if (n < 0) { fprintf(stderr, "error %d\n", n); return 1; }
                int at_boundary = (g.t - g.origin) % C == 0;
                if (at_boundary) { if (with_prepare && nb < 20000) tb[nb++] = d; } else times[(*count)++] = d;
                if (with_prepare) {
                    s = now(); seqmotion_generator_prepare(&g); d = now() - s;
                    if (!at_boundary && (g.t - g.origin + 1) % C != 0) tpr[npr++] = d;
                }
            }
        }
    }
    /* paced at 1 kHz to absolute deadlines */
    long start = now() + 1000000;
    seqmotion_generator_start(&g, z, x0, length, NULL, 1);
    seqmotion_generator_step(&g, NULL, 0, out);
    for (int i = 0; i < calls; ++i) {
        long deadline = start + (long)i * 1000000L;
        long t = g.t - g.origin;
        if (t >= length - 1 - C) {
            seqmotion_generator_start(&g, z, x0, length, NULL, 1);
            seqmotion_generator_step(&g, NULL, 0, out);
            t = 0;
        }
        memcpy(meas, g.pred + (t % C) * S, sizeof meas);
        meas[0] += 1e-5;
        sleep_until(deadline);
        long s = now(); seqmotion_generator_step(&g, meas, 1, out); long d = now() - s;
        late[i] = s - deadline;
        if ((g.t - g.origin) % C == 0) { if (npb < 20000) tpb[npb++] = d; } else tp[np_++] = d;
        s = now(); seqmotion_generator_prepare(&g); d = now() - s;
        if ((g.t - g.origin) % C != 0 && (g.t - g.origin + 1) % C != 0) tpp[npp++] = d;
    }
    printf("{\n");
    report("decoder_step", td, 20000, 0);
    report("between", tm, nm, 0);
    report("between_without_prepare", tm0, nm0, 0);
    report("prepare", tpr, npr, 0);
    report("boundary", tb, nb, 0);
    report("paced_between", tp, np_, 0);
    report("paced_prepare", tpp, npp, 0);
    report("paced_boundary", tpb, npb, 0);
    report("paced_wake_late", late, calls, 1);
    printf("}\n");
    return 0;
}
"""


def cup_arm_model():  # noqa: ANN201 - a TrainedModel
    """The cup arm's ``small`` preset, untrained (seed 0), from ``examples/cup_arm/src``."""
    sys.path.insert(0, str(ROOT / "examples" / "cup_arm" / "src"))
    from seqmotion import tasks

    try:
        task = tasks.get("cup_arm")
    except (KeyError, ValueError):
        from seqmotion_cup_arm.task import CupArmTask

        task = tasks.register(CupArmTask())
    config = task.train_config("small")
    torch.manual_seed(0)
    network = task.build_model(config)
    return task.wrap(network, {"task": task.name, "model": config.model, "training": {"options": config.options}})


def ratios(stats: dict, floor: dict) -> dict:
    """``stats`` (µs) with their ratios to the trivial call's (p50 to p50, p99 to p99, …)."""
    out = {}
    for key, value in stats.items():
        if isinstance(value, dict) and "p50_us" in value:
            value = {**value, **{f"{q}_ratio": value[f"{q}_us"] / floor[f"{q}_us"] for q in ("p50", "p99", "p99.9")
                                 if floor.get(f"{q}_us")}}
        out[key] = value
    return out


def onnx_runs(onnx: OnnxModel, motion: np.ndarray, calls: int, cpu: int, priority: int) -> dict:
    trivial = trivial_call()
    runs = {}
    for mode in ("tight, shared code", "tight, no prepare", "tight", "normal", "realtime"):
        rt = mode == "realtime"
        period = 1e-9 if mode.startswith("tight") else 1e-3
        with realtime(cpu=cpu if rt else None, fifo=rt, priority=priority) as setup:
            floor = paced(lambda _: trivial(), min(calls, 3000), period)
            report = bench_stepper(onnx, motion, calls, period, buffers=mode != "tight, shared code",
                                   prepare=mode not in ("tight, shared code", "tight, no prepare"))
        stats = report.stats()
        floor_stats = floor.stats()["call"]
        runs[mode] = {"setup": setup.to_dict(), "trivial_onnxruntime_call": floor_stats,
                      **ratios(stats, floor_stats)}
        print(f"  {mode} ({setup.describe()}): trivial call p50 {floor_stats['p50_us']:.1f} p99 "
              f"{floor_stats['p99_us']:.1f} µs", flush=True)
        for line in report.summary().splitlines():
            print("    " + line, flush=True)
    return runs


def c_runs(model, folder: Path, calls: int, cpu: int, priority: int, cflags: list[str]) -> dict:  # noqa: ANN001
    compiler = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if compiler is None:
        return {"skipped": "no C compiler"}
    export_c(model, folder)
    (folder / "bench.c").write_text(C_BENCH)
    binary = folder / "bench"
    subprocess.run([compiler, *cflags, "-std=c99", f"-I{folder}", str(folder / "bench.c"),
                    str(folder / "seqmotion_model.c"), str(folder / "seqmotion_generator.c"), "-o", str(binary),
                    "-lm"], check=True, capture_output=True)
    runs = {"cflags": " ".join(cflags)}
    for mode in ("normal", "realtime"):
        rt = mode == "realtime"
        with realtime(cpu=cpu if rt else None, fifo=rt, priority=priority, disable_gc=False) as setup:
            done = subprocess.run([str(binary), str(calls)], capture_output=True, text=True, check=True)
        runs[mode] = {"setup": setup.to_dict(), **json.loads(done.stdout)}
        r = runs[mode]
        print(f"  C {mode}: decoder_step p50 {r['decoder_step']['p50_us']:.1f} p99 {r['decoder_step']['p99_us']:.1f};"
              f" generator between p50 {r['between']['p50_us']:.1f} p99 {r['between']['p99_us']:.1f}; boundary p50 "
              f"{r['boundary']['p50_us']:.1f} p99 {r['boundary']['p99_us']:.1f}; paced between p50 "
              f"{r['paced_between']['p50_us']:.1f} p99 {r['paced_between']['p99_us']:.1f} µs", flush=True)
    return runs


def markdown(result: dict) -> str:
    lines = ["| model | loop | call | p50 µs | p99 µs | p99.9 µs | max µs | p50 / floor | p99 / floor | calls |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for name, entry in result["models"].items():
        for mode, run in entry["onnx"].items():
            floor = run["trivial_onnxruntime_call"]
            lines.append(f"| {name} | {mode} | trivial onnxruntime call | {floor['p50_us']:.1f} | "
                         f"{floor['p99_us']:.1f} | {floor['p99.9_us']:.1f} | {floor['max_us']:.1f} | 1 | 1 | "
                         f"{floor['calls']} |")
            for kind in ("between", "boundary", "final_chunk", "stop", "after between", "after boundary"):
                s = run.get(kind)
                if s and s.get("calls"):
                    lines.append(f"| {name} | {mode} | {kind} | {s['p50_us']:.1f} | {s['p99_us']:.1f} | "
                                 f"{s['p99.9_us']:.1f} | {s['max_us']:.1f} | {s.get('p50_ratio', 0):.1f} | "
                                 f"{s.get('p99_ratio', 0):.1f} | {s['calls']} |")
            if not mode.startswith("tight"):
                w = run["wake_late"]
                lines.append(f"| {name} | {mode} | wake-up lateness ({run['late_wakeups']} > 100 µs) | "
                             f"{w['p50_us']:.1f} | {w['p99_us']:.1f} | {w['p99.9_us']:.1f} | {w['max_us']:.1f} | | | "
                             f"{w['calls']} |")
        for mode in ("normal", "realtime"):
            run = entry.get("c", {}).get(mode)
            if not run:
                continue
            for kind in ("decoder_step", "between", "between_without_prepare", "prepare", "boundary",
                         "paced_between", "paced_prepare", "paced_boundary"):
                s = run[kind]
                lines.append(f"| {name} | C {mode} | {kind} | {s['p50_us']:.1f} | {s['p99_us']:.1f} | "
                             f"{s['p99.9_us']:.1f} | {s['max_us']:.1f} | | | {s['calls']} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", nargs="+", default=["pancake", "sliding", "cup_arm"])
    parser.add_argument("--calls", type=int, default=5000, help="timed calls per loop (default 5000)")
    parser.add_argument("--cpu", type=int, default=-1, help="the core the real-time runs pin to (default: last)")
    parser.add_argument("--priority", type=int, default=80)
    parser.add_argument("--cflags", default="-O2", help="the C compiler's flags (default -O2)")
    parser.add_argument("--no-c", action="store_true", help="skip the C generator")
    parser.add_argument("--json", type=Path, help="write the figures here")
    parser.add_argument("--md", type=Path, help="write the table here (markdown)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    result: dict = {"machine": machine_description(), "load_average_before": load_before, "calls": args.calls,
                    "onnxruntime": __import__("onnxruntime").__version__, "models": {}}
    with tempfile.TemporaryDirectory(prefix="bench-realtime-") as tmp:
        for name in args.models:
            model = cup_arm_model() if name == "cup_arm" else sm.load_pretrained(name)
            folder = Path(tmp) / name
            export_onnx(model, folder, source=name)
            onnx = OnnxModel(folder)
            motion = example_inputs(model, n=1)[0]
            k = int(onnx.contract["default_length"] or len(motion))
            if len(motion) < k:  # the longest motion the model trained on: a whole one per chunk of calls
                motion = np.concatenate([motion, np.repeat(motion[-1:], k - len(motion), axis=0)])
            print(f"{name}: C = {onnx.chunk}, K = {len(motion)}", flush=True)
            entry = {"chunk": onnx.chunk, "length": len(motion),
                     "onnx": onnx_runs(onnx, motion, args.calls, args.cpu, args.priority)}
            if not args.no_c:
                entry["c"] = c_runs(model, Path(tmp) / f"{name}-c", args.calls, args.cpu, args.priority,
                                    args.cflags.split())
            result["models"][name] = entry
    result["load_average_after"] = os.getloadavg()
    table = markdown(result)
    print(table)
    print(f"\nload average (1, 5, 15 min) before {load_before}, after {result['load_average_after']}; "
          f"{result['machine']}")
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    if args.md is not None:
        args.md.write_text(table + "\n")


if __name__ == "__main__":
    main()
