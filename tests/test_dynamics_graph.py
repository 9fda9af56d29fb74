"""The task's own dynamics as a graph of the ONNX bundle (``dynamics.onnx``): traced from the PyTorch code the model
trains with, it computes what that code computes — for the shipped double integrator and sliding contact (sticking
and sliding, at the export's friction and at others given at run time) and for a task defined here with dynamics of
its own — and what cannot be traced faithfully is refused at export by name."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion.core.options import TaskOptions, check_length_range, check_positive
from seqmotion.data.trajectories import TensorBatch, TrajectoryBatch, draw_lengths, path_states
from seqmotion.errors import check_number
from seqmotion.models.seq2seq import ChunkedSeq2Seq, Seq2SeqConfig, rollout
from seqmotion.physics.integrator import DT
from seqmotion.physics.layout import StateLayout
from seqmotion.physics.parameters import Physics
from seqmotion.tasks import Task, register
from seqmotion.training.config import TrainConfig
from seqmotion.training.curriculum import Curriculum, CurriculumParams
from seqmotion.training.losses import masked_mean, sample_mask
from seqmotion.training.trainer import step_loss

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from seqmotion.deploy import OnnxModel, OnnxStepper, export_onnx  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def _one_thread(one_thread):
    """Every test here runs torch on one thread (see conftest)."""


@pytest.fixture(scope="module")
def bundles(tmp_path_factory):
    root = tmp_path_factory.mktemp("graphs")
    for name in ("pancake", "sliding"):
        export_onnx(sm.load_pretrained(name), root / name, source=name, int8=name == "pancake")
    return root


@pytest.fixture(scope="module")
def sliding_onnx(bundles):
    """The sliding bundle loaded once (its graphs take a second to load)."""
    return OnnxModel(bundles / "sliding")


def torch_step(model, x: np.ndarray, accel: np.ndarray, physics: Physics | None = None) -> dict[str, np.ndarray]:
    """One chunk of the model's PyTorch dynamics (what the model trains and generates with)."""
    dynamics = model.dynamics(physics)
    with torch.no_grad():
        _, out = dynamics.step(dynamics.start(torch.from_numpy(x)), torch.from_numpy(accel), None)
    return {key: value.numpy() for key, value in out.items() if key in ("states", "branch")}


def torch_generate(model, batch: np.ndarray, physics: Physics | None = None) -> dict[str, np.ndarray]:
    with torch.inference_mode():
        x = torch.from_numpy(batch)
        states, accel = model.decode_torch(model.encode_torch(x), model.start_state(x).double(), batch.shape[1],
                                           physics)
    return {"states": states.numpy(), "accel": accel.numpy()}


def close(mine: np.ndarray, ref: np.ndarray, rtol: float = 1e-5) -> bool:
    """Within ``rtol`` of the reference's magnitude (at least 1: SI units)."""
    return float(np.abs(mine - ref).max()) <= rtol * max(float(np.abs(ref).max()), 1.0)


# --- the shipped dynamics ------------------------------------------------------------------------------------------


def test_the_pancake_graph_is_the_double_integrator_and_reads_no_physics(bundles):
    """The graph computes what the PyTorch dynamics do, and so does the closed form the contract names (what the
    runner predicts with): the pancake's dynamics are judged a double integrator by what they compute."""
    model, onnx_model = sm.load_pretrained("pancake"), OnnxModel(bundles / "pancake")
    dynamics = onnx_model.contract["dynamics"]
    assert dynamics["physics"]["names"] == ["mu"] and dynamics["physics"]["inputs"] == []
    assert dynamics["closed_form"] == "double_integrator" and onnx_model.physics_inputs == ()
    assert [i.name for i in onnx_model.dynamics_session.get_inputs()] == ["x", "accel"]
    rng = np.random.default_rng(0)
    x, accel = rng.standard_normal((5, 6)), 50 * rng.standard_normal((5, 50, 3))
    ref = torch_step(model, x, accel)["states"]
    np.testing.assert_allclose(onnx_model.predict_graph(x, accel), ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(onnx_model.predict(x, accel), ref, rtol=1e-12, atol=1e-12)
    # fewer outputs than a chunk are padded (the dynamics are causal), more run chunk after chunk
    for n in (1, 17, 50, 130):
        long = 50 * rng.standard_normal((2, n, 3))
        with torch.no_grad():
            ref = model.integrate_torch(torch.from_numpy(x[:2]), torch.from_numpy(long))[:, 1:].numpy()
        for predict in (onnx_model.predict_graph, onnx_model.predict):
            np.testing.assert_allclose(predict(x[:2], long), ref, rtol=1e-12, atol=1e-10)
    through_graph = OnnxModel(bundles / "pancake")
    through_graph.closed_form = None  # what a runner does for dynamics of no closed form
    motion = sm.tasks.pancake.data.straight((0.1, 0.05, 1.0), 180)
    np.testing.assert_allclose(through_graph.generate(motion)["states"], onnx_model.generate(motion)["states"],
                               rtol=0, atol=1e-12)


@pytest.mark.parametrize("friction, sticks", [((1.0, 0.5), True), ((0.6, 0.3), True), ((1.3, 1.3), True),
                                              ((0.05, 0.0), False)])  # nearly frictionless: everything slides
def test_the_sliding_graph_is_the_contact_model_sticking_and_sliding_at_any_friction(sliding_onnx, friction, sticks):
    """The graph was traced at the model's friction with everything at rest; at other states and other friction
    (given at run time) it takes each stick/slip case as the numba kernel does, bit for bit."""
    model, onnx_model = sm.load_pretrained("sliding"), sliding_onnx
    assert onnx_model.closed_form is None  # the contact model is no closed form: the graph runs it
    physics = model.physics.replace(mu=friction[0], mu_dyn=friction[1])
    rng = np.random.default_rng(1)
    x = np.concatenate([0.01 * rng.standard_normal((12, 4)), 0.05 * rng.standard_normal((12, 4))], axis=1)
    x[:6, 6:] = 0.0  # the object at rest relative to the pan: sticking until the pan pushes hard enough
    accel = 8.0 * rng.standard_normal((12, 100, 2))
    ref = torch_step(model, x, accel, physics)
    cases = np.bincount(ref["branch"].ravel(), minlength=4)
    assert (cases[0] > 0) == sticks and cases[2] > 0, cases  # sticking (where friction allows) and sliding
    vector = onnx_model.physics_vector({"mu": physics.mu, "mu_dyn": physics.mu_dyn})
    np.testing.assert_array_equal(onnx_model.predict(x, accel, vector), ref["states"])


class _Loop(torch.nn.Module):
    """The contact loop alone, as the sliding dynamics call it while traced (every output of it read)."""

    def __init__(self, dt: float) -> None:
        super().__init__()
        self.dt = dt

    def forward(self, v0, neg_u, breaks, decel):  # noqa: ANN001, ANN201
        from seqmotion.tasks.sliding.physics import ContactLoop

        return ContactLoop.apply(v0, neg_u, breaks, decel, self.dt)


def test_the_contact_loop_scan_is_the_eager_loop_and_the_kernel_bit_for_bit():
    """Exported, the per-sample contact loop is one Scan whose body is the eager loop's step traced on its own. On
    random inputs that stick, slide, stop on reversal and break away, at per-row friction and a dt that is no float32
    number, its velocities are the numba kernel's bit for bit and its velocities, moving flags and w·v the eager
    loop's (equal values: a stop is +0 in onnxruntime as in the kernel, where torch's ``w · 0`` keeps w's sign)."""
    import onnxruntime as ort

    from seqmotion.deploy.export import to_onnx
    from seqmotion.tasks.sliding.physics import GRAVITY, ContactChunk, _breakaway_t, _torch_forward, contact_loop

    rng = np.random.default_rng(7)
    b, c, dt = 48, 60, 0.003
    mu = rng.uniform(0.2, 1.2, b)
    mu_dyn = rng.uniform(0.3, 1.0, b) * mu
    stick_limit, slide_decel = (torch.from_numpy(f).reshape(b, 1) * GRAVITY for f in (mu, mu_dyn))
    v0 = 0.05 * rng.standard_normal((b, 2))
    v0[: b // 3] = 0.0  # at rest: sticking until the pan pushes past mu g, then breaking away
    u = rng.choice([2.0, 6.0, 20.0], (b, c, 1)) * rng.standard_normal((b, c, 2))
    u[:, ::7] = 0.0  # a still pan: a sliding object decelerates and stops
    v0, u = torch.from_numpy(v0), torch.from_numpy(u)
    p0 = torch.zeros_like(v0)
    _, _, _, code = _torch_forward(p0, v0, u, stick_limit, slide_decel, dt)
    assert (np.bincount(code.numpy().ravel(), minlength=4) > 0).all()  # stick, breakaway, slide and stop all occur
    breaks = _breakaway_t(u, stick_limit, dt)[1]
    with torch.no_grad():
        ref = [t.numpy() for t in contact_loop(v0, -u, breaks, slide_decel, dt)]
        kernel_v = ContactChunk.apply(p0, v0, u, torch.from_numpy(mu), torch.from_numpy(mu_dyn), dt)[1].numpy()
    args = (v0[:1], -u[:1], breaks[:1], slide_decel[:1])
    names, outs = ["v0", "neg_u", "breaks", "decel"], ["v", "moving", "turn"]
    proto = to_onnx(_Loop(dt), args, names, outs, {name: {0: "B"} for name in names + outs})
    ops = [node.op_type for node in proto.graph.node]
    assert ops.count("Scan") == 1 and len(ops) <= 2, ops  # no sample unrolled outside the Scan
    body = next(a.g for a in proto.graph.node[ops.index("Scan")].attribute if a.name == "body")
    assert sum(node.op_type != "Constant" for node in body.node) <= 15
    assert all(entry.domain in ("", "ai.onnx") for entry in proto.opset_import)  # the placeholder is gone
    session = ort.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])
    feeds = dict(zip(names, (v0.numpy(), -u.numpy(), breaks.numpy(), slide_decel.numpy()), strict=True))
    mine = session.run(None, feeds)
    np.testing.assert_array_equal(mine[0].view(np.uint64), kernel_v.view(np.uint64))
    for got, want in zip(mine, ref, strict=True):
        assert got.shape == want.shape and got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)


def test_sliding_generate_and_the_stepper_at_another_friction(sliding_onnx):
    """generate and the stepper at μ = 0.6, μ' = 0.3 (the export recorded 1.0, 0.5) follow PyTorch at that friction,
    and differ from what the export's own friction gives."""
    model, onnx_model = sm.load_pretrained("sliding"), sliding_onnx
    physics = model.physics.replace(mu=0.6, mu_dyn=0.3)
    overrides = {"mu": 0.6, "mu_dyn": 0.3}
    batch = np.stack([sm.tasks.sliding.data.circle(r, 260) for r in (0.03, 0.06)])
    ref, mine = torch_generate(model, batch, physics), onnx_model.generate(batch, physics=overrides)
    branch = torch_step(model, ref["states"][:, 0], ref["accel"][:, :100], physics)["branch"]
    assert {0, 2} <= set(np.unique(branch).tolist())  # the object sticks and slides in these motions
    assert close(mine["states"], ref["states"])
    assert (np.abs(mine["accel"] - ref["accel"]) / np.asarray(model.model.cfg.output_scale)).max() <= 1e-5
    assert not close(onnx_model.generate(batch)["states"], ref["states"], rtol=1e-3)  # the friction mattered
    onnx_gen = OnnxStepper(onnx_model, batch[0], physics=overrides)
    assert onnx_gen.physics == overrides and onnx_gen.contract()["dynamics"]["physics"]["values"] == overrides
    outputs = []
    for gen in (model.generator(batch[0], physics=physics), onnx_gen):
        x, u, applied = gen._x0[0], gen.step(), []
        for n in [1, 37, 62, 1, 99] * 3:
            n = min(n, len(u))
            states = torch_step(model, x[None], np.pad(u[None, :n], ((0, 0), (0, 100 - n), (0, 0))), physics)
            applied.append(u[:n])
            x = states["states"][0, n - 1]
            u = gen.step(states["states"][0, :n])
        outputs.append(np.concatenate(applied))
    assert (np.abs(outputs[0] - outputs[1]) / np.asarray(model.model.cfg.output_scale)).max() <= 1e-5


def test_the_int8_runner_closes_the_loop_through_the_same_dynamics(bundles):
    """The pancake's layers are all narrower than 256: its int8 decoder step is the float one, so the int8 runner
    (another decoder session, the same dynamics graph) generates exactly what the float runner does."""
    motion = sm.tasks.pancake.data.straight((0.1, 0.05, 1.0), 180)
    float_run, int8_run = OnnxModel(bundles / "pancake"), OnnxModel(bundles / "pancake", int8=True)
    np.testing.assert_array_equal(int8_run.generate(motion)["states"], float_run.generate(motion)["states"])


def test_the_standalone_runner_takes_physics_too(bundles):
    """Without seqmotion (no physics classes) the runner checks the names, that the values are finite numbers, and
    the ranges the contract records (the package's check: test_hardening_bundle.py)."""
    folder = bundles / "sliding"
    code = f"""
import sys
sys.modules["torch"] = None
sys.modules["seqmotion"] = None
sys.path.insert(0, {str(folder)!r})
import numpy as np
from onnx_stepper import OnnxModel, OnnxStepper
model = OnnxModel({str(folder)!r})
motion = np.zeros((150, 4)); motion[:, 0] = np.linspace(0.0, 0.03, 150)
a = model.generate(motion, physics={{"mu": 0.3, "mu_dyn": 0.1}})["states"]
b = model.generate(motion)["states"]
gen = OnnxStepper(model, motion, physics={{"mu_dyn": 0.1}})
print(model.physics_inputs, bool(np.abs(a - b).max() > 0), gen.physics)
try:
    model.generate(motion, physics={{"mu": float("inf")}})
except ValueError as exc:
    print(exc)
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=folder.parent)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == "('mu', 'mu_dyn') True {'mu': 1.0, 'mu_dyn': 0.1}" and "physics mu must be finite" in lines[1]


# --- a task with its own dynamics ---------------------------------------------------------------------------------

STATE = StateLayout(("x", "y", "v_x", "v_y"), ("m", "m", "m/s", "m/s"), "cart state")
ACCEL = StateLayout(("a_x", "a_y"), ("m/s²", "m/s²"), "cart drive")
WALL = -0.02
"""The cart cannot pass x = WALL [m]: there it stops (its x velocity is set to 0)."""


@dataclasses.dataclass(frozen=True)
class SpringPhysics(Physics):
    """A damped spring pulling the cart toward ``anchor``: stiffness [1/s²], damping [1/s], anchor's x [m]."""

    stiffness: float = 40.0
    damping: float = 2.0
    anchor: float = 0.0

    def __post_init__(self) -> None:
        for name in ("stiffness", "damping"):
            object.__setattr__(self, name, check_number(name, getattr(self, name), minimum=0.0))
        object.__setattr__(self, "anchor", check_number("anchor", self.anchor))


@dataclasses.dataclass(frozen=True)
class SpringOptions(TaskOptions):
    length: tuple[int, int] = (30, 50)
    reach: float = 0.03
    stiffness: float = 40.0

    def __post_init__(self) -> None:
        check_length_range("length", self.length)
        object.__setattr__(self, "length", tuple(self.length))
        check_positive("reach", self.reach)


@dataclasses.dataclass(frozen=True)
class SpringParams(CurriculumParams):
    teacher_forcing_prob: float


class SpringDynamics:
    """A unit-mass cart on a damped spring behind a wall, semi-implicit Euler per sample: ``v' = v + dt (u − k (p −
    anchor) − c v)``, ``p' = p + dt v'``; past the wall the cart is put back on it and its x velocity stopped (a
    ``torch.where``: a data-dependent case the exported graph must take per sample as PyTorch does). ``stiffness``
    and ``damping`` are read in :meth:`step` (a deployed model may change them); the anchor is held as ``origin``."""

    def __init__(self, stiffness: float, damping: float, anchor: float, dt: float = DT) -> None:
        self.stiffness, self.damping, self.origin, self.dt = stiffness, damping, anchor, dt

    def start(self, x0: torch.Tensor) -> torch.Tensor:
        return x0

    def step(self, carry: torch.Tensor, mean: torch.Tensor, cov: torch.Tensor | None) -> tuple[torch.Tensor, dict]:
        p, v = carry[:, :2], carry[:, 2:]
        offset = torch.tensor([self.origin, 0.0], dtype=carry.dtype)
        states = []
        for k in range(mean.shape[1]):
            v = v + self.dt * (mean[:, k].to(carry.dtype) - self.stiffness * (p - offset) - self.damping * v)
            p = p + self.dt * v
            hit = p[:, :1] < WALL
            p = torch.cat([torch.where(hit, torch.full_like(p[:, :1], WALL), p[:, :1]), p[:, 1:]], dim=1)
            v = torch.cat([torch.where(hit, torch.zeros_like(v[:, :1]), v[:, :1]), v[:, 1:]], dim=1)
            states.append(torch.cat([p, v], dim=1))
        out = torch.stack(states, dim=1)
        return out[:, -1], {"states": out}

    def decoder_input(self, states: torch.Tensor) -> torch.Tensor:
        return states

    def restart(self, carry: torch.Tensor, state: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return torch.where(mask.view(-1, 1), state.to(carry.dtype), carry)


class SpringTask(Task):
    """Follow a rough planar path with a cart held by a spring (a test task: tiny, untrained but for two steps)."""

    name = "spring_cart_graph_test"
    presets = ("tiny", "small")
    options_class = SpringOptions
    params_class = SpringParams
    physics_class = SpringPhysics
    input_layout = STATE
    state_layout = STATE
    accel_layout = ACCEL

    def train_config(self, preset: str) -> TrainConfig:
        model = Seq2SeqConfig(encoder_input_dim=4, decoder_input_dim=4, output_dim=2, chunk=10, layers=1, hidden=16,
                              encoder_input_scale=[0.03, 0.03, 0.3, 0.3], decoder_input_scale=[0.03, 0.03, 0.3, 0.3],
                              output_scale=[5.0, 5.0])
        curriculum = Curriculum(epochs=1, initial={"teacher_forcing_prob": 0.5}, stages=[])
        return TrainConfig(task=self.name, preset=preset, model=model.to_dict(), curriculum=curriculum.to_dict(),
                           batches_per_epoch=2, batch_size=4, options=SpringOptions().to_dict())

    def sample(self, n: int, rng: np.random.Generator, params: SpringParams, options: SpringOptions
               ) -> TrajectoryBatch:
        lengths = draw_lengths(rng, n, options.length)
        waypoints = rng.uniform(-options.reach, options.reach, size=(n, 3, 2))
        waypoints[:, 0] = 0.0
        return TrajectoryBatch(path_states(waypoints, lengths, DT), lengths)

    def loss(self, model: ChunkedSeq2Seq, batch: TensorBatch, dynamics: SpringDynamics, params: SpringParams,
             options: SpringOptions, generator: torch.Generator) -> tuple[torch.Tensor, dict[str, float]]:
        states, lengths = batch.states, batch.lengths
        k_max = states.shape[1]
        out = rollout(model, model.encode(states, lengths), states[:, 0], dynamics, model.num_chunks(k_max),
                      need_cov=False)
        valid = sample_mask(lengths, k_max)
        error = ((states - out.states[:, :k_max])[:, 1:, :2] ** 2).sum(-1)  # squared position error [m²]
        return (error * valid).sum() / valid.sum(), {"L1": masked_mean(error, valid)}

    def physics(self, options: SpringOptions) -> SpringPhysics:
        return SpringPhysics(stiffness=options.stiffness)

    def dynamics(self, options: SpringOptions, physics: SpringPhysics) -> SpringDynamics:
        return SpringDynamics(physics.stiffness, physics.damping, physics.anchor)


SPRING = register(SpringTask())


def spring_model(task: Task = SPRING):  # noqa: ANN201
    """A tiny model of ``task``, trained two steps (gradients flow through the task's own dynamics)."""
    config = task.train_config("tiny")
    torch.manual_seed(0)
    network = task.build_model(config)
    optimizer = torch.optim.Adam(network.parameters(), lr=1e-3)
    rng, generator = np.random.default_rng(0), torch.Generator().manual_seed(0)
    for _ in range(2):
        batch = task.sample(config.batch_size, rng, task.params({"teacher_forcing_prob": 0.5}), task.options(config))
        loss, _ = step_loss(task, network, batch, {"teacher_forcing_prob": 0.5}, config, generator)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return task.wrap(network, {"task": task.name, "model": config.model, "training": {"options": config.options}})


@pytest.fixture(scope="module")
def spring(tmp_path_factory):
    model = spring_model()
    folder = tmp_path_factory.mktemp("spring") / "bundle"
    contract = export_onnx(model, folder)
    return model, folder, contract


def test_a_task_with_its_own_dynamics_exports_them(spring):
    model, folder, contract = spring
    physics = contract["dynamics"]["physics"]
    assert physics == {"class": SpringPhysics.key(), "names": ["stiffness", "damping", "anchor"],
                       "inputs": ["stiffness", "damping"], "values": {"stiffness": 40.0, "damping": 2.0, "anchor": 0.0}}
    assert contract["dynamics"]["closed_form"] is None  # reads physics: the graph runs it
    onnx_model = OnnxModel(folder)
    rng = np.random.default_rng(3)
    x, accel = 0.02 * rng.standard_normal((6, 4)), 20.0 * rng.standard_normal((6, 10, 2))
    x[:, 0], x[:3, 2] = WALL + 1e-3, -0.5  # beside the wall, three carts moving into it
    for stiffness, damping in ((40.0, 2.0), (5.0, 0.0), (300.0, 20.0)):
        physics = model.physics.replace(stiffness=stiffness, damping=damping)
        ref = torch_step(model, x, accel, physics)["states"]
        assert (ref[..., 0] == WALL).any() and (ref[..., 0] > WALL).any()  # the wall's case and the free case
        mine = onnx_model.predict(x, accel, onnx_model.physics_vector({"stiffness": stiffness, "damping": damping}))
        np.testing.assert_allclose(mine, ref, rtol=0, atol=1e-15)


def test_the_onnx_stepper_of_a_task_with_its_own_dynamics_steps_like_pytorch(spring):
    model, folder, _ = spring
    sketch = SPRING.sample(1, np.random.default_rng(4), SpringParams(0.0), model.options).states[0, :45]
    physics = model.physics.replace(stiffness=120.0)
    ref = torch_generate(model, sketch[None], physics)
    mine = OnnxModel(folder).generate(sketch, physics={"stiffness": 120.0})
    assert close(mine["states"], ref["states"][0]) and close(mine["accel"], ref["accel"][0])
    runs = []
    for gen in (model.generator(sketch, physics=physics), OnnxStepper(folder, sketch, physics={"stiffness": 120.0})):
        x, u, applied, noise = gen._x0[0], gen.step(), [], np.random.default_rng(5)
        while len(applied) < 60:  # past the end (K = 45): the stop, through the task's dynamics
            n = min(3, len(u))
            states = torch_step(model, x[None], np.pad(u[None, :n], ((0, 0), (0, 10 - n), (0, 0))), physics)
            measured = states["states"][0, :n] + 1e-5 * noise.standard_normal((n, 4))
            applied.extend(u[:n])
            x = measured[-1]
            u = gen.step(measured)
        runs.append(np.asarray(applied))
    np.testing.assert_allclose(runs[1], runs[0], rtol=0, atol=1e-5 * 5.0)


class BranchingDynamics(SpringDynamics):
    """The wall written as a Python ``if`` on a tensor's value: the tracer bakes the case it saw in."""

    def step(self, carry: torch.Tensor, mean: torch.Tensor, cov: torch.Tensor | None) -> tuple[torch.Tensor, dict]:
        if bool((carry[:, 0] < 0.001).all()):
            return super().step(carry, mean, cov)
        out = carry[:, None] + torch.zeros(carry.shape[0], mean.shape[1], 4, dtype=carry.dtype)
        return out[:, -1], {"states": out}


class DerivedDynamics(SpringDynamics):
    """Stiffness held as an attribute, but the step uses a value computed from it when the dynamics were built."""

    def __init__(self, stiffness: float, damping: float, anchor: float, dt: float = DT) -> None:
        super().__init__(stiffness, damping, anchor, dt)
        self.omega2 = float(stiffness)

    def step(self, carry: torch.Tensor, mean: torch.Tensor, cov: torch.Tensor | None) -> tuple[torch.Tensor, dict]:
        stiffness, self.stiffness = self.stiffness, self.omega2
        try:
            return super().step(carry, mean, cov)
        finally:
            self.stiffness = stiffness


class UntraceableDynamics(SpringDynamics):
    """A step with an operation ONNX has no counterpart for at opset 17 (a running product)."""

    def step(self, carry: torch.Tensor, mean: torch.Tensor, cov: torch.Tensor | None) -> tuple[torch.Tensor, dict]:
        decay = torch.cumprod(torch.full_like(mean, 0.999), dim=1)
        return super().step(carry, mean * decay, cov)


@pytest.mark.parametrize("dynamics_class, message", [
    (BranchingDynamics, r"'spring_cart_graph_test' task's dynamics traced into a graph that differs from PyTorch.*"
                        r"Python if"),
    (DerivedDynamics, r"'spring_cart_graph_test' task's dynamics \(DerivedDynamics\) hold the physics field\(s\) "
                      r"\['stiffness'\] as attributes, but the traced step does not read them"),
    (UntraceableDynamics, r"'spring_cart_graph_test' task's dynamics \(UntraceableDynamics\) cannot be exported as an "
                          r"ONNX graph: tracing their step failed with .*cumprod"),
])
def test_dynamics_the_graph_would_not_follow_are_refused_at_export(spring, tmp_path, monkeypatch, dynamics_class,
                                                                   message):
    model = spring[0]
    monkeypatch.setattr(SPRING, "dynamics", lambda options, physics: dynamics_class(
        physics.stiffness, physics.damping, physics.anchor))
    with pytest.raises(ValueError, match=message):
        export_onnx(model, tmp_path / "out")
    assert not (tmp_path / "out").exists()
