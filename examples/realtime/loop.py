"""A 1 kHz control loop in Python around the ONNX stepper, measured: the recipe.

    seqmotion export-onnx pancake build/pancake-onnx
    python examples/realtime/loop.py build/pancake-onnx --seconds 5        # normal scheduling
    sudo python examples/realtime/loop.py build/pancake-onnx --rt          # pinned, SCHED_FIFO (says if refused)

What makes the loop's calls short and steady:

* ``OnnxStepper.step_into(measured, out)``: the stepper's buffers and bound onnxruntime sessions (one thread), no
  array made per call; ``measured`` a float64 ``(1, S)`` array filled in place, ``out`` a ``(C, d)`` one;
* ``gen.prepare()`` once the command went out: the next call's work that no measurement changes (the predicted
  window's decoder run), done while the loop waits, so the next call holds one decoder run;
* absolute deadlines ``start + i · 1 ms``: a late period is not made up for by shifting the rest;
* ``realtime()``: one core (``os.sched_setaffinity``), ``SCHED_FIFO`` where permitted, a 1 µs timer slack, the
  garbage collector frozen and off for the loop (reference counting still frees everything).

It prints the late wake-ups and the call latencies (p50 / p99 / p99.9 / max). ``seqmotion bench-step`` runs the
same loop on any model, normal and real-time side by side.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from seqmotion.deploy import OnnxModel, OnnxStepper
from seqmotion.deploy.realtime import percentiles, realtime, simulated_robot


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bundle", help="a folder seqmotion export-onnx wrote")
    parser.add_argument("--seconds", type=float, default=5.0, help="how long to run (default 5 s)")
    parser.add_argument("--rt", action="store_true", help="pin a core and ask for SCHED_FIFO")
    args = parser.parse_args()

    model = OnnxModel(args.bundle)
    k = int(model.contract["default_length"] or 4 * model.chunk)
    gen = OnnxStepper(model, latent=np.zeros(model.layers * model.hidden), x0=np.zeros(model.state_dim), length=k)
    robot = simulated_robot(model)  # the robot: the model's own dynamics, one sample a period
    out = np.zeros((gen.chunk, gen.accel_dim))
    measured = np.zeros((1, model.state_dim))
    x = gen._x0.copy()
    periods = int(args.seconds * 1000)
    took, late = np.zeros(periods, dtype=np.int64), np.zeros(periods, dtype=np.int64)
    prepared = np.zeros(periods, dtype=np.int64)
    gen.step_into(None, out)  # the first chunk, before the loop
    with realtime(cpu=-1 if args.rt else None, fifo=args.rt) as setup:
        clock, period = time.perf_counter_ns, 1_000_000
        start = clock() + period
        for i in range(periods):
            deadline = start + i * period
            now = clock()
            if deadline > now:
                time.sleep((deadline - now) * 1e-9)
            woke = clock()
            x = robot(x, out[:1])  # the robot applied out[0] in the last period; its state now
            measured[...] = x
            begin = clock()
            gen.step_into(measured, out)
            sent = clock()  # here a robot's loop sends out[0]
            gen.prepare()
            took[i], late[i], prepared[i] = sent - begin, woke - deadline, clock() - sent
            if gen.done or gen.time > k + gen.chunk:  # stopped: the next motion
                gen.reset()
                x = gen._x0.copy()
                gen.step_into(None, out)
    print(setup.describe())
    call, wake = percentiles(took), percentiles(np.maximum(late, 0))
    print(f"{periods} periods: {int(np.count_nonzero(late > 100_000))} woke more than 100 µs late")
    for name, s in (("wake-up lateness", wake), ("step_into", call), ("prepare (after the command)",
                                                                      percentiles(prepared))):
        print(f"{name}: p50 {s['p50_us']:.1f}  p99 {s['p99_us']:.1f}  p99.9 {s['p99.9_us']:.1f}  "
              f"max {s['max_us']:.1f} µs")


if __name__ == "__main__":
    main()
