"""Task-space PD + disturbance observer on the simulated arm; attitude convention; references."""

import math

import numpy as np
import pytest

from seqmotion.sim import GAINS, run_pancake
from seqmotion.sim.backend import import_mujoco
from seqmotion.sim.control import Gains, TaskSpaceController, resolve_gains, solve_ik
from seqmotion.sim.kinematics import (
    attitude_matrix,
    matrix_to_quat,
    pan_reference,
    planar_reference,
    planar_tilt,
    quat_to_matrix,
)
from seqmotion.sim.scene import SUBSTEPS, build_scene
from seqmotion.tasks.pancake.data import acceleration_type, straight


def test_gain_presets_are_the_dissertations():
    assert GAINS["ch2"].kp == (350,) * 3 + (600,) * 3 and GAINS["ch2"].kd == (60,) * 3 + (90,) * 3
    assert GAINS["ch2"].dob_cutoff == pytest.approx(12.57)
    assert GAINS["ch3"].kp == (800,) * 3 + (1000,) * 3 and GAINS["ch3"].kd == (100,) * 3 + (150,) * 3
    assert GAINS["ch4"].kp == (450,) * 3 + (700,) * 3 and GAINS["ch4"].kd == (60,) * 3 + (90,) * 3
    assert GAINS["ch4"].dob_cutoff == pytest.approx(2 * math.pi * 2.0)
    with pytest.raises(ValueError, match="gains"):
        resolve_gains("ch9")
    with pytest.raises(ValueError):
        Gains(kp=(1.0,) * 5, kd=(1.0,) * 6)


def test_theta_is_a_roll_about_world_x_that_tilts_the_up_normal_toward_minus_y():
    for theta in (-2.5, -0.3, 0.0, 0.7, 3.0):
        rot = attitude_matrix(np.array([theta, math.pi / 2, 0.0]))
        assert planar_tilt(rot) == pytest.approx(theta)
        up = -rot[:, 0]  # the tool's x axis is the surface's down normal
        assert up == pytest.approx([0.0, -math.sin(theta), math.cos(theta)])
        assert rot[:, 2] == pytest.approx([1.0, 0.0, 0.0])  # the tool points along world +x
        assert quat_to_matrix(matrix_to_quat(rot)) == pytest.approx(rot)


def test_planar_reference_feeds_the_generating_inputs_forward_and_decelerates_to_rest():
    batch = acceleration_type(1, np.random.default_rng(0), length=200)
    states, accel = batch.states[0], batch.accel[0]
    ref = planar_reference(states, decel_time=0.1, hold_time=0.05)
    assert len(ref) == 200 + 100 + 50 and ref.n_motion == 200
    assert ref.acc[:199, 1:] == pytest.approx(accel[:, :2], abs=1e-9)
    assert ref.alpha[:199, 0] == pytest.approx(accel[:, 2], abs=1e-9)
    # The tail: constant deceleration from the last velocity to rest in 0.1 s, then still.
    v_end = states[-1, 3:5]
    assert ref.acc[199:299, 1:] == pytest.approx(np.tile(-v_end / 0.1, (100, 1)))
    assert ref.vel[299:] == pytest.approx(np.zeros((51, 3)), abs=1e-12)
    assert ref.pos[-1, 1:] == pytest.approx(ref.pos[199, 1:] + 0.5 * v_end * 0.1, abs=1e-9)
    pan = pan_reference(np.zeros((10, 4)), decel_time=0.0)
    assert pan.pos[0] == pytest.approx([0.65, 0.0, 0.3])


def test_smooth_reference_is_tracked_within_millimetres():
    # An S-curve from rest to rest: 0.12 m, 0.06 m and 1.2 rad in 0.5 s.
    result = run_pancake(straight((0.12, 0.06, 1.2), 500), gains="ch2", hold_time=0.0)
    assert result.diverged is None
    assert result.position_rmse < 2e-3
    assert result.attitude_rmse < math.radians(1.0)
    end_error = np.abs(result.response[-1, :3] - result.command[-1, :3])  # after the 0.1 s tail
    assert end_error[:2].max() < 2e-3 and end_error[2] < math.radians(1.0)


def _hold_with_disturbance(use_dob: bool, seconds: float = 2.0) -> float:
    """Hold the pan's home pose against constant joint torques; the steady-state tool error [m]."""
    mujoco = import_mujoco()
    scene = build_scene("sliding")
    m, d = scene.model, None
    d = mujoco.MjData(m)
    ref = pan_reference(np.zeros((2, 4)))
    d.qpos[scene.arm_qpos] = solve_ik(scene, ref.pos[0], ref.quat[0])
    d.qpos[scene.body_qpos : scene.body_qpos + 3] = (0.0, 0.0, -1.0)  # object out of the way, on nothing
    m.body_gravcomp[scene.body] = 1.0  # ... and weightless there
    mujoco.mj_forward(m, d)
    gains = GAINS["ch3"] if use_dob else Gains(GAINS["ch3"].kp, GAINS["ch3"].kd, None, "PD")
    # Gravity fed forward in both cases, so the only disturbance is the one applied below.
    ctl = TaskSpaceController(scene, gains, model_bias=True)
    ctl.reset(d)
    d.qfrc_applied[scene.arm_dof] = (4.0, -6.0, 3.0, 0.5, -0.8, 0.3)  # [N m], constant
    still = np.zeros(6)
    for _ in range(round(seconds / 1e-3)):
        mujoco.mj_step1(m, d)
        d.ctrl[:] = ctl.torque(d, ref.pos[0], ref.quat[0], still, still)
        mujoco.mj_step2(m, d)
        for _ in range(SUBSTEPS - 1):
            mujoco.mj_step(m, d)
    return float(np.linalg.norm(d.site_xpos[scene.site] - ref.pos[0]))


def test_disturbance_observer_rejects_a_constant_torque_by_an_order_of_magnitude():
    pd_only, with_dob = _hold_with_disturbance(False), _hold_with_disturbance(True)
    assert pd_only > 1e-3  # the torque really pushes the tool away under PD alone
    assert with_dob < 0.1 * pd_only


def test_inverse_kinematics_reaches_the_poses_and_refuses_the_unreachable():
    scene = build_scene("pancake")
    mujoco = import_mujoco()
    d = mujoco.MjData(scene.model)
    for y, z, theta in ((0.0, 0.0, 0.0), (0.25, -0.2, 2.0), (-0.25, 0.25, -3.0)):
        ref = planar_reference(np.array([[y, z, theta, 0, 0, 0]] * 2), decel_time=0.0)
        d.qpos[scene.arm_qpos] = solve_ik(scene, ref.pos[0], ref.quat[0])
        mujoco.mj_kinematics(scene.model, d)
        assert d.site_xpos[scene.site] == pytest.approx(ref.pos[0], abs=1e-7)
        assert planar_tilt(d.site_xmat[scene.site].reshape(3, 3)) == pytest.approx(theta, abs=1e-6)
    with pytest.raises(ValueError, match="reach"):
        solve_ik(scene, np.array([1.5, 0.0, 0.35]), ref.quat[0])


def test_observer_can_start_from_a_known_disturbance():
    from seqmotion.sim.observers import DisturbanceObserver

    dob = DisturbanceObserver(np.ones(3), cutoff=12.57, dt=1e-3)
    known = np.array([1.0, -2.0, 0.5])
    dob.reset(velocity=np.array([0.3, 0.0, -0.1]), estimate=known)
    assert dob.estimate == pytest.approx(known)
    # At rest, applying exactly the disturbance-cancelling command keeps the estimate there.
    for _ in range(100):
        out = dob.update(known, np.array([0.3, 0.0, -0.1]))
    assert out == pytest.approx(known)
