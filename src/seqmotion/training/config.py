"""The configuration of a training run (JSON-serialisable, stored with every checkpoint and model)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any


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
        if self.batches_per_epoch < 1 or self.batch_size < 1:
            raise ValueError("batches_per_epoch and batch_size must be positive")
        if not self.lr > 0:
            raise ValueError(f"lr must be positive, got {self.lr}")
        if not 0.0 < self.lr_final_fraction <= 1.0:
            raise ValueError(f"lr_final_fraction must be in (0, 1], got {self.lr_final_fraction}")

    @property
    def epochs(self) -> int:
        return int(self.curriculum["epochs"])

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> TrainConfig:
        return cls(**data)
