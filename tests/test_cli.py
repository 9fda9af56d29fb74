"""The command line mirrors the API: train, deform, plan, optimize; bad input → clear message, exit 2."""

import numpy as np
import pytest

from seqmotion.cli import main
from seqmotion.tasks.pancake import data as gen
from seqmotion.tasks.sliding import data as commands


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    assert main(["train", "pancake", "--config", "tiny", "--out", str(root / "pancake"), "--quiet"]) == 0
    assert main(["train", "sliding", "--config", "tiny", "--variant", "B", "--out", str(root / "sliding"),
                 "--quiet", "--epochs", "2", "--set", "pan_shaking=velocity", "--set", "length=[60, 90]"]) == 0
    return root


def test_set_takes_json_and_bare_words_for_text_options(runs, capsys):
    import seqmotion as sm

    config = sm.load(runs / "sliding").config
    assert config["training"]["options"]["pan_shaking"] == "velocity"
    assert config["training"]["options"]["length"] == [60, 90]
    assert main(["train", "sliding", "--config", "tiny", "--set", "pan_limit=far"]) == 2
    assert "not a JSON value" in capsys.readouterr().err


def test_train_writes_a_loadable_run_and_resumes(runs, capsys):
    assert (runs / "pancake" / "model.safetensors").is_file()
    assert (runs / "pancake" / "metrics.csv").is_file()
    # running the same command again resumes (nothing left to do) rather than starting over
    assert main(["train", "pancake", "--config", "tiny", "--out", str(runs / "pancake"), "--quiet"]) == 0


def test_deform_csv_round_trip(runs, tmp_path, capsys):
    sketch = gen.straight((0.1, 0.0, 2.0), 150)
    np.savetxt(tmp_path / "in.csv", sketch, delimiter=",", header="y,z,theta,vy,vz,vtheta", comments="")
    assert main(["deform", "--model", str(runs / "pancake"), "--input", str(tmp_path / "in.csv"),
                 "--output", str(tmp_path / "out.npz")]) == 0
    out = np.load(tmp_path / "out.npz")
    assert out["states"].shape == (150, 6) and out["accel"].shape == (149, 3)
    assert "max constraint violation" in capsys.readouterr().out  # the task-generic wording (F_c is the pancake's)


def test_deform_keep_end_says_when_the_end_pose_is_out_of_reach(runs, tmp_path, capsys):
    np.savez(tmp_path / "in.npz", states=gen.straight((0.0, -0.42, 0.0), 200))  # 0.42 m down: beyond the reach
    # not the exact motion asked for: written marked inexact, one warning line (no Python warning), exit code 3
    assert main(["deform", "--model", str(runs / "pancake"), "--input", str(tmp_path / "in.npz"),
                 "--output", str(tmp_path / "out.npz"), "--keep-end"]) == 3
    captured = capsys.readouterr()
    assert "ends at rest as near it as they allow" in captured.out
    assert captured.err.startswith("seqmotion deform: warning: ") and "as near as they allow" in captured.err
    assert not bool(np.load(tmp_path / "out.npz")["exact"])
    states = np.load(tmp_path / "out.npz")["states"]
    np.testing.assert_allclose(states[-1, 3:], 0.0, atol=1e-7)
    assert np.hypot(states[:, 0], states[:, 1]).max() <= 0.40 + 1e-6


def test_plan_and_optimize(runs, tmp_path):
    np.savez(tmp_path / "cmd.npz", states=commands.circle(0.02, 200))
    assert main(["plan", "--model", str(runs / "sliding"), "--command", str(tmp_path / "cmd.npz"),
                 "--output", str(tmp_path / "plan.csv")]) == 0
    table = np.loadtxt(tmp_path / "plan.csv", delimiter=",", skiprows=1)
    assert table.shape[0] == 200
    assert main(["optimize", "--model", str(runs / "pancake"), "--target", "0.05", "0", "1.0", "--steps", "2",
                 "--lr", "0.5", "--output", str(tmp_path / "opt.npz"), "--plot", str(tmp_path / "opt.png")]) == 0
    assert np.load(tmp_path / "opt.npz")["history"].shape == (3,)
    assert (tmp_path / "opt.png").stat().st_size > 0


def test_bad_input_gives_a_message_not_a_traceback(runs, tmp_path, capsys):
    np.savetxt(tmp_path / "bad.csv", np.zeros((10, 4)), delimiter=",")
    code = main(["deform", "--model", str(runs / "pancake"), "--input", str(tmp_path / "bad.csv"),
                 "--output", str(tmp_path / "x.npz")])
    assert code == 2 and "6 columns" in capsys.readouterr().err
    # deform is task-generic: the sliding model reads 4 columns (object x, y, v_x, v_y) and refuses 6
    np.savetxt(tmp_path / "six.csv", np.zeros((10, 6)), delimiter=",")
    code = main(["deform", "--model", str(runs / "sliding"), "--input", str(tmp_path / "six.csv"),
                 "--output", str(tmp_path / "x.npz")])
    assert code == 2 and "4 columns" in capsys.readouterr().err
    # objectives refuse another task's layout by name
    code = main(["optimize", "--model", str(runs / "sliding"), "--preset", "j2", "--input", str(tmp_path / "bad.csv"),
                 "--output", str(tmp_path / "x.npz")])
    err = capsys.readouterr().err
    assert code == 2 and "pancake state" in err and "'sliding' model" in err
    assert main(["train", "pushing", "--config", "tiny"]) == 2
    assert "seqmotion lfd train" in capsys.readouterr().err
    assert main(["train", "nosuchtask", "--config", "tiny"]) == 2
    assert "unknown task" in capsys.readouterr().err
    assert main(["train", "pancake", "--config", "huge"]) == 2


def test_deform_csv_columns_are_named_by_the_task(runs, tmp_path):
    sketch = gen.straight((0.1, 0.0, 2.0), 80)
    np.savez(tmp_path / "in.npz", states=sketch)
    assert main(["deform", "--model", str(runs / "pancake"), "--input", str(tmp_path / "in.npz"),
                 "--output", str(tmp_path / "out.csv")]) == 0
    header = (tmp_path / "out.csv").read_text().splitlines()[0].split(",")
    assert header[:9] == ["y", "z", "theta", "v_y", "v_z", "v_theta", "a_y", "a_z", "a_theta"]
    assert "violation" in header and "psi" in header


def test_train_help_lists_the_tasks(capsys):
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    out = capsys.readouterr().out
    assert "pancake" in out and "sliding" in out


def test_demo_runs_on_the_shipped_models(tmp_path, capsys):
    """`seqmotion demo` — the README's first command — end to end, the arm included."""
    pytest.importorskip("mujoco")
    assert main(["demo", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "deformed" in out and "Sliding" in out and "pancake stayed on" in out
    assert "end exactly at the sketch's end" in out  # keep_end
    keep_end = next(line for line in out.splitlines() if line.strip().startswith("keep_end"))
    assert "pancake stayed on" in keep_end  # executed on the arm, inside its workspace (else run_pancake refuses)
    assert (tmp_path / "fig2_5_deformation.png").stat().st_size > 0
