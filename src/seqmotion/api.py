"""Loading trained models: ``sm.load(path)``, ``sm.load_pretrained(name)``, ``sm.pretrained_models()``.

Shipped models are discovered from what is installed: every folder of a task package's
``pretrained/`` (``seqmotion/pretrained/`` for the built-in tasks, the plug-in's own for a task
from another package; see :func:`seqmotion.core.registry.pretrained_roots`) that holds a model
directory is a pretrained model named after the folder.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from . import tasks
from .errors import CheckpointError
from .io import read_json
from .training import checkpoint as ckpt
from .training.device import resolve_device


def load(path: str | Path, expected_task: str | None = None, device: str | Any | None = None) -> Any:
    """Load a trained model as its task's user-facing object (``Deformer``, ``SlidingPlanner``...).

    Args:
        path: a model directory (``model.safetensors`` + ``config.json``) or a training run
            directory (its latest checkpoint is used).
        expected_task: if given, refuse a checkpoint of any other task.
        device: run the network there (``"auto"``, ``"cpu"``, ``"cuda"``, ``"cuda:N"``; default None: the CPU).
            Weights are stored as CPU tensors whatever device trained them, and load on any device.

    Raises:
        CheckpointError: missing, corrupt or mismatched files, or another task's model.
        ValueError: an unknown device, a CUDA device this machine does not have, or a model that cannot move.
    """
    path = _as_path(path, "path")
    target = None if device is None else resolve_device(device)  # refused before any file is read
    for attempt in range(3):
        directory = ckpt.resolve_model_dir(path)
        try:
            return _on(_load_directory(directory, expected_task), target)
        except CheckpointError:
            # a training writing this run may have replaced `latest` and pruned the checkpoint just resolved
            if attempt == 2 or directory == path or directory.exists():
                raise
    raise AssertionError("unreachable")  # pragma: no cover


def _on(model: Any, device: Any) -> Any:
    """``model`` moved to ``device`` (None: left on the CPU it was loaded on)."""
    if device is None or (device.type == "cpu" and not hasattr(model, "to")):
        return model
    if not hasattr(model, "to"):
        raise ValueError(f"a {type(model).__name__} runs on the CPU only; drop device={str(device)!r}")
    return model.to(device)


def _load_directory(directory: Path, expected_task: str | None) -> Any:
    config = ckpt.read_config(directory)
    task_name = config.get("task")
    if expected_task is not None and task_name != expected_task:
        raise CheckpointError(f"{directory} holds a model for task {task_name!r}, not {expected_task!r}")
    try:
        task = tasks.get(task_name)
    except ValueError as exc:
        raise CheckpointError(f"{directory}: {exc} (is the package that defines it installed?)") from None
    return task.load(directory)


def pretrained_models() -> dict[str, Path]:
    """Every shipped model this installation has: name → model directory (first root wins on a clash)."""
    found: dict[str, Path] = {}
    for root in tasks.pretrained_roots():
        if not root.is_dir():
            continue
        for directory in sorted(root.iterdir()):
            complete = (directory / ckpt.WEIGHTS).is_file() and (directory / ckpt.CONFIG).is_file()
            if directory.name not in found and complete:
                found[directory.name] = directory
    return found


def pretrained_task(name: str) -> str | None:
    """The task of a shipped model (read from its config), or None if there is no such model or its config is
    unreadable (loading it says why)."""
    directory = pretrained_models().get(name)
    if directory is None:
        return None
    try:
        return read_json(directory / ckpt.CONFIG, "model config").get("task")
    except ValueError:
        return None


def _as_path(value: object, what: str) -> Path:
    if not isinstance(value, str | Path) or not str(value) or "\x00" in str(value):
        raise ValueError(f"{what} must be a path (str or Path), got {value!r}")
    return Path(value)


def pretrained_dir(name: str) -> Path:
    """Where a shipped pretrained model lives."""
    if not isinstance(name, str):
        raise ValueError(f"a pretrained model's name is a string, got {type(name).__name__} {name!r}")
    models = pretrained_models()
    if name not in models:
        raise ValueError(f"unknown pretrained model {name!r}; shipped models: {sorted(models)}")
    return models[name]


def load_pretrained(name: str, device: str | Any | None = None) -> Any:
    """A shipped model: ``"pancake"`` → Deformer, ``"sliding"`` → SlidingPlanner, ``"pushing"`` → the
    learning-from-demonstration policy, and any model a plug-in task's package ships. ``device``: as
    :func:`load`."""
    return load(pretrained_dir(name), device=device)


def resolve_model(value: str | Path, expected_task: str | None = None) -> Any:
    """A shipped model's name or a path to a model/run directory (the CLI's ``--model``), of ``expected_task``
    if given."""
    path = _as_path(value, "model")
    if not path.exists() and str(value) in pretrained_models():
        task = pretrained_task(str(value))
        if expected_task is not None and task != expected_task:
            raise ValueError(f"the shipped model {value!r} is a {task!r} model, not a {expected_task!r} model")
        return load_pretrained(str(value))
    if not path.exists():
        raise ValueError(f"{value} is neither a shipped model ({sorted(pretrained_models())}) nor a directory")
    return load(path, expected_task=expected_task)
