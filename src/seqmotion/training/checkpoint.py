"""Checkpoints: ``safetensors`` weights plus a JSON config, written atomically, loaded safely.

Nothing here unpickles: loading a model cannot run code. A model directory holds

* ``model.safetensors`` — the weights;
* ``config.json`` — ``{"format", "task", "model", ..., "weights_sha256", "config_sha256"}``. The
  weights' hash ties the config to its weights, so a half-copied or mixed-up directory is
  refused; the config's own hash (of its canonical JSON without ``config_sha256``) catches an
  edited or corrupted config. Both are required: a config without either is refused, so deleting
  a hash does not switch its check off. (The shipped models, written before the config hash
  existed, were re-sealed with it by :func:`write_model`, their weights unchanged.)

A training checkpoint adds ``optimizer.safetensors`` (Adam's moment tensors, flattened) and
``trainer_state.json`` (step, epoch, optimizer hyper-parameters).

**Every file seqmotion writes goes through this module** (:func:`atomic_path`,
:func:`atomic_write_bytes`, :func:`atomic_write_text`, :func:`atomic_write_json`): it is written
to a temporary name in the same directory, flushed to disk and renamed into place, so a
reader, or a process killed at any instant, sees the old file or the new one, never a part.
Directories are made whole the same way: a new model directory or training checkpoint is
written under a temporary name and renamed into place; in an existing model directory (a
training run's top level) the weights are replaced first and the config, which names the
weights' hash, last. A reader that meets the two in between (a run being trained) retries;
one killed in between leaves a run whose top-level model does not verify, and
:func:`resolve_model_dir` then serves the run's latest checkpoint (complete by construction)
until the next training of the run rewrites the top level.

A training holds :class:`RunLock` on its run directory while it writes there: a second
training into the same directory is refused (:class:`~seqmotion.errors.RunInUseError`), and
temporaries a killed run left behind are removed when the lock is taken.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import stat
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load as load_safetensors_bytes
from safetensors.torch import save as save_safetensors_bytes

from ..errors import CheckpointError, RunInUseError

try:  # POSIX advisory locks; elsewhere a run directory is not locked
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

FORMAT = "seqmotion/1"
WEIGHTS = "model.safetensors"
CONFIG = "config.json"
OPTIMIZER = "optimizer.safetensors"
TRAINER_STATE = "trainer_state.json"
LATEST = "latest"
LOCK = ".lock"
"""The lock file of a run directory (see :class:`RunLock`)."""
HASH_FIELDS = ("format", "weights_sha256", "config_sha256")
"""Keys :func:`write_model` adds to a config (a model's own ``config_json`` leaves them out)."""
MAX_CONFIG_BYTES = 16 * 2**20
"""A ``config.json`` larger than this is refused before it is parsed."""
TEMP_MARK = ".tmp-"
"""Temporary names are ``.<stem>.tmp-<pid>-<random><suffix>`` (a leading dot, so listings skip them)."""


# --- atomic writes ----------------------------------------------------------------------------


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


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        try:
            path.unlink()
        except FileNotFoundError:
            pass


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
        _remove(tmp)
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
            _remove(entry)


def _retire(target: Path, aside: Path) -> None:
    """Remove the set-aside old folder: renamed to a temporary name first, so that a kill during the removal
    leaves a temporary (removed by the next call), never a half-deleted folder under the aside name."""
    doomed = temp_sibling(target)
    try:
        os.replace(aside, doomed)
    except OSError:  # the new bundle is in place: removing the old one is best effort
        doomed = aside
    _remove(doomed)


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
            _retire(target, aside)  # killed after the new bundle was in place
        else:
            os.replace(aside, target)  # killed between the renames: the old bundle goes back first
    _remove_orphans(target)
    tmp = temp_sibling(target)
    tmp.mkdir(parents=True)
    try:
        for name, data in files.items():
            _write_durable(tmp / name, data)
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
        _remove(tmp)
        raise
    _fsync_dir(target.parent)
    if aside.exists():
        _retire(target, aside)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so readers see the old file or the new one, never a mix."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    """:func:`atomic_write_bytes` for UTF-8 text (reports, tables, cards)."""
    atomic_write_bytes(path, text.encode())


def atomic_write_json(path: str | Path, data: Any) -> None:
    atomic_write_bytes(path, (json.dumps(data, indent=2, sort_keys=True) + "\n").encode())


def save_figure(figure: Any, path: str | Path, **savefig: Any) -> Path:
    """Save a matplotlib figure to ``path`` atomically (matplotlib picks the format from the suffix)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        figure.savefig(tmp, **savefig)
    return path


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


def remove_stale_temporaries(directory: str | Path) -> list[Path]:
    """Remove temporaries (``.*.tmp-*``) that killed writers left in ``directory`` and its ``checkpoints/``.

    Only call this while holding the directory's :class:`RunLock` (no live writer then uses them).
    """
    removed = []
    for folder in (Path(directory), Path(directory) / "checkpoints"):
        if not folder.is_dir():
            continue
        for entry in folder.iterdir():
            if entry.name.startswith(".") and TEMP_MARK in entry.name:
                _remove(entry)
                removed.append(entry)
    return removed


def _check_lock_file(path: Path, info: os.stat_result) -> None:
    """CheckpointError unless ``info`` (``lstat``/``fstat`` of a run's lock ``path``) is a regular file with no
    other name."""
    if not stat.S_ISREG(info.st_mode):
        kind = ("a symlink" if stat.S_ISLNK(info.st_mode) else "a directory" if stat.S_ISDIR(info.st_mode)
                else "a FIFO" if stat.S_ISFIFO(info.st_mode) else "a special file")
        raise CheckpointError(
            f"{path} is not a regular file but {kind}; it is left as it is: remove it to train into this directory"
        )
    if info.st_nlink > 1:  # a hard link to another file: writing the pid would truncate that file
        raise CheckpointError(
            f"{path} is not a regular file of its own (it has {info.st_nlink} hard links); it is left as it is: "
            "remove it to train into this directory"
        )


class RunLock:
    """An exclusive lock on a run directory while a training writes there (``fcntl.flock`` on ``.lock``).

    Taking it fails at once with :class:`~seqmotion.errors.RunInUseError` when another process
    (or another training in this one) holds it. The lock lives as long as the open file: a
    killed process releases it. Taking it also removes the temporaries a killed writer left.

    The holder writes its pid into the lock file, so a ``.lock`` that is not a plain file of its
    own is refused (:class:`~seqmotion.errors.CheckpointError`) and left as it is: a symlink
    (writing would truncate its target), a hard link (the same), a FIFO or a directory.
    """

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        self._fd: int | None = None

    def acquire(self) -> RunLock:
        if self._fd is not None:
            return self
        self.directory.mkdir(parents=True, exist_ok=True)
        path = self.directory / LOCK
        try:
            _check_lock_file(path, path.lstat())  # without following a symlink
        except FileNotFoundError:
            pass  # the open creates it
        # O_NOFOLLOW: a symlink swapped in after the check is not followed either (ELOOP); O_NONBLOCK: a FIFO does
        # not block the open (the fstat below refuses it). Windows has neither: the lstat check above stands.
        flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
        flags |= getattr(os, "O_NONBLOCK", 0)
        try:
            fd = os.open(path, flags, 0o644)
        except OSError as exc:  # ELOOP (a symlink), EISDIR, ENXIO, EACCES, ...
            raise CheckpointError(f"cannot open the run lock {path}: {exc.strerror or exc}") from None
        try:
            _check_lock_file(path, os.fstat(fd))  # what was opened, whatever happened since the lstat
        except CheckpointError:
            os.close(fd)
            raise
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                try:
                    holder = os.read(fd, 64).decode(errors="replace").strip() or "unknown"
                finally:
                    os.close(fd)
                raise RunInUseError(
                    f"{self.directory} is being written by another training (process {holder}); wait for it to "
                    "finish, or train into another directory"
                ) from None
        # the lock file is never replaced (a lock is on its inode): the holder's pid is written in place
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        remove_stale_temporaries(self.directory)
        return self

    def release(self) -> None:
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            if fcntl is not None:
                fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)

    @property
    def held(self) -> bool:
        return self._fd is not None

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()

    def __del__(self) -> None:  # an abandoned lock must not outlive its owner
        self.release()


# --- model directories -----------------------------------------------------------------------


def canonical_json(data: Any) -> bytes:
    """The byte form a config's hash is taken of (sorted keys, no spaces)."""
    return json.dumps(data, sort_keys=True, separators=(",", ":")).encode()


def config_digest(config: dict) -> str:
    """SHA-256 of ``config``'s canonical JSON without its ``config_sha256``."""
    return hashlib.sha256(canonical_json({k: v for k, v in config.items() if k != "config_sha256"})).hexdigest()


def _tensors_bytes(tensors: dict[str, torch.Tensor]) -> bytes:
    return save_safetensors_bytes({k: v.detach().contiguous().cpu() for k, v in tensors.items()})


def seal_config(config: dict, weights: bytes) -> dict:
    """``config`` with the format, the hash of ``weights`` and its own hash (replacing any old ones)."""
    sealed = {k: v for k, v in config.items() if k not in HASH_FIELDS}
    sealed["format"] = FORMAT
    sealed["weights_sha256"] = hashlib.sha256(weights).hexdigest()
    sealed["config_sha256"] = config_digest(sealed)
    return sealed


def _write_durable(path: Path, data: bytes) -> None:
    """Write a file inside a temporary directory of :func:`atomic_path` (which flushes it to disk before
    renaming the directory whole)."""
    with open(path, "wb") as f:
        f.write(data)


def _json_bytes(data: Any) -> bytes:
    return (json.dumps(data, indent=2, sort_keys=True) + "\n").encode()


def write_model(directory: str | Path, state_dict: dict[str, torch.Tensor], config: dict) -> None:
    """Write ``model.safetensors`` and ``config.json`` (sealed with both hashes) into ``directory``.

    A new directory appears complete or not at all (written under a temporary name, renamed);
    in an existing one the weights are replaced first and the config last (see the module
    docstring for what readers see meanwhile).
    """
    directory = Path(directory)
    blob = _tensors_bytes(state_dict)
    config_bytes = _json_bytes(seal_config(config, blob))
    if not directory.exists():
        try:
            with atomic_path(directory, directory=True) as tmp:
                _write_durable(tmp / WEIGHTS, blob)
                _write_durable(tmp / CONFIG, config_bytes)
            return
        except ValueError:  # another writer made the directory meanwhile: fall through
            if not directory.is_dir():
                raise
    if not directory.is_dir():
        raise ValueError(f"cannot write a model into {directory}: it is not a directory")
    atomic_write_bytes(directory / WEIGHTS, blob)
    atomic_write_bytes(directory / CONFIG, config_bytes)  # last: it names the weights it belongs to


def read_config(directory: str | Path) -> dict:
    """Read and check a model directory's ``config.json``: a JSON object of this format that carries both hashes
    (``weights_sha256``, checked against the weights by the callers that read them, and ``config_sha256``, checked
    here).

    Raises:
        CheckpointError: missing, too large, not JSON, not an object, another format, a hash missing or
            malformed, or a config hash mismatch.
    """
    path = Path(directory) / CONFIG
    if not path.is_file():
        raise CheckpointError(f"no {CONFIG} in {directory}: not a seqmotion model directory")
    try:
        size = path.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise CheckpointError(f"{path} is {size} bytes, larger than any model config ({MAX_CONFIG_BYTES})")
        config = json.loads(path.read_bytes())
    except OSError as exc:
        raise CheckpointError(f"cannot read {path}: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise CheckpointError(f"{path} is not valid JSON (corrupt checkpoint?): {exc}") from None
    if not isinstance(config, dict):
        raise CheckpointError(f"{path} must hold a JSON object, got {type(config).__name__}: not a model config")
    if config.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a {FORMAT} config (format={config.get('format')!r})")
    for key in ("weights_sha256", "config_sha256"):
        # required, not merely checked when present: otherwise deleting a hash would switch its check off
        if key not in config:
            raise CheckpointError(f"{path} has no {key} (a {FORMAT} config carries both hashes): edited or corrupt")
        value = config[key]
        if not (isinstance(value, str) and len(value) == 64):
            raise CheckpointError(f"{path}: {key} must be a SHA-256 hex digest, got {value!r}")
    if config["config_sha256"] != config_digest(config):
        raise CheckpointError(f"{path} was modified or is corrupt (its contents do not match its config_sha256)")
    return config


def _read_consistent(directory: Path, attempts: int = 6) -> tuple[dict, bytes]:
    """Config and weights bytes that belong together. A training may be replacing both right now (the
    weights first, the config last): a mismatch is retried a few times before it is reported."""
    path = directory / WEIGHTS
    for attempt in range(attempts):
        config = read_config(directory)
        if not path.is_file():
            raise CheckpointError(f"no {WEIGHTS} in {directory}")
        try:
            blob = path.read_bytes()
        except OSError as exc:
            raise CheckpointError(f"cannot read {path}: {exc.strerror or exc}") from None
        if config["weights_sha256"] == hashlib.sha256(blob).hexdigest():
            return config, blob
        if attempt + 1 < attempts:
            time.sleep(0.01 * 2**attempt)
    raise CheckpointError(f"{path} does not match its config (hash mismatch: corrupt or mixed-up files)")


def model_is_complete(directory: str | Path) -> bool:
    """Whether ``directory`` holds a config and weights that verify together."""
    try:
        _read_consistent(Path(directory))
    except CheckpointError:
        return False
    return True


def tensor_shapes(blob: bytes, source: str = "weights") -> dict[str, tuple[int, ...]]:
    """Names and shapes of the tensors in a safetensors file's header, read without loading any tensor.

    Raises:
        CheckpointError: a malformed header.
    """
    if len(blob) < 8:
        raise CheckpointError(f"{source} is not a safetensors file ({len(blob)} bytes)")
    size = int.from_bytes(blob[:8], "little")
    if size > len(blob) - 8 or size > 100 * 2**20:
        raise CheckpointError(f"{source} is not a readable safetensors file (header of {size} bytes)")
    try:
        header = json.loads(blob[8 : 8 + size])
        return {k: tuple(int(n) for n in v["shape"]) for k, v in header.items() if k != "__metadata__"}
    except (ValueError, TypeError, KeyError, AttributeError, RecursionError) as exc:
        raise CheckpointError(f"{source} is not a readable safetensors file: bad header ({exc})") from None


def read_model(directory: str | Path, expected_task: str | None = None) -> tuple[dict, dict[str, torch.Tensor]]:
    """Load a model directory's config and weights, verifying they belong together.

    Raises:
        CheckpointError: missing files, corrupt weights or config, hash mismatch, or another task's model.
    """
    directory = Path(directory)
    config, blob = _read_consistent(directory)
    if expected_task is not None and config.get("task") != expected_task:
        raise CheckpointError(
            f"{directory} holds a model for task {config.get('task')!r}, not {expected_task!r}"
        )
    tensor_shapes(blob, str(directory / WEIGHTS))
    try:
        tensors = load_safetensors_bytes(blob)
    except Exception as exc:  # safetensors raises its own error types for malformed files
        raise CheckpointError(f"{directory / WEIGHTS} is not a readable safetensors file: {exc}") from None
    return config, tensors


def load_state_dict_strict(module: torch.nn.Module, tensors: dict[str, torch.Tensor], source: str) -> None:
    """``load_state_dict`` that reports missing/unexpected/mis-shaped/non-finite tensors, and tensors a module
    refuses (a ``ValueError`` of its own: a scale buffer that differs from the config, see
    :data:`~seqmotion.models.seq2seq.SCALE_BUFFERS`), as CheckpointError."""
    own = {k: tuple(v.shape) for k, v in module.state_dict().items()}
    check_shapes(own, {k: tuple(v.shape) for k, v in tensors.items()}, source)
    for name, tensor in tensors.items():
        if tensor.is_floating_point() and tensor.device.type != "meta" and not bool(torch.isfinite(tensor).all()):
            raise CheckpointError(f"weights in {source} are corrupt: {name} holds NaN or inf")
    try:
        module.load_state_dict(tensors)
    except CheckpointError:
        raise
    except ValueError as exc:
        raise CheckpointError(f"weights in {source} do not fit their config: {exc}") from None


def check_shapes(expected: dict[str, tuple[int, ...]], shapes: dict[str, tuple[int, ...]], source: str) -> None:
    """CheckpointError unless the weights' tensors (name → shape, e.g. from a safetensors header) are exactly
    those ``expected`` (e.g. :meth:`~seqmotion.models.seq2seq.Seq2SeqConfig.parameter_shapes`: compare
    before allocating a model a config describes)."""
    own = expected
    missing = sorted(set(own) - set(shapes))
    unexpected = sorted(set(shapes) - set(own))
    wrong = [k for k in own if k in shapes and tuple(own[k]) != tuple(shapes[k])]
    if missing or unexpected or wrong:
        details = [f"{k}: weights {tuple(shapes[k])}, config {tuple(own[k])}" for k in wrong[:3]]
        raise CheckpointError(
            f"weights in {source} do not fit the model described by its config: "
            f"missing={missing[:5]} unexpected={unexpected[:5]} wrong shape={wrong[:5]}"
            + (f" ({'; '.join(details)})" if details else "")
        )


# --- training checkpoints -------------------------------------------------------------------


def _flatten_optimizer(state: dict) -> tuple[dict[str, torch.Tensor], dict]:
    tensors, scalars = {}, {}
    for idx, slots in state["state"].items():
        for name, value in slots.items():
            if torch.is_tensor(value):
                tensors[f"state.{idx}.{name}"] = value
            else:
                scalars[f"{idx}.{name}"] = value
    return tensors, {"param_groups": state["param_groups"], "scalars": scalars}


def _unflatten_optimizer(tensors: dict[str, torch.Tensor], meta: dict) -> dict:
    state: dict[int, dict] = {}
    for key, value in tensors.items():
        _, idx, name = key.split(".", 2)
        state.setdefault(int(idx), {})[name] = value
    for key, value in meta.get("scalars", {}).items():
        idx, name = key.split(".", 1)
        state.setdefault(int(idx), {})[name] = value
    return {"state": state, "param_groups": meta["param_groups"]}


def write_training_checkpoint(
    run_dir: Path,
    name: str,
    model_state: dict[str, torch.Tensor],
    optimizer_state: dict,
    config: dict,
    trainer_state: dict,
    keep: int = 2,
) -> Path:
    """Write ``run_dir/checkpoints/<name>/`` atomically, point ``run_dir/latest`` at it, prune old ones.

    The checkpoint is written whole under a temporary name and renamed into place; ``latest`` is
    switched after it, and old checkpoints are removed after that, so at every instant
    ``latest`` names a complete checkpoint.
    """
    ckpt_root = Path(run_dir) / "checkpoints"
    ckpt_root.mkdir(parents=True, exist_ok=True)
    final = ckpt_root / name
    blob = _tensors_bytes(model_state)
    opt_tensors, opt_meta = _flatten_optimizer(optimizer_state)
    stale = None
    with atomic_path(final, directory=True) as tmp:
        _write_durable(tmp / WEIGHTS, blob)
        _write_durable(tmp / CONFIG, _json_bytes(seal_config(config, blob)))
        _write_durable(tmp / OPTIMIZER, _tensors_bytes(opt_tensors))
        _write_durable(tmp / TRAINER_STATE, _json_bytes({**trainer_state, "optimizer": opt_meta}))
        if final.exists():  # the same step written again: move the old one aside just before the new one goes in
            stale = temp_sibling(final)
            os.replace(final, stale)
    if stale is not None:
        shutil.rmtree(stale, ignore_errors=True)
    atomic_write_bytes(Path(run_dir) / LATEST, f"checkpoints/{name}\n".encode())
    for old in sorted(p for p in ckpt_root.iterdir() if p.is_dir() and not p.name.startswith("."))[:-keep]:
        if old != final:
            shutil.rmtree(old)
    return final


def latest_checkpoint(run_dir: str | Path) -> Path | None:
    """The checkpoint ``run_dir/latest`` points at (None: no checkpoint yet).

    Raises:
        CheckpointError: the pointer is unreadable or names something that is not a complete checkpoint.
    """
    pointer = Path(run_dir) / LATEST
    if not pointer.is_file():
        return None
    try:
        relative = pointer.read_text().strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise CheckpointError(f"{pointer} is unreadable: {exc}") from None
    if not relative.startswith("checkpoints/") or ".." in Path(relative).parts or "\x00" in relative:
        raise CheckpointError(f"{pointer} does not name a checkpoint of this run ({relative[:80]!r})")
    target = Path(run_dir) / relative
    if not (target / TRAINER_STATE).is_file():
        raise CheckpointError(f"{pointer} points at {target}, which is not a complete training checkpoint")
    return target


def forget_checkpoints(run_dir: str | Path) -> None:
    """Remove a run's training checkpoints (``latest`` first, so no reader follows it into a removed one)."""
    run_dir = Path(run_dir)
    try:
        (run_dir / LATEST).unlink()
    except FileNotFoundError:
        pass
    if (run_dir / "checkpoints").is_dir():
        shutil.rmtree(run_dir / "checkpoints")


def read_training_checkpoint(path: Path) -> tuple[dict, dict[str, torch.Tensor], dict, dict]:
    """Return ``(config, model_tensors, optimizer_state_dict, trainer_state)``."""
    config, tensors = read_model(path)
    try:
        trainer_state = json.loads((Path(path) / TRAINER_STATE).read_text())
        opt_tensors = load_safetensors_bytes((Path(path) / OPTIMIZER).read_bytes())
        optimizer_state = _unflatten_optimizer(opt_tensors, trainer_state.pop("optimizer"))
        if not isinstance(trainer_state.get("step"), int):
            raise ValueError(f"no step counter (step={trainer_state.get('step')!r})")
    except Exception as exc:
        raise CheckpointError(f"training state in {path} is unreadable: {exc}") from None
    return config, tensors, optimizer_state, trainer_state


def resolve_model_dir(path: str | Path) -> Path:
    """A directory holding a model: the path itself, or a training run's latest checkpoint.

    A run directory's own model (written at each checkpoint) is used when it verifies; when it
    does not — the run is being written right now, or a kill interrupted that write — the
    run's latest checkpoint is, which is always complete.
    """
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"{path} does not exist")
    if not path.is_dir():
        raise CheckpointError(f"{path} is a file, not a model directory or training run")
    has_model = (path / WEIGHTS).is_file() or (path / CONFIG).is_file()
    if not (path / LATEST).is_file():
        if has_model:
            return path
        raise CheckpointError(f"{path} holds neither a model ({WEIGHTS} + {CONFIG}) nor a training run")
    if has_model and model_is_complete(path):
        return path
    latest = latest_checkpoint(path)
    if latest is not None:
        return latest
    return path  # read_model says what is wrong
