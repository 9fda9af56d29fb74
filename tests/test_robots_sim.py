"""Motions executed on standard arm models: differential IK + joint-space PD + DOB on the Panda and the UR5e
(robosuite's files), what the results say of the robot, and the envs and CLI with ``robot=``."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo is first imported: offscreen rendering

from seqmotion import sim  # noqa: E402
from seqmotion.sim import robot_models as rb  # noqa: E402

ROBOSUITE = rb.robosuite_root()
try:
    import mink  # noqa: F401
except ImportError:  # pragma: no cover - the robots extra is missing
    HAVE_MINK = False
else:
    HAVE_MINK = True
pytestmark = pytest.mark.skipif(
    ROBOSUITE is None or not (ROBOSUITE / "panda" / "robot.xml").is_file() or not HAVE_MINK,
    reason="needs robosuite's robot files and mink (pip install 'seqmotion[robots]' && "
           "pip install --no-deps 'robosuite>=1.5,<1.6')",
)


def smooth_shift(dy: float, duration: float, k: int) -> np.ndarray:
    """Planar spatula states ``(k, 6)``: a rest-to-rest cosine move of ``dy`` [m] along y in ``duration`` [s]."""
    t = np.arange(k) * 1e-3
    s = np.clip(t / duration, 0.0, 1.0)
    states = np.zeros((k, 6))
    states[:, 0] = dy * (1 - np.cos(np.pi * s)) / 2
    states[:, 3] = np.where(t < duration, dy * np.pi / (2 * duration) * np.sin(np.pi * s), 0.0)
    return states


@pytest.mark.parametrize("robot", ["panda", "ur5e"])
def test_a_gentle_motion_keeps_the_pancake_and_every_limit(robot):
    r = sim.run_pancake(smooth_shift(0.05, 0.4, 450), robot=robot, hold_time=0.1)
    assert r.robot == f"{robot} (robosuite)"
    assert not r.contact_lost and r.on_spatula and r.diverged is None
    assert r.position_rmse < 1e-3  # the joint-space loop tracks the tool within a millimetre here
    assert r.joint_limits_ok and r.velocity_limits_ok and r.torque_limits_ok and r.joints.problem is None
    assert r.joints.torque_share.shape == (len(rb.get_robot(robot).joints),)
    assert np.all(r.joints.torque_share < 1) and np.all(r.joints.torque_share > 0)  # it carries the tool
    assert r.joints.ik_error[0] < 1e-4
    summary = r.summary()
    assert summary["robot"] == f"{robot} (robosuite)" and summary["torque_limits_ok"] is True


def test_a_motion_past_the_robots_limits_is_flagged_by_joint():
    # 15 cm in 60 ms and back: far more than the wrist's rated speed and the shoulder's torque allow.
    out = smooth_shift(0.15, 0.06, 60)
    back = out[::-1].copy()
    back[:, 3] *= -1
    r = sim.run_pancake(np.concatenate([out, back]), robot="panda", hold_time=0.1)
    assert r.joints.problem is not None and "panda/joint" in r.joints.problem
    assert r.torque_limits_ok is False or r.velocity_limits_ok is False
    assert "panda (robosuite)" in r.describe()
    # The torque applied never exceeds the model's limits (the controller saturates; MuJoCo would clamp).
    assert np.all(r.torque_peak <= rb.get_robot("panda").torque_limit + 1e-9)


def test_an_object_on_a_still_pan_stays_put_on_the_panda():
    still = np.zeros((400, 4))
    r = sim.run_sliding(still, np.zeros((400, 4)), robot="panda", hold_time=0.0)
    assert not r.fell_off and not r.tipped and r.rmse < 1e-3 and r.pan_excursion < 1e-3
    assert r.robot == "panda (robosuite)" and r.joints.problem is None


def test_the_built_in_arm_reports_no_modelled_limits():
    r = sim.run_pancake(smooth_shift(0.02, 0.3, 300), hold_time=0.1)
    assert r.robot == "mh3f (seqmotion)"
    assert r.joint_limits_ok is None and r.torque_limits_ok is None and r.joints.torque_share is None


def test_unknown_robot_is_refused_by_name():
    with pytest.raises(ValueError, match="kuka9"):
        sim.run_pancake(smooth_shift(0.02, 0.3, 300), robot="kuka9")


def test_env_on_the_ur5e_steps_and_reports_its_ik():
    import gymnasium as gym

    env = gym.make("seqmotion/PancakeArm-v0", robot="ur5e", frame_skip=5, disable_env_checker=True)
    obs, _ = env.reset(seed=0)
    for _ in range(10):
        obs, reward, terminated, truncated, info = env.step(np.zeros(3))
    assert reward == 1.0 and not terminated and np.all(np.isfinite(obs))
    assert info["ik_error"].shape == (2,) and info["ik_error"][0] < 1e-3 and info["torque_saturated"] is False
    env.close()


def test_cli_simulates_on_a_robot_and_lists_the_robots(tmp_path, capsys):
    from seqmotion.cli import main

    traj = tmp_path / "shift.npz"
    np.savez(traj, states=smooth_shift(0.03, 0.3, 350))
    out = tmp_path / "m.json"
    assert main(["simulate", "pancake", "--trajectory", str(traj), "--robot", "ur5e", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "pancake on ur5e (robosuite): " in printed and "stayed on" in printed
    metrics = json.loads(out.read_text())["metrics"]
    assert metrics["robot"] == "ur5e (robosuite)" and metrics["joint_limits_ok"] is True
    assert main(["robots", "--json"]) == 0
    listed = {(r["name"], r["dof"]) for r in json.loads(capsys.readouterr().out)}
    assert {("mh3f", 6), ("panda", 7), ("ur5e", 6)} <= listed
