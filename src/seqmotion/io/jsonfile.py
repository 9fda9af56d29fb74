"""The one strict JSON reader: every JSON file seqmotion reads goes through :func:`read_json`.

Strict means: a file over a size cap is refused before it is read; bytes that are not UTF-8 JSON are
refused; where a config or a record is expected, a top that is not a JSON object is refused; and so is
any number that is not finite — the constants ``NaN``, ``Infinity`` and ``-Infinity`` Python's ``json``
accepts, and numbers beyond float range (``1e999``, read as infinity) — named by where it sits
(``model.sigma_min``). Every refusal is a ``ValueError`` (or the caller's subclass of it) naming the file.

:mod:`seqmotion.deploy.bundle` keeps a standalone copy of the reading part (a bundle's runner reads its
``contract.json`` without seqmotion installed); its schema refuses every non-finite number by field.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

MAX_JSON_BYTES = 16 * 2**20
"""A JSON file larger than this (16 MiB) is refused before it is read, unless the caller names its own cap."""


def _first_non_finite(value: Any) -> tuple[str, float] | None:
    """Where the first number that is not finite sits in parsed JSON (``model.sigma_min``, ``ranges[2]``), and
    the number; None if every number is finite. Walked with a stack: nesting as deep as the parser allows."""
    stack: list[tuple[str, Any]] = [("", value)]
    while stack:
        where, item = stack.pop()
        if isinstance(item, float) and not math.isfinite(item):
            return where or "the top", item
        if isinstance(item, dict):
            stack.extend((f"{where}.{key}" if where else str(key), v) for key, v in reversed(item.items()))
        elif isinstance(item, list):
            stack.extend((f"{where}[{i}]", v) for i, v in reversed(list(enumerate(item))))
    return None


def parse_json(data: bytes | str, source: str, *, object_required: bool = True,
               error: type[ValueError] = ValueError) -> Any:
    """``data`` parsed as strict JSON (see the module docstring).

    Args:
        source: names the data in messages (a path, ``"config.json of <run>"``).
        object_required: the top must be a JSON object (a config, a record).
        error: the ``ValueError`` subclass to raise (e.g. :class:`~seqmotion.errors.CheckpointError`).

    Raises:
        error: not UTF-8 JSON, a non-finite number, nesting too deep, or (with ``object_required``) a top
            that is not an object.
    """
    try:
        value = json.loads(data)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise error(f"{source} is not valid JSON: {exc}") from None
    if object_required and not isinstance(value, dict):
        raise error(f"{source} must hold a JSON object, got {type(value).__name__}")
    found = _first_non_finite(value)
    if found is not None:
        raise error(f"{source}: {found[0]} is {found[1]}, not a finite number (NaN and Infinity are refused)")
    return value


_REQUIRED: Any = object()
"""The default of :func:`read_json`'s ``missing``: a missing file is an error."""


def read_json(path: str | Path, what: str | None = None, *, missing: Any = _REQUIRED, max_bytes: int = MAX_JSON_BYTES,
              object_required: bool = True, error: type[ValueError] = ValueError) -> Any:
    """The strict JSON (:func:`parse_json`) of the file ``path``.

    Args:
        what: how the caller calls the file (``"--metrics"``): it precedes the path in messages.
        missing: what to return when there is no file at ``path`` (for a file that is optional); without it,
            a missing file is an error. A file that is there but unreadable or not strict JSON is an error
            either way.
        max_bytes: files larger than this are refused before they are read.
        object_required: the top must be a JSON object.
        error: the ``ValueError`` subclass to raise.

    Raises:
        error: no file (unless ``missing`` is given), a file that cannot be read (naming the OS's reason),
            one too large, or not strict JSON.
    """
    path = Path(path)
    shown = str(path) if what is None else f"{what} {path}"
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise error(f"{shown} is {size} bytes, larger than this file may be ({max_bytes})")
        data = path.read_bytes()
    except FileNotFoundError:
        if missing is not _REQUIRED:
            return missing
        raise error(f"{shown} does not exist") from None
    except IsADirectoryError:
        raise error(f"{shown} is a directory, not a JSON file") from None
    except OSError as exc:
        raise error(f"cannot read {shown}: {exc.strerror or exc}") from None
    return parse_json(data, shown, object_required=object_required, error=error)


__all__ = ["MAX_JSON_BYTES", "parse_json", "read_json"]
