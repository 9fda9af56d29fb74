"""Chapter-5 networks and their typed configs: the sequence autoencoder (SeqAE), the image CNN, the keypoint PoseNet.

Data conventions (dissertation 5.2.1 and 5.3.4). A motion is sampled every Δt_NN = 20 ms;
sample k holds 6J columns (:data:`seqmotion.lfd.env.teleop.MOTION_COLUMNS` for the arm): master θ,
θ̇, τ, then slave θ, θ̇, τ, each over the J joints [rad, rad/s, N m]. J is
:attr:`SeqAEConfig.joints`: 3 for the dissertation's arm (the default, and every shipped
model), another robot's joint count when the SeqAE is trained on its LeRobot dataset; the
shapes below are written for J = 3 (18 = 6J columns, 9 = 3J state or command values).

* **Encoder** — a stacked LSTM reads the whole motion ``(B, K, 18)``; a linear layer maps the
  last layer's final hidden state to the latent ``z`` ``(B, 8)``.
* **Decoder** — a stacked LSTM that, at step k, reads ``z`` and the slave's measured state
  ``s[k]`` (θ, θ̇, τ: 9) and emits the master command for the next step ``m̂[k+1]`` (θ, θ̇, τ:
  9). In closed loop (the 3-joint arm only) it is called every 20 ms by
  :func:`seqmotion.lfd.rollout.rollout` and its recurrent state carries the history; in
  training it is teacher-forced on the recorded slave states (as in the dissertation).
* **CNN** — five stride-2 convolutions, each followed by ReLU and BatchNorm (that order, as
  the dissertation states), then a linear layer: a 64 × 64 RGB image → ``ẑ`` ``(B, 8)``.
* **Policy** — the CNN in the encoder's place in front of the decoder (Fig. 5.2):
  :class:`seqmotion.lfd.policy.policy.PushingPolicy` (which also holds the end-to-end baseline).
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

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ...errors import check_number

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


def check_positive_integers(config: Any, names: tuple[str, ...]) -> None:
    """``ValueError`` unless each named field of ``config`` is a positive plain ``int`` (a config is saved as JSON)."""
    for name in names:
        value = getattr(config, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{type(config).__name__}.{name} must be a positive integer, got {value!r}")


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
        check_positive_integers(self, ("layers", "hidden", "latent", "joints"))

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
        if len(self.channels) != 5:
            raise ValueError(f"CNNConfig.channels must be five positive integers, got {self.channels!r}")
        object.__setattr__(self, "channels", tuple(int(check_number("CNNConfig.channels", c, minimum=1, integer=True))
                                                   for c in self.channels))
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
        check_positive_integers(self, ("keypoints", "width", "opening_frames"))


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
