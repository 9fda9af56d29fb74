"""A motion that keeps the pancake on but that a robot cannot execute gets a named answer: ``deform(robot=…)`` and
``seqmotion deform --robot`` judge its joint path (the simulator's IK, kinematics only) against the rated limits.
(With ``keep_end`` the UR5e's limits are kept by the polish itself: ``tests/test_planar_chain.py``.)"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import seqmotion as sm
from seqmotion.cli import main
from seqmotion.core.results import FEASIBLE_TOLERANCE
from seqmotion.errors import EXIT_INEXACT
from seqmotion.sim import robot_models as rb
from seqmotion.tasks.pancake import data as gen

pytest.importorskip("mink", reason="standard robot arms need mink (pip install 'seqmotion[robots]')")
needs_ur5e = pytest.mark.skipif(
    "ur5e" not in {r.name for r in rb.robots()},
    reason="no UR5e model here: robosuite's model files or Menagerie's universal_robots_ur5e are needed")

README_TURN = gen.straight((0.2, 0.0, 2.5), 500)
GENTLE = gen.straight((0.02, 0.0, 0.2), 800)


@pytest.fixture(scope="module")
def turn_on_ur5e(deformer):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = deformer.deform(README_TURN, robot="ur5e")  # the learned motion alone: no polish for the arm
    return result, [w for w in caught if issubclass(w.category, RuntimeWarning)]


@needs_ur5e
def test_the_learned_readme_turn_is_not_executable_on_the_ur5e(turn_on_ur5e):
    result, said = turn_on_ur5e
    check = result.robot_check
    assert bool(feasible_of_cone(result))  # the cone holds ...
    assert result.feasible is False  # ... but the UR5e would stop on it
    assert check.ok is False
    binding = check.binding
    assert binding.kind == "speed" and binding.share > 1
    assert binding.needed > binding.rated == pytest.approx(np.pi)
    duration = (len(result.states) - 1) * 1e-3
    assert check.duration == pytest.approx(duration)
    assert check.needed_duration >= binding.share * duration - 1e-9
    assert len(said) == 1 and binding.joint in str(said[0].message)
    assert str(said[0].message).startswith("not executable on ur5e")
    assert f"needs ≥ {check.needed_duration:.2f} s instead of {duration:.2f} s" in check.describe()


@needs_ur5e
def test_the_verdict_survives_save_and_load(turn_on_ur5e, tmp_path):
    result, _ = turn_on_ur5e
    loaded = sm.load_result(result.save(tmp_path / "r.npz"))
    assert loaded.feasible is False and loaded.robot_check.binding == result.robot_check.binding


@needs_ur5e
def test_a_gentle_motion_is_executable_on_the_ur5e(deformer):
    plain = deformer.deform(GENTLE, keep_end=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        result = deformer.deform(GENTLE, keep_end=True, robot="ur5e")
    check = result.robot_check
    assert check.ok is True and check.problem() is None
    assert result.feasible == plain.feasible
    assert check.speed_share.max() < 1 and check.time_scale == 1.0
    assert "acceleration" in check.unknown  # the UR5e's rated accelerations are not published: said, not assumed


def test_the_built_in_arm_says_its_limits_are_unknown(deformer):
    plain = deformer.deform(GENTLE)
    result = deformer.deform(GENTLE, robot="mh3f")
    check = result.robot_check
    assert check.ok is None and check.binding is None and check.needed_duration is None and check.lost is None
    assert {"speed", "range"} <= set(check.unknown)
    assert "unknown" in check.describe()
    assert result.feasible == plain.feasible  # unknown limits neither pass nor fail the motion


def test_a_motion_whose_stop_leaves_the_workspace_is_not_executable_even_with_unknown_limits(deformer):
    """The learned README turn ends at 2.9 m/s: the 0.1 s stop the simulator appends takes the spatula out of the
    built-in arm's workspace (out of its wrist's reach, then down to the table). Executing it says so, whatever the
    arm's unknown rated limits."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = deformer.deform(README_TURN, robot="mh3f")
    check = result.robot_check
    assert check.ok is False and result.feasible is False and "leaves the arm's workspace" in check.lost
    said = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert len(said) == 1 and said[0].startswith("not executable on mh3f") and "workspace" in said[0]


def test_a_batch_with_a_robot_is_refused(deformer):
    with pytest.raises(ValueError, match="one motion at a time"):
        deformer.deform(np.stack([GENTLE[:200], GENTLE[:200]]), robot="mh3f")


@needs_ur5e
def test_the_cli_exits_3_with_one_warning_line(tmp_path, capsys):
    np.savez(tmp_path / "in.npz", states=README_TURN)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # said once, in its own line, not as a Python warning too
        code = main(["deform", "--input", str(tmp_path / "in.npz"), "--output", str(tmp_path / "out.npz"),
                     "--robot", "ur5e"])
    err = capsys.readouterr().err
    assert code == EXIT_INEXACT
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("seqmotion deform: warning: not executable on ur5e")
    assert "_joint" in lines[0] and "needs ≥" in lines[0]
    assert sm.load_result(tmp_path / "out.npz").feasible is False


def test_the_cli_refuses_an_unknown_robot(tmp_path, capsys):
    np.savez(tmp_path / "in.npz", states=GENTLE)
    assert main(["deform", "--input", str(tmp_path / "in.npz"), "--output", str(tmp_path / "out.npz"),
                 "--robot", "no_such_arm"]) == 2
    assert "--robot no_such_arm" in capsys.readouterr().err
    assert not (tmp_path / "out.npz").exists()


def feasible_of_cone(result) -> bool:  # noqa: ANN001 - a DeformResult
    """The cone's verdict alone (what ``feasible`` was before a robot was checked)."""
    return bool(result.violation.max() <= FEASIBLE_TOLERANCE)


@needs_ur5e
def test_optimize_makes_the_motion_for_the_robot_and_says_when_it_cannot(tmp_path, capsys):
    """``seqmotion optimize --robot``: with --exact the polish keeps the UR5e's limits (exit 0, judged executable);
    the latent stage's motion alone spins the spatula past the wrist's rating (exit 3, one warning line)."""
    made = tmp_path / "made.npz"
    assert main(["optimize", "--target", "0.1", "0.1", "2.3", "--exact", "--robot", "ur5e", "--output",
                 str(made)]) == 0
    assert "executable on ur5e" in capsys.readouterr().out
    assert sm.load_result(made).feasible is True
    alone = tmp_path / "alone.npz"
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        code = main(["optimize", "--target", "0.1", "0.1", "2.3", "--robot", "ur5e", "--output", str(alone)])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == EXIT_INEXACT and sm.load_result(alone).feasible is False
    assert len(lines) == 1 and lines[0].startswith("seqmotion optimize: warning: not executable on ur5e")
