"""Trajectory files for the command lines: read ``.npz``/``.csv``, write them atomically with named columns.

Reading is strict: a file that is not what its suffix says (a truncated or empty zip, an
``.npy`` renamed ``.npz``, pickled objects, text in a data row) raises ``ValueError`` naming the
file and, for a CSV, the row and column; nothing is guessed. A CSV's first row is taken as a
header only when none of its fields is a number.
"""

from __future__ import annotations

import io
import zipfile
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from .checkpoint import atomic_write_bytes, check_writable

TRAJECTORY_SUFFIXES = (".npz", ".csv")
"""File types :func:`read_trajectory` reads and :func:`write_arrays` writes."""
MAX_FILE_BYTES = 2**31
"""Input files larger than this (2 GiB) are refused before they are read."""


def check_output(path: str | Path, what: str = "--output") -> Path:
    """Refuse, before any work, an output that :func:`write_arrays` could not write (suffix, folder)."""
    return check_writable(path, TRAJECTORY_SUFFIXES, what)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def parse_csv(text: str, source: str = "CSV") -> np.ndarray:
    """``(rows, columns)`` float64 from comma-separated text.

    Blank lines and lines starting with ``#`` are skipped; the first remaining row is a header
    if none of its fields is a number (``y,z,theta``); every other row must hold exactly as
    many numbers as the first data row.

    Raises:
        ValueError: a field that is not a number (naming its line and column), rows of different
            widths, or no data row.
    """
    rows: list[list[float]] = []
    width = None
    seen_first = False
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        fields = [f.strip() for f in stripped.split(",")]
        if not seen_first:
            seen_first = True
            if not any(_is_number(f) for f in fields):
                continue  # a header row: names only
        values = []
        for column, field in enumerate(fields, start=1):
            try:
                values.append(float(field))
            except ValueError:
                raise ValueError(
                    f"{source}, line {number}, column {column}: {field[:40]!r} is not a number"
                ) from None
        if width is None:
            width = len(values)
        elif len(values) != width:
            raise ValueError(f"{source}, line {number}: {len(values)} columns, but the first data row has {width}")
        rows.append(values)
    if not rows:
        raise ValueError(f"{source} holds no data rows")
    return np.asarray(rows, dtype=np.float64)


def read_npz(path: str | Path, keys: Sequence[str], required: int = 1) -> dict[str, np.ndarray]:
    """Arrays ``keys`` of an ``.npz`` (the first ``required`` of them must be there), read in full.

    Raises:
        ValueError: not a zip archive (an ``.npy`` renamed, a truncated or empty file), a corrupt
            member, pickled objects, or a required array missing.
    """
    path = Path(path)
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path} is not an .npz archive (empty, truncated, or another format such as .npy)")
    try:
        with np.load(path, allow_pickle=False) as data:
            files = list(data.files)
            arrays = {k: np.asarray(data[k]) for k in keys if k in files}
    except ValueError as exc:  # e.g. pickled object arrays (allow_pickle=False)
        raise ValueError(f"cannot read {path}: {exc}") from None
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error, KeyError, NotImplementedError, RuntimeError) as exc:
        raise ValueError(f"cannot read {path}: corrupt archive ({type(exc).__name__}: {exc})") from None
    missing = [k for k in keys[:required] if k not in arrays]
    if missing:
        raise ValueError(f"{path} has no array {missing[0]!r} (has {sorted(files)})")
    return arrays


def read_trajectory(path: str | Path, key: str = "states") -> np.ndarray:
    """Read ``(K, dim)`` samples from ``.npz`` (array ``key``) or ``.csv`` (one sample per row, an optional header).

    Raises:
        ValueError: a missing or unreadable file, no array ``key``, a malformed file (see the
            module docstring), an unsupported suffix.
    """
    return read_arrays(path, (key,))[key]


def read_arrays(path: str | Path, keys: Sequence[str]) -> dict[str, np.ndarray]:
    """Like :func:`read_trajectory` for several arrays of an ``.npz`` (the first required, the rest
    optional); a ``.csv`` gives the first."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path} does not exist" if not path.exists() else f"{path} is not a file")
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise ValueError(f"{path} is {size / 2**30:.1f} GiB, larger than a trajectory file may be (2 GiB)")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        return read_npz(path, keys)
    if suffix == ".csv":
        try:
            text = path.read_bytes().decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            raise ValueError(f"{path} is not a text file ({exc.reason} at byte {exc.start})") from None
        except OSError as exc:
            raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
        return {keys[0]: parse_csv(text, str(path))}
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
    if path.suffix.lower() not in TRAJECTORY_SUFFIXES:
        raise ValueError(f"unsupported output {path} (use .npz or .csv)")
    buffer = io.BytesIO()
    if path.suffix.lower() == ".npz":
        np.savez(buffer, **columns)
        atomic_write_bytes(path, buffer.getvalue())
        return path
    names = names or {}
    lengths = [len(v) for v in columns.values() if np.ndim(v) >= 1]
    if not lengths:
        raise ValueError(f"nothing per-sample to write to {path}")
    rows = max(lengths)
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


__all__ = ["TRAJECTORY_SUFFIXES", "check_output", "parse_csv", "read_arrays", "read_npz", "read_trajectory",
           "write_arrays"]
