"""Standard robot arms: where their models come from (robosuite's files, Menagerie through mujoco_menagerie),
the arm alone as an MjSpec (torque motors at the model's limits), and the scenes built on them."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo is first imported: offscreen rendering

from seqmotion.sim import robot_models as rb  # noqa: E402
from seqmotion.sim.backend import import_mujoco  # noqa: E402
from seqmotion.sim.kinematics import attitude_matrix  # noqa: E402
from seqmotion.sim.scene import SITE_IN_TOOL, build_scene, get_scene, scene_xml  # noqa: E402

ROBOSUITE = rb.robosuite_root()
needs_robosuite = pytest.mark.skipif(
    ROBOSUITE is None or not (ROBOSUITE / "panda" / "robot.xml").is_file()
    or not (ROBOSUITE / "ur5e" / "robot.xml").is_file(),
    reason="robosuite's robot model files are not installed (pip install --no-deps 'robosuite>=1.5,<1.6')",
)
try:
    import mujoco_menagerie as mm
except ImportError:  # pragma: no cover - the robots extra is missing
    mm = None
needs_menagerie = pytest.mark.skipif(mm is None, reason="mujoco-menagerie is not installed (seqmotion[robots])")

# A small 6-joint arm written the way Menagerie writes its arms: position servos (`general` with an affine
# bias, `position`) whose torque limits are a class default, an override, and a joint's actuatorfrcrange;
# a gripper finger with a tendon, an equality and its own actuator; a sensor, a keyframe, a light, a floor,
# a skybox; an attachment site at the flange.
TINY_ARM = """<mujoco model="tiny">
  <compiler angle="radian" autolimits="true"/>
  <option integrator="implicit"/>
  <default>
    <default class="arm">
      <joint armature="0.05" damping="0.5" axis="0 1 0" range="-2.8 2.8"/>
      <general dyntype="none" biastype="affine" ctrlrange="-2.8 2.8" forcerange="-40 40"/>
      <default class="visual"><geom contype="0" conaffinity="0" group="2"/></default>
      <default class="collision"><geom group="3"/></default>
    </default>
  </default>
  <asset>
    <texture type="skybox" builtin="gradient" rgb1="0.3 0.5 0.7" rgb2="0 0 0" width="32" height="32"/>
  </asset>
  <worldbody>
    <light name="top" pos="0 0 2"/>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="base" childclass="arm">
      <geom class="visual" type="cylinder" size="0.06 0.05" pos="0 0 0.05"/>
      <body name="link1" pos="0 0 0.1">
        <joint name="s" axis="0 0 1"/>
        <inertial pos="0 0 0.1" mass="3" diaginertia="0.03 0.03 0.01"/>
        <geom class="visual" type="capsule" fromto="0 0 0 0 0 0.25" size="0.05"/>
        <geom class="collision" type="capsule" fromto="0 0 0 0 0 0.25" size="0.055"/>
        <body name="link2" pos="0 0 0.25">
          <joint name="l"/>
          <inertial pos="0 0 0.15" mass="2" diaginertia="0.02 0.02 0.004"/>
          <geom class="visual" type="capsule" fromto="0 0 0 0 0 0.3" size="0.04"/>
          <body name="link3" pos="0 0 0.3">
            <joint name="u"/>
            <inertial pos="0.12 0 0" mass="1.5" diaginertia="0.002 0.008 0.008"/>
            <geom class="visual" type="capsule" fromto="0 0 0 0.28 0 0" size="0.035"/>
            <body name="link4" pos="0.1 0 0">
              <joint name="r" axis="1 0 0" actuatorfrcrange="-12 12"/>
              <inertial pos="0.1 0 0" mass="0.8" diaginertia="0.001 0.003 0.003"/>
              <body name="link5" pos="0.18 0 0">
                <joint name="b"/>
                <inertial pos="0.02 0 0" mass="0.4" diaginertia="0.0004 0.0004 0.0004"/>
                <geom class="visual" type="sphere" size="0.035"/>
                <body name="link6" pos="0.06 0 0">
                  <joint name="t" axis="1 0 0" range="-3 3"/>
                  <inertial pos="0.01 0 0" mass="0.2" diaginertia="0.0002 0.0002 0.0002"/>
                  <geom class="visual" type="cylinder" size="0.03 0.01" quat="1 0 1 0"/>
                  <site name="attachment_site" pos="0.02 0 0" quat="1 0 1 0"/>
                  <body name="finger" pos="0.05 0 0">
                    <joint name="finger_joint" type="slide" axis="0 1 0" range="0 0.04"/>
                    <inertial pos="0 0 0" mass="0.02" diaginertia="1e-6 1e-6 1e-6"/>
                    <geom class="collision" type="box" size="0.005 0.01 0.02"/>
                  </body>
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <contact><exclude body1="link6" body2="finger"/></contact>
  <tendon><fixed name="split"><joint joint="finger_joint" coef="1"/></fixed></tendon>
  <equality><joint joint1="finger_joint" joint2="t" polycoef="0 0 0 0 0"/></equality>
  <actuator>
    <general class="arm" name="a_s" joint="s" gainprm="300" biasprm="0 -300 -30"/>
    <general class="arm" name="a_l" joint="l" gainprm="300" biasprm="0 -300 -30" forcerange="-60 60"/>
    <position name="a_u" joint="u" kp="200" forcerange="-30 30" ctrlrange="-2.8 2.8"/>
    <position name="a_r" joint="r" kp="50"/>
    <general class="arm" name="a_b" joint="b" gainprm="50" biasprm="0 -50 -5" forcerange="-12 12"/>
    <general class="arm" name="a_t" joint="t" gainprm="50" biasprm="0 -50 -5" forcerange="-5 5"/>
    <general class="arm" name="a_finger" tendon="split" forcerange="-5 5" ctrlrange="0 255" gainprm="0.01"
             biasprm="0 -100 -10"/>
  </actuator>
  <sensor><jointpos joint="t"/></sensor>
  <keyframe><key name="home" qpos="0 0.5 1.0 0 -1.0 0 0.01"/></keyframe>
</mujoco>
"""
TINY_TORQUES = [40.0, 60.0, 30.0, 12.0, 12.0, 5.0]
"""The tiny arm's torque limits, per joint: class default, override, position's forcerange, the joint's
actuatorfrcrange (its servo has none), class override, override."""
TINY_NAME = "trossen_wx250s"
"""A Menagerie arm (registry name) outside seqmotion's table of known arms: the generic path."""


@pytest.fixture
def menagerie_root(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A local tree in the MENAGERIE_ROOT layout holding the tiny arm as Menagerie's ``trossen_wx250s``."""
    entry = mm.get(TINY_NAME).entry(mm.get(TINY_NAME).default_model).file
    folder = tmp_path / TINY_NAME
    folder.mkdir()
    (folder / entry).write_text(TINY_ARM)
    monkeypatch.setenv("MENAGERIE_ROOT", str(tmp_path))
    rb.get_robot.cache_clear()
    yield tmp_path
    rb.get_robot.cache_clear()


def _actuators(model) -> list[tuple[str, str]]:
    mujoco = import_mujoco()
    return [(model.actuator(i).name, mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, model.actuator_trnid[i, 0]))
            for i in range(model.nu)]


def _check_motors(model, robot: rb.Robot) -> None:
    """One torque motor per arm joint named after it, at the model's limit; no servo, no collision."""
    mujoco = import_mujoco()
    assert _actuators(model) == [(j, j) for j in robot.joints]
    assert np.all(model.actuator_biastype == mujoco.mjtBias.mjBIAS_NONE)  # no position servo left
    assert np.all(model.actuator_dyntype == mujoco.mjtDyn.mjDYN_NONE)
    assert np.all(model.actuator_gaintype == mujoco.mjtGain.mjGAIN_FIXED)
    np.testing.assert_array_equal(model.actuator_gainprm[:, 0], 1.0)
    np.testing.assert_array_equal(model.actuator_gear[:, 0], 1.0)
    assert np.all(model.actuator_ctrllimited)
    np.testing.assert_array_equal(model.actuator_ctrlrange, np.stack([-robot.torque_limit, robot.torque_limit], 1))
    assert not model.geom_contype.any() and not model.geom_conaffinity.any()


@needs_robosuite
def test_listing_has_the_built_in_arm_and_robosuites_panda_and_ur5e():
    listed = {(r.name, r.source): r for r in rb.robots()}
    assert listed[("mh3f", "seqmotion")].dof == 6 and listed[("mh3f", "seqmotion")].path is None
    assert listed[("panda", "robosuite")].dof == 7 and listed[("ur5e", "robosuite")].dof == 6
    assert listed[("panda", "robosuite")].path == ROBOSUITE / "panda" / "robot.xml"


@needs_robosuite
def test_panda_spec_is_the_arm_alone_with_torque_motors_at_its_file_limits():
    robot = rb.get_robot("panda")
    assert robot.label == "panda (robosuite)" and robot is rb.get_robot("panda")  # one object per name
    assert robot.joints == tuple(f"joint{i}" for i in range(1, 8)) and robot.flange == "right_hand"
    np.testing.assert_array_equal(robot.torque_limit, [80, 80, 80, 80, 80, 12, 12])  # robosuite's ctrlrange
    np.testing.assert_allclose(robot.joint_range[3], [-3.0718, -0.0698])
    np.testing.assert_allclose(robot.velocity_limit, [2.175] * 4 + [2.61] * 3)  # Franka's datasheet
    model = robot.spec().compile()
    _check_motors(model, robot)
    assert model.nq == 7 and model.nlight == 0 and model.nkey == 0
    # robosuite's collision meshes (group 0) are hidden behind its visual meshes (group 1).
    assert set(model.geom_group.tolist()) == {1, 3}


@needs_robosuite
@pytest.mark.parametrize("kind", ["pancake", "sliding"])
def test_scene_on_a_robot_has_the_tool_on_its_flange_and_the_same_world(kind):
    mujoco = import_mujoco()
    robot = rb.get_robot("panda")
    scene = get_scene(kind, "panda")
    assert scene is get_scene(kind, robot) and scene.robot == rb.placed_for(robot, kind)
    m, d = scene.model, None
    default = get_scene(kind).model  # the built-in arm's scene
    for name in ("timestep", "impratio", "noslip_iterations", "tolerance", "cone", "solver", "integrator",
                 "jacobian"):
        assert getattr(m.opt, name) == getattr(default.opt, name), name
    np.testing.assert_array_equal(m.opt.gravity, default.opt.gravity)
    assert scene.arm_qpos.size == scene.arm_dof.size == 7 and scene.arm_joints[0] == "panda/joint1"
    for cam in (["front", "oblique"] if kind == "pancake" else ["front", "top"]):
        assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, cam) >= 0
    assert m.npair == default.npair
    # The tool: the same geoms (shape, friction, contact parameters, mass) as on the built-in arm.
    tool, tool0 = m.body("tool").id, default.body("tool").id
    geoms = np.flatnonzero(m.geom_bodyid == tool)
    geoms0 = np.flatnonzero(default.geom_bodyid == tool0)
    assert len(geoms) == len(geoms0) > 0
    for field in ("geom_size", "geom_pos", "geom_quat", "geom_friction", "geom_solref", "geom_solimp",
                  "geom_condim", "geom_contype", "geom_conaffinity", "geom_rgba"):
        np.testing.assert_allclose(getattr(m, field)[geoms], getattr(default, field)[geoms0], atol=1e-12,
                                   err_msg=field)
    np.testing.assert_allclose(m.body_mass[tool], default.body_mass[tool0])
    np.testing.assert_allclose(m.body_inertia[tool], default.body_inertia[tool0])
    # Only the tool, the object and the table collide: the arm's geoms never do.
    arm_bodies = {i for i in range(m.nbody) if m.body(i).name.startswith("panda/")}
    assert arm_bodies and not any(m.geom_contype[g] or m.geom_conaffinity[g] for g in range(m.ngeom)
                                  if m.geom_bodyid[g] in arm_bodies)
    # The control site sits where the tool frame says: the flange's mount frame, turned by the tool roll about its
    # z axis, then by the tool pitch about the turned y axis.
    d = mujoco.MjData(m)
    robot = scene.robot  # where it stands for this task
    d.qpos[scene.arm_qpos] = robot.home
    mujoco.mj_forward(m, d)
    flange_rot = d.site_xmat[scene.flange].reshape(3, 3)
    c, s = np.cos(robot.tool_roll), np.sin(robot.tool_roll)
    cp, sp = np.cos(robot.tool_pitch), np.sin(robot.tool_pitch)
    tool_rot = flange_rot @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ np.array([[cp, 0, sp], [0, 1, 0],
                                                                                    [-sp, 0, cp]])
    np.testing.assert_allclose(d.site_xpos[scene.site], d.site_xpos[scene.flange] + tool_rot @ SITE_IN_TOOL[kind],
                               atol=1e-9)
    np.testing.assert_allclose(d.site_xmat[scene.site].reshape(3, 3), tool_rot, atol=1e-9)
    if kind == "pancake":  # home holds the spatula at the planar origin, blade face up, pointing +x
        np.testing.assert_allclose(d.site_xpos[scene.site], [0.5, 0.0, 0.35], atol=1e-6)
        np.testing.assert_allclose(tool_rot, attitude_matrix(np.array([0.0, np.pi / 2, 0.0])), atol=1e-6)
    assert np.all((robot.home > robot.joint_range[:, 0]) & (robot.home < robot.joint_range[:, 1]))


@needs_robosuite
def test_robot_sags_without_torque_and_mujoco_clamps_torque_at_the_limit():
    mujoco = import_mujoco()
    robot = rb.get_robot("panda")
    scene = get_scene("pancake", "panda")
    m = scene.model
    d = mujoco.MjData(m)
    d.qpos[scene.arm_qpos] = robot.home
    mujoco.mj_forward(m, d)
    start = d.site_xpos[scene.site].copy()
    for _ in range(400):  # 0.2 s with no torque: the arm falls under gravity
        mujoco.mj_step(m, d)
    assert d.site_xpos[scene.site][2] < start[2] - 0.02
    d.ctrl[:] = 10 * robot.torque_limit * np.array([1, -1, 1, -1, 1, -1, 1])
    mujoco.mj_step(m, d)
    np.testing.assert_allclose(np.abs(d.actuator_force), robot.torque_limit)  # clamped to ctrlrange
    np.testing.assert_allclose(np.abs(d.qfrc_actuator[scene.arm_dof]), robot.torque_limit)


@needs_menagerie
def test_menagerie_arm_from_a_local_tree_loads_through_mujoco_menagerie_with_motors(menagerie_root):
    mujoco = import_mujoco()
    name = f"menagerie:{TINY_NAME}"
    assert (name, "menagerie", None) in {(r.name, r.source, r.dof) for r in rb.robots()}  # listed unread
    robot = rb.get_robot(name)
    assert robot.source == "menagerie" and robot.path == menagerie_root / TINY_NAME / robot.path.name
    assert robot.joints == ("s", "l", "u", "r", "b", "t") and robot.flange == "link6"
    np.testing.assert_array_equal(robot.torque_limit, TINY_TORQUES)
    np.testing.assert_allclose(robot.joint_range[5], [-3, 3])
    np.testing.assert_allclose(robot.mount_pos, [0.02, 0, 0])  # the attachment site's frame
    assert robot.velocity_limit is None  # not in the datasheet table: unknown, not guessed
    model = robot.spec().compile()
    _check_motors(model, robot)
    assert model.njnt == 6 and model.ntendon == 0 and model.neq == 0 and model.nsensor == 0
    assert model.nkey == 0 and model.nlight == 0 and model.nexclude == 0
    assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor") < 0
    # Its collision geom is hidden where the body has a visual one; nothing collides.
    assert model.geom_group[np.flatnonzero(model.geom_bodyid == model.body("link1").id)].tolist() == [2, 3]
    with warnings.catch_warnings():  # its own options (integrator="implicit") give way to the scene's quietly
        warnings.simplefilter("error")
        scene = build_scene("pancake", robot)  # its home posture was found by IK from the file's keyframe
    assert scene.model.opt.integrator == get_scene("pancake").model.opt.integrator
    d = mujoco.MjData(scene.model)
    d.qpos[scene.arm_qpos] = robot.home
    mujoco.mj_forward(scene.model, d)
    np.testing.assert_allclose(d.site_xpos[scene.site], [0.5, 0.0, 0.35], atol=1e-6)
    assert scene.model.nu == 6 and scene.arm_joints[0] == f"{TINY_NAME}/s"


def test_bad_and_unavailable_robots_are_refused_by_name(tmp_path, monkeypatch):
    monkeypatch.setenv("MENAGERIE_ROOT", str(tmp_path))  # an empty local tree: nothing may be downloaded
    rb.get_robot.cache_clear()
    try:
        for bad, words in [("nosuchbot", ["unknown robot 'nosuchbot'", "mh3f"]),
                           ("robosuite:baxter", ["unknown robosuite arm 'baxter'", "panda"]),
                           ("ros:panda", ["unknown robot source 'ros'"]),
                           ("", ["non-empty"]), ("mh3f", ["built-in"])]:
            with pytest.raises(ValueError) as err:
                rb.get_robot(bad)
            assert all(w in str(err.value) for w in words), str(err.value)
        with pytest.raises(ValueError, match="robot must be"):
            build_scene("pancake", robot=3)
        with pytest.raises(ValueError, match="scene kind"):
            build_scene("juggling", robot="panda")
        if mm is not None:
            with pytest.raises(ValueError, match="unknown Menagerie robot 'nosuchbot'"):
                rb.get_robot("menagerie:nosuchbot")
            with pytest.raises(ValueError, match="MENAGERIE_ROOT"):  # absent from the local tree, no download
                rb.get_robot("menagerie:kinova_gen3")
        monkeypatch.setattr(rb, "robosuite_root", lambda: None)  # neither source has the arm
        with pytest.raises(ValueError) as err:
            rb.get_robot("jaco")
        assert "not available here" in str(err.value) and "robosuite" in str(err.value)
    finally:
        rb.get_robot.cache_clear()


def test_the_home_poses_tool_site_is_the_scenes():
    np.testing.assert_allclose(rb.HOME_SITE_IN_TOOL, SITE_IN_TOOL["pancake"], rtol=0, atol=1e-15)
    np.testing.assert_allclose(rb.HOME_TOOL_POSE[1], attitude_matrix(np.array([0.0, np.pi / 2, 0.0])), atol=1e-15)


def test_the_built_in_arm_is_the_default_and_its_scene_text_is_unchanged():
    assert rb.resolve_robot(None) is None and rb.resolve_robot("mh3f") is None
    scene = build_scene("pancake")
    assert scene.robot is None and scene.arm_qpos.size == 6 and scene.model.nu == 6
    assert scene_xml("pancake").count("<motor ") == 6 and 'name="riser"' in scene_xml("pancake")
