"""A robot's rated limits as data with their sources, and runs that report them honestly: peaks as shares of each
limit, the worst crossing named, unknown limits said to be unknown; and a pancake run described by its task."""

from __future__ import annotations

import json
import math
import os
import re

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo is first imported: offscreen rendering

from seqmotion.sim import robot_models as rb  # noqa: E402
from seqmotion.sim import run_pancake  # noqa: E402
from seqmotion.tasks.pancake.data import straight  # noqa: E402

ROBOSUITE = rb.robosuite_root()
try:
    import mink  # noqa: F401
except ImportError:  # pragma: no cover - the robots extra is missing
    HAVE_MINK = False
else:
    HAVE_MINK = True
needs_robots = pytest.mark.skipif(
    ROBOSUITE is None or not (ROBOSUITE / "ur5e" / "robot.xml").is_file() or not HAVE_MINK,
    reason="needs robosuite's robot files and mink (pip install 'seqmotion[robots]' && "
           "pip install --no-deps 'robosuite>=1.5,<1.6')",
)
SPIN = (0.2, 0.0, 2.5)  # the README's turn: 2.5 rad in 0.5 s, several times a UR5e wrist's rated π rad/s


def smooth_shift(dy: float, duration: float, k: int) -> np.ndarray:
    """Planar spatula states ``(k, 6)``: a rest-to-rest cosine move of ``dy`` [m] along y in ``duration`` [s]."""
    t = np.arange(k) * 1e-3
    s = np.clip(t / duration, 0.0, 1.0)
    states = np.zeros((k, 6))
    states[:, 0] = dy * (1 - np.cos(np.pi * s)) / 2
    states[:, 3] = np.where(t < duration, dy * np.pi / (2 * duration) * np.sin(np.pi * s), 0.0)
    return states


@pytest.fixture(scope="module")
def ur5e_spin():
    """The README's fast turn on the UR5e (its wrist_3 spins the spatula)."""
    return run_pancake(straight(SPIN, 500), robot="ur5e", hold_time=0.1)


@pytest.fixture(scope="module")
def built_in_hold():
    """A gentle move on the built-in arm that ends tilted 0.4 rad (23°): the pancake can rest there."""
    return run_pancake(straight((0.05, 0.03, 0.4), 150), hold_time=0.05)


# --- limits as data ------------------------------------------------------------------------------------------------


@needs_robots
def test_a_robot_carries_its_limits_with_their_sources():
    ur5e, panda = rb.get_robot("ur5e"), rb.get_robot("panda")
    limits = ur5e.limits
    assert limits.joints == ur5e.joints and limits.robot == "ur5e (robosuite)"
    np.testing.assert_array_equal(limits.position, ur5e.joint_range)
    np.testing.assert_array_equal(limits.torque, ur5e.torque_limit)
    np.testing.assert_allclose(limits.velocity, np.radians(180.0))  # every UR5e joint: ±180°/s
    assert "Universal Robots UR5e" in limits.sources["velocity"]
    assert limits.sources["position"].startswith("model file") and limits.sources["torque"].startswith("model file")
    # UR publishes no joint accelerations in the document cited: unknown, with why, not a guess.
    assert limits.acceleration is None and limits.unknown("acceleration").startswith("rated accelerations unknown")
    np.testing.assert_allclose(panda.limits.acceleration, [15, 7.5, 10, 12.5, 15, 20, 20])  # Franka's q̈_max
    assert "Franka" in panda.limits.sources["acceleration"]
    json.dumps(limits.summary(), allow_nan=False)


def test_the_built_in_arms_limits_are_unknown_and_say_why():
    limits = rb.built_in_limits()
    assert limits.robot == "mh3f (seqmotion)"
    for kind in rb.LIMIT_KINDS:
        assert not limits.known(kind) and "MOTOMAN-MH3F" in limits.unknown(kind)
    assert limits.unknown("velocity").startswith("rated speeds unknown for mh3f")


def test_limits_that_do_not_add_up_are_refused_by_name():
    sources = {kind: "unknown: not published" for kind in rb.LIMIT_KINDS}
    with pytest.raises(ValueError, match="rated speeds must have shape"):
        rb.JointLimits("arm (x)", ("a", "b"), None, np.ones(3), None, None, sources)
    with pytest.raises(ValueError, match="rated speeds must be finite and positive"):
        rb.JointLimits("arm (x)", ("a", "b"), None, np.array([1.0, 0.0]), None, None, sources)
    with pytest.raises(ValueError, match="does not start with 'unknown: '"):
        rb.JointLimits("arm (x)", ("a",), None, None, None, None, {**sources, "torque": "datasheet"})


# --- honest reports ------------------------------------------------------------------------------------------------


@needs_robots
def test_a_slow_motion_keeps_every_share_below_one():
    r = run_pancake(smooth_shift(0.03, 0.3, 350), robot="ur5e", hold_time=0.05)
    j = r.joints
    for share in (j.speed_share, j.torque_share, j.range_share):
        assert share.shape == (6,) and np.all(np.isfinite(share)) and np.all(share < 1)
    assert np.all(j.speed_share > 0)  # it moved
    np.testing.assert_allclose(j.speed_share, j.speed_peak / np.radians(180.0))
    assert j.problem is None and j.crossings == () and j.ok is True and j.unknown == {}
    summary = r.summary()
    json.dumps(summary, allow_nan=False)
    assert summary["speed_share"] == pytest.approx(list(j.speed_share), abs=1e-4)
    assert summary["limits_unknown"] == {} and "Universal Robots" in summary["limit_sources"]["velocity"]


@needs_robots
def test_a_fast_wrist_spin_names_its_worst_speed_not_its_first(ur5e_spin):
    j = ur5e_spin.joints
    worst = int(np.argmax(j.speed_share))
    name = j.joints[worst]
    # the UR5e turns the spatula with its parallel pitch joints (sim.planar_chain): one of them runs fastest
    assert name.split("/")[-1] in ("shoulder_lift_joint", "elbow_joint", "wrist_1_joint")
    assert j.speed_share[worst] > 1.5 and j.velocity_limits_ok is False and j.ok is False
    speed = next(c for c in j.crossings if c.kind == "speed" and c.joint == name)
    assert speed.peak == pytest.approx(j.speed_peak[worst]) and speed.limit == pytest.approx(math.pi)
    assert speed.share == pytest.approx(j.speed_share[worst]) and speed.first_time < speed.time
    # The problem names the peak (not the first sample over the limit, a little past π) and when it happened.
    said = re.search(rf"'{name}' turned at ([\d.]+) rad/s at t = ([\d.]+) s", j.problem)
    assert said and float(said.group(1)) == pytest.approx(j.speed_peak[worst], abs=0.01)
    assert f"{speed.share:.2f}× its rated 3.14 rad/s" in j.problem


def test_unknown_limits_are_reported_as_unknown(built_in_hold):
    j = built_in_hold.joints
    assert j.speed_share is None and j.range_share is None and j.torque_share is None
    assert j.velocity_limits_ok is None and j.joint_limits_ok is None and j.torque_limits_ok is None
    assert j.ok is None  # nothing broken, but nothing checked either: not "ok"
    assert j.speed_peak.shape == (6,) and np.all(np.isfinite(j.speed_peak))  # what it did is known all the same
    assert j.unknown["speed"].startswith("rated speeds unknown for mh3f")
    summary = built_in_hold.summary()
    json.dumps(summary, allow_nan=False)
    assert summary["speed_share"] is None and summary["velocity_limits_ok"] is None
    assert summary["limits_unknown"]["speed"].startswith("rated speeds unknown for mh3f")
    assert "rated speeds" in built_in_hold.describe() and "unknown (not checked)" in built_in_hold.describe()


@needs_robots
def test_cli_warns_once_for_each_limit_broken(tmp_path, capsys):
    from seqmotion.cli import main

    traj = tmp_path / "spin.npz"
    np.savez(traj, states=straight(SPIN, 500))
    assert main(["simulate", "pancake", "--trajectory", str(traj), "--robot", "ur5e"]) == 0  # a result, not an error
    err = capsys.readouterr().err
    warnings = [line for line in err.splitlines() if line.startswith("seqmotion simulate: warning: ")]
    speed = [w for w in warnings if w.startswith("seqmotion simulate: warning: speed limit broken on ur5e")]
    assert len(speed) == 1 and len(set(warnings)) == len(warnings)  # one line per limit broken
    assert re.search(r"'ur5e/\w+_joint' turned at [\d.]+ rad/s at t = [\d.]+ s, [\d.]+× its rated 3.14 rad/s",
                     speed[0])


def test_cli_notes_the_limits_it_cannot_check(tmp_path, capsys):
    from seqmotion.cli import main

    traj = tmp_path / "shift.npz"
    np.savez(traj, states=straight((0.02, 0.0, 0.1), 100))
    assert main(["simulate", "pancake", "--trajectory", str(traj), "--robot", "mh3f"]) == 0
    err = capsys.readouterr().err
    notes = [line for line in err.splitlines() if line.startswith("seqmotion simulate: note: ")]
    assert len(notes) == 3 and all("unknown for mh3f" in line and "(not checked)" in line for line in notes)
    assert "warning" not in err


# --- what happened to the pancake ---------------------------------------------------------------------------------


def test_a_turn_that_carries_the_pancake_then_releases_it_says_so(deformer):
    states = deformer.deform(straight((0.2, 0.1, 2.5), 500)).states
    r = run_pancake(states, hold_time=0.1, mu=deformer.options.mu)
    assert r.task == "turn" and not r.contact_lost and r.turned_over and not r.on_spatula
    assert r.left_time is not None and r.left_time > r.time[r.n_motion - 1]  # released after the motion, not during
    text = r.describe()
    assert "task: carry the pancake through the turn, then release it turned over" in text
    assert "carried through the turn: yes" in text
    after = text.split("after the motion: ")[1]
    assert after.startswith("released — it ") and f"t = {r.left_time:.2f} s" in after and "turned over" in after
    assert "it slid off after the motion, during the hold" not in text  # the old line that read as a failure


def test_a_motion_that_ends_where_the_pancake_can_rest_is_judged_by_holding_it(built_in_hold):
    r = built_in_hold
    assert r.task == "hold" and not r.contact_lost and r.on_spatula
    text = r.describe()
    assert "task: carry the pancake and hold it on the spatula" in text and "held on the spatula: yes" in text
    assert text.endswith("after the motion: it stayed on and ends face up, on the spatula")


@needs_robots
def test_a_turn_that_loses_the_pancake_says_when(ur5e_spin):
    r = ur5e_spin
    assert r.task == "turn" and r.contact_lost
    assert f"carried through the turn: no — the pancake lost contact at t = {r.contact_lost_time:.3f} s" in r.describe()


def test_snapshots_show_the_turn_itself():
    from seqmotion.sim.arm import Media
    from seqmotion.sim.kinematics import planar_reference

    ref = planar_reference(straight(SPIN, 500), decel_time=0.1, hold_time=0.5)
    steps = Media.plan(ref, None, "x.png", 6, 30.0, 1.0, "front").snapshot_steps
    assert len(steps) == 6 and steps[0] == 0 and steps[-1] == ref.n_motion - 1  # first to last sample of the motion
