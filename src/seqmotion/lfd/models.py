"""Chapter-5 networks: the sequence autoencoder (SeqAE), the image CNN and the combined policy.

Data conventions (dissertation 5.2.1 and 5.3.4). A motion is sampled every Δt_NN = 20 ms;
sample k holds 6J columns (:data:`seqmotion.lfd.teleop.MOTION_COLUMNS` for the arm): master θ,
θ̇, τ, then slave θ, θ̇, τ, each over the J joints [rad, rad/s, N m]. J is
:attr:`SeqAEConfig.joints`: 3 for the dissertation's arm (the default, and every shipped
model), another robot's joint count when the SeqAE is trained on its LeRobot dataset; the
shapes below are written for J = 3 (18 = 6J columns, 9 = 3J state or command values).

* **Encoder** — a stacked LSTM reads the whole motion ``(B, K, 18)``; a linear layer maps the
  last layer's final hidden state to the latent ``z`` ``(B, 8)``.
* **Decoder** — a stacked LSTM that, at step k, reads ``z`` and the slave's measured state
  ``s[k]`` (θ, θ̇, τ: 9) and emits the master command for the next step ``m̂[k+1]`` (θ, θ̇, τ:
  9). In closed loop (the 3-joint arm only) it is called every 20 ms by
  :func:`seqmotion.lfd.teleop.run_autonomous` and its recurrent state carries the history; in
  training it is teacher-forced on the recorded slave states (as in the dissertation).
* **CNN** — five stride-2 convolutions, each followed by ReLU and BatchNorm (that order, as
  the dissertation states), then a linear layer: a 64 × 64 RGB image → ``ẑ`` ``(B, 8)``.
* **Policy** — the CNN in the encoder's place in front of the decoder (Fig. 5.2). The same
  class holds the end-to-end baseline (same layers, trained directly on image–motion pairs).
* **Object feedback** (kind ``feedback``, beyond the dissertation) — the decoder's z slot carries
  the object's features *now* (:data:`FEATURES`), read every 20 ms from the webcam frame by a
  keypoint network (:class:`PoseNet`), so the decoder sees the object move as it pushes it
  (:class:`FeedbackSource`). On the hard benchmark the one-z policy cannot: it decodes the first
  image's z for the whole episode.

All networks work on *normalised* columns (per-column mean and standard deviation of the
SeqAE's training motions, stored with the weights as buffers), which keeps the LSTM inputs
O(1) whatever the units; the loss is still eq. 5.1 on the raw values (see :func:`motion_loss`).

Presets (layers × LSTM units, same for encoder and decoder): ``original`` 7 × 64 (the
dissertation gives 7 layers but no width; 64 sits between its ``smaller`` and ``larger``),
``larger`` 10 × 128 (its encoder reads every layer's final hidden state; see
:attr:`SeqAEConfig.readout`), ``smaller`` 3 × 32 (and ``tiny`` 1 × 16 for tests).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any, ClassVar

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..errors import CheckpointError
from ..training.checkpoint import load_state_dict_strict
from ..training.pretrained import PretrainedModel
from ..training.provenance import describe_machine
from .timing import COMMAND_INTERVAL

ARM_JOINTS = 3
"""Joints of the dissertation's arm (yaw, shoulder, elbow): the default J of a SeqAE, and the only J
the closed loop in MuJoCo (:class:`DecoderSource`, :func:`seqmotion.lfd.evaluation.evaluate`) runs."""
VARIABLES = ("theta", "dtheta", "tau")


def motion_dim(joints: int = ARM_JOINTS) -> int:
    """Columns per motion sample: master θ, θ̇, τ and slave θ, θ̇, τ, ``joints`` each (6J)."""
    return 2 * len(VARIABLES) * joints


def state_dim(joints: int = ARM_JOINTS) -> int:
    """Slave state the decoder reads (θ, θ̇, τ) and master command it writes (θ, θ̇, τ): 3J values."""
    return len(VARIABLES) * joints


def master_columns(joints: int = ARM_JOINTS) -> slice:
    """The master's θ, θ̇, τ in a motion sample (the first 3J columns)."""
    return slice(0, state_dim(joints))


def slave_columns(joints: int = ARM_JOINTS) -> slice:
    """The slave's θ, θ̇, τ in a motion sample (the last 3J columns)."""
    return slice(state_dim(joints), motion_dim(joints))


MOTION_DIM = motion_dim()
"""Columns per motion sample of the 3-joint arm (18)."""
STATE_DIM = state_dim()
"""Slave state / master command values of the 3-joint arm (9)."""
MASTER = master_columns()
SLAVE = slave_columns()


READOUTS = ("top", "all_layers")
"""What the motion encoder's output layer reads (see :class:`SeqAEConfig`)."""


@dataclass(frozen=True)
class SeqAEConfig:
    """Shape of the SeqAE (encoder and decoder share layers and width).

    Attributes:
        layers: stacked LSTM layers in the encoder and in the decoder.
        hidden: LSTM units per layer.
        latent: dimension of z (8 in the dissertation).
        normalize_latent: end the encoder with a BatchNorm without scale and shift, so that z
            has zero mean and unit variance over the data (a fixed signal level for the latent
            noise of training; not in the dissertation).
        joints: J, the robot's joint count (3: the dissertation's arm); a motion sample has 6J
            columns (see the module docstring). A config saved without it (every model before
            it existed) is the arm's 3.
        readout: what the encoder's linear layer reads (one of :data:`READOUTS`): ``"top"``
            (the dissertation) the last layer's final hidden state; ``"all_layers"`` the final
            hidden states of every layer, concatenated. A deep stack at its initial weights
            passes almost none of the motion's variation to its top (the spread of z over the
            90 demonstrations: 5e-3 for 3 × 32, 3e-5 for 7 × 64, 5e-7 for 10 × 128), far below
            the latent noise of training (σ = 0.1), so the decoder learns to ignore z, the
            encoder gets no gradient and z stays constant: the 10 × 128 SeqAE trained for 2000
            epochs encoded all 90 demonstrations to the same z. Reading every layer gives the
            first layers a direct path to z.
    """

    layers: int = 7
    hidden: int = 64
    latent: int = 8
    normalize_latent: bool = False
    readout: str = "top"
    joints: int = ARM_JOINTS

    def __post_init__(self) -> None:
        if not isinstance(self.normalize_latent, bool):
            raise ValueError(f"SeqAEConfig.normalize_latent must be a bool, got {self.normalize_latent!r}")
        if self.readout not in READOUTS:
            raise ValueError(f"SeqAEConfig.readout must be one of {READOUTS}, got {self.readout!r}")
        for name in ("layers", "hidden", "latent", "joints"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"SeqAEConfig.{name} must be a positive integer, got {value!r}")

    @property
    def motion_dim(self) -> int:
        """Columns of a motion sample (6J)."""
        return motion_dim(self.joints)

    @property
    def state_dim(self) -> int:
        """Values of the slave state the decoder reads and of the command it writes (3J)."""
        return state_dim(self.joints)

    @property
    def master(self) -> slice:
        """The master's columns of a motion sample."""
        return master_columns(self.joints)

    @property
    def slave(self) -> slice:
        """The slave's columns of a motion sample."""
        return slave_columns(self.joints)


PRESETS: dict[str, SeqAEConfig] = {
    "original": SeqAEConfig(7, 64),
    "larger": SeqAEConfig(10, 128, readout="all_layers"),
    "smaller": SeqAEConfig(3, 32),
    "tiny": SeqAEConfig(1, 16),
    "wide64": SeqAEConfig(3, 64, latent=16, readout="all_layers"),
}
"""The dissertation's three model sizes (Table 5.2; ``original``'s width is our choice), ``tiny``
(1 × 16, for tests and smoke runs) and ``wide64`` (3 × 64 with a 16-dimensional z, tried on the hard
benchmark: it fits its training scenes far better than ``smaller`` and generalises no better,
``benchmarks/RESULTS_lfd.md``)."""


def preset(name: str) -> SeqAEConfig:
    """The named :data:`PRESETS` entry; ``ValueError`` for an unknown name."""
    if name not in PRESETS:
        raise ValueError(f"unknown model preset {name!r}; choose one of {sorted(PRESETS)}")
    return PRESETS[name]


@dataclass(frozen=True)
class CNNConfig:
    """Shape of the image CNN.

    Attributes:
        channels: output channels of the five convolutions (4 × 4 kernels, stride 2, so a
            64 × 64 image ends as ``channels[-1]`` maps of 2 × 2).
        latent: output dimension (the SeqAE's z).
        image_size: input height and width [px].
    """

    channels: tuple[int, ...] = (16, 32, 32, 64, 64)
    latent: int = 8
    image_size: int = 64

    def __post_init__(self) -> None:
        object.__setattr__(self, "channels", tuple(int(c) for c in self.channels))
        if len(self.channels) != 5 or min(self.channels) < 1:
            raise ValueError(f"CNNConfig.channels must be five positive integers, got {self.channels!r}")
        if self.image_size != 64:
            raise ValueError(f"the CNN takes 64 x 64 images, got image_size={self.image_size!r}")


# ----------------------------------------------------------------------------------------------
# Normalisation and loss
# ----------------------------------------------------------------------------------------------
class MotionScaler(nn.Module):
    """Per-column statistics of the training motions, stored as buffers (they travel with the weights).

    Buffers:
        mean, std: ``(6J,)`` per-column mean and standard deviation (std floored at 1e-6).
        variance: ``(3J,)`` eq. 5.1's σ² for each master column: the variance of its variable
            (θ, θ̇ or τ) pooled over the J joints and all samples.
    """

    def __init__(self, joints: int = ARM_JOINTS) -> None:
        super().__init__()
        self.joints = joints
        self.register_buffer("mean", torch.zeros(motion_dim(joints)))
        self.register_buffer("std", torch.ones(motion_dim(joints)))
        self.register_buffer("variance", torch.ones(state_dim(joints)))

    @torch.no_grad()
    def fit(self, motions: np.ndarray | torch.Tensor) -> MotionScaler:
        """Set the statistics from motions ``(N, K, 6J)`` (raw units)."""
        j = self.joints
        flat = torch.as_tensor(np.asarray(motions), dtype=torch.float64).reshape(-1, motion_dim(j))
        self.mean.copy_(flat.mean(0))
        self.std.copy_(flat.std(0).clamp_min(1e-6))
        master = flat[:, master_columns(j)]
        for v in range(len(VARIABLES)):  # θ, θ̇, τ: one σ² per variable (eq. 5.1), shared by its J joints
            cols = slice(j * v, j * v + j)
            self.variance[cols] = master[:, cols].var().clamp_min(1e-12)
        return self

    def normalize(self, x: torch.Tensor, cols: slice = slice(None)) -> torch.Tensor:
        return (x - self.mean[cols]) / self.std[cols]

    def denormalize(self, x: torch.Tensor, cols: slice = slice(None)) -> torch.Tensor:
        return x * self.std[cols] + self.mean[cols]


def motion_loss(command: torch.Tensor, target: torch.Tensor, variance: torch.Tensor) -> torch.Tensor:
    """Eq. 5.1, averaged: ``mean_{b,k} Σ_c (m̂_c − m_c)² / σ²_{v(c)}`` over the 3J command columns.

    Args:
        command: predicted master commands ``(B, K, 3J)`` [raw units].
        target: recorded master states ``(B, K, 3J)``.
        variance: ``(3J,)`` σ² of each column's variable (see :class:`MotionScaler`).

    Returns:
        A scalar. Eq. 5.1 sums over the K samples; dividing by B·K only rescales it, so
        the learning rate does not depend on the sequence length or batch size.
    """
    if command.shape != target.shape or command.shape[-1] != variance.shape[-1]:
        raise ValueError(
            f"motion_loss needs (..., {variance.shape[-1]}) tensors of equal shape, got "
            f"{tuple(command.shape)} and {tuple(target.shape)}"
        )
    return ((command - target) ** 2 / variance).sum(-1).mean()


# ----------------------------------------------------------------------------------------------
# Networks
# ----------------------------------------------------------------------------------------------
class MotionEncoder(nn.Module):
    """LSTM over normalised motions ``(B, K, 6J)`` → z ``(B, latent)`` (final hidden state(s) → linear)."""

    def __init__(self, config: SeqAEConfig) -> None:
        super().__init__()
        self.lstm = nn.LSTM(config.motion_dim, config.hidden, config.layers, batch_first=True)
        self.all_layers = config.readout == "all_layers"
        self.out = nn.Linear(config.hidden * (config.layers if self.all_layers else 1), config.latent)
        self.norm = nn.BatchNorm1d(config.latent, affine=False) if config.normalize_latent else None

    def forward(self, motion_n: torch.Tensor) -> torch.Tensor:
        _, (h, _) = self.lstm(motion_n)  # h: (layers, B, hidden)
        z = self.out(h.permute(1, 0, 2).flatten(1) if self.all_layers else h[-1])
        return self.norm(z) if self.norm is not None else z


class CommandDecoder(nn.Module):
    """LSTM that reads ``[z, s[k]]`` and emits the normalised next master command ``m̂[k+1]``."""

    def __init__(self, config: SeqAEConfig) -> None:
        super().__init__()
        self.lstm = nn.LSTM(config.latent + config.state_dim, config.hidden, config.layers, batch_first=True)
        self.out = nn.Linear(config.hidden, config.state_dim)

    def forward(
        self, z: torch.Tensor, slave_n: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor] | None = None
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """``z (B, latent)``, ``slave_n (B, K, 3J)`` → commands ``(B, K, 3J)`` and the LSTM state.

        Called with the whole recorded sequence in training (one fused LSTM call) and with
        ``K = 1`` plus the carried state in closed loop. ``z`` may also be ``(B, K, latent)``, a
        different value at every step (the object features of a ``feedback`` policy).
        """
        z_steps = z if z.dim() == 3 else z.unsqueeze(1).expand(-1, slave_n.shape[1], -1)
        inputs = torch.cat([z_steps, slave_n], dim=-1)
        y, state = self.lstm(inputs, state)
        return self.out(y), state


class ImageEncoder(nn.Module):
    """The CNN: 5 × (conv 4×4 stride 2 → ReLU → BatchNorm) → linear; uint8 images → ẑ.

    Images enter as ``(B, 64, 64, 3)`` uint8 (or floats in [0, 255]); they are scaled to
    [−0.5, 0.5] here so callers never normalise by hand.
    """

    def __init__(self, config: CNNConfig) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        c_in = 3
        for c_out in config.channels:
            layers += [nn.Conv2d(c_in, c_out, 4, stride=2, padding=1), nn.ReLU(), nn.BatchNorm2d(c_out)]
            c_in = c_out
        self.features = nn.Sequential(*layers)
        side = config.image_size // 2 ** len(config.channels)
        self.out = nn.Linear(c_in * side * side, config.latent)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        x = images.to(torch.float32).permute(0, 3, 1, 2) / 255.0 - 0.5
        return self.out(self.features(x).flatten(1))



FEATURES = ("side", "distance", "reach", "is_box", "yaw")
"""The object features a ``feedback`` policy's decoder reads every step (:func:`object_features`)."""


def object_yaw(pose: np.ndarray) -> np.ndarray:
    """The object's turn about z [rad] from its poses ``(..., 7)`` (centre, quaternion w, x, y, z)."""
    pose = np.asarray(pose, dtype=np.float64)
    return 2.0 * np.arctan2(pose[..., 6], pose[..., 3])


def object_features(sign: Any, is_box: Any, pose: Any) -> np.ndarray:
    """The features ``(..., 5)`` of :data:`FEATURES`: side sign (+1 left), sign·y (distance from the centre line
    [m]), x (reach [m]), 1.0 for a box (0.0 a cylinder), the box's yaw [rad] (0 for a cylinder).

    ``pose (..., 7)``: the object's centre [m] and quaternion (w, x, y, z), turning about z only;
    ``sign`` and ``is_box`` broadcast against ``pose[..., 0]``.
    """
    pose = np.asarray(pose, dtype=np.float64)
    yaw = object_yaw(pose)
    sign = np.broadcast_to(np.asarray(sign, dtype=np.float64), yaw.shape)
    is_box = np.broadcast_to(np.asarray(is_box, dtype=np.float64), yaw.shape)
    return np.stack([sign, sign * pose[..., 1], pose[..., 0], is_box, is_box * yaw], -1)


POSE_REACH_OFFSET = 0.16
"""[m] subtracted from the object's x before :class:`PoseNet` regresses it (the middle of the placements)."""


@dataclass(frozen=True)
class PoseNetConfig:
    """Shape of the keypoint network of a ``feedback`` policy, and how its estimates are used.

    Attributes:
        keypoints: spatial soft-argmax keypoints (each an expected image position).
        width: channels of its three convolutions.
        opening_frames: the side (left or right) and the shape (box or cylinder) are the mean of
            this many first frames' estimates, then held: they do not change during a push, and a
            single frame with the pen over the object can misjudge them.
    """

    keypoints: int = 16
    width: int = 24
    opening_frames: int = 10

    def __post_init__(self) -> None:
        for name in ("keypoints", "width", "opening_frames"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"PoseNetConfig.{name} must be a positive integer, got {value!r}")


class PoseNet(nn.Module):
    """Keypoint CNN (spatial soft-argmax, Levine et al. 2016): one webcam frame → the object's pose.

    ``forward(images (B, 64, 64, 3) uint8, tip_xy (B, 2))`` → ``(B, 4)``: the object's
    ``x − 0.16 m`` and ``y`` [cm], a box-or-cylinder logit and the box's yaw [rad]. ``tip_xy`` is
    the pen tip's ``x, y`` [m], known from the slave's measured angles: a point in the world to read
    the jittered camera against. Its keypoints are expected image coordinates, so it locates to a
    fraction of a pixel where a flattening CNN (:class:`ImageEncoder`, the chapter's) does not:
    1.6 mm in closed loop against the chapter CNN's 14 mm (``benchmarks/RESULTS_lfd.md``).
    """

    def __init__(self, config: PoseNetConfig | None = None) -> None:
        super().__init__()
        config = config or PoseNetConfig()
        width = config.width
        self.conv = nn.Sequential(
            nn.Conv2d(3, width, 5, stride=2, padding=2), nn.ReLU(),
            nn.Conv2d(width, width, 3, padding=1), nn.ReLU(),
            nn.Conv2d(width, width, 3, padding=1), nn.ReLU(),
        )
        self.keypoints = nn.Conv2d(width, config.keypoints, 1)
        self.temperature = nn.Parameter(torch.ones(1))
        grid = torch.linspace(-1, 1, 32)  # the 32 × 32 feature map's image coordinates
        self.register_buffer("gx", grid[None, :].expand(32, 32).reshape(-1).clone())
        self.register_buffer("gy", grid[:, None].expand(32, 32).reshape(-1).clone())
        self.head = nn.Sequential(nn.Linear(2 * config.keypoints + width + 2, 128), nn.ReLU(),
                                  nn.Linear(128, 128), nn.ReLU(), nn.Linear(128, 4))

    def forward(self, images: torch.Tensor, tip_xy: torch.Tensor) -> torch.Tensor:
        x = images.to(torch.float32).permute(0, 3, 1, 2) / 255.0 - 0.5
        f = self.conv(x)
        attention = F.softmax(self.keypoints(f).flatten(2) / self.temperature, -1)  # (B, K, 32·32)
        points = torch.cat([attention @ self.gx, attention @ self.gy], -1)  # (B, 2K)
        return self.head(torch.cat([points, f.mean((2, 3)), tip_xy.to(torch.float32) * 10.0], -1))

    @staticmethod
    def targets(pose: np.ndarray, is_box: np.ndarray) -> np.ndarray:
        """What :meth:`forward` regresses ``(N, 4)`` for object poses ``(N, 7)`` and is-box flags ``(N,)``."""
        pose = np.asarray(pose, dtype=np.float64)
        return np.stack([(pose[:, 0] - POSE_REACH_OFFSET) * 100, pose[:, 1] * 100, np.asarray(is_box, np.float64),
                         object_yaw(pose)], -1).astype(np.float32)

    @torch.no_grad()
    def estimate(self, image: np.ndarray, tip_xy: np.ndarray) -> np.ndarray:
        """One frame ``(64, 64, 3)`` uint8 and pen tip ``(2,)`` [m] → ``(4,)``: the object's ``x, y`` [m], P(box),
        box yaw [rad]."""
        e = self(torch.as_tensor(image)[None], torch.as_tensor(np.asarray(tip_xy), dtype=torch.float32)[None])[0]
        e = e.double().numpy()
        return np.array([e[0] / 100 + POSE_REACH_OFFSET, e[1] / 100, 0.5 * (1.0 + math.tanh(0.5 * e[2])), e[3]])


def check_images(images: Any) -> np.ndarray:
    """``(64, 64, 3)`` or ``(B, 64, 64, 3)`` image(s) → ``(B, 64, 64, 3)`` array; ``ValueError`` otherwise."""
    arr = np.asarray(images)
    if arr.ndim == 3:
        arr = arr[None]
    if arr.ndim != 4 or arr.shape[1:] != (64, 64, 3):
        raise ValueError(f"images must be (64, 64, 3) or (B, 64, 64, 3) RGB arrays, got shape {np.shape(images)}")
    if arr.dtype != np.uint8:
        if not np.issubdtype(arr.dtype, np.number) or not np.all(np.isfinite(arr)):
            raise ValueError("images must be uint8 or finite numbers in [0, 255]")
        if arr.min() < 0 or arr.max() > 255:
            raise ValueError(f"image values must lie in [0, 255], got [{arr.min()}, {arr.max()}]")
    return arr


def check_motions(motions: Any, name: str = "motions", joints: int = ARM_JOINTS) -> np.ndarray:
    """``(K, 6J)`` or ``(B, K, 6J)`` finite motion(s) of ``joints`` = J joints, K ≥ 2 → ``(B, K, 6J)`` float64."""
    arr = np.asarray(motions, dtype=np.float64) if not isinstance(motions, np.ndarray) else motions
    if arr.ndim == 2:
        arr = arr[None]
    width = motion_dim(joints)
    if arr.ndim != 3 or arr.shape[-1] != width:
        joint_text = f" ({joints} joints)" if joints != ARM_JOINTS else ""
        raise ValueError(f"{name} must be (K, {width}) or (B, K, {width}){joint_text}, got shape {np.shape(motions)}")
    if arr.shape[1] < 2:
        raise ValueError(f"{name} need at least K = 2 samples, got {arr.shape[1]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contain NaN or inf")
    return arr.astype(np.float64, copy=False)


class SeqAE(nn.Module):
    """Sequence autoencoder of demonstrations (dissertation Fig. 5.2, eq. 5.1).

    ``forward(motion)`` is the teacher-forced training pass: encode the whole motion, then
    decode the slave states ``s[0..K-2]`` into commands that should equal ``m[1..K-1]``.
    """

    def __init__(self, config: SeqAEConfig = PRESETS["original"]) -> None:
        super().__init__()
        self.config = config
        self.scaler = MotionScaler(config.joints)
        self.encoder = MotionEncoder(config)
        self.decoder = CommandDecoder(config)

    def encode(self, motion: torch.Tensor) -> torch.Tensor:
        """Raw motions ``(B, K, 6J)`` → z ``(B, latent)``."""
        return self.encoder(self.scaler.normalize(motion))

    def decode(
        self,
        z: torch.Tensor,
        slave: torch.Tensor,
        state: tuple[torch.Tensor, torch.Tensor] | None = None,
        slave_noise: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """Raw slave states ``(B, K, 3J)`` → raw master commands ``(B, K, 3J)`` (one step ahead) and the LSTM state.

        ``slave_noise`` (``(B, K, 3J)``, in normalised units) is added to the decoder's input
        only: training-time noise injection (see :mod:`seqmotion.lfd.train`).
        """
        slave_n = self.scaler.normalize(slave, self.config.slave)
        if slave_noise is not None:
            slave_n = slave_n + slave_noise
        out, state = self.decoder(z, slave_n, state)
        return self.scaler.denormalize(out, self.config.master), state

    def forward(self, motion: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Teacher-forced reconstruction: ``(B, K, 6J)`` → (commands ``(B, K-1, 3J)`` for m[1:], z)."""
        z = self.encode(motion)
        command, _ = self.decode(z, motion[:, :-1, self.config.slave])
        return command, z


# ----------------------------------------------------------------------------------------------
# The combined policy
# ----------------------------------------------------------------------------------------------
CNN_TARGET_TEXT = {
    "pair": "each image's target the encoder's z of its own demonstration (eq. 5.2)",
    "position_mean": "each image's target the mean encoder z of the demonstrations without images at its block "
    "position (see `CNNTraining.targets`)",
    "position_medoid": "each image's target the encoder z of the most typical demonstration without images at its "
    "block position, the one nearest their mean (see `CNNTraining.targets`)",
}
"""How a model card describes each choice of :attr:`seqmotion.lfd.train.CNNTraining.targets`."""

KINDS = ("proposed", "end_to_end", "seqae", "feedback")
"""``proposed``: SeqAE on motions, then CNN → z; ``end_to_end``: CNN + decoder trained on pairs;
``seqae``: the SeqAE alone, no CNN (``seqmotion lfd train --methods seqae``: motions without the
images or block positions a CNN needs, e.g. another robot's LeRobot dataset); ``feedback``: a decoder
reading the object's features every step from a keypoint network (:class:`PoseNet`; hard benchmark)."""


def require_arm(config: SeqAEConfig, what: str) -> None:
    """``ValueError`` unless the SeqAE is the 3-joint arm's: ``what`` (a closed loop in MuJoCo) drives that arm."""
    if config.joints != ARM_JOINTS:
        raise ValueError(
            f"{what} drives the simulated {ARM_JOINTS}-joint arm; this model's SeqAE has joints={config.joints} "
            "(trained on another robot's motions): encode and decode its motions with policy.seqae() instead"
        )


@dataclass
class PolicyConfig:
    """Everything needed to rebuild a :class:`PushingPolicy` (stored in ``config.json``).

    Attributes:
        kind: one of :data:`KINDS` (``"proposed"``, ``"end_to_end"``, ``"seqae"``).
        preset: SeqAE size name (informational; ``seqae`` is authoritative).
        seqae: :class:`SeqAEConfig` as a dict.
        cnn: :class:`CNNConfig` as a dict.
        camera: webcam pose the CNN was trained on (a key of ``seqmotion.sim.pushing.CAMERAS``).
        command_interval: Δt_NN [s] (the decoder's period).
        training: how it was trained (data, seeds, epochs, wall time...), for the record.
        pose: kind ``feedback``: its :class:`PoseNetConfig` as a dict (empty for the other kinds,
            whose ``seqae`` latent is then z; a feedback policy's is the 5 :data:`FEATURES`).
    """

    kind: str = "proposed"
    preset: str = "original"
    seqae: dict = field(default_factory=lambda: asdict(PRESETS["original"]))
    cnn: dict = field(default_factory=lambda: asdict(CNNConfig()))
    camera: str = "default"
    command_interval: float = COMMAND_INTERVAL
    training: dict = field(default_factory=dict)
    pose: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown policy kind {self.kind!r}; choose one of {KINDS}")
        if self.kind == "feedback" and self.seqae.get("latent") != len(FEATURES):
            raise ValueError(f"a 'feedback' policy's decoder reads the {len(FEATURES)} object features {FEATURES} in "
                             f"its z slot: seqae latent must be {len(FEATURES)}, got {self.seqae.get('latent')!r}")


class PushingPolicy(nn.Module, PretrainedModel):
    """Image → z → closed-loop command source: the combined model of Fig. 5.2 (or the E2E baseline).

    Typical use::

        policy = sm.load_pretrained("pushing")
        z = policy.latent(image)                       # (8,) from a 64 × 64 × 3 uint8 image
        source = policy.source(z)                      # a fresh decoder state for one episode
        run = run_autonomous(scene, source, position)  # 1 ms bilateral control, decoder every 20 ms

    or simply ``policy.run(scene, position, variation)`` (takes the image, then runs).

    Modules: ``scaler`` (motion statistics), ``encoder`` (the SeqAE's motion encoder; kept
    for ``kind == "proposed"`` and ``"seqae"``, absent in the end-to-end baseline), ``decoder``,
    ``cnn`` (absent, ``None``, in a ``"seqae"`` model: the SeqAE alone).

    Saved and loaded like every trained seqmotion model (:class:`~seqmotion.training.pretrained.PretrainedModel`):
    ``policy.save_pretrained(directory)`` writes ``model.safetensors`` (tensor prefixes
    ``scaler.``, ``encoder.``, ``decoder.``, ``cnn.``) and ``config.json`` (``"task": "pushing"``
    and the whole :class:`PolicyConfig`); ``PushingPolicy.from_pretrained(directory)`` and
    ``sm.load(directory)`` rebuild exactly this policy.
    """

    task: ClassVar[str] = "pushing"
    config_class: ClassVar[type] = PolicyConfig

    def __init__(
        self, config: PolicyConfig, seqae: SeqAE | None = None, cnn: ImageEncoder | PoseNet | None = None,
    ) -> None:
        super().__init__()
        self.config = config
        seq_cfg = SeqAEConfig(**config.seqae)
        seqae = seqae if seqae is not None else SeqAE(seq_cfg)
        if seqae.config != seq_cfg:
            raise ValueError(f"the SeqAE's shape {seqae.config} differs from the config's {seq_cfg}")
        self.scaler = seqae.scaler
        self.decoder = seqae.decoder
        self.encoder = seqae.encoder if config.kind in ("proposed", "seqae") else None
        if config.kind == "seqae" and cnn is not None:
            raise ValueError("a 'seqae' model is the SeqAE alone: it takes no CNN")
        self.pose_net: PoseNet | None = None
        if config.kind == "feedback":  # the eye is the keypoint network; the features' statistics travel along
            if cnn is not None and not isinstance(cnn, PoseNet):
                raise ValueError(f"a 'feedback' policy's eye is a PoseNet, got {type(cnn).__name__}")
            self.pose_net = cnn if cnn is not None else PoseNet(PoseNetConfig(**config.pose))
            self.register_buffer("feature_mean", torch.zeros(len(FEATURES)))
            self.register_buffer("feature_std", torch.ones(len(FEATURES)))
            self.cnn = None
        elif config.kind == "seqae":
            self.cnn = None
        else:
            self.cnn = cnn if cnn is not None else ImageEncoder(CNNConfig(**config.cnn))
        self.eval()

    def _one_latent(self, what: str) -> None:
        """``ValueError`` for a ``feedback`` policy, which has no single z: ``what`` needs one."""
        if self.config.kind == "feedback":
            raise ValueError(
                f"{what} needs one z for the whole episode; a 'feedback' policy reads the object's pose from "
                "every webcam frame instead: run it with policy.run(scene, position, variation) or "
                "sm.lfd.evaluate(policy, benchmark='hard'), or drive it with policy.feedback_source(scene)"
            )

    @property
    def seqae_config(self) -> SeqAEConfig:
        return SeqAEConfig(**self.config.seqae)

    def seqae(self) -> SeqAE:
        """A :class:`SeqAE` view sharing this policy's scaler, encoder and decoder (not ``end_to_end``)."""
        if self.encoder is None:
            raise ValueError(f"a {self.config.kind!r} policy has no motion encoder (it was trained without one)")
        model = SeqAE(self.seqae_config)
        model.scaler, model.encoder, model.decoder = self.scaler, self.encoder, self.decoder
        return model

    # -- the model contract (save, load, model card) ---------------------------------------------
    def weights(self) -> dict[str, torch.Tensor]:
        return self.state_dict()

    def config_json(self) -> dict[str, Any]:
        return {"task": self.task, "model": type(self).__name__, "policy": asdict(self.config)}

    @classmethod
    def from_checkpoint(cls, config: dict[str, Any], tensors: dict[str, torch.Tensor], source: str) -> PushingPolicy:
        """Rebuild a policy from ``config.json``'s ``"policy"`` (a :class:`PolicyConfig`) and its weights.

        Raises:
            seqmotion.CheckpointError: the config does not describe a policy, or the weights do not fit it.
        """
        try:
            policy_config = PolicyConfig(**config["policy"])
            policy_config.cnn["channels"] = tuple(policy_config.cnn["channels"])
            policy = cls(policy_config)
        except (KeyError, TypeError, ValueError) as exc:
            raise CheckpointError(f"{source}/config.json does not describe a pushing policy: {exc}") from None
        load_state_dict_strict(policy, tensors, source)
        return policy.eval()

    def card_summary(self, name: str) -> list[str]:
        cfg = self.config
        seq, cnn = cfg.seqae, cfg.cnn
        joints = seq.get("joints", ARM_JOINTS)
        if cfg.kind == "seqae":
            return [
                f"Task `pushing` (dissertation ch. 5) — the sequence autoencoder alone (kind `seqae`, no CNN): an "
                f"encoder ({seq['layers']} × {seq['hidden']} LSTM, preset `{cfg.preset}`) from a motion of "
                f"{joints} joints to z ∈ R^{seq['latent']}, and a decoder that reads z and the slave state and emits "
                f"the next master command every {cfg.command_interval * 1000:g} ms.",
                "",
                "```python",
                "import seqmotion as sm",
                f"seqae = sm.load_pretrained({name!r}).seqae()",
                "command, z = seqae(motions)   # teacher-forced reconstruction of (B, K, 6J) motions",
                "```",
            ]
        if cfg.kind == "feedback":
            pose = PoseNetConfig(**cfg.pose)
            return [
                f"Task `pushing` (dissertation ch. 5, hard benchmark) — object feedback, kind `feedback`: every "
                f"{cfg.command_interval * 1000:g} ms a keypoint network ({pose.keypoints} spatial soft-argmax "
                f"keypoints over 3 convolutions of {pose.width} channels, plus the pen tip from the slave's angles) "
                "estimates the object's position, shape and yaw from the webcam frame, and a decoder "
                f"({seq['layers']} × {seq['hidden']} LSTM) reads those 5 features with the slave state and emits the "
                f"next master command. Side and shape: the mean of the first {pose.opening_frames} frames.",
                "",
                "```python",
                "import seqmotion as sm",
                f"policy = sm.load_pretrained({name!r})",
                "result = sm.lfd.evaluate(policy, trials=30, benchmark='hard')   # 30 held-out hard scenes",
                "```",
                "",
                f"Webcam pose: `{cfg.camera}`. It has no single z: `latent(image)` and `source(z)` refuse it, and so "
                "do the standard arms of `seqmotion.lfd.robot` (robosuite's, Menagerie's), which run one z from the "
                "first image.",
            ]
        encoder = (
            "the SeqAE's motion encoder is kept"
            if cfg.kind == "proposed"
            else "CNN and decoder were trained together on image–motion pairs (the end-to-end baseline; no motion "
            "encoder)"
        )
        return [
            f"Task `pushing` (dissertation ch. 5) — the combined policy of Fig. 5.2, kind `{cfg.kind}`: a CNN "
            f"(5 conv + ReLU + BatchNorm, channels {list(cnn['channels'])}, linear → z ∈ R^{seq['latent']}) in front "
            f"of the SeqAE's decoder ({seq['layers']} × {seq['hidden']} LSTM, preset `{cfg.preset}`), which reads z "
            f"and the slave state and emits the next master command every {cfg.command_interval * 1000:g} ms; "
            f"{encoder}.",
            "",
            "```python",
            "import seqmotion as sm",
            f"policy = sm.load_pretrained({name!r})",
            "result = sm.lfd.evaluate(policy, trials=30, benchmark='hard')   # 30 held-out scenes of the hard benchmark"
            if cfg.training.get("benchmark") == "hard"
            else "result = sm.lfd.evaluate(policy, trials=5)      # 30 closed-loop trials, 5 at each block position",
            "```",
            "",
            f"Webcam pose: `{cfg.camera}`.",
        ]

    def card_training(self) -> list[str]:
        training: dict[str, Any] = self.config.training
        if not training:
            return ["(no training record)"]
        seqae, cnn, e2e = (training.get(part, {}) for part in ("seqae", "cnn", "end_to_end"))
        lines = [
            f"- Command: `{training.get('command') or 'unknown'}`",
            f"- Seed: {training.get('seed')}; data `{training.get('data_dir')}` (written by `seqmotion lfd collect`)",
        ]
        if seqae:
            reused = f"; reused from `{seqae['reused_from']}`" if seqae.get("reused_from") else ""
            which = f"{seqae.get('motions')} of {seqae.get('of')} demonstrations without images (failed ones left out)"
            if training.get("benchmark") == "hard":  # the CNN pairs the first `demos` with their images
                which = f"{seqae.get('motions')} demonstrations: the hard set's first {training.get('demos')} "
                which += "successful ones (the CNN's pairs)"
                if training.get("extra_motions"):
                    which += " and the hard_motions set's successful motions without images"
            lines.append(
                f"- SeqAE: {which}{reused}; settings "
                f"{json.dumps(seqae.get('settings', {}), sort_keys=True)}; final eq.-5.1 "
                f"loss {seqae.get('final_loss', float('nan')):.4f}"
            )
        if cnn:
            lines.append(
                f"- CNN: {cnn.get('pairs')} of {cnn.get('of')} image–motion pairs (`{cnn.get('dataset')}`), "
                f"{CNN_TARGET_TEXT.get(cnn.get('settings', {}).get('targets', 'pair'), '')}; "
                f"settings {json.dumps(cnn.get('settings', {}), sort_keys=True)}"
            )
        decoder, pose = training.get("feedback_decoder", {}), training.get("pose", {})
        if decoder:
            lines.append(
                f"- Decoder: teacher-forced eq. 5.1 on {decoder.get('demos')} demonstrations of the hard set, its z "
                "slot each step's recorded object features (normalised, with the latent noise); settings "
                f"{json.dumps(decoder.get('settings', {}), sort_keys=True)}; final loss "
                f"{decoder.get('final_loss', float('nan')):.4f}"
            )
        if pose:
            lines.append(
                f"- Pose network: {pose.get('frames')} frames of those demonstrations' recorded states re-rendered "
                "under fresh camera jitter, lighting, colours and distractors (half with the object moved ±1.5 cm and "
                f"turned ±10°); settings {json.dumps(pose.get('settings', {}), sort_keys=True)}; final loss "
                f"{pose.get('final_loss', float('nan')):.4f}; rendering {pose.get('render_seconds', 0):.0f} s"
            )
        if e2e:
            settings = json.dumps(e2e.get("settings", {}), sort_keys=True)
            lines.append(
                f"- End to end: CNN and decoder trained together on {e2e.get('pairs')} of {e2e.get('of')} image–motion "
                f"pairs (`{e2e.get('dataset')}`) with eq. 5.1; settings {settings}; final loss "
                f"{e2e.get('final_loss', float('nan')):.4f}"
            )
        seconds = {
            name: part["seconds"]
            for name, part in (("SeqAE", seqae), ("CNN", cnn), ("end to end", e2e), ("decoder", decoder),
                               ("rendering the pose frames", {"seconds": pose.get("render_seconds")}),
                               ("pose network", pose))
            if part.get("seconds") is not None
        }
        if seconds:
            lines.append(
                "- Wall time: " + ", ".join(f"{name} {s:.0f} s" for name, s in seconds.items())
                + f" (total {sum(seconds.values()) / 60:.1f} min)"
            )
        machine = training.get("machine")
        if isinstance(machine, dict):  # provenance.machine_record() at training time
            where = f" ({machine['platform']})" if machine.get("platform") else ""
            load = machine.get("load_average")
            load_text = f"; load average {[round(x, 2) for x in load]} when training started" if load else ""
            lines.append(f"- Machine: {describe_machine(machine)}{where}{load_text}")
        else:
            lines.append(f"- Machine: {machine or 'not recorded'}")
        return lines

    # -- inference -----------------------------------------------------------------------------
    @torch.no_grad()
    def latent(self, images: Any) -> np.ndarray:
        """ẑ of ``(64, 64, 3)`` → ``(latent,)`` or ``(B, 64, 64, 3)`` → ``(B, latent)`` images (uint8 RGB)."""
        self._one_latent("latent(images)")
        if self.cnn is None:
            raise ValueError("a 'seqae' model has no CNN: it maps motions to z (encode), not images")
        arr = check_images(images)
        z = self.cnn.eval()(torch.as_tensor(arr)).double().numpy()
        return z[0] if np.ndim(images) == 3 else z

    @torch.no_grad()
    def encode(self, motions: Any) -> np.ndarray:
        """z of recorded motions ``(K, 6J)`` → ``(latent,)`` or ``(B, K, 6J)`` → ``(B, latent)`` (20 ms samples)."""
        if self.encoder is None:
            raise ValueError(f"a {self.config.kind!r} policy has no motion encoder (it was trained without one)")
        arr = check_motions(motions, joints=self.seqae_config.joints)
        z = self.encoder(self.scaler.normalize(torch.as_tensor(arr, dtype=torch.float32))).double().numpy()
        return z[0] if np.ndim(motions) == 2 else z

    def source(self, z: Any) -> DecoderSource:
        """A command source for :func:`~seqmotion.lfd.teleop.run_autonomous` decoding latent ``z`` ``(latent,)``."""
        self._one_latent("source(z)")
        return DecoderSource(self, z)

    def feedback_source(self, scene: Any, camera: str | None = None) -> FeedbackSource:
        """A ``feedback`` policy's command source for one episode in ``scene`` (reset it first): every 20 ms it
        renders the webcam (``camera``, default the trained one), estimates the object's pose and decodes."""
        if self.config.kind != "feedback":
            raise ValueError(f"feedback_source is a 'feedback' policy's; this one is {self.config.kind!r}: "
                             "use source(latent(image))")
        return FeedbackSource(self, scene, camera or self.config.camera)

    def run(
        self,
        scene: Any,
        position: Any,
        variation: Any = None,
        camera: str | None = None,
        duration: float = 4.0,
        latent: Any = None,
    ) -> tuple[Any, np.ndarray, np.ndarray]:
        """One closed-loop episode: reset the scene, take the image, ẑ = CNN(image), decode at 20 ms.

        Args:
            scene: a :class:`seqmotion.sim.pushing.PushingScene`.
            position: a :class:`~seqmotion.sim.pushing.BlockPosition`.
            variation: a :class:`~seqmotion.sim.pushing.SceneVariation` (none if omitted).
            camera: webcam pose (default: the one the CNN was trained on).
            duration: episode length [s].
            latent: decode this z ``(latent,)`` instead of the CNN's ẑ (a diagnostic: with the
                demonstrations' own z it measures the decoder alone).

        Returns:
            ``(AutonomousRun, image (64, 64, 3) uint8, z (latent,))``.
        """
        from ..sim.pushing import SceneVariation
        from .teleop import run_autonomous

        variation = variation or SceneVariation()
        scene.reset(position, variation)
        image = scene.render(camera or self.config.camera)
        if self.config.kind == "feedback":
            if latent is not None:
                raise ValueError("a 'feedback' policy decodes the object features it sees every step: it takes no "
                                 "latent")
            source = self.feedback_source(scene, camera)
            run = run_autonomous(
                scene, source, position, duration, variation, self.config.command_interval, reset=False
            )
            return run, image, source.first_features
        z = self.latent(image) if latent is None else np.asarray(latent, dtype=np.float64)
        if z.shape != (self.seqae_config.latent,):
            raise ValueError(f"latent must have shape ({self.seqae_config.latent},), got {z.shape}")
        run = run_autonomous(
            scene, self.source(z), position, duration, variation, self.config.command_interval, reset=False
        )
        return run, image, z


class DecoderSource:
    """The decoder as a master stand-in: ``source(t, slave_state) → ArmState`` with its LSTM state.

    One instance per episode. It must be called at t = 0, Δt_NN, 2 Δt_NN, … (as
    :func:`~seqmotion.lfd.teleop.run_autonomous` does); a skipped or repeated call would
    desynchronise the recurrent state from the time steps it was trained on, so it is refused.
    The simulated slave is the 3-joint arm: a SeqAE of another joint count is refused.
    """

    def __init__(self, policy: PushingPolicy, z: Any) -> None:
        require_arm(policy.seqae_config, "the closed-loop decoder")
        z_arr = np.asarray(z, dtype=np.float64)
        latent = policy.seqae_config.latent
        if z_arr.shape != (latent,) or not np.all(np.isfinite(z_arr)):
            raise ValueError(f"z must be {latent} finite numbers, got shape {z_arr.shape}")
        self.policy = policy
        self.z = torch.as_tensor(z_arr, dtype=torch.float32)[None]
        self.interval = policy.config.command_interval
        self.state: tuple[torch.Tensor, torch.Tensor] | None = None
        self.calls = 0

    @torch.no_grad()
    def __call__(self, t: float, slave_state: Any) -> Any:
        from .teleop import ArmState

        expected = self.calls * self.interval
        if abs(t - expected) > 1e-6:
            raise ValueError(
                f"decoder called at t = {t:.4f} s, expected {expected:.4f} s (one call per "
                f"{self.interval * 1000:g} ms from t = 0; use a fresh source per episode)"
            )
        self.calls += 1
        s = torch.as_tensor(slave_state.as_vector(), dtype=torch.float32)[None, None]
        p = self.policy
        slave_n = p.scaler.normalize(s, SLAVE)
        out, self.state = p.decoder(self.latent_now(slave_state), slave_n, self.state)
        m = p.scaler.denormalize(out, MASTER)[0, 0].double().numpy()
        return ArmState(m[0:3], m[3:6], m[6:9])

    def latent_now(self, slave_state: Any) -> torch.Tensor:
        """What the decoder's z slot reads at this step ``(1, latent)``: the episode's one z."""
        return self.z


class FeedbackSource(DecoderSource):
    """A ``feedback`` policy's command source: the same decoder step, its z slot the object features seen now.

    Every call renders the scene's webcam, estimates the object's ``x, y``, shape and yaw with the
    policy's :class:`PoseNet` (given the pen tip from the slave's measured angles) and feeds the
    normalised :func:`object_features` to the decoder. The side and the shape are the mean of the
    first ``opening_frames`` estimates, then held (:class:`PoseNetConfig`).

    Attributes:
        first_features: the features ``(5,)`` of the first step (unnormalised; :data:`FEATURES`).
        estimates: every step's raw estimate ``(4,)`` (x, y [m], P(box), yaw [rad]).
    """

    def __init__(self, policy: PushingPolicy, scene: Any, camera: str) -> None:
        super().__init__(policy, np.zeros(policy.seqae_config.latent))
        self.scene, self.camera = scene, camera
        self.opening = int(policy.config.pose.get("opening_frames", PoseNetConfig.opening_frames))
        self.side_shape: tuple[float, float] | None = None
        self.first_features = np.full(len(FEATURES), np.nan)
        self.estimates: list[np.ndarray] = []

    @staticmethod
    def _side_shape(estimate: np.ndarray) -> tuple[float, float]:
        """An estimate's side sign (+1 left: y > 0) and is-box (P(box) > 0.5) as the features' values."""
        return (1.0 if estimate[1] > 0 else -1.0, 1.0 if estimate[2] > 0.5 else 0.0)

    def latent_now(self, slave_state: Any) -> torch.Tensor:
        from ..sim.pushing import forward_kinematics

        p = self.policy
        assert p.pose_net is not None
        estimate = p.pose_net.estimate(self.scene.render(self.camera), forward_kinematics(slave_state.theta)[:2])
        if not np.all(np.isfinite(estimate)):
            raise ValueError(f"the pose network's estimate is not finite ({estimate}): the policy's weights are broken")
        self.estimates.append(estimate)
        if self.side_shape is None and len(self.estimates) == self.opening:  # the object has not moved yet
            self.side_shape = self._side_shape(np.mean(self.estimates, 0))
        sign, box = self.side_shape or self._side_shape(estimate)
        features = np.array([sign, sign * estimate[1], estimate[0], box, box * estimate[3]])
        if len(self.estimates) == 1:
            self.first_features = features
        c = torch.as_tensor(features, dtype=torch.float32)
        return ((c - p.feature_mean) / p.feature_std)[None]
