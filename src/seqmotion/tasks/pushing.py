"""The chapter-5 pushing task in the model registry (learning from demonstration).

Its models are not trained by the shared seq2seq trainer but by ``seqmotion lfd train``
(:mod:`seqmotion.lfd.train`), so the task registers a plain object with a ``name`` and a
``load(directory)`` method; ``sm.load(path)`` and ``sm.load_pretrained("pushing")`` call it and
get a :class:`seqmotion.lfd.models.PushingPolicy`. Importing this module stays light: torch
and the policy classes are imported only when a model is loaded.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


class PushingTask:
    """Registry entry of the pushing task: ``name`` and ``load``."""

    name = "pushing"

    def load(self, directory: str | Path) -> Any:
        """The :class:`~seqmotion.lfd.models.PushingPolicy` stored in ``directory``.

        Raises:
            seqmotion.CheckpointError: missing, corrupt or mismatched files.
        """
        from ..lfd.models import load_policy

        return load_policy(Path(directory))


TASK = PushingTask()
