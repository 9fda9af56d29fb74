"""The UR5e turns the spatula with its three parallel pitch joints, the Panda with its joints 2, 4 and 6: the planar
chain they form, its kinematics and inverse dynamics against MuJoCo's, and the polish on those joints (a turn within
the rated limits)."""

from __future__ import annotations

import numpy as np
import pytest

from seqmotion.sim import robot_models as rb
from seqmotion.tasks.pancake import data as gen

pytest.importorskip("mink", reason="standard robot arms need mink (pip install 'seqmotion[robots]')")
pytestmark = pytest.mark.skipif(
    "ur5e" not in {r.name for r in rb.robots()},
    reason="no UR5e model here: robosuite's model files or Menagerie's universal_robots_ur5e are needed")

from seqmotion.sim.planar_chain import (  # noqa: E402 - after the skip: MuJoCo models needed
    SINGULARITY_CLEARANCE,
    chain_joints,
    chain_task,
    chain_torques,
    flange_clearance,
    planar_chain,
)


@pytest.fixture(scope="module")
def chain():
    return planar_chain("ur5e")


def test_the_ur5e_turns_the_spatula_with_its_pitch_joints(chain):
    assert chain.joints == ("shoulder_lift_joint", "elbow_joint", "wrist_1_joint")
    assert chain.upper == pytest.approx(0.425, abs=1e-3) and chain.fore == pytest.approx(0.392, abs=1e-3)
    assert planar_chain("mh3f") is None  # the built-in arm turns the spatula with its wrist


HAS_PANDA = "panda" in {r.name for r in rb.robots()}


@pytest.mark.skipif(not HAS_PANDA, reason="no Panda model here")
def test_the_panda_turns_the_spatula_with_joints_2_4_and_6():
    """Joints 3 and 5 (along its links) held at 0 leave the Panda's links between joints 2, 4 and 6 rigid: a planar
    chain of the DH offsets' lengths (0.316 m and 0.0825 m, 0.384 m and 0.0825 m)."""
    panda = planar_chain("panda")
    assert panda.joints == ("joint2", "joint4", "joint6") and panda.index == (1, 3, 5)
    assert panda.upper == pytest.approx(np.hypot(0.316, 0.0825), abs=1e-4)
    assert panda.fore == pytest.approx(np.hypot(0.384, 0.0825), abs=1e-4)
    assert np.allclose(panda.home[[0, 2, 4, 6]], 0.0)


def test_forward_kinematics_inverts_the_inverse(chain):
    states = gen.straight((0.15, -0.1, 1.5), 400)
    joints = chain_joints(chain, states)
    assert np.allclose(joints[0, :3], chain.home[list(chain.index)], atol=1e-6)  # the origin is the home posture
    accel = np.diff(joints[:, 3:], axis=0) / 1e-3
    again, spatula_accel = chain_task(chain, joints, accel)
    assert np.allclose(again, states, atol=1e-9)
    implied = np.diff(states[:, 3:], axis=0) / 1e-3
    assert np.median(np.abs(spatula_accel - implied)) < 0.05  # exact accelerations vs their 1 ms differences


@pytest.mark.parametrize("robot", ["ur5e", pytest.param("panda", marks=pytest.mark.skipif(not HAS_PANDA,
                                                                                     reason="no Panda model here"))])
def test_the_chains_inverse_dynamics_is_mujocos(robot):
    import mujoco

    from seqmotion.sim.scene import get_scene

    chain = planar_chain(robot)
    scene = get_scene("pancake", robot)
    data = mujoco.MjData(scene.model)
    rng = np.random.default_rng(0)
    dofs = np.array(scene.arm_dof)[list(chain.index)]
    for _ in range(3):
        q = chain.home[list(chain.index)] + rng.uniform(-1, 1, 3)
        qd, qdd = rng.uniform(-3, 3, 3), rng.uniform(-30, 30, 3)
        data.qpos[scene.arm_qpos] = chain.home
        data.qpos[np.array(scene.arm_qpos)[list(chain.index)]] = q
        data.qvel[:], data.qacc[:] = 0.0, 0.0
        data.qvel[dofs], data.qacc[dofs] = qd, qdd
        mujoco.mj_inverse(scene.model, data)
        assert np.allclose(chain_torques(chain, q, qd, qdd), data.qfrc_inverse[dofs], atol=0.05)


@pytest.fixture(scope="module")
def turn(deformer):
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = deformer.deform(TURN, keep_end=True, robot="ur5e")
    return result, [w for w in caught if issubclass(w.category, RuntimeWarning)]


TURN = gen.straight((0.1, -0.1, 2.2), 400)
"""A turn past the cone's half-angle in 0.4 s: its learned motion asks the UR5e's joints for 2–3× their rated speeds."""


def test_a_turn_becomes_executable_on_the_ur5e(turn):
    result, said = turn
    check = result.robot_check
    assert result.exact and result.feasible is True and check.ok is True and not said
    assert result.length > 800  # a loop at the rated speeds takes longer than the 0.4 s sketch
    assert check.speed_share.max() <= 1.0 and check.torque_share.max() <= 1.0 and check.range_margin.min() > 0
    assert np.allclose(result.states[result.length - 1, :3], TURN[-1, :3], atol=1e-6)


def test_the_turn_keeps_the_pancake_and_the_limits_when_executed(turn):
    from seqmotion import sim

    result, _ = turn
    run = sim.run_pancake(result.states[: result.length], gains="ch2", robot="ur5e")
    assert not run.contact_lost and run.joints.problem is None
    assert run.joints.speed_share.max() <= 1.0 and run.joints.torque_share.max() < 1.0


def test_the_simulators_ik_follows_the_chains_joint_path(turn, chain):
    from seqmotion.sim.executable import _joint_path
    from seqmotion.sim.kinematics import planar_reference
    from seqmotion.sim.scene import get_scene

    result, _ = turn
    states = result.states[: result.length]
    ref = planar_reference(states, decel_time=0.0, hold_time=0.0)
    path, _ = _joint_path(get_scene("pancake", "ur5e"), ref.pos, ref.quat, 1e-3)
    planned = chain_joints(chain, states)[:, :3]
    assert np.abs(path[:, list(chain.index)] - planned).max() < 1e-3
    others = [j for j in range(6) if j not in chain.index]
    assert np.abs(path[:, others] - chain.home[others]).max() < 1e-3  # pan, wrist 2 and 3 hold still
    assert flange_clearance(chain, states).min() >= SINGULARITY_CLEARANCE - 1e-3  # imposed at the 4 ms knots


def test_the_learned_motion_alone_is_flagged_by_name(deformer):
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = deformer.deform(gen.straight((0.2, 0.0, 2.5), 500), robot="ur5e")
    check = result.robot_check
    assert result.feasible is False and check.ok is False and check.binding.share > 1
    said = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert len(said) == 1 and said[0].startswith("not executable on ur5e") and "needs ≥" in said[0]


def test_a_turn_the_arm_cannot_end_at_rest_ends_as_near_as_it_can_rising_and_braking(deformer):
    """Turned to 2.9 rad at the start point: to hold the pancake on a spatula tilted past the cone's half-angle while
    it comes to rest, the arm has to brake a rising spatula at more than g; within the UR5e's rated speeds that loop
    cannot end where it started, so the motion ends at rest as near as it can, says so, and stays executable."""
    import warnings

    from seqmotion import sim

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = deformer.deform(gen.straight((0.0, 0.0, 2.9), 500), keep_end=True, robot="ur5e")
    said = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert not result.exact and result.feasible is True and result.robot_check.ok is True
    assert len(said) == 1 and "ends at rest as near as they allow" in said[0] and "ur5e" in said[0]
    states = result.states[: result.length]
    assert 1.5 < states[-1, 2] < 2.9 and np.abs(states[-1, 3:]).max() < 1e-6  # short of the turn, at rest
    assert (states[-40:-1, 4] > 0).all()  # rising into the stop…
    assert (result.accel[result.length - 40 : result.length - 1, 1] < -9.8).all()  # …braking at more than g
    run = sim.run_pancake(states, gains="ch2", robot="ur5e")
    assert not run.contact_lost and run.joints.problem is None


def test_the_chain_in_torch_is_the_chain_in_numpy(chain):
    """``chain_motion`` (the latent objective's differentiable chain) gives the closed-form joints of
    ``chain_joints`` and the inverse dynamics of ``chain_torques`` on the same motion."""
    import torch

    from seqmotion.sim.arm_limits import chain_motion

    states = gen.straight((0.15, -0.1, 1.5), 400)
    q, qd, dist = chain_motion(chain, torch.as_tensor(states)[None])
    joints = chain_joints(chain, states)
    assert np.abs(q[0].numpy() - joints[:, :3]).max() < 1e-9 and np.abs(qd[0].numpy() - joints[:, 3:]).max() < 1e-9
    inner, outer = chain.reach
    assert ((dist > inner) & (dist < outer)).all()


def test_latent_updates_with_the_arms_limits_bring_the_learned_motion_within_its_rated_speeds(deformer):
    """Ch. 4's external order on a real arm: the learned motion of a fast turn asks the UR5e's joints for several times
    their rated speeds; gradient steps on z with ``ArmLimits`` beside the end pose bring it near them, with the
    pancake kept — and say what that cost (a turn this fast within these speeds ends short of its end attitude)."""
    import warnings

    import seqmotion as sm
    from seqmotion.sim.arm_limits import ArmLimits

    sketch = gen.straight((0.05, 0.05, 1.5), 250)
    objective = ArmLimits("ur5e") + sm.objectives.EndPose((0.05, 0.05, 1.5))
    before = objective.bind(deformer).report(*_batched(deformer.deform(sketch)))
    assert before["rated joint speeds"].value[0] > 1.5 and not before["rated joint speeds"].met
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = sm.optimize_latent(deformer, sketch, objective, steps=15)
    after = result.terms
    speeds = float(np.max(after["rated joint speeds"].value))
    assert speeds < 1.1 and after["torque limits"].met  # from 1.8× the rated speed
    assert result.violation is None or float(np.max(result.violation)) <= 0.01  # the pancake kept


def _batched(result):
    import torch

    return torch.as_tensor(result.states)[None], torch.as_tensor(result.accel)[None]


def test_arm_limits_refuse_an_arm_without_a_chain_by_name():
    from seqmotion.sim.arm_limits import ArmLimits

    with pytest.raises(ValueError, match="built-in arm"):
        ArmLimits("mh3f")
    with pytest.raises(ValueError, match="kinds"):
        ArmLimits("ur5e", kinds=("speed", "jerk"))
    with pytest.raises(ValueError, match="margin"):
        ArmLimits("ur5e", margin=1.5)
