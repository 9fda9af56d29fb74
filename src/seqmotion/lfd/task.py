"""The chapter-5 pushing task in the task registry (learning from demonstration).

Its models are not trained by the seq2seq trainer but from demonstrations by
``seqmotion lfd collect`` and ``seqmotion lfd train`` (:mod:`seqmotion.lfd.train`), so the
registry entry is a plain object with a ``name``, the ``model_class`` its models load as and
``load(directory)``; ``sm.load(path)`` and ``sm.load_pretrained("pushing")`` call it and get a
:class:`~seqmotion.lfd.policy.policy.PushingPolicy`.

It is registered through seqmotion's own entry point (``pyproject.toml``)::

    [project.entry-points."seqmotion.tasks"]
    pushing = "seqmotion.lfd.task:TASK"

the way any other package adds a task, so the task layer never imports ``lfd``.
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

from .policy.policy import PushingPolicy


class PushingTask:
    """Registry entry of the pushing task: ``name``, ``model_class``, ``trained_by`` and ``load``."""

    name: ClassVar[str] = "pushing"
    model_class: ClassVar[type[PushingPolicy]] = PushingPolicy
    trained_by: ClassVar[str] = (
        "its models are trained from demonstrations by `seqmotion lfd collect` and `seqmotion lfd train`"
    )

    def load(self, directory: str | Path) -> PushingPolicy:
        """The policy stored in ``directory`` (a policy directory or a shipped model's folder), verified.

        Raises:
            seqmotion.CheckpointError: missing, corrupt or mismatched files, or another task's model.
        """
        return self.model_class.from_pretrained(directory)


TASK = PushingTask()
