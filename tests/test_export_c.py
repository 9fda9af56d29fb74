"""``seqmotion export-c``: the decoder step, the task's dynamics and the online generator as C99,
compiled here with the system's compiler and called through ``ctypes``: ``generate`` in C is PyTorch's (states
within 1e-6 of their magnitude) for the pancake, the sliding planner (its contact loop a ``Scan``) and a plug-in
task with its own dynamics at two physics; the C generator steps like the PyTorch stepper through the end of a
motion and its stop; a C++ control loop embeds it. Skipped where there is no C compiler."""

from __future__ import annotations

import ctypes
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

import seqmotion as sm

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from seqmotion.cli import main as cli_main  # noqa: E402
from seqmotion.deploy import c_emit, c_export, c_values  # noqa: E402
from seqmotion.deploy.c_export import compile_library, export_c, rollout_c  # noqa: E402

COMPILER = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
pytestmark = pytest.mark.skipif(COMPILER is None, reason="no C compiler (cc, gcc or clang) on the PATH")
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "realtime" / "loop.cpp"
ERRORS = {"call": -1, "too_many": -2, "state": -3, "argument": -5}


@pytest.fixture(scope="module", autouse=True)
def _one_thread(one_thread):
    """torch on one thread (see conftest)."""


@pytest.fixture(scope="module")
def spring():
    from test_dynamics_graph import spring_model

    return spring_model()


@pytest.fixture(scope="module")
def built(tmp_path_factory, spring):
    """pancake (through the command line, with its parity check), sliding and the spring plug-in, exported to C
    and compiled once: name → (model, folder, library)."""
    root = tmp_path_factory.mktemp("export_c")
    out = {}
    for name, model in (("pancake", None), ("sliding", sm.load_pretrained("sliding")), ("spring", spring)):
        folder = root / name
        if model is None:
            assert cli_main(["export-c", name, str(folder)]) == 0
            model = sm.load_pretrained(name)
        else:
            export_c(model, folder, source=name)
        library = ctypes.CDLL(str(compile_library(folder, root / f"{name}.so", compiler=COMPILER,
                                                  flags=("-O2", "-Wall", "-Wextra", "-pedantic", "-Werror"))))
        out[name] = (model, folder, library)
    return out


def inputs(name: str, model, k: int) -> np.ndarray:  # noqa: ANN001
    rng = np.random.default_rng(7)
    if name == "pancake":
        return np.stack([sm.tasks.pancake.data.straight((rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2),
                                                   rng.uniform(-2, 2)), k) for _ in range(3)])
    if name == "sliding":
        return np.stack([sm.tasks.sliding.data.circle(rng.uniform(0.02, 0.06), k) for _ in range(3)])
    from test_dynamics_graph import SPRING, SpringParams

    return SPRING.sample(3, rng, SpringParams(0.0), model.options).states[:, :k]


def ptr(a: np.ndarray | None):  # noqa: ANN201
    return None if a is None else a.ctypes.data_as(ctypes.c_void_p)


@pytest.mark.parametrize("name", ["pancake", "sliding", "spring"])
def test_generate_in_c_is_pytorchs(built, name):
    model, folder, library = built[name]
    c = model.model.chunk
    k = 3 * c + 17 if name != "spring" else 45
    batch = inputs(name, model, k)
    scale = np.asarray(model.model.cfg.output_scale)
    cases = [(None, None)]
    if name == "spring":  # at another physics too: the C dynamics read it like the graph
        cases.append((model.physics.replace(stiffness=120.0, damping=0.5), np.array([120.0, 0.5])))
    for physics, vector in cases:
        with torch.inference_mode():
            x = torch.from_numpy(batch)
            latent, start = model.encode_torch(x), model.start_state(x).double()
            states, accel = model.decode_torch(latent, start, k, physics)
        for b in range(len(batch)):
            mine, outputs = rollout_c(library, latent[b].numpy(), start[b].numpy(), k, vector,
                                      dim=model.accel_layout.dim)
            ref = states[b].numpy()
            assert np.abs(mine - ref).max() <= 1e-6 * np.abs(ref).max()
            assert (np.abs(outputs - accel[b].numpy()) / scale).max() <= 1e-5
    assert (folder / "seqmotion_model.h").is_file() and (folder / "seqmotion_generator.h").is_file()


def generator(library, model, z: np.ndarray, x0: np.ndarray, length: int) -> np.ndarray:  # noqa: ANN001
    library.seqmotion_generator_size.restype = ctypes.c_ulong
    state = np.zeros(library.seqmotion_generator_size(), dtype=np.uint8)
    zz, xx = np.ascontiguousarray(z, dtype=np.float32), np.ascontiguousarray(x0, dtype=np.float64)
    assert library.seqmotion_generator_start(ptr(state), ptr(zz), ptr(xx), ctypes.c_long(length), None, 1) == 0
    return state


@pytest.mark.parametrize("name", ["pancake", "sliding"])
def test_the_c_generator_steps_like_the_pytorch_stepper(built, name):
    """Pieces of 1 to 7 measured states with noise, through the end of the motion and into the stop."""
    model, _, library = built[name]
    c = model.model.chunk
    k = 2 * c + 30
    motion = inputs(name, model, k)[0]
    reference = model.generator(motion)
    state = generator(library, model, reference.latent, reference._x0[0], k)
    out = np.zeros((c, model.accel_layout.dim))
    n = library.seqmotion_generator_step(ptr(state), None, 0, ptr(out))
    u = reference.step()
    scale = np.asarray(model.model.cfg.output_scale)
    worst, x, rng, call = float((np.abs(out[:n] - u) / scale).max()), reference._x0[0], np.random.default_rng(3), 0
    while reference.time < k + 150:
        m = min((1, 1, 4, 1, 7)[call % 5], len(u))
        call += 1
        with torch.inference_mode():
            states = model.integrate_torch(torch.from_numpy(x[None]), torch.from_numpy(u[None, :m]))[0, 1:].numpy()
        x = states[-1]
        measured = np.ascontiguousarray(states + 1e-4 * rng.standard_normal(states.shape))
        u = reference.step(measured)
        n = library.seqmotion_generator_step(ptr(state), ptr(measured), m, ptr(out))
        assert n == len(u)
        worst = max(worst, float((np.abs(out[:n] - u) / scale).max()))
    assert reference.stopping and worst <= 1e-5


@pytest.mark.parametrize("name", ["pancake", "sliding"])
def test_prepare_between_calls_changes_no_output_bit(built, name):
    """Two C generators fed the same noisy states one per call (several now and then), one calling
    ``seqmotion_generator_prepare`` after most calls (twice now and then): the same outputs, bit for bit."""
    model, _, library = built[name]
    c, d = model.model.chunk, model.accel_layout.dim
    k = 2 * c + 30
    reference = model.generator(inputs(name, model, k)[0])
    plain, prepared = (generator(library, model, reference.latent, reference._x0[0], k) for _ in range(2))
    out_a, out_b = np.zeros((c, d)), np.zeros((c, d))
    n = library.seqmotion_generator_step(ptr(plain), None, 0, ptr(out_a))
    assert library.seqmotion_generator_step(ptr(prepared), None, 0, ptr(out_b)) == n
    x, rng = reference._x0[0], np.random.default_rng(5)
    for call in range(k + 60):
        m = min(3 if call % 23 == 11 else 1, n)
        with torch.inference_mode():
            states = model.integrate_torch(torch.from_numpy(x[None]), torch.from_numpy(out_a[None, :m]))[0, 1:]
        x = states.numpy()[-1]
        measured = np.ascontiguousarray(states.numpy() + 1e-4 * rng.standard_normal((m, len(x))))
        n = library.seqmotion_generator_step(ptr(plain), ptr(measured), m, ptr(out_a))
        assert library.seqmotion_generator_step(ptr(prepared), ptr(measured), m, ptr(out_b)) == n > 0
        assert np.array_equal(out_a[:n], out_b[:n]), call
        for _ in range((call % 4 != 0) + (call % 9 == 2)):
            library.seqmotion_generator_prepare(ptr(prepared))


def test_the_generator_refuses_what_the_stepper_refuses_and_changes_nothing(built):
    model, _, library = built["pancake"]
    motion = inputs("pancake", model, 120)[0]
    reference = model.generator(motion)
    z, x0 = reference.latent, reference._x0[0]
    out = np.zeros((50, 3))
    zz, xx = z.astype(np.float32), np.ascontiguousarray(x0)
    library.seqmotion_generator_size.restype = ctypes.c_ulong
    state = np.zeros(library.seqmotion_generator_size(), dtype=np.uint8)
    assert library.seqmotion_generator_start(ptr(state), ptr(zz), ptr(xx), ctypes.c_long(1), None, 1) == \
        ERRORS["argument"]
    state = generator(library, model, z, x0, 120)
    measured = np.ascontiguousarray(x0[None])
    assert library.seqmotion_generator_step(ptr(state), ptr(measured), 1, ptr(out)) == ERRORS["call"]
    assert library.seqmotion_generator_step(ptr(state), None, 0, ptr(out)) == 50
    assert library.seqmotion_generator_step(ptr(state), None, 0, ptr(out)) == ERRORS["call"]
    many = np.ascontiguousarray(np.repeat(measured, 51, axis=0))
    assert library.seqmotion_generator_step(ptr(state), ptr(many), 51, ptr(out)) == ERRORS["too_many"]
    for bad in (np.nan, np.inf, 2e6):
        wrong = measured.copy()
        wrong[0, 1] = bad
        assert library.seqmotion_generator_step(ptr(state), ptr(wrong), 1, ptr(out)) == ERRORS["state"]
    assert library.seqmotion_generator_step(ptr(state), ptr(measured), 1, ptr(out)) == 49  # t advanced once only
    reference.step()
    np.testing.assert_allclose(reference.step(measured), out[:49], rtol=0, atol=1e-5 * 100)


def test_the_header_carries_the_contract(built):
    model, folder, _ = built["spring"]
    header = (folder / "seqmotion_model.h").read_text()
    source = (folder / "seqmotion_model.c").read_text()
    contract = model.generator(inputs("spring", model, 45)[0]).contract()
    for macro, value in (("CHUNK", contract["chunk"]), ("STATE_DIM", 4), ("ACCEL_DIM", 2), ("LAYERS", 1),
                         ("HIDDEN", 16), ("LATENT_DIM", 16), ("PHYSICS_DIM", 2), ("STOP_SHRINK_COUNT", 5)):
        assert re.search(rf"^#define SEQMOTION_{macro} {value}\b", header, re.M), macro
    assert re.search(r"^#define SEQMOTION_DT 0\.001\b", header, re.M) and "stiffness, damping" in header
    assert 'seqmotion_physics_names[2] = {"stiffness", "damping"}' in source
    assert "seqmotion_physics_defaults[2] = {40.0, 2.0}" in source
    assert "malloc" not in source and "malloc" not in (folder / "seqmotion_generator.c").read_text()


def test_a_cpp_control_loop_embeds_the_generator(built, tmp_path):
    """The example C++ loop (examples/realtime/loop.cpp) builds against the exported headers and runs a motion."""
    cxx = shutil.which("c++") or shutil.which("g++") or shutil.which("clang++")
    if cxx is None:
        pytest.skip("no C++ compiler")
    model, folder, _ = built["pancake"]
    objects = []
    for part in ("model", "generator"):
        target = tmp_path / f"{part}.o"
        subprocess.run([COMPILER, "-O2", "-std=c99", "-c", str(folder / f"seqmotion_{part}.c"), "-o", str(target)],
                       check=True, capture_output=True)
        objects.append(str(target))
    binary = tmp_path / "loop"
    done = subprocess.run([cxx, "-O2", "-std=c++17", "-Wall", "-Wextra", f"-I{folder}", str(EXAMPLE), *objects,
                           "-o", str(binary), "-lm"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    motion = inputs("pancake", model, 130)[0]
    with torch.inference_mode():
        x = torch.from_numpy(motion[None])
        z, x0 = model.encode_torch(x)[0].numpy(), model.start_state(x).double()[0].numpy()
    latent = tmp_path / "latent.txt"
    latent.write_text(f"130\n{' '.join(map(repr, x0.tolist()))}\n{' '.join(map(repr, z.tolist()))}\n")
    run = subprocess.run([str(binary), str(latent), "300"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    assert "300 periods:" in run.stdout and "seqmotion_generator_step: p50" in run.stdout


def test_what_has_no_c_form_is_refused_by_name(tmp_path):
    from onnx import TensorProto, helper

    def model(nodes, inputs, outputs):  # noqa: ANN001, ANN202
        graph = helper.make_graph(nodes, "g", inputs, outputs)
        return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])

    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [4])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, None)
    k = helper.make_tensor_value_info("k", TensorProto.INT64, None)
    top = model([helper.make_node("Constant", [], ["n"], value=helper.make_tensor("n", TensorProto.INT64, [1], [2])),
                 helper.make_node("TopK", ["x", "n"], ["y", "k"])], [x], [y, k])
    statics = c_values.Statics("t")
    with pytest.raises(ValueError, match="the op TopK .* has no C form"):
        c_emit.Emitter(statics, "t_f", top, [("x", "x", (4,), np.dtype(np.float32))], [("y", "y")],
                         {"x": np.zeros(4, np.float32)}).emit()
    n = helper.make_tensor_value_info("n", TensorProto.INT64, [])
    ranged = model([helper.make_node("Constant", [], ["zero"], value=helper.make_tensor("zero", TensorProto.INT64, [],
                                                                                          [0])),
                    helper.make_node("Constant", [], ["one"], value=helper.make_tensor("one", TensorProto.INT64, [],
                                                                                         [1])),
                    helper.make_node("Range", ["zero", "n", "one"], ["y"])], [n],
                   [helper.make_tensor_value_info("y", TensorProto.INT64, None)])
    with pytest.raises(ValueError, match="makes a shape from the data"):
        c_emit.Emitter(statics, "t_g", ranged, [("n", "n", (), np.dtype(np.int64))], [("y", "y")],
                         {"n": np.array(3, np.int64)}).emit()
    with pytest.raises(ValueError, match="prefix must be a C identifier"):
        export_c(sm.load_pretrained("pancake"), tmp_path / "c", prefix="not valid")
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError, match="it is a file"):
        export_c(sm.load_pretrained("pancake"), tmp_path / "file")


def test_a_constraint_of_later_samples_is_refused(tmp_path):
    pointwise = lambda s, a: np.abs(a[..., 0])  # noqa: E731
    assert c_export._causal(pointwise, 3, 2, 10)
    running = lambda s, a: np.cumsum(np.abs(a[..., ::-1, 0]), axis=-1)[..., ::-1]  # noqa: E731
    assert not c_export._causal(running, 3, 2, 10)
