"""Hostile attempts for the ONNX bundle: export-onnx's check before the swap (9), what the seal does not promise (10),
and the standalone runner's physics (17).

Each snippet runs after benchmarks/hostile.py's PRELUDE in a fresh interpreter and an empty temporary folder.
"""

from __future__ import annotations

# A plug-in task written into the cwd and registered through a fake distribution (as defect 8's attempts do): the
# pancake task under another name, whose example_inputs (what export-onnx's parity check runs on) are bad; its
# model is the shipped pancake model with the task renamed in a re-hashed config.
_PLUGIN = '''
Path("badplug.py").write_text("""
import numpy as np
from seqmotion.tasks.pancake import PancakeTask
class Bad(PancakeTask):
    name = "badpancake"
    model_class = None
    def example_inputs(self, n, seed=0):
        x = np.array(super().example_inputs(n, seed), dtype=float)
        {edit}
        return x
TASK = Bad()
""")
info = Path("badplug-0.1.dist-info"); info.mkdir()
(info / "METADATA").write_text("Metadata-Version: 2.1\\nName: badplug\\nVersion: 0.1\\n")
(info / "entry_points.txt").write_text("[seqmotion.tasks]\\nbadpancake = badplug:TASK\\n")
sys.path.insert(0, os.getcwd())
from seqmotion.core import registry
registry.refresh()
shutil.copytree(sm.api.pretrained_dir("pancake"), "m")
config = json.loads(Path("m/config.json").read_text())
config["task"] = "badpancake"
from seqmotion.training.checkpoint import config_digest
config.pop("config_sha256", None)
config["config_sha256"] = config_digest(config)
Path("m/config.json").write_text(json.dumps(config))
'''

_SWAP = '''
assert cli("export-onnx", "sliding", "b")[0] == 0  # a good bundle of another task
before = {p.name: sha(p) for p in Path("b").iterdir()}
rc, err = cli("export-onnx", "m", "b")
kept = {p.name: sha(p) for p in Path("b").iterdir()} == before
beside = [p.name for p in Path(".").iterdir() if p.name.startswith(".b")]
held(rc == 2 and kept and not beside and err.count("\\n") == 1 and "Traceback" not in err and {expect},
     f"rc {rc}, bundle {'kept' if kept else 'REPLACED'}, beside {beside}: {err[-300:]}")
'''

# A bundle re-sealed after a graph was replaced, as anyone holding it can (bundle.seal is public).
_RESEAL = '''
from seqmotion.deploy import OnnxModel, OnnxStepper, bundle, export_onnx
export_onnx(sm.load_pretrained("pancake"), "b")
export_onnx(sm.load_pretrained("sliding"), "s")
def reseal(key, data):
    contract = json.loads(Path("b/contract.json").read_text())
    Path("b", contract["files"][key]).write_bytes(data)
    blobs = {k: Path("b", name).read_bytes() for k, name in contract["files"].items() if name}
    Path("b/contract.json").write_text(json.dumps(bundle.seal(contract, blobs)))
def by_name(call, *names):
    try:
        call()
        return "accepted"
    except ValueError as exc:
        return "ok" if all(name in str(exc) for name in names) else f"unnamed: {exc}"
    except Exception as exc:
        return f"{type(exc).__name__}: {str(exc)[:200]}"
sketch = sketches.straight((0.1, 0.0, 2.0), 150)
'''

ATTEMPTS: dict[int, list[tuple[str, str]]] = {
    9: [(f"export-onnx of a plug-in whose example inputs {what}, over a good bundle",
         _PLUGIN.replace("{edit}", edit) + _SWAP.replace("{expect}", expect))
        for what, edit, expect in (
            ("hold NaN", "x[0, 3, 0] = np.nan", '"NaN" in err and "badpancake" in err'),
            ("are 5 wide, not 6", "x = x[..., :5]", '"badpancake" in err and "(2, 116, 5)" in err'),
        )],
    10: [
        ("re-sealed: the sliding decoder step in a pancake bundle", _RESEAL + """
reseal("decoder_step", Path("s/decoder_step.onnx").read_bytes())
what = by_name(lambda: OnnxStepper("b", sketch).step(), "decoder_step.onnx", "'h'")
held(what == "ok", what)
"""),
        ("re-sealed: a garbage encoder.onnx", _RESEAL + """
reseal("encoder", b"\\x08\\x07 not a graph " * 40)
what = by_name(lambda: OnnxModel("b"), "encoder.onnx")
held(what == "ok", what)
"""),
        ("re-sealed: a 4 kB violation.onnx with ConstantOfShape([40000, 40000])", _RESEAL + """
import resource
from onnx import TensorProto, helper, numpy_helper
nodes = [helper.make_node("ConstantOfShape", ["shape"], ["big"],
                          value=helper.make_tensor("one", TensorProto.FLOAT, [1], [1.0])),
         helper.make_node("ReduceSum", ["big"], ["total"], keepdims=0),
         helper.make_node("ReduceSum", ["accel", "last"], ["per_sample"], keepdims=0),
         helper.make_node("Add", ["per_sample", "total"], ["violation"])]
graph = helper.make_graph(nodes, "bomb",
                          [helper.make_tensor_value_info("states", TensorProto.FLOAT, ["B", "N1", 6]),
                           helper.make_tensor_value_info("accel", TensorProto.FLOAT, ["B", "N", 3])],
                          [helper.make_tensor_value_info("violation", TensorProto.FLOAT, ["B", "N"])],
                          [numpy_helper.from_array(np.array([40000, 40000], np.int64), "shape"),
                           numpy_helper.from_array(np.array([2], np.int64), "last")])
data = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]).SerializeToString()
assert len(data) < 4096
reseal("violation", data)
what = by_name(lambda: OnnxModel("b").generate(sketch), "violation.onnx", "ConstantOfShape")
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024
held(what == "ok" and peak < 2000, f"{what}; peak {peak} MB")
"""),
        ("re-sealed: a decoder step whose accel is NaN", _RESEAL + """
import onnx
from onnx import helper, numpy_helper
proto = onnx.load("b/decoder_step.onnx")
for node in proto.graph.node:
    node.output[:] = ["accel_raw" if name == "accel" else name for name in node.output]
proto.graph.initializer.append(numpy_helper.from_array(np.array(np.nan, np.float32), "not_a_number"))
proto.graph.node.append(helper.make_node("Mul", ["accel_raw", "not_a_number"], ["accel"]))
reseal("decoder_step", proto.SerializeToString())
model = OnnxModel("b")
whats = [by_name(call, "decoder_step.onnx", "NaN") for call in (
    lambda: model.generate(sketch), lambda: model.decode(np.zeros(128), np.zeros(6), 80),
    lambda: OnnxStepper(model, sketch).step())]
held(whats == ["ok"] * 3, str(whats))
"""),
    ],
    17: [("the standalone runner given physics the package refuses", """
from seqmotion.deploy import OnnxStepper, export_onnx
export_onnx(sm.load_pretrained("sliding"), "b")
sys.path.insert(0, os.path.abspath("b"))
from onnx_stepper import OnnxStepper as Standalone  # the copy beside the graphs (NumPy + onnxruntime only)
command = commands.line(0.05, 300)
results = []
for physics in ({"mu": -1.0}, {"mu_dyn": 2.0}, {"mu": 1e300}, {"mu": 0.3, "mu_dyn": 0.4}):
    mine = [refused(runner, "b", command, physics=physics) for runner in (OnnxStepper, Standalone)]
    results.append((physics, mine))
same = all(a is not None and a == b for _, (a, b) in results)
held(same, str([(p, m[1]) for p, m in results if m[1] is None or m[0] != m[1]]))
""")],
}
