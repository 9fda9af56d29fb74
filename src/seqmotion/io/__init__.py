"""Files in one place: every file seqmotion writes (atomically), the trajectory files it reads, the JSON it reads.

This module holds the writers: bytes, text, JSON, arrays, figures, through one set of functions.
:mod:`.trajectories` reads and writes the trajectory files of the command lines (``.npz``, ``.csv``),
bounded and strict; :mod:`.jsonfile` is the one strict JSON reader. Their names are exported here too.

A file is written to a temporary name in its own directory, flushed to disk and renamed into
place, so a reader, or a process killed at any instant, sees the old file or the new one, never
a part (:func:`atomic_path` and the writers built on it). A directory is made whole the same way
(:func:`atomic_path` with ``directory=True``, :func:`replace_directory`). Temporaries are named
``.<stem>.tmp-<pid>-<random><suffix>``: a leading dot, so listings skip them, and the writer's
pid, so the next writer of the same path removes those a killed process left.

Outputs are checked before any work is done (:func:`check_writable`, :func:`check_writable_dir`),
so a long computation does not end in an unwritable path.

This is the library's lowest layer beside :mod:`seqmotion.errors`: it imports only the standard
library, NumPy and :mod:`seqmotion.errors` (matplotlib only inside :func:`pyplot`).
"""

from __future__ import annotations

import io
import json
import os
import shutil
import uuid
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

TEMP_MARK = ".tmp-"
"""Temporary names are ``.<stem>.tmp-<pid>-<random><suffix>`` (a leading dot, so listings skip them)."""


def temp_sibling(path: str | Path) -> Path:
    """A fresh temporary name beside ``path`` that keeps its suffix (matplotlib and imageio pick the
    format from it): ``dir/.<stem>.tmp-<pid>-<random><suffix>``."""
    path = Path(path)
    return path.with_name(f".{path.stem}{TEMP_MARK}{os.getpid()}-{uuid.uuid4().hex[:8]}{path.suffix}")


def _fsync_path(path: Path) -> None:
    """Flush a file (or a directory tree's files) to disk. A failure (EIO, a full disk) is an error: the
    write did not happen, and the old file stays."""
    if path.is_dir():
        for child in path.iterdir():
            _fsync_path(child)
        _fsync_dir(path)
        return
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(path: Path) -> None:
    """Flush a directory's entries (a rename) to disk; best effort (not every file system allows it)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def remove_path(path: str | Path) -> None:
    """Remove a file, a symlink or a directory tree; nothing there is not an error."""
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        try:
            path.unlink()
        except FileNotFoundError:
            pass


def write_durable(path: str | Path, data: bytes) -> None:
    """Write a file inside a temporary directory of :func:`atomic_path` (which flushes it to disk before it
    renames the directory whole); on its own this write is not atomic."""
    with open(path, "wb") as f:
        f.write(data)


@contextmanager
def atomic_path(path: str | Path, *, directory: bool = False) -> Iterator[Path]:
    """Write ``path`` atomically through a temporary path: ``with atomic_path(p) as tmp: fig.savefig(tmp)``.

    Yields a temporary path in ``path``'s directory (with ``path``'s suffix). When the block
    ends without an exception, the temporary is flushed to disk and renamed to ``path``
    (replacing a file there); when it raises, the temporary is removed and ``path`` is left as
    it was. Parent folders are created.

    Args:
        directory: the temporary is a directory (created for the block) that replaces ``path``,
            which must not exist or be an empty directory.

    Raises:
        ValueError: ``path`` is an existing directory (files), or a non-empty directory (directories).
    """
    path = Path(path)
    if not directory and path.is_dir():
        raise ValueError(f"cannot write {path}: it is a directory")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(path)
    if directory:
        tmp.mkdir()
    try:
        yield tmp
        if not tmp.exists():
            raise FileNotFoundError(f"nothing was written to the temporary {tmp} of {path}")
        _fsync_path(tmp)
        try:
            os.replace(tmp, path)
        except OSError as exc:
            if directory and path.is_dir() and any(path.iterdir()):
                raise ValueError(f"cannot write the directory {path}: it exists and is not empty") from None
            raise exc
    except BaseException:
        remove_path(tmp)
        raise
    _fsync_dir(path.parent)
    _remove_orphans(path)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, but not ours to signal
        return True
    return True


def _remove_orphans(path: Path) -> None:
    """Remove temporaries of ``path`` that killed writers left (their process is gone)."""
    prefix = f".{path.stem}{TEMP_MARK}"
    try:
        entries = [e for e in path.parent.iterdir() if e.name.startswith(prefix) and e.name.endswith(path.suffix)]
    except OSError:
        return
    for entry in entries:
        pid = entry.name[len(prefix) :].split("-", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not _pid_alive(int(pid)):
            remove_path(entry)


def _retire(target: Path, aside: Path) -> None:
    """Remove the set-aside old folder: renamed to a temporary name first, so that a kill during the removal
    leaves a temporary (removed by the next call), never a half-deleted folder under the aside name."""
    doomed = temp_sibling(target)
    try:
        os.replace(aside, doomed)
    except OSError:  # the new folder is in place: removing the old one is best effort
        doomed = aside
    remove_path(doomed)


def replace_directory(target: Path, files: dict[str, bytes], aside: Path) -> None:
    """Replace the folder ``target`` by one holding ``files`` (name → bytes), whole: a kill at any point leaves
    the old folder or the new one (between the two renames, the old one at ``aside``, which a reader may look
    for; the next call puts it back first). Whatever ``target`` held is removed: the caller checks it may be.

    Steps: (0) a kill of an earlier call is repaired (the old folder at ``aside`` goes back into place if
    ``target`` is missing, or is removed if ``target`` is the complete new one; temporaries are removed);
    (1) the files are written into a temporary sibling and flushed; (2) ``target`` is renamed to ``aside``;
    (3) the temporary is renamed to ``target``; (4) the old folder is removed. An exception in (1)-(3)
    restores the old folder.

    Raises:
        OSError: a write, flush or rename failed (the old folder is left as it was).
    """
    target = Path(target)
    if aside.is_dir():
        if target.exists():
            _retire(target, aside)  # killed after the new folder was in place
        else:
            os.replace(aside, target)  # killed between the renames: the old folder goes back first
    _remove_orphans(target)
    tmp = temp_sibling(target)
    tmp.mkdir(parents=True)
    try:
        for name, data in files.items():
            write_durable(tmp / name, data)
        _fsync_path(tmp)
        if target.exists():
            os.replace(target, aside)
        try:
            os.replace(tmp, target)
        except BaseException:
            if aside.exists() and not target.exists():
                os.replace(aside, target)
            raise
    except BaseException:
        remove_path(tmp)
        raise
    _fsync_dir(target.parent)
    if aside.exists():
        _retire(target, aside)


# --- the writers --------------------------------------------------------------------------------


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so readers see the old file or the new one, never a mix."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    """:func:`atomic_write_bytes` for UTF-8 text (reports, tables, cards)."""
    atomic_write_bytes(path, text.encode())


def json_bytes(data: Any) -> bytes:
    """The bytes every JSON file seqmotion writes holds: indented by 2, keys sorted, a final newline."""
    return (json.dumps(data, indent=2, sort_keys=True) + "\n").encode()


def atomic_write_json(path: str | Path, data: Any) -> None:
    """:func:`atomic_write_bytes` of :func:`json_bytes` (``ValueError`` for data JSON cannot hold, before
    anything is written)."""
    try:
        blob = json_bytes(data)
    except TypeError as exc:  # an object json does not know
        raise ValueError(f"cannot write {path} as JSON: {exc}") from None
    atomic_write_bytes(path, blob)


def atomic_write_npz(path: str | Path, arrays: Mapping[str, Any]) -> Path:
    """Write named arrays to the ``.npz`` ``path`` (``np.savez``, uncompressed) atomically; returns ``path``."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    atomic_write_bytes(path, buffer.getvalue())
    return Path(path)


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the file-only Agg backend (imported on first use: matplotlib is slow to
    import, and a figure is drawn by few commands)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(figure: Any, path: str | Path, *, close: bool = False, **savefig: Any) -> Path:
    """Save a matplotlib figure to ``path`` atomically, in the format of the path's suffix (``.png``,
    ``.pdf``, ``.svg``, ...); ``savefig`` as in ``Figure.savefig`` (``dpi=130``). ``close``: release a
    pyplot figure afterwards (``plt.close``), written or not.

    Raises:
        ValueError: ``path`` has no suffix (no format), or matplotlib cannot write that format.
    """
    path = Path(path)
    try:
        if not path.suffix:
            raise ValueError(f"cannot save a figure to {path}: the file name needs a suffix (.png, .pdf, .svg)")
        with atomic_path(path) as tmp:
            figure.savefig(tmp, **savefig)
    finally:
        if close:
            pyplot().close(figure)
    return path


# --- outputs checked before the work --------------------------------------------------------------


def check_writable(path: str | Path, suffixes: tuple[str, ...] | None = None, what: str = "output") -> Path:
    """Refuse, before any work, an output path that cannot be written (``ValueError`` naming it).

    Checks the suffix (if ``suffixes``), that ``path`` is not a directory, and that the nearest
    existing folder above it is a writable folder (by creating and removing a temporary file
    there: permissions, read-only file systems and a file in the way all show). Nothing is
    created.
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{what} {path} is a directory, not a file")
    if suffixes is not None and path.suffix.lower() not in suffixes:
        kind = path.suffix or "(none)"
        raise ValueError(f"{what} {path}: unsupported file type {kind!r} (use {', '.join(suffixes)})")
    return check_writable_dir(path.parent, what, path)


def check_writable_dir(directory: str | Path, what: str = "output directory", shown: str | Path | None = None) -> Path:
    """Refuse a folder that cannot be created or written into (``ValueError``); nothing is created."""
    directory = Path(directory) if str(directory) else Path(".")
    shown = directory if shown is None else shown
    existing = directory
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"cannot write {what} {shown}: {existing} is not a directory")
    probe = existing / f".seqmotion-write-test{TEMP_MARK}{os.getpid()}-{uuid.uuid4().hex[:8]}"
    try:
        with open(probe, "xb"):
            pass
    except OSError as exc:
        raise ValueError(f"cannot write {what} {shown}: {existing} is not writable ({exc.strerror})") from None
    finally:
        try:
            probe.unlink()
        except OSError:
            pass
    return Path(shown)


# The readers, beside the writers they use (imported last: they import the writers above).
from .jsonfile import MAX_JSON_BYTES, parse_json, read_json  # noqa: E402
from .trajectories import (  # noqa: E402
    MAX_FILE_BYTES,
    TRAJECTORY_SUFFIXES,
    check_declared_size,
    check_not_an_input,
    check_output,
    parse_csv,
    read_arrays,
    read_npz,
    read_trajectory,
    write_arrays,
)

__all__ = [
    "MAX_FILE_BYTES", "MAX_JSON_BYTES", "TEMP_MARK", "TRAJECTORY_SUFFIXES", "atomic_path", "atomic_write_bytes",
    "atomic_write_json", "atomic_write_npz", "atomic_write_text", "check_declared_size", "check_not_an_input",
    "check_output", "check_writable", "check_writable_dir", "json_bytes", "parse_csv", "parse_json", "pyplot",
    "read_arrays", "read_json", "read_npz", "read_trajectory", "remove_path", "replace_directory", "save_figure",
    "temp_sibling", "write_arrays", "write_durable",
]
