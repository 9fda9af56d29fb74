"""A new user's first hour (issue 32): what the CLI and the demo say matches what they did.

* plain ``seqmotion deform`` warns when the learned motion is not executable as is (ends away from the sketch,
  still moving) and points to ``--keep-end``; ``--keep-end`` does not warn (item 3);
* ``deform --plot`` writes the figure (item 11);
* the demo's snapshot rows are labelled with their run and agree with the lines it prints (item 6);
* ``reproduce ch5`` evaluates the shipped policy without training anything unless ``--retrain`` (which prints
  its estimated time first); ``--quick`` output says it is a smoke test (item 10).
"""

from __future__ import annotations

import functools
import json
import re

import numpy as np
import pytest

import seqmotion as sm
from seqmotion.cli import main


@pytest.fixture(scope="module")
def readme_sketch(tmp_path_factory):
    """The README's sketch, ``sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 500)``, as the CLI's input."""
    path = tmp_path_factory.mktemp("sketch") / "sketch.npz"
    np.savez(path, states=sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 500))
    return path


def test_plain_deform_says_it_is_not_executable_and_names_keep_end(readme_sketch, tmp_path, capsys):
    assert main(["deform", "--input", str(readme_sketch), "--output", str(tmp_path / "d.npz")]) == 0
    out = capsys.readouterr().out
    warnings = [line for line in out.splitlines() if line.startswith("warning:")]
    assert any(line.startswith("warning: end_position_error") for line in warnings), out  # 348 mm off
    assert any(line.startswith("warning: end_speed") for line in warnings), out  # at 2.9 m/s
    assert any("not executable as is" in line and "--keep-end" in line for line in warnings), out


def test_keep_end_deform_does_not_warn(readme_sketch, tmp_path, capsys):
    assert main(["deform", "--input", str(readme_sketch), "--output", str(tmp_path / "k.npz"), "--keep-end"]) == 0
    out = capsys.readouterr().out
    assert "ends exactly at the input's end pose" in out
    assert "warning" not in out, out


def test_pancake_tolerances_judge_the_end():
    task = sm.tasks.get("pancake")
    tol = task.tolerances(task.options(task.train_config("tiny")))
    assert {"max_violation_rad", "end_position_error_m", "end_speed_m_s"} <= set(tol)
    assert 0 < tol["end_speed_m_s"] < 2.9 and 0 < tol["end_position_error_m"] < 0.348  # the README's plain deform


def test_deform_plot_writes_the_figure(readme_sketch, tmp_path, capsys):
    png = tmp_path / "fig" / "deform.png"
    png.parent.mkdir()
    assert main(["deform", "--input", str(readme_sketch), "--output", str(tmp_path / "d.csv"),
                 "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in png.parent.iterdir()] == ["deform.png"]  # written atomically: no temporary left
    capsys.readouterr()
    # refused before the work: an unsupported type, and the input itself
    assert main(["deform", "--input", str(readme_sketch), "--output", str(tmp_path / "e.npz"),
                 "--plot", str(tmp_path / "e.txt")]) == 2
    assert "--plot" in capsys.readouterr().err
    assert main(["deform", "--input", str(readme_sketch), "--output", str(tmp_path / "e.npz"),
                 "--plot", str(readme_sketch)]) == 2
    assert not (tmp_path / "e.npz").exists()


def test_demo_snapshot_labels_agree_with_what_it_prints(tmp_path, capsys):
    pytest.importorskip("mujoco")
    from seqmotion.reproduce import demo

    labelled = demo._robot(tmp_path)
    out = capsys.readouterr().out
    if "(no snapshots:" in out:
        pytest.skip("no offscreen rendering here: no snapshots to label")
    assert (tmp_path / "robot_snapshots.png").stat().st_size > 0
    assert list(labelled) == ["sketch", "deformed", "keep_end"]
    for name, (title, labels) in labelled.items():
        printed = next(line.split(":", 1)[1].strip() for line in out.splitlines()
                       if line.strip().startswith(f"{name} ") or line.strip().startswith(f"{name}:"))
        assert title == f"{name}: {printed}"  # the row says which run it is, and what the demo says of it
        times = [float(re.match(r"t = ([\d.]+) s: (on|off)", label).group(1)) for label in labels]
        states = [re.match(r"t = [\d.]+ s: (on|off)", label).group(1) for label in labels]
        lost = re.search(r"lost contact at t = ([\d.]+) s", printed)
        for t, state, label in zip(times, states, labels, strict=True):
            if lost:  # off from the moment the demo says contact was lost
                assert state == ("off" if t >= float(lost.group(1)) - 0.005 else "on"), (name, label)
            elif "stopping" not in label:  # "stayed on" during the motion
                assert state == "on", (name, label)
        if lost:  # lost during the motion: its last frame shows the pancake off
            assert states[-1] == "off", (name, labels)
        assert not any("stopping" in label for label in labels)  # frames of the turn; the title says what came after


def test_snapshot_times_are_the_ones_the_arm_renders():
    pytest.importorskip("mujoco")
    from seqmotion.sim.arm import Media
    from seqmotion.sim.kinematics import planar_reference
    from seqmotion.sim.pancake import PancakeResult
    from seqmotion.sim.plots import snapshot_steps

    states = sm.tasks.pancake.data.straight((0.1, 0.0, 1.0), 300)
    ref = planar_reference(states, decel_time=0.1, hold_time=0.5)
    planned = Media.plan(ref, None, "x.png", 6, 30.0, 1.0, "front").snapshot_steps
    n = len(ref)
    result = PancakeResult(np.arange(n) * ref.dt, *([np.zeros((n, 6))] * 2), *([np.zeros(n)] * 3), 0.0, 0.0, 0.0,
                           0.0, False, None, False, True, True, np.zeros(0), np.zeros(6), 1.0, None, ref.n_motion)
    assert snapshot_steps(result, 6) == planned


@pytest.fixture
def unseen_only(tmp_path):
    """A ch5 work folder holding only the unseen images (short episodes): no training data, no models."""
    pytest.importorskip("seqmotion.lfd.env.pushing")
    from seqmotion.lfd.data import dataset
    from seqmotion.reproduce import ch5

    dataset.collect(tmp_path / "data_unseen", ["pairs_default"], seed=ch5.UNSEEN_SEED_OFFSET, duration=0.6,
                    per_position={"pairs_default": 1}, progress=False)
    return tmp_path


def _no_training(monkeypatch):
    from seqmotion.lfd import train

    def trainer(*args, **kwargs):
        raise AssertionError("reproduce ch5 trained a policy without --retrain")

    for name in ("train", "train_seqae", "train_cnn", "train_end_to_end"):
        if hasattr(train, name):
            monkeypatch.setattr(train, name, trainer)


def test_reproduce_ch5_uses_the_shipped_policy_and_trains_nothing(unseen_only, monkeypatch, capsys):
    from seqmotion.api import pretrained_dir
    from seqmotion.lfd import evaluation
    from seqmotion.reproduce import ch5

    _no_training(monkeypatch)
    monkeypatch.setattr(evaluation, "evaluate", functools.partial(evaluation.evaluate, duration=0.5))
    paths, missing = ch5.available_models(unseen_only / "models")
    assert paths == {ch5.SHIPPED_SLOT: pretrained_dir("pushing")} and ch5.SHIPPED_SLOT not in missing
    assert main(["reproduce", "ch5", "--out", str(unseen_only), "--quick"]) == 0
    out = capsys.readouterr().out
    assert "--retrain trains them (estimated" in out and "SMOKE TEST" in out
    assert not (unseen_only / "data").exists()  # no training data collected either
    summary = json.loads((unseen_only / "summary.json").read_text())
    assert summary["table5_2"]["proposed"]["smaller"]["n_trials"] == 6  # the shipped policy, evaluated
    assert summary["table5_2"]["end_to_end"]["smaller"] is None and summary["not_evaluated"]
    for table in ("table5_2.md", "table5_3.md"):
        text = (unseen_only / table).read_text()
        assert "SMOKE TEST" in text and "not evaluated (--retrain)" in text, table


def test_reproduce_ch5_retrain_prints_the_eta_before_training(tmp_path, monkeypatch, capsys):
    from seqmotion.reproduce import ch5

    def stop(*args, **kwargs):
        raise RuntimeError("stopped before the work")

    monkeypatch.setattr(ch5, "ensure_data", stop)
    with pytest.raises(RuntimeError, match="stopped before the work"):
        ch5.run(tmp_path, retrain=True)
    out = capsys.readouterr().out
    minutes = float(re.search(r"estimated (\d+) min", out).group(1))
    assert minutes > 55  # the 7 x 64 SeqAE alone: 2000 epochs at ~1.4 s
    assert main(["reproduce", "ch2", "--retrain", "--out", str(tmp_path / "ch2")]) == 2
