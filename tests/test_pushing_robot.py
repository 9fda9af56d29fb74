"""The chapter-5 pushing closed loop on a standard arm: the Panda holding the Touch's pen in the pushing world."""

from __future__ import annotations

import importlib.util
import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo is first imported: offscreen rendering

from seqmotion.lfd.env import pushing  # noqa: E402
from seqmotion.sim import robot_models as rb  # noqa: E402

ROBOSUITE = rb.robosuite_root()
pytestmark = [
    pytest.mark.skipif(ROBOSUITE is None or not (ROBOSUITE / "panda" / "robot.xml").is_file(),
                       reason="robosuite's robot model files are not installed (pip install --no-deps "
                              "'robosuite>=1.5,<1.6')"),
    pytest.mark.skipif(importlib.util.find_spec("mink") is None, reason="mink is not installed (seqmotion[robots])"),
]


@pytest.fixture(scope="module")
def scene():
    from seqmotion.lfd.env.robot import RobotPushingScene

    world = RobotPushingScene("panda")
    yield world
    world.close()


def test_scene_holds_the_pen_at_the_panda_flange_pointing_down(scene):
    from seqmotion.lfd.env.robot import PEN_LENGTH

    m = scene.model
    holder = m.body("pen_holder")
    assert m.body(int(holder.parentid[0])).name == "panda/" + scene.robot.flange
    assert m.geom("pen").bodyid[0] == holder.id and m.site("tip").bodyid[0] == holder.id
    assert m.geom("pen").size[0] == pytest.approx(pushing.ARM.pen_radius)
    assert m.nu == 7 and np.allclose(m.actuator_ctrlrange[:, 1], scene.robot.torque_limit)
    scene.reset(pushing.POSITIONS[1])
    flange = scene.data.site_xpos[scene.control_scene.flange]
    pen_axis = scene.data.site_xmat[scene.tip_site].reshape(3, 3)[:, 2]
    np.testing.assert_allclose(scene.tip, pushing.DEFAULT_TIP, atol=1e-6)  # home: the Touch's start tip
    np.testing.assert_allclose(pen_axis, [0.0, 0.0, -1.0], atol=1e-6)  # vertical, pointing down
    np.testing.assert_allclose(flange - scene.tip, [0.0, 0.0, PEN_LENGTH], atol=1e-6)
    lo, hi = scene.robot.joint_range.T
    assert np.all(scene.home > lo + 0.1) and np.all(scene.home < hi - 0.1)
    np.testing.assert_allclose(scene.block_pose[:2], pushing.POSITIONS[1].xy, atol=1e-9)
    image = scene.render("default")
    assert image.shape == (64, 64, 3) and image.dtype == np.uint8 and image.std() > 5


def test_tip_follows_a_commanded_path_within_a_millimetre(scene):
    from seqmotion.lfd.env.robot import track_tip

    t = np.linspace(0.0, 1.0, 1000)
    ease = 0.5 * (1 - np.cos(np.pi * t))  # starts and ends at rest; ≤ 0.3 m/s, within the joints' speed limits
    path = pushing.DEFAULT_TIP + np.column_stack([0.03 * np.sin(2 * np.pi * ease), 0.08 * ease, -0.05 * ease])
    result = track_tip(scene, path, pushing.POSITIONS[0])
    assert result.errors.max() < 1e-3
    assert result.joints.problem is None and result.joints.torque_limits_ok and result.joints.joint_limits_ok
    np.testing.assert_allclose(scene.data.site_xmat[scene.tip_site].reshape(3, 3)[:, 2], [0, 0, -1], atol=0.02)


def test_pen_pressed_on_the_table_feels_an_upward_force(scene):
    from seqmotion.lfd.env.robot import track_tip

    t = np.linspace(0.0, 1.0, 400)
    down = pushing.DEFAULT_TIP + np.outer(0.5 * (1 - np.cos(np.pi * t)), [0.0, 0.0, -0.1])  # 5 mm into the table
    track_tip(scene, np.vstack([down, np.repeat(down[-1:], 100, axis=0)]), pushing.POSITIONS[2])
    force = scene.pen_force()
    assert force[2] > 1.0 and abs(force[2]) > 3 * np.hypot(force[0], force[1])
    assert scene.tip[2] > pushing.ARM.pen_radius - 2e-3  # the table holds it (soft contact: ≤ 2 mm in)


def test_touch_twin_reads_the_touch_joints_and_reaction_torque():
    from seqmotion.lfd.env.robot import TouchTwin, touch_angles, touch_jacobian

    q = pushing.default_pose()
    tip = pushing.forward_kinematics(q)
    np.testing.assert_allclose(touch_angles(tip, q)[0], q, atol=1e-9)
    far, clamped = touch_angles(np.array([0.5, 0.0, 0.1]), q)  # beyond the Touch's 0.3 m reach
    assert clamped and np.all(np.isfinite(far))
    jac = touch_jacobian(q)
    dq = np.array([1e-4, -2e-4, 1.5e-4])
    np.testing.assert_allclose(pushing.forward_kinematics(q + dq) - tip, jac @ dq, atol=1e-7)
    twin = TouchTwin(tip)
    push = np.array([0.0, -0.5, 0.0])  # the block pushes the tip toward -y: the yaw joint resists in +
    for _ in range(500):
        state = twin.sense(tip, push)
    np.testing.assert_allclose(state.tau, -jac.T @ push, rtol=1e-3, atol=1e-9)
    assert state.tau[0] > 0 and np.allclose(state.dtheta, 0.0, atol=1e-9)


@pytest.mark.parametrize("mode", ["command", "twin"])
def test_one_short_closed_loop_trial_runs_end_to_end(scene, mode):
    import seqmotion as sm
    from seqmotion.lfd.rollout import run_trial

    policy = sm.load_pretrained("pushing")
    run, image, z = run_trial(policy, scene, pushing.POSITIONS[3], pushing.SceneVariation(), duration=0.3, mode=mode)
    assert run.steps == 300 and image.shape == (64, 64, 3) and z.shape == (policy.seqae_config.latent,)
    for name in ("slave_theta", "slave_dtheta", "slave_tau", "command_theta", "tip", "joint_pos", "torque"):
        assert np.all(np.isfinite(getattr(run, name))), name
    assert run.tip[-1][2] > 0 and np.linalg.norm(run.tip[-1] - run.tip[0]) > 1e-3  # the decoder moved it
    assert run.tracking_max < 0.01 and run.joints is not None and run.joints.joint_limits_ok
    assert not run.success  # 0.3 s is too short to push the block across


def test_bad_inputs_are_refused_by_name(scene):
    import seqmotion as sm
    from seqmotion.lfd.env.robot import RobotPushingScene, track_tip
    from seqmotion.lfd.evaluation import run_on_robot

    with pytest.raises(ValueError, match="standard arm"):
        RobotPushingScene("mh3f")
    with pytest.raises(ValueError, match="pen_length"):
        RobotPushingScene("panda", pen_length=-1.0)
    with pytest.raises(ValueError, match="path"):
        track_tip(scene, np.zeros((5, 2)))
    with pytest.raises(ValueError, match="PushingPolicy"):
        run_on_robot(object(), scene=scene)
    policy = sm.load_pretrained("pushing")
    with pytest.raises(ValueError, match="trials"):
        run_on_robot(policy, scene=scene, trials=0)
    with pytest.raises(ValueError, match="latents"):
        run_on_robot(policy, scene=scene, latents="oracle")
    with pytest.raises(ValueError, match="mode"):
        run_on_robot(policy, scene=scene, mode="puppet", trials=1, positions=[0])
    with pytest.raises(ValueError, match="block position index"):
        run_on_robot(policy, scene=scene, positions=[7])
