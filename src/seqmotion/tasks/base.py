"""What a task is: physics + input generators + loss + curriculum, wired to the shared model.

A new task is one module in ``seqmotion/tasks/`` defining a :class:`Task` subclass and an
instance named ``TASK``; the registry (``seqmotion.tasks.get``) finds it, so the trainer,
checkpoints and CLI work for it with no edits elsewhere.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch

from ..data.trajectories import TrajectoryBatch
from ..models.seq2seq import ChunkedSeq2Seq, Seq2SeqConfig
from ..training.curriculum import Curriculum


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


class Task(ABC):
    """A learning problem for the chunked seq2seq model."""

    name: ClassVar[str]
    presets: ClassVar[tuple[str, ...]]

    @abstractmethod
    def train_config(self, preset: str) -> TrainConfig:
        """The named configuration (at least ``"tiny"`` for tests, ``"small"`` and ``"paper"``)."""

    @abstractmethod
    def curriculum(self, config: TrainConfig) -> Curriculum:
        """The run's schedule (normally ``Curriculum.from_dict(config.curriculum)``)."""

    @abstractmethod
    def sample(
        self, n: int, rng: np.random.Generator, params: dict[str, float], config: TrainConfig
    ) -> TrajectoryBatch:
        """Draw ``n`` training trajectories for the curriculum parameters ``params``."""

    @abstractmethod
    def loss(
        self,
        model: ChunkedSeq2Seq,
        batch: TrajectoryBatch,
        params: dict[str, float],
        config: TrainConfig,
        generator: torch.Generator,
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """Scalar loss to minimise and named terms to log (include ``"feasible"`` if meaningful)."""

    @abstractmethod
    def wrap(self, model: ChunkedSeq2Seq, config: dict) -> Any:
        """The user-facing object for a trained model (``Deformer``, ``SlidingPlanner``...)."""

    def build_model(self, config: TrainConfig) -> ChunkedSeq2Seq:
        return ChunkedSeq2Seq(Seq2SeqConfig.from_dict(config.model))


def first_of(result: Any) -> Any:
    """The same result dataclass with every array field indexed by ``[0]`` (drop a batch axis of 1)."""
    values = {f.name: getattr(result, f.name) for f in fields(result)}
    return type(result)(**{k: v if v is None else v[0] for k, v in values.items()})


class TrainedModel:
    """What every task's user-facing model shares: encode, decode and integrate, in torch.

    Subclasses say which dynamics close the decoder's loop and how the decoder's start state
    follows from an input trajectory. Latent optimisation (:mod:`seqmotion.latent`) works on
    any subclass through these three differentiable maps.
    """

    task: ClassVar[str]
    input_dim: ClassVar[int]  # features per sample of the trajectories the encoder reads

    def __init__(self, model: ChunkedSeq2Seq, config: dict) -> None:
        self.model = model.eval()
        self.config = config

    def dynamics(self, **physics: Any) -> Any:
        """The :class:`~seqmotion.models.seq2seq.ChunkDynamics` the decoder runs with."""
        raise NotImplementedError

    def start_state(self, inputs: torch.Tensor) -> torch.Tensor:
        """Decoder start state ``(B, state_dim)`` for input trajectories ``(B, K, input_dim)``."""
        raise NotImplementedError

    def encode_torch(self, inputs: torch.Tensor) -> torch.Tensor:
        """``(B, K, input_dim)`` → latents ``(B, L·H)``."""
        return self.model.encode(inputs.float())

    def decode_torch(
        self, latent: torch.Tensor, x0: torch.Tensor, length: int, **physics: Any
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Decode latents from start states into ``(states (B, K, S), accel (B, K-1, d))``, differentiably.

        The physics runs in the dtype of ``x0`` (float64 gives exact bookkeeping).
        """
        from ..models.seq2seq import rollout

        out = rollout(self.model, latent, x0, self.dynamics(**physics), self.model.num_chunks(length), need_cov=False)
        return out.states[:, :length], out.accel[:, : length - 1].to(x0.dtype)

    def integrate_torch(self, x0: torch.Tensor, accel: torch.Tensor, **physics: Any) -> torch.Tensor:
        """States ``(B, N+1, S)`` that accelerations ``(B, N, d)`` produce from ``x0`` through the task's physics."""
        dynamics = self.dynamics(**physics)
        _, out = dynamics.step(dynamics.start(x0), accel.to(x0.dtype), None)
        return torch.cat([x0.unsqueeze(1), out["states"]], dim=1)

    def quantized(self, min_features: int = 256) -> TrainedModel:
        """A copy for fast CPU inference with the big linear layers in int8 (weight-only).

        Worth it for wide models (the paper-size sliding planner: ~2.5× faster generation);
        narrow layers stay float32. See :mod:`seqmotion.models.quantize` for the error it adds.
        """
        from ..models.quantize import quantize_int8

        copy = object.__new__(type(self))
        copy.__dict__.update(self.__dict__)
        copy.model = quantize_int8(self.model, min_features)
        copy.is_quantized = True
        return copy

    def save_pretrained(self, directory: str | Path) -> None:
        """Write ``model.safetensors`` + ``config.json`` (loadable with ``sm.load``)."""
        if getattr(self, "is_quantized", False):
            raise ValueError("a quantized copy is for inference only; save the float model it came from")
        from ..training.checkpoint import write_model

        write_model(Path(directory), self.model.state_dict(), self.config)

    @classmethod
    def from_pretrained(cls, directory: str | Path) -> TrainedModel:
        from ..api import load

        return load(directory, expected_task=cls.task)
