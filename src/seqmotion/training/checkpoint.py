"""Checkpoints: ``safetensors`` weights plus a JSON config, written atomically, loaded safely.

Nothing here unpickles: loading a model cannot run code. A model directory holds

* ``model.safetensors`` — the weights;
* ``config.json`` — ``{"format", "task", "model", ..., "weights_sha256"}``; the hash ties the
  config to its weights, so a half-copied or mixed-up directory is refused.

A training checkpoint adds ``optimizer.safetensors`` (Adam's moment tensors, flattened) and
``trainer_state.json`` (step, epoch, optimizer hyper-parameters). Every file is written to a
temporary name, flushed to disk and renamed into place; checkpoint directories are renamed
into place whole, and a run's ``latest`` pointer is switched last.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import torch
from safetensors.torch import load as load_safetensors_bytes
from safetensors.torch import save as save_safetensors_bytes

from ..errors import CheckpointError

FORMAT = "seqmotion/1"
WEIGHTS = "model.safetensors"
CONFIG = "config.json"
OPTIMIZER = "optimizer.safetensors"
TRAINER_STATE = "trainer_state.json"
LATEST = "latest"


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so readers see the old file or the new one, never a mix."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def atomic_write_text(path: Path, text: str) -> None:
    """:func:`atomic_write_bytes` for UTF-8 text (reports, tables, cards)."""
    atomic_write_bytes(path, text.encode())


def atomic_write_json(path: Path, data: dict) -> None:
    atomic_write_bytes(path, (json.dumps(data, indent=2, sort_keys=True) + "\n").encode())


def _tensors_bytes(tensors: dict[str, torch.Tensor]) -> bytes:
    return save_safetensors_bytes({k: v.detach().contiguous().cpu() for k, v in tensors.items()})


def write_model(directory: Path, state_dict: dict[str, torch.Tensor], config: dict) -> None:
    """Write ``model.safetensors`` and ``config.json`` (with the weights' hash) into ``directory``."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    blob = _tensors_bytes(state_dict)
    config = {**config, "format": FORMAT, "weights_sha256": hashlib.sha256(blob).hexdigest()}
    atomic_write_bytes(directory / WEIGHTS, blob)
    atomic_write_json(directory / CONFIG, config)


def read_config(directory: Path) -> dict:
    """Read and sanity-check a model directory's ``config.json``."""
    path = Path(directory) / CONFIG
    if not path.is_file():
        raise CheckpointError(f"no {CONFIG} in {directory}: not a seqmotion model directory")
    try:
        config = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CheckpointError(f"{path} is not valid JSON (corrupt checkpoint?): {exc}") from None
    if not isinstance(config, dict) or config.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a {FORMAT} config (format={config.get('format')!r})")
    return config


def read_model(directory: Path, expected_task: str | None = None) -> tuple[dict, dict[str, torch.Tensor]]:
    """Load a model directory's config and weights, verifying they belong together.

    Raises:
        CheckpointError: missing files, corrupt weights, hash mismatch, or another task's model.
    """
    directory = Path(directory)
    config = read_config(directory)
    if expected_task is not None and config.get("task") != expected_task:
        raise CheckpointError(
            f"{directory} holds a model for task {config.get('task')!r}, not {expected_task!r}"
        )
    path = directory / WEIGHTS
    if not path.is_file():
        raise CheckpointError(f"no {WEIGHTS} in {directory}")
    blob = path.read_bytes()
    digest = hashlib.sha256(blob).hexdigest()
    if config.get("weights_sha256") not in (None, digest):
        raise CheckpointError(f"{path} does not match its config (hash mismatch: corrupt or mixed-up files)")
    try:
        tensors = load_safetensors_bytes(blob)
    except Exception as exc:  # safetensors raises its own error types for malformed files
        raise CheckpointError(f"{path} is not a readable safetensors file: {exc}") from None
    return config, tensors


def load_state_dict_strict(module: torch.nn.Module, tensors: dict[str, torch.Tensor], source: str) -> None:
    """``load_state_dict`` that reports missing/unexpected/mis-shaped tensors as CheckpointError."""
    own = module.state_dict()
    missing = sorted(set(own) - set(tensors))
    unexpected = sorted(set(tensors) - set(own))
    shapes = [k for k in own if k in tensors and tuple(own[k].shape) != tuple(tensors[k].shape)]
    if missing or unexpected or shapes:
        raise CheckpointError(
            f"weights in {source} do not fit the model described by its config: "
            f"missing={missing[:5]} unexpected={unexpected[:5]} wrong shape={shapes[:5]}"
        )
    module.load_state_dict(tensors)


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
    """Write ``run_dir/checkpoints/<name>/`` atomically, point ``run_dir/latest`` at it, prune old ones."""
    ckpt_root = Path(run_dir) / "checkpoints"
    ckpt_root.mkdir(parents=True, exist_ok=True)
    final = ckpt_root / name
    tmp = ckpt_root / f".{name}.tmp-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    write_model(tmp, model_state, config)
    opt_tensors, opt_meta = _flatten_optimizer(optimizer_state)
    atomic_write_bytes(tmp / OPTIMIZER, _tensors_bytes(opt_tensors))
    atomic_write_json(tmp / TRAINER_STATE, {**trainer_state, "optimizer": opt_meta})
    if final.exists():
        shutil.rmtree(final)
    os.replace(tmp, final)
    atomic_write_bytes(Path(run_dir) / LATEST, f"checkpoints/{name}\n".encode())
    for old in sorted(p for p in ckpt_root.iterdir() if p.is_dir() and not p.name.startswith("."))[:-keep]:
        if old != final:
            shutil.rmtree(old)
    return final


def latest_checkpoint(run_dir: Path) -> Path | None:
    pointer = Path(run_dir) / LATEST
    if not pointer.is_file():
        return None
    target = Path(run_dir) / pointer.read_text().strip()
    if not (target / TRAINER_STATE).is_file():
        raise CheckpointError(f"{pointer} points at {target}, which is not a complete training checkpoint")
    return target


def read_training_checkpoint(path: Path) -> tuple[dict, dict[str, torch.Tensor], dict, dict]:
    """Return ``(config, model_tensors, optimizer_state_dict, trainer_state)``."""
    config, tensors = read_model(path)
    try:
        trainer_state = json.loads((Path(path) / TRAINER_STATE).read_text())
        opt_tensors = load_safetensors_bytes((Path(path) / OPTIMIZER).read_bytes())
    except Exception as exc:
        raise CheckpointError(f"training state in {path} is unreadable: {exc}") from None
    optimizer_state = _unflatten_optimizer(opt_tensors, trainer_state.pop("optimizer"))
    return config, tensors, optimizer_state, trainer_state


def resolve_model_dir(path: Path) -> Path:
    """A directory holding ``model.safetensors``: the path itself, or a run's latest checkpoint."""
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"{path} does not exist")
    if (path / WEIGHTS).is_file() or (path / CONFIG).is_file():
        return path
    latest = latest_checkpoint(path)
    if latest is not None:
        return latest
    raise CheckpointError(f"{path} holds neither a model ({WEIGHTS} + {CONFIG}) nor a training run")
