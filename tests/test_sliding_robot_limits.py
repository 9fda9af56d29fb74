"""Sliding plans the Panda can execute within its limits: the kinematic check of a pan motion
(``sim.executable_sliding.check_sliding_executable``, registered for the task "sliding"), the limits as latent
objective terms (``PanJointLimits``), and ``planner.plan(command, robot=…)`` / ``refine_plan(…, robot=…)`` /
``seqmotion plan --robot``."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion.cli import main
from seqmotion.core.execution import check_execution, execution_check_for
from seqmotion.errors import EXIT_INEXACT
from seqmotion.reproduce.ch3 import eval_commands
from seqmotion.sim import robot_models as rb
from seqmotion.sim.sliding import ARM_PHYSICS
from seqmotion.tasks.sliding import RUN_KINDS, PanJointLimits, SlidingExecutionCheck, pan_acceleration_reach
from seqmotion.tasks.sliding.physics import GRAVITY

pytest.importorskip("mink", reason="standard robot arms need mink (pip install 'seqmotion[robots]')")
pytestmark = pytest.mark.skipif("panda" not in {r.name for r in rb.robots()},
                                reason="no Panda model here: robosuite's model files are needed")

ARM = {"mu": ARM_PHYSICS.mu, "mu_dyn": ARM_PHYSICS.mu_dyn}
DT = 1e-3


def still(k: int = 300) -> np.ndarray:
    """Pan states ``(k, 4)`` at rest at home."""
    return np.zeros((k, 4))


def shake(axis: int, amplitude: float, hz: float, k: int = 400, speedup: float = 1.0) -> np.ndarray:
    """Pan states ``(k, 4)``: from rest, ``x = A (1 - cos 2πft) / 2`` along ``axis`` (0: x, 1: y), run ``speedup``×
    faster."""
    t = np.arange(k) * DT * speedup
    w = 2 * np.pi * hz
    out = np.zeros((k, 4))
    out[:, axis] = amplitude * (1 - np.cos(w * t)) / 2
    out[:, 2 + axis] = amplitude * w * np.sin(w * t) / 2 * speedup
    return out


@pytest.fixture(scope="module")
def sliding_check():
    return execution_check_for("sliding")


def test_the_check_is_registered_for_the_sliding_task(sliding_check):
    from seqmotion.sim.executable_sliding import check_sliding_executable

    assert sliding_check is check_sliding_executable
    check = check_execution("sliding", still(), "panda", dt=DT)
    assert isinstance(check, SlidingExecutionCheck)


def test_a_pan_held_still_keeps_every_limit(sliding_check):
    check = sliding_check(still(), "panda")
    assert check.ok is True and check.problem() is None
    assert np.all(check.speed_peak < 1e-6) and check.worst_share["reach"] < 1e-3
    assert check.torque_share is not None and check.worst_share["torque"] < 1  # gravity on the arm and the pan
    assert check.kept() is True
    assert check.pan_map.shape == (300 + 100, 7, 2)  # the plan and the run's 0.1 s stop


def test_joint_speeds_scale_with_the_pan_speed_and_accelerations_with_its_square(sliding_check):
    slow = sliding_check(shake(0, 0.02, 2.0, k=500), "panda")
    fast = sliding_check(shake(0, 0.02, 2.0, k=250, speedup=2.0), "panda")  # the same path in half the time
    j = int(np.argmax(slow.speed_peak))
    assert fast.speed_peak[j] == pytest.approx(2 * slow.speed_peak[j], rel=0.03)
    k = int(np.argmax(slow.accel_peak))
    assert fast.accel_peak[k] == pytest.approx(4 * slow.accel_peak[k], rel=0.08)
    assert fast.duration == pytest.approx(slow.duration / 2, abs=2 * DT)


def test_the_pan_map_is_the_joint_speed_per_pan_speed(sliding_check):
    check = sliding_check(shake(1, 0.01, 1.0, k=400), "panda")
    qd = np.diff(check.joint_path, axis=0) / DT
    v = check.pan_velocity
    predicted = np.einsum("knj,kj->kn", check.pan_map[:-1], (v[1:] + v[:-1]) / 2)
    assert np.abs(predicted - qd).max() < 0.02 * np.abs(qd).max()


def test_the_rated_accelerations_cap_the_pans_acceleration_near_mu_g(sliding_check):
    """Why a Panda plan that keeps its rated accelerations barely slides the object (μ = 0.5 on the simulated pan):
    at home, no direction of the pan lets the joints' rated accelerations reach 1.5 μg, and sideways not even μg."""
    check = sliding_check(still(), "panda")
    m, rated = check.pan_map[0], check.rated_acceleration
    angles = np.linspace(0, np.pi, 181)
    reach = [float(np.min(rated / np.maximum(np.abs(m @ [np.cos(a), np.sin(a)]), 1e-12))) for a in angles]
    mu_g = ARM_PHYSICS.mu * GRAVITY
    assert max(reach) < 1.5 * mu_g
    assert reach[90] < mu_g  # along y
    assert pan_acceleration_reach(check) == pytest.approx((min(reach), max(reach)))


def test_a_pan_motion_past_a_rated_limit_is_flagged_by_name(sliding_check):
    check = sliding_check(shake(1, 0.08, 4.0), "panda")  # sideways at up to 1 m/s, 12 m/s²
    assert check.ok is False
    assert check.speed_share[0] > 1 and check.binding.share > 1 and check.binding.joint == "joint1"
    problem = check.problem()
    assert problem.startswith("not executable on panda") and "'joint1'" in problem
    assert "the pan's motion itself must change" in problem  # a slower pan would slide the object differently
    assert check.kept(("speed",)) is False and check.kept(("range",)) is True


def test_bad_states_and_robots_are_refused(sliding_check):
    with pytest.raises(ValueError, match="states"):
        sliding_check(np.zeros((10, 3)), "panda")
    with pytest.raises(ValueError, match="NaN"):
        sliding_check(np.full((10, 4), np.nan), "panda")
    with pytest.raises(ValueError):
        sliding_check(still(), "no-such-robot")


def test_the_limit_term_predicts_the_check_exactly_at_its_plan_and_closely_nearby(sliding_check):
    pan = shake(0, 0.02, 3.0, k=400)
    check = sliding_check(pan, "panda")
    term = PanJointLimits(check, margin=1.0)
    states = torch.from_numpy(np.concatenate([pan, np.zeros_like(pan)], axis=1))[None]
    shares = term.shares(states)
    for kind in ("speed", "acceleration", "torque"):
        assert float(shares[kind].max()) == pytest.approx(check.worst_share[kind], rel=1e-6)
    nearby = shake(0, 0.021, 3.0, k=400)  # 5 % farther: the prediction is first order about the checked path
    again = sliding_check(nearby, "panda")
    shares = term.shares(torch.from_numpy(np.concatenate([nearby, np.zeros_like(nearby)], axis=1))[None])
    for kind in ("speed", "acceleration", "torque"):
        assert float(shares[kind].max()) == pytest.approx(again.worst_share[kind], rel=0.02)
    assert float(term(states).sum()) >= 0


def test_robot_none_changes_nothing(planner):
    command = sm.tasks.sliding.data.line(0.05, 300)
    a, b = planner.plan(command, **ARM), planner.plan(command, robot=None, **ARM)
    np.testing.assert_array_equal(a.states, b.states)
    assert b.robot_check is None and b.feasible is None
    batch = planner.plan(np.stack([command, command]), robot=None, **ARM)
    np.testing.assert_allclose(batch.states[0], a.states, rtol=1e-4, atol=1e-6)  # float32 batches differ a little
    refined = sm.refine_plan(planner, command, steps=2, gains=(1.0,), robot=None, **ARM)
    assert refined.robot_check is None and refined.feasible is None


def test_a_batch_or_an_unknown_limit_is_refused(planner):
    command = sm.tasks.sliding.data.line(0.05, 300)
    with pytest.raises(ValueError, match="one command at a time"):
        planner.plan(np.stack([command, command]), robot="panda", **ARM)
    with pytest.raises(ValueError, match="limits"):
        planner.plan(command, robot="panda", limits=("speed", "jerk"), **ARM)
    with pytest.raises(ValueError):
        planner.plan(command, robot="no-such-robot", **ARM)


@pytest.fixture(scope="module")
def panda_plan(planner, one_thread):
    """An evaluation command whose plain plan turns the Panda's joint 1 past its rated speed, planned for it
    keeping what a simulated run judges (speeds, ranges, torques)."""
    command = eval_commands(20, 0)[7]
    plain = planner.plan(command, **ARM)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        plan = planner.plan(command, robot="panda", limits=RUN_KINDS, **ARM)
    return command, plain, plan, [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]


def test_a_plan_refined_for_the_panda_keeps_its_speeds_ranges_and_torques(panda_plan):
    command, plain, plan, said = panda_plan
    before = check_execution("sliding", plain.states, "panda", dt=DT)
    assert before.ok is False and before.speed_share[0] > 1  # the plain plan: joint 1 too fast
    again = check_execution("sliding", plan.states, "panda", dt=DT)  # the verdict is the returned plan's
    assert again.worst_share == pytest.approx(plan.robot_check.worst_share)
    assert again.kept(RUN_KINDS) is True and max(again.speed_share) <= 0.95 and max(again.torque_share) <= 0.95
    assert np.min(again.range_margin) > 0
    assert plan.errors["tracking_rmse_m"] < 1.5 * plain.errors["tracking_rmse_m"]
    # the rated accelerations are still broken (not asked for): judged all the same, feasible False, named
    assert again.worst_share["acceleration"] > 1 and plan.feasible is False
    assert any(s.startswith("not executable on panda") and "rad/s²" in s for s in said)


def test_the_verdict_survives_save_and_load(panda_plan, tmp_path):
    _, _, plan, _ = panda_plan
    loaded = sm.load_result(plan.save(tmp_path / "plan.npz"))
    assert isinstance(loaded.robot_check, SlidingExecutionCheck)
    assert loaded.feasible is False and loaded.robot_check.binding == plan.robot_check.binding
    assert loaded.robot_check.worst_share == pytest.approx(plan.robot_check.worst_share)
    assert loaded.robot_check.pan_map is None  # derived data is not saved


def test_a_plan_for_the_panda_within_every_limit_is_feasible(planner, one_thread):
    command = sm.tasks.sliding.data.line(0.01, 300)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plan = planner.plan(command, robot="panda", **ARM)
    assert plan.feasible is True and plan.robot_check.ok is True
    again = check_execution("sliding", plan.states, "panda", dt=DT)
    assert again.ok is True and again.worst_share["acceleration"] <= 1


def test_refine_plan_for_the_panda_carries_the_verdict(planner, one_thread):
    command = sm.tasks.sliding.data.line(0.03, 300)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        plan = sm.refine_plan(planner, command, steps=6, gains=(1.0,), accel_steps=3, robot="panda",
                              limits=RUN_KINDS, **ARM)
    check = plan.robot_check
    assert isinstance(check, SlidingExecutionCheck) and check.kept(RUN_KINDS) is True
    again = check_execution("sliding", plan.states, "panda", dt=DT)
    assert again.worst_share == pytest.approx(check.worst_share)
    assert plan.feasible is check.ok
    if check.ok is False:
        assert any(str(w.message).startswith("not executable on panda") for w in caught)


def test_cli_plan_robot_exits_3_when_the_panda_cannot_execute_it(tmp_path, capsys):
    np.savez(tmp_path / "line.npz", states=sm.tasks.sliding.data.line(0.05, 300))
    out = tmp_path / "plan.npz"
    code = main(["plan", "--command", str(tmp_path / "line.npz"), "--mu", "0.5", "--mu-dyn", "0.5", "--robot",
                 "panda", "--robot-limits", "speed,range,torque", "--output", str(out)])
    captured = capsys.readouterr()
    assert code == EXIT_INEXACT
    assert "seqmotion plan: warning: not executable on panda" in captured.err
    loaded = sm.load_result(out)
    assert loaded.feasible is False and loaded.robot_check.kept(RUN_KINDS) is True
    assert main(["plan", "--circle", "0.05", "--length", "300", "--robot-limits", "speed", "--output",
                 str(tmp_path / "x.npz")]) == 2
    assert "--robot-limits needs --robot" in capsys.readouterr().err
