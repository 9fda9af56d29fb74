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

Every file is written through :mod:`seqmotion.io` (atomically: a reader, or a process killed at any
instant, sees the old file or the new one, never a part). A new model directory or training checkpoint is
written whole under a temporary name and renamed into place; in an existing model directory (a
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
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load as load_safetensors_bytes
from safetensors.torch import save as save_safetensors_bytes

from ..errors import CheckpointError, RunInUseError
from ..io import (
    TEMP_MARK,
    atomic_path,
    atomic_write_bytes,
    json_bytes,
    parse_json,
    read_json,
    remove_path,
    temp_sibling,
    write_durable,
)

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
                remove_path(entry)
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


def write_model(directory: str | Path, state_dict: dict[str, torch.Tensor], config: dict) -> None:
    """Write ``model.safetensors`` and ``config.json`` (sealed with both hashes) into ``directory``.

    A new directory appears complete or not at all (written under a temporary name, renamed);
    in an existing one the weights are replaced first and the config last (see the module
    docstring for what readers see meanwhile).
    """
    directory = Path(directory)
    blob = _tensors_bytes(state_dict)
    config_bytes = json_bytes(seal_config(config, blob))
    if not directory.exists():
        try:
            with atomic_path(directory, directory=True) as tmp:
                write_durable(tmp / WEIGHTS, blob)
                write_durable(tmp / CONFIG, config_bytes)
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
    config = read_json(path, "model config", max_bytes=MAX_CONFIG_BYTES, error=CheckpointError)
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
        header = parse_json(blob[8 : 8 + size], "its header")
        return {k: tuple(int(n) for n in v["shape"]) for k, v in header.items() if k != "__metadata__"}
    except (ValueError, TypeError, KeyError, AttributeError) as exc:
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
        write_durable(tmp / WEIGHTS, blob)
        write_durable(tmp / CONFIG, json_bytes(seal_config(config, blob)))
        write_durable(tmp / OPTIMIZER, _tensors_bytes(opt_tensors))
        write_durable(tmp / TRAINER_STATE, json_bytes({**trainer_state, "optimizer": opt_meta}))
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
        trainer_state = read_json(Path(path) / TRAINER_STATE)
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
