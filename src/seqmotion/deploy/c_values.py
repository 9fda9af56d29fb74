"""The C side of :mod:`.c_emit`, the ONNX-to-C emitter: tensor types and exact literals (:func:`literal`), the
buffers and the values that view them with offsets and strides (:class:`Buffer`, :class:`Val`), the index arithmetic
of broadcasting and collapsed loops (:func:`index`, :func:`broadcast_strides`, :func:`collapse`), and the static
arrays a generated file shares between its functions (:class:`Statics`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

F32, F64, I64, I32, BOOL = (np.dtype(t) for t in (np.float32, np.float64, np.int64, np.int32, np.bool_))
CTYPE = {F32: "float", F64: "double", I64: "int64_t", I32: "int32_t", BOOL: "unsigned char"}
"""The C type of each tensor type the emitter handles."""


def c_strides(shape: Sequence[int]) -> tuple[int, ...]:
    """Row-major strides (in elements) of ``shape``."""
    out, step = [], 1
    for n in reversed(shape):
        out.append(step)
        step *= int(n)
    return tuple(reversed(out))


def literal(value: Any, dtype: np.dtype) -> str:
    """``value`` as an exact C literal of ``dtype``."""
    if dtype == BOOL:
        return "1" if bool(value) else "0"
    if dtype in (I64, I32):
        v = int(value)
        return f"INT64_C({v})" if dtype == I64 else str(v)
    v = float(value)
    suffix = "f" if dtype == F32 else ""
    if math.isnan(v):
        return "NAN" if dtype == F32 else "(double)NAN"
    if math.isinf(v):
        text = "INFINITY" if dtype == F32 else "(double)INFINITY"
        return text if v > 0 else f"(-{text})"
    text = f"{np.float32(v).item():.9g}" if dtype == F32 else f"{v:.17g}"
    if "e" not in text and "." not in text and "n" not in text:
        text += ".0"
    return f"{text}{suffix}"


@dataclass(eq=False)
class Buffer:
    """An intermediate array of a function, placed in one of its static arrays by lifetime (:meth:`Emitter.place`)."""

    index: int
    dtype: np.dtype
    size: int
    first: int
    last: int

    @property
    def token(self) -> str:
        return f"@B{self.index}@"


@dataclass
class Val:
    """A tensor while a function is emitted: a constant (``const``), or elements of a C array ``base`` at ``offset``
    (a C expression; a loop's index inside a ``Scan``) with ``strides`` (in elements; 0 where broadcast)."""

    shape: tuple[int, ...]
    dtype: np.dtype
    const: np.ndarray | None = None
    base: str = ""
    offset: str = "0"
    strides: tuple[int, ...] = ()
    buffer: Buffer | None = None

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    def contiguous(self) -> bool:
        return all(s == c for n, s, c in zip(self.shape, self.strides, c_strides(self.shape), strict=True) if n != 1)

    def view(self, shape: Sequence[int], strides: Sequence[int], offset: int | str = 0) -> Val:
        return Val(tuple(int(n) for n in shape), self.dtype, None, self.base, add(self.offset, offset),
                   tuple(int(s) for s in strides), self.buffer)


def add(a: int | str, b: int | str) -> str:
    """The C expression ``a + b`` of two offsets, simplified where they are numbers."""
    a, b = str(a), str(b)
    if b == "0":
        return a
    if a == "0":
        return b
    if a.lstrip("-").isdigit() and b.lstrip("-").isdigit():
        return str(int(a) + int(b))
    return f"{a} + {b}"


def index(offset: str, strides: Sequence[int], variables: Sequence[str]) -> str:
    terms = [offset] if offset != "0" else []
    for s, v in zip(strides, variables, strict=True):
        if s == 1:
            terms.append(v)
        elif s != 0:
            terms.append(f"{v} * {s}")
    return " + ".join(terms) or "0"


def broadcast_strides(val: Val, shape: Sequence[int]) -> tuple[int, ...]:
    """``val``'s strides read along ``shape`` (NumPy broadcasting: missing leading axes and axes of 1 stride 0)."""
    lead = len(shape) - len(val.shape)
    if lead < 0:
        raise ValueError(f"cannot broadcast shape {val.shape} to {tuple(shape)}")
    out = [0] * lead
    for n, m, s in zip(val.shape, shape[lead:], val.strides, strict=True):
        out.append(0 if n == 1 and m != 1 else s)
    return tuple(out)


def collapse(shape: Sequence[int], strides: list[Sequence[int]]) -> tuple[list[int], list[list[int]]]:
    """Loops over ``shape`` for operands of ``strides``, with axes of 1 dropped and neighbouring axes that every
    operand walks as one merged: the fewest loops for the same elements in the same order."""
    dims: list[int] = []
    per: list[list[int]] = [[] for _ in strides]
    for axis in range(len(shape) - 1, -1, -1):
        n = int(shape[axis])
        if n == 1:
            continue
        if dims and all(st[axis] == p[0] * dims[0] for st, p in zip(strides, per, strict=True)):
            dims[0] *= n  # this axis continues the inner one for every operand: one loop, the inner stride
            continue
        dims.insert(0, n)
        for st, p in zip(strides, per, strict=True):
            p.insert(0, st[axis])
    return dims, per


@dataclass
class Statics:
    """The file's constant arrays, each written once (by dtype, shape and bytes)."""

    prefix: str
    lines: list[str] = field(default_factory=list)
    names: dict[tuple, str] = field(default_factory=dict)

    def array(self, value: np.ndarray) -> str:
        value = np.ascontiguousarray(value)
        dtype = value.dtype
        if dtype not in CTYPE:
            raise ValueError(f"a constant of type {dtype} (the C export handles {', '.join(map(str, CTYPE))})")
        key = (dtype.str, value.shape, value.tobytes())
        name = self.names.get(key)
        if name is None:
            name = self.names[key] = f"{self.prefix}_k{len(self.names)}"
            flat = value.reshape(-1)
            items = [literal(v, dtype) for v in flat.tolist()]
            rows = [", ".join(items[i:i + 8]) for i in range(0, len(items), 8)]
            body = ",\n    ".join(rows) if rows else "0"
            self.lines.append(f"static const {CTYPE[dtype]} {name}[{max(flat.size, 1)}] = {{\n    {body}\n}};")
        return name


__all__ = ["BOOL", "CTYPE", "F32", "F64", "I32", "I64", "Buffer", "Statics", "Val", "add", "broadcast_strides",
           "c_strides", "collapse", "index", "literal"]
