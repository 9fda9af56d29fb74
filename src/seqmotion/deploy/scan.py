"""The sliding contact loop of an exported dynamics graph as an ONNX ``Scan``.

Traced, the contact model's per-sample loop would unroll into ~15 nodes per sample (1,500 for a chunk of 100), and
at a chunk boundary, where the stepper runs the graph once after many decoder calls, onnxruntime's cost is mostly
per node and per cold cache line. While tracing, the loop is one placeholder node instead
(:class:`~seqmotion.physics.sliding.ContactLoop`, domain ``seqmotion``); :func:`expand_contact_loops` replaces it by
a ``Scan`` whose body is :func:`~seqmotion.physics.sliding.contact_sample` — the function the eager loop calls per
sample — traced on its own. Body and loop are the same ops on the same values, so the graph computes what the
PyTorch loop does, bit for bit, with one ``Scan`` node and a ~15-node body in place of the unrolled chain.
"""

from __future__ import annotations

import io
import warnings
from typing import Any

import torch
from torch import nn

from ..physics.sliding import CONTACT_LOOP_DOMAIN, CONTACT_LOOP_OP, contact_sample

PREFIX = "contact_loop/"
"""The body's own namespace (every value, node and initializer name in it starts with this)."""


class ContactSample(nn.Module):
    """One sample of the contact loop, ``(v, −u_p, breakaway velocity (B, 2), μ' g (B, 1))`` →
    ``(v' (B, 2), moving (B, 1), w · v (B, 1))`` at the sampling period ``dt`` [s]."""

    def __init__(self, dt: float) -> None:
        super().__init__()
        self.dt = float(dt)

    def forward(self, v: torch.Tensor, neg_u: torch.Tensor, brk: torch.Tensor, decel: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return contact_sample(v, neg_u, brk, decel, self.dt)


def contact_body(dt: float, opset: int) -> Any:
    """:class:`ContactSample` at ``dt`` traced into an ONNX GraphProto (batch dimension ``B`` free), names
    prefixed by :data:`PREFIX`: inputs ``v``, ``neg_u``, ``brk``, ``decel``; outputs ``v_next``, ``moving``,
    ``turn``."""
    import onnx

    buffer = io.BytesIO()
    args = tuple(torch.zeros(1, n, dtype=torch.float64) for n in (2, 2, 2, 1))
    names = ["v", "neg_u", "brk", "decel"]
    with warnings.catch_warnings(), torch.inference_mode(False), torch.no_grad():
        warnings.simplefilter("ignore")
        torch.onnx.export(ContactSample(dt).eval(), args, buffer, dynamo=False, opset_version=opset,
                          input_names=names, output_names=["v_next", "moving", "turn"],
                          dynamic_axes={name: {0: "B"} for name in [*names, "v_next", "moving", "turn"]},
                          do_constant_folding=True)
    graph = onnx.load_from_string(buffer.getvalue()).graph

    def rename(value: str) -> str:
        return PREFIX + value if value else value

    for node in graph.node:
        node.name = rename(node.name)
        node.input[:] = [rename(v) for v in node.input]
        node.output[:] = [rename(v) for v in node.output]
    for collection in (graph.input, graph.output, graph.value_info):
        for value in collection:
            value.name = rename(value.name)
    for init in graph.initializer:
        init.name = rename(init.name)
    return graph


def expand_contact_loops(proto: Any, opset: int) -> Any:
    """A copy of ``proto`` with each contact-loop placeholder (:data:`~seqmotion.physics.sliding.CONTACT_LOOP_OP`,
    inputs ``v0 (B, 2)``, ``−u_p (B, C, 2)``, ``breakaway velocities (B, C, 2)``, ``μ' g (B, 1)``; attribute ``dt``)
    replaced by a ``Scan`` over the C samples with :func:`contact_body` as its body. μ' g is read from the outer
    graph (it is the same every sample); of the loop's outputs (velocities ``(B, C, 2)``, moving ``(B, C, 1)``,
    ``w · v`` ``(B, C, 1)``) only those the graph reads are collected; the velocities' last select (between the
    moving object's next velocity and the breakaway one, which the next sample does not need) is made once for all
    samples after the loop, on the per-sample values the Scan collects. A graph without placeholders is returned
    as it is."""
    import onnx
    from onnx import helper, numpy_helper

    if not any(n.op_type == CONTACT_LOOP_OP and n.domain == CONTACT_LOOP_DOMAIN for n in proto.graph.node):
        return proto
    model = onnx.ModelProto()
    model.CopyFrom(proto)
    graph = model.graph
    read = {name for node in graph.node for name in node.input} | {value.name for value in graph.output}
    nodes, stale = [], set()
    for index, node in enumerate(graph.node):
        if node.op_type != CONTACT_LOOP_OP or node.domain != CONTACT_LOOP_DOMAIN:
            nodes.append(node)
            continue
        stale.update(node.output)
        dt = float(numpy_helper.to_array(next(a.t for a in node.attribute if a.name == "dt")))  # float64
        v0, neg_u, breaks, decel = node.input
        body = contact_body(dt, opset)
        body_decel = PREFIX + "decel"
        # μ' g from the outer scope: the body reads the placeholder's input under its outer name
        for inner in body.node:
            inner.input[:] = [decel if name == body_decel else name for name in inner.input]
        kept_inputs = [value for value in body.input if value.name != body_decel]
        del body.input[:]
        body.input.extend(kept_inputs)
        outputs = {value.name: value for value in body.output}
        v_next = outputs[PREFIX + "v_next"]
        double = v_next.type.tensor_type.elem_type
        last = next(inner for inner in body.node if v_next.name in inner.output)
        collect: dict[str, str] = {}  # body value → the outer name its values over the samples take
        if last.op_type == "Where" and last.input[2] == PREFIX + "brk":
            # v' = Where(moving, w', brk) selects with nothing the next sample needs: collect its condition and w'
            # per sample and select once after the loop (the body keeps it for the carried state), rather than
            # copy v' through one more node per sample
            cond, chosen = last.input[0], last.input[1]
            outputs.setdefault(cond, helper.make_tensor_value_info(cond, onnx.TensorProto.BOOL, ["B", 1]))
            outputs.setdefault(chosen, helper.make_tensor_value_info(chosen, double, ["B", 2]))
            collect[chosen], collect[cond] = f"{PREFIX}chosen_{index}", f"{PREFIX}cond_{index}"
        else:  # the state carried to the next sample and, under another name, the velocity of every sample
            collected = helper.make_tensor_value_info(PREFIX + "v_collected", double, ["B", 2])
            body.node.append(helper.make_node("Identity", [v_next.name], [collected.name], name=PREFIX + "collect"))
            outputs[collected.name], collect[collected.name] = collected, node.output[0]
        for name, outer in zip(("moving", "turn"), node.output[1:], strict=True):
            if outer in read:
                collect[PREFIX + name] = outer
        del body.output[:]
        body.output.extend([v_next, *(outputs[name] for name in collect)])
        body.name = "contact_sample"
        nodes.append(helper.make_node(
            "Scan", [v0, neg_u, breaks], [f"{PREFIX}v_last_{index}", *collect.values()], name=f"contact_loop_{index}",
            body=body, num_scan_inputs=2, scan_input_axes=[1, 1], scan_output_axes=[1] * len(collect)))
        if node.output[0] not in collect.values():
            nodes.append(helper.make_node("Where", [collect[cond], collect[chosen], breaks], [node.output[0]],
                                          name=f"contact_select_{index}"))
    del graph.node[:]
    graph.node.extend(nodes)
    opsets = [entry for entry in model.opset_import if entry.domain != CONTACT_LOOP_DOMAIN]
    del model.opset_import[:]
    model.opset_import.extend(opsets)
    # the placeholder's outputs had only symbolic shapes; the Scan's are inferred from its body
    info = [value for value in graph.value_info if value.name not in stale]
    del graph.value_info[:]
    graph.value_info.extend(info)
    onnx.checker.check_model(model)
    return model


__all__ = ["ContactSample", "contact_body", "expand_contact_loops"]
