"""Training the chapter-5 models (dissertation 5.2.1 and 5.3.4).

Three procedures, each seeded and deterministic on a given machine and thread count:

1. :func:`train_seqae` — the SeqAE on motions without images (the 90 demonstrations, or the
   motions of another robot: the SeqAE's joint count J is the data's),
   teacher-forced, loss eq. 5.1 (:func:`~seqmotion.lfd.policy.networks.motion_loss`), Adam, mini-batches of 16.
2. :func:`train_cnn` — the CNN on image–motion pairs (18 per camera): target = the trained
   encoder's z of the paired motion, loss ``|z − ẑ|²`` (eq. 5.2), Adam, mini-batches of 8, 100 epochs.
3. :func:`train_end_to_end` — the baseline: the same CNN and decoder trained together on the
   18 pairs with eq. 5.1 (2000 epochs in the dissertation).

:func:`train` runs them from the dataset directory written by ``seqmotion lfd collect`` and
writes policy directories (``<method>_<camera>/``) loadable with ``sm.load``.

Beyond the dissertation (all switchable; defaults in :class:`SeqAETraining` and :class:`CNNTraining`;
the end-to-end baseline gets the same settings, so the comparison stays like for like; how each was
chosen, with the closed-loop success rates, is in ``benchmarks/RESULTS_lfd.md``):

* **Noise injection** on the decoder's *inputs* (the slave states; white Gaussian, σ = 0.3 in
  normalised units) while the targets stay the recorded master states. With plain teacher
  forcing the decoder learns to copy the slave (the master leads it by a few hundredths of a
  radian), ignores z and, in closed loop, wanders off in the wrong direction; with noise it must
  use z and its own memory, and it learns to steer back towards the demonstration from states
  slightly off it.
* **Latent noise**: Gaussian noise (σ = 0.1) on z while decoding, so that z's near a
  demonstration's decode to similar motions (the CNN's ẑ is never exact: 18 images, 2–3 per
  position). An optional penalty ``β · ½ |z|²`` (off by default) turns it into a VAE with a
  fixed posterior spread (it did not help the closed loop).
* **Photometric augmentation** of the CNN's training images (brightness, colour gain, offset,
  pixel noise; never geometry).
* Failed demonstrations (``success = False``, 3 of 90 in the default set) are left out.
* Gradient-norm clipping at 1 and a cosine learning-rate decay to 10 % over the run.
* Checkpoints and exact resume of the long trainings (SeqAE, end-to-end baseline).
* Epochs per preset (:data:`SEQAE_EPOCHS`, :func:`default_settings`): the dissertation's 2000
  for the ``smaller`` and ``original`` SeqAE, 1200 for ``larger``; 2000 for the end-to-end
  baseline of every size, as in the dissertation.

All three run on the library's one optimisation loop,
:class:`~seqmotion.training.loop.TrainingLoop` (Adam, the learning-rate schedule, clipping,
checkpoints, resume, ``metrics.csv``); this module adds the epochs over the demonstrations,
the losses and the noise.

:data:`DEFAULT_PRESET` is the size ``seqmotion lfd train`` uses by default and the shipped
policy's; see its docstring for why it is not the dissertation's 7-layer model.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import check_finite_array, check_number
from ..io import atomic_write_bytes
from ..training.provenance import machine_record
from .data.frames import POSE_FRAMES as POSE_FRAMES
from .data.frames import render_pose_frames as render_pose_frames
from .data.slicing import concatenate, mean_latent_per_position, subset, usable_episodes
from .fitting import CHECKPOINT_EVERY as CHECKPOINT_EVERY  # the settings and the loop, re-exported where users
from .fitting import CNN_TARGETS as CNN_TARGETS  # have always found them (seqmotion.lfd.train.X)
from .fitting import DEFAULT_PRESET as DEFAULT_PRESET
from .fitting import E2E_EPOCHS as E2E_EPOCHS
from .fitting import SEQAE_EPOCHS as SEQAE_EPOCHS
from .fitting import CNNTraining as CNNTraining
from .fitting import SeqAETraining as SeqAETraining
from .fitting import augment_images as augment_images
from .fitting import default_settings as default_settings
from .fitting import fit as fit
from .fitting import seeded_generator
from .fitting import state_noise as state_noise
from .policy.networks import (
    FEATURES,
    CNNConfig,
    ImageEncoder,
    PoseNet,
    PoseNetConfig,
    SeqAE,
    SeqAEConfig,
    check_images,
    check_motions,
    motion_loss,
    object_features,
    preset,
)
from .policy.policy import PolicyConfig, PushingPolicy


def finite_shaped(name: str, values: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``values`` as a float64 array of finite numbers of ``shape``; ``ValueError`` naming ``name`` otherwise."""
    arr = check_finite_array(name, values)
    if arr.shape != shape:
        raise ValueError(f"{name} must be finite and shaped {shape}, got {arr.shape}")
    return arr


def train_seqae(
    motions: np.ndarray,
    config: SeqAEConfig,
    settings: SeqAETraining | None = None,
    progress: bool = False,
    checkpoint_dir: str | Path | None = None,
    resume: bool = True,
) -> tuple[SeqAE, dict]:
    """Train a SeqAE on motions ``(N, K, 6J)`` sampled every 20 ms (raw units), J = ``config.joints``.

    ``checkpoint_dir``: write resumable checkpoints there and continue from one found there (``resume``;
    False: remove them and start over).

    Returns:
        ``(model in eval mode, history)`` with ``history = {"loss": [per-epoch mean eq.-5.1 loss],
        "seconds": wall time}``.
    """
    settings = settings or SeqAETraining()
    motions = check_motions(motions, joints=config.joints)
    if len(motions) < 2:
        raise ValueError(f"need at least 2 motions to train a SeqAE, got {len(motions)}")
    gen = seeded_generator(settings.seed)
    model = SeqAE(config)
    model.scaler.fit(motions)
    data = torch.as_tensor(motions, dtype=torch.float32)
    params = [p for p in model.parameters() if p.requires_grad]
    history = fit(model, params, len(data), settings, gen,
                   lambda idx: _seqae_loss(model, data[idx], settings, gen),
                   f"SeqAE {config.layers}x{config.hidden}", progress,
                   checkpoint_dir=checkpoint_dir, data=(motions,), resume=resume, part="seqae")
    return model.eval(), history


def _seqae_loss(model: SeqAE, batch: torch.Tensor, settings: SeqAETraining, gen: torch.Generator) -> torch.Tensor:
    """Eq. 5.1 of the teacher-forced reconstruction, with the optional input and latent noise."""
    z = model.encode(batch)
    penalty = 0.5 * settings.latent_penalty * (z**2).sum(-1).mean() if settings.latent_penalty > 0 else 0.0
    if settings.latent_noise > 0:
        z = z + settings.latent_noise * torch.randn(z.shape, generator=gen)
    slave = batch[:, :-1, model.config.slave]
    command, _ = model.decode(z, slave, slave_noise=state_noise(tuple(slave.shape), settings, gen))
    return motion_loss(command, batch[:, 1:, model.config.master], model.scaler.variance) + penalty


@torch.no_grad()
def encode_motions(model: SeqAE, motions: np.ndarray) -> np.ndarray:
    """z ``(N, latent)`` of motions ``(N, K, 6J)`` with a trained SeqAE."""
    model.eval()
    arr = check_motions(motions, joints=model.config.joints)
    return model.encode(torch.as_tensor(arr, dtype=torch.float32)).double().numpy()


def train_cnn(
    images: np.ndarray,
    targets: np.ndarray,
    config: CNNConfig | None = None,
    settings: CNNTraining | None = None,
    progress: bool = False,
) -> tuple[ImageEncoder, dict]:
    """Fit the CNN so that ``CNN(images[i]) ≈ targets[i]`` (eq. 5.2).

    Args:
        images: ``(N, 64, 64, 3)`` uint8.
        targets: ``(N, latent)`` the encoder's z of the paired motions.

    Returns:
        ``(CNN in eval mode, {"loss": per-epoch mean |z − ẑ|², "seconds"})``.
    """
    config = config or CNNConfig()
    settings = settings or CNNTraining()
    images = check_images(images)
    targets = finite_shaped("targets", targets, (len(images), config.latent))
    if len(images) < 2:
        raise ValueError(f"need at least 2 images to train the CNN (BatchNorm), got {len(images)}")
    gen = seeded_generator(settings.seed)
    cnn = ImageEncoder(config)
    x, y = torch.as_tensor(images), torch.as_tensor(targets, dtype=torch.float32)

    def batch_loss(idx: torch.Tensor) -> torch.Tensor:
        batch = augment_images(x[idx], gen) if settings.augment else x[idx]
        return ((cnn(batch) - y[idx]) ** 2).sum(-1).mean()

    # BatchNorm cannot normalise a batch of one: a last mini-batch of one image is skipped
    history = fit(cnn, list(cnn.parameters()), len(x), settings, gen, batch_loss, "CNN", progress, min_batch=2,
                   part="cnn")
    return cnn.eval(), history


def train_end_to_end(
    images: np.ndarray,
    motions: np.ndarray,
    config: SeqAEConfig,
    settings: SeqAETraining | None = None,
    cnn_config: CNNConfig | None = None,
    camera: str = "default",
    preset_name: str = "",
    progress: bool = False,
    checkpoint_dir: str | Path | None = None,
    resume: bool = True,
) -> tuple[PushingPolicy, dict]:
    """The baseline: CNN → z → decoder trained together on image–motion pairs with eq. 5.1.

    Same layers and the same optimisation settings (noise injection included) as the
    proposed method; mini-batches of ``settings.batch_size`` pairs. ``checkpoint_dir`` and ``resume`` as in
    :func:`train_seqae`.
    """
    settings = settings or SeqAETraining()
    cnn_config = cnn_config or CNNConfig(latent=config.latent)
    images, motions = check_images(images), check_motions(motions, joints=config.joints)
    if len(images) != len(motions):
        raise ValueError(f"{len(images)} images but {len(motions)} motions: pairs must match")
    if len(images) < 2:
        raise ValueError(f"need at least 2 pairs for end-to-end training, got {len(images)}")
    gen = seeded_generator(settings.seed)
    seqae = SeqAE(config)
    seqae.scaler.fit(motions)
    policy = PushingPolicy(
        PolicyConfig("end_to_end", preset_name, asdict(config), asdict(cnn_config), camera),
        seqae,
        ImageEncoder(cnn_config),
    )
    x = torch.as_tensor(images)
    data = torch.as_tensor(motions, dtype=torch.float32)

    def batch_loss(idx: torch.Tensor) -> torch.Tensor:
        z = policy.cnn(x[idx])
        penalty = 0.5 * settings.latent_penalty * (z**2).sum(-1).mean() if settings.latent_penalty > 0 else 0.0
        if settings.latent_noise > 0:
            z = z + settings.latent_noise * torch.randn(z.shape, generator=gen)
        batch = data[idx]
        slave = batch[:, :-1, config.slave]
        noise = state_noise(tuple(slave.shape), settings, gen)
        slave_n = policy.scaler.normalize(slave, config.slave) + (0 if noise is None else noise)
        out, _ = policy.decoder(z, slave_n)
        loss = motion_loss(policy.scaler.denormalize(out, config.master), batch[:, 1:, config.master],
                           policy.scaler.variance)
        return loss + penalty

    # BatchNorm in the CNN needs two images per batch
    history = fit(policy, list(policy.parameters()), len(data), settings, gen, batch_loss,
                   f"end-to-end {config.layers}x{config.hidden}", progress, min_batch=2,
                   checkpoint_dir=checkpoint_dir, data=(images, motions), resume=resume, part="end_to_end")
    return policy.eval(), history


# ----------------------------------------------------------------------------------------------
# Object feedback (kind "feedback", hard benchmark; beyond the dissertation)
# ----------------------------------------------------------------------------------------------


def pose_training(seed: int = 0) -> CNNTraining:
    """The pose network's default settings: 12 epochs of 64 frames, Adam at 2e-3 decaying to 2 % (cosine).

    (``targets`` is the CNN's notion and means nothing here; each frame's target is its own pose.)
    """
    return CNNTraining(epochs=12, batch_size=64, lr=2e-3, lr_final_fraction=0.02, targets="pair", seed=seed)


def train_pose_net(
    images: np.ndarray, tips: np.ndarray, targets: np.ndarray, config: PoseNetConfig | None = None,
    settings: CNNTraining | None = None, progress: bool = False, checkpoint_dir: str | Path | None = None,
    resume: bool = True,
) -> tuple[PoseNet, dict]:
    """Fit the :class:`PoseNet` to frames ``(N, 64, 64, 3)``, pen tips ``(N, 2)`` [m] and targets ``(N, 4)``.

    Loss per frame: the squared position error [cm²], the shape's cross-entropy and, for a box,
    the yaw error with 0.2 rad weighing as 1 cm. Photometric augmentation as the CNN's
    (``settings.augment``). ``checkpoint_dir`` and ``resume`` as in :func:`train_seqae`.
    """
    settings = settings or pose_training()
    images = check_images(images)
    tips = finite_shaped("tips", tips, (len(images), 2)).astype(np.float32)
    targets = finite_shaped("targets", targets, (len(images), 4)).astype(np.float32)
    gen = seeded_generator(settings.seed)
    net = PoseNet(config)
    x, tip, y = torch.as_tensor(images), torch.as_tensor(tips), torch.as_tensor(targets)

    def batch_loss(idx: torch.Tensor) -> torch.Tensor:
        batch = augment_images(x[idx], gen) if settings.augment else x[idx]
        out, t = net(batch, tip[idx]), y[idx]
        position = ((out[:, :2] - t[:, :2]) ** 2).sum(-1)  # [cm²]
        shape = torch.nn.functional.binary_cross_entropy_with_logits(out[:, 2], t[:, 2], reduction="none")
        yaw = t[:, 2] * ((out[:, 3] - t[:, 3]) / 0.2) ** 2  # a box's yaw: 0.2 rad weighs as 1 cm
        return (position + shape + yaw).mean()

    history = fit(net, list(net.parameters()), len(x), settings, gen, batch_loss, "pose network", progress,
                   checkpoint_dir=checkpoint_dir, data=(images, tips, targets), resume=resume, part="pose")
    return net.eval(), history


def train_feedback_decoder(
    motions: np.ndarray, features: np.ndarray, config: SeqAEConfig, settings: SeqAETraining | None = None,
    progress: bool = False, checkpoint_dir: str | Path | None = None, resume: bool = True,
) -> tuple[SeqAE, np.ndarray, np.ndarray, dict]:
    """Teacher-forced eq.-5.1 training of a decoder whose z slot reads each step's object features.

    Args:
        motions: ``(N, K, 18)`` at 20 ms (raw units).
        features: ``(N, K, 5)`` the recorded object's :func:`~seqmotion.lfd.policy.networks.object_features` at the
            same samples.
        config: the decoder's shape (``latent`` must be 5).
        settings: as the SeqAE's; ``latent_noise`` is added to the (normalised) features, ``state_noise``
            to the slave states.

    Returns:
        ``(model, feature mean (5,), feature std (5,), history)``: the model's scaler and decoder are
        trained (its motion encoder is not used).
    """
    settings = settings or SeqAETraining()
    motions = check_motions(motions, joints=config.joints)
    if config.latent != len(FEATURES):
        raise ValueError(f"the feedback decoder's z slot holds the {len(FEATURES)} features {FEATURES}; "
                         f"config.latent is {config.latent}")
    features = finite_shaped("features", features, (*motions.shape[:2], len(FEATURES)))
    if len(motions) < 2:
        raise ValueError(f"need at least 2 demonstrations to train the decoder, got {len(motions)}")
    mean = features.reshape(-1, len(FEATURES)).mean(0)
    std = features.reshape(-1, len(FEATURES)).std(0)
    std = np.where(std < 1e-3, 1.0, std)  # a feature constant in training (one side, one shape) is left unscaled
    gen = seeded_generator(settings.seed)
    model = SeqAE(config)
    model.scaler.fit(motions)
    data = torch.as_tensor(motions, dtype=torch.float32)
    c_all = torch.as_tensor((features - mean) / std, dtype=torch.float32)

    def batch_loss(idx: torch.Tensor) -> torch.Tensor:
        batch, c = data[idx], c_all[idx, :-1]
        if settings.latent_noise > 0:
            c = c + settings.latent_noise * torch.randn(c.shape, generator=gen)
        slave = batch[:, :-1, config.slave]
        command, _ = model.decode(c, slave, slave_noise=state_noise(tuple(slave.shape), settings, gen))
        return motion_loss(command, batch[:, 1:, config.master], model.scaler.variance)

    history = fit(model, list(model.decoder.parameters()), len(data), settings, gen, batch_loss,
                   f"feedback decoder {config.layers}x{config.hidden}", progress, checkpoint_dir=checkpoint_dir,
                   data=(motions, features), resume=resume, part="feedback_decoder")
    return model.eval(), mean, std, history


def train_feedback(
    data: Any, config: SeqAEConfig, settings: SeqAETraining, pose_settings: CNNTraining, pose_frames: int,
    workers: int, progress: bool, checkpoints: Path, resume: bool, preset_name: str = "",
) -> tuple[PushingPolicy, dict[str, Any], dict[str, Any]]:
    """A ``feedback`` policy from a hard set's demonstrations ``data``: the decoder, then the pose network.

    Returns ``(policy, decoder history, pose history)`` (the pose history adds ``render_seconds``).
    """
    import time

    from .timing import samples_per_command

    motions = data.motion()
    sign = np.where(np.asarray(data.episodes["side"]).astype(str) == "left", 1.0, -1.0)
    is_box = (np.asarray(data.episodes["shape"]).astype(str) == "box").astype(float)
    pose = data.motions["block_pose"][:, :: samples_per_command(data.dt)]
    features = object_features(sign[:, None], is_box[:, None], pose)
    config = replace(config, latent=len(FEATURES), readout="top", normalize_latent=False)
    model, mean, std, decoder_history = train_feedback_decoder(
        motions, features, config, settings, progress, checkpoints / "feedback_decoder", resume)
    start = time.perf_counter()
    images, tips, targets = render_pose_frames(data, pose_frames, pose_settings.seed, workers)
    render_seconds = time.perf_counter() - start
    pose_config = PoseNetConfig()
    net, pose_history = train_pose_net(images, tips, targets, pose_config, pose_settings, progress,
                                       checkpoints / "feedback_pose", resume)
    pose_history["render_seconds"] = render_seconds
    policy = PushingPolicy(
        PolicyConfig("feedback", preset_name, asdict(config), asdict(CNNConfig()), pose=asdict(pose_config)),
        model, net,
    )
    policy.feature_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
    policy.feature_std.copy_(torch.as_tensor(std, dtype=torch.float32))
    return policy.eval(), decoder_history, pose_history


# ----------------------------------------------------------------------------------------------
# From a dataset directory to policy directories
# ----------------------------------------------------------------------------------------------
METHODS = ("proposed", "end_to_end", "seqae", "feedback")
"""``proposed`` (SeqAE, then a CNN per camera), ``end_to_end`` (the baseline), ``seqae`` (the SeqAE
alone, written to ``out/seqae/``: for motions without the images or block positions a CNN needs),
``feedback`` (hard benchmark: a decoder reading the object's features every step and the pose
network that estimates them, :func:`train_feedback`; written to ``out/feedback_default/``)."""


@dataclass
class TrainReport:
    """What :func:`train` wrote: ``{name: directory}`` and per-part wall times [s]."""

    out: Path
    policies: dict[str, Path] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    final_loss: dict[str, float] = field(default_factory=dict)


def train(
    data_dir: str | Path,
    out: str | Path,
    preset_name: str = DEFAULT_PRESET,
    methods: tuple[str, ...] = ("proposed",),
    cameras: tuple[str, ...] = ("default",),
    seed: int = 0,
    seqae_settings: SeqAETraining | None = None,
    e2e_settings: SeqAETraining | None = None,
    cnn_settings: CNNTraining | None = None,
    seqae_from: str | Path | None = None,
    progress: bool = True,
    command: str | None = None,
    successful_only: bool = True,
    resume: bool = True,
    mapping: Mapping[str, str] | None = None,
    benchmark: str = "chapter",
    demos: int | None = None,
    extra_motions: bool = False,
    pose_settings: CNNTraining | None = None,
    pose_frames: int = POSE_FRAMES,
    workers: int = 1,
) -> TrainReport:
    """Train policies from ``data_dir`` (``motions.h5``, ``pairs_<camera>.h5``) into ``out/<method>_<camera>/``.

    The SeqAE's joint count J (:attr:`~seqmotion.lfd.policy.networks.SeqAEConfig.joints`) is the data's:
    3 for seqmotion's arm, another robot's count for its LeRobot dataset (whose models cannot run
    the closed loop in MuJoCo, which is the 3-joint arm's).

    Args:
        data_dir: written by ``seqmotion lfd collect``, or LeRobot v3.0 datasets (see :func:`_open_set`).
        out: output directory.
        preset_name: SeqAE size (``original``, ``larger``, ``smaller``).
        methods: any of :data:`METHODS`: ``"proposed"``, ``"end_to_end"``, ``"seqae"`` (the SeqAE
            alone, into ``out/seqae/``; it needs the motions only).
        cameras: which image–motion sets to train on (``default``, ``position1``, ``position2``).
            The proposed method trains one SeqAE and one CNN per camera (the SeqAE reused).
        seed: seeds everything (overrides the settings' seeds).
        seqae_settings, e2e_settings, cnn_settings: optimisation settings (defaults:
            :func:`default_settings` of the preset).
        seqae_from: reuse the SeqAE of this proposed-policy directory instead of training one
            (the camera-moved experiment: only the CNN is retrained; position-wise CNN targets
            are still taken over ``data_dir``'s motions).
        progress: tqdm bars on stderr.
        command: the command line that started the run (recorded in each config).
        successful_only: leave failed demonstrations out (default); False keeps every episode.
        resume: continue the SeqAE and end-to-end trainings from their checkpoints in
            ``out/checkpoints/`` (written every :data:`CHECKPOINT_EVERY` epochs) when there are
            some; False has each training this run does remove its own and start over.
        mapping: ``{field: feature key}`` for LeRobot folders (``--map``, see
            :func:`seqmotion.lfd.data.lerobot_import.from_lerobot`): another robot's feature names.
        benchmark: ``"hard"`` trains every method on the same demonstrations, the ``hard`` set's
            (``hard.h5``), with their images (default camera): the SeqAE on their motions, the CNN
            on their image–motion pairs.
        demos: hard benchmark: train on the set's first ``demos`` usable (successful)
            demonstrations (the data-efficiency curve's 10, 25, 50, 100); default all.
        extra_motions: hard benchmark: the SeqAE also trains on the ``hard_motions`` set's usable
            demonstrations (motions without images, as the chapter's SeqAE trains on 90 motions and
            its CNN on 18 pairs); the CNN still pairs the ``demos`` images with their own z.
        pose_settings, pose_frames, workers: method ``feedback``: the pose network's settings (default
            :func:`pose_training`), how many frames it trains on and how many processes render them
            (``workers`` > 1 spawns them: a script calling this needs the ``if __name__ == "__main__":``
            guard). Its decoder takes ``seqae_settings`` and the preset's layers and width.
    """
    data_dir, out = Path(data_dir), Path(out)
    seed = check_number("seed", seed, minimum=0, integer=True)
    config = preset(preset_name)
    methods = tuple(methods)
    if not methods or any(m not in METHODS for m in methods):
        raise ValueError(f"methods must be a non-empty subset of {METHODS}, got {methods!r}")
    if "seqae" in methods and seqae_from is not None:
        raise ValueError("methods 'seqae' trains a SeqAE and seqae_from (--seqae-from) reuses one: pass one of them")
    from .env.pushing import CAMERAS

    if not cameras or any(c not in CAMERAS for c in cameras):
        raise ValueError(f"cameras must be a non-empty subset of {sorted(CAMERAS)}, got {cameras!r}")
    if benchmark not in ("chapter", "hard"):
        raise ValueError(f"unknown benchmark {benchmark!r}; choose 'chapter' or 'hard'")
    hard = benchmark == "hard"
    if "feedback" in methods and not hard:
        raise ValueError("method 'feedback' reads the object's pose every step, which the hard benchmark's "
                         "demonstrations record with the scene variation it renders: pass benchmark='hard'")
    if demos is not None and not hard:
        raise ValueError("demos picks the hard set's first demonstrations; the chapter's sets are fixed (5.3.3)")
    if hard and tuple(cameras) != ("default",):
        raise ValueError(f"the hard set is filmed from the default camera only, got cameras {cameras!r}")
    defaults = default_settings(preset_name, benchmark)
    seqae_settings = _with_seed(seqae_settings or defaults[0], seed)
    e2e_settings = _with_seed(e2e_settings or defaults[1], seed)
    cnn_settings = _with_seed(cnn_settings or defaults[2], seed)
    if hard and cnn_settings.targets != "pair":
        raise ValueError(f"the hard benchmark has no block positions for the CNN targets {cnn_settings.targets!r}: "
                         "use 'pair' (each image's own demonstration's z)")
    # the SeqAE alone needs motions only; a CNN (proposed, end to end) needs the image-motion pairs
    needs_pairs = "proposed" in methods or "end_to_end" in methods
    needs_motions = "proposed" in methods or "seqae" in methods
    if hard:  # one set of demonstrations, with images, for every method
        hard_data = _open_set(data_dir, "hard", mapping)
        usable = usable_episodes(hard_data, successful_only)
        if demos is not None:
            demos = check_number("demos", demos, minimum=2, integer=True)
            if demos > len(usable):
                raise ValueError(f"{hard_data.path} has {len(usable)} usable demonstrations, fewer than demos={demos}")
            usable = usable[:demos]
        hard_data = subset(hard_data, usable)
        pairs = {"default": hard_data} if needs_pairs else {}
        motions_data = hard_data if needs_motions else None
        if extra_motions and needs_motions:
            more = _open_set(data_dir, "hard_motions", mapping)
            motions_data = concatenate(hard_data, subset(more, usable_episodes(more, successful_only)))
    elif extra_motions:
        raise ValueError("extra_motions adds the hard benchmark's motions: pass benchmark='hard'")
    else:
        pairs = {c: _open_set(data_dir, f"pairs_{c}", mapping) for c in cameras} if needs_pairs else {}
        motions_data = _open_set(data_dir, "motions", mapping) if needs_motions else None
    config = replace(config, joints=_joint_count({"motions": motions_data, **pairs,
                                                  **({"hard": hard_data} if hard else {})}))

    report = TrainReport(out)
    checkpoints = out / "checkpoints"
    record = {"command": command, "seed": seed, "data_dir": str(data_dir), "machine": machine_record(),
              "benchmark": benchmark, **({"demos": len(hard_data), "extra_motions": extra_motions} if hard else {})}

    if needs_motions:
        keep_motions = usable_episodes(motions_data, successful_only)
        motions = motions_data.motion(episodes=keep_motions)  # trains the SeqAE and/or sets the CNN's targets
        unplaced = motions_data.episodes["position_index"][keep_motions] < 0
        if "proposed" in methods and cnn_settings.targets != "pair" and np.any(unplaced):
            # before the long SeqAE training: another robot's dataset has no block positions
            raise ValueError(
                f"{motions_data.path}: {int(unplaced.sum())} demonstration(s) have no block position (not recorded "
                f"by seqmotion), which the CNN's targets {cnn_settings.targets!r} need: pass --cnn-targets pair, or "
                "--methods seqae to train the SeqAE alone"
            )
        if seqae_from is not None:
            donor = PushingPolicy.from_pretrained(seqae_from)
            seqae = donor.seqae()
            if donor.config.preset and donor.config.preset != preset_name:
                raise ValueError(f"{seqae_from} holds a {donor.config.preset!r} SeqAE, not {preset_name!r}")
            if seqae.config.joints != config.joints:
                raise ValueError(f"{seqae_from} holds a SeqAE of {seqae.config.joints} joints; {data_dir}'s motions "
                                 f"have {config.joints}")
            seqae_record = {"reused_from": str(seqae_from), **donor.config.training.get("seqae", {})}
        else:
            seqae, history = train_seqae(motions, config, seqae_settings, progress, checkpoints / "seqae", resume)
            seqae_record = _record(
                report, "seqae", seqae_settings, history, motions=int(len(keep_motions)), of=len(motions_data)
            )

    if "seqae" in methods:
        alone = PushingPolicy(
            PolicyConfig("seqae", preset_name, asdict(config), asdict(CNNConfig(latent=config.latent)),
                         training={**record, "seqae": seqae_record}),
            seqae,
        )
        report.policies["seqae"] = alone.save_pretrained(out / "seqae")

    if "proposed" in methods:
        if cnn_settings.targets != "pair":
            position_z = mean_latent_per_position(
                encode_motions(seqae, motions),
                motions_data.episodes["position_index"][keep_motions],
                medoid=cnn_settings.targets == "position_medoid",
            )
        for camera, data in pairs.items():
            keep = usable_episodes(data, successful_only)
            if cnn_settings.targets == "pair":
                targets = encode_motions(seqae, data.motion(episodes=keep))
            else:
                targets = position_z[data.episodes["position_index"][keep]]
            cnn, history = train_cnn(
                data.images[keep], targets, CNNConfig(latent=config.latent), cnn_settings, progress
            )
            cnn_record = _record(
                report, f"cnn_{camera}", cnn_settings, history, pairs=int(len(keep)), of=len(data),
                dataset=str(data.path),
            )
            training = {**record, "seqae": seqae_record, "cnn": cnn_record}
            policy = PushingPolicy(
                PolicyConfig(
                    "proposed",
                    preset_name,
                    asdict(config),
                    asdict(CNNConfig(latent=config.latent)),
                    camera,
                    training=training,
                ),
                seqae,
                cnn,
            )
            report.policies[f"proposed_{camera}"] = policy.save_pretrained(out / f"proposed_{camera}")

    if "feedback" in methods:
        pose_settings = _with_seed(pose_settings or pose_training(), seed)
        policy, decoder_history, pose_history = train_feedback(
            hard_data, config, seqae_settings, pose_settings, pose_frames, workers, progress, checkpoints, resume,
            preset_name,
        )
        policy.config.training = {
            **record,
            "feedback_decoder": _record(report, "feedback_decoder", seqae_settings, decoder_history,
                                        demos=len(hard_data)),
            "pose": {**_record(report, "pose", pose_settings, pose_history, frames=int(pose_frames)),
                     "render_seconds": pose_history["render_seconds"]},
        }
        report.policies["feedback_default"] = policy.save_pretrained(out / "feedback_default")

    if "end_to_end" in methods:
        for camera, data in pairs.items():
            keep = usable_episodes(data, successful_only)
            policy, history = train_end_to_end(
                data.images[keep],
                data.motion(episodes=keep),
                config,
                e2e_settings,
                camera=camera,
                preset_name=preset_name,
                progress=progress,
                checkpoint_dir=checkpoints / f"end_to_end_{camera}",
                resume=resume,
            )
            e2e_record = _record(
                report, f"end_to_end_{camera}", e2e_settings, history, pairs=int(len(keep)), of=len(data),
                dataset=str(data.path),
            )
            policy.config.training = {**record, "end_to_end": e2e_record}
            report.policies[f"end_to_end_{camera}"] = policy.save_pretrained(out / f"end_to_end_{camera}")

    out.mkdir(parents=True, exist_ok=True)
    entry = {
        "preset": preset_name,
        **record,
        "seconds": report.seconds,
        "final_loss": report.final_loss,
        "policies": {k: str(v) for k, v in report.policies.items()},
    }
    log_path = out / "train_log.json"
    try:  # one entry per run into this directory (e.g. proposed first, end-to-end later)
        runs = json.loads(log_path.read_text())["runs"] if log_path.is_file() else []
    except (json.JSONDecodeError, KeyError, TypeError):
        runs = []
    atomic_write_bytes(log_path, (json.dumps({"runs": [*runs, entry]}, indent=2) + "\n").encode())
    return report


def _open_set(data_dir: Path, name: str, mapping: Mapping[str, str] | None = None) -> Any:
    """The set ``name`` (``motions``, ``pairs_<camera>``) of ``data_dir`` as a ``PushingDataset``.

    Looked for as ``data_dir/<name>.h5`` (``seqmotion lfd collect``), then as a LeRobot v3.0
    folder ``data_dir/<name>/`` (``seqmotion lfd export-lerobot``), then ``data_dir`` itself
    when it is one LeRobot dataset: it then serves as every set (its motions train the SeqAE,
    its camera images the CNN). A LeRobot folder's features are read through ``mapping``
    (``--map``). ``ValueError`` when none is there, when a pairs set has no images, or when
    ``mapping`` is given for a seqmotion ``.h5`` set (it has no feature keys to map).
    """
    from .data.dataset import load_dataset
    from .data.lerobot_import import from_lerobot, is_lerobot_dataset
    from .timing import COMMAND_INTERVAL

    if (data_dir / f"{name}.h5").is_file():
        if mapping:
            raise ValueError(f"--map renames a LeRobot dataset's features; {data_dir / name}.h5 is a seqmotion "
                             "dataset (its fields need no map)")
        return load_dataset(data_dir / f"{name}.h5")
    folder = data_dir / name if is_lerobot_dataset(data_dir / name) else data_dir
    if not is_lerobot_dataset(folder):
        raise ValueError(f"{data_dir / name}.h5 is missing: run 'seqmotion lfd collect --out {data_dir}' first "
                         "(or pass a LeRobot dataset folder)")
    data = from_lerobot(folder, mapping, name=name)
    fps = round(1 / data.dt, 6)
    if round(fps * COMMAND_INTERVAL, 6) != round(fps * COMMAND_INTERVAL):  # the decoder reads every 20 ms
        raise ValueError(f"{folder} is recorded at {fps:g} fps; the decoder runs every {COMMAND_INTERVAL * 1000:g} ms, "
                         f"so training needs a rate that is a multiple of {1 / COMMAND_INTERVAL:g} Hz")
    if name.startswith("pairs_") and data.images is None:
        raise ValueError(f"{folder} has no camera images: it cannot train the CNN of {name!r} (map its camera "
                         "with --map image=KEY, or train the SeqAE alone with --methods seqae)")
    return data


def _joint_count(sets: dict[str, Any]) -> int:
    """J of the datasets ``{name: PushingDataset or None}``: every motion field of every set has J joints,
    else ``ValueError`` naming them."""
    from .data.dataset import MOTION_KEYS

    counts = {f"{name}.{key}": int(data.motions[key].shape[-1])
              for name, data in sets.items() if data is not None for key in MOTION_KEYS}
    if len(set(counts.values())) != 1:
        raise ValueError(f"the training data's motion fields have different joint counts {counts}; a SeqAE takes "
                         "one robot's motions")
    return next(iter(counts.values()))


def _record(report: TrainReport, part: str, settings: Any, history: dict, **counts: Any) -> dict[str, Any]:
    """The training record of one part (settings, how much data, wall time, final loss); notes the
    last two in ``report`` under ``part``."""
    report.seconds[part] = history["seconds"]
    report.final_loss[part] = history["loss"][-1]
    return {"settings": asdict(settings), **counts, "seconds": history["seconds"], "final_loss": history["loss"][-1]}


def _with_seed(settings: Any, seed: int) -> Any:
    settings.seed = seed
    return settings
