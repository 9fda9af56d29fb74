"""The ONNX bundle, hardened: ``export-onnx`` checks before it swaps, loading checks what the seal cannot, and the
standalone runner refuses the physics the package refuses.

* export: the parity check runs on the new bundle in a folder beside OUT, before the swap; an example input with
  NaN or of the wrong width is refused in one line, and the old bundle stays byte for byte.
* load: the seal detects accidents, not intent (anyone can re-seal), so each graph's inputs and outputs are checked
  against the contract, a file onnxruntime cannot parse is refused by name, a graph's allocations are bounded (the
  op types the exporter writes, constant shapes under a cap, a capped arena at run time), and a graph that returns
  NaN or inf is refused in ``generate``, ``decode`` and ``step``, in the package and in the standalone copy.
* physics: the contract carries the ranges the task's physics class accepts, and one function checks them for both
  the package and the standalone runner.
"""

from __future__ import annotations

import json
import resource
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import seqmotion as sm
from seqmotion.cli import main as cli_main

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

from onnx import TensorProto, helper, numpy_helper  # noqa: E402

from seqmotion.deploy import OnnxModel, OnnxStepper, bundle  # noqa: E402
from seqmotion.deploy import export as export_module  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def _one_thread(one_thread):
    """Every test here runs torch on one thread (see conftest)."""


@pytest.fixture(scope="module")
def pristine(shipped_bundles):
    """The pancake (a constraint graph, physics the graph does not read) and sliding (friction the graph reads)
    bundles: the session's (conftest), read or copied, never changed."""
    return shipped_bundles


def copy(pristine: Path, name: str, to: Path) -> Path:
    return Path(shutil.copytree(pristine / name, to))


def files_of(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def beside(parent: Path) -> list[str]:
    """What an export left beside its output: temporaries and set-aside bundles."""
    return sorted(p.name for p in parent.iterdir() if p.name.startswith("."))


def reseal(folder: Path, **graphs: bytes) -> None:
    """Replace graphs (by their key in ``files``) and seal the contract again, as anyone holding the bundle can: the
    seal then holds, and only the load checks stand between the graphs and onnxruntime."""
    contract = json.loads((folder / "contract.json").read_text())
    for key, data in graphs.items():
        (folder / contract["files"][key]).write_bytes(data)
    blobs = {key: (folder / name).read_bytes() for key, name in contract["files"].items() if name}
    (folder / "contract.json").write_text(json.dumps(bundle.seal(contract, blobs), indent=2))


def standalone(folder: Path, body: str) -> list[str]:
    """Run ``body`` with the bundle's own runner (no torch, no seqmotion) under a 4 GiB address space; its printed
    lines. ``attempt(call)`` prints ``ValueError: <message>`` or ``ok``."""
    code = textwrap.dedent(f"""
        import sys
        sys.modules["torch"] = None
        sys.modules["seqmotion"] = None
        sys.path.insert(0, {str(folder)!r})
        import numpy as np
        from onnx_stepper import OnnxModel, OnnxStepper
        def attempt(call):
            try:
                call()
                print("ok")
            except ValueError as exc:
                print("ValueError:", exc)
        """) + textwrap.dedent(body)

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (4 * 2**30, 4 * 2**30))

    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=folder.parent,
                          timeout=120, preexec_fn=limit)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.splitlines()


def message(call, *args, **kwargs) -> str:
    with pytest.raises(ValueError) as info:
        call(*args, **kwargs)
    return str(info.value)


# --- export-onnx checks the new bundle before it swaps it in ------------------------------------------


@pytest.mark.parametrize("bad", ["NaN", "width"])
def test_a_failed_check_leaves_the_old_bundle_byte_for_byte(pristine, tmp_path, monkeypatch, capsys, bad):
    """A task whose example inputs hold NaN (or have the wrong width) exported over a good bundle of another task:
    the old code swapped the new bundle in, then its check failed (exit 2; a width: a traceback, exit 1)."""
    out = copy(pristine, "sliding", tmp_path / "out")
    before = files_of(out)
    task = sm.load_pretrained("pancake").task_def
    real = task.example_inputs

    def example_inputs(n: int, seed: int = 0) -> np.ndarray:
        x = np.array(real(n, seed), dtype=np.float64)
        if bad == "NaN":
            x[0, 3, 0] = np.nan
            return x
        return x[..., :5]

    monkeypatch.setattr(task, "example_inputs", example_inputs)
    assert cli_main(["export-onnx", "pancake", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("seqmotion export-onnx: error: ") and len(err.strip().splitlines()) == 1, err
    assert "'pancake'" in err and "Traceback" not in err
    if bad == "width":
        assert "(2, 116, 5)" in err and "6" in err, err
    else:
        assert "NaN" in err, err
    assert files_of(out) == before and beside(tmp_path) == []
    assert OnnxModel(out).contract["task"] == "sliding"


def test_the_check_runs_on_the_new_bundle_beside_out_before_the_swap(pristine, tmp_path, monkeypatch, capsys):
    out = copy(pristine, "sliding", tmp_path / "out")
    seen = []
    real = export_module.check_parity

    def spy(model, folder, inputs, physics=None):
        seen.append((Path(folder), json.loads((out / "contract.json").read_text())["task"],
                     json.loads((Path(folder) / "contract.json").read_text())["task"]))
        return real(model, folder, inputs, physics)

    monkeypatch.setattr(export_module, "check_parity", spy)
    assert cli_main(["export-onnx", "pancake", str(out)]) == 0
    assert "parity with PyTorch" in capsys.readouterr().out
    ((folder, at_out, checked),) = seen
    assert folder.parent == tmp_path and folder != out  # a sibling of OUT: the same file system, no copy
    assert (at_out, checked) == ("sliding", "pancake")  # OUT still held the old bundle while the new one was checked
    assert OnnxModel(out).contract["task"] == "pancake" and beside(tmp_path) == []


# --- what the seal does not promise: load checks ------------------------------------------------------


def test_a_resealed_graph_of_another_model_is_refused_at_load(pristine, tmp_path):
    """(a) the sliding decoder step in a pancake bundle: it loaded, then failed inside onnxruntime."""
    folder = copy(pristine, "pancake", tmp_path / "b")
    reseal(folder, decoder_step=(pristine / "sliding" / "decoder_step.onnx").read_bytes())
    text = message(OnnxModel, folder)
    assert "decoder_step.onnx" in text and "'h'" in text and "\n" not in text, text


def test_a_graph_that_is_not_one_is_refused_by_name(pristine, tmp_path):
    """(b) garbage in encoder.onnx raised onnxruntime's InvalidProtobuf."""
    folder = copy(pristine, "pancake", tmp_path / "b")
    reseal(folder, encoder=b"\x08\x07garbage, not a graph" * 10)
    text = message(OnnxModel, folder)
    assert "encoder.onnx" in text and "\n" not in text, text


def bomb(extra_nodes: list, extra_inits: list) -> bytes:
    """A violation graph of the pancake interface whose result adds the sum of a tensor the extra nodes make."""
    nodes = [*extra_nodes,
             helper.make_node("ReduceSum", ["big"], ["total"], keepdims=0),
             helper.make_node("ReduceSum", ["accel", "last"], ["per_sample"], keepdims=0),
             helper.make_node("Add", ["per_sample", "total"], ["violation"])]
    graph = helper.make_graph(
        nodes, "bomb",
        [helper.make_tensor_value_info("states", TensorProto.FLOAT, ["B", "N1", 6]),
         helper.make_tensor_value_info("accel", TensorProto.FLOAT, ["B", "N", 3])],
        [helper.make_tensor_value_info("violation", TensorProto.FLOAT, ["B", "N"])],
        [numpy_helper.from_array(np.array([2], np.int64), "last"), *extra_inits])
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]).SerializeToString()


CONSTANT_OF_SHAPE = bomb([helper.make_node("ConstantOfShape", ["shape"], ["big"],
                                           value=helper.make_tensor("one", TensorProto.FLOAT, [1], [1.0]))],
                         [numpy_helper.from_array(np.array([40000, 40000], np.int64), "shape")])
LOOP = bomb([helper.make_node("Loop", ["trips", "", "zero"], ["big"], body=helper.make_graph(
    [helper.make_node("Identity", ["cond_in"], ["cond_out"]), helper.make_node("Identity", ["v_in"], ["v_out"])],
    "body",
    [helper.make_tensor_value_info("i", TensorProto.INT64, []),
     helper.make_tensor_value_info("cond_in", TensorProto.BOOL, []),
     helper.make_tensor_value_info("v_in", TensorProto.FLOAT, [1])],
    [helper.make_tensor_value_info("cond_out", TensorProto.BOOL, []),
     helper.make_tensor_value_info("v_out", TensorProto.FLOAT, [1])]))],
    [numpy_helper.from_array(np.array(2**62, np.int64), "trips"),
     numpy_helper.from_array(np.zeros(1, np.float32), "zero")])


@pytest.mark.parametrize("graph, named", [(CONSTANT_OF_SHAPE, "ConstantOfShape"), (LOOP, "Loop")])
def test_a_graph_that_would_allocate_or_loop_without_bound_is_refused_at_load(pristine, tmp_path, graph, named):
    """(c) a 4 kB violation.onnx asking for 6.4 GB (or looping 2⁶² times) loaded, then failed or hung at run."""
    assert len(graph) < 4096
    folder = copy(pristine, "pancake", tmp_path / "b")
    reseal(folder, violation=graph)
    text = message(OnnxModel, folder)
    assert "violation.onnx" in text and named in text and "\n" not in text, text


def test_what_no_scan_sees_is_bounded_at_run_time(pristine, tmp_path):
    """Two 30000-element constants broadcast into 3.6 GB: no constant shape to read, so the capped arena refuses it
    when the graph runs (onnxruntime folded constants up to 1 GB while it loaded the graph, before any run)."""
    graph = bomb([helper.make_node("Add", ["column", "row"], ["big"])],
                 [numpy_helper.from_array(np.ones((30000, 1), np.float32), "column"),
                  numpy_helper.from_array(np.ones((1, 30000), np.float32), "row")])
    folder = copy(pristine, "pancake", tmp_path / "b")
    reseal(folder, violation=graph)
    lines = standalone(folder, f"""
        import resource
        model = OnnxModel({str(folder)!r})
        attempt(lambda: model.generate(np.zeros((60, 6))))
        print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024)
        """)
    assert lines[0].startswith("ValueError:") and "violation.onnx" in lines[0], lines
    # MB: within the arena's cap (2 GiB; onnxruntime may fill it before it refuses) and the process's own ~0.3 GB,
    # far from the 3.6 GB asked for
    assert int(lines[1]) < bundle.MAX_RUN_BYTES // 2**20 + 600


def test_a_graph_larger_than_any_export_is_refused_before_it_is_read(pristine, tmp_path, monkeypatch):
    folder = copy(pristine, "pancake", tmp_path / "b")
    size = (folder / "decoder_step.onnx").stat().st_size
    monkeypatch.setattr(bundle, "MAX_GRAPH_BYTES", size - 1)
    text = message(OnnxModel, folder)
    assert "decoder_step.onnx" in text and str(size) in text, text


def nan_decoder(pristine: Path) -> bytes:
    """The pancake decoder step with its accel output multiplied by NaN."""
    proto = onnx.load(str(pristine / "pancake" / "decoder_step.onnx"))
    for node in proto.graph.node:
        node.output[:] = ["accel_raw" if name == "accel" else name for name in node.output]
    proto.graph.initializer.append(numpy_helper.from_array(np.array(np.nan, np.float32), "not_a_number"))
    proto.graph.node.append(helper.make_node("Mul", ["accel_raw", "not_a_number"], ["accel"]))
    return proto.SerializeToString()


def test_a_graph_that_returns_nan_is_refused_everywhere(pristine, tmp_path):
    """(d) generate and decode returned the NaN outputs silently (only step refused them)."""
    folder = copy(pristine, "pancake", tmp_path / "b")
    reseal(folder, decoder_step=nan_decoder(pristine))
    model = OnnxModel(folder)  # a NaN is a value: only running the graph shows it
    sketch = sm.tasks.pancake.data.straight((0.1, 0.0, 2.0), 150)
    for call in (lambda: model.generate(sketch), lambda: model.decode(np.zeros(128), np.zeros(6), 80),
                 lambda: OnnxStepper(model, sketch).step()):
        text = message(call)
        assert "decoder_step.onnx" in text and "'accel'" in text and "NaN" in text, text
    lines = standalone(folder, f"""
        model = OnnxModel({str(folder)!r})
        sketch = np.zeros((150, 6))
        attempt(lambda: model.generate(sketch))
        attempt(lambda: model.decode(np.zeros(128), np.zeros(6), 80))
        attempt(lambda: OnnxStepper(model, sketch).step())
        """)
    assert len(lines) == 3 and all(line.startswith("ValueError:") and "decoder_step.onnx" in line for line in lines)


def test_the_shipped_bundles_pass_the_load_checks_and_run_as_before(pristine):
    for name, motion in (("pancake", np.zeros((120, 6))), ("sliding", sm.tasks.sliding.data.line(0.05, 300))):
        out = OnnxModel(pristine / name).generate(motion)
        assert np.all(np.isfinite(out["states"])) and np.all(np.isfinite(out["accel"]))


# --- one physics check for the package and the standalone runner --------------------------------------


SLIDING_PHYSICS = [{"mu": -1.0}, {"mu_dyn": 2.0}, {"mu": 1e300}, {"mu": 0.3, "mu_dyn": 0.4}, {"mu": 0.0},
                   {"mu_dyn": -0.1}, {"mu": 1000.5}]


def test_the_standalone_runner_refuses_the_physics_the_package_refuses(pristine, tmp_path):
    folder = copy(pristine, "sliding", tmp_path / "b")
    command = np.zeros((300, 4))
    mine = [message(OnnxStepper, folder, command, physics=physics) for physics in SLIDING_PHYSICS]
    for physics, text in zip(SLIDING_PHYSICS, mine, strict=True):
        assert str(folder / "contract.json") in text and next(iter(physics)) in text, text
    lines = standalone(folder, "\n".join(
        f"attempt(lambda: OnnxStepper({str(folder)!r}, np.zeros((300, 4)), physics={physics!r}))"
        for physics in SLIDING_PHYSICS))
    assert lines == [f"ValueError: {text}" for text in mine]
    # and both run where the package's physics class runs
    for physics in ({"mu": 0.5, "mu_dyn": 0.5}, {"mu": 1000.0, "mu_dyn": 0.0}, {"mu": 1e-9, "mu_dyn": 0.0}):
        sm.tasks.sliding.physics.SlidingPhysics(**physics)
        OnnxStepper(folder, command, physics=physics)


def test_the_contract_carries_the_ranges_of_the_physics_class(pristine):
    contract = json.loads((pristine / "sliding" / "contract.json").read_text())
    assert contract["physics_ranges"] == {
        "fields": {"mu": {"above": 0.0, "at_most": 1000.0}, "mu_dyn": {"at_least": 0.0}},
        "order": [["mu_dyn", "mu"]],
    }
    assert json.loads((pristine / "pancake" / "contract.json").read_text())["physics_ranges"] == {
        "fields": {}, "order": []}  # the pancake graph reads no physics: nothing to override


def test_a_bundle_whose_ranges_are_not_recorded_runs_only_at_its_own_physics(pristine, tmp_path):
    folder = copy(pristine, "sliding", tmp_path / "b")
    contract = json.loads((folder / "contract.json").read_text())
    del contract["physics_ranges"]  # a bundle exported before the contract carried them
    blobs = {key: (folder / name).read_bytes() for key, name in contract["files"].items() if name}
    (folder / "contract.json").write_text(json.dumps(bundle.seal(contract, blobs)))
    command = np.zeros((300, 4))
    OnnxStepper(folder, command).step()
    text = message(OnnxStepper, folder, command, physics={"mu": 0.9})
    assert "physics_ranges" in text and "re-export" in text, text


RULES = {
    "a >= 0 and b >= a": (lambda a, b: a >= 0 and b >= a, {"fields": {"a": {"at_least": 0.0}}, "order": [["a", "b"]]}),
    "0 < a <= 2 and b < 5": (lambda a, b: 0 < a <= 2 and b < 5,
                             {"fields": {"a": {"above": 0.0, "at_most": 2.0}, "b": {"below": 5.0}}, "order": []}),
    "a * b <= 1": (lambda a, b: a * b <= 1, None),  # not ranges and orderings: only the exported physics run
}


@pytest.mark.parametrize("rule", list(RULES))
def test_the_ranges_are_read_off_the_physics_class(rule):
    import dataclasses

    from seqmotion.physics.parameters import Physics

    accepts, ranges = RULES[rule]

    @dataclasses.dataclass(frozen=True)
    class Rules(Physics):
        a: float = 0.5
        b: float = 1.0

        def __post_init__(self) -> None:
            if not accepts(self.a, self.b):
                raise ValueError(rule)

    assert export_module.physics_ranges(Rules(), ["a", "b"]) == ranges


def test_an_export_into_a_folder_whose_parent_is_new_is_checked_and_written(tmp_path, capsys):
    """`seqmotion export-onnx pancake onnx/pancake/` (the README's command) on a fresh machine: the parity check's
    folder beside OUT is made with OUT's missing parents, as the bundle itself is."""
    from seqmotion.cli import main

    out = tmp_path / "onnx" / "pancake"
    assert main(["export-onnx", "pancake", str(out)]) == 0, capsys.readouterr().err
    assert (out / "contract.json").is_file() and [p.name for p in out.parent.iterdir()] == ["pancake"]
