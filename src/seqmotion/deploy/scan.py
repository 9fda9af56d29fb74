"""A dynamics' sequential per-sample loop in an exported graph as an ONNX ``Scan``.

Traced, a per-sample loop (the sliding contact model's, say) would unroll into a dozen nodes per sample (1,500 for a
chunk of 100), and at a chunk boundary, where the stepper runs the graph once after many decoder calls,
onnxruntime's cost is mostly per node and per cold cache line. So while tracing, such a loop is one placeholder node
(an ``autograd.Function`` whose ``symbolic`` emits it), and the dynamics name its placeholders in their
``traced_loops`` (:class:`TracedLoop`: the placeholder's op, the roles of its inputs and outputs, and the per-sample
step the eager loop calls). :func:`expand_loops` replaces each placeholder by a ``Scan`` whose body is that step
traced on its own. Body and loop are the same ops on the same values, so the graph computes what the PyTorch loop
does, bit for bit, with one ``Scan`` node and a small body in place of the unrolled chain.
"""

from __future__ import annotations

import io
import warnings
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import torch
from torch import nn


class TracedLoop(Protocol):
    """A loop placeholder a dynamics' step traces into, as :func:`expand_loops` reads it (class attributes).

    The placeholder node (op ``loop_op`` in domain ``loop_domain``) has inputs ``(state0 (B, n), *scanned (B, C, m),
    *constants (B, m))`` in that order, one float64 tensor attribute per name in ``loop_attributes``, and outputs
    ``(states (B, C, n), *per-sample outputs (B, C, m))``. ``loop_sample(state (B, n), *scanned rows (B, m),
    *constants, **attributes)`` is one sample: it returns the next state, then the per-sample outputs.

    Attributes:
        loop_op, loop_domain: the placeholder's op type and domain.
        loop_name: the namespace of the exported loop (``NAME_loop/`` prefixes its body, ``NAME_loop_i`` names the
            Scan, ``NAME_sample`` its body graph).
        loop_state: ``(name, width)`` of the carried state.
        loop_scanned: ``(name, width)`` of each input read one sample at a time (along axis 1).
        loop_constants: ``(name, width)`` of each input every sample reads whole.
        loop_outputs: the names of ``loop_sample``'s outputs: the next state's, then the per-sample outputs'.
        loop_attributes: the names of the placeholder's float attributes, passed to ``loop_sample`` by name.
    """

    loop_op: str
    loop_domain: str
    loop_name: str
    loop_state: tuple[str, int]
    loop_scanned: tuple[tuple[str, int], ...]
    loop_constants: tuple[tuple[str, int], ...]
    loop_outputs: tuple[str, ...]
    loop_attributes: tuple[str, ...]
    loop_sample: Callable[..., tuple[torch.Tensor, ...]]


def traced_loops(dynamics: object) -> tuple[TracedLoop, ...]:
    """The loop placeholders ``dynamics`` trace into (their ``traced_loops``; none for most dynamics)."""
    return tuple(getattr(dynamics, "traced_loops", ()))


def defined_loops() -> tuple[TracedLoop, ...]:
    """Every loop placeholder defined in this process: the ``torch.autograd.Function`` subclasses with a ``loop_op``
    (what :func:`~seqmotion.deploy.export.to_onnx` expands when it is not told the dynamics' own)."""
    found, todo = [], list(torch.autograd.Function.__subclasses__())
    while todo:
        cls = todo.pop()
        todo.extend(cls.__subclasses__())
        if isinstance(getattr(cls, "loop_op", None), str):
            found.append(cls)
    return tuple(sorted(set(found), key=lambda cls: (cls.__module__, cls.__qualname__)))


def prefixed(graph: Any, prefix: str) -> Any:
    """A copy of the ONNX GraphProto ``graph`` with every value, initializer and node name prefixed (a subgraph's
    own namespace)."""
    import onnx

    g = onnx.GraphProto()
    g.CopyFrom(graph)

    def name(value: str) -> str:
        return prefix + value if value else value

    for node in g.node:
        node.name = name(node.name)
        node.input[:] = [name(v) for v in node.input]
        node.output[:] = [name(v) for v in node.output]
    for collection in (g.input, g.output, g.value_info):
        for value in collection:
            value.name = name(value.name)
    for init in g.initializer:
        init.name = name(init.name)
    return g


class LoopSample(nn.Module):
    """One sample of ``loop`` (:class:`TracedLoop`) at the placeholder's ``attributes`` (float values by name)."""

    def __init__(self, loop: TracedLoop, attributes: dict[str, float]) -> None:
        super().__init__()
        self.loop, self.attributes = loop, dict(attributes)

    def forward(self, *args: torch.Tensor) -> tuple[torch.Tensor, ...]:
        return self.loop.loop_sample(*args, **self.attributes)


def loop_body(loop: TracedLoop, attributes: dict[str, float], opset: int) -> Any:
    """:class:`LoopSample` traced into an ONNX GraphProto (batch dimension ``B`` free), its names prefixed by
    ``NAME_loop/``: inputs the state's, scanned and constant names of ``loop``, outputs its ``loop_outputs``."""
    import onnx

    roles = [loop.loop_state, *loop.loop_scanned, *loop.loop_constants]
    names, outputs = [name for name, _ in roles], list(loop.loop_outputs)
    args = tuple(torch.zeros(1, width, dtype=torch.float64) for _, width in roles)
    buffer = io.BytesIO()
    with warnings.catch_warnings(), torch.inference_mode(False), torch.no_grad():
        warnings.simplefilter("ignore")
        torch.onnx.export(LoopSample(loop, attributes).eval(), args, buffer, dynamo=False, opset_version=opset,
                          input_names=names, output_names=outputs,
                          dynamic_axes={name: {0: "B"} for name in [*names, *outputs]}, do_constant_folding=True)
    return prefixed(onnx.load_from_string(buffer.getvalue()).graph, f"{loop.loop_name}_loop/")


def expand_loops(proto: Any, opset: int, loops: Sequence[TracedLoop]) -> Any:
    """A copy of the ONNX ModelProto ``proto`` with each placeholder of ``loops`` replaced by a ``Scan`` over the C
    samples with :func:`loop_body` as its body. The constant inputs are read from the outer graph (the same every
    sample); of the per-sample outputs only those the graph reads are collected. Where the body's next state is a
    last ``Where(cond, chosen, scanned input)`` — a select the next sample does not need, as the sliding contact's
    breakaway velocity is — ``cond`` and ``chosen`` are collected instead and the select made once for all samples
    after the loop. A graph without placeholders is returned as it is.

    Raises:
        ValueError: the graph holds a placeholder in a domain of ``loops`` that none of them names.
    """
    import onnx
    from onnx import helper, numpy_helper

    by_op = {(loop.loop_domain, loop.loop_op): loop for loop in loops}
    domains = {domain for domain, _ in by_op}
    placeholders = [node for node in proto.graph.node if node.domain in domains]
    if not placeholders:
        return proto
    unknown = sorted({f"{n.domain}::{n.op_type}" for n in placeholders if (n.domain, n.op_type) not in by_op})
    if unknown:
        raise ValueError(f"the traced graph holds loop placeholder(s) {unknown} that no traced loop names")
    model = onnx.ModelProto()
    model.CopyFrom(proto)
    graph = model.graph
    read = {name for node in graph.node for name in node.input} | {value.name for value in graph.output}
    nodes, stale = [], set()
    for index, node in enumerate(graph.node):
        loop = by_op.get((node.domain, node.op_type))
        if loop is None:
            nodes.append(node)
            continue
        stale.update(node.output)
        prefix, (state, _) = f"{loop.loop_name}_loop/", loop.loop_state
        given = {a.name: a for a in node.attribute}
        attributes = {name: float(numpy_helper.to_array(given[name].t)) for name in loop.loop_attributes}  # float64
        n_scanned = len(loop.loop_scanned)
        outer_scanned = list(node.input[1: 1 + n_scanned])
        body = loop_body(loop, attributes, opset)
        # the constants from the outer scope: the body reads each under the placeholder input's outer name
        constants = {prefix + name: outer for (name, _), outer in
                     zip(loop.loop_constants, node.input[1 + n_scanned:], strict=True)}
        for inner in body.node:
            inner.input[:] = [constants.get(name, name) for name in inner.input]
        kept_inputs = [value for value in body.input if value.name not in constants]
        del body.input[:]
        body.input.extend(kept_inputs)
        outputs = {value.name: value for value in body.output}
        infos = {value.name: value for value in body.value_info}
        state_next = outputs[prefix + loop.loop_outputs[0]]
        elem = state_next.type.tensor_type.elem_type
        last = next(inner for inner in body.node if state_next.name in inner.output)
        scanned_inner = {prefix + name: outer for (name, _), outer in zip(loop.loop_scanned, outer_scanned,
                                                                          strict=True)}
        collect: dict[str, str] = {}  # body value → the outer name its values over the samples take
        select_from = scanned_inner.get(last.input[2]) if last.op_type == "Where" else None
        if select_from is not None:
            # next = Where(cond, chosen, scanned) selects with nothing the next sample needs: collect cond and chosen
            # per sample and select once after the loop (the body keeps it for the carried state), rather than copy
            # the next state through one more node per sample
            cond, chosen = last.input[0], last.input[1]
            if cond not in outputs:
                outputs[cond] = infos.get(cond) or helper.make_tensor_value_info(cond, onnx.TensorProto.BOOL, None)
            if chosen not in outputs:
                outputs[chosen] = helper.make_tensor_value_info(chosen, elem, ["B", loop.loop_state[1]])
            collect[chosen], collect[cond] = f"{prefix}chosen_{index}", f"{prefix}cond_{index}"
        else:  # the state carried to the next sample and, under another name, the state of every sample
            collected = helper.make_tensor_value_info(f"{prefix}{state}_collected", elem, ["B", loop.loop_state[1]])
            body.node.append(helper.make_node("Identity", [state_next.name], [collected.name], name=prefix + "collect"))
            outputs[collected.name], collect[collected.name] = collected, node.output[0]
        for name, outer in zip(loop.loop_outputs[1:], node.output[1:], strict=True):
            if outer in read:
                collect[prefix + name] = outer
        del body.output[:]
        body.output.extend([state_next, *(outputs[name] for name in collect)])
        body.name = f"{loop.loop_name}_sample"
        nodes.append(helper.make_node(
            "Scan", [node.input[0], *outer_scanned], [f"{prefix}{state}_last_{index}", *collect.values()],
            name=f"{loop.loop_name}_loop_{index}", body=body, num_scan_inputs=n_scanned,
            scan_input_axes=[1] * n_scanned, scan_output_axes=[1] * len(collect)))
        if node.output[0] not in collect.values():
            nodes.append(helper.make_node("Where", [collect[cond], collect[chosen], select_from], [node.output[0]],
                                          name=f"{loop.loop_name}_select_{index}"))
    del graph.node[:]
    graph.node.extend(nodes)
    opsets = [entry for entry in model.opset_import if entry.domain not in domains]
    del model.opset_import[:]
    model.opset_import.extend(opsets)
    # the placeholders' outputs had only symbolic shapes; the Scans' are inferred from their bodies
    info = [value for value in graph.value_info if value.name not in stale]
    del graph.value_info[:]
    graph.value_info.extend(info)
    onnx.checker.check_model(model)
    return model


__all__ = ["LoopSample", "TracedLoop", "defined_loops", "expand_loops", "loop_body", "prefixed", "traced_loops"]
