"""4-channel bilateral teleoperation, the scripted operator and the slave-only loop (Fig. 5.7)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

pushing = pytest.importorskip("seqmotion.lfd.env.pushing")
from seqmotion.lfd.env import teleop  # noqa: E402
from seqmotion.lfd.env.operator import PHASES, OperatorParams, ScriptedOperator  # noqa: E402
from seqmotion.lfd.rollout import run_autonomous  # noqa: E402


@pytest.fixture(scope="module")
def arms():
    scene, master = pushing.PushingScene(), pushing.MasterArm()
    yield scene, master
    scene.close()


class CircleHand(teleop.Operator):
    """A spring-damper hand dragging the master's tip around a 3 cm circle above the table."""

    def reset(self, tip, block_pose, position):
        self.t, self.start = 0.0, tip.copy()

    def hand_force(self, tip, tip_velocity, slave_tip, block_pose):
        t, self.t = self.t, self.t + pushing.DT
        circle = self.start + 0.03 * np.array([math.cos(math.pi * t) - 1.0, math.sin(math.pi * t), 0.0])
        target = self.start + min(1.0, t / 0.5) * (circle - self.start)
        return 200.0 * (target - tip) - 5.0 * tip_velocity


class PressHand(teleop.Operator):
    """Lowers the stylus and presses it down with 1 N (the slave presses on the table)."""

    def reset(self, tip, block_pose, position):
        self.t, self.hold = 0.0, tip.copy()

    def hand_force(self, tip, tip_velocity, slave_tip, block_pose):
        self.t += pushing.DT
        force = 200.0 * (self.hold - tip) - 5.0 * tip_velocity
        force[2] = -min(1.0, self.t / 0.5) - 5.0 * tip_velocity[2]
        return force


def test_slave_tracks_master_in_free_space(arms):
    scene, master = arms
    demo = teleop.teleoperate(scene, master, CircleHand(), pushing.POSITIONS[2], duration=2.5)
    assert np.ptp(demo.master_tip[:, 0]) > 0.04  # the hand really moved the master around
    assert np.abs(demo.master_theta - demo.slave_theta).max() < 0.04  # rad
    assert np.linalg.norm(demo.master_tip - demo.slave_tip, axis=1).max() < 0.006  # m
    assert np.abs(demo.block_pose - demo.block_pose[0]).max() < 1e-3  # nothing was touched


def test_force_channel_reflects_contact(arms):
    scene, master = arms
    demo = teleop.teleoperate(scene, master, PressHand(), pushing.POSITIONS[5], duration=2.5)
    steady = slice(2000, 2500)
    tau_m, tau_s = demo.master_tau[steady].mean(0), demo.slave_tau[steady].mean(0)
    assert np.linalg.norm(tau_s) > 0.05  # N m: the slave really presses on the table
    assert np.linalg.norm(tau_m + tau_s) < 0.05 * np.linalg.norm(tau_s)  # action = reaction
    # ...and the slave presses with the hand's 1 N.
    m, d = scene.model, scene.data
    normal = 0.0
    for i in range(d.ncon):
        names = {m.geom(d.contact[i].geom1).name, m.geom(d.contact[i].geom2).name}
        if names == {"pen", "table"}:
            wrench = np.zeros(6)
            mujoco.mj_contactForce(m, d, i, wrench)
            normal += wrench[0]
    assert normal == pytest.approx(1.0, rel=0.1)


@pytest.mark.parametrize("index", range(6))
def test_scripted_operator_pushes_block_across(arms, index):
    scene, master = arms
    position = pushing.POSITIONS[index]
    rng = np.random.default_rng([0, index])
    operator = ScriptedOperator(OperatorParams.sample(rng), rng)
    demo = teleop.teleoperate(scene, master, operator, position, 4.0, pushing.SceneVariation.sample(rng))
    assert demo.success, (position.name, demo.block_pose[-1])
    assert not math.isnan(demo.crossed_time) and demo.n_pushes >= 1
    assert position.sign * demo.block_pose[0, 1] > 0 > position.sign * demo.block_pose[-1, 1]
    assert demo.length == 4000 and demo.motion().shape == (4000, 18) and demo.motion(20).shape == (200, 18)
    assert PHASES[demo.phase[0]] == "wait" and (demo.phase == PHASES.index("push")).any()
    # The operator applies force to the master, within human limits, and it does work.
    assert np.linalg.norm(demo.hand_force, axis=1).max() <= operator.params.force_limit + 1e-9
    assert np.abs(demo.slave_tau).max() > 0.03  # N m: pushing the block is felt on the slave
    assert np.all(np.isfinite(demo.motion()))


def test_policy_slot_replays_a_demonstration(arms):
    """Fig. 5.7: a command source in the master's place, refreshed every 20 ms, drives the slave."""
    scene, master = arms
    position, rng = pushing.POSITIONS[4], np.random.default_rng(7)
    operator = ScriptedOperator(OperatorParams.sample(rng), rng)
    variation = pushing.SceneVariation.sample(rng)
    demo = teleop.teleoperate(scene, master, operator, position, 4.0, variation)
    assert demo.success
    calls = []

    def source(t, state):
        calls.append(t)
        return teleop.ReplayMaster(demo)(t, state)

    run = run_autonomous(scene, source, position, 4.0, variation)
    assert len(calls) == 200 and calls[1] == pytest.approx(0.02)
    assert run.success
    np.testing.assert_allclose(run.slave_theta, demo.slave_theta, atol=0.15)
    # Doing nothing (holding the start pose) leaves the block where it is.
    still = run_autonomous(scene, lambda t, s: teleop.ArmState(demo.slave_theta[0], np.zeros(3),
                                                                       np.zeros(3)), position, 1.0, variation)
    assert not still.success and np.abs(still.block_pose[-1, :2] - still.block_pose[0, :2]).max() < 1e-3


def test_bad_arguments(arms):
    scene, master = arms
    rng = np.random.default_rng(0)
    operator = ScriptedOperator(OperatorParams.sample(rng), rng)
    with pytest.raises(ValueError, match="kp"):
        teleop.BilateralGains(kp=-1.0)
    with pytest.raises(ValueError, match="cutoff_hz"):
        teleop.BilateralGains(cutoff_hz=0.0)
    with pytest.raises(ValueError, match="simulation steps"):
        teleop.teleoperate(scene, master, operator, pushing.POSITIONS[0], 1.0, gains=teleop.BilateralGains(dt=2e-3))
    with pytest.raises(ValueError, match="duration"):
        teleop.teleoperate(scene, master, operator, pushing.POSITIONS[0], duration=0.0)
    with pytest.raises(ValueError, match="duration"):
        teleop.teleoperate(scene, master, operator, pushing.POSITIONS[0], duration=float("nan"))
    hold = teleop.ArmState(pushing.default_pose(), np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="command_interval"):
        run_autonomous(scene, lambda t, s: hold, pushing.POSITIONS[0], 1.0, command_interval=0.0205)
    with pytest.raises(ValueError, match="bad theta"):
        run_autonomous(scene, lambda t, s: teleop.ArmState(np.zeros(2), np.zeros(3), np.zeros(3)),
                              pushing.POSITIONS[0], 1.0)
    with pytest.raises(ValueError, match="bad tau"):
        run_autonomous(scene, lambda t, s: teleop.ArmState(np.zeros(3), np.zeros(3), np.full(3, np.nan)),
                              pushing.POSITIONS[0], 1.0)
