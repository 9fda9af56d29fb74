"""Loading trained models: ``sm.load(path)`` and ``sm.load_pretrained(name)``."""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

from . import tasks
from .errors import CheckpointError
from .models.seq2seq import ChunkedSeq2Seq, Seq2SeqConfig
from .training import checkpoint as ckpt

PRETRAINED = {  # shipped model → its task
    "pancake": "pancake",  # ch. 2/4: 2 × 64 LN-LSTM Deformer
    "sliding": "sliding",  # ch. 3: model A (full curriculum, trained across 9 friction pairs), the SlidingPlanner
    "sliding-A-nominal": "sliding",  # ch. 3: A trained at the nominal friction only (the dissertation's protocol)
    "sliding-A-velocity": "sliding",  # ch. 3: A on the drifting (velocity-level) pan shaking B and C learn from
    "sliding-B": "sliding",  # ch. 3 baselines on A's budget, for `seqmotion reproduce ch3`
    "sliding-C": "sliding",
    "pushing": "pushing",  # ch. 5: SeqAE + CNN policy
}


def load_model(path: str | Path, expected_task: str | None = None) -> tuple[ChunkedSeq2Seq, dict]:
    """Load a chunked seq2seq model and its config from a model directory or a training run."""
    directory = ckpt.resolve_model_dir(Path(path))
    config, tensors = ckpt.read_model(directory, expected_task)
    try:
        model = ChunkedSeq2Seq(Seq2SeqConfig.from_dict(config["model"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{directory}/config.json does not describe a valid model: {exc}") from None
    ckpt.load_state_dict_strict(model, tensors, str(directory))
    return model.eval(), config


def load(path: str | Path, expected_task: str | None = None) -> Any:
    """Load a trained model as its task's user-facing object (``Deformer``, ``SlidingPlanner``...).

    Args:
        path: a model directory (``model.safetensors`` + ``config.json``) or a training run
            directory (its latest checkpoint is used).
        expected_task: if given, refuse a checkpoint of any other task.

    Raises:
        CheckpointError: missing, corrupt or mismatched files, or another task's model.
    """
    directory = ckpt.resolve_model_dir(Path(path))
    config = ckpt.read_config(directory)
    task_name = config.get("task")
    if expected_task is not None and task_name != expected_task:
        raise CheckpointError(f"{directory} holds a model for task {task_name!r}, not {expected_task!r}")
    try:
        task = tasks.get(task_name)
    except ValueError as exc:
        raise CheckpointError(f"{directory}: {exc}") from None
    loader = getattr(task, "load", None)
    if loader is not None:  # tasks with their own model class (e.g. learning from demonstration)
        return loader(directory)
    model, config = load_model(directory, task_name)
    return task.wrap(model, config)


def pretrained_dir(name: str) -> Path:
    """Where a shipped pretrained model lives inside the installed package."""
    if name not in PRETRAINED:
        raise ValueError(f"unknown pretrained model {name!r}; shipped models: {sorted(PRETRAINED)}")
    path = Path(str(resources.files("seqmotion") / "pretrained" / name))
    if not (path / ckpt.WEIGHTS).is_file():
        raise CheckpointError(f"pretrained model {name!r} is not shipped in this installation ({path})")
    return path


def load_pretrained(name: str) -> Any:
    """A model shipped with the package: ``"pancake"`` → Deformer, ``"sliding"`` → SlidingPlanner,
    ``"pushing"`` → the learning-from-demonstration policy."""
    return load(pretrained_dir(name), expected_task=PRETRAINED.get(name))
