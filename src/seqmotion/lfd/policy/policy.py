"""The pushing policy: the combined model of Fig. 5.2 with LeRobot's per-step interface.

* :class:`PolicyConfig` — the typed config saved with the weights (kind, SeqAE/CNN/PoseNet shapes, camera,
  the decoder's period).
* :class:`PushingPolicy` — the trained model (save / load / model card like every seqmotion model) and the
  controller: :meth:`PushingPolicy.reset` starts an episode, :meth:`PushingPolicy.select_action` maps an
  :class:`~seqmotion.lfd.policy.interface.Observation` to the master command every Δt_NN.
* :class:`DecoderSource`, :class:`FeedbackSource` — one episode's decoder state (the z of the first image, or
  the object features read from every image).

The policy runs no episodes itself: :func:`seqmotion.lfd.rollout.rollout` drives it in a world.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from ...errors import CheckpointError, check_finite_array
from ...training.checkpoint import load_state_dict_strict
from ...training.pretrained import PretrainedModel
from ...training.provenance import describe_machine
from ..env.state import ArmState
from ..timing import COMMAND_INTERVAL
from .interface import Observation
from .networks import (
    ARM_JOINTS,
    FEATURES,
    MASTER,
    PRESETS,
    SLAVE,
    CNNConfig,
    ImageEncoder,
    PoseNet,
    PoseNetConfig,
    SeqAE,
    SeqAEConfig,
    check_images,
    check_motions,
)

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
        camera: webcam pose the CNN was trained on (a key of ``seqmotion.lfd.env.pushing.CAMERAS``).
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

    Typical use (one step at a time, as LeRobot's policies are driven)::

        policy = sm.load_pretrained("pushing")
        policy.reset()                                   # a new episode: fresh decoder state
        command = policy.select_action(observation)      # every 20 ms: Observation → master ArmState

    The first observation of an episode carries the webcam image (ẑ = CNN(image)); a ``feedback``
    policy reads the image of every observation. :func:`seqmotion.lfd.rollout.rollout` is the loop
    that drives it in a world (1 ms bilateral control, a decision every ``command_interval``).

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
                "every webcam frame instead: drive it with policy.select_action(observation) "
                "(seqmotion.lfd.rollout.rollout) or sm.lfd.evaluate(policy, benchmark='hard')"
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
                "do the standard arms of `seqmotion.lfd.env.robot` (robosuite's, Menagerie's), which run one z from "
                "the first image.",
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
        """A per-episode decoder decoding latent ``z`` ``(latent,)`` (one z for the whole episode)."""
        self._one_latent("source(z)")
        return DecoderSource(self, z)

    # -- the per-step controller interface (seqmotion.lfd.policy.interface.Controller) -----------
    @property
    def camera(self) -> str:
        """The webcam pose the policy reads (the one its CNN or PoseNet was trained on)."""
        return self.config.camera

    @property
    def command_interval(self) -> float:
        """Δt_NN [s]: the period of :meth:`select_action`."""
        return float(self.config.command_interval)

    @property
    def images_every_step(self) -> bool:
        """Whether every observation must carry a webcam image (``feedback``), not only the first."""
        return self.config.kind == "feedback"

    def reset(self, latent: Any = None) -> None:
        """Start an episode: the decoder's recurrent state is cleared.

        Args:
            latent: decode this z ``(latent,)`` for the whole episode instead of the CNN's ẑ of the first
                image (a diagnostic: with the demonstrations' own z it measures the decoder alone; a
                ``"seqae"`` model, which has no CNN, needs it). A ``feedback`` policy takes none.
        """
        if latent is not None:
            if self.config.kind == "feedback":
                raise ValueError("a 'feedback' policy decodes the object features it sees every step: it takes no "
                                 "latent")
            self._given = check_latent(latent, self.seqae_config.latent, "latent")
        else:
            self._given = None
        self._episode: DecoderSource | None = None

    def select_action(self, observation: Observation) -> ArmState:
        """The master command ``ArmState`` (θ, θ̇, τ: ``(3,)`` each) for the slave state of ``observation``.

        Called every :attr:`command_interval` from ``observation.t = 0`` after :meth:`reset`. The first
        call fixes the episode's z: the given latent, or the CNN's ẑ of ``observation.image``
        (``(64, 64, 3)`` uint8); a ``feedback`` policy estimates the object's pose from every
        observation's image instead.
        """
        episode = getattr(self, "_episode", None)
        if episode is None:
            given = getattr(self, "_given", None)
            if self.config.kind == "feedback":
                episode = FeedbackSource(self)
            else:
                if given is None and observation.image is None:
                    raise ValueError("the first observation of an episode must carry the webcam image (or pass "
                                     "reset(latent=z))")
                episode = self.source(self.latent(observation.image) if given is None else given)
            self._episode = episode
        return episode.step(observation)

    @property
    def episode_latent(self) -> np.ndarray:
        """The z decoded this episode ``(latent,)``; a ``feedback`` policy's first features ``(5,)``."""
        episode = getattr(self, "_episode", None)
        if episode is None:
            return np.full(self.seqae_config.latent, np.nan)
        return episode.first_features if isinstance(episode, FeedbackSource) else episode.z_value


def check_latent(z: Any, latent: int, name: str = "z") -> np.ndarray:
    """``z`` as ``(latent,)`` finite float64 numbers (a SeqAE's latent); ``ValueError`` naming ``name`` otherwise."""
    arr = check_finite_array(name, z)
    if arr.shape != (latent,):
        raise ValueError(f"{name} must be {latent} finite numbers, got shape {arr.shape}")
    return arr


class DecoderSource:
    """The decoder as a master stand-in: ``source(t, slave_state) → ArmState`` with its LSTM state.

    One instance per episode. It must be called at t = 0, Δt_NN, 2 Δt_NN, … (as
    :func:`~seqmotion.lfd.rollout.rollout` does); a skipped or repeated call would
    desynchronise the recurrent state from the time steps it was trained on, so it is refused.
    The simulated slave is the 3-joint arm: a SeqAE of another joint count is refused.
    """

    def __init__(self, policy: PushingPolicy, z: Any) -> None:
        require_arm(policy.seqae_config, "the closed-loop decoder")
        z_arr = check_latent(z, policy.seqae_config.latent)
        self.policy = policy
        self.z = torch.as_tensor(z_arr, dtype=torch.float32)[None]
        self.z_value = z_arr  # ``(latent,)`` float64, as given
        self.interval = policy.config.command_interval
        self.state: tuple[torch.Tensor, torch.Tensor] | None = None
        self.calls = 0

    def __call__(self, t: float, slave_state: ArmState) -> ArmState:
        """The command source form ``source(t, slave_state)`` (an observation without an image)."""
        return self.step(Observation(t, slave_state))

    @torch.no_grad()
    def step(self, observation: Observation) -> ArmState:
        """One decoder step: the master command for ``observation``'s slave state."""
        t, slave_state = observation.t, observation.state
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
        out, self.state = p.decoder(self.latent_now(observation), slave_n, self.state)
        m = p.scaler.denormalize(out, MASTER)[0, 0].double().numpy()
        return ArmState(m[0:3], m[3:6], m[6:9])

    def latent_now(self, observation: Observation) -> torch.Tensor:
        """What the decoder's z slot reads at this step ``(1, latent)``: the episode's one z."""
        return self.z


class FeedbackSource(DecoderSource):
    """A ``feedback`` policy's command source: the same decoder step, its z slot the object features seen now.

    Every call reads the observation's webcam image, estimates the object's ``x, y``, shape and yaw with the
    policy's :class:`PoseNet` (given the pen tip from the slave's measured angles) and feeds the
    normalised :func:`object_features` to the decoder. The side and the shape are the mean of the
    first ``opening_frames`` estimates, then held (:class:`PoseNetConfig`).

    Attributes:
        first_features: the features ``(5,)`` of the first step (unnormalised; :data:`FEATURES`).
        estimates: every step's raw estimate ``(4,)`` (x, y [m], P(box), yaw [rad]).
    """

    def __init__(self, policy: PushingPolicy) -> None:
        super().__init__(policy, np.zeros(policy.seqae_config.latent))
        self.opening = int(policy.config.pose.get("opening_frames", PoseNetConfig.opening_frames))
        self.side_shape: tuple[float, float] | None = None
        self.first_features = np.full(len(FEATURES), np.nan)
        self.estimates: list[np.ndarray] = []

    @staticmethod
    def _side_shape(estimate: np.ndarray) -> tuple[float, float]:
        """An estimate's side sign (+1 left: y > 0) and is-box (P(box) > 0.5) as the features' values."""
        return (1.0 if estimate[1] > 0 else -1.0, 1.0 if estimate[2] > 0.5 else 0.0)

    def latent_now(self, observation: Observation) -> torch.Tensor:
        from ..env.pushing import forward_kinematics  # MuJoCo only when a feedback policy runs

        p = self.policy
        assert p.pose_net is not None
        if observation.image is None:
            raise ValueError("a 'feedback' policy reads the webcam image of every observation; this one has none")
        estimate = p.pose_net.estimate(observation.image, forward_kinematics(observation.state.theta)[:2])
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
