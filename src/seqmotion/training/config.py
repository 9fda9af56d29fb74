"""The configuration of a training run (JSON-serialisable, stored with every checkpoint and model)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from ..errors import check_number

MAX_COUNT = 10**9
"""Upper bound of the run's counts (batches, batch size, epochs): a typo, not a training."""


@dataclass
class TrainConfig:
    """Everything that defines a training run (JSON-serialisable, stored with every checkpoint).

    Attributes:
        task: registered task name.
        preset: name of the preset this config came from (informational).
        model: :class:`Seq2SeqConfig` as a dict.
        curriculum: :class:`Curriculum` as a dict; its ``epochs`` is the run's length.
        batches_per_epoch, batch_size: mini-batches per epoch and trajectories per mini-batch
            (the global batch; data-parallel ranks each take an equal share).
        lr: Adam learning rate (other Adam settings are PyTorch's defaults, as in the dissertation).
        lr_final_fraction: the learning rate follows a cosine from ``lr`` down to
            ``lr_final_fraction · lr`` at the last step; 1.0 (the default) keeps it constant, as
            the dissertation's Adam "with default settings" does.
        grad_clip: clip the global gradient norm to this (None: no clipping).
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
    lr: float = 1e-3
    lr_final_fraction: float = 1.0
    grad_clip: float | None = 1.0
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
        check_number("lr", self.lr, minimum=0, strict_minimum=True)
        fraction = check_number("lr_final_fraction", self.lr_final_fraction, minimum=0, strict_minimum=True)
        if fraction > 1:
            raise ValueError(f"lr_final_fraction must be in (0, 1], got {self.lr_final_fraction}")
        if self.grad_clip is not None:
            check_number("grad_clip", self.grad_clip, minimum=0)
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
