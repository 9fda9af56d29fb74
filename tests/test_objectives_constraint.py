"""Issue 32 items 1 and 7: every objective keeps the task's constraint; Ranges and `optimize` on any task.

Item 1: a plain callable objective dropped the task's constraint — the pancake thrown at 9.7 m/s with the
spatula 2.4 rad outside the cone, ``res.terms == {}``, no warning. Now the task's constraint is a term of
every objective (a penalty in J, as in EndPose, and a reported term), the result carries ``violation``
per sample like ``Motion``, and a missed constraint is said in ``describe()`` and in a warning.

Item 7: ``Ranges`` took only the pancake's layout; ``seqmotion optimize`` defaulted to K = 500 whatever
the task (the tray-tiny model trained on K ≤ 200 warned out of distribution on the README's own example).
"""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion import tasks
from seqmotion.core.results import Motion
from seqmotion.latent.objectives import EndPose, Function, Ranges, TaskConstraint

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "tray"


def fast_end(states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
    """Rewards a large end speed [m²/s²]: its unconstrained optimum throws the pancake off."""
    return -(states[:, -1, 3:5] ** 2).sum(-1)


def _violation(model, res) -> np.ndarray:
    return model.violation_torch(torch.from_numpy(res.states)[None], torch.from_numpy(res.accel)[None])[0].numpy()


def test_a_function_objective_keeps_the_tasks_constraint(deformer):
    sketch = sm.tasks.pancake.data.straight((0.1, 0.0, 1.0), 300)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = sm.optimize_latent(deformer, sketch, fast_end, steps=10)
    # the result carries the constraint like a Motion does: per sample, and as a term of the objective
    assert isinstance(res, Motion)
    assert res.violation.shape == (299,)
    np.testing.assert_allclose(res.violation, _violation(deformer, res), atol=1e-12)
    assert "constraint" in res.terms
    assert res.terms["constraint"].value == pytest.approx(res.violation.max())
    # the constraint is in J, as in EndPose: J = f + α Σ_k F[k] with α = 1
    final = fast_end(torch.from_numpy(res.states)[None], None) + res.violation.sum()
    assert res.history[-1] == pytest.approx(float(final), rel=1e-6)
    # met, or said to be missed: in describe(), in res.met, res.feasible and a warning
    if res.terms["constraint"].met:
        assert res.feasible and "constraint:" in res.describe() and "met" in res.describe()
    else:
        assert not res.met and not res.feasible
        assert any(line.startswith("constraint:") and "MISSED" in line for line in res.describe().splitlines())
        assert any("constraint" in str(w.message) and issubclass(w.category, RuntimeWarning) for w in caught)


def test_the_constraint_penalty_is_weighed_or_dropped_on_request_and_never_counted_twice(deformer):
    sketch = sm.tasks.pancake.data.straight((0.1, 0.0, 1.0), 200)
    # weight 0: not penalised (the unconstrained optimum), still reported, and the miss is warned about
    with pytest.warns(RuntimeWarning, match="constraint"):
        free = sm.optimize_latent(deformer, sketch, Function(fast_end) + TaskConstraint(alpha=0), steps=10)
    assert not free.terms["constraint"].met and "MISSED" in free.describe()
    final = fast_end(torch.from_numpy(free.states)[None], None)
    assert free.history[-1] == pytest.approx(float(final), rel=1e-6)
    # a heavier weight keeps the cone better than none
    kept = sm.optimize_latent(deformer, sketch, Function(fast_end) + TaskConstraint(alpha=100.0), steps=10)
    assert kept.violation.max() < free.violation.max()
    # EndPose already penalises the constraint: a callable added to it does not add it a second time
    target = EndPose((0.1, 0.0, 1.0))
    res = sm.optimize_latent(deformer, sketch, target + (lambda s, a: 1e-6 * (a**2).mean((1, 2))), steps=3)
    s, a = torch.from_numpy(res.states)[None], torch.from_numpy(res.accel)[None]
    expected = target.bind(deformer)(s, a) + 1e-6 * (a**2).mean((1, 2))
    assert res.history[-1] == pytest.approx(float(expected), rel=1e-6)


def test_case_3_and_batches_carry_the_violation_too(deformer):
    starts = np.stack([sm.tasks.pancake.data.straight(t, 150) for t in ((0.1, 0.0, 1.0), (0.0, 0.1, -1.0))])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = sm.optimize_trajectory(deformer, starts, fast_end, steps=3)
    assert res.violation.shape == (2, 149) and res.terms["constraint"].value.shape == (2,)
    assert res.feasible.shape == (2,)


def test_the_cli_keeps_the_constraint_term(tmp_path):
    done = subprocess.run([sys.executable, "-m", "seqmotion.cli", "optimize", "--target", "0.1", "0.0", "1.0",
                           "--steps", "2", "--output", "out.npz"], cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "constraint:" in done.stdout
    assert np.load(tmp_path / "out.npz")["violation"].shape == (499,)  # the pancake trained on K ≤ 500


# --- item 7: a plug-in task (the example tray package, installed as a user would) -------------------------


@pytest.fixture(scope="module")
def tray(tmp_path_factory):
    """The tray plug-in installed into a fresh folder and a tiny model of it (as in test_plugin_task.py)."""
    target = tmp_path_factory.mktemp("site")
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--target",
                    str(target), str(EXAMPLE)], check=True, cwd=tmp_path_factory.mktemp("build"), capture_output=True)
    sys.path.insert(0, str(target))
    tasks.refresh()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(target), os.environ.get("PYTHONPATH", "")])}
    out = tmp_path_factory.mktemp("tray") / "run"
    done = subprocess.run([sys.executable, "-m", "seqmotion.cli", "train", "tray", "--config", "tiny", "--epochs",
                           "20", "--batches-per-epoch", "5", "--out", str(out), "--quiet"], env=env, cwd=out.parent,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    yield sm.load(out), out, env
    sys.path.remove(str(target))
    for name in [m for m in sys.modules if m.split(".")[0] == "seqmotion_tray"]:  # so the next install is imported
        del sys.modules[name]
    tasks.refresh()


def test_ranges_by_field_name_on_a_plug_in_task(tray):
    model, _, _ = tray
    sketch = model.task_def.sketch((0.02, 0.01), 150)
    bands = Ranges(end={"x": (0.004, 0.01), "y": (-0.005, 0.005)}, limits={"v_x": 0.4, "v_y": 0.4})
    before = sm.optimize_latent(model, sketch, bands, steps=0)
    assert set(before.terms) == {"end x band", "end y band", "limits", "constraint"}
    assert not before.terms["end x band"].met  # the tiny model's motion ends near x = 0, short of the band
    res = sm.optimize_latent(model, sketch, bands, steps=30)
    assert res.history[-1] < res.history[0]
    assert 0.004 - 1e-6 <= res.states[-1, 0] <= 0.01 and res.terms["end x band"].met
    # the terms read the returned motion: each band's excess, the limits', and the tilt limit at the model's options
    excess_y = max(-0.005 - res.states[-1, 1], res.states[-1, 1] - 0.005, 0.0)
    assert res.terms["end y band"].value == pytest.approx(excess_y, abs=1e-12)
    assert res.terms["limits"].value == pytest.approx(max(np.abs(res.states[1:, 2:]).max() - 0.4, 0.0), abs=1e-12)
    assert res.terms["constraint"].value == pytest.approx(res.violation.max())
    # names not in the task's layout, bad bands, and pancake-only arguments mixed in are refused by name
    with pytest.raises(ValueError, match="no column 'theta'.*'x', 'y', 'v_x', 'v_y'"):
        sm.optimize_latent(model, sketch, Ranges(end={"theta": (0.0, 1.0)}), steps=1)
    with pytest.raises(ValueError, match="low ≤ high"):
        Ranges(end={"x": (0.1, 0.0)})
    with pytest.raises(ValueError, match="limits"):
        Ranges(limits={"v_x": -1.0})
    with pytest.raises(ValueError, match="p_lim"):
        Ranges(p_lim=0.1, end={"x": (0.0, 0.1)})
    # the pancake's bands (no field names) still refuse it, and say how to give bands for it
    with pytest.raises(ValueError, match="pancake state.*'tray' model.*end="):
        sm.optimize_latent(model, sketch, Ranges(), steps=1)


def test_ranges_by_field_name_match_the_pancakes_own_on_its_layout(deformer):
    sketch = sm.tasks.pancake.data.straight((0.0, 0.0, -2.0), 300)
    named = Ranges(end={"theta": (-3.0, -2.0)}, limits={"v_y": 1.5, "v_z": 1.5, "v_theta": 4.5})
    res = sm.optimize_latent(deformer, sketch, named, steps=0)
    assert set(res.terms) == {"end theta band", "limits", "constraint"}
    j = named.bind(deformer)(torch.from_numpy(res.states)[None], torch.from_numpy(res.accel)[None])
    assert float(j) == pytest.approx(float(res.history[-1]), rel=1e-9)


def test_cli_optimize_defaults_to_the_tasks_own_length(tray, tmp_path):
    _, run, env = tray
    done = subprocess.run([sys.executable, "-m", "seqmotion.cli", "optimize", "--model", str(run), "--target", "0.02",
                           "0.01", "--steps", "2", "--output", "reach.npz"], env=env, cwd=tmp_path,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert np.load(tmp_path / "reach.npz")["states"].shape == (200, 4)  # tray-tiny trained on K in [100, 200]
    assert "out of distribution" not in done.stdout
    assert "constraint:" in done.stdout
    # --length is the default input's; with --input it would be ignored, so it is refused
    np.savetxt(tmp_path / "path.csv", np.zeros((50, 4)), delimiter=",")
    both = subprocess.run([sys.executable, "-m", "seqmotion.cli", "optimize", "--model", str(run), "--target",
                           "0.02", "0.01", "--input", "path.csv", "--length", "100", "--output", "x.npz"], env=env,
                          cwd=tmp_path, capture_output=True, text=True)
    assert both.returncode == 2 and "--length" in both.stderr
