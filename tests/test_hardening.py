"""Hardening (issue 19): every bad input is a named error, nothing is lost when a write fails.

One test (or a few) per defect of the issue, each failing on the old behaviour. Training and run
directories are in ``test_hardening_training.py``, kills in ``test_kill.py``, property-based
tests in ``test_property.py``.
"""

from __future__ import annotations

import json
import math
import os
import resource
import shutil
import threading

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion.cli import main
from seqmotion.io import parse_csv, read_trajectory, write_arrays
from seqmotion.tasks.pancake import data as inputs
from seqmotion.tasks.sliding import data as commands
from seqmotion.training import checkpoint as ckpt


@pytest.fixture(scope="module")
def sketch():
    return inputs.straight((0.1, 0.0, 2.0), 150)


def no_temporaries(folder) -> bool:
    return not [p for p in folder.rglob("*") if ckpt.TEMP_MARK in p.name]


# --- 1. outputs are replaced atomically ------------------------------------------------------------


def test_a_failed_write_leaves_the_previous_output_intact(tmp_path, sketch, monkeypatch, capsys):
    """Item 1: the CLI wrote its outputs in place; a failure (or kill) mid-write lost the old result."""
    np.savez(tmp_path / "in.npz", states=sketch)
    out = tmp_path / "out.npz"
    assert main(["deform", "--input", str(tmp_path / "in.npz"), "--output", str(out)]) == 0
    good = out.read_bytes()

    def full_disk(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(ckpt.os, "fsync", full_disk)  # the temporary is written, flushing it fails
    for argv in (["deform", "--input", str(tmp_path / "in.npz"), "--output", str(out)],
                 ["plan", "--circle", "0.02", "--length", "200", "--output", str(out)],
                 ["optimize", "--target", "0.05", "0", "1", "--steps", "1", "--length", "150", "--output", str(out)]):
        assert main(argv) == 1
        assert "No space left on device" in capsys.readouterr().err
        assert out.read_bytes() == good, argv[0]
    assert no_temporaries(tmp_path)


def test_every_writer_goes_through_the_atomic_helper():
    """The systematic part of item 1: no module writes a file in place."""
    import re
    from pathlib import Path

    root = Path(sm.__file__).parent
    pattern = re.compile(r"np\.savez\(\s*(?!buffer)|np\.savetxt\(\s*(?!buffer)|\.savefig\(\s*(?!tmp)|"
                         r"\.write_text\(|\.write_bytes\(|open\([^)]*[\"'](?:w|a|wb|ab)[\"']|imageio\.imwrite\(\s*(?!tmp)|"
                         r"get_writer\(\s*(?!tmp)|h5py\.File\([^)]*[\"']w[\"']")
    allowed = {"io/__init__.py": {"wb", "xb"}, "training/loop.py": {"a"}}  # io/: the one atomic-write helper
    offenders = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel.startswith(("pretrained/", "deploy/")):
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if pattern.search(line) and not line.lstrip().startswith("#"):
                if rel in allowed and any(f'"{m}"' in line for m in allowed[rel]):
                    continue  # the helper itself; the metrics log appends rows (flushed one by one)
                if rel == "lfd/data/dataset.py" and "h5py.File(tmp" in line:
                    continue
                if rel == "training/pretrained.py" and "(tmp / CARD).write_bytes" in line:
                    continue  # inside a temporary directory that is renamed whole
                if rel == "lfd/data/lerobot.py" and ("(tmp / " in line or "path.write_text(json.dumps" in line):
                    continue  # a LeRobot folder is written inside a temporary directory renamed whole
                offenders.append(f"{rel}:{number}: {line.strip()}")
    assert not offenders, "\n".join(offenders)


def test_atomic_path_cleans_up_and_refuses_directories(tmp_path):
    target = tmp_path / "fig.png"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with ckpt.atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("the writer failed")
    assert target.read_bytes() == b"old" and no_temporaries(tmp_path)
    with ckpt.atomic_path(target) as tmp:
        assert tmp.suffix == ".png" and tmp.parent == tmp_path
        tmp.write_bytes(b"new")
    assert target.read_bytes() == b"new"
    with pytest.raises(ValueError, match="is a directory"):
        with ckpt.atomic_path(tmp_path):
            pass
    # a temporary a killed writer left behind is removed by the next write of that file
    orphan = tmp_path / f".fig{ckpt.TEMP_MARK}999999999-deadbeef.png"
    orphan.write_bytes(b"half")
    ckpt.atomic_write_bytes(target, b"newer")
    assert not orphan.exists() and target.read_bytes() == b"newer"


# --- 4.-6. arguments of objectives, physics and the online generator ----------------------------------


@pytest.mark.parametrize("make", [
    lambda: sm.objectives.EndPose((0.1, 0.0, 3.0), alpha=float("nan")),
    lambda: sm.objectives.EndPose((0.1, 0.0, 3.0), alpha=-1.0),
    lambda: sm.objectives.EndPose((0.1, 0.0, 3.0), mu=float("inf")),
    lambda: sm.objectives.EndPose((0.1, 0.0), fields=("y", "z"), weights=(1.0, float("nan"))),
    lambda: sm.objectives.EndPose((0.1, float("nan"), 3.0)),
    lambda: sm.objectives.EndPose("far"),
    lambda: sm.objectives.Ranges(v_lim=(float("nan"), 1, 1)),
    lambda: sm.objectives.Ranges(p_lim=float("inf")),
    lambda: sm.objectives.Ranges(mu=-1.0),
    lambda: sm.objectives.Ranges(theta_end="north"),
    lambda: sm.objectives.Ranges(v_lim=1.5),
])
def test_objectives_refuse_bad_weights(make):
    """Item 4: EndPose(alpha=nan) ran and returned an all-NaN history; Ranges accepted v_lim=(nan, 1, 1)."""
    with pytest.raises(ValueError):
        make()


@pytest.mark.parametrize("physics, name", [({"mu": -1.0}, "mu"), ({"mu": float("nan")}, "mu"),
                                           ({"mu": 0.5, "mu_dyn": 0.9}, "mu_dyn")])
def test_sliding_latent_optimisation_refuses_bad_friction(planner, physics, name):
    """Item 5: optimize_latent(sliding, ..., mu=-1) ran while plan() refused the same value."""
    objective = sm.objectives.Function(lambda s, a: (s[:, -1, :2] ** 2).sum(-1))
    with pytest.raises(ValueError, match=name):
        sm.optimize_latent(planner, commands.circle(0.05, 300), objective, steps=2,
                           physics=planner.physics.replace(**physics))
    with pytest.raises(ValueError, match=name):
        planner.plan(commands.circle(0.05, 300), **physics)


def test_generator_refuses_a_nan_or_misshaped_start(deformer, sketch):
    """Item 6: generator(latent=z, x0=NaN).step() returned NaN accelerations; x0 (2, 6) was accepted."""
    z = deformer.deform(sketch).latent
    with pytest.raises(ValueError, match="finite"):
        deformer.generator(latent=z, x0=np.full(6, np.nan))
    with pytest.raises(ValueError, match="x0"):
        deformer.generator(latent=z, x0=np.zeros((2, 6)))
    with pytest.raises(ValueError):
        deformer.decode(z, np.full(6, np.inf), 100)


# --- 7. CSV parsing --------------------------------------------------------------------------------


def test_a_typo_in_the_first_data_row_is_an_error_not_a_header(tmp_path, sketch, capsys):
    """Item 7: a typo in the first data row made it a 'header': 499 of 500 samples deformed, exit 0."""
    np.savetxt(tmp_path / "in.csv", sketch, delimiter=",", header="y,z,theta,v_y,v_z,v_theta", comments="")
    lines = (tmp_path / "in.csv").read_text().splitlines()
    assert len(read_trajectory(tmp_path / "in.csv")) == len(sketch)  # a header of names is skipped
    (tmp_path / "typo.csv").write_text("\n".join([lines[0], "0.0,0.0,O.0," + lines[1].split(",", 3)[3], *lines[2:]]))
    (tmp_path / "noheader.csv").write_text("\n".join(["0.0,0.0,O.0," + lines[1].split(",", 3)[3], *lines[2:]]))
    for name, line in (("typo.csv", 2), ("noheader.csv", 1)):
        assert main(["deform", "--input", str(tmp_path / name), "--output", str(tmp_path / "o.csv")]) == 2
        err = capsys.readouterr().err
        assert f"line {line}, column 3" in err and "'O.0' is not a number" in err
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize("text, match", [
    ("", "no data rows"), ("y,z\n", "no data rows"), ("1,2\n3\n", "line 2: 1 columns"),
    ("# comment\n\n1,2\n", None), ("1,2\n3,four\n", "line 2, column 2"), ("a,b\nc,d\n", "line 2, column 1"),
    ("nan,1\n", None), ("1;2\n3;4\n", "line 2, column 1"),
])
def test_csv_rules(text, match):
    if match is None:
        assert parse_csv(text).shape[0] == 1
    else:
        with pytest.raises(ValueError, match=match):
            parse_csv(text)


# --- 8. the CLI: 0 is a value ------------------------------------------------------------------------


def test_zero_is_a_value_not_not_given(tmp_path, capsys):
    """Item 8: `optimize --steps 0` ran 100 updates, `--lr 0` silently used the line search,
    `plan --circle 0` raised TypeError, `train --epochs 0` was ignored, `--max-steps 0` wrote nothing and exit 0."""
    out = tmp_path / "o.npz"
    argv = ["optimize", "--target", "0.05", "0", "1", "--steps", "0", "--length", "150", "--output", str(out)]
    assert main(argv) == 0
    assert np.load(out)["history"].shape == (1,)
    capsys.readouterr()
    cases = [
        (["optimize", "--target", "0.05", "0", "1", "--lr", "0", "--output", str(out)], "--lr must be > 0"),
        (["optimize", "--target", "0.05", "0", "1", "--steps", "-1", "--output", str(out)], "--steps"),
        (["plan", "--circle", "0", "--output", str(out)], "--circle"),
        (["plan", "--circle", "nan", "--output", str(out)], "--circle"),
        (["plan", "--circle", "0.05", "--length", "0", "--output", str(out)], "--length"),
    ]
    run = tmp_path / "run"
    for flags, name in ((["--epochs", "0"], "--epochs"), (["--max-steps", "0"], "--max-steps"),
                        (["--max-steps", "-5"], "--max-steps"), (["--batches-per-epoch", "0"], "--batches-per-epoch"),
                        (["--batch-size", "0"], "--batch-size"), (["--lr", "0"], "--lr"), (["--lr", "nan"], "--lr"),
                        (["--lr-final-fraction", "5"], "--lr-final-fraction"), (["--seed", "-1"], "--seed"),
                        (["--checkpoint-every", "0"], "--checkpoint-every")):
        cases.append((["train", "pancake", "--config", "tiny", "--out", str(run), "--quiet", *flags], name))
    for argv, expected in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith(f"seqmotion {argv[0]}: error: ") and expected in err and err.count("\n") == 1, err
    assert not run.exists(), "a refused training wrote nothing"


def test_plan_errors_name_the_command(tmp_path, capsys):
    """Item 12: `plan --command` overwrote the subcommand's name: errors printed `seqmotion None: …`."""
    assert main(["plan", "--command", str(tmp_path / "missing.npz"), "--output", str(tmp_path / "o.npz")]) == 2
    assert capsys.readouterr().err.startswith("seqmotion plan: error: ")


# --- 9. threads --------------------------------------------------------------------------------------


def test_latent_optimisation_never_touches_the_weights_flags(deformer, sketch):
    """Item 9: `_frozen` switched requires_grad off on the shared weights during optimisation (and two
    threads restored each other's False): now the flags are never touched."""
    seen = []

    def objective(states, accel):
        seen.append(all(p.requires_grad for p in deformer.model.parameters()))
        return (states[:, -1, :2] ** 2).sum(-1)

    sm.optimize_latent(deformer, sketch, objective, steps=2)
    assert seen and all(seen)
    assert all(p.grad is None for p in deformer.model.parameters())


def test_two_threads_optimising_one_model(deformer, sketch):
    target = sm.objectives.EndPose((0.05, 0.0, 2.0))
    alone = sm.optimize_latent(deformer, sketch, target, steps=3)
    results, errors = [], []

    def work():
        try:
            results.append(sm.optimize_latent(deformer, sketch, target, steps=3))
        except Exception as exc:  # pragma: no cover - reported below
            errors.append(exc)

    for _ in range(3):
        threads = [threading.Thread(target=work) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert all(p.requires_grad for p in deformer.model.parameters())
    assert not errors and len(results) == 6
    for res in results:  # the same answer as alone (threads share nothing but the weights)
        np.testing.assert_allclose(res.states, alone.states, rtol=0, atol=1e-9)


# --- 10.-11. configs -----------------------------------------------------------------------------------


def _model_dir(tmp_path, name, config, weights_from="pancake"):
    directory = tmp_path / name
    directory.mkdir()
    shutil.copyfile(sm.api.pretrained_dir(weights_from) / "model.safetensors", directory / "model.safetensors")
    (directory / "config.json").write_text(json.dumps(config))
    return directory


@pytest.mark.parametrize("value", [[], None, "x", 1, 2.5, True])
def test_a_config_that_is_not_an_object_is_a_checkpoint_error(tmp_path, value):
    """Item 10: config.json holding [], null, "x" or 1 raised AttributeError."""
    with pytest.raises(sm.CheckpointError, match="JSON object"):
        sm.load(_model_dir(tmp_path, "m", value))


def _edited(change):
    config = json.loads((sm.api.pretrained_dir("pancake") / "config.json").read_text())
    change(config)
    config["config_sha256"] = ckpt.config_digest(config)  # re-hashed after the edit: test the schema behind it
    return config


@pytest.mark.parametrize("change, match", [
    (lambda c: c["model"].update(hidden=20000), "do not fit"),
    (lambda c: c["model"].update(hidden=1e8), "hidden must be an integer"),
    (lambda c: c["model"].update(chunk=10**9), "chunk must be an integer"),
    (lambda c: c["model"].update(head_hidden=-5), "head_hidden"),
    (lambda c: c["model"].update(layers="2"), "layers"),
    (lambda c: c.update(task="sliding"), "task sliding"),
    (lambda c: c.update(task=["pancake"]), "task"),
    (lambda c: c["model"].update(output_scale=[0, 0, 0]), "output_scale"),
    (lambda c: c["model"].update(output_scale=[1, 1]), "output_scale"),
    (lambda c: c["model"].update(encoder_input_scale=[1e-300 * 0] * 6), "encoder_input_scale"),
    (lambda c: c["model"].update(sigma_min=-1), "sigma_min"),
    (lambda c: c["model"].update(sigma_min=float("nan")), "sigma_min"),
    (lambda c: c["model"].update(correlated_pairs=[[0, 7]]), "correlated pair"),
    (lambda c: c["model"].update(unknown=1), "unexpected keyword"),
    (lambda c: c.update(model=[1, 2]), "JSON object"),
    (lambda c: c.update(training=5), "training record"),
    (lambda c: c["training"].update(options={"mu": -1}), "mu"),
    (lambda c: c["training"].update(options=["mu"]), "options"),
])
def test_the_config_is_checked_before_anything_is_allocated(tmp_path, change, match):
    """Item 11: a 2 KB config with hidden=20000 made sm.load allocate 6.4 GB; hidden=1e8, chunk=1e9,
    head_hidden=-5 gave RuntimeError; relabelled weights loaded; output_scale=0, sigma_min=-1 or NaN passed."""
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(sm.CheckpointError, match=match):
        sm.load(_model_dir(tmp_path, "m", _edited(change)))
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200 * 1024  # kB: no big allocation


@pytest.mark.parametrize("change", [{"hidden": 20000}, {"layers": 500}, {"hidden": -3}])
def test_any_model_kind_is_checked_before_allocating(tmp_path, change):
    """The learning-from-demonstration policy too (a generic dry run on the meta device): hidden=20000 would
    allocate ~40 GB."""
    config = json.loads((sm.api.pretrained_dir("pushing") / "config.json").read_text())
    config["policy"]["seqae"].update(change)
    config["config_sha256"] = ckpt.config_digest(config)  # re-hashed: the sizes are what refuses it
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(sm.CheckpointError):
        sm.load(_model_dir(tmp_path, "m", config, weights_from="pushing"))
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200 * 1024


def test_the_config_is_covered_by_its_hash(tmp_path, deformer):
    saved = deformer.save_pretrained(tmp_path / "m")
    config = json.loads((saved / "config.json").read_text())
    assert config["config_sha256"] == ckpt.config_digest(config)
    assert isinstance(sm.load(saved), type(deformer))
    config["training"]["options"]["mu"] = 0.5  # a valid value, but not what the model was saved with
    (saved / "config.json").write_text(json.dumps(config))
    with pytest.raises(sm.CheckpointError, match="config_sha256"):
        sm.load(saved)
    # every shipped model carries a matching one (those from before the config hash were re-sealed with it)
    for name in sm.pretrained_models():
        shipped = json.loads((sm.api.pretrained_dir(name) / "config.json").read_text())
        assert shipped["config_sha256"] == ckpt.config_digest(shipped)
    sm.load_pretrained("sliding")
    sm.load_pretrained("pancake-end")


def _reseal(directory):
    """Re-hash a model directory's config for its (edited) weights, as a forger would: what is behind the
    hashes is tested."""
    config = json.loads((directory / "config.json").read_text())
    sealed = ckpt.seal_config(config, (directory / "model.safetensors").read_bytes())
    (directory / "config.json").write_text(json.dumps(sealed))


def test_corrupt_weights_are_refused(tmp_path):
    config = json.loads((sm.api.pretrained_dir("pancake") / "config.json").read_text())
    directory = _model_dir(tmp_path, "m", config)
    from safetensors.torch import load_file, save_file

    tensors = load_file(directory / "model.safetensors")
    next(iter(tensors.values())).view(-1)[0] = float("nan")
    save_file(tensors, directory / "model.safetensors")
    _reseal(directory)
    with pytest.raises(sm.CheckpointError, match="NaN"):
        sm.load(directory)
    (directory / "model.safetensors").write_bytes(b"\xff" * 8 + b"{}")
    _reseal(directory)
    with pytest.raises(sm.CheckpointError, match="not a readable safetensors"):
        sm.load(directory)


# --- 12. the rest -------------------------------------------------------------------------------------


def test_malformed_trajectory_files_are_value_errors(tmp_path, sketch):
    """Item 12: truncated npz, empty npz, .npy renamed .npz gave BadZipFile/EOFError/TypeError tracebacks."""
    np.savez(tmp_path / "good.npz", states=sketch)
    blob = (tmp_path / "good.npz").read_bytes()
    (tmp_path / "truncated.npz").write_bytes(blob[: len(blob) // 2])
    (tmp_path / "cut_tail.npz").write_bytes(blob[:-10])
    (tmp_path / "empty.npz").write_bytes(b"")
    np.save(tmp_path / "array.npy", sketch)
    shutil.copyfile(tmp_path / "array.npy", tmp_path / "renamed.npz")
    np.savez(tmp_path / "objects.npz", states=np.array([{"a": 1}], dtype=object))
    np.savez(tmp_path / "other.npz", motion=sketch)
    (tmp_path / "binary.csv").write_bytes(b"\x00\xff\xfe" * 10)
    (tmp_path / "folder.npz").mkdir()
    for name in ("truncated.npz", "cut_tail.npz", "empty.npz", "renamed.npz", "objects.npz", "other.npz",
                 "binary.csv", "folder.npz", "missing.npz", "good.txt"):
        with pytest.raises(ValueError, match=name.split(".")[0]):
            read_trajectory(tmp_path / name)
    np.testing.assert_array_equal(read_trajectory(tmp_path / "good.npz"), sketch)


def test_outputs_are_checked_before_the_work(tmp_path, sketch, capsys, monkeypatch):
    """Item 12: an unwritable --output/--plot/--json/--video failed only after all the work."""
    np.savez(tmp_path / "in.npz", states=sketch)
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    import seqmotion.api

    def no_work(*args, **kwargs):
        raise AssertionError("the work started before the output was checked")

    monkeypatch.setattr(seqmotion.api, "resolve_model", no_work)
    bad = str(blocker / "out.npz")
    cases = [
        (["deform", "--input", str(tmp_path / "in.npz"), "--output", bad], "--output"),
        (["deform", "--input", str(tmp_path / "in.npz"), "--output", str(tmp_path / "out.txt")], "unsupported"),
        (["deform", "--input", str(tmp_path / "in.npz"), "--output", str(tmp_path)], "directory"),
        (["plan", "--circle", "0.05", "--output", bad], "--output"),
        (["optimize", "--target", "0", "0", "1", "--output", bad], "--output"),
        (["optimize", "--target", "0", "0", "1", "--output", str(tmp_path / "o.npz"), "--plot", str(blocker / "p.png")],
         "--plot"),
        (["simulate", "pancake", "--trajectory", str(tmp_path / "in.npz"), "--json", str(blocker / "m.json")],
         "--json"),
        (["simulate", "pancake", "--trajectory", str(tmp_path / "in.npz"), "--video", str(tmp_path / "v.gif")],
         "--video"),
        (["simulate", "pancake", "--trajectory", str(tmp_path / "in.npz"), "--snapshots", str(blocker / "s.png")],
         "--snapshots"),
        (["train", "pancake", "--config", "tiny", "--out", str(blocker / "run")], "--out"),
        (["reproduce", "ch2", "--out", str(blocker / "r")], "--out"),
        (["demo", "--out", str(blocker / "d")], "--out"),
        (["export", str(tmp_path), "--name", "ok", "--to", str(blocker / "p")], "--to"),
        (["lfd", "evaluate", "--json", str(blocker / "e.json")], "--json"),
        (["lfd", "train", "--data", str(tmp_path), "--out", str(blocker / "o")], "--out"),
        (["lfd", "collect", "--out", str(blocker / "o")], "--out"),
    ]
    for argv, expected in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert expected in err and "Traceback" not in err, (argv, err)


def test_option_values_must_be_finite(capsys):
    """Item 12: `--set alpha_constraint=NaN` gave FloatingPointError in the first step."""
    for value in ("NaN", "Infinity", "-Infinity", "1e999", "true", '"high"', "[1]"):
        assert main(["train", "pancake", "--config", "tiny", "--set", f"alpha_constraint={value}"]) == 2
        assert "alpha_constraint" in capsys.readouterr().err


def test_a_dataset_without_its_groups_is_a_value_error(tmp_path):
    """Item 12: an h5 file without the `motions` group raised KeyError."""
    h5py = pytest.importorskip("h5py")
    from seqmotion.lfd.data.dataset import FORMAT, VERSION, load_dataset

    path = tmp_path / "motions.h5"
    with h5py.File(path, "w") as f:
        f.attrs.update(format=FORMAT, version=VERSION, complete=True)
    with pytest.raises(ValueError, match="motions"):
        load_dataset(path)
    (tmp_path / "junk.h5").write_bytes(b"not hdf5")
    with pytest.raises(ValueError, match="HDF5"):
        load_dataset(tmp_path / "junk.h5")


@pytest.mark.parametrize("name", [["pancake"], None, 3, {"pancake": 1}])
def test_load_pretrained_refuses_a_name_that_is_not_a_string(name):
    """Item 12: load_pretrained(["pancake"]) raised TypeError: unhashable."""
    with pytest.raises(ValueError, match="name"):
        sm.load_pretrained(name)
    with pytest.raises(ValueError):
        sm.load(name)


def test_simulation_times_are_bounded(sketch):
    """Item 12: run_pancake(hold_time=1e9) tried to allocate 7 TiB."""
    pytest.importorskip("mujoco")
    for kwargs in ({"hold_time": 1e9}, {"settle_time": float("inf")}, {"decel_time": -1.0}, {"hold_time": "1"},
                   {"video": "v.mp4", "fps": 1e9}):
        with pytest.raises(ValueError, match="time|fps"):
            sm.sim.run_pancake(sketch, **kwargs)
    with pytest.raises(ValueError, match="hold_time"):
        sm.sim.run_sliding(np.zeros((50, 4)), hold_time=61.0)


@pytest.mark.parametrize("name", ["../../x", "..", ".hidden", "a/b", "a\\b", "", "x" * 101, "sp ace", None, "é"])
def test_export_refuses_a_name_that_is_not_one_folder(tmp_path, deformer, name):
    """Item 12: export_pretrained(name="../../x") wrote outside pretrained/."""
    from seqmotion.training.pretrained import export_pretrained

    source = deformer.save_pretrained(tmp_path / "src")
    root = tmp_path / "deep" / "pretrained"
    with pytest.raises(ValueError, match="plain folder name"):
        export_pretrained(deformer, source, name, root)
    assert not (tmp_path / "x").exists() and not root.exists()
    target = export_pretrained(deformer, source, "pancake-copy", root)
    assert sorted(p.name for p in target.iterdir()) == ["MODEL_CARD.md", "config.json", "model.safetensors"]
    assert isinstance(sm.load(target), type(deformer)) and no_temporaries(root)


def test_errors_are_one_line_and_exit_2(tmp_path, capsys):
    """Every ValueError/CheckpointError is exit 2 and one line `seqmotion <command>: error: …`."""
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "config.json").write_text("[]")
    np.savez(tmp_path / "in.npz", states=np.zeros((10, 6)))
    for argv in (["deform", "--model", str(tmp_path / "bad"), "--input", str(tmp_path / "in.npz"),
                  "--output", str(tmp_path / "o.npz")],
                 ["simulate", "--model", str(tmp_path / "bad"), "--trajectory", str(tmp_path / "in.npz")],
                 ["lfd", "info", str(tmp_path / "none.h5")],
                 ["export", str(tmp_path / "bad"), "--name", "x", "--to", str(tmp_path / "p")],
                 ["export", str(tmp_path / "bad"), "--name", "x", "--metrics", str(tmp_path / "none.json")]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith(f"seqmotion {argv[0]}: error: ") and err.count("\n") == 1, err


def test_large_finite_inputs_are_refused_or_finite(deformer):
    """Extreme magnitudes give a finite motion or a ValueError, never NaN."""
    for scale in (1e3, 1e30, 1e300):
        motion = inputs.straight((0.1, 0.0, 2.0), 120) * scale
        try:
            result = deformer.deform(motion)
        except ValueError as exc:
            assert "NaN or inf" in str(exc)
        else:
            assert np.all(np.isfinite(result.states)) and np.all(np.isfinite(result.accel))


def test_fixed_lr_and_steps_types(deformer, sketch):
    objective = sm.objectives.EndPose((0.05, 0.0, 2.0))
    for kwargs in ({"steps": 1.5}, {"steps": True}, {"steps": -1}, {"lr": 0}, {"lr": float("nan")}, {"lr": "fast"},
                   {"lr": -1e-3}, {"steps": 10**9}):
        with pytest.raises(ValueError):
            sm.optimize_latent(deformer, sketch, objective, **kwargs)
    assert math.isfinite(sm.optimize_latent(deformer, sketch, objective, steps=0).history[0])


def test_write_arrays_round_trip_and_header(tmp_path):
    states = np.arange(12.0).reshape(4, 3)
    path = write_arrays(tmp_path / "x.csv", {"states": states, "accel": states[:-1, :2]}, {"states": ["a", "b", "c"]})
    table = read_trajectory(path)
    assert table.shape == (4, 5) and np.isnan(table[-1, -1])
    np.testing.assert_array_equal(table[:, :3], states)
    with pytest.raises(ValueError, match="nothing per-sample"):
        write_arrays(tmp_path / "y.csv", {"latent": np.float64(1.0)})
    assert torch.get_default_dtype() == torch.float32
    assert os.listdir(tmp_path) == ["x.csv"]
