"""Where tasks come from: seqmotion's own ``tasks/`` modules and other installed packages.

A task is found by name from two sources:

* every module of the package ``seqmotion.tasks`` that defines ``TASK``;
* every entry point of the group ``seqmotion.tasks`` in installed distributions. A package
  declares, in its ``pyproject.toml``::

      [project.entry-points."seqmotion.tasks"]
      tray = "seqmotion_tray.task:TASK"     # a Task instance (or a Task class, instantiated)

So ``sm.load``, ``sm.load_pretrained``, the trainer and the CLI find a task of the user's own
package without edits to seqmotion. Task modules are imported by name only (nothing here
imports :mod:`.base`), which keeps the task layer free of import cycles.

:func:`pretrained_roots` lists the folders that ship pretrained models: ``pretrained/`` beside
the top-level package that defines each task (``seqmotion/pretrained/`` for the built-in ones,
``seqmotion_tray/pretrained/`` for the example plug-in), plus the folders named in the
environment variable ``SEQMOTION_PRETRAINED_PATH`` (``os.pathsep``-separated).
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import pkgutil
import sys
from importlib import metadata
from pathlib import Path
from typing import Any

ENTRY_POINT_GROUP = "seqmotion.tasks"
PRETRAINED_PATH_ENV = "SEQMOTION_PRETRAINED_PATH"
_BUILTIN_PACKAGE = "seqmotion.tasks"
_SKIP = {"base", "options", "registry", "stepper", "trust"}
"""Modules of ``seqmotion.tasks`` that are the task layer's machinery, not tasks (``--help`` lists the rest)."""

_REGISTRY: dict[str, Any] | None = None


def _is_task(obj: object) -> bool:
    """A registry entry: has a ``name`` and either builds seq2seq models or loads its own."""
    return isinstance(getattr(obj, "name", None), str) and (hasattr(obj, "train_config") or hasattr(obj, "load"))


def _builtin() -> dict[str, Any]:
    found: dict[str, Any] = {}
    package = importlib.import_module(_BUILTIN_PACKAGE)
    for info in pkgutil.iter_modules(package.__path__):
        if info.name.startswith("_") or info.name in _SKIP:
            continue
        task = getattr(importlib.import_module(f"{_BUILTIN_PACKAGE}.{info.name}"), "TASK", None)
        if _is_task(task):
            found[task.name] = task
    return found


def _plugins(known: dict[str, Any]) -> dict[str, Any]:
    found: dict[str, Any] = {}
    for entry in metadata.entry_points(group=ENTRY_POINT_GROUP):
        try:
            task = entry.load()
        except Exception as exc:  # a broken plug-in must not break seqmotion: say which one
            raise ValueError(
                f"the seqmotion task plug-in {entry.name!r} ({entry.value}) fails to import: {exc}"
            ) from exc
        if isinstance(task, type):
            task = task()
        if not _is_task(task):
            raise ValueError(f"entry point {entry.name!r} ({entry.value}) is not a seqmotion task")
        if task.name in known or task.name in found:
            raise ValueError(f"two tasks are called {task.name!r} (one from the plug-in {entry.value})")
        found[task.name] = task
    return found


def _discover() -> dict[str, Any]:
    global _REGISTRY
    if _REGISTRY is None:
        builtin = _builtin()
        _REGISTRY = {**builtin, **_plugins(builtin)}
    return _REGISTRY


def register(task: Any) -> Any:
    """Register a task object by hand (a script or notebook; installed packages use the entry point).

    Returns the task, so it can be used as ``TASK = register(MyTask())``.
    """
    if not _is_task(task):
        raise ValueError(f"{task!r} is not a seqmotion task (needs a name and train_config or load)")
    tasks = _discover()
    if task.name in tasks and tasks[task.name] is not task:
        raise ValueError(f"a task called {task.name!r} is already registered")
    tasks[task.name] = task
    return task


def refresh() -> None:
    """Forget what was discovered (after installing a plug-in in a running process)."""
    global _REGISTRY
    _REGISTRY = None


def get(name: str) -> Any:
    """The registered task called ``name``.

    Raises:
        ValueError: no such task (the message lists the known ones).
    """
    tasks = _discover()
    if not isinstance(name, str) or name not in tasks:
        raise ValueError(f"unknown task {name!r}; known tasks: {sorted(tasks)}")
    return tasks[name]


def names() -> list[str]:
    return sorted(_discover())


def declared_names() -> list[str]:
    """Task names as declared (built-in module names and entry-point names) without importing any
    task: cheap enough for ``--help``. :func:`names` is authoritative."""
    spec = importlib.util.find_spec(_BUILTIN_PACKAGE)
    locations = list(spec.submodule_search_locations or []) if spec else []
    builtin = [i.name for i in pkgutil.iter_modules(locations) if not i.name.startswith("_") and i.name not in _SKIP]
    return sorted(set(builtin) | {e.name for e in metadata.entry_points(group=ENTRY_POINT_GROUP)})


def home_package(task: Any) -> Path:
    """The folder of the top-level package that defines ``task`` (``.../seqmotion`` for built-ins)."""
    top = type(task).__module__.split(".")[0]
    module = sys.modules.get(top) or importlib.import_module(top)
    return Path(next(iter(module.__path__))) if hasattr(module, "__path__") else Path(module.__file__).parent


def pretrained_roots() -> list[Path]:
    """Folders that hold shipped models, one sub-folder per model (see the module docstring)."""
    roots: list[Path] = []
    for part in os.environ.get(PRETRAINED_PATH_ENV, "").split(os.pathsep):
        if part:
            roots.append(Path(part))
    for task in _discover().values():
        root = home_package(task) / "pretrained"
        if root not in roots:
            roots.append(root)
    return roots
