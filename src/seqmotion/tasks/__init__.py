"""Tasks: the registry (seqmotion's own modules and the ``seqmotion.tasks`` entry-point group),
the :class:`Task` base, typed options and the task-generic trained model.

>>> from seqmotion import tasks
>>> tasks.names()                       # every task this installation knows, plug-ins included
>>> tasks.train(tasks.get("pancake").train_config("tiny"), "runs/tiny")
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..core import registry
from ..core.options import TaskOptions
from ..core.registry import ENTRY_POINT_GROUP, get, names, pretrained_roots, refresh, register
from ..core.results import Motion
from ..core.stepper import OnlineGenerator
from ..core.task import Task
from ..core.trained import TrainedModel
from ..training.config import TrainConfig


def train(config: TrainConfig, run_dir: str | Path, **kwargs: Any) -> Path:
    """Train ``config`` with its registered task: :func:`seqmotion.training.trainer.train` (same keywords)."""
    from ..training.trainer import train as run

    task = get(config.task)
    if not isinstance(task, Task):
        raise ValueError(
            f"task {config.task!r} is not trained by the seq2seq trainer"
            + (f"; {task.trained_by}" if getattr(task, "trained_by", None) else "")
        )
    return run(task, config, run_dir, **kwargs)


__all__ = [
    "ENTRY_POINT_GROUP", "Motion", "OnlineGenerator", "Task", "TaskOptions", "TrainConfig", "TrainedModel", "get",
    "names", "pretrained_roots", "refresh", "register", "registry", "train",
]
