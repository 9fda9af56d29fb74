"""Task registry: every module in this package that defines ``TASK`` is a trainable task."""

from __future__ import annotations

import importlib
import pkgutil

from .base import Task, TrainConfig

_REGISTRY: dict[str, Task] | None = None


def _discover() -> dict[str, Task]:
    global _REGISTRY
    if _REGISTRY is None:
        found: dict[str, Task] = {}
        for info in pkgutil.iter_modules(__path__):
            if info.name.startswith("_") or info.name == "base":
                continue
            module = importlib.import_module(f"{__name__}.{info.name}")
            task = getattr(module, "TASK", None)
            if isinstance(task, Task):
                found[task.name] = task
        _REGISTRY = found
    return _REGISTRY


def get(name: str) -> Task:
    """The registered task called ``name``."""
    tasks = _discover()
    if name not in tasks:
        raise ValueError(f"unknown task {name!r}; known tasks: {sorted(tasks)}")
    return tasks[name]


def names() -> list[str]:
    return sorted(_discover())


__all__ = ["Task", "TrainConfig", "get", "names"]
