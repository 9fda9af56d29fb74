"""Trajectory files for the command lines: read ``.npz``/``.csv``, write them atomically with named columns.

Reading is strict: a file that is not what its suffix says (a truncated or empty zip, an
``.npy`` renamed ``.npz``, pickled objects, text in a data row) raises ``ValueError`` naming the
file and, for a CSV, the row and column; nothing is guessed. A CSV's first row is taken as a
header only when none of its fields is a number.

Reading is bounded: a file over :data:`MAX_FILE_BYTES`, an array whose ``.npy`` header declares
an axis over :data:`~seqmotion.errors.MAX_LENGTH` or more than :data:`MAX_FILE_BYTES` once read,
a CSV with more rows than that, are refused before they are read into memory. An output that is
the same file as an input is refused before any work (:func:`check_not_an_input`).
"""

from __future__ import annotations

import array
import io
import math
import os
import zipfile
import zlib
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import IO

import numpy as np

from ..errors import MAX_LENGTH
from . import atomic_write_bytes, atomic_write_npz, check_writable

TRAJECTORY_SUFFIXES = (".npz", ".csv")
"""File types :func:`read_trajectory` reads and :func:`write_arrays` writes."""
MAX_FILE_BYTES = 2**31
"""Input files larger than this (2 GiB) are refused before they are read, and so are arrays whose
declared shape would take more than this once read as float64 (an ``.npz`` member, an HDF5 dataset:
a small compressed file can declare a huge array)."""
MAX_CSV_LINE = 2**20
"""Characters in one CSV line (1 Mi): a row of samples is a few hundred, and a file without line
breaks must not be read into one string."""


def check_output(path: str | Path, what: str = "--output") -> Path:
    """Refuse, before any work, an output that :func:`write_arrays` could not write (suffix, folder)."""
    return check_writable(path, TRAJECTORY_SUFFIXES, what)


def check_not_an_input(
    output: str | Path | None, what: str, inputs: Mapping[str, str | Path | None]
) -> None:
    """Refuse, before any work, an output that is the same file as one of the ``inputs``.

    Writing the output replaces the file, so ``--output in.csv`` for ``--input in.csv`` would
    destroy the input (after the work, or half-way if it fails). The same file is found through
    links and ``..``: ``os.path.samefile`` when both exist, else equal real paths.

    Args:
        output: the output path (``None``: not given, nothing to check).
        what: the output's option name for the message (``--output``).
        inputs: option name → input path (``None`` entries are skipped).

    Raises:
        ValueError: naming both options and the path.
    """
    if output is None:
        return
    for name, source in inputs.items():
        if source is None:
            continue
        try:
            same = os.path.samefile(output, source)
        except OSError:  # one of them does not exist (yet): compare where they would be
            same = os.path.realpath(output) == os.path.realpath(source)
        if same:
            raise ValueError(f"{what} {output} is the same file as {name} {source}: writing it would destroy "
                             "the input; choose another output file")


def check_declared_size(shape: tuple[int, ...], itemsize: int, what: str) -> int:
    """Refuse an array by its declared shape, before it is read or allocated.

    Args:
        shape: the shape a file declares (an ``.npy`` header, an HDF5 dataset's ``.shape``).
        itemsize: bytes per element once read (8 for arrays converted to float64).
        what: names the array (and file) in the message.

    Returns:
        The array's size once read [bytes], for callers that bound a whole file.

    Raises:
        ValueError: an axis longer than :data:`~seqmotion.errors.MAX_LENGTH`, or more than
            :data:`MAX_FILE_BYTES` once read.
    """
    longest = max(shape, default=0)
    if longest > MAX_LENGTH:
        raise ValueError(f"{what} declares shape {tuple(shape)}: {longest} along an axis, more than the "
                         f"{MAX_LENGTH} samples a motion may have")
    size = math.prod(shape) * itemsize
    if size > MAX_FILE_BYTES:
        raise ValueError(f"{what} declares shape {tuple(shape)}: {size / 2**30:.1f} GiB once read, more than an "
                         f"input may take ({MAX_FILE_BYTES / 2**30:.0f} GiB)")
    return size


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def parse_csv(text: str | Iterable[str], source: str = "CSV", columns: Sequence[str] | None = None) -> np.ndarray:
    """``(rows, columns)`` float64 from comma-separated text (a string, or lines as they are read).

    Blank lines and lines starting with ``#`` are skipped; the first remaining row is a header
    if none of its fields is a number (``y,z,theta``); every other row must hold exactly as
    many numbers as the first data row.

    Args:
        columns: the names the columns must have (a task's layout, e.g. ``y, z, theta, v_y, v_z,
            v_theta``). A header is then matched to them by name, in any order, and the columns are
            returned in this order; a unit in brackets may follow a name (``y [m]``). Without a header
            the columns are taken to be in this order.

    Raises:
        ValueError: a field that is not a number (naming its line and column), rows of different
            widths, no data row, or more data rows than a motion may have (refused at the first row
            too many: lines are parsed as they come, the rest is never read); with ``columns``, a
            header name that is none of them, one given twice, or one of them missing.
    """
    lines = text.splitlines() if isinstance(text, str) else text
    order: list[int] | None = None  # the header's column of each of `columns`
    values = array.array("d")  # 8 bytes a number: a list of Python floats would take ~4 times that
    rows = 0
    width = None
    max_rows = MAX_LENGTH
    seen_first = False
    for number, line in enumerate(lines, start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        fields = [f.strip() for f in stripped.split(",")]
        if not seen_first:
            seen_first = True
            if not any(_is_number(f) for f in fields):
                if columns is not None:
                    order = header_order(fields, columns, f"{source}, line {number}")
                continue  # a header row: names only
        row = []
        for column, field in enumerate(fields, start=1):
            try:
                row.append(float(field))
            except ValueError:
                raise ValueError(
                    f"{source}, line {number}, column {column}: {field[:40]!r} is not a number"
                ) from None
        if width is None:
            width = len(row)
            max_rows = min(MAX_LENGTH, MAX_FILE_BYTES // (8 * width))
        elif len(row) != width:
            raise ValueError(f"{source}, line {number}: {len(row)} columns, but the first data row has {width}")
        if rows == max_rows:  # refused at the first row too many: the rest of the file is never read
            limit = (f"a motion has at most {MAX_LENGTH} samples" if max_rows == MAX_LENGTH
                     else f"{width} columns of them would take more than {MAX_FILE_BYTES / 2**30:.0f} GiB")
            raise ValueError(f"{source}, line {number}: more than {max_rows} data rows ({limit})")
        values.extend(row)
        rows += 1
    if not rows:
        raise ValueError(f"{source} holds no data rows")
    data = np.frombuffer(values, dtype=np.float64).reshape(rows, width)  # no copy: it keeps `values` alive
    if order is not None:
        if width != len(order):
            raise ValueError(f"{source}: the header names {len(order)} columns, the data rows hold {width}")
        data = data[:, order]
    return data


def header_order(names: Sequence[str], columns: Sequence[str], where: str) -> list[int]:
    """For each of ``columns``, the index of the header field ``names`` that names it. Case, spaces,
    underscores and θ for ``theta`` do not matter (``vy``, ``V_Y`` and ``v_y`` are one name), and a unit in
    brackets may follow a name (``y [m]``).

    Raises:
        ValueError: a name that is none of ``columns``, a name given twice, or one of ``columns`` missing.
    """
    def key(name: str) -> str:
        return name.split("[")[0].strip().lower().replace("θ", "theta").replace("_", "").replace(" ", "")

    given, wanted = [key(name) for name in names], [key(name) for name in columns]
    unknown = [name for name, k in zip(names, given, strict=True) if k not in wanted]
    if unknown:
        raise ValueError(f"{where}: header column {unknown[0].strip()!r} is not one of {', '.join(columns)} "
                         "(name the columns so, in any order, or leave the header out for that order)")
    twice = [name for name, k in zip(names, given, strict=True) if given.count(k) > 1]
    if twice:
        raise ValueError(f"{where}: header column {twice[0].strip()!r} appears more than once")
    missing = [name for name, k in zip(columns, wanted, strict=True) if k not in given]
    if missing:
        raise ValueError(f"{where}: the header has no column {missing[0]!r} (needs {', '.join(columns)})")
    return [given.index(k) for k in wanted]


def _csv_lines(path: Path) -> Iterator[str]:
    """The lines of a UTF-8 text file, read one at a time (none longer than :data:`MAX_CSV_LINE`)."""
    number = 0
    with path.open(encoding="utf-8-sig", newline=None) as stream:
        try:
            while line := stream.readline(MAX_CSV_LINE + 1):
                number += 1
                if len(line) > MAX_CSV_LINE:
                    raise ValueError(f"{path}, line {number}: longer than {MAX_CSV_LINE} characters "
                                     "(not a CSV of samples)")
                yield line
        except UnicodeDecodeError as exc:  # decoded in blocks: the bad bytes are at or just after this line
            raise ValueError(f"{path} is not a UTF-8 text file ({exc.reason} near line {number + 1})") from None


def _read_member(stream: IO[bytes], what: str, used: int) -> tuple[np.ndarray, int]:
    """One ``.npy`` member of an archive: its header checked, then its data read.

    Args:
        stream: the opened member.
        what: names the array in messages.
        used: bytes the archive's arrays read before this one take (as float64).

    Returns:
        ``(array, bytes it takes as float64)``.

    Raises:
        ValueError: not an ``.npy`` array, declared too large (:func:`check_declared_size`), or more
            than :data:`MAX_FILE_BYTES` together with the arrays read before it.
    """
    fmt = np.lib.format
    try:
        version = fmt.read_magic(stream)
    except ValueError:
        raise ValueError(f"{what} is not an .npy array") from None
    reader = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
    shape, _, dtype = reader(stream)  # the header only: nothing of the data is decompressed yet
    size = check_declared_size(shape, max(dtype.itemsize, 8), what)
    if used + size > MAX_FILE_BYTES:
        raise ValueError(f"{what} declares shape {tuple(shape)}: with the arrays before it, more than "
                         f"{MAX_FILE_BYTES / 2**30:.0f} GiB once read")
    stream.seek(0)
    return fmt.read_array(stream, allow_pickle=False), size


def read_npz(path: str | Path, keys: Sequence[str], required: int = 1) -> dict[str, np.ndarray]:
    """Arrays ``keys`` of an ``.npz`` (the first ``required`` of them must be there), read in full.

    Each array's ``.npy`` header is checked (:func:`check_declared_size`, and their sum) before
    its data is decompressed: a small archive can declare an array of any size.

    Raises:
        ValueError: not a zip archive (an ``.npy`` renamed, a truncated or empty file), a corrupt
            member, pickled objects, a member that is not an ``.npy`` array, an array declared too
            large, or a required array missing.
    """
    path = Path(path)
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path} is not an .npz archive (empty, truncated, or another format such as .npy)")
    arrays: dict[str, np.ndarray] = {}
    total = 0
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
            # np.load's names: "x" finds member "x.npy", and an exact member name wins
            members = {name.removesuffix(".npy"): name for name in names} | {name: name for name in names}
            for key in keys:
                if key not in members:
                    continue
                with archive.open(members[key]) as stream:
                    arrays[key], size = _read_member(stream, f"array {key!r}", total)
                total += size
    except ValueError as exc:  # e.g. pickled object arrays (allow_pickle=False), a header declaring too much
        raise ValueError(f"cannot read {path}: {exc}") from None
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error, KeyError, NotImplementedError, RuntimeError) as exc:
        raise ValueError(f"cannot read {path}: corrupt archive ({type(exc).__name__}: {exc})") from None
    missing = [k for k in keys[:required] if k not in arrays]
    if missing:
        raise ValueError(f"{path} has no array {missing[0]!r} (has {sorted({m.removesuffix('.npy') for m in names})})")
    return arrays


def read_trajectory(path: str | Path, key: str = "states", columns: Sequence[str] | None = None) -> np.ndarray:
    """Read ``(K, dim)`` samples from ``.npz`` (array ``key``) or ``.csv`` (one sample per row, an optional header).

    Raises:
        ValueError: a missing or unreadable file, no array ``key``, a malformed file (see the
            module docstring), an unsupported suffix, a file or array too large (checked before
            it is read).
    """
    return read_arrays(path, (key,), columns)[key]


def read_arrays(
    path: str | Path, keys: Sequence[str], columns: Sequence[str] | None = None
) -> dict[str, np.ndarray]:
    """Like :func:`read_trajectory` for several arrays of an ``.npz`` (the first required, the rest
    optional); a ``.csv`` gives the first (its header matched to ``columns`` by name, :func:`parse_csv`)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path} does not exist" if not path.exists() else f"{path} is not a file")
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise ValueError(f"{path} is {size / 2**30:.1f} GiB, larger than a trajectory file may be "
                         f"({MAX_FILE_BYTES / 2**30:.0f} GiB)")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        return read_npz(path, keys)
    if suffix == ".csv":
        try:
            return {keys[0]: parse_csv(_csv_lines(path), str(path), columns)}
        except OSError as exc:
            raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
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
    if path.suffix.lower() == ".npz":
        return atomic_write_npz(path, columns)
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
    buffer = io.BytesIO()
    np.savetxt(buffer, np.hstack(blocks), delimiter=",", header=",".join(header), comments="")
    atomic_write_bytes(path, buffer.getvalue())
    return path


__all__ = ["MAX_FILE_BYTES", "TRAJECTORY_SUFFIXES", "check_declared_size", "check_not_an_input", "check_output",
           "parse_csv", "read_arrays", "read_npz", "read_trajectory", "write_arrays"]
