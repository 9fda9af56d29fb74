"""The chapter-5 trainings' shared parts: their typed settings and the epochs over the demonstrations.

* :class:`SeqAETraining`, :class:`CNNTraining` — the optimisation settings (checked on construction,
  saved with every trained policy), :func:`default_settings` per SeqAE preset.
* :func:`fit` — Adam over shuffled epochs of a training set on the library's one optimisation loop
  (:class:`~seqmotion.training.loop.TrainingLoop`: schedule, clipping, checkpoints, exact resume).
* :func:`augment_images`, :func:`state_noise` — the photometric augmentation and the decoder-input noise.

:mod:`seqmotion.lfd.train` builds the trainings of every policy kind on these.
"""

from __future__ import annotations

import hashlib
import math
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from ..errors import check_number
from ..training.config import Optimization
from ..training.loop import TrainingLoop
from .policy.networks import preset
from .task import PushingTask

CHECKPOINT_EVERY = 50
"""Epochs between training checkpoints of the SeqAE and the end-to-end baseline."""


@dataclass(kw_only=True)
class SeqAETraining(Optimization):
    """Optimisation settings of the SeqAE (and of the end-to-end baseline's motion loss).

    Attributes:
        epochs: passes over the motions (dissertation: 2000).
        batch_size: motions per mini-batch (dissertation: 16).
        lr, lr_final_fraction, grad_clip: the optimiser's settings shared with ``seqmotion train``
            (:class:`~seqmotion.training.config.Optimization`); here a cosine decay to 10 % and clipping at 1.
        state_noise: stationary std of the noise on the decoder's slave-state inputs [normalised units].
        noise_correlation: correlation time of that noise [decoder steps of 20 ms]; 0 = white,
            otherwise a first-order autoregressive (Ornstein–Uhlenbeck) process, which looks like
            the slow drifts of a closed loop and cannot be averaged away by the LSTM.
        latent_noise: std of the Gaussian noise added to z before decoding.
        latent_penalty: weight β of ``β · ½ mean |z|²`` added to the loss. With the latent noise
            this is a variational bottleneck (a VAE with a fixed posterior spread): the encoder
            cannot outgrow the noise, so z keeps what explains most of the motions (where the
            block is) before the operator's idiosyncrasies, which an image cannot predict.
        seed: seeds the weights, the batch order and the noise.
    """

    epochs: int = 2000
    batch_size: int = 16
    lr_final_fraction: float = 0.1
    state_noise: float = 0.3
    noise_correlation: float = 0.0
    latent_noise: float = 0.1
    latent_penalty: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        _check_counts(self)
        for name in ("state_noise", "noise_correlation", "latent_noise", "latent_penalty"):
            check_number(name, getattr(self, name), minimum=0)


def _check_counts(settings: SeqAETraining | CNNTraining) -> None:
    """The checks every chapter-5 training's settings share: the optimiser's, epochs, batch size and seed."""
    settings.check_optimization()
    check_number("epochs", settings.epochs, minimum=1, integer=True)
    check_number("batch_size", settings.batch_size, minimum=1, integer=True)
    check_number("seed", settings.seed, minimum=0, integer=True)


@dataclass(kw_only=True)
class CNNTraining(Optimization):
    """Optimisation settings of the CNN (dissertation: 100 epochs, mini-batches of 8, Adam).

    Attributes:
        lr, lr_final_fraction, grad_clip: the optimiser's settings
            (:class:`~seqmotion.training.config.Optimization`); here the dissertation's plain Adam:
            a constant rate, no clipping.
        augment: photometric augmentation of the training images (see :func:`augment_images`):
            the nuisance the webcam sees between episodes is lighting and colour, and 18 images
            show too little of it. Geometry is never altered (it carries the block's position).
        targets: what the CNN regresses for each image (one of :data:`CNN_TARGETS`).
            ``"pair"`` is the dissertation's eq. 5.2: the encoder's z of the image's own
            demonstration. An image shows where the block is, not how this operator's pass
            went, and with 2–3 pairs per position the pair's own z is a noisy stand-in for "the
            z of this position" (for the 7-layer SeqAE 9 of 17 pairs' z lie nearer another
            position's mean z than their own). The other two take that z from all the
            (successful) demonstrations *without* images at the image's block position:
            ``"position_mean"`` their mean encoder z (what |z − ẑ|² converges to with
            unlimited pairs), ``"position_medoid"`` (default) the z of the one demonstration
            nearest that mean — the most typical demonstration, a z the decoder was trained
            on. The mean can lie where no demonstration is: for the 7-layer SeqAE every
            far-right z is 2.6–5.2 latent units from its position's mean, and decoding the
            mean there pushes the block across in 21 of 30 trials, the medoid in 29.
    """

    epochs: int = 100
    batch_size: int = 8
    grad_clip: float | None = None
    augment: bool = True
    targets: str = "position_medoid"
    seed: int = 0

    def __post_init__(self) -> None:
        _check_counts(self)
        if self.targets not in CNN_TARGETS:
            raise ValueError(f"CNN targets must be one of {CNN_TARGETS}, got {self.targets!r}")


CNN_TARGETS = ("position_medoid", "position_mean", "pair")
"""What the CNN learns to output per image (see :class:`CNNTraining`)."""

DEFAULT_PRESET = "smaller"
"""Model size ``seqmotion lfd train`` (and the shipped ``"pushing"`` policy) uses by default.

Not the dissertation's 7-layer model: the 3 × 32 ``smaller`` model succeeds as often in closed loop
and its SeqAE training fits the 45-minute collect-and-train budget of a 2-core CPU, which the larger
ones' do not (``benchmarks/RESULTS_lfd.md``).
"""

SEQAE_EPOCHS = {"tiny": 200, "smaller": 2000, "original": 2000, "larger": 1200, "wide64": 2000}
"""Default SeqAE epochs per preset: the dissertation's 2000, except ``larger``, whose 2000 epochs would take
hours on a 2-core CPU (``tiny`` is for tests)."""

E2E_EPOCHS = 2000
"""Default epochs of the end-to-end baseline (the dissertation's), every preset."""


def default_settings(
    preset_name: str = DEFAULT_PRESET, benchmark: str = "chapter"
) -> tuple[SeqAETraining, SeqAETraining, CNNTraining]:
    """``(SeqAE, end-to-end, CNN)`` training settings ``seqmotion lfd train`` uses for ``preset_name``.

    On the hard benchmark the CNN regresses each pair's own z (``"pair"``, eq. 5.2): its placements
    are continuous, so there are no block positions to pool demonstrations over.
    """
    preset(preset_name)  # ValueError for an unknown name
    cnn = CNNTraining(targets="pair") if benchmark == "hard" else CNNTraining()
    return SeqAETraining(epochs=SEQAE_EPOCHS[preset_name]), SeqAETraining(epochs=E2E_EPOCHS), cnn


def augment_images(images: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """Random photometric changes of uint8 images ``(B, 64, 64, 3)`` → float images in [0, 255].

    Per image: overall brightness ×U(0.8, 1.2), per-channel gain ×U(0.93, 1.07), offset
    U(−8, 8) grey levels; per pixel: Gaussian noise with σ = 2 grey levels.
    """
    b = images.shape[0]
    x = images.to(torch.float32)
    brightness = 0.8 + 0.4 * torch.rand((b, 1, 1, 1), generator=gen)
    gain = 0.93 + 0.14 * torch.rand((b, 1, 1, 3), generator=gen)
    offset = -8.0 + 16.0 * torch.rand((b, 1, 1, 1), generator=gen)
    x = x * brightness * gain + offset + 2.0 * torch.randn(x.shape, generator=gen)
    return x.clamp(0.0, 255.0)


# ----------------------------------------------------------------------------------------------
# The three procedures
# ----------------------------------------------------------------------------------------------
def seeded_generator(seed: int) -> torch.Generator:
    """Seed torch's global generator (the networks' initial weights) and return a generator of the same seed (the
    order of the mini-batches, the noise): one training's randomness from one number."""
    torch.manual_seed(seed)
    return torch.Generator().manual_seed(seed)


def fit(
    module: torch.nn.Module, params: list, n: int, settings: SeqAETraining | CNNTraining, gen: torch.Generator,
    batch_loss: Any, desc: str, progress: bool, min_batch: int = 1,
    checkpoint_dir: str | Path | None = None, data: tuple = (), resume: bool = True, part: str | None = None,
) -> dict[str, Any]:
    """Adam over ``settings.epochs`` shuffled passes of ``n`` examples, on the shared :class:`TrainingLoop`.

    ``batch_loss(indices) -> loss`` is the mean loss of one mini-batch; mini-batches smaller
    than ``min_batch`` are skipped. The loop takes its optimiser settings from ``settings``
    (:meth:`~seqmotion.training.config.Optimization.loop_settings`). ``desc`` names the training on the
    progress bar, ``part`` (``"seqae"``, ``"cnn"``, ``"end_to_end"``; default ``desc``) in its checkpoints.
    Returns ``{"loss": per-epoch mean, "seconds": wall time}``.

    With ``checkpoint_dir``, everything the loop depends on (weights, Adam's moments, the random
    generator, the epoch, the loss history) is written there every :data:`CHECKPOINT_EVERY`
    epochs and at the end, with a ``metrics.csv`` of the per-epoch loss, and a run finding a
    checkpoint of the same settings and ``data`` (arrays whose hash identifies the training
    set) there continues from it (unless ``resume`` is False: the loop then removes them first):
    an interrupted run resumed ends with exactly the weights of an uninterrupted one.
    """
    steps_per_epoch = math.ceil(n / settings.batch_size)
    digest = hashlib.sha256()
    for array in data:
        digest.update(np.ascontiguousarray(array).tobytes())
    shapes = {name: list(t.shape) for name, t in module.state_dict().items()}
    # what makes a checkpoint this training's: the task and part, the data, the settings and the layers
    identity = {"task": PushingTask.name, "part": part or desc, "data_sha256": digest.hexdigest(),
                "settings": asdict(settings), "shapes": shapes}
    loop = TrainingLoop(
        module, params, **settings.loop_settings(), total_steps=settings.epochs * steps_per_epoch,
        run_dir=checkpoint_dir, identity=identity, generators={"rng": gen},
    )
    try:
        history = _epochs(loop, module, n, settings, gen, batch_loss, desc, progress, min_batch, checkpoint_dir,
                          steps_per_epoch, resume)
    finally:
        loop.close()  # also unlocks the checkpoint directory when the training fails
    history["seconds"] = loop.elapsed
    return history


def _epochs(
    loop: TrainingLoop, module: torch.nn.Module, n: int, settings: SeqAETraining | CNNTraining, gen: torch.Generator,
    batch_loss: Any, desc: str, progress: bool, min_batch: int, checkpoint_dir: str | Path | None,
    steps_per_epoch: int, resume: bool,
) -> dict[str, Any]:
    """The epochs of :func:`fit` on its loop."""
    saved = loop.start(resume=resume)
    history: dict[str, Any] = {"loss": list(saved.get("loss", []))}
    first_epoch = int(saved.get("epoch", 0))
    module.train()
    bar = tqdm(range(first_epoch, settings.epochs), desc=desc, unit="epoch", disable=not progress, file=sys.stderr,
               initial=first_epoch, total=settings.epochs)
    for epoch in bar:
        order = torch.randperm(n, generator=gen)
        total = 0.0
        for b in range(steps_per_epoch):
            idx = order[b * settings.batch_size : (b + 1) * settings.batch_size]
            if len(idx) < min_batch:
                continue
            loss = batch_loss(idx)
            loop.step(loss, about=f" ({desc}, epoch {epoch + 1})")
            total += loss.item() * len(idx)
        history["loss"].append(total / n)
        bar.set_postfix(loss=f"{history['loss'][-1]:.4f}")
        done = epoch + 1
        loop.log({"loss": history["loss"][-1]}, epoch=done)
        if checkpoint_dir is not None and (done % CHECKPOINT_EVERY == 0 or done == settings.epochs):
            loop.checkpoint(extra={"epoch": done, "loss": history["loss"]})
    return history


def state_noise(shape: tuple[int, ...], settings: SeqAETraining, gen: torch.Generator) -> torch.Tensor | None:
    """Noise ``(B, K, 3J)`` for the decoder's inputs: white, or AR(1) with the configured correlation time."""
    if settings.state_noise <= 0:
        return None
    white = torch.randn(shape, generator=gen)
    if settings.noise_correlation <= 0:
        return settings.state_noise * white
    a = math.exp(-1.0 / settings.noise_correlation)
    scale = math.sqrt(1.0 - a * a)
    out = torch.empty(shape)
    out[:, 0] = white[:, 0]  # start in the stationary distribution
    for k in range(1, shape[1]):
        out[:, k] = a * out[:, k - 1] + scale * white[:, k]
    return settings.state_noise * out
