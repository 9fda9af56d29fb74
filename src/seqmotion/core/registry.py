"""Where tasks come from: seqmotion's own ``tasks/`` modules and other installed packages.

A task is found by name from two sources:

* every module of the package ``seqmotion.tasks`` that defines ``TASK``;
* every entry point of the group ``seqmotion.tasks`` in installed distributions. A package
  declares, in its ``pyproject.toml``::

      [project.entry-points."seqmotion.tasks"]
      tray = "seqmotion_tray.task:TASK"     # a Task instance (or a Task class, instantiated)

So ``sm.load``, ``sm.load_pretrained``, the trainer and the CLI find a task of the user's own
package without edits to seqmotion. Task modules are imported by name only (nothing here
imports :mod:`.task`), which keeps the task layer free of import cycles.

Plug-ins are untrusted neighbours: an entry point is imported only when a name is asked for that
no built-in task has (or when every task is listed), each at most once per process, and one that
fails to import (an exception, even ``sys.exit``), is not a task, or reuses a taken name is skipped
with a ``RuntimeWarning`` naming it — it never stops the built-in tasks or the other plug-ins.

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
import warnings
from importlib import metadata
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

ENTRY_POINT_GROUP = "seqmotion.tasks"
PRETRAINED_PATH_ENV = "SEQMOTION_PRETRAINED_PATH"
_BUILTIN_PACKAGE = "seqmotion.tasks"

_REGISTRY: dict[str, Any] | None = None
"""Tasks known so far: the built-in ones, those registered by hand and the plug-ins loaded yet."""
_TRIED: set[tuple[str, str]] = set()
"""Entry points ``(name, value)`` already imported (or tried): each is imported, and warned about, once."""


@runtime_checkable
class TaskEntry(Protocol):
    """What the registry holds: a task's ``name`` and how its trained models load. Every
    :class:`~seqmotion.core.task.Task` is one; so is a task trained some other way (the chapter-5
    pushing task, trained from demonstrations)."""

    name: str

    def load(self, directory: Any) -> Any:
        """The trained model stored in ``directory``."""
        ...


def _is_task(obj: object) -> bool:
    return isinstance(obj, TaskEntry) and not isinstance(obj, type) and isinstance(obj.name, str)


def _builtin() -> dict[str, Any]:
    found: dict[str, Any] = {}
    package = importlib.import_module(_BUILTIN_PACKAGE)
    for info in pkgutil.iter_modules(package.__path__):
        if info.name.startswith("_"):
            continue
        task = getattr(importlib.import_module(f"{_BUILTIN_PACKAGE}.{info.name}"), "TASK", None)
        if _is_task(task):
            found[task.name] = task
    return found


def _skip(entry: metadata.EntryPoint, why: str) -> None:
    warnings.warn(f"skipping the seqmotion task plug-in {entry.name!r} ({entry.value}): {why}", RuntimeWarning,
                  stacklevel=4)


def _load_entry(entry: metadata.EntryPoint) -> Any | None:
    """The task an entry point names, or None (with a warning) when it cannot be one."""
    try:
        task = entry.load()
        if isinstance(task, type):
            task = task()
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - a plug-in's failure, even sys.exit, stays its own
        what = f"it called sys.exit({exc.code!r})" if isinstance(exc, SystemExit) else f"{type(exc).__name__}: {exc}"
        _skip(entry, f"it fails to import ({what})")
        return None
    if not _is_task(task):
        _skip(entry, f"it is a {type(task).__name__}, not a seqmotion task (a TaskEntry: needs a name and load)")
        return None
    return task


def _load_plugins(only: str | None = None) -> None:
    """Import the entry points not tried yet (only those declared as ``only`` when given) into the registry."""
    tasks = _known()
    for entry in metadata.entry_points(group=ENTRY_POINT_GROUP):
        if (only is not None and entry.name != only) or (entry.name, entry.value) in _TRIED:
            continue
        _TRIED.add((entry.name, entry.value))
        task = _load_entry(entry)
        if task is None:
            continue
        if task.name in tasks and tasks[task.name] is not task:
            _skip(entry, f"a task called {task.name!r} exists already (the first one is kept)")
            continue
        tasks[task.name] = task


def _known() -> dict[str, Any]:
    global _REGISTRY
    if _REGISTRY is None:
        _REGISTRY = _builtin()
    return _REGISTRY


def _discover() -> dict[str, Any]:
    """Every task: the built-in ones and all plug-ins (broken ones skipped with a warning)."""
    _load_plugins()
    return _known()


def register(task: Any) -> Any:
    """Register a task by hand (a script or notebook; installed packages use the entry point): an instance
    (``TASK = register(MyTask())`` returns it) or, as a class decorator, a class (``@register`` above
    ``class MyTask(Task)`` registers one instance and returns the class).
    """
    if isinstance(task, type):
        register(task())
        return task
    if not _is_task(task):
        raise ValueError(f"{task!r} is not a seqmotion task (a TaskEntry: needs a name and load)")
    tasks = _known()
    if task.name in tasks and tasks[task.name] is not task:
        raise ValueError(f"a task called {task.name!r} is already registered")
    tasks[task.name] = task
    return task


def refresh() -> None:
    """Forget what was discovered (after installing a plug-in in a running process)."""
    global _REGISTRY
    _REGISTRY = None
    _TRIED.clear()


def get(name: str) -> Any:
    """The registered task called ``name``.

    Raises:
        ValueError: no such task (the message lists the known ones).
    """
    tasks = _known()
    if isinstance(name, str) and name not in tasks:  # a plug-in: the one declared under that name first, then all
        _load_plugins(only=name)
        if name not in tasks:
            _load_plugins()
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
    builtin = [i.name for i in pkgutil.iter_modules(locations) if not i.name.startswith("_")]
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
    homes = [home_package(task) for task in _known().values()]
    homes += [home for home in map(_entry_home, metadata.entry_points(group=ENTRY_POINT_GROUP)) if home is not None]
    for home in homes:
        root = home / "pretrained"
        if root not in roots:
            roots.append(root)
    return roots


def _entry_home(entry: metadata.EntryPoint) -> Path | None:
    """The folder of an entry point's top-level package, found without importing (running) the plug-in."""
    top = entry.value.split(":")[0].strip().split(".")[0]
    try:
        spec = importlib.util.find_spec(top)
    except (ImportError, ValueError):
        return None
    if spec is None:
        return None
    if spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations)))
    return Path(spec.origin).parent if spec.origin else None
