"""The ONNX stepper's control-loop calls: one measured state per call runs on buffers made once
(``OnnxStepper._fast_call``: bound sessions, windows as slices of a history, the plan's states predicted one per
call, the stop on buffers) and gives what the shared ``StepperCore`` code gives, bit for bit, without making an
array; ``step_into`` writes into the caller's array."""

from __future__ import annotations

import gc
import os
import tracemalloc

import numpy as np
import pytest
import torch

import seqmotion as sm

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from seqmotion.deploy import OnnxModel, OnnxStepper  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def _one_thread(one_thread):
    """torch on one thread (see conftest)."""


@pytest.fixture(scope="module")
def bundles(shipped_bundles):
    """The shipped pancake and sliding models exported (the session's, conftest)."""
    return shipped_bundles


def motion(name: str, k: int) -> np.ndarray:
    if name == "pancake":
        return sm.tasks.pancake.data.straight((0.15, -0.05, 2.0), k)
    return sm.tasks.sliding.data.circle(0.05, k)


def plant(model):  # noqa: ANN001, ANN201
    def step(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return model.integrate_torch(torch.from_numpy(x[None]), torch.from_numpy(u[None]))[0, 1:].numpy()
    return step


def counted(gen: OnnxStepper) -> list[int]:
    """Count the calls ``gen`` ran on its buffers (its ``_fast_call`` returned outputs)."""
    fast_call, calls = gen._fast_call, [0]

    def wrapper(measured, out):  # noqa: ANN001, ANN202
        n = fast_call(measured, out)
        calls[0] += n >= 0
        return n
    gen._fast_call = wrapper
    return calls


def drive(gens: list[OnnxStepper], model, k: int, extra: int, seed: int = 0,  # noqa: ANN001
          prepare: bool = False) -> list[list[np.ndarray]]:
    """The steppers fed the same measured states (the first one's outputs applied to the model's own dynamics, plus
    noise), one per call except a few calls of several; a latent swap (replay) and a restart on the way; ``extra``
    samples past the end. The first stepper is called through ``step_into``, the others through ``step``;
    ``prepare``: the first one's ``prepare()`` after two calls of three (and twice in a row now and then)."""
    robot, rng = plant(model), np.random.default_rng(seed)
    out = np.zeros((gens[0].chunk, gens[0].accel_dim))
    n = gens[0].step_into(None, out)
    outputs = [[out[:n].copy()], *([g.step()] for g in gens[1:])]
    x, call, other = gens[0]._x0[0].copy(), 0, None
    while gens[0].time < k + extra:
        u = outputs[0][-1]
        rows = 3 if call % 97 == 50 else 1  # now and then several states at once (the core's call)
        rows = min(rows, len(u))
        states = robot(x, u[:rows])
        x = states[-1]
        measured = states + 1e-4 * rng.standard_normal(states.shape)
        if call == 70:
            other = 0.97 * gens[0].latent
            for g in gens:
                g.set_latent(other)
        if call == 2 * k // 3:
            for g in gens:
                g.set_latent(other, restart=True, length=k // 2)
        n = gens[0].step_into(measured, out)
        outputs[0].append(out[:n].copy())
        for g, o in zip(gens[1:], outputs[1:], strict=True):
            o.append(g.step(measured))
        if prepare and call % 3:
            for _ in range(1 + (call % 11 == 1)):
                gens[0].prepare()
        call += 1
    return outputs


@pytest.mark.parametrize("name", ["pancake", "sliding"])
def test_the_control_loop_calls_give_the_cores_outputs_bit_for_bit(bundles, name):
    model = sm.load_pretrained(name)
    k = 3 * model.model.chunk + 20
    fast, core = OnnxStepper(bundles / name, motion(name, k)), OnnxStepper(bundles / name, motion(name, k))
    core._fast = None  # every call through StepperCore
    calls = counted(fast)
    mine, theirs = drive([fast, core], model, k, extra=2 * model.model.chunk + 7)
    assert len(mine) == len(theirs) and all(np.array_equal(a, b) for a, b in zip(mine, theirs, strict=True))
    # the control loop's calls ran on the buffers: all but the first, the few of several states and the restart
    assert calls[0] >= len(mine) - 8
    assert fast.stopping == core.stopping and fast.time == core.time
    torch_gen = model.generator(motion(name, k))
    again = OnnxStepper(bundles / name, motion(name, k))
    a, b = drive([again, torch_gen], model, k, extra=model.model.chunk)
    scale = np.asarray(model.model.cfg.output_scale)
    assert max(float((np.abs(p - q) / scale).max()) for p, q in zip(a[:-model.model.chunk], b, strict=False)) < 1e-2


@pytest.mark.parametrize("name", ["pancake", "sliding"])
def test_prepare_between_calls_leaves_one_decoder_run_per_call_and_the_same_outputs(bundles, name):
    model = sm.load_pretrained(name)
    k = 3 * model.model.chunk + 20
    fast, core = OnnxStepper(bundles / name, motion(name, k)), OnnxStepper(bundles / name, motion(name, k))
    core._fast = None
    runs = {"m": 0, "p": 0, "2": 0}

    def counting(bound, side: str):  # noqa: ANN001, ANN202
        def run() -> None:
            runs[side] += 1
            bound()
        return run

    fast._fast.decode_p = counting(fast._fast.decode_p, "p")
    fast._fast.decode2 = counting(fast._fast.decode2, "2")
    fast._fast.decode_m = [counting(bound, "m") for bound in fast._fast.decode_m]  # one per position
    calls = counted(fast)
    mine, theirs = drive([fast, core], model, k, extra=2 * model.model.chunk + 7, prepare=True)
    assert len(mine) == len(theirs) and all(np.array_equal(a, b) for a, b in zip(mine, theirs, strict=True))
    # prepared calls ran the measured window alone (B = 1), the others both windows at once (B = 2); a prepare is
    # wasted only before a call the core runs (several states, the latent swap, the restart)
    assert runs["m"] > model.model.chunk and runs["2"] > model.model.chunk // 2
    assert runs["m"] <= runs["p"] <= runs["m"] + len(mine) - calls[0]
    # a call after prepare holds one decoder run, the measured window's; prepare twice runs it once
    gen = OnnxStepper(bundles / name, motion(name, k))
    out = np.zeros((gen.chunk, gen.accel_dim))
    gen.step_into(None, out)
    gen.step_into(gen._x0.copy(), out)  # the core's first chunk, taken over
    seen = []
    def counting(bound, side: str):  # noqa: ANN001, ANN202
        def run() -> None:
            seen.append(side)
            bound()
        return run

    for side in ("decode_p", "decode2"):
        setattr(gen._fast, side, counting(getattr(gen._fast, side), side))
    gen._fast.decode_m = [counting(bound, "decode_m") for bound in gen._fast.decode_m]  # one per position
    gen.prepare()
    gen.prepare()
    assert seen == ["decode_p"] and gen._fast.prepared == 2
    gen.step_into(gen._x0.copy(), out)
    assert seen == ["decode_p", "decode_m"] and gen._fast.prepared == -1
    gen.step_into(gen._x0.copy(), out)  # not prepared: both windows in one run
    assert seen == ["decode_p", "decode_m", "decode2"]


def test_without_the_one_sample_graph_the_chunk_is_predicted_at_its_boundary(bundles):
    model = sm.load_pretrained("sliding")
    onnx = OnnxModel(bundles / "sliding")
    assert onnx.sample_session is not None and onnx.contract["files"]["dynamics_sample"] == "dynamics_sample.onnx"
    onnx.sample_session = None  # a bundle exported before the graph
    k = 2 * model.model.chunk + 10
    fast, core = OnnxStepper(onnx, motion("sliding", k)), OnnxStepper(bundles / "sliding", motion("sliding", k))
    core._fast = None
    assert fast._fast.chunk_prediction is not None
    mine, theirs = drive([fast, core], model, k, extra=5)
    assert all(np.array_equal(a, b) for a, b in zip(mine, theirs, strict=True))


def call_peaks(gen: OnnxStepper, calls: int) -> list[int]:
    """The memory Python allocates above its level before each of ``calls`` calls, at the call's peak (tracemalloc:
    NumPy's arrays and every Python object)."""
    out = np.zeros((gen.chunk, gen.accel_dim))
    measured = gen._x0.copy()
    gc.collect()
    gc.disable()
    tracemalloc.start()
    try:
        peaks = []
        for _ in range(calls):
            before = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            gen.step_into(measured, out)
            peaks.append(tracemalloc.get_traced_memory()[1] - before)
    finally:
        tracemalloc.stop()
        gc.enable()
    return peaks


@pytest.mark.parametrize("name", ["pancake", "sliding"])
def test_a_control_loop_call_makes_no_array(bundles, name):
    c = sm.load_pretrained(name).model.chunk
    peaks = {}
    for kind in ("buffers", "core"):
        gen = OnnxStepper(bundles / name, motion(name, 6 * c))
        if kind == "core":
            gen._fast = None
        out = np.zeros((c, gen.accel_dim))
        gen.step_into(None, out)
        for _ in range(c + 2):  # past the first chunk: every view made
            gen.step_into(gen._x0.copy(), out)
        peaks[kind] = call_peaks(gen, 2 * c)[1:]  # the first traced call pays tracemalloc's own start
    # onnxruntime's wrapper holds ~0.5 kB for a run and Python's integers a few bytes; an array of one chunk's
    # outputs alone is 112 + 8 C d bytes (1.3 kB for the pancake), a window 2.4 kB
    assert max(peaks["buffers"]) < 1024, max(peaks["buffers"])
    assert min(peaks["core"]) > 2048  # what the shared code makes per call (the test can tell)


def test_step_into_takes_only_an_array_it_can_write_whole(bundles):
    gen = OnnxStepper(bundles / "pancake", motion("pancake", 200))
    for bad in (np.zeros((50, 3), dtype=np.float32), np.zeros((49, 3)), np.zeros((50, 3, 1)),
                np.zeros((3, 50)).T, [[0.0] * 3] * 50):
        with pytest.raises(ValueError, match=r"out must be a writable C-contiguous float64 array of shape \(50, 3\)"):
            gen.step_into(None, bad)
    frozen = np.zeros((50, 3))
    frozen.flags.writeable = False
    with pytest.raises(ValueError, match="writable"):
        gen.step_into(None, frozen)
    out = np.full((50, 3), np.nan)
    assert gen.step_into(None, out) == 50 and np.all(np.isfinite(out))


@pytest.mark.parametrize("bad", [np.nan, np.inf, 2e6])
def test_a_bad_measurement_gets_the_cores_refusal_and_changes_nothing(bundles, bad):
    gen = OnnxStepper(bundles / "pancake", motion("pancake", 200))
    out = np.zeros((50, 3))
    gen.step_into(None, out)
    for _ in range(60):
        gen.step_into(gen._x0.copy(), out)
    before = (gen.time, out.copy())
    measured = gen._x0.copy()
    measured[0, 2] = bad
    with pytest.raises(ValueError, match="measured (contains NaN or inf|has a magnitude above)"):
        gen.step_into(measured, out)
    assert gen.time == before[0] and np.array_equal(out, before[1])
    n = gen.step_into(gen._x0.copy(), out)
    assert n == 50 - 11 and gen.time == 61


# --- the recipe: seqmotion.deploy.realtime and seqmotion bench-step -------------------------------------------


def test_the_realtime_setup_is_undone_on_exit():
    from seqmotion.deploy.realtime import realtime

    affinity, policy, gc_on = os.sched_getaffinity(0), os.sched_getscheduler(0), gc.isenabled()
    with realtime(cpu=-1, fifo=True, priority=10) as setup:
        assert os.sched_getaffinity(0) == {max(affinity)} and setup.cpu == max(affinity)
        assert not gc.isenabled() and setup.gc_disabled
        # SCHED_FIFO where this process may have it, else a note that says why not
        assert (setup.policy == "SCHED_FIFO" and os.sched_getscheduler(0) == os.SCHED_FIFO) or any(
            "SCHED_FIFO" in note for note in setup.notes)
        assert "SCHED_" in setup.describe() and setup.to_dict()["cpu"] == setup.cpu
    assert os.sched_getaffinity(0) == affinity and os.sched_getscheduler(0) == policy and gc.isenabled() == gc_on
    with pytest.raises(ValueError, match="priority must be 1 to 99"), realtime(priority=0):
        pass
    with pytest.raises(ValueError, match="is not one this process may run on"), realtime(cpu=10**6):
        pass
    assert os.sched_getaffinity(0) == affinity


def test_a_paced_loop_reports_every_call_by_kind():
    from seqmotion.deploy.realtime import paced

    seen = []
    report = paced(lambda i: seen.append(i) or ("even" if i % 2 == 0 else "odd"), calls=40, period=2e-4,
                   between=lambda i: None)
    stats = report.stats()
    assert seen == list(range(40)) and stats["calls"] == 40 and stats["even"]["calls"] == stats["odd"]["calls"] == 20
    assert report.wake_ns.shape == report.call_ns.shape == (40,) and np.all(report.call_ns >= 0)
    assert {"p50_us", "p99_us", "p99.9_us", "max_us"} <= set(stats["call"]) and "late_wakeups" in stats
    assert "woke more than 100 µs late" in report.summary()
    with pytest.raises(ValueError, match="calls >= 1 and a period > 0"):
        paced(lambda i: None, calls=0)


def test_bench_step_runs_the_stepper_in_a_paced_loop(bundles, tmp_path):
    import json

    from seqmotion.cli import main as cli_main

    out = tmp_path / "bench.json"
    assert cli_main(["bench-step", str(bundles / "pancake"), "--calls", "120", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    run = result["runs"]["normal"]
    assert result["task"] == "pancake" and run["calls"] == 120 and run["between"]["calls"] > 0
    assert run["trivial_onnxruntime_call"]["p50_us"] > 0 and run["setup"]["gc_disabled"]
    assert cli_main(["bench-step", str(bundles / "pancake"), "--calls", "0"]) == 2
