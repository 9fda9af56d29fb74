"""A new user's verdicts on latent adjustment and the exact commands.

* ``Ranges`` bands and limits act on the columns they name in both stages — the latent updates and the exact
  polish — for every field and combination; ``res.exact`` True means the returned states meet them. (The
  polish's end bands read the limits' columns when both were given; with several end fields and a limit the
  NLP could not be built.)
* A limit alone leaves the end pose free: the polish may drop the turn, and the result says so
  (``res.end_shift``, a ``RuntimeWarning``) instead of returning a motion that no longer does the task silently.
* ``seqmotion deform --keep-end`` and ``seqmotion optimize --exact`` that cannot make the exact motion print
  one ``seqmotion <command>: warning:`` line (no Python warning text), write the result marked inexact and
  exit 3.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import seqmotion as sm
from seqmotion.cli import main
from seqmotion.latent.objectives import Ranges

FIELDS = ("y", "z", "theta", "v_y", "v_z", "v_theta")
# bands the README's sketch (to y 0.2 m, θ 2.5 rad in 0.5 s) can end in, each away from where its motion ends
BANDS = {"y": (0.10, 0.11), "z": (-0.02, 0.02), "theta": (2.4, 2.6), "v_y": (-0.05, 0.05), "v_z": (-0.05, 0.05),
         "v_theta": (-0.1, 0.1)}


@pytest.fixture(scope="module")
def sketch() -> np.ndarray:
    return sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 500)


def _assert_meets(res, end: dict, limits: dict) -> None:
    """The returned states meet every band and limit on the column of its name (1e-6: IPOPT's tolerance)."""
    names = list(FIELDS)
    for name, (low, high) in end.items():
        value = res.states[-1, names.index(name)]
        assert low - 1e-6 <= value <= high + 1e-6, (name, value, (low, high), res.states[-1])
    for name, limit in limits.items():
        peak = np.abs(res.states[1:, names.index(name)]).max()
        assert peak <= limit + 1e-6, (name, peak, limit)
    assert res.met, res.describe()


@pytest.mark.parametrize(("end", "limits"), [
    *[({name: BANDS[name]}, None) for name in FIELDS],
    ({"y": (0.10, 0.11)}, {"v_theta": 20.0}),  # the user's call: y missed its band, v_θ ended at 0.1
    (BANDS, None),  # all six: a raw NumPy broadcast error with a limit beside them
    (BANDS, {"v_y": 1.5}),
    ({"theta": (2.4, 2.6), "z": (-0.02, 0.02)}, {"v_y": 1.5, "v_z": 2.0, "y": 0.3}),
], ids=[*FIELDS, "y+limit", "all-six", "all-six+limit", "two+three-limits"])  # a limit alone: below
def test_ranges_fields_are_met_on_the_columns_they_name_when_exact(deformer, sketch, end, limits):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # fields left free may end elsewhere (tested below)
        res = sm.optimize_latent(deformer, sketch, Ranges(end=end, limits=limits), exact=True)
    assert res.exact is True, res.describe()
    _assert_meets(res, end or {}, limits or {})


def test_a_band_outside_the_same_fields_limit_is_refused_by_name():
    with pytest.raises(ValueError, match="'v_theta'.*outside its limit"):
        Ranges(end={"v_theta": (25.0, 30.0)}, limits={"v_theta": 20.0})
    Ranges(end={"v_theta": (15.0, 30.0)}, limits={"v_theta": 20.0})  # overlapping: both can hold


def test_a_limit_alone_is_optimised_without_the_exact_polish(deformer, sketch):
    """The limit already holds: the gradient is 0, and the line search's step doubled until it overflowed."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = sm.optimize_latent(deformer, sketch, Ranges(limits={"v_theta": 20.0}), steps=30)  # inf by update 26
    assert np.all(np.isfinite(res.states)) and np.all(np.isfinite(res.history)) and len(res.history) == 31
    assert np.abs(res.states[1:, 5]).max() <= 20.0


def test_the_result_says_when_the_objective_left_the_turn_behind(deformer, sketch):
    with pytest.warns(RuntimeWarning, match=r"theta.*2\.5"):
        res = sm.optimize_latent(deformer, sketch, Ranges(limits={"v_theta": 20.0}), exact=True)
    assert res.exact is True
    _assert_meets(res, {}, {"v_theta": 20.0})
    shift = res.end_shift["theta"]  # the task's turn, which the limit alone does not ask for
    assert shift.value == pytest.approx(abs(res.states[-1, 2] - 2.5), abs=1e-12)
    assert shift.value > shift.limit and not shift.met
    assert any(line.startswith("theta end, left free") and "NOT KEPT" in line for line in res.describe().splitlines())
    # a field the objective names is its business: only the others are compared with the input's end
    with pytest.warns(RuntimeWarning, match="no end value of y, z,"):  # the learned motion ends short of y, z
        named = sm.optimize_latent(deformer, sketch, Ranges(end={"theta": (2.4, 2.6)}, limits={"v_theta": 20.0}),
                                   steps=0)
    assert set(named.end_shift) == {"y", "z"}
    assert sm.optimize_latent(deformer, sketch, sm.objectives.EndPose((0.2, 0.0, 2.5)), steps=0).end_shift == {}


def test_deform_keep_end_that_cannot_be_exact_exits_3_with_one_warning_line(tmp_path, capsys):
    sketch = sm.tasks.pancake.data.straight((0.0, 0.0, 0.5), 100)
    sketch[:, 0] += 0.45  # starts beyond the polish's reach: no motion from there can be exact
    np.savez(tmp_path / "in.npz", states=sketch)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no Python warning reaches the user
        rc = main(["deform", "--input", str(tmp_path / "in.npz"), "--output", str(tmp_path / "out.npz"),
                   "--keep-end"])
    captured = capsys.readouterr()
    assert rc == 3, captured
    lines = [line for line in captured.err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("seqmotion deform: warning: "), captured.err
    assert "RuntimeWarning" not in captured.err + captured.out and "cli.py" not in captured.err
    assert "warning:" not in "\n".join(line for line in captured.out.splitlines() if "--keep-end" in line)
    saved = np.load(tmp_path / "out.npz")
    assert not bool(saved["exact"])  # written, marked inexact
    with pytest.raises(SystemExit):
        main(["deform", "--help"])
    assert "exit code 3" in " ".join(capsys.readouterr().out.split())


def test_optimize_exact_that_cannot_be_exact_exits_3_with_one_warning_line(tmp_path, capsys):
    out = tmp_path / "sink.npz"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rc = main(["optimize", "--target", "0.0", "-5.0", "0.0", "--length", "100", "--steps", "2", "--exact",
                   "--output", str(out)])  # 5 m down in 0.1 s: faster than the pancake can fall
    captured = capsys.readouterr()
    assert rc == 3, captured
    lines = [line for line in captured.err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("seqmotion optimize: warning: "), captured.err
    assert "RuntimeWarning" not in captured.err + captured.out
    assert not bool(np.load(out)["exact"])
    with pytest.raises(SystemExit):
        main(["optimize", "--help"])
    assert "exit code 3" in " ".join(capsys.readouterr().out.split())
