"""Export a trained model for deployment: ONNX graphs, the stepper's contract as JSON, and a NumPy runner.

``export_onnx(model, OUT)`` (``seqmotion export-onnx MODEL OUT/``) writes:

* ``encoder.onnx`` — any K: input ``chunks`` ``(B, n, C·input_dim)`` float64, the motion padded to
  whole chunks by repeating its last sample and reshaped (sample-major within a chunk); outputs
  ``z`` ``(B, L·H)`` float32 (the latent) and ``x0`` ``(B, S)`` float64 (the task's start state). The
  chunk loop is an ONNX ``Scan`` over the encoder's LN-LSTM step, so one call encodes any length.
* ``decoder_step.onnx`` — one decoder step: inputs ``h``, ``c`` ``(L, B, H)`` and ``window``
  ``(B, C, S)`` float32 (C states in physical units; the task's decoder-input map and the scales are
  inside); outputs ``h_out``, ``c_out`` and ``accel`` ``(B, C, d)`` (the Gaussian head's means).
* ``dynamics.onnx`` — one chunk of the task's own dynamics, traced from the PyTorch code the model
  trains with (``ChunkDynamics.step``; the sliding contact's stick/slip cases are ``Where`` nodes, so
  every case and every friction value runs through the same graph, and its per-sample loop is a ``Scan``
  whose body is the loop's traced step, :mod:`seqmotion.deploy.scan`): inputs ``x`` ``(B, S)`` and
  ``accel`` ``(B, C, d)`` float64, and ``physics`` ``(P,)`` float64 — the fields of the task's physics
  the dynamics read (:func:`~seqmotion.core.stepper.physics_inputs`; absent when there are none) —
  output ``states`` ``(B, C, S)`` float64, the C states that follow ``x``.
* ``dynamics_sample.onnx`` (dynamics without a closed form) — the same dynamics traced on one sample (``accel``
  ``(B, 1, d)``, ``states`` ``(B, 1, S)``): the runner predicts the plan's states one sample per call, so a
  chunk boundary does not pay for the whole chunk's prediction at once. Written only where C of its steps
  chained agree with ``dynamics.onnx`` (:func:`sample_graph`); without it the runner predicts the chunk at once.
* ``outputs_for.onnx`` (tasks whose outputs are not accelerations, e.g. joint torques) — the dynamics'
  ``outputs_for``, traced like ``dynamics.onnx``: inputs ``x`` ``(B, S)``, ``accel`` ``(B, C, d)`` float64
  (accelerations of the velocity columns) and ``physics`` as above, output ``outputs`` ``(B, C, d)``
  float64, the outputs that give those accelerations along the path from ``x`` (the stepper's stop).
* ``violation.onnx`` (tasks with a constraint) — ``states`` ``(B, N+1, S)``, ``accel`` ``(B, N, d)``
  float32 → ``violation`` ``(B, N)``: the task's constraint at the model's options.
* ``contract.json`` — :func:`seqmotion.core.stepper.stepper_contract` (layouts, units, chunk, dt,
  how z initialises the decoder, the stop, the dynamics' graph and physics) plus the graphs' files and
  tensors, sealed: the SHA-256 of each graph and of the contract itself (:mod:`seqmotion.deploy.bundle`,
  which also holds the schema the runner checks it against; an export the runner would refuse is
  refused here).
* ``onnx_stepper.py``, ``hot_path.py``, ``bundle.py``, ``stepper.py``, ``numpy_physics.py`` — the runner: NumPy +
  onnxruntime only (``from onnx_stepper import OnnxStepper`` with OUT/ on the path). Dynamics the
  contract names a closed form of (the double integrator) it computes in NumPy.
* with ``int8=True`` also ``decoder_step.int8.onnx``: onnxruntime's dynamic quantisation (int8
  weights per output channel) of the layers ≥ 256 wide, like ``TrainedModel.quantized()``.

``contract.json`` also carries ``physics_ranges`` (:func:`physics_ranges`): the ranges and orderings of the
physics fields the dynamics graph reads, read off the task's physics class, which the runner checks an override
against (:func:`seqmotion.deploy.bundle.check_physics`; the standalone copy has no physics classes).

With a ``check`` (``seqmotion export-onnx`` passes its parity check), the new bundle is first written
into a folder beside OUT and checked there; only a bundle that passed is swapped in. OUT/ is
replaced whole (:func:`write_bundle`): the bundle is written into a temporary sibling
folder, flushed to disk, and swapped in (the old bundle renamed aside to ``.OUT.previous``, the
new one renamed into place, the old one removed). A failure at any step leaves the old bundle; a
kill leaves the old bundle or the new one — between the two renames the old one under its aside
name, which the runner loads then and the next export puts back before it starts. OUT/ must be
new, empty, or a previous export: a folder holding anything else is refused, never deleted.
"""

from __future__ import annotations

import io
import json
import sys
import tempfile
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from ..core.stepper import DYNAMICS_GRAPH, OUTPUTS_FOR_GRAPH, stepper_contract
from ..core.trained import TrainedModel
from ..io import check_writable_dir, remove_path, replace_directory, temp_sibling, write_durable
from ..physics.parameters import Physics
from .bundle import CONTRACT, RANGES, check_contract, check_graph, physics_violation, previous_path, seal
from .scan import TracedLoop, defined_loops, expand_loops, prefixed, traced_loops

OPSET = 17
INT8_MIN_FEATURES = 256
RUNNER_FILES = ("onnx_stepper.py", "hot_path.py", "bundle.py", "numpy_physics.py")
GRAPH_FILES = {"encoder": "encoder.onnx", "decoder_step": "decoder_step.onnx", "dynamics": DYNAMICS_GRAPH,
               "violation": "violation.onnx", "decoder_step_int8": "decoder_step.int8.onnx",
               "outputs_for": OUTPUTS_FOR_GRAPH, "dynamics_sample": "dynamics_sample.onnx"}
"""The graphs' file names, by their key in the contract's ``files``."""
BUNDLE_NAMES = frozenset({CONTRACT, "stepper.py", *RUNNER_FILES, *GRAPH_FILES.values(), "__pycache__"})
"""What a previous export (of any version) holds; ``__pycache__``: Python's, from running the runner there."""


class EncoderInput(nn.Module):
    """Chunked motion ``(B, n, C·in)`` → start state, the encoder's projected chunks and zero states."""

    def __init__(self, trained: TrainedModel) -> None:
        super().__init__()
        self.trained, self.model = trained, trained.model
        cfg = self.model.cfg
        self.layers, self.chunk, self.input_dim = cfg.layers, cfg.chunk, cfg.encoder_input_dim

    def forward(self, chunks: torch.Tensor) -> tuple[torch.Tensor, ...]:
        b = chunks.shape[0]
        motion = chunks.reshape(b, -1, self.input_dim)
        x0 = self.trained.start_state(motion)
        scaled = (motion.float() / self.model.encoder_scale).reshape(b, -1, self.chunk * self.input_dim)
        proj = self.model.encoder_in(scaled)
        zeros = torch.zeros_like(proj[:, 0]).unsqueeze(0).repeat(self.layers, 1, 1)
        return x0, proj, zeros, zeros.clone()


class EncoderStep(nn.Module):
    """One encoder step over all layers: ``(h, c)`` ``(L, B, H)`` and a projected chunk ``(B, H)``."""

    def __init__(self, trained: TrainedModel) -> None:
        super().__init__()
        self.cells = trained.model.encoder.cells

    def forward(self, h: torch.Tensor, c: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        hs, cs = [], []
        for layer, cell in enumerate(self.cells):
            h_l, c_l = cell(x, (h[layer], c[layer]))
            hs.append(h_l)
            cs.append(c_l)
            x = h_l
        return torch.stack(hs), torch.stack(cs)


class DecoderStep(nn.Module):
    """One decoder step with the state flattened: ``(h, c, window)`` → ``(h_out, c_out, accel)``: the model's
    ``decode_step`` (the means only), traced into few graph nodes, since onnxruntime runs a graph node by node and
    at one trajectory a node's dispatch costs more than its arithmetic (a 1 kHz call is mostly that):

    * the input scaling folded into ``decoder_in``'s columns, and the head's mean rows, scale and offset into its
      last layer (one ``Gemm`` where a ``Div``, a ``Slice``, a ``Mul`` and an ``Add`` were);
    * each layer's state kept ``(1, B, H)`` (one ``Split`` of ``h``, one of ``c``, one ``Concat`` out, where each
      layer was a ``Gather`` in and an ``Unsqueeze`` out);
    * the input, forget and output gates through one ``Sigmoid``: the inference cell's arithmetic
      (``LayerNormLSTMCell.step_projected``), element by element in the same order.

    The same function to float rounding (`seqmotion export-onnx` checks it against PyTorch: :func:`check_parity`)."""

    def __init__(self, trained: TrainedModel, dynamics: Any) -> None:
        super().__init__()
        model, self.dynamics = trained.model, dynamics
        self.cells, self.hidden = model.decoder.cells, model.decoder.hidden_size
        head, chunk = model.head, model.cfg.chunk
        self.head_hidden = head.net[:-1]  # the head's hidden layer, if it has one
        self.chunk, self.dim = chunk, head.dim
        last = head.net[-1]
        rows = (torch.arange(chunk)[:, None] * head.per_sample + torch.arange(head.dim)[None, :]).reshape(-1)
        scale, offset = head.scale.repeat(chunk), head.offset.repeat(chunk)  # (C·d,): per sample, its dims
        column_scale = model.decoder_scale.repeat(chunk)  # (C·S,): the flattened window's columns
        with torch.no_grad():
            self.register_buffer("in_weight", model.decoder_in.weight / column_scale[None, :])
            self.register_buffer("in_bias", model.decoder_in.bias.clone())
            self.register_buffer("mean_weight", last.weight[rows] * scale[:, None])
            self.register_buffer("mean_bias", last.bias[rows] * scale + offset)

    def forward(self, h: torch.Tensor, c: torch.Tensor, window: torch.Tensor) -> tuple[torch.Tensor, ...]:
        flat = self.dynamics.decoder_input(window).to(self.in_weight.dtype).flatten(1)
        x = nn.functional.linear(flat, self.in_weight, self.in_bias)  # (B, H)
        hs, cs, H = [], [], self.hidden
        for cell, h_l, c_l in zip(self.cells, h.split(1), c.split(1), strict=True):  # (1, B, H) each
            gates = cell.ln_input(cell.input_proj(x)) + cell.ln_hidden(cell.hidden_proj(h_l))
            ifo, g = gates.split([3 * H, H], dim=-1)
            i, f, o = torch.sigmoid(ifo).split(H, dim=-1)
            c_l = f * c_l + i * torch.tanh(g)
            h_l = o * torch.tanh(cell.ln_cell(c_l))
            hs.append(h_l)
            cs.append(c_l)
            x = h_l
        top = self.head_hidden(x.squeeze(0))
        mean = nn.functional.linear(top, self.mean_weight, self.mean_bias).reshape(-1, self.chunk, self.dim)
        return torch.cat(hs), torch.cat(cs), mean


class DynamicsStep(nn.Module):
    """One chunk of the task's dynamics, ``(x (B, S), accel (B, C, d)[, physics (P,)])`` → ``states (B, C, S)``:
    ``model.dynamics(physics)`` with each field in ``inputs`` set, as an attribute of the dynamics object, to the
    traced ``physics[i]`` (a 0-d tensor), so the graph computes with whatever value it is given."""

    def __init__(self, trained: TrainedModel, physics: Physics, inputs: list[str]) -> None:
        super().__init__()
        self.trained, self.physics, self.inputs = trained, physics, list(inputs)

    def forward(self, x: torch.Tensor, accel: torch.Tensor, physics: torch.Tensor | None = None) -> torch.Tensor:
        dynamics = self.trained.dynamics(self.physics)
        for i, name in enumerate(self.inputs):
            setattr(dynamics, name, physics[i])
        _, out = dynamics.step(dynamics.start(x), accel, None)
        return out["states"]


class OutputsFor(DynamicsStep):
    """The dynamics' ``outputs_for``, ``(x (B, S), accel (B, C, d)[, physics (P,)])`` → ``outputs (B, C, d)``,
    with the physics fields set like :class:`DynamicsStep`'s."""

    def forward(self, x: torch.Tensor, accel: torch.Tensor, physics: torch.Tensor | None = None) -> torch.Tensor:
        dynamics = self.trained.dynamics(self.physics)
        for i, name in enumerate(self.inputs):
            setattr(dynamics, name, physics[i])
        return dynamics.outputs_for(x, accel)


class Violation(nn.Module):
    """The task's constraint at the model's options, for ``(states (B, N+1, S), accel (B, N, d))``."""

    def __init__(self, trained: TrainedModel) -> None:
        super().__init__()
        self.trained = trained

    def forward(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return self.trained.violation_torch(states, accel)


def to_onnx(module: nn.Module, args: tuple, inputs: list[str], outputs: list[str],
            dynamic: dict[str, dict[int, str]], loops: Sequence[TracedLoop] | None = None) -> Any:
    """``module`` traced into an ONNX ModelProto (TorchScript exporter, opset :data:`OPSET`), each loop placeholder
    of ``loops`` as a ``Scan`` (:func:`~seqmotion.deploy.scan.expand_loops`). ``loops``: the dynamics' own
    ``traced_loops``; None: every placeholder defined (:func:`~seqmotion.deploy.scan.defined_loops`)."""
    import onnx

    buffer = io.BytesIO()
    with warnings.catch_warnings(), torch.inference_mode(False), torch.no_grad():
        warnings.simplefilter("ignore")
        torch.onnx.export(module.eval(), args, buffer, dynamo=False, opset_version=OPSET, input_names=inputs,
                          output_names=outputs, dynamic_axes=dynamic, do_constant_folding=True)
    return expand_loops(onnx.load_from_string(buffer.getvalue()), OPSET, defined_loops() if loops is None else loops)


def encoder_graph(trained: TrainedModel) -> Any:
    """The encoder for any number of chunks: the input stage, then a ``Scan`` over :class:`EncoderStep`."""
    import onnx
    from onnx import TensorProto, helper

    cfg = trained.model.cfg
    c, width, layers, hidden = cfg.chunk, cfg.chunk * cfg.encoder_input_dim, cfg.layers, cfg.hidden
    chunks = torch.zeros(1, 2, width, dtype=torch.float64)
    front = to_onnx(EncoderInput(trained), (chunks,), ["chunks"], ["x0", "proj", "h0", "c0"],
                    {"chunks": {0: "B", 1: "n"}, "x0": {0: "B"}, "proj": {0: "B", 1: "n"}, "h0": {1: "B"},
                     "c0": {1: "B"}})
    step = to_onnx(EncoderStep(trained), (torch.zeros(layers, 1, hidden), torch.zeros(layers, 1, hidden),
                                          torch.zeros(1, hidden)),
                   ["h", "c", "x"], ["h_out", "c_out"], {"h": {1: "B"}, "c": {1: "B"}, "x": {0: "B"},
                                                         "h_out": {1: "B"}, "c_out": {1: "B"}})
    body = prefixed(step.graph, "step/")
    graph = front.graph
    graph.node.extend([
        helper.make_node("Scan", ["h0", "c0", "proj"], ["h_last", "c_last"], name="chunk_loop", body=body,
                         num_scan_inputs=1, scan_input_axes=[1]),
        helper.make_node("Transpose", ["c_last"], ["c_by_batch"], name="latent_transpose", perm=[1, 0, 2]),
        helper.make_node("Constant", [], ["latent_shape"], name="latent_shape",
                         value=helper.make_tensor("latent_shape_value", TensorProto.INT64, [2], [0, -1])),
        helper.make_node("Reshape", ["c_by_batch", "latent_shape"], ["z"], name="latent"),
    ])
    x0 = next(v for v in graph.output if v.name == "x0")
    del graph.output[:]
    graph.output.extend([helper.make_tensor_value_info("z", TensorProto.FLOAT, ["B", layers * hidden]), x0])
    graph.name = f"seqmotion encoder (C = {c}, any number of chunks)"
    onnx.checker.check_model(front)
    return front


def gemm_as_matmul(proto: Any) -> Any:
    """A copy of ``proto`` with each ``Gemm(x, W, b)`` of a constant weight (alpha = beta = 1, x not
    transposed) written as ``MatMul(x, Wᵀ) + b``: the same numbers, in a form dynamic quantisation takes."""
    import onnx
    from onnx import helper, numpy_helper

    model = onnx.ModelProto()
    model.CopyFrom(proto)
    graph = model.graph
    inits = {init.name: init for init in graph.initializer}
    nodes = []
    for node in graph.node:
        attrs = {a.name: helper.get_attribute_value(a) for a in node.attribute}
        plain = attrs.get("alpha", 1.0) == 1.0 and attrs.get("beta", 1.0) == 1.0 and not attrs.get("transA", 0)
        if node.op_type != "Gemm" or not plain or node.input[1] not in inits:
            nodes.append(node)
            continue
        weight = numpy_helper.to_array(inits[node.input[1]])
        name = node.input[1] + ".matmul"
        graph.initializer.append(numpy_helper.from_array(weight.T.copy() if attrs.get("transB", 0) else weight, name))
        product = node.output[0] + ".product" if len(node.input) > 2 else node.output[0]
        nodes.append(helper.make_node("MatMul", [node.input[0], name], [product], name=node.name))
        if len(node.input) > 2:
            nodes.append(helper.make_node("Add", [product, node.input[2]], [node.output[0]], name=node.name + ".bias"))
    del graph.node[:]
    graph.node.extend(nodes)
    used = {name for node in nodes for name in node.input}
    kept = [init for init in graph.initializer if init.name in used]
    del graph.initializer[:]
    graph.initializer.extend(kept)
    return model


def quantized(proto: Any, workdir: Path, min_features: int = INT8_MIN_FEATURES) -> bytes:
    """``proto`` with the weights of its MatMul/Gemm layers of ≥ ``min_features`` inputs and outputs in int8
    (onnxruntime's dynamic quantisation, per output channel); narrow layers stay float32, as in
    :meth:`~seqmotion.tasks.TrainedModel.quantized`."""
    import logging

    from onnxruntime.quantization import QuantType, quantize_dynamic

    original, proto = proto, gemm_as_matmul(proto)  # dynamic quantisation covers MatMul, not Gemm
    weights = {init.name: tuple(init.dims) for init in proto.graph.initializer}
    nodes = [node.name for node in proto.graph.node if node.op_type == "MatMul"
             and len(weights.get(node.input[1], ())) == 2 and min(weights[node.input[1]]) >= min_features]
    if not nodes:
        return original.SerializeToString()  # nothing wide enough: the float graph
    source, target = workdir / ".float.tmp.onnx", workdir / ".int8.tmp.onnx"
    source.write_bytes(proto.SerializeToString())
    level = logging.getLogger().level
    logging.getLogger().setLevel(logging.ERROR)  # quantize_dynamic's advice to pre-process is for CNNs
    try:
        quantize_dynamic(source, target, weight_type=QuantType.QInt8, per_channel=True, nodes_to_quantize=nodes)
        return target.read_bytes()
    finally:
        logging.getLogger().setLevel(level)
        for path in (source, target):
            path.unlink(missing_ok=True)


def bundle_target(out: str | Path) -> Path:
    """The folder a bundle for ``out`` is swapped into (a link is followed), refused before any work if it is a
    file, holds the current directory, cannot be written beside, or is a non-empty folder that is not a
    previous export (its files are the user's: they are never deleted).

    Raises:
        ValueError: naming ``out`` and, for a foreign folder, what it holds.
    """
    target = Path(out).resolve()
    if Path.cwd().resolve().is_relative_to(target):
        raise ValueError(f"cannot export into {out}: it holds the current directory, which the export replaces")
    if target.exists():
        if not target.is_dir():
            raise ValueError(f"cannot export into {out}: it is a file, not a folder")
        names = sorted(entry.name for entry in target.iterdir())
        foreign = [name for name in names if name not in BUNDLE_NAMES]
        if names and (CONTRACT not in names or foreign):
            held = ", ".join(foreign[:5]) + (", ..." if len(foreign) > 5 else "") if foreign else f"no {CONTRACT}"
            raise ValueError(f"cannot export into {out}: it is not empty and not an exported model (it holds {held}); "
                             "export into a new or empty folder (a previous export is replaced whole, and nothing "
                             "else is deleted)")
    check_writable_dir(target.parent, shown=out)
    return target


def write_bundle(out: str | Path, files: dict[str, bytes], check: Callable[[Path], None] | None = None) -> None:
    """Replace the folder ``out`` by one holding ``files`` (name → bytes), whole (module docstring;
    :func:`~seqmotion.io.replace_directory`, the old bundle set aside under the name the runner
    knows, :func:`~seqmotion.deploy.bundle.previous_path`).

    Args:
        check: called with a folder beside ``out`` holding ``files`` before anything at ``out`` changes; what it
            raises ends the export with the old bundle untouched (the folder is removed either way).

    Raises:
        ValueError: ``out`` is not a folder a bundle may replace (:func:`bundle_target`), or ``check`` refused.
        OSError: a write, flush or rename failed (the old bundle is left as it was).
    """
    target = bundle_target(out)
    if check is not None:
        # a sibling under the temporaries' name: the same file system as OUT, and a killed export's copy is removed
        # by the next export into OUT (io's orphan clean-up)
        scratch = temp_sibling(target)
        try:
            scratch.mkdir(parents=True)  # OUT's parent may not exist yet (replace_directory makes it too)
            for name, data in files.items():
                write_durable(scratch / name, data)
            check(scratch)
        finally:
            remove_path(scratch)
    replace_directory(target, files, previous_path(target))


PARITY_TOLERANCE = 1e-6
"""How far (relative to the states' largest magnitude) the traced dynamics graph may differ from the PyTorch
dynamics on inputs other than the traced ones before the export is refused: rounding in another order is
~1e-16 in float64 and ~1e-7 in float32; a value the tracer baked in (a Python ``if`` on a tensor, a NumPy
call) is off by the size of the states themselves."""


def shared_constants(proto: Any) -> Any:
    """A copy of ``proto`` in which each ``Constant`` node's value is made once: a later ``Constant`` of the same
    type, shape and bytes is dropped and its uses read the first. The tracer writes a constant per use, which for
    the per-sample steps of a dynamics graph is hundreds of copies of ``dt`` and ``0``; fewer make a smaller graph
    to keep in cache, and the same numbers (only names change)."""
    import onnx
    from onnx import numpy_helper

    model = onnx.ModelProto()
    model.CopyFrom(proto)
    graph = model.graph
    first: dict[tuple, str] = {}
    renamed: dict[str, str] = {}
    outputs = {value.name for value in graph.output}
    nodes = []
    for node in graph.node:
        node.input[:] = [renamed.get(name, name) for name in node.input]
        if (node.op_type == "Constant" and len(node.attribute) == 1 and node.attribute[0].name == "value"
                and node.output[0] not in outputs):
            value = node.attribute[0].t
            key = (value.data_type, tuple(value.dims), numpy_helper.to_array(value).tobytes())
            if key in first:
                renamed[node.output[0]] = first[key]
                continue
            first[key] = node.output[0]
        nodes.append(node)
    del graph.node[:]
    graph.node.extend(nodes)
    return model


def physics_read(proto: Any) -> set[int]:
    """The entries of the graph input ``physics`` that ``proto`` reads: each ``Gather(physics, i)`` with a
    constant index i (how the tracer writes ``physics[i]``); any other use of ``physics`` reads all of it.
    Returns the empty set when the graph has no ``physics`` input or never uses it."""
    from onnx import numpy_helper

    graph = proto.graph
    if not any(value.name == "physics" for value in graph.input):
        return set()
    size = next(v for v in graph.input if v.name == "physics").type.tensor_type.shape.dim[0].dim_value
    constants = {init.name: numpy_helper.to_array(init) for init in graph.initializer}
    for node in graph.node:
        if node.op_type == "Constant" and node.attribute and node.attribute[0].name == "value":
            constants[node.output[0]] = numpy_helper.to_array(node.attribute[0].t)
    read: set[int] = set()
    for node in graph.node:
        if "physics" not in node.input:
            continue
        index = constants.get(node.input[1]) if node.op_type == "Gather" and len(node.input) > 1 else None
        if index is None or np.ndim(index) != 0:
            return set(range(size))
        read.add(int(index) % size)
    return read


def dynamics_graph(model: TrainedModel, physics: Physics, inputs: list[str]) -> Any:
    """The ``dynamics`` graph of ``model`` at ``physics``, with a ``physics`` input for the fields ``inputs``
    (module docstring), checked: each of those fields is read by the graph, and on inputs other than the
    traced ones the graph computes what the PyTorch dynamics do.

    Raises:
        ValueError: naming the task and the reason: tracing failed, the dynamics hold a physics field as an
            attribute the traced step does not read (a value derived from it when the dynamics were built
            would not follow an override), or the graph differs from PyTorch (something the tracer cannot
            follow, such as a Python ``if`` on a tensor's value: write it with ``torch.where``).
    """
    task = model.task_def.name
    cfg = model.model.cfg
    s, d = model.state_layout.dim, model.accel_layout.dim
    step = DynamicsStep(model, physics, inputs)
    vector = (torch.tensor([getattr(physics, name) for name in inputs], dtype=torch.float64),) if inputs else ()
    x, accel = torch.zeros(1, s, dtype=torch.float64), torch.zeros(1, cfg.chunk, d, dtype=torch.float64)
    try:
        proto = to_onnx(step, (x, accel, *vector), ["x", "accel", *(["physics"] if inputs else [])], ["states"],
                        {"x": {0: "B"}, "accel": {0: "B"}, "states": {0: "B"}},
                        traced_loops(model.dynamics(physics)))
    except Exception as exc:  # whatever the task's own dynamics code raises under the tracer
        raise ValueError(f"the {task!r} task's dynamics ({type(model.dynamics(physics)).__name__}) cannot be "
                         f"exported as an ONNX graph: tracing their step failed with {type(exc).__name__}: {exc}"
                         ) from exc
    proto = shared_constants(proto)
    read = physics_read(proto)
    unread = [name for i, name in enumerate(inputs) if i not in read]
    if unread:
        raise ValueError(f"the {task!r} task's dynamics ({type(model.dynamics(physics)).__name__}) hold the physics "
                         f"field(s) {unread} as attributes, but the traced step does not read them: a deployed model "
                         "could not run at other values of them. Read them in step() (not a value derived from them "
                         "when the dynamics are built), or name the attribute unlike the field")
    _check_traced(model, physics, inputs, proto)
    return proto


def sample_graph(model: TrainedModel, physics: Physics, inputs: list[str], chunk_graph: Any) -> Any | None:
    """The ``dynamics_sample`` graph (module docstring): the dynamics traced on one sample, or None where it cannot
    stand in for the chunk graph — tracing fails, or C of its steps chained from random states and outputs (at rest
    and moving, up to the output scale) differ from one run of ``chunk_graph`` by more than
    :data:`PARITY_TOLERANCE` of the states' magnitude (dynamics whose chunk is more than its samples one after the
    other: the runner then predicts whole chunks)."""
    import onnxruntime as ort

    cfg = model.model.cfg
    s, d, c = model.state_layout.dim, model.accel_layout.dim, cfg.chunk
    vector = (torch.tensor([getattr(physics, name) for name in inputs], dtype=torch.float64),) if inputs else ()
    try:
        proto = to_onnx(DynamicsStep(model, physics, inputs),
                        (torch.zeros(1, s, dtype=torch.float64), torch.zeros(1, 1, d, dtype=torch.float64), *vector),
                        ["x", "accel", *(["physics"] if inputs else [])], ["states"],
                        {"x": {0: "B"}, "accel": {0: "B"}, "states": {0: "B"}},
                        traced_loops(model.dynamics(physics)))
        proto = shared_constants(proto)
        rng = np.random.default_rng(1)
        x = 0.1 * rng.standard_normal((8, s))
        x[:2] = 0.0
        accel = np.asarray(cfg.output_scale or [1.0] * d, dtype=np.float64) * rng.standard_normal((8, c, d))
        feeds = {"x": x, "accel": accel}
        if inputs:
            feeds["physics"] = np.array([getattr(physics, name) for name in inputs], dtype=np.float64)
        whole = ort.InferenceSession(chunk_graph.SerializeToString(), providers=["CPUExecutionProvider"])
        (ref,) = whole.run(None, {i.name: feeds[i.name] for i in whole.get_inputs()})
        one = ort.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])
        names = [i.name for i in one.get_inputs()]
        state, chained = x, []
        for k in range(c):
            given = {**feeds, "x": state, "accel": np.ascontiguousarray(accel[:, k:k + 1])}
            (out,) = one.run(None, {name: given[name] for name in names})
            state = out[:, 0]
            chained.append(state)
    except Exception:  # the task's own code under the tracer, or a graph onnxruntime refuses: predict whole chunks
        return None
    got = np.stack(chained, axis=1)
    scale = max(float(np.abs(ref).max()), 1e-300)
    if not np.all(np.isfinite(got)) or float(np.abs(got - ref).max()) / scale > PARITY_TOLERANCE:
        return None
    return proto


def outputs_for_graph(model: TrainedModel, physics: Physics, inputs: list[str]) -> Any:
    """The ``outputs_for`` graph of ``model`` at ``physics`` (module docstring), with the same ``physics`` input
    as the dynamics graph, checked against the PyTorch ``outputs_for`` on fresh inputs like the dynamics graph.

    Raises:
        ValueError: naming the task: tracing failed, or the graph differs from PyTorch.
    """
    task = model.task_def.name
    s, d, c = model.state_layout.dim, model.accel_layout.dim, model.model.cfg.chunk
    vector = (torch.tensor([getattr(physics, name) for name in inputs], dtype=torch.float64),) if inputs else ()
    x, accel = torch.zeros(1, s, dtype=torch.float64), torch.zeros(1, c, d, dtype=torch.float64)
    try:
        proto = to_onnx(OutputsFor(model, physics, inputs), (x, accel, *vector),
                        ["x", "accel", *(["physics"] if inputs else [])], ["outputs"],
                        {"x": {0: "B"}, "accel": {0: "B"}, "outputs": {0: "B"}}, traced_loops(model.dynamics(physics)))
    except Exception as exc:  # whatever the task's own code raises under the tracer
        raise ValueError(f"the {task!r} task's outputs_for cannot be exported as an ONNX graph: tracing it failed "
                         f"with {type(exc).__name__}: {exc}") from exc
    proto = shared_constants(proto)
    _check_traced(model, physics, inputs, proto, "outputs_for")
    return proto


def _check_traced(model: TrainedModel, physics: Physics, inputs: list[str], proto: Any,
                  method: str = "step") -> None:
    """Refuse a dynamics graph (``method`` ``"step"``; ``"outputs_for"``: that graph) that differs from the PyTorch
    dynamics on fresh inputs (:data:`PARITY_TOLERANCE`): rows at rest and rows in motion, outputs up to the
    model's output scale (accelerations up to the stop's limit)."""
    import onnxruntime as ort

    cfg = model.model.cfg
    s, d = model.state_layout.dim, model.accel_layout.dim
    rng = np.random.default_rng(0)
    x = 0.1 * rng.standard_normal((8, s))
    x[:2] = 0.0  # at rest (a contact sticking, say) as well as moving
    dynamics = model.dynamics(physics)
    limit = getattr(dynamics, "stop_accel_limit", None) if method == "outputs_for" else None
    scale = np.asarray(limit or cfg.output_scale or [1.0] * d, dtype=np.float64)
    accel = scale * rng.standard_normal((8, cfg.chunk, d))
    feeds = {"x": x, "accel": accel}
    if inputs:
        feeds["physics"] = np.array([getattr(physics, name) for name in inputs], dtype=np.float64)
    session = ort.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])
    feeds = {i.name: feeds[i.name] for i in session.get_inputs()}  # a graph may not read every input
    (graph,) = session.run(None, feeds)
    with torch.no_grad():
        if method == "outputs_for":
            ref = dynamics.outputs_for(torch.from_numpy(x), torch.from_numpy(accel)).double().cpu().numpy()
        else:
            _, out = dynamics.step(dynamics.start(torch.from_numpy(x)), torch.from_numpy(accel), None)
            ref = out["states"].double().cpu().numpy()
    same = (graph == ref) | (np.isnan(graph) & np.isnan(ref))  # a NaN both give (e.g. sqrt of a negative) agrees
    diff = np.where(same, 0.0, np.abs(graph - ref))
    finite = np.abs(ref[np.isfinite(ref)])
    gap = float(np.nan_to_num(diff, nan=np.inf).max()) / max(float(finite.max()) if finite.size else 0.0, 1e-300)
    if not gap <= PARITY_TOLERANCE:
        what = "dynamics" if method == "step" else method
        raise ValueError(f"the {model.task_def.name!r} task's {what} traced into a graph that differs from PyTorch "
                         f"on inputs other than the traced ones (by {gap:.3g} of the states' magnitude): the step "
                         "has something the tracer cannot follow, such as a Python if on a tensor's value (write it "
                         "with torch.where) or a computation outside torch (NumPy, numba)")


def export_onnx(model: TrainedModel, out: str | Path, *, int8: bool = False, source: str | None = None,
                physics: Physics | None = None, check: Callable[[Path], None] | None = None) -> dict[str, Any]:
    """Write ``model``'s encoder, decoder step, dynamics, constraint, sealed contract and runner into ``out``.

    Args:
        model: a trained seq2seq model of any task whose dynamics trace into ONNX (torch code, data-dependent
            cases written with ``torch.where``).
        out: the output folder: new, empty, or a previous export, which is replaced whole
            (:func:`write_bundle`).
        int8: also write a dynamically quantised int8 decoder step.
        source: how the model was named (recorded in the contract).
        physics: the physics the contract records as the deployed model's default, a physics of the model's
            kind (default: the model's own, ``model.physics``); the runner may override the fields the
            dynamics graph reads (``OnnxStepper(..., physics={"mu": 0.8})``) within the ranges of their class
            (:func:`physics_ranges`).
        check: run on the new bundle in a folder beside ``out`` before it replaces ``out``
            (:func:`write_bundle`; ``seqmotion export-onnx``: the parity check).

    Returns:
        The contract written to ``contract.json``.

    Raises:
        ValueError: a model that is not a seq2seq ``TrainedModel``, physics of another kind, dynamics that
            do not trace into a graph that computes what they do (:func:`dynamics_graphs`), a contract the
            runner would refuse (e.g. a non-finite output scale), an output that is a file, not writable,
            or a folder that is not a previous export; a graph the runner would refuse
            (:func:`~seqmotion.deploy.bundle.check_graph`); what ``check`` raises (the old bundle is left as it was).
        OSError: writing failed (the previous bundle is left as it was).
    """
    import importlib.util

    if importlib.util.find_spec("onnx") is None or importlib.util.find_spec("onnxruntime") is None:
        raise ValueError("export-onnx needs the onnx and onnxruntime packages: pip install 'seqmotion[deploy]'")
    if not isinstance(model, TrainedModel):
        raise ValueError(f"export-onnx exports sequence-to-sequence motion models, not a {type(model).__name__}")
    if getattr(model, "is_quantized", False):
        raise ValueError("export the float model: its int8 copy runs on a PyTorch kernel; export_onnx(int8=True) "
                         "(--int8) writes an int8 decoder step for onnxruntime")
    bundle_target(out)  # before the work
    physics = model.resolve_physics(physics)
    dynamics = model.dynamics(physics)
    contract = stepper_contract(model, dynamics, physics)
    cfg = model.model.cfg
    layers, hidden, c, s, d = cfg.layers, cfg.hidden, cfg.chunk, model.state_layout.dim, model.accel_layout.dim
    graphs = {
        "encoder": encoder_graph(model),
        "decoder_step": to_onnx(
            DecoderStep(model, dynamics), (torch.zeros(layers, 1, hidden), torch.zeros(layers, 1, hidden),
                                           torch.zeros(1, c, s)),
            ["h", "c", "window"], ["h_out", "c_out", "accel"],
            {"h": {1: "B"}, "c": {1: "B"}, "window": {0: "B"}, "h_out": {1: "B"}, "c_out": {1: "B"},
             "accel": {0: "B"}}),
        "dynamics": dynamics_graph(model, physics, contract["dynamics"]["physics"]["inputs"]),
    }
    if contract["dynamics"]["closed_form"] is None:
        sample = sample_graph(model, physics, contract["dynamics"]["physics"]["inputs"], graphs["dynamics"])
        if sample is not None:
            graphs["dynamics_sample"] = sample
    if contract["stop"]["outputs"] == "outputs_for":
        graphs["outputs_for"] = outputs_for_graph(model, physics, contract["dynamics"]["physics"]["inputs"])
    if contract["constraint"]:
        graphs["violation"] = to_onnx(
            Violation(model), (torch.zeros(1, 3, s), torch.zeros(1, 2, d)), ["states", "accel"], ["violation"],
            {"states": {0: "B", 1: "N1"}, "accel": {0: "B", 1: "N"}, "violation": {0: "B", 1: "N"}})
    blobs = {key: proto.SerializeToString() for key, proto in graphs.items()}
    if int8:
        with tempfile.TemporaryDirectory(prefix="seqmotion-int8-") as scratch:  # quantize_dynamic works on files
            blobs["decoder_step_int8"] = quantized(graphs["decoder_step"], Path(scratch))
    files = {key: GRAPH_FILES[key] for key in ("encoder", "decoder_step", "dynamics")}
    files["violation"] = GRAPH_FILES["violation"] if contract["constraint"] else None
    if int8:
        files["decoder_step_int8"] = GRAPH_FILES["decoder_step_int8"]
    for key in ("outputs_for", "dynamics_sample"):
        if key in graphs:
            files[key] = GRAPH_FILES[key]
    vector_doc = {"physics": "(P,) float64: the values of dynamics.physics.inputs, in that order"} \
        if contract["dynamics"]["physics"]["inputs"] else {}
    contract = {
        **contract,
        "source": source,
        "opset": OPSET,
        "model": cfg.to_dict(),
        "files": files,
        "graphs": {
            "encoder": {
                "inputs": {"chunks": "(B, n, C*input_dim) float64: the motion (input_layout) padded to whole chunks "
                                     "by repeating its last sample, reshaped sample-major within each chunk"},
                "outputs": {"z": "(B, L*H) float32: the latent (the encoder's final cell states, layer-major)",
                            "x0": "(B, S) float64: the task's start state for the motion (state_layout)"},
            },
            "decoder_step": {
                "inputs": {"h": "(L, B, H) float32", "c": "(L, B, H) float32",
                           "window": "(B, C, S) float32: C states of state_layout in its units"},
                "outputs": {"h_out": "(L, B, H) float32", "c_out": "(L, B, H) float32",
                            "accel": "(B, C, d) float32: the next C outputs (accel_layout means)"},
            },
            "dynamics": {
                "inputs": {"x": "(B, S) float64: the state before the chunk (state_layout)",
                           "accel": "(B, C, d) float64: C outputs (accel_layout); fewer: pad with zeros and keep "
                                    "the first states (the dynamics are causal)", **vector_doc},
                "outputs": {"states": "(B, C, S) float64: the C states that follow x"},
            },
            **({"dynamics_sample": {
                "inputs": {"x": "(B, S) float64: the state before the sample (state_layout)",
                           "accel": "(B, 1, d) float64: one output (accel_layout)", **vector_doc},
                "outputs": {"states": "(B, 1, S) float64: the state that follows x (the dynamics graph's first "
                                      "state; C of them chained give its C states)"},
            }} if "dynamics_sample" in graphs else {}),
            **({"outputs_for": {
                "inputs": {"x": "(B, S) float64: the state before the chunk (state_layout)",
                           "accel": "(B, C, d) float64: accelerations of the velocity columns (their units per "
                                    "second); fewer: pad with zeros and keep the first outputs", **vector_doc},
                "outputs": {"outputs": "(B, C, d) float64: the outputs (accel_layout) that give those "
                                       "accelerations along the path from x"},
            }} if "outputs_for" in graphs else {}),
            "violation": None if not contract["constraint"] else {
                "inputs": {"states": "(B, N+1, S) float32", "accel": "(B, N, d) float32"},
                "outputs": {"violation": "(B, N) float32: >= 0, 0 where the constraint holds"},
            },
        },
        "runner": "python: sys.path.insert(0, OUT); from onnx_stepper import OnnxStepper; "
                  "gen = OnnxStepper(OUT, motion); u = gen.step(); u = gen.step(measured)  (numpy + onnxruntime)",
        RANGES: physics_ranges(type(physics).from_dict(contract["dynamics"]["physics"]["values"]),
                               contract["dynamics"]["physics"]["inputs"]),
    }
    if contract[RANGES] is None:
        warnings.warn(f"the rules of {type(physics).__name__} are not ranges and orderings of its fields: the bundle "
                      f"runs at the exported physics only ({physics.describe()}); export at another with "
                      "export_onnx(..., physics=...)", stacklevel=2)
    contract = seal(contract, blobs)
    check_contract(contract, f"the contract exported for {out}")  # what the runner would refuse is not written
    for key, data in blobs.items():
        check_graph(data, f"the {key} graph exported for {out} ({model.task_def.name!r} task)")
    here = Path(__file__).resolve().parent
    payload = {GRAPH_FILES[key]: data for key, data in blobs.items()}
    payload.update({name: (here / name).read_bytes() for name in RUNNER_FILES})
    payload["stepper.py"] = (here.parent / "core" / "stepper.py").read_bytes()
    payload[CONTRACT] = (json.dumps(contract, indent=2, sort_keys=True) + "\n").encode()
    write_bundle(out, payload, check)
    return contract


def example_inputs(model: TrainedModel, n: int = 2, seed: int = 0) -> np.ndarray:
    """The task's ``example_inputs(n, seed)`` (a plug-in's own code) as the ``(n, K, input_dim)`` float64 batch a
    parity check runs on.

    Raises:
        ValueError: naming the task and the shapes: not numbers, another shape or width, K < 2, NaN or inf.
    """
    task, width = model.task_def.name, model.model.cfg.encoder_input_dim
    where = f"the {task!r} task's example_inputs({n}, seed={seed})"
    try:
        batch = np.asarray(model.task_def.example_inputs(n, seed=seed), dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where} are not an array of numbers: {exc}") from None
    if batch.ndim != 3 or batch.shape[0] != n or batch.shape[2] != width or batch.shape[1] < 2:
        raise ValueError(f"{where} have shape {batch.shape}; the model reads ({n}, K >= 2, {width}) "
                         f"({', '.join(model.input_layout.names)})")
    if not np.all(np.isfinite(batch)):
        raise ValueError(f"{where} hold NaN or inf (first at {np.argwhere(~np.isfinite(batch))[0].tolist()})")
    return batch


# --- the physics' ranges --------------------------------------------------------------------------------------
# The standalone runner has no physics classes, so the contract carries what the task's class accepts as data: per
# field a lower and an upper bound, and orderings between fields (sliding: 0 < mu <= 1000, mu_dyn >= 0,
# mu_dyn <= mu). They are read off the class itself — the one definition — by bisection over the floats, and
# checked against it on sampled values; a class whose rules are not of this form records null (the bundle then
# runs at its own physics only) rather than ranges that would let through what the class refuses.

_FAR = sys.float_info.max
_SIGN = 1 << 63


def _key(value: float) -> int:
    """An integer that orders the floats as they compare, adjacent floats adjacent (IEEE 754 bits, sign folded)."""
    bits = int.from_bytes(np.float64(value).tobytes(), "little", signed=True)
    return bits if bits >= 0 else -(bits & (_SIGN - 1))


def _float(key: int) -> float:
    bits = key if key >= 0 else (-key) | _SIGN
    return float(np.frombuffer((bits & ((1 << 64) - 1)).to_bytes(8, "little"), dtype=np.float64)[0])


def _edge(accepts: Callable[[float], bool], start: float, toward: float) -> tuple[float, float] | None:
    """From ``start`` (accepted) toward ``toward`` (±the largest float): the last accepted float and the first
    refused one, adjacent; None where ``toward`` itself is accepted (no bound that way)."""
    if accepts(toward):
        return None
    good, bad = _key(start), _key(toward)
    while abs(bad - good) > 1:
        middle = (good + bad) // 2
        if accepts(_float(middle)):
            good = middle
        else:
            bad = middle
    return _float(good), _float(bad)


def _bound(edge: tuple[float, float], direction: int) -> dict[str, float]:
    """An edge as the bound a contract states, the shorter number of the two: ``at_most 1000.0`` rather than
    ``below 1000.0000000000001``, ``above 0.0`` rather than ``at_least 5e-324``."""
    last, first = edge
    if len(repr(first)) < len(repr(last)):
        return {"below" if direction > 0 else "above": first}
    return {"at_most" if direction > 0 else "at_least": last}


def physics_ranges(physics: Physics, inputs: list[str]) -> dict[str, Any] | None:
    """What ``physics``'s class accepts for the fields ``inputs`` (the others held at ``physics``'s values), as the
    contract's ``physics_ranges``: ``{"fields": {name: {bound: value}}, "order": [[a, b], ...]}`` (``a <= b``), or
    None when its rules are not of that form (:func:`~seqmotion.deploy.bundle.physics_violation` and the class
    disagree on a value)."""
    cls, base = type(physics), physics.to_dict()
    point = {name: base[name] for name in inputs}

    def accepts(values: dict[str, float]) -> bool:
        try:
            cls.from_dict({**base, **values})
        except (ValueError, TypeError, ArithmeticError):  # how a physics class refuses a value
            return False
        return True

    def edge(name: str, direction: int, at: dict[str, float]) -> tuple[float, float] | None:
        return _edge(lambda v: accepts({**at, name: v}), at[name], direction * _FAR)

    # orderings: a bound that is another field's value, and moves with it
    order: set[tuple[str, str]] = set()
    for name in inputs:
        for direction in (1, -1):
            found = edge(name, direction, point)
            for other in inputs:
                if other == name or found is None or found[0] != point[other]:
                    continue
                small, large = (name, other) if direction > 0 else (other, name)
                moved = _moved(edge, small, large, point)
                if moved is False:
                    return None  # the bound follows the other field, but not as small <= large
                if moved:
                    order.add((small, large))
    # each field's own bounds, with the fields it is ordered against moved out of the way
    fields: dict[str, dict[str, float]] = {}
    for name in inputs:
        for direction in (1, -1):
            at = dict(point)
            partners = [b if direction > 0 else a for a, b in order if (a if direction > 0 else b) == name]
            for other in partners:
                far = edge(other, direction, at)
                at[other] = far[0] if far is not None else direction * _FAR
            found = edge(name, direction, at)
            if found is not None and not any(found[0] == at[other] for other in partners):
                fields.setdefault(name, {}).update(_bound(found, direction))
    ranges = {"fields": fields, "order": [list(pair) for pair in sorted(order)]}
    return ranges if _agrees(ranges, accepts, point) else None


def _moved(edge: Callable, small: str, large: str, point: dict[str, float]) -> bool | None:
    """Whether ``small <= large`` is an ordering: ``large`` moved up (or ``small`` down) and the bound followed it
    exactly (True), stayed (None: an own bound that equals the other's value by chance), or moved elsewhere
    (False: a rule that is not an ordering)."""
    for mover, follower, direction in ((large, small, 1), (small, large, -1)):
        far = edge(mover, direction, point)
        target = (far[0] if far is not None else direction * _FAR)
        middle = _float((_key(point[mover]) + _key(target)) // 2)
        if middle == point[mover]:
            continue  # cannot move this one: try the other
        at = {**point, mover: middle}
        found = edge(follower, direction, at)
        if found is None or found[0] != middle:
            return None if found is not None and found[0] == point[mover] else False
        return True
    return None


def _agrees(ranges: dict[str, Any], accepts: Callable[[dict[str, float]], bool], point: dict[str, float]) -> bool:
    """Whether ``ranges`` and the class agree on values around every bound, ordering and default (sampled)."""
    candidates = {name: {value, 0.0, -1.0, 1.0, 1e-300, -1e300, 1e300} for name, value in point.items()}
    for name, bounds in ranges["fields"].items():
        for limit in bounds.values():
            candidates[name].update((limit, float(np.nextafter(limit, np.inf)), float(np.nextafter(limit, -np.inf)),
                                     2 * limit + 1, limit / 2 - 1))
    for small, large in ranges["order"]:
        for value in list(candidates[large]):
            candidates[small].update((value, float(np.nextafter(value, np.inf))))
        for value in list(candidates[small]):
            candidates[large].update((value, float(np.nextafter(value, -np.inf))))
    rng = np.random.default_rng(0)
    names = list(point)
    pools = {name: sorted(candidates[name]) for name in names}
    samples = [dict(point)] + [{name: float(rng.choice(pools[name])) for name in names} for _ in range(400)]
    samples += [{**point, name: value} for name in names for value in pools[name]]
    return all(accepts(values) == (physics_violation(ranges, values) is None) for values in samples)


def check_parity(model: TrainedModel, out: str | Path, inputs: np.ndarray, physics: Physics | None = None
                 ) -> dict[str, float]:
    """How far the exported bundle's ``generate`` is from PyTorch ``generate`` on ``inputs`` at ``physics``
    (default: the model's): the largest |difference| of the outputs (``accel``, in the accel layout's units) and
    of the states (``states``, the state layout's)."""
    from .onnx_stepper import OnnxModel

    physics = model.resolve_physics(physics)
    batch = np.asarray(inputs, dtype=np.float64)
    batch = batch[None] if batch.ndim == 2 else batch
    with torch.inference_mode():  # generate's rollout, as tensors (any task's result holds these)
        x = torch.from_numpy(batch)
        states, accel = model.decode_torch(model.encode_torch(x), model.start_state(x).double(), batch.shape[1],
                                           physics)
    onnx_model = OnnxModel(out)
    mine = onnx_model.generate(batch, physics={name: getattr(physics, name) for name in onnx_model.physics_inputs})
    return {"accel": float(np.max(np.abs(mine["accel"] - accel.cpu().numpy()))),
            "states": float(np.max(np.abs(mine["states"] - states.cpu().numpy())))}


__all__ = ["OPSET", "bundle_target", "check_parity", "dynamics_graph", "encoder_graph", "example_inputs", "export_onnx",
           "outputs_for_graph", "physics_ranges", "physics_read", "sample_graph", "shared_constants", "to_onnx",
           "write_bundle"]
