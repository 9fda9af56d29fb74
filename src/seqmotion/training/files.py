"""Trajectory files for the command lines: read ``.npz``/``.csv``, write them atomically with named columns."""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from .checkpoint import atomic_write_bytes


def read_trajectory(path: str | Path, key: str = "states") -> np.ndarray:
    """Read ``(K, dim)`` samples from ``.npz`` (array ``key``) or ``.csv`` (one sample per row, an optional header).

    Raises:
        ValueError: a missing or unreadable file, no array ``key``, an unsupported suffix.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path} does not exist")
    if path.suffix == ".npz":
        try:
            with np.load(path, allow_pickle=False) as data:
                if key not in data:
                    raise ValueError(f"{path} has no array {key!r} (has {sorted(data.files)})")
                return np.asarray(data[key])
        except (OSError, EOFError) as exc:
            raise ValueError(f"cannot read {path}: {exc}") from None
    if path.suffix == ".csv":
        try:
            return np.loadtxt(path, delimiter=",", ndmin=2)
        except ValueError:  # a header row
            try:
                return np.loadtxt(path, delimiter=",", ndmin=2, skiprows=1)
            except ValueError as exc:
                raise ValueError(f"cannot read {path} as numeric columns: {exc}") from None
    raise ValueError(f"unsupported trajectory file {path} (use .npz or .csv)")


def write_arrays(
    path: str | Path, columns: Mapping[str, np.ndarray], names: Mapping[str, Sequence[str]] | None = None
) -> Path:
    """Write named per-sample arrays to ``.npz``, or side by side to ``.csv`` (one row per sample), atomically.

    Args:
        columns: array name → ``(K, …)`` or ``(K-1, …)`` array (or anything else for ``.npz``).
        names: array name → one header name per column (e.g. the task's state names
            ``y, z, theta, …``); arrays without names get ``name0, name1, …``.

    In a CSV, arrays with one sample fewer (inputs ``u[0..K-2]``) get a NaN last row, and
    arrays that are not per-sample (a latent) are left out: use ``.npz`` to keep them.
    The file is written to a temporary name and renamed into place: a killed process
    leaves the old file or the new one, never a partial one.
    """
    path = Path(path)
    if path.suffix not in (".npz", ".csv"):
        raise ValueError(f"unsupported output {path} (use .npz or .csv)")
    path.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    if path.suffix == ".npz":
        np.savez(buffer, **columns)
        atomic_write_bytes(path, buffer.getvalue())
        return path
    names = names or {}
    rows = max(len(v) for v in columns.values() if np.ndim(v) >= 1)
    blocks, header = [], []
    for name, value in columns.items():
        value = np.asarray(value, dtype=np.float64)
        if value.ndim == 0 or len(value) not in (rows, rows - 1):
            continue
        value = value.reshape(len(value), -1)
        if len(value) == rows - 1:
            value = np.vstack([value, np.full((1, value.shape[1]), np.nan)])
        blocks.append(value)
        given = list(names.get(name, []))
        if len(given) == value.shape[1]:
            header += given
        else:
            header += [f"{name}{i}" if value.shape[1] > 1 else name for i in range(value.shape[1])]
    np.savetxt(buffer, np.hstack(blocks), delimiter=",", header=",".join(header), comments="")
    atomic_write_bytes(path, buffer.getvalue())
    return path
