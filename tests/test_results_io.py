"""Issue 32, item 11: results save and load as named arrays without pickle, plot themselves, and
``seqmotion --version`` prints the installed version."""

from __future__ import annotations

import dataclasses
import importlib.metadata
import io
import zipfile

import numpy as np
import pytest
from matplotlib.figure import Figure

import seqmotion as sm
from seqmotion.cli import main
from seqmotion.tasks.pancake import data as gen
from seqmotion.tasks.sliding import data as commands


def assert_same(a, b, where="result"):
    """Equal value by value, of the same type (arrays: dtype, shape and values)."""
    assert type(a) is type(b), f"{where}: {type(a).__name__} != {type(b).__name__}"
    if isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape, f"{where}: {a.dtype}{a.shape} != {b.dtype}{b.shape}"
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, dict):
        assert list(a) == list(b), where
        for key in a:
            assert_same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{where}[{i}]")
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


@pytest.fixture(scope="module")
def sketch():
    return gen.straight((0.1, 0.05, 1.0), 300)


@pytest.fixture(scope="module")
def results(deformer, planner, sketch):
    """One of each result kind: a deformed pancake motion (with keep_end's exact and length), a batch of
    two, a sliding plan and a latent optimisation (stages and terms)."""
    return {
        "deform": deformer.deform(sketch, keep_end=True),
        "deform batch": deformer.deform(np.stack([sketch, sketch[::-1].copy()])),
        "plan": planner.plan(commands.circle(0.05, 300)),
        "optimize": sm.optimize_latent(deformer, sketch, sm.objectives.EndPose((0.1, 0.0, 1.5)), steps=2),
    }


@pytest.mark.parametrize("kind", ["deform", "deform batch", "plan", "optimize"])
def test_every_result_round_trips_field_by_field(results, kind, tmp_path):
    result = results[kind]
    path = result.save(tmp_path / "result.npz")
    assert path == tmp_path / "result.npz"
    back = sm.load_result(path)
    assert type(back) is type(result)
    assert_same(result, back, kind)
    with np.load(path, allow_pickle=False) as saved:  # plain named arrays: readable without seqmotion or pickle
        assert "states" in saved.files or "pan_states" in saved.files
        assert not any(saved[name].dtype.hasobject for name in saved.files)
        if result.errors:
            assert {f"errors.{name}" for name in result.errors} <= set(saved.files)
        if result.ood_reasons is not None:
            assert saved["ood_reasons"].dtype.kind == "U"  # one JSON string array
        assert str(saved["result.class"]).endswith(type(result).__name__)


def test_optimization_stages_and_terms_come_back(results, tmp_path):
    res = results["optimize"]
    back = sm.load_result(res.save(tmp_path / "opt.npz"))
    assert res.stages and res.terms  # the test means something only if they are there
    assert back.describe() == res.describe() and back.met == res.met


def test_a_file_with_an_object_array_is_refused_by_name(results, tmp_path):
    path = results["deform"].save(tmp_path / "r.npz")
    with zipfile.ZipFile(path) as archive:  # the same file with one array replaced by a pickled object array
        members = {name: archive.read(name) for name in archive.namelist()}
    buffer = io.BytesIO()
    np.save(buffer, np.array([{"evil": 1}], dtype=object), allow_pickle=True)
    members["errors.shape_rmse_m.npy"] = buffer.getvalue()
    bad = tmp_path / "bad.npz"
    with zipfile.ZipFile(bad, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    with pytest.raises(ValueError, match=r"errors\.shape_rmse_m"):
        sm.load_result(bad)
    # what users wrote before save() existed: object arrays for the dicts, lists and Nones
    old = tmp_path / "vars.npz"
    np.savez(old, **vars(results["deform"]))
    with pytest.raises(ValueError, match="not a result saved by result.save"):
        sm.load_result(old)


def test_save_refuses_what_it_cannot_store_without_pickle(results, tmp_path):
    r = dataclasses.replace(results["deform"], errors={"note": object()})
    with pytest.raises(ValueError, match="errors.note"):
        r.save(tmp_path / "r.npz")
    with pytest.raises(ValueError, match=".npz"):
        results["deform"].save(tmp_path / "r.pkl")
    with pytest.raises(ValueError, match="does not exist"):
        sm.load_result(tmp_path / "missing.npz")


def test_plot_returns_a_figure_and_writes_a_png(results, tmp_path):
    fig = results["deform"].plot(tmp_path / "deform.png")
    assert isinstance(fig, Figure)
    assert (tmp_path / "deform.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert labels[-1] == "violation" and len(labels) >= 2
    # with its task known, the state fields are named and grouped by unit
    named = dataclasses.replace(results["deform"], task="pancake").plot()
    legends = {t.get_text() for ax in named.axes if ax.get_legend() for t in ax.get_legend().get_texts()}
    assert {"y", "z", "theta", "v_y"} <= legends
    assert {"m", "rad", "m/s", "rad/s", "violation"} <= {ax.get_ylabel() for ax in named.axes}
    plan = dataclasses.replace(results["plan"], task="sliding").plot(tmp_path / "plan.png")
    legends = {t.get_text() for ax in plan.axes if ax.get_legend() for t in ax.get_legend().get_texts()}
    assert {"pan_x", "x", "v_y"} <= legends and (tmp_path / "plan.png").is_file()
    assert isinstance(results["deform batch"].plot(), Figure) and isinstance(results["optimize"].plot(), Figure)


def test_version_prints_the_installed_version(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"seqmotion {importlib.metadata.version('seqmotion')}"


def test_one_motion_with_task_named_views(results, planner, deformer):
    """Every result is a Motion: code meant for any task reads ``motion().states``/``.accel``; the sliding plan's
    own names are views of them, and CSV/NPZ columns are named by the task's layouts."""
    from seqmotion.core.results import Motion, TrustSignals, View, columns_of

    plan = results["plan"]
    assert isinstance(plan, Motion) and plan.motion() is plan
    np.testing.assert_array_equal(plan.pan_states, plan.states[:, :4])
    np.testing.assert_array_equal(plan.rel_states, plan.states[:, 4:])
    np.testing.assert_array_equal(plan.pan_accel, plan.accel)
    columns, names = columns_of(plan, planner.state_layout, planner.accel_layout, planner.uncertainty_names)
    assert names["pan_states"] == ["pan_x", "pan_y", "pan_v_x", "pan_v_y"] and names["rel_states"][:2] == ["x", "y"]
    assert names["pan_accel"] == list(planner.accel_layout.names) and "states" not in columns
    assert names["uncertainty"] == ["std.x", "std.y"] and float(columns["physics.mu"]) == plan.physics.mu
    deformed = results["deform"]
    columns, names = columns_of(deformed, deformer.state_layout, deformer.accel_layout)
    assert names["states"] == list(deformer.state_layout.names) and names["accel"] == ["a_y", "a_z", "a_theta"]
    assert names["psi"] == ["psi"] and names["violation"] == ["violation"]

    @dataclasses.dataclass
    class Scores(TrustSignals):  # a result without a motion
        score: float

    with pytest.raises(ValueError, match="Scores holds no states and accel"):
        Scores(1.0).motion()
    with pytest.raises(ValueError, match="'states' or 'accel'"):
        View("torques")
    with pytest.raises(ValueError, match="stop"):
        View("states", 4, 2)


def test_a_plan_saved_with_its_views_as_fields_loads(results, tmp_path):
    """A sliding plan saved when ``pan_states``, ``rel_states`` and ``pan_accel`` were its fields comes back as
    the plan, its views joined into ``states`` and ``accel``."""
    import json

    plan = results["plan"]
    path = plan.save(tmp_path / "plan.npz")
    with np.load(path) as saved:
        arrays = {name: saved[name] for name in saved.files}
    layout = json.loads(str(arrays["result.layout"]))
    states, accel = arrays.pop("states"), arrays.pop("accel")
    arrays.update(pan_states=states[:, :4], rel_states=states[:, 4:], pan_accel=accel)
    fields = layout["fields"]
    del fields["states"], fields["accel"]
    for name in ("pan_accel", "pan_states", "rel_states"):
        fields[name] = {"array": name, "as": "ndarray"}
    arrays["result.layout"] = np.array(json.dumps(layout))
    old = tmp_path / "old.npz"
    np.savez(old, **arrays)
    back = sm.load_result(old)
    assert type(back) is type(plan)
    np.testing.assert_array_equal(back.states, plan.states)
    np.testing.assert_array_equal(back.accel, plan.accel)
    assert back.physics == plan.physics and back.errors.keys() == plan.errors.keys()
