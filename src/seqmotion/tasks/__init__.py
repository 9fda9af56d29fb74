"""Task registry: every module in this package that defines ``TASK`` registers it.

A ``TASK`` is normally a :class:`Task` (trained by the shared seq2seq trainer). Models that
are trained otherwise (learning from demonstration) register an object with a ``name`` and a
``load(directory)`` method, so ``sm.load`` and ``sm.load_pretrained`` still find them.
"""

from __future__ import annotations

import importlib
import pkgutil

from .base import Task, TrainConfig

_REGISTRY: dict[str, Task] | None = None


def _discover() -> dict[str, Task]:  # values: Task, or any object with .name and .load
    global _REGISTRY
    if _REGISTRY is None:
        found: dict[str, Task] = {}
        for info in pkgutil.iter_modules(__path__):
            if info.name.startswith("_") or info.name == "base":
                continue
            module = importlib.import_module(f"{__name__}.{info.name}")
            task = getattr(module, "TASK", None)
            if isinstance(task, Task) or (hasattr(task, "name") and hasattr(task, "load")):
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
