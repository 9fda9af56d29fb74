"""Property-based tests (Hypothesis) of the public API and the command line's input parsers (issue 19).

Every property is the same promise: for *any* input — arbitrary shapes and dtypes, NaN and inf,
extreme magnitudes, malformed files — a public entry point returns a valid, finite result or
raises ``ValueError`` (``CheckpointError`` is one) naming the problem. Never another exception,
never a NaN. The example counts are kept moderate (the whole file runs in well under a minute on two
cores); ``--hypothesis-show-statistics`` prints how many inputs each property tried.
"""

from __future__ import annotations

import io
import math
import os
import zipfile

import numpy as np
import pytest
import torch

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402

import seqmotion as sm  # noqa: E402
from seqmotion.io import parse_csv, read_trajectory  # noqa: E402
from seqmotion.tasks.pancake import physics as pancake_physics  # noqa: E402
from seqmotion.tasks.sliding import physics as sliding_physics  # noqa: E402

SCALE = float(os.environ.get("SEQMOTION_PROPERTY_SCALE", "1"))
"""Multiplies every property's example count (the default run tries 60 or 25 inputs per property)."""
_QUIET = [HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.filter_too_much]
FAST = settings(max_examples=round(60 * SCALE), deadline=None, suppress_health_check=_QUIET)
SLOWER = settings(max_examples=round(25 * SCALE), deadline=None, suppress_health_check=_QUIET)


@pytest.fixture(scope="module")
def motion(deformer):
    """A decoded pancake motion as torch ``(states (1, K, 6), accel (1, K-1, 3))``."""
    result = deformer.deform(sm.tasks.pancake.data.straight((0.05, 0.0, 1.0), 80))
    return torch.from_numpy(result.states)[None], torch.from_numpy(result.accel)[None]


def finite(*arrays) -> bool:
    return all(a is None or bool(np.all(np.isfinite(np.asarray(a, dtype=np.float64)))) for a in arrays)


# --- strategies ------------------------------------------------------------------------------------

SPECIAL = st.sampled_from([0.0, -0.0, 1.0, -1.0, 1e-300, 1e300, -1e300, 1e38, 3.4e38, float("nan"), float("inf"),
                           float("-inf"), 5e-324])
NUMBER = st.one_of(st.floats(allow_nan=True, allow_infinity=True), SPECIAL,
                   st.floats(-10, 10), st.integers(-(2**70), 2**70))
DTYPES = st.sampled_from([np.float64, np.float32, np.float16, np.int64, np.int8, np.uint8, np.bool_, np.complex128])


@st.composite
def arrays(draw, dims=(6,), max_k=120, allow_weird_shape=True, max_scale=1e200):
    """Mostly well-shaped trajectories (K up to max_k, last axis one of ``dims``), sometimes any shape;
    values in a physical range, sometimes extreme or non-finite; any numeric dtype."""
    if allow_weird_shape and draw(st.booleans()) and draw(st.booleans()):
        shape = draw(hnp.array_shapes(min_dims=0, max_dims=4, min_side=0, max_side=9))
    else:
        batch = draw(st.sampled_from([(), (), (1,), (2,), (3,)]))
        shape = (*batch, draw(st.integers(0, max_k)), draw(st.sampled_from(dims)))
    dtype = draw(DTYPES)
    scale = draw(st.sampled_from([s for s in (0.1, 1.0, 10.0, 1e6, 1e200) if s <= max_scale]))
    values = draw(hnp.arrays(np.float64, shape, elements=st.floats(-1, 1, allow_subnormal=False)))
    values = values * scale
    if values.size and draw(st.booleans()):
        flat = values.reshape(-1)
        special = SPECIAL.filter(lambda v: not abs(v) > max_scale or not math.isfinite(v))
        for _ in range(draw(st.integers(1, 3))):
            flat[draw(st.integers(0, flat.size - 1))] = draw(special)
    with np.errstate(all="ignore"):
        return values.astype(dtype)


ODD_OBJECTS = st.sampled_from([None, "states", b"\x00", {"a": 1}, [[1, 2], [3]], object(), [[None] * 6] * 3,
                               [["1", "2", "3", "4", "5", "6"]] * 4, torch.zeros(10, 6), torch.zeros(10, 6).half()])


def value_error_or(check):
    """Run ``check``: it returns normally (having asserted its result) or raises ValueError."""
    try:
        check()
    except ValueError:
        pass


# --- the model: generate, decode, the online generator ---------------------------------------------


@FAST
@given(data=st.one_of(arrays(dims=(6, 3, 4)), ODD_OBJECTS))
def test_deform_returns_a_finite_motion_or_raises(deformer, data):
    def check():
        result = deformer.deform(data)
        assert finite(result.states, result.accel, result.latent, result.violation)

    value_error_or(check)


@SLOWER
@given(data=st.one_of(arrays(dims=(4,), max_k=120), ODD_OBJECTS))
def test_generate_on_the_sliding_planner(planner, data):
    def check():
        result = planner.generate(data)
        assert finite(result.pan_states, result.rel_states)

    value_error_or(check)


@FAST
@given(latent=st.one_of(arrays(dims=(128, 64, 6), max_k=3), ODD_OBJECTS),
       x0=st.one_of(arrays(dims=(6, 4), max_k=3), ODD_OBJECTS),
       length=st.one_of(st.integers(-3, 400), st.sampled_from([10**7, 10**12, 2.5, "100", None, True])))
def test_decode(deformer, latent, x0, length):
    def check():
        result = deformer.decode(latent, x0, length)
        assert finite(result.states, result.accel)
        assert result.states.shape[-2] == length

    value_error_or(check)


def _step_through(deformer, measured) -> None:
    gen = deformer.generator(sm.tasks.pancake.data.straight((0.1, 0.0, 2.0), 300))
    first = gen.step()
    assert finite(first)
    for chunk in measured:
        try:
            out = gen.step(chunk)
        except ValueError:
            continue
        assert finite(out)


@SLOWER
@given(measured=st.lists(st.one_of(arrays(dims=(6, 3), max_k=60, max_scale=1e6), ODD_OBJECTS), min_size=1,
                         max_size=3))
def test_online_generator_steps(deformer, measured):
    _step_through(deformer, measured)


def test_online_generator_refuses_absurd_measured_states(deformer):
    gen = deformer.generator(sm.tasks.pancake.data.straight((0.1, 0.0, 2.0), 300))
    gen.step()
    for absurd in (1e300, 1e7):
        with pytest.raises(ValueError, match="magnitude"):
            gen.step(np.array([[absurd, 0, 0, 0, 0, 0]]))
    with pytest.raises(ValueError, match="complex"):
        gen.step(np.zeros((1, 6), dtype=complex))


# --- latent optimisation and objectives -------------------------------------------------------------


@SLOWER
@given(steps=st.one_of(st.integers(-2, 2), st.sampled_from([1.5, True, "2", None, 10**12])),
       lr=st.one_of(st.sampled_from(["auto", "fast", 0, -1.0, float("nan"), float("inf"), None, 1e300]),
                    st.floats(1e-6, 10.0)),
       init=st.one_of(st.sampled_from(["encoder", "random", "other", None]), arrays(dims=(128, 5), max_k=2)),
       optimizer=st.sampled_from(["auto", "sgd", "adam", "lm", "bfgs", None]),
       continuation=st.one_of(st.sampled_from([None, "auto", "off"]),
                              st.tuples(st.floats(allow_nan=True), st.integers(-3, 5))),
       seed=st.one_of(st.integers(-5, 2**70), st.just(1.5)),
       exact=st.sampled_from([False, True, 1, "yes"]))
@example(steps=0, lr="auto", init="encoder", optimizer="auto", continuation=None, seed=0, exact=True)  # always polish
def test_optimize_latent_arguments(deformer, steps, lr, init, optimizer, continuation, seed, exact):
    # 0.2 s: within the arm's limits (30 m/s², 300 rad/s²) and the cone this end pose is reachable; in 0.1 s it is
    # not, and the polish flags it (test_exact.py::test_exact_flags_an_unreachable_target)
    sketch = sm.tasks.pancake.data.straight((0.05, 0.0, 1.0), 200)

    def check():
        res = sm.optimize_latent(deformer, sketch, sm.objectives.EndPose((0.05, 0.0, 1.0)), steps=steps, lr=lr,
                                 init=init, optimizer=optimizer, continuation=continuation, seed=seed, exact=exact)
        assert finite(res.states, res.accel, res.latent, res.history)
        if exact is True:  # the polish reaches this easy target whatever the latent stage did
            assert res.exact and res.terms["end error"].value <= 1e-9

    value_error_or(check)


@FAST
@given(target=st.one_of(arrays(dims=(3, 2), max_k=3), ODD_OBJECTS), alpha=NUMBER,
       mu=st.one_of(st.none(), NUMBER), fields=st.sampled_from([None, ("y", "z"), ("y",), ("nope",), "yz", ()]),
       weights=st.one_of(st.none(), st.lists(NUMBER, max_size=3)))
def test_end_pose_objective(deformer, motion, target, alpha, mu, fields, weights):
    states, accel = motion

    def check():
        objective = sm.objectives.EndPose(target, alpha=alpha, mu=mu, fields=fields, weights=weights)
        bound = objective.bind(deformer)
        value = bound(states, accel)
        assert torch.isfinite(value).all()

    value_error_or(check)


@FAST
@given(p_lim=NUMBER, theta_end=NUMBER, theta_lim=NUMBER, alpha=NUMBER, beta=NUMBER,
       v_lim=st.one_of(st.lists(NUMBER, max_size=4), ODD_OBJECTS), mu=st.one_of(st.none(), NUMBER))
def test_ranges_objective(deformer, motion, p_lim, theta_end, theta_lim, alpha, beta, v_lim, mu):
    states, accel = motion

    def check():
        objective = sm.objectives.Ranges(p_lim, theta_end, theta_lim, alpha, beta, v_lim, mu)
        assert torch.isfinite(objective.bind(deformer)(states, accel)).all()

    value_error_or(check)


# --- physics -----------------------------------------------------------------------------------------


@FAST
@given(states=st.one_of(arrays(dims=(6, 3)), ODD_OBJECTS), accel=st.one_of(arrays(dims=(3, 6)), ODD_OBJECTS),
       mu=NUMBER)
def test_pancake_violation(states, accel, mu):
    def check():
        out = pancake_physics.violation(states, accel, mu)
        assert finite(out) and np.all(out >= 0)

    value_error_or(check)


def test_pancake_violation_refuses_a_string_mu():
    with pytest.raises(ValueError):
        pancake_physics.violation(np.zeros((3, 6)), np.zeros((2, 3)), "1")


@FAST
@given(pan_accel=st.one_of(arrays(dims=(2, 4), max_k=80), ODD_OBJECTS), mu=st.one_of(NUMBER, arrays(dims=(2,))),
       mu_dyn=NUMBER)
def test_sliding_rollout(pan_accel, mu, mu_dyn):
    def check():
        pan, rel = sliding_physics.rollout(pan_accel, mu, mu_dyn)
        assert finite(pan, rel)

    value_error_or(check)


@SLOWER
@given(command=st.one_of(arrays(dims=(4,), max_k=150, allow_weird_shape=False), ODD_OBJECTS),
       mu=st.one_of(st.none(), NUMBER), mu_dyn=st.one_of(st.none(), NUMBER))
def test_plan(planner, command, mu, mu_dyn):
    def check():
        plan = planner.plan(command, mu=mu, mu_dyn=mu_dyn)
        assert finite(plan.pan_states, plan.rel_states)

    value_error_or(check)


# --- the command line's input parsers ----------------------------------------------------------------

CSV_FIELD = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), st.integers().map(str),
                      st.sampled_from(["", " ", "y", "theta", "1e999", "0x10", "1_000", "١", "nan", "-inf", "1,",
                                       "\t3", "4 5", "1e", ".", "+", '"1"', "\x00"]))


@FAST
@given(rows=st.lists(st.lists(CSV_FIELD, min_size=0, max_size=7), max_size=12),
       newline=st.sampled_from(["\n", "\r\n", "\r"]))
def test_csv_text(rows, newline):
    text = newline.join(",".join(r) for r in rows)
    try:
        table = parse_csv(text)
    except ValueError:
        return
    assert table.ndim == 2 and table.shape[0] >= 1 and table.dtype == np.float64


@FAST
@given(blob=st.binary(max_size=400), suffix=st.sampled_from([".csv", ".npz"]))
def test_arbitrary_bytes_as_a_trajectory_file(tmp_path_factory, blob, suffix):
    path = tmp_path_factory.mktemp("bytes") / f"x{suffix}"
    path.write_bytes(blob)
    try:
        read_trajectory(path)
    except ValueError:
        pass


@st.composite
def npz_files(draw):
    """A real ``.npz`` (arrays of any dtype and shape, maybe not ``states``), possibly damaged."""
    names = draw(st.lists(st.sampled_from(["states", "accel", "x", "states.npy", "a/b"]), max_size=3, unique=True))
    buffer = io.BytesIO()
    arrays_ = {}
    for name in names:
        kind = draw(st.sampled_from(["float", "int", "str", "object", "complex", "empty", "scalar"]))
        if kind == "float":
            arrays_[name] = draw(arrays(dims=(6,), max_k=20))
        elif kind == "int":
            arrays_[name] = np.arange(draw(st.integers(0, 30))).reshape(-1, 1) * 10**draw(st.integers(0, 18))
        elif kind == "str":
            arrays_[name] = np.array(["a", "b"])
        elif kind == "object":
            arrays_[name] = np.array([None, 1], dtype=object)
        elif kind == "complex":
            arrays_[name] = np.ones((3, 6), dtype=np.complex64)
        elif kind == "empty":
            arrays_[name] = np.zeros((0, 6))
        else:
            arrays_[name] = np.float64(draw(st.floats()))
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, value in arrays_.items():
            inner = io.BytesIO()
            np.lib.format.write_array(inner, np.asanyarray(value), allow_pickle=True)
            archive.writestr(name if name.endswith(".npy") else f"{name}.npy", inner.getvalue())
    blob = buffer.getvalue()
    damage = draw(st.sampled_from(["none", "none", "truncate", "flip", "append"]))
    if damage == "truncate" and blob:
        blob = blob[: draw(st.integers(0, len(blob) - 1))]
    elif damage == "flip" and blob:
        i = draw(st.integers(0, len(blob) - 1))
        blob = blob[:i] + bytes([blob[i] ^ 0xFF]) + blob[i + 1:]
    elif damage == "append":
        blob += draw(st.binary(min_size=1, max_size=50))
    return blob


@FAST
@given(blob=npz_files())
def test_npz_variants(tmp_path_factory, deformer, blob):
    path = tmp_path_factory.mktemp("npz") / "x.npz"
    path.write_bytes(blob)
    try:
        states = read_trajectory(path)
    except ValueError:
        return
    assert isinstance(states, np.ndarray)

    def check():
        assert finite(deformer.deform(states).states)

    value_error_or(check)


@SLOWER
@given(rows=st.lists(st.lists(st.floats(-1, 1), min_size=6, max_size=6), min_size=0, max_size=40),
       header=st.sampled_from(["", "y,z,theta,v_y,v_z,v_theta\n", "# comment\n", "y,z\n"]))
def test_cli_deform_never_prints_a_traceback(tmp_path_factory, rows, header, capsys):
    from seqmotion.cli import main

    folder = tmp_path_factory.mktemp("cli")
    (folder / "in.csv").write_text(header + "\n".join(",".join(repr(v) for v in r) for r in rows))
    code = main(["deform", "--input", str(folder / "in.csv"), "--output", str(folder / "out.npz")])
    err = capsys.readouterr().err
    assert code in (0, 2) and "Traceback" not in err
    if code == 0:
        assert finite(np.load(folder / "out.npz")["states"])
    else:
        assert err.startswith("seqmotion deform: error: ") and err.count("\n") == 1


