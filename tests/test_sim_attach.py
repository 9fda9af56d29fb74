"""One attach of a standard arm to a world spec (:func:`seqmotion.sim.scene.attach_robot`): the arm scenes and the
standard-arm pushing world put the robot in by the same code."""

from __future__ import annotations

import importlib.util
import math
import os
import warnings
from dataclasses import replace

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo is first imported: offscreen rendering

from seqmotion.sim import robot_models as rb  # noqa: E402
from seqmotion.sim.backend import import_mujoco  # noqa: E402
from seqmotion.sim.scene import attach_robot, build_scene, robot_prefix  # noqa: E402

ROBOSUITE = rb.robosuite_root()
pytestmark = pytest.mark.skipif(ROBOSUITE is None or not (ROBOSUITE / "panda" / "robot.xml").is_file(),
                                reason="robosuite's robot model files are not installed (pip install --no-deps "
                                       "'robosuite>=1.5,<1.6')")

WORLD = """<mujoco><option timestep="0.002" integrator="RK4"/><worldbody>
<geom name="floor" type="plane" size="1 1 0.1"/></worldbody></mujoco>"""


def _arm_fields(model: object, prefix: str) -> dict[str, np.ndarray]:
    """The attached arm's bodies, joints and motors as compiled (positions relative to the arm's root body)."""
    bodies = [i for i in range(model.nbody) if model.body(i).name.startswith(prefix)]
    joints = [i for i in range(model.njnt) if model.joint(i).name.startswith(prefix)]
    dofs = [int(model.jnt_dofadr[j]) for j in joints]
    motors = [i for i in range(model.nu) if model.actuator(i).name.startswith(prefix)]
    return {"body_mass": model.body_mass[bodies], "body_inertia": model.body_inertia[bodies],
            "body_ipos": model.body_ipos[bodies], "body_pos": model.body_pos[bodies[1:]],
            "body_quat": model.body_quat[bodies[1:]], "jnt_range": model.jnt_range[joints],
            "dof_damping": model.dof_damping[dofs], "dof_armature": model.dof_armature[dofs],
            "actuator_ctrlrange": model.actuator_ctrlrange[motors],
            "names": np.array([model.body(i).name for i in bodies] + [model.joint(j).name for j in joints])}


def test_attach_robot_puts_the_arm_at_its_base_under_its_prefix_and_returns_the_flange():
    mujoco = import_mujoco()
    robot = replace(rb.get_robot("panda"), base_pos=np.array([0.1, -0.2, 0.05]), base_yaw=math.pi / 3)
    world = mujoco.MjSpec.from_string(WORLD)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the robot takes the world's options first: no attach conflict
        flange = attach_robot(world, robot)
    prefix = robot_prefix(robot)
    assert flange.name == prefix + robot.flange
    model = world.compile()
    assert model.opt.timestep == 0.002 and model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4  # the world's
    assert [model.joint(i).name for i in range(model.njnt)] == [prefix + j for j in robot.joints]
    assert model.nu == robot.dof
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    root = next(i for i in range(model.nbody) if model.body(i).name.startswith(prefix))
    np.testing.assert_allclose(data.xpos[root], robot.base_pos, atol=1e-12)
    yaw = math.atan2(data.xmat[root].reshape(3, 3)[1, 0], data.xmat[root].reshape(3, 3)[0, 0])
    assert yaw == pytest.approx(math.pi / 3, abs=1e-12)
    with pytest.raises(ValueError, match="MjSpec"):
        attach_robot(WORLD, robot)


@pytest.mark.skipif(importlib.util.find_spec("mink") is None, reason="mink is not installed (seqmotion[robots])")
def test_the_arm_scenes_and_the_pushing_world_attach_the_same_arm():
    """The same robot at the same base is the same arm in the pancake scene and in the pushing world (bodies,
    inertias, joints, ranges, damping, motors), each world keeping its own options."""
    from seqmotion.lfd.env.robot import BASE, RobotPushingScene

    pushing = RobotPushingScene("panda")
    try:
        robot = pushing.robot
        scene = build_scene("pancake", replace(robot, base_pos=np.asarray(BASE, dtype=np.float64)))
        prefix = robot_prefix(robot)
        ours, theirs = _arm_fields(pushing.model, prefix), _arm_fields(scene.model, prefix)
        assert ours.keys() == theirs.keys()
        for name in ours:
            np.testing.assert_array_equal(ours[name], theirs[name], err_msg=name)
        assert pushing.model.opt.timestep == 1e-3 and scene.model.opt.timestep == 5e-4
        assert pushing.model.body(pushing.model.body("pen_holder").parentid[0]).name == prefix + robot.flange
    finally:
        pushing.close()
