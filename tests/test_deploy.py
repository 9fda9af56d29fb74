"""Deployment: every shipped seq2seq model exported to ONNX (``seqmotion export-onnx``) runs in onnxruntime
within 1e-4 of PyTorch, behind the PyTorch stepper's interface, and the exported folder runs without torch."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion.cli import main as cli_main
from seqmotion.tasks import TrainedModel

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from seqmotion.deploy import OnnxModel, OnnxStepper, export_onnx  # noqa: E402
from seqmotion.deploy.export import gemm_as_matmul, quantized  # noqa: E402

SEQ2SEQ = [name for name in sm.pretrained_models() if isinstance(sm.load_pretrained(name), TrainedModel)]


@pytest.fixture(scope="module", autouse=True)
def _one_thread(one_thread):
    """Every test here runs torch on one thread (see conftest)."""


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """Every shipped seq2seq model, exported once (pancake through the command line)."""
    root = tmp_path_factory.mktemp("onnx")
    out = {}
    for name in SEQ2SEQ:
        if name == "pancake":
            assert cli_main(["export-onnx", name, str(root / name)]) == 0  # with its parity check
        else:
            export_onnx(sm.load_pretrained(name), root / name, source=name)
        out[name] = root / name
    return out


def motions(task: str, rng: np.random.Generator, k: int) -> np.ndarray:
    if task == "pancake":
        return sm.tasks.pancake.data.straight((rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(-2, 2)), k)
    return sm.tasks.sliding.data.circle(rng.uniform(0.02, 0.06), k)


def reference(model: TrainedModel, batch: np.ndarray) -> dict[str, np.ndarray | None]:
    """PyTorch ``generate``'s rollout of ``batch`` ``(B, K, input_dim)`` as arrays (any task's result holds them)."""
    with torch.inference_mode():
        x = torch.from_numpy(batch)
        latent = model.encode_torch(x)
        states, accel = model.decode_torch(latent, model.start_state(x).double(), batch.shape[1])
        violation = model.violation_torch(states, accel)
    return {"states": states.numpy(), "accel": accel.numpy(), "latent": latent.numpy(),
            "violation": None if violation is None else violation.numpy()}


def plant(model: TrainedModel):  # noqa: ANN201
    """The model's own (PyTorch) dynamics as the robot: ``(x (S,), u (n, d))`` → the n states that follow."""
    def step(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            states = model.integrate_torch(torch.from_numpy(x[None]), torch.from_numpy(np.asarray(u)[None]))
        return states[0, 1:].numpy()
    return step


def test_every_shipped_seq2seq_model_is_covered():
    assert "pancake" in SEQ2SEQ and {"sliding", "sliding-A-nominal", "sliding-A-velocity", "sliding-B",
                                     "sliding-C"} <= set(SEQ2SEQ)


@pytest.mark.parametrize("name", SEQ2SEQ)
def test_closed_loop_parity_with_pytorch_at_any_length(exported, name):
    model, onnx_model = sm.load_pretrained(name), OnnxModel(exported[name])
    task = model.task_def.name
    rng = np.random.default_rng(sum(map(ord, name)))
    c, scale = model.model.chunk, np.asarray(model.model.cfg.output_scale)
    for k in (2, c, 3 * c + 17) if task == "pancake" else (2, c + 1, 7 * c + 31):  # the export traced 2 chunks
        batch = np.stack([motions(task, rng, k) for _ in range(2)])
        ref, mine = reference(model, batch), onnx_model.generate(batch)
        # float32 in two runtimes: outputs agree to ~1e-6 of the model's output scale (pancake a_θ: 100 rad/s²,
        # where 1e-4 rad/s² is 8 float32 steps); the states they produce to 1e-5 of their magnitude (at least
        # 1 m, m/s or rad: the outputs' rounding moves a motion of millimetres by nanometres, not by 1e-5 of it)
        assert (np.abs(mine["accel"] - ref["accel"]) / scale).max() <= 1e-5
        assert np.abs(mine["states"] - ref["states"]).max() <= 1e-5 * max(np.abs(ref["states"]).max(), 1.0)
        np.testing.assert_allclose(mine["latent"], ref["latent"], atol=1e-5)
        if task == "pancake":
            assert np.abs(mine["violation"] - ref["violation"]).max() <= 1e-4


@pytest.mark.parametrize("name", ["pancake", "sliding"])
def test_the_onnx_stepper_steps_like_the_pytorch_one(exported, name):
    """Pieces of every size, measurement noise, a latent swap, a restart and the end: the same outputs."""
    model = sm.load_pretrained(name)
    task = model.task_def.name
    rng = np.random.default_rng(3)
    k = 2 * model.model.chunk + 30
    first, second = motions(task, rng, k), motions(task, rng, k)
    other = reference(model, second[None])["latent"][0]
    robot = plant(model)
    runs = []
    for gen in (model.generator(first), OnnxStepper(exported[name], first)):
        noise, x = np.random.default_rng(5), gen._x0[0]
        u, applied = gen.step(), []
        for i, n in enumerate([1, 17, 5, 40, 1, 1, 60, 33, 9] * 6):
            n = min(n, len(u))
            states = robot(x, u[:n])
            applied.append(u[:n])
            measured = states + 1e-4 * noise.standard_normal(states.shape)
            x = states[-1]
            if i == 4:
                gen.set_latent(other)
            if i == 30:
                gen.set_latent(other, restart=True, length=k // 2)
            u = gen.step(measured)
        runs.append((np.concatenate(applied), (gen.done, gen.stopping), gen.time))
    (a, done_a, t_a), (b, done_b, t_b) = runs
    assert (done_a, t_a) == (done_b, t_b) and any(done_a)  # past the end, both in the same phase
    assert (np.abs(a - b) / np.asarray(model.model.cfg.output_scale)).max() <= 1e-5


def test_the_contract_is_the_steppers(exported):
    contract = json.loads((exported["pancake"] / "contract.json").read_text())
    gen = sm.load_pretrained("pancake").generator(sm.tasks.pancake.data.straight((0.1, 0.0, 0.5), 100))
    same = {k: v for k, v in gen.contract().items() if k not in ("length", "batch", "replan")}
    assert {k: contract[k] for k in same} == same
    assert contract["files"]["encoder"] == "encoder.onnx" and contract["opset"] >= 17
    assert set(contract["graphs"]["decoder_step"]["inputs"]) == {"h", "c", "window"}


def test_the_sliding_dynamics_graph_stays_small(exported):
    """The stepper runs the sliding dynamics graph at every chunk boundary, where its cost is its node count (each
    node costs about as much as its arithmetic, and a large graph finds the cache cold): the contact loop is one Scan
    of at most 15 nodes per sample, nothing unrolled per sample outside it, each constant value made once, and the
    graph still the contact model (the rest of its parity: test_dynamics_graph.py)."""
    import onnx
    import onnxruntime as ort

    from seqmotion.deploy.export import shared_constants

    folder = exported["sliding"]
    proto = onnx.load(folder / "dynamics.onnx")
    chunk = json.loads((folder / "contract.json").read_text())["chunk"]
    ops = [node.op_type for node in proto.graph.node]
    # outside the Scan only the all-sample work: the pan's integration, breakaway, positions (~100 nodes, not 100 C)
    assert chunk == 100 and ops.count("Scan") == 1 and len(ops) - ops.count("Constant") <= 120, ops
    body = next(a.g for a in proto.graph.node[ops.index("Scan")].attribute if a.name == "body")
    assert sum(node.op_type != "Constant" for node in body.node) <= 15
    values = [node.attribute[0].t.SerializeToString() for node in proto.graph.node if node.op_type == "Constant"]
    assert len(values) == len(set(values))
    # sharing the constants changes names only: a graph with a repeated constant computes the same after it
    doubled = onnx.ModelProto()
    doubled.CopyFrom(proto)
    first = next(node for node in doubled.graph.node if node.op_type == "Constant")
    user = next(node for node in doubled.graph.node if first.output[0] in node.input)
    copy = onnx.helper.make_node("Constant", [], ["copy_of_" + first.output[0]], value=first.attribute[0].t)
    doubled.graph.node.insert(list(doubled.graph.node).index(user), copy)
    user.input[:] = [copy.output[0] if name == first.output[0] else name for name in user.input]
    shared = shared_constants(doubled)
    assert len(shared.graph.node) == len(proto.graph.node)
    rng = np.random.default_rng(5)
    feeds = {"x": 0.05 * rng.standard_normal((3, 8)), "accel": 8.0 * rng.standard_normal((3, chunk, 2)),
             "physics": np.array([0.6, 0.3])}
    runs = [ort.InferenceSession(p.SerializeToString(), providers=["CPUExecutionProvider"]).run(None, feeds)[0]
            for p in (doubled, shared)]
    np.testing.assert_array_equal(runs[0], runs[1])


def test_the_exported_folder_runs_with_numpy_and_onnxruntime_only(exported):
    folder = exported["pancake"]
    code = f"""
import sys
sys.modules["torch"] = None  # importing torch (or seqmotion) fails
sys.modules["seqmotion"] = None
sys.path.insert(0, {str(folder)!r})
import numpy as np
from onnx_stepper import OnnxStepper
motion = np.zeros((120, 6)); motion[:, 1] = np.linspace(0.0, 0.05, 120)
gen = OnnxStepper({str(folder)!r}, motion)
u = gen.step()
u = gen.step(np.repeat(motion[:1], 3, axis=0))
print(u.shape, gen.contract()["task"])
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=folder.parent)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["(47,", "3)", "pancake"]


def test_int8_graphs(exported, tmp_path):
    import onnx
    import onnxruntime as ort

    proto = onnx.load(str(exported["pancake"] / "decoder_step.onnx"))
    feeds = {"h": np.zeros((2, 1, 64), np.float32), "c": np.full((2, 1, 64), 0.1, np.float32),
             "window": np.full((1, 50, 6), 0.01, np.float32)}
    run = [ort.InferenceSession(p.SerializeToString(), providers=["CPUExecutionProvider"]).run(None, feeds)[2]
           for p in (proto, gemm_as_matmul(proto))]
    np.testing.assert_allclose(run[0], run[1], atol=1e-4)  # the rewrite quantisation needs changes nothing
    assert quantized(proto, tmp_path) == proto.SerializeToString()  # nothing 256 wide: stays float (like PyTorch)
    small = onnx.load_from_string(quantized(proto, tmp_path, min_features=64))
    assert sum(n.op_type == "MatMulInteger" for n in small.graph.node) >= 4


def test_named_errors(exported, tmp_path):
    with pytest.raises(ValueError, match="no exported model"):
        OnnxModel(tmp_path)
    with pytest.raises(ValueError, match="int8"):
        OnnxModel(exported["pancake"], int8=True)
    gen = OnnxStepper(exported["pancake"], latent=np.zeros(128), x0=np.zeros(6), length=80)
    gen.step()
    with pytest.raises(ValueError, match=r"6 columns.*pancake state"):
        gen.step(np.zeros((2, 8)))
    with pytest.raises(ValueError, match="NaN"):
        gen.step(np.full((2, 6), np.nan))
    with pytest.raises(ValueError, match="inputs must have shape"):
        OnnxStepper(exported["pancake"], np.zeros((10, 4)))
    with pytest.raises(ValueError, match=r"'pancake' model's exported dynamics take no physics \(got \['mu'\]\)"):
        OnnxStepper(exported["pancake"], np.zeros((10, 6)), physics={"mu": 0.5})
    with pytest.raises(ValueError, match=r"take no physics \['friction'\]; they take \['mu', 'mu_dyn'\]"):
        OnnxModel(exported["sliding"]).generate(np.zeros((10, 4)), physics={"friction": 0.5})
    for bad, message in ((float("nan"), "finite"), ("much", "must be a number"), (True, "real number"),
                         (0.2, r"mu_dyn <= mu")):
        with pytest.raises(ValueError, match=message):
            OnnxStepper(exported["sliding"], np.zeros((10, 4)), physics={"mu": bad})
    with pytest.raises(ValueError, match="dict of field name"):
        OnnxStepper(exported["sliding"], np.zeros((10, 4)), physics=0.8)
    with pytest.raises(ValueError, match="sequence-to-sequence"):
        export_onnx(sm.load_pretrained("pushing"), tmp_path / "x")
    with pytest.raises(ValueError, match="float model"):
        export_onnx(sm.load_pretrained("pancake").quantized(), tmp_path / "x")
