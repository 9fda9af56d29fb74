"""A task from another installed package: found through the entry-point group, with zero edits to seqmotion.

The example package ``examples/tray`` (its own ``pyproject.toml``) is installed the way a user
would — ``pip install`` into a folder on ``sys.path`` — and then trained with ``seqmotion train``,
loaded with ``sm.load``, deformed, stepped online with measured states of its own size,
steered to an end point with Levenberg–Marquardt on a residual objective, and driven
through ``seqmotion deform`` / ``seqmotion optimize``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import install_example
from conftest import seqmotion_cli as seqmotion

import seqmotion as sm
from seqmotion import tasks
from seqmotion.physics.integrator import integrate_numpy
from seqmotion.tasks.sliding.physics import SlidingPhysics


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The example package installed into a fresh folder and put on the path (in-process and for subprocesses)."""
    yield from install_example("tray", tmp_path_factory)


@pytest.fixture(scope="module")
def run(installed, tmp_path_factory):
    _, env = installed
    out = tmp_path_factory.mktemp("tray") / "run"
    done = seqmotion(env, "train", "tray", "--config", "tiny", "--epochs", "20", "--batches-per-epoch", "5",
                     "--out", str(out), "--quiet", cwd=out.parent)
    assert done.returncode == 0, done.stderr
    return out


def test_the_plug_in_is_found_without_editing_seqmotion(installed):
    assert "tray" in tasks.names()
    _, env = installed
    listing = seqmotion(env, "train", "--help", cwd=Path.cwd())
    assert "tray" in listing.stdout
    # its options are typed and checked: an unknown option and a bad value are refused by name
    bad = seqmotion(env, "train", "tray", "--config", "tiny", "--set", "max_tilt_deg=120", cwd=Path.cwd())
    assert bad.returncode == 2 and "max_tilt_deg" in bad.stderr
    bad = seqmotion(env, "train", "tray", "--config", "tiny", "--set", "mu=0.5", cwd=Path.cwd())
    assert bad.returncode == 2 and "unknown option 'mu'" in bad.stderr


def test_load_deform_and_step_online_with_the_tasks_own_state(run):
    model = sm.load(run)
    assert model.task_def.name == "tray" and model.state_layout.names == ("x", "y", "v_x", "v_y")
    sketch = model.task_def.sketch((0.02, 0.01), 200)
    motion = model.generate(sketch)
    assert motion.states.shape == (200, 4) and motion.accel.shape == (199, 2)
    assert motion.violation.shape == (199,) and np.all(motion.violation >= 0)
    np.testing.assert_allclose(motion.states, integrate_numpy(sketch[0], motion.accel), atol=1e-9)
    # the online stepper reads measured (K, 4) tray states and reproduces generate exactly
    gen = model.generator(sketch)
    c = gen.chunk
    u, x = [gen.step()], sketch[0]
    for _ in range(3):
        states = integrate_numpy(x, u[-1])
        x = states[-1]
        u.append(gen.step(states[1:]))
    np.testing.assert_allclose(np.concatenate(u)[: 4 * c], motion.accel[: 4 * c], atol=1e-6)
    with pytest.raises(ValueError, match="4 columns"):
        gen.step(np.zeros((c, 6)))


def test_the_plug_in_exports_to_onnx_and_steps_past_its_end(run, tmp_path):
    pytest.importorskip("onnxruntime")
    from seqmotion.deploy import OnnxModel, OnnxStepper, export_onnx

    model = sm.load(run)
    export_onnx(model, tmp_path / "onnx")  # its constraint (atan(|a|/g) under 15°) goes into violation.onnx
    sketch = model.task_def.sketch((0.02, 0.01), 150)
    ref, mine = model.generate(sketch), OnnxModel(tmp_path / "onnx").generate(sketch)
    assert np.abs(mine["states"] - ref.states).max() <= 1e-4
    assert np.abs(mine["violation"] - ref.violation).max() <= 1e-4
    for gen in (model.generator(sketch), OnnxStepper(tmp_path / "onnx", sketch)):
        u, x, peak = gen.step(), sketch[0], 0.0
        while not gen.done:  # past K: brought to rest within the tilt limit
            assert gen.time < 150 + 5000, "never came to rest"
            if gen.stopping:
                peak = max(peak, np.abs(u).max())
            states = integrate_numpy(x, u)
            x = states[-1]
            u = gen.step(states[1:])
        assert np.abs(x[2:]).max() <= 1e-6 and np.all(u == 0) and np.degrees(np.arctan(peak / 9.8)) < 15


def test_lm_reaches_an_end_point_on_a_residual_objective(run):
    model = sm.load(run)
    sketch = model.task_def.sketch((0.02, 0.01), 200)
    target = torch.tensor(model.generate(sketch).states[-1, :2] + [0.005, -0.005])
    reach = sm.objectives.Function(residuals=lambda states, accel: states[:, -1, :2] - target)
    res = sm.optimize_latent(model, sketch, reach, steps=15, optimizer="lm")
    assert np.linalg.norm(res.states[-1, :2] - target.numpy()) < 1e-4  # from 7 mm
    # objectives of another task's layout, or physics parameters the task lacks, are refused by name
    with pytest.raises(ValueError, match="pancake state.*'tray' model"):
        sm.optimize_latent(model, sketch, sm.objectives.Ranges(), steps=1)
    with pytest.raises(ValueError, match="end pose is \\['x', 'y'\\]"):
        sm.optimize_latent(model, sketch, sm.objectives.EndPose((0.1, 0.05, 0.0)), steps=1)
    with pytest.raises(ValueError, match="runs at Physics"):
        sm.optimize_latent(model, sketch, reach, steps=1, physics=SlidingPhysics(mu=0.5))


def test_cli_deform_and_optimize_on_the_plug_in(installed, run, tmp_path):
    _, env = installed
    sketch = sm.load(run).task_def.sketch((0.02, 0.01), 150)
    np.savetxt(tmp_path / "path.csv", sketch, delimiter=",")
    done = seqmotion(env, "deform", "--model", str(run), "--input", "path.csv", "--output", "out.csv", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    header = (tmp_path / "out.csv").read_text().splitlines()[0]
    assert header.startswith("x,y,v_x,v_y,a_x,a_y")
    done = seqmotion(env, "optimize", "--model", str(run), "--target", "0.02", "0.01", "--length", "150", "--steps",
                     "3", "--output", "opt.npz", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert np.load(tmp_path / "opt.npz")["states"].shape == (150, 4)
    done = seqmotion(env, "simulate", "--model", str(run), "--trajectory", "out.csv", cwd=tmp_path)
    assert done.returncode == 2 and "'tray' model's task has no simulated scene" in done.stderr


def test_export_ships_the_model_with_the_plug_in(installed, run, tmp_path):
    target, env = installed
    done = seqmotion(env, "export", str(run), "--name", "tray-tiny", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert (target / "seqmotion_tray" / "pretrained" / "tray-tiny" / "MODEL_CARD.md").is_file()
    model = sm.load_pretrained("tray-tiny")
    assert model.task_def.name == "tray"
    assert "Machine:" in (target / "seqmotion_tray" / "pretrained" / "tray-tiny" / "MODEL_CARD.md").read_text()
