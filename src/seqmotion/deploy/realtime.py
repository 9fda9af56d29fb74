"""A 1 kHz control loop in Python, measured: the recipe ``seqmotion bench-step`` and ``examples/realtime`` run.

    from seqmotion.deploy.realtime import realtime, paced
    with realtime(cpu=1, fifo=True) as setup:                 # pin a core, SCHED_FIFO where permitted, no gc
        report = paced(lambda i: gen.step_into(measured, out), calls=5000, period=1e-3)
    print(setup.describe(), report.summary())

:func:`realtime` is what a Python control loop on Linux can do for itself: pin the process to one core
(``os.sched_setaffinity``), ask for ``SCHED_FIFO`` (``os.sched_setscheduler``; refused without the right, which
:attr:`Setup.notes` then says, with how to grant it), cut the kernel's timer slack to 1 µs (``prctl``; a normal
thread's sleeps otherwise end up to 50 µs late), lock its memory (``mlockall``, where permitted) and keep the
garbage collector out of the loop (``gc.freeze`` of what exists, ``gc.disable``; reference counting still frees
every array). Everything is undone on exit.

:func:`paced` calls ``step(i)`` at absolute deadlines ``start + i · period`` (sleeping until each, never
drifting: a late call is not made up for by shifting the ones after it) and records for each call its wake-up
lateness (when it started against its deadline), its duration and the deadlines it overran; :class:`LoopReport`
gives p50 / p99 / p99.9 / max of both, per kind of call when ``step`` names one.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import gc
import math
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

PR_SET_TIMERSLACK = 29
"""``prctl`` option: the calling thread's timer slack in ns (Linux)."""
MCL_CURRENT, MCL_FUTURE = 1, 2
LATE_US = 100.0
"""A wake-up this much after its deadline [µs] counts as late (a tenth of a 1 kHz period)."""


def percentiles(values_ns: np.ndarray) -> dict[str, float]:
    """p50 / p99 / p99.9 / max and the mean of durations in ns, in µs (and their count)."""
    t = np.asarray(values_ns, dtype=np.float64) / 1e3
    if t.size == 0:
        return {"calls": 0}
    return {"p50_us": float(np.percentile(t, 50)), "p99_us": float(np.percentile(t, 99)),
            "p99.9_us": float(np.percentile(t, 99.9)), "max_us": float(t.max()), "mean_us": float(t.mean()),
            "calls": int(t.size)}


@dataclass
class Setup:
    """What :func:`realtime` managed to set up, and what it could not (with why)."""

    cpu: int | None = None
    policy: str = "SCHED_OTHER"
    priority: int = 0
    timer_slack_ns: int | None = None
    memory_locked: bool = False
    gc_disabled: bool = False
    notes: list[str] = field(default_factory=list)

    def describe(self) -> str:
        parts = [f"cpu {self.cpu}" if self.cpu is not None else "any cpu",
                 f"{self.policy}" + (f" priority {self.priority}" if self.priority else ""),
                 f"timer slack {self.timer_slack_ns} ns" if self.timer_slack_ns is not None else "timer slack as is",
                 "memory locked" if self.memory_locked else "memory not locked",
                 "gc off" if self.gc_disabled else "gc on"]
        return ", ".join(parts) + "".join(f"; {note}" for note in self.notes)

    def to_dict(self) -> dict[str, Any]:
        return {"cpu": self.cpu, "policy": self.policy, "priority": self.priority,
                "timer_slack_ns": self.timer_slack_ns, "memory_locked": self.memory_locked,
                "gc_disabled": self.gc_disabled, "notes": list(self.notes)}


def _libc() -> Any:
    name = ctypes.util.find_library("c")
    return ctypes.CDLL(name, use_errno=True) if name else None


@contextlib.contextmanager
def realtime(cpu: int | None = -1, fifo: bool = True, priority: int = 80, lock_memory: bool = False,
             timer_slack_ns: int | None = 1000, disable_gc: bool = True) -> Iterator[Setup]:
    """Set this process up for a control loop (module docstring) and undo it on exit.

    Args:
        cpu: the core to pin to (-1: the last one allowed; None: do not pin).
        fifo: ask for ``SCHED_FIFO`` at ``priority`` (1–99).
        lock_memory: ``mlockall`` the process (no page fault in the loop; on a robot computer, not on a machine
            shared with others: it pins every page the process has and will have).
        timer_slack_ns: the timer slack to set (None: leave it).
        disable_gc: freeze the existing objects and turn the cyclic garbage collector off.

    Raises:
        ValueError: a ``cpu`` the process may not run on, or a priority outside 1–99.
    """
    if not 1 <= int(priority) <= 99:
        raise ValueError(f"priority must be 1 to 99 (SCHED_FIFO's range), got {priority}")
    setup = Setup()
    linux = sys.platform.startswith("linux")
    affinity = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    policy = os.sched_getscheduler(0) if hasattr(os, "sched_getscheduler") else None
    param = os.sched_getparam(0) if hasattr(os, "sched_getparam") else None
    libc = _libc() if linux else None
    slack_before = None
    gc_was = gc.isenabled()
    try:
        if cpu is not None and affinity is not None:
            allowed = sorted(affinity)
            chosen = allowed[-1] if cpu == -1 else int(cpu)
            if chosen not in affinity:
                raise ValueError(f"cpu {cpu} is not one this process may run on (allowed: {allowed})")
            os.sched_setaffinity(0, {chosen})
            setup.cpu = chosen
        elif cpu is not None:
            setup.notes.append("no os.sched_setaffinity here: not pinned")
        if fifo and hasattr(os, "sched_setscheduler"):
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(priority)))
                setup.policy, setup.priority = "SCHED_FIFO", int(priority)
            except PermissionError:
                setup.notes.append("SCHED_FIFO not permitted (run as root, or grant rtprio in "
                                   "/etc/security/limits.conf or CAP_SYS_NICE): normal scheduling")
            except OSError as exc:
                setup.notes.append(f"SCHED_FIFO refused ({exc.strerror or exc}): normal scheduling")
        elif fifo:
            setup.notes.append("no os.sched_setscheduler here: normal scheduling")
        if libc is not None and timer_slack_ns is not None:
            get = libc.prctl(30, 0, 0, 0, 0)  # PR_GET_TIMERSLACK
            slack_before = int(get) if get >= 0 else None
            if libc.prctl(PR_SET_TIMERSLACK, ctypes.c_ulong(int(timer_slack_ns)), 0, 0, 0) == 0:
                setup.timer_slack_ns = int(timer_slack_ns)
        if libc is not None and lock_memory:
            if libc.mlockall(MCL_CURRENT | MCL_FUTURE) == 0:
                setup.memory_locked = True
            else:
                setup.notes.append(f"mlockall refused ({os.strerror(ctypes.get_errno())}): memory not locked")
        if disable_gc:
            gc.collect()
            gc.freeze()
            gc.disable()
            setup.gc_disabled = True
        yield setup
    finally:
        if setup.gc_disabled:
            gc.unfreeze()
            if gc_was:
                gc.enable()
        if setup.memory_locked and libc is not None:
            libc.munlockall()
        if slack_before is not None and libc is not None:
            libc.prctl(PR_SET_TIMERSLACK, ctypes.c_ulong(slack_before), 0, 0, 0)
        if setup.policy != "SCHED_OTHER" and policy is not None and param is not None:
            with contextlib.suppress(OSError):
                os.sched_setscheduler(0, policy, param)
        if setup.cpu is not None and affinity is not None:
            os.sched_setaffinity(0, affinity)


@dataclass
class LoopReport:
    """What :func:`paced` measured (ns arrays, one entry per call)."""

    period_s: float
    wake_ns: np.ndarray
    call_ns: np.ndarray
    kinds: list[str]
    overruns: int
    late_us: float = LATE_US
    after_ns: np.ndarray | None = None  # the work after each call (``after``: the stepper's prepare), if any

    def stats(self) -> dict[str, Any]:
        kinds = np.asarray(self.kinds)
        out: dict[str, Any] = {
            "calls": int(self.call_ns.size), "period_ms": self.period_s * 1e3,
            "wake_late": percentiles(np.maximum(self.wake_ns, 0)),
            "late_wakeups": int(np.count_nonzero(self.wake_ns > self.late_us * 1e3)),
            "late_threshold_us": self.late_us, "overruns": self.overruns,
            "call": percentiles(self.call_ns)}
        for kind in sorted(set(self.kinds)):
            if kind:
                out[kind] = percentiles(self.call_ns[kinds == kind])
        if self.after_ns is not None:
            out["after"] = percentiles(self.after_ns)
            for kind in sorted(set(self.kinds)):
                if kind:
                    out[f"after {kind}"] = percentiles(self.after_ns[kinds == kind])
        return out

    def summary(self) -> str:
        s = self.stats()

        def line(name: str, d: dict) -> str:
            return (f"{name}: p50 {d['p50_us']:.1f}  p99 {d['p99_us']:.1f}  p99.9 {d['p99.9_us']:.1f}  "
                    f"max {d['max_us']:.1f} µs ({d['calls']} calls)")
        lines = [f"{s['calls']} calls at {1e3 / s['period_ms']:.0f} Hz: {s['late_wakeups']} woke more than "
                 f"{s['late_threshold_us']:.0f} µs late, {s['overruns']} overran the next deadline",
                 line("wake-up lateness", s["wake_late"]), line("call", s["call"])]
        lines += [line(f"  {kind}", s[kind]) for kind in sorted(set(self.kinds)) if kind]
        if "after" in s:
            lines.append(line("after the call (prepare, off the command's path)", s["after"]))
        return "\n".join(lines)


def paced(step: Callable[[int], str | None], calls: int, period: float = 1e-3,
          between: Callable[[int], Any] | None = None, spin: float = 0.0,
          after: Callable[[int], Any] | None = None) -> LoopReport:
    """Call ``step(i)`` for i = 0..calls-1 at absolute deadlines ``start + i · period`` (module docstring); ``step``
    may return the kind of its call (a name the report groups by). ``after(i)``, if given, runs right after call i
    and is timed apart (the work a loop does once its command went out: the stepper's ``prepare``);
    ``between(i)`` then runs untimed (a simulated robot taking the outputs). ``spin`` [s]: the last part of each
    wait is a busy wait instead of a sleep (``spin = period``: never sleep): a core kept busy wakes on time and
    keeps the model's weights in its caches, at the price of the whole core (on a robot, the core the loop is
    pinned to).

    Raises:
        ValueError: ``calls`` < 1 or ``period`` not > 0.
    """
    if int(calls) < 1 or not (math.isfinite(period) and period > 0):
        raise ValueError(f"paced needs calls >= 1 and a period > 0 s, got {calls} calls of {period} s")
    calls, period_ns, spin_ns = int(calls), int(round(period * 1e9)), int(round(max(spin, 0.0) * 1e9))
    wake = np.zeros(calls, dtype=np.int64)
    took = np.zeros(calls, dtype=np.int64)
    after_took = np.zeros(calls, dtype=np.int64) if after is not None else None
    kinds = [""] * calls
    clock, sleep = time.perf_counter_ns, time.sleep
    overruns = 0
    start = clock() + period_ns
    for i in range(calls):
        deadline = start + i * period_ns
        now = clock()
        if deadline - spin_ns > now:
            sleep((deadline - spin_ns - now) * 1e-9)
        while clock() < deadline:  # the busy part of the wait (none past the deadline)
            pass
        begin = clock()
        kind = step(i)
        end = clock()
        wake[i], took[i] = begin - deadline, end - begin
        kinds[i] = kind or ""
        if after_took is not None:
            after(i)
            after_took[i] = clock() - end
        if between is not None:
            between(i)
        if clock() > deadline + period_ns:
            overruns += 1
    return LoopReport(period, wake, took, kinds, overruns, after_ns=after_took)


def trivial_call() -> Callable[[], None]:
    """One run of the smallest onnxruntime graph (an ``Identity`` of one float) through I/O binding, one thread:
    the floor a stepper call is compared with, measured in the same run (``bench-step``)."""
    import onnxruntime as ort
    from onnx import TensorProto, helper

    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "trivial",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    session = ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"])
    x, y = np.zeros(1, np.float32), np.zeros(1, np.float32)
    binding = session.io_binding()
    binding.bind_cpu_input("x", x)
    binding.bind_output("y", "cpu", 0, np.float32, [1], y.ctypes.data)
    run = session.run_with_iobinding

    def call() -> None:
        run(binding)
    call.buffers = (x, y, binding)  # type: ignore[attr-defined]
    return call


def simulated_robot(model: Any, physics: np.ndarray | None = None) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The bundle's own dynamics as the robot a loop drives: ``(x (1, S), u (1, d))`` → the next state ``(1, S)``
    (the closed form, else the one-sample graph, else a chunk of the dynamics graph padded)."""
    if model.closed_form is None and model.sample_session is not None:
        session = model.sample_session
        names = [i.name for i in session.get_inputs()]
        vector = model.physics_vector(None) if physics is None else physics

        def one(x: np.ndarray, u: np.ndarray) -> np.ndarray:
            feeds = {"x": np.ascontiguousarray(x, dtype=np.float64), "accel": np.ascontiguousarray(u[:, None]),
                     "physics": vector}
            return session.run(None, {name: feeds[name] for name in names})[0][:, 0]
        return one

    def chunk(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return model.predict(x, u[:, None], physics)[:, 0]
    return chunk


def bench_stepper(model: Any, inputs: np.ndarray, calls: int, period: float = 1e-3, *, noise: float = 1e-5,
                  seed: int = 0, buffers: bool = True, prepare: bool = True) -> LoopReport:
    """``calls`` control-loop calls of an :class:`~seqmotion.deploy.onnx_stepper.OnnxStepper` on ``model`` (an
    ``OnnxModel``) for the motion ``inputs``, paced at ``period``, one measured state per call (the robot:
    :func:`simulated_robot`, untimed, with measurement noise), motion after motion (each run into its stop for
    half a chunk, then the stepper is reset). Calls are named by kind: ``boundary`` (a chunk boundary inside the
    motion), ``between`` (between boundaries), ``final_chunk`` (the chunk where the motion ends: the stop is
    planned too), ``stop`` (past the end); the first call of each motion is not timed. ``prepare``: the stepper's
    ``prepare()`` after each call, timed apart (``LoopReport.after_ns``), as a loop runs it once its command went
    out. ``buffers=False``: every call through the shared ``StepperCore`` code (the general path every call took
    before)."""
    from .onnx_stepper import OnnxStepper

    gen = OnnxStepper(model, inputs)
    if not buffers:
        gen._fast = None
    c, length = gen.chunk, gen.length
    robot = simulated_robot(model)
    out = np.zeros((c, gen.accel_dim))
    rng = np.random.default_rng(seed)
    state = {"x": gen._x0.copy(), "measured": gen._x0.copy(), "n": gen.step_into(None, out)}
    last = (length - 2) // c

    def between(_: int) -> None:
        t = gen.time
        if t >= length - 1 + c // 2:  # well into the stop: the next motion
            gen.reset()
            state["x"] = gen._x0.copy()
            state["n"] = gen.step_into(None, out)
        else:
            state["x"] = robot(state["x"], out[:1])
        np.add(state["x"], noise * rng.standard_normal(state["x"].shape), out=state["measured"])

    between(0)

    def step(_: int) -> str:
        gen.step_into(state["measured"], out)
        t = gen.time
        if t >= length - 1:
            return "stop"
        if t // c == last:  # the outputs of the chunk in which the motion ends (its boundary's call too)
            return "final_chunk"
        return "boundary" if t % c == 0 else "between"
    return paced(step, calls, period, between, after=(lambda _: gen.prepare()) if prepare else None)


__all__ = ["LATE_US", "LoopReport", "Setup", "bench_stepper", "paced", "percentiles", "realtime", "simulated_robot",
           "trivial_call"]
