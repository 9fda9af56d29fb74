"""An ONNX graph of fixed input shapes as one dependency-free C99 function: :class:`Emitter`, for
``seqmotion export-c`` (:mod:`seqmotion.deploy.c_export`).

The emitter takes an ONNX graph of fixed input shapes and writes one C function. What
depends only on constants and shapes (the tracer's shape arithmetic: ``Shape``, ``Gather`` of it, ``Concat``,
``Range``, ``ConstantOfShape``, …) is computed here, once, by onnxruntime on the graph, and the values that remain
are C loops: elementwise operations with broadcasting (:data:`UNARY`, :data:`BINARY`, ``Where``, ``Cast``,
``Max``/``Min``, ``Clip``), ``MatMul`` and ``Gemm`` (weights in the order the inner loop reads), ``LayerNormalization``,
reductions (:data:`REDUCTIONS`) and ``CumSum``; views without a copy (``Reshape``, ``Flatten``, ``Squeeze``,
``Unsqueeze``, ``Identity``, ``Slice``, ``Transpose``, ``Expand``, ``Split``, ``Gather`` of constant indices) as
offsets and strides into the buffer they read; ``Concat`` as copies; ``Scan`` as a loop with its body inside.
The intermediate buffers are static arrays shared by values whose lifetimes do not overlap. A product of which
the graph reads some columns only (the Gaussian head, whose means alone the decoder step returns) computes those
columns (:meth:`Emitter.prune`); a product sums over k in order, four k per pass over the outputs; a float
``Tanh`` is ``(1 − e)/(1 + e)`` with ``e = expf(−2|x|)`` (glibc's ``tanhf`` costs five ``expf``; the error is
below 1e-7 absolute). An op outside
:data:`OPS`, a shape that depends on the data, or a ``Scan`` that runs backwards is refused by name
(``ValueError``). Constants are written exactly (floats with 9 significant digits, doubles with 17).

Why not an existing ONNX-to-C generator: ``onnx2c`` (kraiskil) is a C++ tool built from
source (no package), with no ``Scan`` or ``CumSum`` node (the sliding dynamics); ``emx-onnx-cgen`` 1.4 (PyPI)
refuses the exported graphs as they are (shapes computed in the graph, a ``Scan`` over axis 1), and after folding
them and moving the scan axis it unrolls the sliding contact's ``Scan`` into 100 copies (2 MB of C), and its
pancake decoder step ran 41 µs per call at ``gcc -O2`` — slower than onnxruntime.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .c_values import (
    BOOL,
    CTYPE,
    F32,
    F64,
    Buffer,
    Statics,
    Val,
    add,
    broadcast_strides,
    c_strides,
    collapse,
    index,
    literal,
)

UNARY: dict[str, tuple[str, str]] = {  # op → (float form, double form), {x} the operand
    "Neg": ("(-{x})", "(-{x})"), "Abs": ("fabsf({x})", "fabs({x})"), "Sqrt": ("sqrtf({x})", "sqrt({x})"),
    "Exp": ("expf({x})", "exp({x})"), "Log": ("logf({x})", "log({x})"), "Sin": ("sinf({x})", "sin({x})"),
    "Cos": ("cosf({x})", "cos({x})"), "Tan": ("tanf({x})", "tan({x})"), "Atan": ("atanf({x})", "atan({x})"),
    "Asin": ("asinf({x})", "asin({x})"), "Acos": ("acosf({x})", "acos({x})"), "Sinh": ("sinhf({x})", "sinh({x})"),
    "Cosh": ("coshf({x})", "cosh({x})"), "Tanh": ("tanh_f({x})", "tanh({x})"), "Erf": ("erff({x})", "erf({x})"),
    "Floor": ("floorf({x})", "floor({x})"), "Ceil": ("ceilf({x})", "ceil({x})"),
    "Round": ("nearbyintf({x})", "nearbyint({x})"),
    "Reciprocal": ("(1.0f / {x})", "(1.0 / {x})"),
    "Sigmoid": ("(1.0f / (1.0f + expf(-{x})))", "(1.0 / (1.0 + exp(-{x})))"),
    "Relu": ("({x} < 0.0f ? 0.0f : {x})", "({x} < 0.0 ? 0.0 : {x})"),
    "Sign": ("(float)(({x} > 0.0f) - ({x} < 0.0f))", "(double)(({x} > 0.0) - ({x} < 0.0))"),
    "Softplus": ("log1pf(expf({x}))", "log1p(exp({x}))"),
}
BINARY = {"Add": "({x} + {y})", "Sub": "({x} - {y})", "Mul": "({x} * {y})", "Div": "({x} / {y})",
          "Equal": "({x} == {y})", "Greater": "({x} > {y})", "GreaterOrEqual": "({x} >= {y})", "Less": "({x} < {y})",
          "LessOrEqual": "({x} <= {y})", "And": "({x} && {y})", "Or": "({x} || {y})", "Xor": "(!{x} != !{y})"}
"""Elementwise binary ops (NumPy broadcasting) as C expressions."""
REDUCTIONS = ("ReduceSum", "ReduceMean", "ReduceMax", "ReduceMin", "ReduceL2", "ReduceSumSquare", "ReduceProd")
VIEWS = ("Reshape", "Flatten", "Squeeze", "Unsqueeze", "Identity", "Slice", "Transpose", "Expand", "Split", "Gather")
"""Ops that become offsets and strides into what they read (no code)."""
FOLDED = ("Constant", "Shape", "Size", "ConstantOfShape", "Range")
"""Ops whose outputs are constants here (computed at export); with an input that is not, the shape is the data's."""
OPS = frozenset({*UNARY, *BINARY, *REDUCTIONS, *VIEWS, *FOLDED, "Pow", "Max", "Min", "Clip", "Where", "Cast", "Not",
                 "MatMul", "Gemm", "LayerNormalization", "CumSum", "Concat", "Scan"})
"""Every op type the emitter compiles (the exported graphs' op set, and the elementwise ops near it)."""


def _attrs(node: Any) -> dict[str, Any]:
    from onnx import helper

    return {a.name: helper.get_attribute_value(a) for a in node.attribute}


def run_intermediates(graph_proto: Any, opset: Any, feeds: dict[str, np.ndarray],
                      extra_inputs: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Every value of ``graph_proto`` (its nodes' outputs) on ``feeds`` by onnxruntime, with ``extra_inputs``
    (names a body reads from the graph around it) fed as inputs: where constants are computed and shapes read."""
    import onnx
    import onnxruntime as ort
    from onnx import helper, shape_inference

    extra = extra_inputs or {}
    graph = onnx.GraphProto()
    graph.CopyFrom(graph_proto)
    for name, value in {**feeds, **extra}.items():
        info = helper.make_tensor_value_info(name, helper.np_dtype_to_tensor_dtype(value.dtype), list(value.shape))
        known = [v for v in graph.input if v.name == name]
        if known:
            known[0].CopyFrom(info)
        else:
            graph.input.append(info)
    del graph.value_info[:]
    model = helper.make_model(graph, opset_imports=list(opset))
    model.ir_version = min(model.ir_version, 10)
    inferred = shape_inference.infer_shapes(model)
    types = {v.name: v.type.tensor_type.elem_type for v in [*inferred.graph.value_info, *inferred.graph.output]}
    names = [o for node in graph.node for o in node.output if o]
    outputs = {v.name for v in graph.output}
    for name in names:
        if name not in outputs and types.get(name):
            graph.output.append(helper.make_tensor_value_info(name, types[name], None))
    model = helper.make_model(graph, opset_imports=list(opset))
    model.ir_version = min(model.ir_version, 10)
    options = ort.SessionOptions()
    options.log_severity_level = 4
    session = ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"])
    taken = {i.name for i in session.get_inputs()}
    given = {k: v for k, v in {**feeds, **extra}.items() if k in taken}
    out_names = [o.name for o in session.get_outputs()]
    return dict(zip(out_names, session.run(out_names, given), strict=True))


class Emitter:
    """One C function from an ONNX graph of fixed input shapes (module docstring).

    Args:
        statics: the file's constant arrays (shared by its functions).
        name: the C function's name.
        proto: the ONNX ModelProto.
        inputs: ``(graph input name, C parameter name, shape, dtype)`` for each parameter, in order; a graph input
            it does not name is not read.
        outputs: ``(graph output name, C parameter name)``, in order.
        sample: a value for each input (the constants and shapes are computed from a run on them).
    """

    def __init__(self, statics: Statics, name: str, proto: Any, inputs: Sequence[tuple[str, str, tuple, np.dtype]],
                 outputs: Sequence[tuple[str, str]], sample: dict[str, np.ndarray]) -> None:
        self.statics, self.name, self.proto = statics, name, proto
        self.inputs, self.outputs = list(inputs), list(outputs)
        self.sample = sample
        self.body: list[str] = []
        self.depth = 1
        self.step = 0
        self.buffers: list[Buffer] = []
        self.loop_vars = 0
        self.out_params = {graph: param for graph, param in outputs}

    # --- the function --------------------------------------------------------------------------------------

    def emit(self) -> tuple[str, str]:
        """The C function: its declaration (for the header) and its definition."""
        graph = self.proto.graph
        scope: dict[str, Val] = {}
        for init in graph.initializer:
            from onnx import numpy_helper

            scope[init.name] = self.constant(numpy_helper.to_array(init))
        declared = {v.name for v in graph.input}
        params, unused = [], []
        for graph_name, param, shape, dtype in self.inputs:
            if graph_name not in declared:  # an input the graph does not read (the physics of most dynamics)
                unused.append(f"    (void){param};")
            scope[graph_name] = Val(tuple(shape), dtype, None, param, "0", c_strides(shape))
            params.append(f"const {CTYPE[dtype]} *restrict {param}")
        values = run_intermediates(graph, self.proto.opset_import, self.sample)
        self.graph(graph, scope, values, self.proto.opset_import)
        self.step += 1
        for graph_name, param in self.outputs:
            val = scope[graph_name]
            if val.base != param:
                target = Val(val.shape, val.dtype, None, param, "0", c_strides(val.shape))
                self.copy(val, target)
            out_dtype = val.dtype
            params.append(f"{CTYPE[out_dtype]} *restrict {param}")
        declaration = f"void {self.name}({', '.join(params)})"
        arrays, code = self.place()
        return declaration + ";", "\n".join([declaration, "{", *arrays, *unused, *code, "}"])

    def place(self) -> tuple[list[str], list[str]]:
        """The static arrays the buffers share (intervals of use that do not overlap share one), and the code with
        each buffer's token replaced by its array's name."""
        slots: list[tuple[np.dtype, int, int]] = []  # dtype, size, busy until step
        where: dict[int, int] = {}
        for buf in sorted(self.buffers, key=lambda b: (b.first, b.index)):
            free = [i for i, (dtype, _, until) in enumerate(slots) if dtype == buf.dtype and until < buf.first]
            if free:
                fits = [i for i in free if slots[i][1] >= buf.size]
                i = min(fits, key=lambda i: slots[i][1]) if fits else max(free, key=lambda i: slots[i][1])
                slots[i] = (buf.dtype, max(slots[i][1], buf.size), buf.last)
            else:
                i = len(slots)
                slots.append((buf.dtype, buf.size, buf.last))
            where[buf.index] = i
        arrays = [f"    static {CTYPE[dtype]} s{i}[{max(size, 1)}];" for i, (dtype, size, _) in enumerate(slots)]
        code = "\n".join(self.body)
        for buf in self.buffers:
            code = code.replace(buf.token, f"s{where[buf.index]}")
        return arrays, code.split("\n") if code else []

    # --- values ------------------------------------------------------------------------------------------------

    def constant(self, value: np.ndarray) -> Val:
        value = np.asarray(value)
        return Val(tuple(int(n) for n in value.shape), value.dtype, value)

    def new(self, shape: Sequence[int], dtype: np.dtype, name: str | None = None) -> Val:
        """A new contiguous array of ``shape``: the output parameter where ``name`` is one, else a buffer."""
        shape = tuple(int(n) for n in shape)
        dtype = np.dtype(dtype)
        if dtype not in CTYPE:
            raise ValueError(f"{self.name}: a tensor of type {dtype} (the C export handles "
                             f"{', '.join(map(str, CTYPE))})")
        if name is not None and name in self.out_params and self.depth == 1:
            return Val(shape, dtype, None, self.out_params.pop(name), "0", c_strides(shape))
        buf = Buffer(len(self.buffers), dtype, int(np.prod(shape, dtype=np.int64)), self.step, self.step)
        self.buffers.append(buf)
        return Val(shape, dtype, None, buf.token, "0", c_strides(shape), buf)

    def read(self, val: Val) -> Val:
        """``val`` as an array to read (a constant becomes a static array); marks its buffer used now."""
        if val.const is not None:
            if val.const.dtype not in CTYPE:
                raise ValueError(f"{self.name}: a constant of type {val.const.dtype}")
            return Val(val.shape, val.dtype, None, self.statics.array(val.const), "0", c_strides(val.shape))
        if val.buffer is not None:
            val.buffer.last = max(val.buffer.last, self.step)
        return val

    def operand(self, val: Val, dtype: np.dtype | None = None) -> Val | str:
        """An elementwise operand: a literal for a constant of one element, else an array."""
        if val.const is not None and val.const.size == 1:
            return literal(val.const.reshape(()).item(), np.dtype(dtype or val.const.dtype))
        return self.read(val)

    def line(self, text: str) -> None:
        self.body.append("    " * self.depth + text)

    def loops(self, dims: Sequence[int], statement: Callable[[list[str]], list[str] | str]) -> None:
        """Nested loops over ``dims`` around ``statement(index variables)``."""
        names = []
        for n in dims:
            v = f"i{self.loop_vars}"
            self.loop_vars += 1
            names.append(v)
            self.line(f"for (int {v} = 0; {v} < {n}; ++{v}) {{")
            self.depth += 1
        body = statement(names)
        for text in [body] if isinstance(body, str) else body:
            self.line(text)
        for _ in dims:
            self.depth -= 1
            self.line("}")

    def elementwise(self, out: Val, operands: Sequence[Val | str], expression: Callable[..., str]) -> None:
        """``out[...] = expression(operand reads...)`` over ``out``'s shape with broadcasting."""
        arrays = [op for op in operands if isinstance(op, Val)]
        strides = [list(out.strides)] + [list(broadcast_strides(op, out.shape)) for op in arrays]
        dims, per = collapse(out.shape, strides)

        def statement(v: list[str]) -> str:
            reads, k = [], 1
            for op in operands:
                if isinstance(op, Val):
                    reads.append(f"{op.base}[{index(op.offset, per[k], v)}]")
                    k += 1
                else:
                    reads.append(op)
            return f"{out.base}[{index(out.offset, per[0], v)}] = {expression(*reads)};"
        if out.size:
            self.loops(dims, statement)

    def copy(self, src: Val, dst: Val) -> None:
        src = self.read(src)
        cast = "" if src.dtype == dst.dtype else f"({CTYPE[dst.dtype]})"
        self.elementwise(dst, [src], lambda x: f"{cast}{x}")

    def materialize(self, val: Val) -> Val:
        """``val`` as a contiguous array (a copy where it is a constant or a strided view)."""
        if val.const is not None:
            return self.read(val)
        if val.contiguous():
            return self.read(val)
        out = self.new(val.shape, val.dtype)
        self.copy(val, out)
        return out

    # --- graphs ------------------------------------------------------------------------------------------------

    def graph(self, graph: Any, scope: dict[str, Val], values: dict[str, np.ndarray], opset: Any) -> None:
        """Emit ``graph``'s nodes into ``scope`` (name → value); ``values``: every node output from a run (shapes,
        and the values of what is constant)."""
        pruned = self.prune(graph, scope, values)
        for node in graph.node:
            if node.domain not in ("", "ai.onnx"):
                raise ValueError(f"{self.name}: an op of domain {node.domain!r} ({node.op_type}) has no C form")
            if node.op_type not in OPS:
                raise ValueError(f"{self.name}: the op {node.op_type} (node {node.name!r}) has no C form in the "
                                 f"C export (it compiles {', '.join(sorted(OPS))})")
            if pruned.get(node.output[0], ("",))[0] == "skip":
                continue
            ins = [scope.get(name) if name else None for name in node.input]
            missing = [name for name, val in zip(node.input, ins, strict=True) if name and val is None]
            if missing:
                raise ValueError(f"{self.name}: node {node.name!r} reads {missing[0]!r}, which nothing computes")
            present = [v for v in ins if v is not None]
            if node.op_type in ("Shape", "Size") or (node.op_type != "Scan" and all(v.const is not None
                                                                                   for v in present)):
                for name in node.output:
                    if name:
                        scope[name] = self.constant(values[name])
                continue
            if node.op_type in FOLDED:
                raise ValueError(f"{self.name}: node {node.name!r} ({node.op_type}) makes a shape from the data; the C "
                                 "export needs shapes fixed at export")
            shapes = [values[name].shape if name in values else None for name in node.output]
            dtypes = [values[name].dtype if name in values else None for name in node.output]
            plan = pruned.get(node.output[0])
            if plan is None:
                outs = self.node(node, ins, shapes, dtypes, values, scope, opset)
            elif plan[0] == "product":  # only the columns the graph reads (module docstring)
                outs = [self.matmul(node.op_type, _attrs(node), ins, shapes[0], dtypes[0], node.output[0],
                                    columns=plan[1])]
            else:  # the reshape of those columns is the slice that read them
                outs = [ins[0].view(plan[1], c_strides(plan[1]))]
                scope[plan[2]] = outs[0]
            for name, val in zip(node.output, outs, strict=False):
                if name:
                    scope[name] = val
            if self.depth == 1:
                self.step += 1

    def prune(self, graph: Any, scope: dict[str, Val], values: dict[str, np.ndarray]) -> dict[str, tuple]:
        """Products of which the graph reads some columns only: a ``Gemm``/``MatMul`` of constant weights whose
        one reader is a ``Reshape`` that splits its last axis, read by one ``Slice`` of that axis with step 1 (a
        Gaussian head whose means alone are read, the decoder step's). Such a product computes only those
        columns. By a node's first output: the product's → ``("product", columns)``, the reshape's → ``("slice",
        shape, slice output name)``, the slice's → ``("skip",)`` (the reshape's view is its output)."""
        readers: dict[str, list[Any]] = {}
        known = {name: val.const for name, val in scope.items() if val.const is not None}
        for node in graph.node:  # what graph() will find constant (the same rule)
            for name in node.input:
                readers.setdefault(name, []).append(node)
            present = [name for name in node.input if name]
            if node.op_type in ("Shape", "Size") or (node.op_type != "Scan" and all(n in known for n in present)):
                known.update({name: values[name] for name in node.output if name in values})
        scope = {**scope, **{name: self.constant(value) for name, value in known.items() if name not in scope}}
        outputs = {v.name for v in graph.output}
        plans: dict[int, tuple] = {}
        for node in graph.node:
            if node.op_type not in ("Gemm", "MatMul") or node.output[0] in outputs:
                continue
            weight = scope.get(node.input[1])
            bias = scope.get(node.input[2]) if len(node.input) > 2 and node.input[2] else None
            if weight is None or weight.const is None or weight.const.ndim != 2 or len(readers.get(
                    node.output[0], [])) != 1 or (bias is not None and bias.const is None):
                continue
            trans_b = node.op_type == "Gemm" and _attrs(node).get("transB", 0)
            if node.op_type == "Gemm" and _attrs(node).get("transA", 0):
                continue
            reshape = readers[node.output[0]][0]
            product = values.get(node.output[0])
            if reshape.op_type != "Reshape" or reshape.output[0] in outputs or product is None \
                    or product.ndim != 2 or len(readers.get(reshape.output[0], [])) != 1 \
                    or weight.const.shape[0 if trans_b else 1] != product.shape[1]:
                continue
            cut = readers[reshape.output[0]][0]
            shaped, sliced = values.get(reshape.output[0]), values.get(cut.output[0])
            if cut.op_type != "Slice" or shaped is None or sliced is None or shaped.shape[0] != product.shape[0]:
                continue
            width = shaped.shape[-1]
            params = [scope.get(name) if name else None for name in cut.input[1:]]
            if any(v is None or v.const is None for v in params[:2]) or any(
                    v is not None and v.const is None for v in params[2:]):
                continue
            starts, ends = (np.asarray(v.const).reshape(-1) for v in params[:2])
            axes = np.asarray(params[2].const).reshape(-1) if len(params) > 2 and params[2] is not None \
                else np.arange(len(starts))
            steps = np.asarray(params[3].const).reshape(-1) if len(params) > 3 and params[3] is not None \
                else np.ones(len(starts), dtype=np.int64)
            if len(starts) != 1 or int(axes[0]) % shaped.ndim != shaped.ndim - 1 or int(steps[0]) != 1:
                continue
            lo, hi, _ = slice(int(max(min(starts[0], 2**62), -(2**62))), int(max(min(ends[0], 2**62), -(2**62))),
                              1).indices(width)
            if not 0 <= lo < hi <= width or hi - lo == width or sliced.shape[:-1] != shaped.shape[:-1]:
                continue
            rows = product.shape[1] // width
            columns = [i * width + j for i in range(rows) for j in range(lo, hi)]
            plans[node.output[0]] = ("product", columns)
            plans[reshape.output[0]] = ("slice", tuple(sliced.shape), cut.output[0])
            plans[cut.output[0]] = ("skip",)
        return plans

    def node(self, node: Any, ins: list[Val | None], shapes: list, dtypes: list, values: dict[str, np.ndarray],
             scope: dict[str, Val], opset: Any) -> list[Val]:
        op, attrs, name = node.op_type, _attrs(node), node.output[0]
        shape, dtype = shapes[0], dtypes[0]
        if op in UNARY or op in BINARY or op in ("Pow", "Where", "Cast", "Not", "Max", "Min", "Clip"):
            out = self.new(shape, dtype, name)
            self.elementwise_op(op, attrs, out, [v for v in ins], dtype)
            return [out]
        if op in VIEWS:
            return self.view_op(op, attrs, ins, shapes, node)
        if op == "Concat":
            out = self.new(shape, dtype, name)
            axis = attrs["axis"] % len(shape)
            start = 0
            for v in ins:
                part = out.view(v.shape, out.strides, start * out.strides[axis])
                self.copy(v, part)
                start += v.shape[axis]
            return [out]
        if op in ("MatMul", "Gemm"):
            return [self.matmul(op, attrs, ins, shape, dtype, name)]
        if op == "LayerNormalization":
            if len([o for o in node.output if o]) > 1:
                raise ValueError(f"{self.name}: LayerNormalization's mean and inverse deviation outputs have no C form")
            return [self.layer_norm(attrs, ins, shape, dtype, name)]
        if op in REDUCTIONS:
            return [self.reduce(op, attrs, ins, shape, dtype, name)]
        if op == "CumSum":
            return [self.cumsum(attrs, ins, dtype, name)]
        if op == "Scan":
            return self.scan(node, attrs, ins, shapes, dtypes, values, scope, opset)
        raise ValueError(f"{self.name}: the op {op} has no C form")  # pragma: no cover - OPS is checked first

    # --- elementwise -------------------------------------------------------------------------------------------

    def elementwise_op(self, op: str, attrs: dict, out: Val, ins: list[Val | None], dtype: np.dtype) -> None:
        float_type = dtype in (F32, F64)
        if op in UNARY:
            x = ins[0]
            if op == "Abs" and not float_type:
                self.elementwise(out, [self.operand(x)], lambda a: f"({a} < 0 ? -{a} : {a})")
                return
            if not float_type and op != "Neg":
                raise ValueError(f"{self.name}: {op} of {dtype} has no C form")
            form = UNARY[op][0 if dtype == F32 else 1] if float_type else UNARY[op][1]
            self.elementwise(out, [self.operand(x)], lambda a: form.format(x=a))
            return
        if op in BINARY:
            form = BINARY[op]
            self.elementwise(out, [self.operand(ins[0]), self.operand(ins[1])], lambda a, b: form.format(x=a, y=b))
            return
        if op == "Pow":
            if dtype not in (F32, F64):
                raise ValueError(f"{self.name}: Pow of {dtype} has no C form")
            fn = "powf" if dtype == F32 else "pow"
            base, exponent = self.operand(ins[0]), self.operand(ins[1], dtype)
            self.elementwise(out, [base, exponent], lambda a, b: f"{fn}({a}, {b})")
            return
        if op == "Where":
            self.elementwise(out, [self.operand(v) for v in ins], lambda c, a, b: f"({c} ? {a} : {b})")
            return
        if op == "Not":
            self.elementwise(out, [self.operand(ins[0])], lambda a: f"(!{a})")
            return
        if op == "Cast":
            target = CTYPE[dtype]
            if dtype == BOOL:
                self.elementwise(out, [self.operand(ins[0])], lambda a: f"({a} != 0)")
            else:  # C's conversion: to an integer it truncates toward zero, as onnxruntime's
                self.elementwise(out, [self.operand(ins[0])], lambda a: f"({target})({a})")
            return
        if op in ("Max", "Min"):  # NaN propagates, as in NumPy and PyTorch
            compare = ">" if op == "Max" else "<"
            operands = [self.operand(v) for v in ins if v is not None]

            def pick(*reads: str) -> str:
                expr = reads[0]
                for r in reads[1:]:
                    expr = f"(({expr}) != ({expr}) || ({expr}) {compare} {r} ? ({expr}) : {r})"
                return expr
            self.elementwise(out, operands, pick)
            return
        if op == "Clip":
            lo = ins[1] if len(ins) > 1 else None
            hi = ins[2] if len(ins) > 2 else None
            operands: list[Val | str] = [self.operand(ins[0])]
            if lo is not None:
                operands.append(self.operand(lo))
            if hi is not None:
                operands.append(self.operand(hi))

            def clip(*reads: str) -> str:
                expr, k = reads[0], 1
                if lo is not None:
                    expr, k = f"({expr} < {reads[k]} ? {reads[k]} : {expr})", k + 1
                if hi is not None:
                    expr = f"({expr} > {reads[k]} ? {reads[k]} : {expr})"
                return expr
            self.elementwise(out, operands, clip)
            return
        raise ValueError(f"{self.name}: the op {op} has no C form")  # pragma: no cover

    # --- views -------------------------------------------------------------------------------------------------

    def view_op(self, op: str, attrs: dict, ins: list[Val | None], shapes: list, node: Any) -> list[Val]:
        x = ins[0]
        if op in ("Reshape", "Flatten", "Squeeze", "Unsqueeze", "Identity"):
            shape = shapes[0]
            if op in ("Squeeze", "Unsqueeze", "Identity") or x.contiguous():
                if x.contiguous():
                    return [x.view(shape, c_strides(shape))]
                kept = [s for n, s in zip(x.shape, x.strides, strict=True) if n != 1]  # only axes of 1 come or go
                strides, it = [], iter(kept)
                for n in shape:
                    strides.append(next(it) if n != 1 else 0)
                return [x.view(shape, strides)]
            dense = self.materialize(x)
            return [dense.view(shape, c_strides(shape))]
        if op == "Transpose":
            perm = attrs.get("perm", list(range(len(x.shape)))[::-1])
            return [x.view([x.shape[p] for p in perm], [x.strides[p] for p in perm])]
        if op == "Expand":
            shape = shapes[0]
            return [x.view(shape, broadcast_strides(x, shape))]
        if op == "Slice":
            starts, ends = (self.const_of(v, node) for v in ins[1:3])
            axes = self.const_of(ins[3], node) if len(ins) > 3 and ins[3] is not None else range(len(starts))
            steps = self.const_of(ins[4], node) if len(ins) > 4 and ins[4] is not None else [1] * len(starts)
            shape, strides, offset = list(x.shape), list(x.strides), 0
            for start, end, axis, step in zip(starts, ends, axes, steps, strict=True):
                axis = int(axis) % len(shape)
                lo, hi, st = slice(int(max(min(start, 2**62), -(2**62))), int(max(min(end, 2**62), -(2**62))),
                                   int(step)).indices(shape[axis])
                offset += lo * strides[axis]
                shape[axis] = len(range(lo, hi, st))
                strides[axis] *= st
            if tuple(shape) != tuple(shapes[0]):
                raise ValueError(f"{self.name}: node {node.name!r} (Slice) gives {tuple(shapes[0])}, not {shape}")
            return [x.view(shape, strides, offset)]
        if op == "Split":
            axis = attrs.get("axis", 0) % len(x.shape)
            outs, start = [], 0
            for shape in shapes:
                strides = list(x.strides)
                outs.append(x.view(shape, strides, start * x.strides[axis]))
                start += shape[axis]
            return outs
        if op == "Gather":
            axis = attrs.get("axis", 0) % len(x.shape)
            indices = np.asarray(self.const_of(ins[1], node))
            idx = np.where(indices < 0, indices + x.shape[axis], indices).astype(np.int64)
            before, after = list(x.shape[:axis]), list(x.shape[axis + 1:])
            sb, sa = list(x.strides[:axis]), list(x.strides[axis + 1:])
            if idx.ndim == 0:
                return [x.view(before + after, sb + sa, int(idx) * x.strides[axis])]
            flat = idx.reshape(-1)
            step = int(flat[1] - flat[0]) if flat.size > 1 else 1
            if idx.ndim == 1 and np.array_equal(flat, flat[0] + step * np.arange(flat.size)):
                return [x.view(before + [flat.size] + after, sb + [step * x.strides[axis]] + sa,
                               int(flat[0]) * x.strides[axis])]
            out = self.new(shapes[0], x.dtype, node.output[0])
            k = 0
            for position in np.ndindex(*idx.shape):  # a copy per index
                src = x.view(before + after, sb + sa, int(idx[position]) * x.strides[axis])
                width = len(before)
                dst_strides = list(out.strides[:width]) + list(out.strides[width + idx.ndim:])
                dst_offset = sum(p * s for p, s in zip(position, out.strides[width:width + idx.ndim], strict=True))
                self.copy(src, out.view(before + after, dst_strides, dst_offset))
                k += 1
            return [out]
        raise ValueError(f"{self.name}: the op {op} has no C form")  # pragma: no cover

    def const_of(self, val: Val | None, node: Any) -> Any:
        if val is None or val.const is None:
            raise ValueError(f"{self.name}: node {node.name!r} ({node.op_type}) takes a shape or an index from the "
                             "data; the C export needs them fixed at export")
        return val.const.tolist()

    # --- linear algebra ----------------------------------------------------------------------------------------

    def matmul(self, op: str, attrs: dict, ins: list[Val | None], shape: tuple, dtype: np.dtype, name: str,
               columns: list[int] | None = None) -> Val:
        """``MatMul``/``Gemm``; with ``columns`` (constant weights, a 2-D product) only those columns, in order."""
        a, b = ins[0], ins[1]
        bias = ins[2] if len(ins) > 2 else None
        alpha, beta = float(attrs.get("alpha", 1.0)), float(attrs.get("beta", 1.0))
        if op == "Gemm":
            if attrs.get("transA", 0):
                a = a.view(a.shape[::-1], a.strides[::-1]) if a.const is None else self.constant(a.const.T)
            if attrs.get("transB", 0):
                b = self.constant(np.ascontiguousarray(b.const.T)) if b.const is not None else \
                    b.view(b.shape[::-1], b.strides[::-1])
        if columns is not None:  # (prune: constant weights, a constant bias of a value per column or one)
            b = self.constant(np.ascontiguousarray(b.const[..., columns]))
            shape = (*shape[:-1], len(columns))
            if bias is not None and bias.const is not None and bias.const.ndim and bias.const.shape[-1] > 1:
                bias = self.constant(np.ascontiguousarray(bias.const[..., columns]))
            name = ""
        squeeze_a, squeeze_b = len(a.shape) == 1, len(b.shape) == 1
        if squeeze_a:
            a = a.view((1, *a.shape), (0, *a.strides)) if a.const is None else self.constant(a.const[None])
        if squeeze_b:
            b = b.view((*b.shape, 1), (*b.strides, 0)) if b.const is None else self.constant(b.const[:, None])
        a, b = self.read(a), self.read(b)
        m, k, n = a.shape[-2], a.shape[-1], b.shape[-1]
        batch = tuple(np.broadcast_shapes(a.shape[:-2], b.shape[:-2]))
        full = (*batch, m, n)
        out = self.new(shape, dtype, name)
        out_full = out.view(full, c_strides(full))
        c_val = None
        if bias is not None and beta != 0.0:
            c_val = self.operand(bias)
        sa = broadcast_strides(a.view(a.shape[:-2], a.strides[:-2]), batch) if batch else ()
        sb = broadcast_strides(b.view(b.shape[:-2], b.strides[:-2]), batch) if batch else ()
        so = out_full.strides[:-2]
        t = CTYPE[dtype]
        mul_alpha = "" if alpha == 1.0 else f" * {literal(alpha, dtype)}"

        def statement(bv: list[str]) -> list[str]:
            oa, ob, oo = index(a.offset, sa, bv), index(b.offset, sb, bv), index(out_full.offset, so, bv)
            mv, kv, nv = (f"i{self.loop_vars}", f"i{self.loop_vars + 1}", f"i{self.loop_vars + 2}")
            self.loop_vars += 3
            a_m, a_k = a.strides[-2], a.strides[-1]
            b_k, b_n = b.strides[-2], b.strides[-1]
            o_m, o_n = out_full.strides[-2], out_full.strides[-1]
            row = f"{out.base} + {add(oo, f'{mv} * {o_m}')}"
            # each o_[m, n] a sequential dot product over k, four k at a time (o_ read and written once per four;
            # the same additions in the same order as one k at a time), the four rows of weights read once for
            # every m (a batch of two reads them once for both)
            quad = k - k % 4
            a_at = f"{a.base}[{add(oa, f'{mv} * {a_m} + ({kv} + {{j}}) * {a_k}')}]"
            w_at = f"{b.base} + {add(ob, f'({kv} + {{j}}) * {b_k}')}"
            lines = ["{",
                     f"    int {kv} = 0;",
                     f"    for (int {mv} = 0; {mv} < {m}; ++{mv})",
                     f"        for (int {nv} = 0; {nv} < {n}; ++{nv}) ({row})[{nv} * {o_n}] = 0;"]
            for count, stop, step in ((4, quad, 4), (1, k, 1)):
                if (count == 4 and not quad) or (count == 1 and quad == k):
                    continue
                update = f"o_[{nv} * {o_n}]"
                for j in range(count):
                    update = f"({update} + a{j}_ * w{j}_[{nv} * {b_n}])"
                lines += [f"    for (; {kv} < {stop}; {kv} += {step}) {{",
                          *(f"        const {t} *restrict w{j}_ = {w_at.format(j=j)};" for j in range(count)),
                          f"        for (int {mv} = 0; {mv} < {m}; ++{mv}) {{",
                          f"            {t} *restrict o_ = {row};",
                          *(f"            const {t} a{j}_ = {a_at.format(j=j)};" for j in range(count)),
                          f"            for (int {nv} = 0; {nv} < {n}; ++{nv}) o_[{nv} * {o_n}] = {update[1:-1]};",
                          "        }",
                          "    }"]
            return [*lines, "}"]
        self.loops([d for d in batch], statement)
        if mul_alpha or c_val is not None:
            operands: list[Val | str] = [out_full]
            if c_val is not None:
                operands.append(c_val)
            bias_term = "" if c_val is None else (" + {c}" if beta == 1.0 else f" + {{c}} * {literal(beta, dtype)}")

            def finish(o: str, c: str = "") -> str:
                return f"{o}{mul_alpha}{bias_term.format(c=c)}"
            self.elementwise(out_full, operands, finish)
        return out

    def layer_norm(self, attrs: dict, ins: list[Val | None], shape: tuple, dtype: np.dtype, name: str) -> Val:
        x = self.read(ins[0])
        axis = attrs.get("axis", -1) % len(x.shape)
        eps = float(attrs.get("epsilon", 1e-5))
        inner = int(np.prod(x.shape[axis:]))
        scale = self.operand(ins[1]) if ins[1] is not None else None
        bias = self.operand(ins[2]) if len(ins) > 2 and ins[2] is not None else None
        scale = self.materialize(scale) if isinstance(scale, Val) else scale
        bias = self.materialize(bias) if isinstance(bias, Val) else bias
        out = self.new(shape, dtype, name)
        xd = self.materialize(x)
        t = CTYPE[dtype]
        flat_x = f"{xd.base} + {add(xd.offset, '0')}"

        def term(v: Val | str | None, k: str) -> str:
            if v is None:
                return ""
            if isinstance(v, str):
                return v
            return f"{v.base}[{add(v.offset, k)}]"

        def statement(vs: list[str]) -> list[str]:
            r = vs[0] if vs else "0"
            kv = f"i{self.loop_vars}"
            self.loop_vars += 1
            row_x, row_o = f"(({flat_x}) + {r} * {inner})", f"({out.base} + {r} * {inner})"
            sc, bi = term(scale, kv), term(bias, kv)
            expr = f"({t})(((double){row_x}[{kv}] - mean_) * inv_)"
            if sc:
                expr = f"{expr} * {sc}"
            if bi:
                expr = f"{expr} + {bi}"
            return ["double mean_ = 0.0, var_ = 0.0, inv_;",
                    f"for (int {kv} = 0; {kv} < {inner}; ++{kv}) mean_ += {row_x}[{kv}];",
                    f"mean_ /= {inner};",
                    f"for (int {kv} = 0; {kv} < {inner}; ++{kv}) {{ const double d_ = {row_x}[{kv}] - mean_; "
                    "var_ += d_ * d_; }",
                    f"var_ /= {inner};",
                    f"inv_ = 1.0 / sqrt(var_ + {literal(eps, F64)});",
                    f"for (int {kv} = 0; {kv} < {inner}; ++{kv}) {row_o}[{kv}] = {expr};"]
        outer = int(np.prod(x.shape[:axis])) if axis else 1
        self.loops([outer], statement)
        return out

    # --- reductions --------------------------------------------------------------------------------------------

    def reduce(self, op: str, attrs: dict, ins: list[Val | None], shape: tuple, dtype: np.dtype, name: str) -> Val:
        x = self.read(ins[0])
        if len(ins) > 1 and ins[1] is not None:
            if ins[1].const is None:
                raise ValueError(f"{self.name}: {op} over axes computed from the data has no C form")
            axes = [int(a) for a in np.asarray(ins[1].const).reshape(-1)]
        else:
            axes = list(attrs.get("axes", []))
        if not axes:
            axes = [] if attrs.get("noop_with_empty_axes", 0) else list(range(len(x.shape)))
        axes = sorted({a % len(x.shape) for a in axes})
        kept = [a for a in range(len(x.shape)) if a not in axes]
        out = self.new(shape, dtype, name)
        t = "double" if dtype in (F32, F64) else CTYPE[dtype]
        init = {"ReduceMax": "-INFINITY", "ReduceMin": "INFINITY", "ReduceProd": "1"}.get(op, "0")
        update = {"ReduceMax": "if (v_ > acc_ || v_ != v_) acc_ = v_;",
                  "ReduceMin": "if (v_ < acc_ || v_ != v_) acc_ = v_;", "ReduceProd": "acc_ *= v_;",
                  "ReduceL2": "acc_ += v_ * v_;", "ReduceSumSquare": "acc_ += v_ * v_;"}.get(op, "acc_ += v_;")
        count = int(np.prod([x.shape[a] for a in axes])) if axes else 1
        final = {"ReduceMean": f"acc_ / {count}", "ReduceL2": "sqrt(acc_)"}.get(op, "acc_")
        kept_shape = [x.shape[a] for a in kept]
        out_kept = out.view(kept_shape, c_strides(kept_shape))
        cast = CTYPE[dtype]

        def statement(vs: list[str]) -> list[str]:
            base = index(x.offset, [x.strides[a] for a in kept], vs)
            rv = [f"i{self.loop_vars + i}" for i in range(len(axes))]
            self.loop_vars += len(axes)
            lines = [f"{t} acc_ = {init};"]
            for v, a in zip(rv, axes, strict=True):
                lines.append(f"for (int {v} = 0; {v} < {x.shape[a]}; ++{v}) " + "{")
            inner = index(base, [x.strides[a] for a in axes], rv)
            lines.append(f"    const {t} v_ = {x.base}[{inner}]; {update}")
            lines.extend("}" for _ in axes)
            lines.append(f"{out.base}[{index(out_kept.offset, out_kept.strides, vs)}] = ({cast})({final});")
            return lines
        self.loops(kept_shape, statement)
        return out

    def cumsum(self, attrs: dict, ins: list[Val | None], dtype: np.dtype, name: str) -> Val:
        x = self.read(ins[0])
        if ins[1].const is None:
            raise ValueError(f"{self.name}: CumSum along an axis computed from the data has no C form")
        axis = int(np.asarray(ins[1].const).reshape(())) % len(x.shape)
        exclusive, reverse = attrs.get("exclusive", 0), attrs.get("reverse", 0)
        out = self.new(x.shape, dtype, name)
        others = [a for a in range(len(x.shape)) if a != axis]
        t = CTYPE[dtype]

        def statement(vs: list[str]) -> list[str]:
            kv = f"i{self.loop_vars}"
            self.loop_vars += 1
            xi = index(x.offset, [x.strides[a] for a in others], vs)
            oi = index(out.offset, [out.strides[a] for a in others], vs)
            n = x.shape[axis]
            pos = f"({n - 1} - {kv})" if reverse else kv
            read = f"{x.base}[{add(xi, f'{pos} * {x.strides[axis]}')}]"
            write = f"{out.base}[{add(oi, f'{pos} * {out.strides[axis]}')}]"
            body = (f"{{ {write} = acc_; acc_ += {read}; }}" if exclusive else
                    f"{{ acc_ += {read}; {write} = acc_; }}")
            return [f"{t} acc_ = 0;", f"for (int {kv} = 0; {kv} < {n}; ++{kv}) {body}"]
        self.loops([x.shape[a] for a in others], statement)
        return out

    # --- Scan --------------------------------------------------------------------------------------------------

    def scan(self, node: Any, attrs: dict, ins: list[Val | None], shapes: list, dtypes: list,
             values: dict[str, np.ndarray], scope: dict[str, Val], opset: Any) -> list[Val]:
        body = attrs["body"]
        n_scan = int(attrs["num_scan_inputs"])
        n_state = len(ins) - n_scan
        in_axes = list(attrs.get("scan_input_axes", [0] * n_scan))
        out_axes = list(attrs.get("scan_output_axes", [0] * (len(node.output) - n_state)))
        if any(attrs.get("scan_input_directions", [])) or any(attrs.get("scan_output_directions", [])):
            raise ValueError(f"{self.name}: a Scan that runs backwards (node {node.name!r}) has no C form")
        scanned = [self.read(v) if v.const is None else self.read(self.constant(v.const)) for v in ins[n_state:]]
        axes = [a % len(v.shape) for a, v in zip(in_axes, scanned, strict=True)]
        steps = {v.shape[a] for v, a in zip(scanned, axes, strict=True)}
        if len(steps) != 1:
            raise ValueError(f"{self.name}: node {node.name!r} (Scan) scans inputs of different lengths {steps}")
        count = steps.pop()
        carries = []
        for v in ins[:n_state]:
            carry = self.new(v.shape, v.dtype)
            self.copy(v, carry)
            carries.append(carry)
        outputs = [self.new(shape, dtype) for shape, dtype in zip(shapes[n_state:], dtypes[n_state:], strict=True)]
        for val in [*carries, *outputs]:
            val.buffer.last = self.step
        # the body's values: one run on the first sample, the graph around it fed what it reads
        inner_names = {v.name for v in body.input} | {o for n in body.node for o in n.output} | \
            {i.name for i in body.initializer}
        outer_reads = sorted({i for n in body.node for i in n.input if i and i not in inner_names})
        feeds = {}
        for k, value in enumerate(body.input[:n_state]):
            feeds[value.name] = self.sample_value(ins[k], values, node.input[k])
        for k, a in enumerate(axes):
            whole = self.sample_value(ins[n_state + k], values, node.input[n_state + k])
            feeds[body.input[n_state + k].name] = np.take(whole, 0, axis=a)
        extra = {name: self.sample_value(scope[name], values, name) for name in outer_reads}
        inner_values = run_intermediates(body, opset, feeds, extra)
        it = f"t{self.loop_vars}"
        self.loop_vars += 1
        inner = dict(scope)
        from onnx import numpy_helper

        for init in body.initializer:
            inner[init.name] = self.constant(numpy_helper.to_array(init))
        for carry, value in zip(carries, body.input[:n_state], strict=True):
            inner[value.name] = carry
        for v, a, value in zip(scanned, axes, body.input[n_state:], strict=True):
            shape = v.shape[:a] + v.shape[a + 1:]
            strides = v.strides[:a] + v.strides[a + 1:]
            inner[value.name] = v.view(shape, strides, f"{it} * {v.strides[a]}")
        self.line(f"for (int {it} = 0; {it} < {count}; ++{it}) {{")
        self.depth += 1
        self.graph(body, inner, inner_values, opset)
        results = [inner[o.name] for o in body.output]
        # the next carried state: through a copy where it reads a carried array (a swap would read what it wrote)
        staged = []
        for carry, result in zip(carries, results[:n_state], strict=True):
            if result.buffer is not None and result.buffer in {c.buffer for c in carries} and not (
                    result.buffer is carry.buffer and result.offset == carry.offset
                    and result.strides == carry.strides):
                temp = self.new(result.shape, result.dtype)
                temp.buffer.first = temp.buffer.last = self.step
                self.copy(result, temp)
                staged.append((carry, temp))
            elif not (result.base == carry.base and result.offset == carry.offset and result.strides == carry.strides):
                staged.append((carry, result))
        for carry, result in staged:
            self.copy(result, carry)
        for out, result, axis in zip(outputs, results[n_state:], out_axes, strict=True):
            a = axis % len(out.shape)
            dst = out.view(out.shape[:a] + out.shape[a + 1:], out.strides[:a] + out.strides[a + 1:],
                           f"{it} * {out.strides[a]}")
            self.copy(result, dst)
        self.depth -= 1
        self.line("}")
        for buf in self.buffers:
            if buf.first == self.step:
                buf.last = max(buf.last, self.step)
        return [*carries, *outputs]

    def sample_value(self, val: Val, values: dict[str, np.ndarray], name: str) -> np.ndarray:
        if val.const is not None:
            return val.const
        if name in values:
            return values[name]
        if name in self.sample:
            return self.sample[name]
        raise ValueError(f"{self.name}: no value of {name!r} to size the Scan's body with")


__all__ = ["BINARY", "CTYPE", "Emitter", "OPS", "REDUCTIONS", "Statics", "UNARY", "VIEWS", "literal",
           "run_intermediates"]
