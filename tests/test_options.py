"""Typed task options: checked by name, saved with the model, and the one μ every consumer reads."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion import tasks
from seqmotion.cli import main
from seqmotion.tasks.pancake import PancakeOptions, physics
from seqmotion.tasks.pancake import data as gen
from seqmotion.tasks.sliding import SlidingOptions


@pytest.fixture(scope="module")
def run08(tmp_path_factory):
    out = tmp_path_factory.mktemp("mu08") / "run"
    assert main(["train", "pancake", "--config", "tiny", "--set", "mu=0.8", "--out", str(out), "--quiet"]) == 0
    return out


def test_options_refuse_unknown_keys_and_bad_values_by_name():
    with pytest.raises(ValueError, match="unknown option.*'mew'"):
        PancakeOptions.from_dict({"mew": 0.8})
    for bad in ({"mu": -1.0}, {"mu": float("nan")}, {"length": [500, 100]}, {"alpha_constraint": "big"}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            PancakeOptions.from_dict(bad)
    with pytest.raises(ValueError, match="mu_dyn"):
        SlidingOptions(mu=0.5, mu_dyn=0.7)
    with pytest.raises(ValueError, match="friction_pairs"):
        SlidingOptions(friction_pairs=[[0.5, 0.7]])
    assert PancakeOptions.from_dict({"mu": 0.8}).replace(alpha_shape=2.0).mu == 0.8


def test_cli_set_is_checked_against_the_options(capsys, tmp_path):
    assert main(["train", "pancake", "--config", "tiny", "--set", "mu=-0.5", "--out", str(tmp_path)]) == 2
    assert "mu" in capsys.readouterr().err
    assert main(["train", "pancake", "--config", "tiny", "--set", "friction=1", "--out", str(tmp_path)]) == 2
    assert "unknown option 'friction'" in capsys.readouterr().err


def test_a_model_trained_at_mu_08_is_judged_at_08_everywhere(run08, tmp_path, capsys, monkeypatch):
    model = sm.load(run08)
    assert model.options.mu == 0.8
    assert model.config["training"]["options"]["mu"] == 0.8  # saved with the model
    sketch = gen.straight((0.1, 0.0, 2.0), 120)
    r = model.deform(sketch)
    np.testing.assert_allclose(r.violation, physics.violation(r.states[:-1], r.accel, mu=0.8), atol=1e-12)
    # the cone at 0.8 (38.7°) is narrower than at 1 (45°): a motion with |ψ| between the two violates only at 0.8
    tilted = torch.zeros((1, 2, 6), dtype=torch.float64)
    tilted[..., 2] = math.radians(42.0)  # a still spatula tilted 42°: ψ = −42°
    still = torch.zeros((1, 1, 3), dtype=torch.float64)
    assert float(model.violation_torch(tilted, still)) == pytest.approx(math.radians(42.0) - math.atan(0.8))
    assert float(physics.violation_torch(tilted[:, :1, 2], still, 1.0)) == 0

    # objectives bound to the model take its μ
    states, accel = torch.from_numpy(r.states)[None], torch.from_numpy(r.accel)[None]
    bound = sm.objectives.EndPose((0.1, 0.0, 2.0)).bind(model)
    expected = physics.violation(r.states[:-1], r.accel, mu=0.8).sum()
    assert float(bound.penalty(states, accel)) == pytest.approx(expected, rel=1e-9)
    assert sm.objectives.Ranges().bind(model).mu == 0.8
    assert sm.objectives.EndPose((0.1, 0.0, 2.0), mu=1.0).bind(model).penalty(states, accel) <= expected
    assert model.physics.mu == 0.8  # the model's physics, resolved from its options
    with pytest.raises(ValueError, match="trained at"):  # its cone is the one it learned to keep
        sm.optimize_latent(model, sketch, sm.objectives.EndPose((0.1, 0.0, 2.0)), steps=1,
                           physics=model.physics.replace(mu=0.9))

    # the CLI prints F_c at the model's μ, and the plot's cone band is ±atan 0.8
    np.savez(tmp_path / "in.npz", states=sketch)
    assert main(["deform", "--model", str(run08), "--input", str(tmp_path / "in.npz"),
                 "--output", str(tmp_path / "out.npz")]) == 0
    assert "at mu = 0.8" in capsys.readouterr().out
    import matplotlib.figure

    saved = []
    def savefig(fig, path, *args, **kwargs):  # keep the figure; write a placeholder (outputs are renamed into place)
        saved.append(fig)
        Path(path).write_bytes(b"")

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", savefig)
    assert main(["optimize", "--model", str(run08), "--target", "0.05", "0", "1.0", "--steps", "1", "--length", "120",
                 "--output", str(tmp_path / "opt.npz"), "--plot", str(tmp_path / "opt.png")]) == 0
    assert "at mu = 0.8" in capsys.readouterr().out
    patch = saved[0].axes[1].patches[0]
    band = patch.get_patch_transform().transform(patch.get_path().vertices)[:, 1]  # data coordinates
    assert band.max() == pytest.approx(math.atan(0.8), rel=1e-6)
    assert band.min() == pytest.approx(-math.atan(0.8), rel=1e-6)


def test_tasks_registry_lists_builtin_tasks():
    assert {"pancake", "sliding", "pushing"} <= set(tasks.names())
    with pytest.raises(ValueError, match="unknown task"):
        tasks.get("nosuchtask")


def test_help_names_only_real_tasks():
    """``--help`` lists tasks without importing them; every name it lists must be a task (the task layer's
    helper modules, ``stepper`` and ``trust``, are not)."""
    from seqmotion.core.registry import declared_names

    assert set(declared_names()) <= set(tasks.names())
    assert {"pancake", "sliding"} <= set(declared_names())


def test_the_simulator_judges_at_the_models_mu(run08, tmp_path, capsys):
    pytest.importorskip("mujoco")
    still = np.zeros((300, 6))
    still[:, 2] = math.radians(42.0)  # held still at 42°: inside the cone at μ = 1, outside at 0.8
    np.savez(tmp_path / "still.npz", states=still)
    result = sm.sim.run_pancake(still, mu=sm.load(run08).options.mu, decel_time=0.01, hold_time=0.01)
    assert result.mu == 0.8 and np.median(result.executed_violation) > 0.03
    assert main(["simulate", "--trajectory", str(tmp_path / "still.npz"), "--model", str(run08),
                 "--json", str(tmp_path / "sim.json")]) == 0
    import json

    assert json.loads((tmp_path / "sim.json").read_text())["metrics"]["mu"] == 0.8
