"""``seqmotion view``: the server logic without a browser, then the page in a real headless browser.

The browser tests need viser, Python playwright and a Chromium executable (Debian's ``chromium``:
``.ci/run`` installs it with apt-get; ``SEQMOTION_CHROMIUM`` names another, ``SEQMOTION_CHROMIUM=none``
hides it). Where one is missing they skip, saying which; the module must then still exit cleanly (what
the servers it starts leave running is joined: ``.ci/run`` checks it with the browser hidden). They
start one server for the module (port 0: any free port), open the page once, and take ~30 s on two cores.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion.core.options import TaskOptions
from seqmotion.core.task import Task
from seqmotion.data.trajectories import TensorBatch, TrajectoryBatch, draw_lengths, s_curve
from seqmotion.errors import check_number
from seqmotion.io import read_arrays
from seqmotion.models.seq2seq import ChunkedSeq2Seq, Seq2SeqConfig
from seqmotion.physics.integrator import DT
from seqmotion.physics.layout import StateLayout
from seqmotion.physics.parameters import Physics
from seqmotion.tasks import train
from seqmotion.training.config import TrainConfig
from seqmotion.training.curriculum import Curriculum, CurriculumParams
from seqmotion.training.losses import encode_and_rollout, sample_mask
from seqmotion.view import commands, scene3d
from seqmotion.view.sessions import (
    LatentSession,
    PancakeControls,
    PancakeSession,
    Pca,
    SlidingControls,
    SlidingSession,
    TaskSession,
)


@pytest.fixture(scope="module")
def deformer():
    return sm.load_pretrained("pancake")


@pytest.fixture(scope="module")
def planner():
    return sm.load_pretrained("sliding")


# --- commands ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", commands.SHAPES)
def test_each_command_shape_starts_at_the_origin_and_ends_at_rest(shape):
    cmd = commands.command(shape, 0.04, 400, 30.0, "30,0; 40,20; 20,40")
    assert cmd.shape == (400, 4) and np.all(np.isfinite(cmd))
    np.testing.assert_allclose(cmd[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(cmd[-1, 2:], 0.0, atol=1e-9)
    assert np.linalg.norm(cmd[:, :2], axis=1).max() > 0.01


def test_a_spline_passes_through_the_points_entered():
    cmd = commands.command("spline", 0.0, 600, points="30,0; 40,20; 20,40")
    for p in commands.parse_points("30,0; 40,20; 20,40"):
        assert np.linalg.norm(cmd[:, :2] - p, axis=1).min() < 1e-3
    np.testing.assert_allclose(cmd[-1, :2], [0.02, 0.04], atol=1e-9)


@pytest.mark.parametrize("text", ["", "30", "a,b", "1,2,3", "nan,1"])
def test_bad_points_are_refused_by_name(text):
    with pytest.raises(ValueError, match="point|enter at least"):
        commands.parse_points(text)


def test_points_round_trip():
    pts = commands.parse_points("30,0\n40 20 | -20,40")
    np.testing.assert_allclose(pts, [[0.03, 0], [0.04, 0.02], [-0.02, 0.04]])
    np.testing.assert_allclose(commands.parse_points(commands.format_points(pts)), pts)


# --- sessions ----------------------------------------------------------------------------------------


def test_pancake_frame_follows_the_end_pose_and_is_cached(deformer):
    session = PancakeSession(deformer)
    a = session.update(PancakeControls(end_y=0.2))
    b = session.update(PancakeControls(end_y=0.1))
    assert a.states.shape == (500, 6) and a.psi.shape == (499,) and a.std.shape == (500, 3)
    assert a.cone == pytest.approx(np.arctan(deformer.options.mu))
    np.testing.assert_allclose(a.sketch[-1, :3], (0.2, 0.0, 2.5), atol=1e-9)
    assert not np.allclose(a.states[:, :2], b.states[:, :2])  # the deformed path moved with the slider
    assert session.update(PancakeControls(end_y=0.2)) is a and session.cache.hits == 1
    assert a.feasible and a.out_of_distribution is False and "max_violation_rad" in a.errors
    text = a.readout()
    assert "learned" in text and "in distribution" in text and "end position error" in text
    lo, hi = a.std_band(2)
    assert np.all(hi >= lo)


def test_pancake_keep_end_is_exact(deformer):
    frame = PancakeSession(deformer).update(PancakeControls(end_y=0.1, end_theta=3.0, keep_end=True))
    assert frame.exact is True and frame.source == "keep_end"
    np.testing.assert_allclose(frame.states[-1, :3], (0.1, 0.0, 3.0), atol=1e-6)


def test_pancake_latent_adjustment_reaches_the_target_update_by_update(deformer):
    session = PancakeSession(deformer)
    seen = []
    frame = session.adjust(PancakeControls(), (0.1, 0.0, np.pi), updates=5, on_update=lambda f: seen.append(f))
    assert [f.source for f in seen] == [f"latent {k}/5" for k in range(1, 6)]
    np.testing.assert_allclose(frame.states[-1, :3], (0.1, 0.0, np.pi), atol=2e-3)
    assert frame.target == pytest.approx((0.1, 0.0, np.pi)) and frame.feasible
    stopped = session.adjust(PancakeControls(), (0.1, 0.0, np.pi), updates=5, on_update=lambda f: True)
    assert stopped.source == "latent 1/5"  # a newer request stops it after the current update


@pytest.mark.parametrize("suffix", ["csv", "npz"])
def test_pancake_export(deformer, tmp_path, suffix):
    session = PancakeSession(deformer)
    frame = session.update(PancakeControls())
    path = session.export(frame, tmp_path / f"motion.{suffix}")
    got = read_arrays(path, ["states"])["states"]
    np.testing.assert_allclose(got[:, :6] if suffix == "csv" else got, frame.states, rtol=1e-6, atol=1e-9)


def test_sliding_frame_plans_each_shape_and_reacts_to_friction(planner, tmp_path):
    session = SlidingSession(planner)
    base = session.defaults()
    assert (base.mu, base.mu_dyn) == (planner.options.mu, planner.options.mu_dyn)
    for shape in commands.SHAPES:
        frame = session.update(SlidingControls(shape=shape, length=400))
        assert frame.obj.shape == (400, 4) and frame.pan.shape == (400, 4) and frame.tracking.shape == (400,)
        assert frame.errors["tracking_rmse_m"] == pytest.approx(np.sqrt(np.mean(frame.tracking**2)), rel=1e-6)
    slippery = session.update(SlidingControls(mu=0.2, mu_dyn=0.1, length=400))
    sticky = session.update(SlidingControls(mu=0.9, mu_dyn=0.8, length=400))
    assert not np.allclose(slippery.obj[:, :2], sticky.obj[:, :2])
    assert "RMSE" in sticky.readout()
    path = session.export(sticky, tmp_path / "plan.npz")
    assert read_arrays(path, ["pan_states"])["pan_states"].shape == (400, 4)


def test_generic_task_panel_uses_the_layout(planner):
    session = TaskSession(planner, n=4)
    frame = session.update(1)
    assert frame.state_names == tuple(planner.state_layout.names)
    gen, inp = frame.series("x")
    assert gen.shape == inp.shape == (len(frame.states),)
    assert frame.state_path is not None and frame.input_path is not None
    assert "input 1" in frame.readout()


# --- any registered task: a plug-in with its own physics and a torque output -----------------------------

JOINT = StateLayout(("q", "dq"), ("rad", "rad/s"), "joint state")
TORQUE = StateLayout(("tau",), ("N·m",), "joint torque")


@dataclass(frozen=True)
class JointPhysics(Physics):
    """A single joint's viscous damping [N·m·s/rad] and inertia [kg·m²]."""

    damping: float = 0.5
    inertia: float = 0.2

    def __post_init__(self) -> None:
        for name in ("damping", "inertia"):
            check_number(name, getattr(self, name), minimum=0.0, strict_minimum=name == "inertia")


@dataclass(frozen=True)
class JointOptions(TaskOptions):
    length: tuple[int, int] = (40, 60)
    max_speed: float = 2.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "length", tuple(self.length))


@dataclass(frozen=True)
class JointParams(CurriculumParams):
    teacher_forcing_prob: float


class JointDynamics:
    """``I q̈ = τ − b q̇``, semi-implicit Euler at 1 ms: its own physics, driven by a torque."""

    def __init__(self, physics: JointPhysics) -> None:
        self.damping, self.inertia, self.dt = physics.damping, physics.inertia, DT

    def start(self, x0: torch.Tensor) -> torch.Tensor:
        return x0

    def step(self, carry: torch.Tensor, mean: torch.Tensor, cov: torch.Tensor | None) -> tuple[torch.Tensor, dict]:
        q, dq, out = carry[:, 0], carry[:, 1], []
        for k in range(mean.shape[1]):
            dq = dq + self.dt * (mean[:, k, 0].to(carry.dtype) - self.damping * dq) / self.inertia
            q = q + self.dt * dq
            out.append(torch.stack([q, dq], dim=-1))
        states = torch.stack(out, dim=1)
        return states[:, -1], {"states": states}

    def decoder_input(self, states: torch.Tensor) -> torch.Tensor:
        return states

    def restart(self, carry: torch.Tensor, state: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return torch.where(mask.view(-1, 1), state.to(carry.dtype), carry)

    def narrow(self, carry: torch.Tensor, rows: int) -> torch.Tensor:
        return carry[:rows]


class JointTask(Task):
    """Follow a rough joint move with torques, the joint's speed under a limit."""

    name = "view_joint"
    presets = ("tiny", "small")
    options_class = JointOptions
    input_layout = state_layout = JOINT
    accel_layout = TORQUE
    physics_class = JointPhysics
    params_class = JointParams
    end_pose = (("q",), (1.0,))

    def train_config(self, preset: str) -> TrainConfig:
        model = Seq2SeqConfig(encoder_input_dim=2, decoder_input_dim=2, output_dim=1, chunk=10, layers=1, hidden=8,
                              correlated_pairs=[],
                              encoder_input_scale=[1.0, 1.0], decoder_input_scale=[1.0, 1.0], output_scale=[1.0])
        curriculum = Curriculum(epochs=1, initial={"teacher_forcing_prob": 0.5})
        return TrainConfig(task=self.name, preset=preset, model=model.to_dict(), curriculum=curriculum.to_dict(),
                           batches_per_epoch=2, batch_size=4, options=JointOptions().to_dict())

    def sample(self, n: int, rng: np.random.Generator, params: JointParams, options: JointOptions) -> TrajectoryBatch:
        lengths = draw_lengths(rng, n, options.length)
        k_max, end = int(lengths.max()), rng.uniform(-1.0, 1.0, n)
        states = np.zeros((n, k_max, 2))
        for b, k in enumerate(lengths):
            s, ds, _ = s_curve(np.linspace(0.0, 1.0, k))
            states[b, :k] = np.stack([end[b] * s, end[b] * ds / ((k - 1) * DT)], axis=1)
            states[b, k:] = states[b, k - 1]
        return TrajectoryBatch(states, lengths).longest_first()

    def loss(self, model: ChunkedSeq2Seq, batch: TensorBatch, dynamics: JointDynamics, params: JointParams,
             options: JointOptions, generator: torch.Generator) -> tuple[torch.Tensor, dict[str, float]]:
        states, lengths = batch.states, batch.lengths
        k_max = states.shape[1]
        out = encode_and_rollout(model, states, lengths, states[:, 0], dynamics, teacher=states,
                                 teacher_forcing_prob=params.teacher_forcing_prob, generator=generator)
        valid = sample_mask(lengths, k_max)
        error = ((out.states[:, 1:k_max] - states[:, 1:]) ** 2).sum(-1)
        speed = torch.relu(out.states[:, 1:k_max, 1].abs() - options.max_speed)
        return masked_mean_tensor(error + speed, valid), {"error": float(masked_mean_tensor(error.detach(), valid))}

    def dynamics(self, options: JointOptions, physics: JointPhysics) -> JointDynamics:
        return JointDynamics(physics)

    def violation(self, states: torch.Tensor, accel: torch.Tensor, options: JointOptions) -> torch.Tensor:
        return torch.relu(states[:, 1 : accel.shape[1] + 1, 1].abs() - options.max_speed)


def masked_mean_tensor(values: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    return (values * valid).sum() / valid.sum().clamp_min(1)


@pytest.fixture(scope="module")
def joint_run(tmp_path_factory):
    """A tiny model of a task registered by hand, with its own physics and a torque output, trained two steps."""
    from seqmotion.core import registry

    registry.register(JointTask())
    run = tmp_path_factory.mktemp("joint") / "run"
    train(registry.get("view_joint").train_config("tiny"), run, progress=False)
    yield run
    registry.refresh()


def test_generic_task_panel_for_a_plug_in_with_its_own_physics_and_torques(joint_run, tmp_path):
    model = sm.load(joint_run)
    session = TaskSession(model, n=3)
    assert len(session.inputs) == 3 and session.inputs[2].shape[1] == 2  # Task.example_inputs, like training's
    frame = session.update(2)
    k = len(session.inputs[2])
    assert frame.states.shape == (k, 2) and frame.accel.shape == (k - 1, 1) and frame.violation.shape == (k - 1,)
    assert frame.fields == ("q", "dq", "tau") and frame.unit("tau") == "N·m"
    tau, none = frame.series("tau")
    np.testing.assert_array_equal(tau, frame.accel[:, 0])
    assert none is None
    q, q_in = frame.series("q")
    np.testing.assert_array_equal(q_in, session.inputs[2][:, 0])
    assert frame.state_path is None and frame.path_names is None  # no metre fields: no path, plots only
    with pytest.raises(ValueError, match="no field 'x'.*'q', 'dq', 'tau'"):
        frame.series("x")
    assert "max constraint violation" in frame.readout()
    # the export names every column by the task's layouts
    path = session.export(frame, tmp_path / "joint.csv")
    header = path.read_text().splitlines()[0].split(",")
    assert header[:5] == ["input.q", "input.dq", "q", "dq", "tau"] and "violation" in header
    npz = np.load(session.export(frame, tmp_path / "joint.npz"))
    np.testing.assert_array_equal(npz["states"], frame.states)
    assert float(npz["physics.damping"]) == 0.5
    latent = LatentSession(model, n=6, directions=2)
    assert latent.update((1.0, 0.0)).path is None and latent.update((1.0, 0.0)).states.shape == (latent.length, 2)


def test_the_viewer_serves_a_plug_in_task_with_plots_and_no_3d_scene(joint_run, tmp_path):
    if importlib.util.find_spec("viser") is None:
        pytest.skip("viser is not installed")
    from seqmotion.view.app import ViewerApp

    threads = torch.get_num_threads()
    app = ViewerApp(str(joint_run), port=0, simulate=False, latent_n=6, out=tmp_path / "exports")
    try:
        assert app.wait_idle(120)
        panel = app.panels["task"]
        assert app.errors == [] and panel.frame is not None and panel.arm is None and app.scene_choice is None
        assert "plotted: **q** [rad]" in panel.readout.content and panel.violation_plot.visible
        panel.field.value = "tau"  # as the page would set it: redrawn with the torque
        panel.worker.submit(panel._redraw)
        assert app.wait_idle(60) and "plotted: **tau** [N·m]" in panel.readout.content
        panel.worker.submit(panel._export)
        assert app.wait_idle(60) and app.errors == []
        exported = sorted((tmp_path / "exports").glob("view_joint-input0.csv"))
        assert exported and exported[0].read_text().startswith("input.q,input.dq,q,dq,tau")
    finally:
        app.stop()
        torch.set_num_threads(threads)


def test_latent_pca_decodes_live(deformer):
    session = LatentSession(deformer, n=24, directions=3)
    assert session.pca.components.shape == (3, deformer.model.latent_dim)
    np.testing.assert_allclose(session.pca.components @ session.pca.components.T, np.eye(3), atol=1e-9)
    mean, moved = session.update((0, 0, 0)), session.update((2.0, 0, 0))
    assert mean.states.shape == (session.length, 6) and not np.allclose(mean.states, moved.states)
    assert mean.path.shape == (session.length, 2) and 0 <= moved.nearest < 24
    assert "PC1" in moved.readout(session.pca)


def test_pushing_latent_clusters_from_webcam_images():
    from seqmotion.view.sessions import PushingLatentSession

    session = PushingLatentSession(sm.load_pretrained("pushing"), variations=1)
    assert session.images.shape == (6, 64, 64, 3) and session.images.dtype == np.uint8
    assert session.z.shape == (6, 8) and list(session.labels) == list(range(6))
    for position in range(6):  # a cluster's own centre is nearest to it
        coords = tuple(session.centres[position, :3] / session.pca.std[:3])
        assert session.nearest_position(coords) == position
    np.testing.assert_array_equal(session.image_for(2), session.images[2])


def test_pca_round_trip():
    rng = np.random.default_rng(0)
    z = rng.normal(size=(50, 6)) @ np.diag([5, 3, 1, 0.5, 0.1, 0.01])
    pca = Pca.fit(z, 6)
    np.testing.assert_allclose(pca.latent(pca.scores[7] / pca.std), z[7], atol=1e-9)


def test_pancake_redraw_is_fast(deformer):
    """A slider move (an uncached frame) on the fast path: measured ~10 ms on 2 cores with one torch thread
    (benchmarks/results_view.md); the bound here leaves room for a loaded CI machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        session = PancakeSession(deformer)
        session.update(PancakeControls())
        seconds = []
        for i in range(5):
            start = time.perf_counter()
            session.update(PancakeControls(end_y=0.2 + 0.005 * (i + 1)))
            seconds.append(time.perf_counter() - start)
    finally:
        torch.set_num_threads(threads)
    assert np.median(seconds) < 0.5


# --- the 3-D scene -----------------------------------------------------------------------------------


def test_scene_meshes_and_a_replay():
    from seqmotion.sim.arm import get_scene

    model = get_scene("pancake").model
    geoms = scene3d.scene_geoms(model)
    assert {g.name for g in geoms} >= {"blade", "table", "spatula_handle"}
    assert not any(g.name.startswith("pancake_") for g in geoms)  # collision spheres are not drawn
    for g in geoms:
        assert g.faces.max() < len(g.vertices) and np.all(np.isfinite(g.vertices))
    motion = sm.tasks.pancake.data.straight((0.05, 0.02, 0.5), 200)
    replay = scene3d.replay("pancake", motion, stride=20, tail=0.2)
    assert replay.pos.shape[1:] == (model.nbody, 3) and replay.quat.shape[1:] == (model.nbody, 4)
    assert len(replay.time) == replay.pos.shape[0] >= 10 and "tracking" in replay.summary
    blade = next(g for g in geoms if g.name == "blade").body
    assert np.linalg.norm(replay.pos[-1, blade] - replay.pos[0, blade]) > 0.01  # the arm moved


MESH_SCENE = """<mujoco>
  <compiler angle="radian"/>
  <asset>
    <mesh name="tet" vertex="0 0 0  0.1 0 0  0 0.2 0  0 0 0.3" face="0 2 1  0 1 3  0 3 2  1 2 3"/>
    <material name="green" rgba="0 1 0 1"/>
  </asset>
  <worldbody>
    <body name="link" pos="0.3 -0.2 0.5" euler="0.4 -0.7 1.1">
      <geom name="painted" type="mesh" mesh="tet" pos="0.05 0.02 -0.01" euler="1.0 0.3 -0.5" material="green"/>
      <geom name="red" type="mesh" mesh="tet" material="green" rgba="1 0 0 1"/>
      <geom name="collision" type="mesh" mesh="tet" group="3"/>
    </body>
  </worldbody>
</mujoco>"""


def _euler_matrix(x: float, y: float, z: float) -> np.ndarray:
    """MJCF's default ``euler`` (intrinsic x, then y, then z)."""
    cx, sx, cy, sy, cz, sz = np.cos(x), np.sin(x), np.cos(y), np.sin(y), np.cos(z), np.sin(z)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rx @ ry @ rz


def test_mesh_geoms_are_drawn_where_the_file_puts_them():
    """MuJoCo recentres a mesh at its centroid and turns it to its principal axes; the drawn vertices must
    still be the file's vertices through the geom's and the body's poses as the file wrote them."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(MESH_SCENE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    geoms = {g.name: g for g in scene3d.scene_geoms(model)}
    assert set(geoms) == {"painted", "red"}  # the group-3 collision mesh is not drawn
    assert geoms["painted"].rgb == (0, 255, 0) and geoms["red"].rgb == (255, 0, 0)  # material, then own rgba
    tet = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.2, 0], [0, 0, 0.3]])
    body_rot, body_pos = _euler_matrix(0.4, -0.7, 1.1), np.array([0.3, -0.2, 0.5])
    for name, rot, pos in [("painted", _euler_matrix(1.0, 0.3, -0.5), np.array([0.05, 0.02, -0.01])),
                           ("red", np.eye(3), np.zeros(3))]:
        g = geoms[name]
        drawn = data.xpos[g.body] + g.vertices.astype(np.float64) @ data.xmat[g.body].reshape(3, 3).T
        expected = body_pos + (pos + tet @ rot.T) @ body_rot.T
        assert len(drawn) == 4 and len(g.faces) == 4
        assert np.abs(np.sort(drawn, axis=0) - np.sort(expected, axis=0)).max() < 1e-6
        corners = drawn[g.faces]  # every face's normal points out of the tetrahedron, as in the file
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        assert np.all(np.einsum("ij,ij->i", normals, corners.mean(1) - drawn.mean(0)) > 0)


def test_a_fine_mesh_is_simplified_to_its_budget_and_keeps_its_shape():
    verts, faces = scene3d._capsule(0.1, 0.0, 80)  # a sphere of 0.1 m, ~12 800 triangles
    assert len(faces) > 10_000
    v, f = scene3d.decimate(verts, faces, 600)
    assert 300 <= len(f) <= 600 and f.max() < len(v) and np.all(np.isfinite(v))
    radius = np.linalg.norm(v, axis=1)
    assert np.abs(radius - 0.1).max() < 0.012  # still the sphere, within about a grid cell
    assert np.abs(v.max(0) - verts.max(0)).max() < 0.015 and np.abs(v.min(0) - verts.min(0)).max() < 0.015
    same_v, same_f = scene3d.decimate(verts, faces, len(faces))  # within its cap: untouched
    assert same_v is verts and same_f is faces
    # water filling: small meshes stay whole, the large ones share what is left of the budget
    assert scene3d.fit_budget([100, 1000, 5000], 2100) == 1000
    assert scene3d.fit_budget([100, 3000, 5000], 2100) == 1000
    assert scene3d.fit_budget([100, 200], 2100) == 200
    with pytest.raises(ValueError, match="max_faces"):
        scene3d.decimate(verts, faces, 0)


def _standard_arm_here(name: str) -> None:
    """Skip, by name, where the standard arm ``name`` or the IK library its controller needs is absent."""
    if importlib.util.find_spec("mink") is None:
        pytest.skip("mink is not installed (pip install 'seqmotion[robots]')")
    from seqmotion.sim.robot_models import robots

    if name not in {r.name for r in robots()}:
        pytest.skip(f"robot {name!r} is not available here (robosuite's model files are not installed)")


def test_a_replay_on_the_panda_moves_its_meshes_and_says_what_its_joints_did():
    _standard_arm_here("panda")
    from seqmotion.sim.arm import get_scene

    model = get_scene("pancake", "panda").model
    geoms = scene3d.scene_geoms(model)
    links = {model.geom_bodyid[i] for i in range(model.ngeom) if model.geom_type[i] == scene3d.GEOM_MESH}
    assert links <= {g.body for g in geoms}  # every link with a mesh is drawn
    mesh_faces = sum(len(g.faces) for g in geoms if g.body in links)
    assert 10_000 < mesh_faces <= scene3d.MESH_FACE_BUDGET  # the links' meshes, simplified to the budget
    motion = sm.tasks.pancake.data.straight((0.05, 0.02, 0.5), 200)
    replay = scene3d.replay("pancake", motion, stride=20, tail=0.2, robot="panda")
    assert replay.pos.shape[1:] == (model.nbody, 3) and replay.quat.shape[1:] == (model.nbody, 4)
    assert len(replay.time) == replay.pos.shape[0] >= 10 and np.all(np.isfinite(replay.pos))
    assert "tracking" in replay.summary and replay.robot == "panda (robosuite)"
    blade = next(g for g in geoms if g.name == "blade").body
    assert np.linalg.norm(replay.pos[-1, blade] - replay.pos[0, blade]) > 0.01  # the arm moved
    rest_pos, _ = scene3d.rest_poses("pancake", robot="panda")
    assert np.abs(rest_pos - replay.pos[0]).max() < 0.01  # the replay starts from the scene's rest pose
    if importlib.util.find_spec("viser") is None:
        return
    import viser

    from seqmotion.view.app import ArmView

    server = viser.ViserServer(port=0, verbose=False)
    try:  # the page's scene: a frame per drawn body, moved by the replay's poses
        arm = ArmView(server, "/pancake", "pancake", "panda")
        assert set(arm.frames) == {g.body for g in geoms} and arm.triangles == sum(len(g.faces) for g in geoms)
        arm.pose(replay.pos[-1], replay.quat[-1])
        assert np.allclose(arm.frames[blade].position, replay.pos[-1, blade], atol=1e-6)
    finally:
        server.stop()


# --- the command line --------------------------------------------------------------------------------


def test_cli_registers_view_and_refuses_a_bad_port(capsys):
    from seqmotion.cli import build_parser, main

    args = build_parser().parse_args(["view", "sliding", "--port", "0"])
    assert args.model == "sliding" and args.port == 0
    if importlib.util.find_spec("viser") is None:
        pytest.skip("viser is not installed")
    assert main(["view", "--port", "70000"]) == 2
    assert "--port" in capsys.readouterr().err
    assert main(["view", "no-such-model", "--port", "0"]) == 2
    assert "no-such-model" in capsys.readouterr().err
    assert main(["view", "pushing-hard", "--port", "0"]) == 2  # a feedback policy has no z to show
    assert "'feedback' policy" in capsys.readouterr().err
    assert main(["view", "--robot", "no-such-robot", "--port", "0"]) == 2  # refused before any server starts
    assert "no-such-robot" in capsys.readouterr().err
    assert main(["view", "--robot", "menagerie:ur5e", "--no-sim", "--port", "0"]) == 2
    assert "--no-sim" in capsys.readouterr().err


def test_cli_warns_that_a_public_host_has_no_authentication(capsys):
    if importlib.util.find_spec("viser") is None:
        pytest.skip("viser is not installed")
    from seqmotion.cli import main

    threads = torch.get_num_threads()
    try:
        assert main(["view", "sliding", "--host", "0.0.0.0", "--port", "0", "--no-sim", "--seconds", "0.1"]) == 0
    finally:
        torch.set_num_threads(threads)
    assert "no authentication" in capsys.readouterr().err
    assert main(["view", "--port", "70000"]) == 2  # the default host (127.0.0.1) warns of nothing
    assert "warning" not in capsys.readouterr().err


def test_stop_joins_every_thread_the_viewer_started():
    """A worker still inside torch when the interpreter exits aborts it (``terminate called without an
    active exception``, rc 134): ``stop`` ends and joins them, with the job they were running."""
    if importlib.util.find_spec("viser") is None:
        pytest.skip("viser is not installed")
    import threading

    from seqmotion.view.app import ViewerApp

    app = ViewerApp("sliding", port=0, simulate=False, latent_n=8)
    ran = []
    try:
        assert app.wait_idle(120)
        for panel in app.panels.values():
            panel.worker.submit(lambda: (time.sleep(0.5), ran.append(1)))
        time.sleep(0.1)  # the jobs are running
    finally:
        app.stop()
    assert len(ran) == len(app.panels)  # each job ran to its end inside stop()
    assert [t.name for t in threading.enumerate() if t.name.startswith("seqmotion-view")] == []


def test_cli_serves_a_sliding_model_for_a_moment(capsys):
    if importlib.util.find_spec("viser") is None:
        pytest.skip("viser is not installed")
    from seqmotion.cli import main

    threads = torch.get_num_threads()
    try:
        assert main(["view", "sliding", "--port", "0", "--no-sim", "--seconds", "0.2"]) == 0
    finally:
        torch.set_num_threads(threads)
    assert "open http://127.0.0.1:" in capsys.readouterr().out


# --- in a real browser -------------------------------------------------------------------------------


def chromium_path() -> str | None:
    if os.environ.get("SEQMOTION_CHROMIUM", "").lower() == "none":  # hidden: run as on a machine without one
        return None
    for candidate in (os.environ.get("SEQMOTION_CHROMIUM"), "chromium", "chromium-browser", "google-chrome"):
        if candidate and (found := shutil.which(candidate) or (Path(candidate).exists() and candidate)):
            return found
    return None


def _browser_missing() -> str | None:
    if importlib.util.find_spec("viser") is None:
        return "viser is not installed (pip install -e '.[dev]')"
    if importlib.util.find_spec("playwright") is None:
        return "playwright is not installed (pip install -e '.[dev]')"
    if chromium_path() is None:
        return "no Chromium executable (apt-get install chromium, or set SEQMOTION_CHROMIUM)"
    return None


SHOTS = Path(os.environ["SEQMOTION_VIEW_SHOTS"]) if os.environ.get("SEQMOTION_VIEW_SHOTS") else None


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    missing = _browser_missing()
    if missing:
        pytest.skip(f"browser tests skipped: {missing}")
    from playwright.sync_api import sync_playwright

    from seqmotion.view.app import ViewerApp

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("view")
    app = ViewerApp("pancake", port=0, out=out / "exports", latent_n=32)
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=chromium_path(), args=[
                "--no-sandbox", "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"])
            tab = browser.new_page(viewport={"width": 1280, "height": 1700})
            tab.goto(app.url)
            tab.app, tab.shots = app, SHOTS or out
            yield tab
            browser.close()
    finally:
        app.stop()
        torch.set_num_threads(threads)


def _control(page, label: str):
    """The row of the viser control labelled ``label`` (its label and its input)."""
    label_el = page.locator(f'label:text-is("{label}")').first
    return label_el.locator("xpath=ancestor::div[contains(@class, 'mantine-Flex-root')][1]")


def _dismiss_notifications(page) -> None:
    """Close the 'software WebGL' notice headless Chromium gets (it would cover the screenshots)."""
    for button in page.locator(".mantine-Notification-closeButton").all():
        try:
            button.click(timeout=1000)
        except Exception:  # noqa: BLE001 - gone already
            pass


def _readout(page, marker: str):
    return page.locator("p", has_text=marker).first


def _wait_text_change(page, locator, before: str, timeout: float = 20.0) -> str:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        text = locator.inner_text()
        if text != before:
            return text
        page.wait_for_timeout(20)
    raise AssertionError(f"the page did not redraw within {timeout} s (still {before!r})")


def test_page_loads(page):
    page.get_by_role("tab", name="Pancake").wait_for(timeout=90_000)  # generous: CI machines may be busy
    readout = _readout(page, "motion, K =")
    readout.wait_for(timeout=60_000)
    assert "learned" in readout.inner_text()
    assert page.get_by_role("tab", name="Sliding").is_visible()
    assert page.get_by_role("tab", name="Latent space").is_visible()
    assert page.locator("canvas").count() >= 3  # the 3-D view and the uPlot charts
    assert page.app.errors == []
    _dismiss_notifications(page)


def test_moving_the_end_pose_redraws_the_deformed_path(page):
    app = page.app
    readout = _readout(page, "motion, K =")
    before = readout.inner_text()
    image = page.locator("p", has_text="path (z vs y)").locator("xpath=following-sibling::div[1]//img")
    src_before, shot_before = image.get_attribute("src"), image.screenshot()
    path_before = app.panels["pancake"].frame.states[:, :2].copy()
    thumb = _control(page, "end y [m]").locator('[role="slider"]')
    thumb.focus()
    for _ in range(6):  # 6 steps of 5 mm: the sketch now ends at y = 0.23 m
        page.keyboard.press("ArrowRight")
    after = _wait_text_change(page, readout, before)
    app.wait_idle()
    page.wait_for_timeout(300)
    frame = app.panels["pancake"].frame
    assert frame.controls.end_y == pytest.approx(0.23)
    assert not np.allclose(frame.states[:, :2], path_before)  # the server drew a new deformed path ...
    assert after != before and image.get_attribute("src") != src_before  # ... and the page shows it
    assert image.screenshot() != shot_before
    page.screenshot(path=str(page.shots / "view-pancake.png"))


def test_latent_adjustment_replay_and_export_buttons(page):
    app = page.app
    panel = app.panels["pancake"]
    page.get_by_role("button", name="Adjust latent to target").click(force=True)
    _readout(page, "latent 6/6").wait_for(timeout=30_000)
    app.wait_idle()
    np.testing.assert_allclose(panel.frame.states[-1, :3], panel.target, atol=2e-3)  # (0.1, 0, π) reached
    page.get_by_role("button", name="Simulate on the arm").click(force=True)
    _readout(page, "simulated").wait_for(timeout=30_000)
    assert "tracking" in panel.sim_readout.content and panel.arm.replay.pos.shape[1] == 10
    page.get_by_role("button", name="Export motion").click(force=True)
    _readout(page, "wrote").wait_for(timeout=20_000)
    exported = sorted(Path(app.out).glob("pancake-*.csv"))
    assert exported and read_arrays(exported[0], ["states"])["states"].shape[0] == len(panel.frame.states)


def test_sliding_panel_plans_a_path_entered_through_the_page(page):
    app = page.app
    page.get_by_role("tab", name="Sliding").click(force=True)
    readout = _readout(page, "for a line command")
    readout.wait_for(timeout=20_000)
    _control(page, "shape").locator("input").first.click(force=True)
    page.get_by_role("option", name="spline").click()
    box = _control(page, "points x,y [mm]").locator("input")
    box.fill("20,0; 40,30; 10,50")
    box.press("Enter")
    spline = _readout(page, "for a spline command")
    spline.wait_for(timeout=20_000)
    app.wait_idle()
    frame = app.panels["sliding"].frame
    assert frame.controls.shape == "spline" and frame.controls.points == "20,0; 40,30; 10,50"
    np.testing.assert_allclose(frame.command[-1, :2], [0.01, 0.05], atol=1e-9)
    assert frame.obj.shape == frame.command.shape and "RMSE" in spline.inner_text()
    page.wait_for_timeout(300)
    page.screenshot(path=str(page.shots / "view-sliding.png"))


def test_latent_panel_decodes_a_slider_move(page):
    app = page.app
    page.get_by_role("tab", name="Latent space").click(force=True)
    readout = _readout(page, "decoded z at")
    readout.wait_for(timeout=30_000)
    before = readout.inner_text()
    thumb = _control(page, "PC1 [σ]").locator('[role="slider"]')
    thumb.focus()
    for _ in range(5):
        page.keyboard.press("ArrowRight")
    _wait_text_change(page, readout, before)
    end = time.monotonic() + 30
    while "(+0.5σ" not in readout.inner_text() and time.monotonic() < end:  # 5 steps of 0.1σ, drawn in turn
        page.wait_for_timeout(20)
    assert "(+0.5σ" in readout.inner_text()
    app.wait_idle()
    page.wait_for_timeout(300)
    page.screenshot(path=str(page.shots / "view-latent.png"))
    assert app.errors == []
