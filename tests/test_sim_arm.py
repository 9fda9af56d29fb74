"""The shared arm layer: one control period, the Arm, the scene cache, gravity, rendering, μ of the cone."""

import argparse
import ast
import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo is first imported: offscreen rendering

from seqmotion.sim import arm, backend, run_pancake  # noqa: E402
from seqmotion.sim.control import resolve_gains  # noqa: E402
from seqmotion.sim.kinematics import attitude_matrix, matrix_to_quat  # noqa: E402
from seqmotion.sim.motions import still  # noqa: E402
from seqmotion.sim.scene import PANCAKE_MASS, PANCAKE_ORIGIN, SUBSTEPS, TOOL_PITCH  # noqa: E402
from seqmotion.tasks.pancake import physics as pancake_physics  # noqa: E402

SIM = Path(__file__).resolve().parents[1] / "src" / "seqmotion" / "sim"


def _start_pose() -> tuple[np.ndarray, np.ndarray]:
    return PANCAKE_ORIGIN.copy(), matrix_to_quat(attitude_matrix(np.array([0.0, TOOL_PITCH, 0.0])))


def _started_arm() -> arm.Arm:
    scene = arm.get_scene("pancake")
    a = arm.Arm(scene, resolve_gains("ch2"))
    a.reset(*_start_pose(), arm.place_on_tool(scene, 0.0, np.zeros(2)), arm.weight(PANCAKE_MASS))
    return a


def test_control_period_is_step1_torque_step2_then_held_substeps():
    mujoco = backend.import_mujoco()
    a, b = _started_arm(), _started_arm()
    m = a.scene.model
    tau = np.array([0.5, -1.0, 2.0, 0.1, -0.2, 0.05])
    seen = []

    def torque():
        seen.append(a.data.site_xpos[a.scene.site].copy())  # kinematics of the current state are there
        return tau

    for _ in range(5):
        assert backend.control_period(m, a.data, torque, SUBSTEPS) is tau
        b.data.ctrl[:] = tau
        for _ in range(SUBSTEPS):
            mujoco.mj_step(m, b.data)
        np.testing.assert_array_equal(a.data.qpos, b.data.qpos)  # bit for bit: one mj_step per substep
        np.testing.assert_array_equal(a.data.qvel, b.data.qvel)
    assert len(seen) == 5 and a.data.time == pytest.approx(5 * backend.CONTROL_DT)


def test_control_period_stops_before_advancing_when_the_torque_is_refused():
    a = _started_arm()
    qpos, time = a.data.qpos.copy(), a.data.time
    assert backend.control_period(a.scene.model, a.data, lambda: None, SUBSTEPS) is None
    assert a.data.time == time
    np.testing.assert_array_equal(a.data.qpos, qpos)
    calls = []
    pos, quat = _start_pose()
    still6 = np.zeros(6)
    assert a.step(pos, quat, still6, still6, inspect=lambda tau: calls.append(tau.copy()) or False) is None
    assert len(calls) == 1 and a.data.time == time


def test_arm_holds_the_pancake_at_rest_on_the_blade():
    a = _started_arm()
    pos, quat = _start_pose()
    still6 = np.zeros(6)
    start = a.data.qpos[a.scene.body_qpos : a.scene.body_qpos + 3].copy()
    for _ in range(200):
        a.step(pos, quat, still6, still6)
    assert not a.diverged()
    assert np.linalg.norm(a.data.site_xpos[a.scene.site] - pos) < 1e-3
    assert np.linalg.norm(a.data.qpos[a.scene.body_qpos : a.scene.body_qpos + 3] - start) < 1e-3
    with pytest.raises(RuntimeError, match="reset"):
        arm.Arm(a.scene, a.gains).step(pos, quat, still6, still6)


def test_scene_cache_and_gravity_are_shared():
    assert arm.get_scene("pancake") is arm.get_scene("pancake")
    assert backend.GRAVITY == pancake_physics.GRAVITY == 9.8
    np.testing.assert_array_equal(arm.weight(2.0), [0.0, 0.0, -2.0 * 9.8])
    assert arm.get_scene("sliding").model.opt.gravity[2] == -backend.GRAVITY
    from seqmotion.lfd.env import pushing

    # The pushing scene keeps 9.81 on purpose (its shipped policy was evaluated there).
    assert backend.PUSHING_GRAVITY == 9.81
    scene = pushing.PushingScene()
    try:
        assert scene.model.opt.gravity[2] == -backend.PUSHING_GRAVITY
    finally:
        scene.close()


def test_envs_use_only_public_names_of_other_modules():
    tree = ast.parse((SIM / "envs.py").read_text())
    private = [
        (node.module, alias.name)
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
        if alias.name.startswith("_")
    ]
    assert private == []


def test_only_the_backend_imports_mujoco_and_steps_it():
    """One MuJoCo import (with the MUJOCO_GL default) and one control-period step for every scene."""
    for path in SIM.glob("*.py"):
        text = path.read_text()
        if path.name != "backend.py":
            # (mujoco_menagerie, the robot models' source, is another package)
            assert re.search(r"import mujoco\b(?!_)", text) is None, path.name
            assert re.search(r"\bmj_step\d?\(", text) is None, path.name
        if path.name != "render.py":
            assert ".Renderer(" not in text, path.name


def test_renderer_named_and_free_cameras():
    from seqmotion.sim.render import Renderer, free_camera

    scene = arm.get_scene("pancake")
    try:
        renderer = Renderer(scene.model, 64, 48)
    except RuntimeError as exc:  # no OpenGL on this machine (CI installs Mesa's EGL)
        pytest.skip(str(exc))
    a = _started_arm()
    try:
        named = renderer.render(a.data, "oblique")
        free = renderer.render(a.data, free_camera((0.5, 0.0, 0.3), 1.5, 180.0, -20.0))
        assert named.shape == free.shape == (48, 64, 3) and named.dtype == np.uint8
        assert np.abs(named.astype(int) - free.astype(int)).mean() > 1.0
        with pytest.raises(ValueError, match="no camera named"):
            renderer.render(a.data, "ceiling")
    finally:
        renderer.close()


@pytest.fixture(scope="module")
def tilted_runs():
    """The spatula held at 42°: inside the μ = 1 cone (45°), outside the μ = 0.8 cone (38.7°)."""
    states = still(math.radians(42), 0.3)
    return states, run_pancake(states, hold_time=0.0), run_pancake(states, hold_time=0.0, mu=0.8)


def test_executed_violation_is_judged_with_the_given_mu(tilted_runs):
    _, at_1, at_08 = tilted_runs
    # μ only judges the executed motion; the simulation (contact μ = 1) is the same run.
    np.testing.assert_array_equal(at_1.response, at_08.response)
    assert at_1.mu == 1.0 and at_08.mu == 0.8
    assert not at_1.contact_lost  # the simulated pancake (μ = 1) really sticks at 42°
    assert at_1.executed_violation.max() < 0.01
    # Held still the specific force is g, so ψ = -42° and F_c = 42° - atan 0.8 ≈ 0.058 rad.
    expected = math.radians(42) - math.atan(0.8)
    assert np.median(at_08.executed_violation) == pytest.approx(expected, abs=0.01)
    assert at_08.summary()["executed_max_violation_rad"] > at_1.summary()["executed_max_violation_rad"] + 0.04


def test_psi_plot_shades_the_runs_cone(tilted_runs, tmp_path):
    from seqmotion.sim import plot_pancake_psi

    states, _, at_08 = tilted_runs
    assert plot_pancake_psi(states, at_08, tmp_path / "psi.png").stat().st_size > 0
    with pytest.raises(ValueError, match="mu"):
        plot_pancake_psi(states, at_08, tmp_path / "bad.png", mu=0.0)


@pytest.mark.parametrize("mu", [0.0, -0.5, float("nan"), float("inf"), True, "1"])
def test_bad_mu_is_refused_before_simulating(mu):
    with pytest.raises(ValueError, match="mu"):
        run_pancake(still(0.0, 0.01), mu=mu)


def test_cli_mu_and_atomic_json(tmp_path):
    from seqmotion.sim import cli

    parser = argparse.ArgumentParser()
    cli.add_parser(parser.add_subparsers(dest="command"))
    np.savez(tmp_path / "still.npz", states=still(math.radians(42), 0.2))
    out = tmp_path / "out" / "m.json"
    args = parser.parse_args(["simulate", "pancake", "--trajectory", str(tmp_path / "still.npz"),
                              "--mu", "0.8", "--json", str(out)])
    assert cli.run(args) == 0
    metrics = json.loads(out.read_text())["metrics"]
    assert metrics["executed_max_violation_rad"] > 0.04
    assert sorted(p.name for p in out.parent.iterdir()) == ["m.json"]  # no temporary file left behind
    np.savez(tmp_path / "pan.npz", pan_states=np.zeros((50, 4)))
    args = parser.parse_args(["simulate", "sliding", "--trajectory", str(tmp_path / "pan.npz"), "--mu", "0.5"])
    with pytest.raises(ValueError, match="--mu"):
        cli.run(args)


@pytest.mark.parametrize("kind", ["pancake", "sliding"])
def test_the_built_in_arm_by_name_gets_the_built_in_arms_workspace_verdicts(kind):
    """``robot="mh3f"`` (the built-in arm's name) is resolved to the built-in arm: its reach is checked, as with
    ``robot=None`` (a name tested as "a robot was given" skipped it, leaving only the table)."""
    from seqmotion.sim.kinematics import pan_reference, planar_reference
    from seqmotion.sim.robot_models import BUILT_IN

    if kind == "pancake":  # [y, z, θ] held: in reach, out to the side, out below, out to the other side tilted
        poses = [(0.0, 0.0, 0.0), (0.45, 0.0, 0.0), (0.0, -0.45, 0.0), (-0.45, 0.1, 1.0), (0.0, 0.3, 0.0)]
        refs = [planar_reference(np.tile(np.r_[p, 0.0, 0.0, 0.0], (3, 1))) for p in poses]
    else:  # pan [x, y] held: at its origin, far forward, far to the side
        poses = [(0.0, 0.0), (0.3, 0.0), (0.0, 0.5)]
        refs = [pan_reference(np.tile(np.r_[p, 0.0, 0.0], (3, 1))) for p in poses]
    verdicts = [arm.workspace_problem(r, kind) for r in refs]
    assert [arm.workspace_problem(r, kind, BUILT_IN) for r in refs] == verdicts
    assert verdicts[0] is None and sum("from the shoulder" in (v or "") for v in verdicts) >= 2
    for ref, verdict in zip(refs, verdicts, strict=True):
        for robot in (None, BUILT_IN):
            if verdict is None:
                arm.prepare_reference(ref, kind, accel_feedforward=True, check_workspace=True, robot=robot)
            else:
                with pytest.raises(ValueError, match="workspace"):
                    arm.prepare_reference(ref, kind, accel_feedforward=True, check_workspace=True, robot=robot)


def test_run_pancake_refuses_a_motion_out_of_the_built_in_arms_reach_by_name():
    states = np.zeros((50, 6))
    states[:, 0] = 0.45  # the tool 0.45 m to the side: past the built-in arm's reach, above the table
    for robot in (None, "mh3f"):
        with pytest.raises(ValueError, match="wrist centre"):
            run_pancake(states, robot=robot)


def test_joint_report_judges_the_joint_arrays_it_is_given():
    scene = arm.get_scene("pancake")
    n, dt = len(scene.arm_dof), 1e-3
    empty = arm.joint_report(scene, dt, joint_pos=np.zeros((0, n)), joint_vel=np.zeros((0, n)),
                             torque=np.zeros((0, n)), saturated=np.zeros(0, dtype=bool), ik_error=np.zeros((0, 2)))
    assert empty.problem is None and empty.ik_error == (0.0, 0.0) and np.all(empty.speed_peak == 0)
    qd = np.zeros((4, n))
    qd[2, 1] = -3.0
    tau = np.full((4, n), 0.5)
    ik = np.zeros((4, 2))
    ik[3] = (1e-4, 2e-3)
    report = arm.joint_report(scene, dt, joint_pos=np.zeros((4, n)), joint_vel=qd, torque=tau,
                              saturated=np.zeros(4, dtype=bool), ik_error=ik)
    assert report.robot == arm.BUILT_IN_ARM and report.joints == scene.arm_joints
    np.testing.assert_array_equal(report.speed_peak, np.abs(qd).max(axis=0))
    np.testing.assert_array_equal(report.torque_peak, np.full(n, 0.5))
    assert report.ik_error == (1e-4, 2e-3) and report.problem is None  # the built-in arm's limits are unknown


def test_the_runners_hand_every_executed_period_to_observe():
    """``observe=`` reaches the control step's recording hook: the caller reads the very run it gets the verdict
    of (the viewer's replay), every period of the reference, with the kinematics of that period's state."""
    from seqmotion.sim import run_sliding
    from seqmotion.sim.kinematics import planar_reference

    states = np.zeros((40, 6))
    seen: list[int] = []
    sites: list[np.ndarray] = []
    site = arm.get_scene("pancake").site

    def observe(k: int, data: object) -> None:
        seen.append(k)
        sites.append(data.site_xpos[site].copy())

    result = run_pancake(states, hold_time=0.0, decel_time=0.0, settle_time=0.01, observe=observe)
    ref = planar_reference(states, decel_time=0.0, hold_time=0.0)
    assert seen == list(range(len(ref))) == list(range(len(result.time)))
    np.testing.assert_allclose(np.array(sites), ref.pos, atol=1e-3)  # held at the start pose
    plain = run_pancake(states, hold_time=0.0, decel_time=0.0, settle_time=0.01)
    np.testing.assert_array_equal(plain.slip, result.slip)  # observing changes nothing
    pan_seen: list[int] = []
    run_sliding(np.zeros((30, 4)), hold_time=0.0, decel_time=0.0, settle_time=0.01,
                observe=lambda k, data: pan_seen.append(k))
    assert pan_seen == list(range(30))
    assert not hasattr(arm, "observing")  # no process-wide hook besides the explicit one
