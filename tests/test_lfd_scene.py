"""Chapter-5 pushing scene: kinematics, friction, images, argument checks."""

from __future__ import annotations

import math

import numpy as np
import pytest

pushing = pytest.importorskip("seqmotion.lfd.env.pushing")


@pytest.fixture(scope="module")
def scene():
    s = pushing.PushingScene()
    yield s
    s.close()


def test_kinematics_match_mujoco(scene):
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.uniform([-1.0, 0.0, -0.5], [1.0, 1.2, 1.0])
        scene.set_joint_state(q)
        np.testing.assert_allclose(pushing.forward_kinematics(q), scene.tip, atol=1e-6)
        np.testing.assert_allclose(pushing.inverse_kinematics(scene.tip), q, atol=1e-4)
        # The RTOB's gravity model is exactly MuJoCo's (qfrc_bias at rest is minus the gravity torque).
        np.testing.assert_allclose(scene.data.qfrc_bias[scene._dof], -pushing.gravity_torque(q), atol=1e-12)


def test_every_push_pose_is_reachable_inside_joint_limits():
    lo, hi = np.array(pushing.ARM.joint_range).T
    for pos in pushing.POSITIONS:
        x, y = pos.xy
        outer = y + pos.sign * (pushing.BLOCK_SIZE[1] / 2 + 0.02)
        for tip in ([x, outer, 0.02], [x, outer, 0.09], [x, -pos.sign * 0.01, 0.03], [x + 0.03, 0.0, 0.03]):
            q = pushing.inverse_kinematics(np.array(tip))
            assert np.all(q > lo) and np.all(q < hi), (pos.name, tip, q)


def test_positions_geometry():
    assert [p.name for p in pushing.POSITIONS] == [
        "left_4.5cm", "left_8cm", "left_11.5cm", "right_4.5cm", "right_8cm", "right_11.5cm"
    ]
    for p in pushing.POSITIONS:
        # Centre offset laterally by the distance, on the named side, at a fixed reach.
        assert p.xy[1] == pytest.approx(p.sign * p.distance)
        assert p.xy[0] == pytest.approx(pushing.BLOCK_REACH_X)
        # No block straddles the centre line before the push.
        assert abs(p.xy[1]) - pushing.BLOCK_SIZE[1] / 2 > 0


def _settle(scene, steps, block_force=None):
    """Hold the arm still (gravity compensated) and optionally push the block horizontally."""
    for _ in range(steps):
        if block_force is not None:
            scene.data.xfrc_applied[scene.block_body, :3] = block_force
        scene.step(-pushing.gravity_torque(scene.q))
    scene.data.xfrc_applied[:] = 0.0


def test_untouched_block_stays_put(scene):
    for pos in (pushing.POSITIONS[0], pushing.POSITIONS[5]):
        scene.reset(pos, pushing.SceneVariation.sample(np.random.default_rng(pos.index)))
        start = scene.block_pose
        _settle(scene, 1000)
        end = scene.block_pose
        assert np.linalg.norm(end[:2] - start[:2]) < 1e-4  # < 0.1 mm in a second
        assert abs(end[2] - start[2]) < 3e-4  # only the soft contact's static penetration
        assert abs(np.dot(end[3:], start[3:])) > 1 - 1e-8  # no turning
        assert not scene.success()


def test_friction_holds_below_and_slides_above_mu_m_g(scene):
    limit = pushing.BLOCK_TABLE_FRICTION * pushing.BLOCK_MASS * pushing.PUSHING_GRAVITY  # ~0.59 N
    scene.reset(pushing.POSITIONS[1])
    start = scene.block_pose
    _settle(scene, 500, block_force=[0.0, -0.7 * limit, 0.0])
    assert np.linalg.norm(scene.block_pose[:2] - start[:2]) < 2e-4  # static friction holds (no creep)
    _settle(scene, 500, block_force=[0.0, -1.5 * limit, 0.0])
    assert start[1] - scene.block_pose[1] > 0.01  # it slid towards the centre line


def test_images(scene):
    variation = pushing.SceneVariation()  # identical nuisance: only the block position differs
    images = {}
    for index in (0, 2, 3):
        scene.reset(pushing.POSITIONS[index], variation)
        for camera in pushing.CAMERAS:
            img = scene.render(camera)
            assert img.shape == (64, 64, 3) and img.dtype == np.uint8
            assert img.std() > 10  # not blank
            images[index, camera] = img.astype(int)
    for camera in pushing.CAMERAS:
        assert np.abs(images[0, camera] - images[2, camera]).mean() > 1.0
        assert np.abs(images[0, camera] - images[3, camera]).mean() > 1.0
    for index in (0, 2, 3):
        assert np.abs(images[index, "default"] - images[index, "position1"]).mean() > 10
        assert np.abs(images[index, "default"] - images[index, "position2"]).mean() > 10
    # Same placement, different light/colour/jitter: similar but not identical images.
    scene.reset(pushing.POSITIONS[0], pushing.SceneVariation.sample(np.random.default_rng(3)))
    jittered = scene.render("default").astype(int)
    difference = np.abs(jittered - images[0, "default"]).mean()
    assert 0.1 < difference < np.abs(images[0, "default"] - images[3, "default"]).mean() * 5


def test_bad_arguments(scene):
    with pytest.raises(ValueError, match="0..5"):
        pushing.block_position(6)
    with pytest.raises(ValueError, match="0..5"):
        pushing.block_position(True)
    with pytest.raises(ValueError, match="unknown camera"):
        scene.render("ceiling")
    with pytest.raises(ValueError, match="outside the arm's reach"):
        pushing.inverse_kinematics(np.array([0.5, 0.0, 0.0]))


def test_success_means_centre_across_the_line(scene):
    scene.reset(pushing.POSITIONS[0])  # left: y > 0
    assert not scene.success()
    adr = scene._block_qpos
    scene.data.qpos[adr + 1] = -0.001
    assert scene.success()
    scene.reset(pushing.POSITIONS[3])  # right: y < 0
    scene.data.qpos[adr + 1] = 0.001
    assert scene.success()
    assert math.isclose(scene.position.sign, -1.0)
