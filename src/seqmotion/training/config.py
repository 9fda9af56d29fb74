"""The configuration of a training run (JSON-serialisable, stored with every checkpoint and model).

:class:`Optimization` is the optimiser's part, shared by every training: ``seqmotion train``'s
:class:`TrainConfig` and the chapter-5 settings (:class:`seqmotion.lfd.train.SeqAETraining`,
:class:`~seqmotion.lfd.train.CNNTraining`) are its subclasses, checked by the same code and handed to
:class:`~seqmotion.training.loop.TrainingLoop` by :meth:`Optimization.loop_settings`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from ..errors import check_number

MAX_COUNT = 10**9
"""Upper bound of the run's counts (batches, batch size, epochs): a typo, not a training."""


@dataclass(kw_only=True)
class Optimization:
    """Adam's settings of a training: its learning rate, the rate's schedule and gradient clipping.

    Attributes:
        lr: Adam's (initial) learning rate (the other Adam settings are PyTorch's defaults, as in the
            dissertation).
        lr_final_fraction: the learning rate follows a cosine from ``lr`` down to ``lr_final_fraction · lr``
            at the last step; 1.0 keeps it constant, as the dissertation's Adam "with default settings" does.
        grad_clip: clip the global gradient norm to this (None or 0: no clipping).
    """

    lr: float = 1e-3
    lr_final_fraction: float = 1.0
    grad_clip: float | None = 1.0

    def check_optimization(self) -> None:
        """``ValueError`` naming the first bad setting (a subclass calls it from its own checks)."""
        check_number("lr", self.lr, minimum=0, strict_minimum=True)
        check_number("lr_final_fraction", self.lr_final_fraction, minimum=0, strict_minimum=True, maximum=1)
        if self.grad_clip is not None:
            check_number("grad_clip", self.grad_clip, minimum=0)

    def loop_settings(self) -> dict[str, Any]:
        """The keyword arguments of :class:`~seqmotion.training.loop.TrainingLoop` these settings fix."""
        self.check_optimization()
        return {"lr": self.lr, "lr_final_fraction": self.lr_final_fraction, "grad_clip": self.grad_clip}


@dataclass
class TrainConfig(Optimization):
    """Everything that defines a training run (JSON-serialisable, stored with every checkpoint).

    Attributes:
        task: registered task name.
        preset: name of the preset this config came from (informational).
        model: :class:`Seq2SeqConfig` as a dict.
        curriculum: :class:`Curriculum` as a dict; its ``epochs`` is the run's length.
        batches_per_epoch, batch_size: mini-batches per epoch and trajectories per mini-batch
            (the global batch; data-parallel ranks each take an equal share).
        lr, lr_final_fraction, grad_clip: the optimiser's settings (:class:`Optimization`).
        seed: seeds weights, data and scheduled sampling.
        checkpoint_every: steps between checkpoints (default: once per epoch).
        keep_checkpoints: how many training checkpoints to keep.
        options: task-specific settings (loss weights, variance floor, lengths, ...).
    """

    task: str
    preset: str
    model: dict
    curriculum: dict
    batches_per_epoch: int
    batch_size: int
    seed: int = 0
    checkpoint_every: int | None = None
    keep_checkpoints: int = 2
    options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> TrainConfig:
        """Check every setting (types, finiteness, ranges); call again after changing attributes.

        Raises:
            ValueError: naming the first bad setting.
        """
        for name in ("task", "preset"):
            if not isinstance(getattr(self, name), str):
                raise ValueError(f"{name} must be a string, got {getattr(self, name)!r}")
        for name in ("model", "curriculum", "options"):
            if not isinstance(getattr(self, name), dict):
                raise ValueError(f"{name} must be a dict, got {type(getattr(self, name)).__name__}")
        for name in ("batches_per_epoch", "batch_size"):
            check_number(name, getattr(self, name), minimum=1, maximum=MAX_COUNT, integer=True)
        self.check_optimization()
        check_number("seed", self.seed, minimum=0, integer=True)
        if self.checkpoint_every is not None:
            check_number("checkpoint_every", self.checkpoint_every, minimum=1, integer=True)
        check_number("keep_checkpoints", self.keep_checkpoints, minimum=1, maximum=MAX_COUNT, integer=True)
        epochs = self.curriculum.get("epochs")
        check_number("curriculum epochs", epochs, minimum=1, maximum=MAX_COUNT, integer=True)
        return self

    @property
    def epochs(self) -> int:
        return int(self.curriculum["epochs"])

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> TrainConfig:
        """The config ``to_dict`` wrote (``ValueError`` for anything else)."""
        if not isinstance(data, dict):
            raise ValueError(f"a training config must be a dict, got {type(data).__name__}")
        try:
            return cls(**data)
        except TypeError as exc:  # unknown or missing keys
            raise ValueError(f"not a training config: {exc}") from None
