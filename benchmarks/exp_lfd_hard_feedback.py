"""Experiments on the hard pushing benchmark: what would lift the proposed policy towards 80 %?

The shipped proposed policy decodes one z, taken from the first image, for the whole episode: its
decoder never sees the object again. Three ways to give the policy more of the scene, each trained on
the same successful v2 demonstrations and scored on the same held-out trials as ``evaluate``
(``seqmotion.lfd.evaluation.evaluate(..., benchmark="hard")``, evaluation seed ``--eval-seed``)::

    # 1. re-planning: a SeqAE of 1 s windows; every window a CNN maps (image now, slave state, time)
    #    to the window's z and the decoder starts afresh (needs the filmed set: images mid-episode)
    python benchmarks/exp_lfd_hard_feedback.py replan --data runs/hard/hard.h5 --demos 128 --out runs/exp/replan
    #    ... or the shipped kind of policy for the first 3 s (--first MODEL), windows after it
    python benchmarks/exp_lfd_hard_feedback.py replan --data runs/hard/hard.h5 --demos 128 --switch 150 \
        --first runs/curve/models/proposed_100_0/proposed_default --out runs/exp/replan_after3s
    # 2. the placement as an input: the decoder reads [c, slave state], c = (side, distance, reach, is
    #    box, yaw) of the object as placed; a CNN regresses c from the first image (also run with the
    #    true c: "oracle")
    python benchmarks/exp_lfd_hard_feedback.py placement --data runs/v2/hard.h5 --demos 279 --epochs 700 \
        --out runs/exp/placement
    # 3. object feedback: the decoder reads [c_k, slave state] every 20 ms, c_k the object's pose *now*;
    #    trained on the demonstrations' recorded object poses; run with the true pose ("oracle") and with
    #    a CNN that estimates it from the webcam frame of every step (trained on the filmed set's frames,
    #    labelled with the recorded poses; "cnn": side and shape read once from the first frame,
    #    "cnn_every": everything from every frame)
    python benchmarks/exp_lfd_hard_feedback.py feedback --data runs/v2/hard.h5 --film runs/v2film/hard.h5 \
        --demos 279 --epochs 700 --out runs/exp/feedback
    #    ... "keypoint": the pose from each frame by a keypoint network (spatial soft-argmax) that also reads
    #    the pen tip's position (known from the slave's angles), trained on 60,000 frames of the
    #    demonstrations' own states re-rendered under fresh camera jitter, lighting, colours and
    #    distractors (no film needed); 900 demonstrations (826 successful, 8 min without video)
    seqmotion lfd collect --benchmark hard --episodes 900 --no-video --out runs/v2big
    python benchmarks/exp_lfd_hard_feedback.py feedback --data runs/v2big/hard.h5 --demos 826 --epochs 700 \
        --hidden 64 --modes oracle,keypoint --eval-seed 1 --cache runs/exp/cache --out runs/exp/feedback826

Each writes ``OUT/eval_<mode>.json`` (``evaluate``'s JSON plus the arguments). Results and what they
mean: ``benchmarks/RESULTS_lfd.md`` ("What lifts the hard benchmark"). These are experiments, not
library features: the networks are the library's layers (``MotionEncoder``, ``CommandDecoder``,
``ImageEncoder``, ``MotionScaler``) trained on the library's loop (``seqmotion.lfd.train._fit``), one
torch thread, seeded.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
import torch.nn.functional as F
from safetensors.torch import load, save
from torch import nn

from seqmotion.io import atomic_write_bytes
from seqmotion.lfd.dataset import load_dataset
from seqmotion.lfd.evaluation import evaluate
from seqmotion.lfd.models import (
    PRESETS,
    CNNConfig,
    CommandDecoder,
    ImageEncoder,
    MotionScaler,
    PushingPolicy,
    SeqAEConfig,
    motion_loss,
)
from seqmotion.lfd.teleop import ArmState, run_autonomous
from seqmotion.lfd.train import (
    CNNTraining,
    SeqAETraining,
    _fit,
    augment_images,
    encode_motions,
    state_noise,
    train_seqae,
)
from seqmotion.sim.pushing import BlockPosition, PushingScene, SceneVariation, forward_kinematics, sample_hard_placement

MASTER, SLAVE = slice(0, 9), slice(9, 18)
STEPS = 300  # 20 ms decoder steps in a 6 s hard episode
POSE_STREAM = 2000  # the seed stream of the pose network's rendered frames: never the evaluation's (1000)


def _yaw(pose: np.ndarray) -> np.ndarray:
    """The object's turn about z [rad] from its poses ``(..., 7)`` (centre, quaternion w, x, y, z)."""
    return 2.0 * np.arctan2(pose[..., 6], pose[..., 3])


def features(sign: np.ndarray, is_box: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Object features ``(..., 5)``: side sign, sign·y (distance from the centre line), x (reach), is box, yaw if a box.

    ``pose (..., 7)``: the object's centre [m] and quaternion (w, x, y, z), turning about z only.
    """
    yaw = _yaw(pose)
    sign, is_box = np.broadcast_to(sign, yaw.shape), np.broadcast_to(is_box, yaw.shape)
    return np.stack([sign, sign * pose[..., 1], pose[..., 0], is_box, is_box * yaw], -1)


def _side_and_shape(data, episodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    sign = np.where(data.episodes["side"][episodes] == "left", 1.0, -1.0)  # load_dataset gives str
    is_box = (data.episodes["shape"][episodes] == "box").astype(float)
    return sign, is_box


def _side_shape(side: float, box: float) -> tuple[float, float]:
    """An estimate's side sign (+1 left: ``side`` > 0) and is-box (``box`` > 0.5) as the features' 1.0 / 0.0."""
    return (1.0 if side > 0 else -1.0, 1.0 if box > 0.5 else 0.0)


def _command(decoded: torch.Tensor, scaler: MotionScaler) -> ArmState:
    m = scaler.denormalize(decoded, MASTER)[0, 0].double().numpy()
    return ArmState(m[0:3], m[3:6], m[6:9])


class _Policy:
    """``evaluate``'s interface around a per-episode command source factory ``make(scene, position)``."""

    def __init__(self, make) -> None:  # noqa: ANN001
        self.make = make
        self.config = SimpleNamespace(kind="experiment", preset="smaller", camera="default", command_interval=0.02)

    def run(self, scene, position, variation=None, camera=None, duration=6.0, latent=None):  # noqa: ANN001, ANN201
        variation = variation or SceneVariation()
        scene.reset(position, variation)
        image = scene.render(camera or "default")
        source = self.make(scene, position, variation)
        return run_autonomous(scene, source, position, duration, variation, 0.02, reset=False), image, np.zeros(1)


def _evaluate(args: argparse.Namespace, make, mode: str, errors: list | None = None) -> None:  # noqa: ANN001
    start = time.time()
    result = evaluate(_Policy(make), trials=args.trials, seed=args.eval_seed, benchmark="hard")
    seconds = time.time() - start
    line = f"eval {mode}: {result.successes}/{result.n_trials} = {result.success_rate:.0%} ({seconds:.0f} s)"
    if errors:
        line += f"; mean |estimate - true| per feature {np.abs(np.array(errors)).mean(0).round(4).tolist()}"
    print(line, flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    payload = {"args": vars(args), **result.as_dict()}
    atomic_write_bytes(out / f"eval_{mode}.json", (json.dumps(payload, indent=1, default=float) + "\n").encode())


# ----------------------------------------------------------------------------------------------
# 1. re-planning every window
# ----------------------------------------------------------------------------------------------
class _StateCNN(nn.Module):
    """CNN features of the image, with the slave state and the time, → the window's z."""

    def __init__(self, latent: int) -> None:
        super().__init__()
        self.img = ImageEncoder(CNNConfig(latent=64))
        self.head = nn.Sequential(nn.ReLU(), nn.Linear(64 + 9 + 1, 64), nn.ReLU(), nn.Linear(64, latent))

    def forward(self, images: torch.Tensor, state_n: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return self.head(torch.cat([self.img(images), state_n, t[:, None]], -1))


def replan(args: argparse.Namespace) -> None:
    data = load_dataset(args.data)
    ok = np.flatnonzero(data.episodes["success"])[: args.demos]
    motion = data.motion(episodes=ok)
    motion = np.concatenate([motion, motion[:, -1:]], 1)  # the last window's target: the final sample held
    video = data.video[ok]
    window = args.window
    starts = list(range(args.switch, STEPS, window))
    windows, images, states, times = [], [], [], []
    for n in range(len(ok)):
        for i0 in starts:
            windows.append(motion[n, i0 : i0 + window + 1])
            images.append(video[n, i0])
            states.append(motion[n, i0, SLAVE])
            times.append(i0 / STEPS)
    windows, images, states, times = np.stack(windows), np.stack(images), np.stack(states), np.array(times)
    config = PRESETS["smaller"]
    seqae, history = train_seqae(windows, config, SeqAETraining(epochs=args.epochs, seed=args.seed))
    print(f"windows {windows.shape}; SeqAE loss {history['loss'][-1]:.4f}", flush=True)
    z = encode_motions(seqae, windows)
    torch.manual_seed(args.seed)
    gen = torch.Generator().manual_seed(args.seed)
    cnn = _StateCNN(config.latent)
    x = torch.as_tensor(images)
    s = seqae.scaler.normalize(torch.as_tensor(states, dtype=torch.float32), SLAVE)
    t = torch.as_tensor(times, dtype=torch.float32)
    y = torch.as_tensor(z, dtype=torch.float32)

    def loss(idx: torch.Tensor) -> torch.Tensor:
        return ((cnn(augment_images(x[idx], gen), s[idx], t[idx]) - y[idx]) ** 2).sum(-1).mean()

    _fit(cnn, list(cnn.parameters()), len(x), CNNTraining(epochs=args.cnn_epochs, seed=args.seed), gen, loss,
         "CNN", False, min_batch=2, part="cnn")
    cnn.eval()
    first = PushingPolicy.from_pretrained(args.first) if args.first else None
    if args.switch and first is None:
        raise ValueError("--switch needs --first (the policy that runs before the first window)")

    class Source:
        def __init__(self, scene, position, variation) -> None:  # noqa: ANN001
            self.scene, self.calls, self.state = scene, 0, None
            self.first = first.source(first.latent(scene.render("default"))) if args.switch else None

        @torch.no_grad()
        def __call__(self, t: float, slave_state: ArmState) -> ArmState:
            k = self.calls
            self.calls += 1
            if k < args.switch:
                return self.first(t, slave_state)
            state_n = seqae.scaler.normalize(torch.as_tensor(slave_state.as_vector(), dtype=torch.float32)[None], SLAVE)
            if (k - args.switch) % window == 0:  # look again: a new z, and the decoder starts afresh
                image = torch.as_tensor(self.scene.render("default"))[None]
                self.z, self.state = cnn(image, state_n, torch.tensor([k / STEPS])), None
            out, self.state = seqae.decoder(self.z, state_n[:, None], self.state)
            return _command(out, seqae.scaler)

    _evaluate(args, Source, "cnn")


# ----------------------------------------------------------------------------------------------
# 2. the placement as the decoder's input, 3. the object's pose every step
# ----------------------------------------------------------------------------------------------
class _Decoder(nn.Module):
    """LSTM reading ``[c_k, slave state_k]`` → the next master command (normalised)."""

    def __init__(self, motions: np.ndarray, layers: int, hidden: int) -> None:
        super().__init__()
        self.scaler = MotionScaler(3).fit(motions)
        self.decoder = CommandDecoder(SeqAEConfig(layers, hidden, latent=5))


def _train_decoder(args: argparse.Namespace, motion: np.ndarray, c_n: np.ndarray, per_step: bool) -> tuple:
    """Teacher-forced eq.-5.1 training of the decoder on ``c_n`` (``(N, 5)`` or ``(N, K, 5)`` normalised)."""
    torch.manual_seed(args.seed)
    gen = torch.Generator().manual_seed(args.seed)
    model = _Decoder(motion, args.layers, args.hidden)
    motions = torch.as_tensor(motion, dtype=torch.float32)
    c_all = torch.as_tensor(c_n, dtype=torch.float32)
    settings = SeqAETraining(epochs=args.epochs, seed=args.seed)

    def loss(idx: torch.Tensor) -> torch.Tensor:
        batch, c = motions[idx], c_all[idx]
        c = c[:, :-1] if per_step else c
        c = c + args.c_noise * torch.randn(c.shape, generator=gen)
        slave = batch[:, :-1, SLAVE]
        slave_n = model.scaler.normalize(slave, SLAVE) + state_noise(tuple(slave.shape), settings, gen)
        if per_step:  # the decoder's z slot carries c_k, a different value at every step
            y, _ = model.decoder.lstm(torch.cat([c, slave_n], -1))
            out = model.decoder.out(y)
        else:
            out, _ = model.decoder(c, slave_n)
        return motion_loss(model.scaler.denormalize(out, MASTER), batch[:, 1:, MASTER], model.scaler.variance)

    start = time.time()
    history = _fit(model, list(model.parameters()), len(motions), settings, gen, loss, "decoder", False,
                   part="seqae")
    print(f"decoder: loss {history['loss'][-1]:.4f}, {time.time() - start:.0f} s", flush=True)
    return model.eval(), gen


def _train_pose_cnn(args: argparse.Namespace, images: np.ndarray, c_n: np.ndarray, gen: torch.Generator,
                    settings: CNNTraining) -> ImageEncoder:
    cnn = ImageEncoder(CNNConfig(latent=5))
    x, y = torch.as_tensor(images), torch.as_tensor(c_n, dtype=torch.float32)

    def loss(idx: torch.Tensor) -> torch.Tensor:
        return ((cnn(augment_images(x[idx], gen)) - y[idx]) ** 2).sum(-1).mean()

    start = time.time()
    history = _fit(cnn, list(cnn.parameters()), len(x), settings, gen, loss, "CNN", False, min_batch=2, part="cnn")
    print(f"CNN on {len(x)} images: loss {history['loss'][-1]:.4f}, {time.time() - start:.0f} s", flush=True)
    return cnn.eval()


def placement(args: argparse.Namespace) -> None:
    data = load_dataset(args.data)
    ok = np.flatnonzero(data.episodes["success"])[: args.demos]
    sign, is_box = _side_and_shape(data, ok)
    c = features(sign, is_box, data.episodes["block_initial_pose"][ok])
    mean, std = c.mean(0), c.std(0) + 1e-9
    model, gen = _train_decoder(args, data.motion(episodes=ok), (c - mean) / std, per_step=False)
    settings = CNNTraining(epochs=args.cnn_epochs, seed=args.seed)
    cnn = _train_pose_cnn(args, data.images[ok], (c - mean) / std, gen, settings)
    errors: list = []

    def make(oracle: bool):  # noqa: ANN202
        def source(scene, position, variation):  # noqa: ANN001, ANN202
            true = (features(np.array(position.sign, float), np.array(float(position.shape == "box")),
                             np.asarray(scene.block_pose)) - mean) / std
            with torch.no_grad():
                seen = cnn(torch.as_tensor(scene.render("default"))[None])
            errors.append((seen[0].numpy() - true) * std)
            c_used = torch.as_tensor(true, dtype=torch.float32)[None] if oracle else seen
            state: list = [None]

            @torch.no_grad()
            def step(t: float, slave_state: ArmState) -> ArmState:
                x = torch.as_tensor(slave_state.as_vector(), dtype=torch.float32)[None, None]
                out, state[0] = model.decoder(c_used, model.scaler.normalize(x, SLAVE), state[0])
                return _command(out, model.scaler)

            return step
        return source

    for mode in args.modes.split(","):
        errors.clear()
        _evaluate(args, make(mode == "oracle"), mode, errors)


class _PoseNet(nn.Module):
    """Keypoint CNN (spatial soft-argmax, as in Levine et al. 2016) → the object's pose from one frame.

    ``(B, 64, 64, 3)`` uint8 frame and ``(B, 2)`` pen-tip ``x, y`` [m] (from the slave's measured angles:
    a point the network knows in the world, to read the jittered camera against) → ``(B, 4)``: the
    object's ``x − 16 cm`` and ``y`` [cm], a box-or-cylinder logit and the box's yaw [rad]. Its keypoints
    are expected image coordinates, so it locates to a fraction of a pixel where a flattening CNN
    (the chapter's, :class:`ImageEncoder`) does not.
    """

    def __init__(self, keypoints: int = 16, width: int = 24) -> None:
        super().__init__()
        self.conv = nn.Sequential(
            nn.Conv2d(3, width, 5, stride=2, padding=2), nn.ReLU(),
            nn.Conv2d(width, width, 3, padding=1), nn.ReLU(),
            nn.Conv2d(width, width, 3, padding=1), nn.ReLU(),
        )
        self.keypoints = nn.Conv2d(width, keypoints, 1)
        self.temperature = nn.Parameter(torch.ones(1))
        grid = torch.linspace(-1, 1, 32)
        self.register_buffer("gx", grid[None, :].expand(32, 32).reshape(-1))
        self.register_buffer("gy", grid[:, None].expand(32, 32).reshape(-1))
        self.head = nn.Sequential(nn.Linear(2 * keypoints + width + 2, 128), nn.ReLU(),
                                  nn.Linear(128, 128), nn.ReLU(), nn.Linear(128, 4))

    def forward(self, images: torch.Tensor, tip_xy: torch.Tensor) -> torch.Tensor:
        x = images.to(torch.float32).permute(0, 3, 1, 2) / 255.0 - 0.5
        f = self.conv(x)
        attention = F.softmax(self.keypoints(f).flatten(2) / self.temperature, -1)  # (B, K, 32·32)
        points = torch.cat([attention @ self.gx, attention @ self.gy], -1)  # (B, 2K)
        return self.head(torch.cat([points, f.mean((2, 3)), tip_xy * 10.0], -1))

    def estimate(self, image: np.ndarray, tip_xy: np.ndarray) -> np.ndarray:
        """One frame → ``(4,)``: the object's ``x, y`` [m], P(box), box yaw [rad]."""
        with torch.no_grad():
            e = self(torch.as_tensor(image)[None], torch.as_tensor(tip_xy, dtype=torch.float32)[None])[0].numpy()
        return np.array([e[0] / 100 + 0.16, e[1] / 100, 1 / (1 + math.exp(-e[2])), e[3]])


def _pose_targets(pose: np.ndarray, is_box: np.ndarray) -> np.ndarray:
    return np.stack([(pose[:, 0] - 0.16) * 100, pose[:, 1] * 100, is_box, _yaw(pose)], -1).astype(np.float32)


def _render_pose_frames(job: tuple) -> tuple:
    """Shard ``(path, seed, shard, n)``: demonstrated states re-rendered under fresh scene variation.

    Each frame: a random demonstration's arm and object at a random 20 ms step; in half of them the
    object moved ±1.5 cm and turned ±10° off where it was (states a closed loop reaches and the
    demonstrations did not); a new webcam jitter, lighting, colours and distractors
    (:func:`sample_hard_placement`). Returns the frames ``(n, 64, 64, 3)``, the pen tips ``(n, 2)`` [m]
    and the targets ``(n, 4)`` of :class:`_PoseNet`.
    """
    path, seed, shard, n = job
    data = load_dataset(path)
    theta, poses, tips = data.motions["slave_theta"], data.motions["block_pose"], data.motions["slave_tip"]
    side, shape = data.episodes["side"], data.episodes["shape"]
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(POSE_STREAM, shard)))
    scene = PushingScene(benchmark="hard")
    images, tip_xy, pose, is_box = np.zeros((n, 64, 64, 3), np.uint8), np.zeros((n, 2)), np.zeros((n, 7)), np.zeros(n)
    try:
        for i in range(n):
            e, k = int(rng.integers(len(side))), int(rng.integers(STEPS)) * 20
            pose[i] = poses[e, k]
            if rng.random() < 0.5:
                pose[i, :2] += rng.uniform(-0.015, 0.015, 2)
                yaw = float(_yaw(pose[i])) + rng.uniform(-0.17, 0.17)
                pose[i, 3:] = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
            _, variation = sample_hard_placement(rng)
            scene.reset(BlockPosition(-1, str(side[e]), 0.08, 0.16, str(shape[e])), variation)
            scene.set_state(theta[e, k], pose[i])
            images[i], tip_xy[i], is_box[i] = scene.render("default"), tips[e, k, :2], float(shape[e] == "box")
    finally:
        scene.close()
    return images, tip_xy, _pose_targets(pose, is_box)


def _train_pose_net(args: argparse.Namespace) -> _PoseNet:
    """Render ``args.pose_frames`` frames (two processes) and fit :class:`_PoseNet` on the library's loop."""
    start = time.time()
    jobs = [(args.data, args.seed, shard, args.pose_frames // 2) for shard in range(2)]
    with ProcessPoolExecutor(2) as pool:
        parts = list(pool.map(_render_pose_frames, jobs))
    images, tips, targets = (torch.as_tensor(np.concatenate(x)) for x in zip(*parts, strict=True))
    tips, targets = tips.to(torch.float32), targets.to(torch.float32)
    print(f"pose frames: {len(images)} rendered, {time.time() - start:.0f} s", flush=True)
    torch.manual_seed(args.seed)
    gen = torch.Generator().manual_seed(args.seed)
    net = _PoseNet()
    settings = CNNTraining(epochs=args.pose_epochs, batch_size=64, lr=2e-3, lr_final_fraction=0.02, seed=args.seed)

    def loss(idx: torch.Tensor) -> torch.Tensor:
        out, t = net(augment_images(images[idx], gen), tips[idx]), targets[idx]
        position = ((out[:, :2] - t[:, :2]) ** 2).sum(-1)  # [cm²]
        shape = F.binary_cross_entropy_with_logits(out[:, 2], t[:, 2])
        yaw = t[:, 2] * ((out[:, 3] - t[:, 3]) / 0.2) ** 2  # a box's yaw: 0.2 rad weighs as 1 cm
        return (position + shape + yaw).mean()

    start = time.time()
    history = _fit(net, list(net.parameters()), len(images), settings, gen, loss, "pose", False, part="cnn")
    print(f"pose network: loss {history['loss'][-1]:.4f}, {time.time() - start:.0f} s", flush=True)
    return net.eval()


def _cached(args: argparse.Namespace, name: str, make: nn.Module, train, *key: np.ndarray) -> nn.Module:  # noqa: ANN001
    """``train()``'s network, or its weights from ``args.cache`` if a run with the same data and settings left them.

    The file's name carries the settings and a hash of ``key`` (the arrays the network learns from);
    the weights are safetensors, written atomically. ``make`` is an untrained network of the same layers.
    """
    if not args.cache:
        return train()
    digest = hashlib.sha256()
    for array in key:
        digest.update(np.ascontiguousarray(array).tobytes())
    settings = (
        f"{args.layers}x{args.hidden}_{args.epochs}ep_noise{args.c_noise:g}" if name == "decoder"
        else f"{args.pose_frames}f_{args.pose_epochs}ep"
    ) + f"_seed{args.seed}"
    path = Path(args.cache) / f"{name}_{settings}_{digest.hexdigest()[:12]}.safetensors"
    if path.exists():
        make.load_state_dict(load(path.read_bytes()))
        print(f"{name}: weights from {path}", flush=True)
        return make.eval()
    net = train()
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, save({k: v.contiguous() for k, v in net.state_dict().items()}))
    return net


def feedback(args: argparse.Namespace) -> None:
    data = load_dataset(args.data)
    ok = np.flatnonzero(data.episodes["success"])[: args.demos]
    sign, is_box = _side_and_shape(data, ok)
    every = 20  # 1 ms recording → the decoder's 20 ms
    c = features(sign[:, None], is_box[:, None], data.motions["block_pose"][ok, ::every])  # (N, 300, 5)
    mean, std = c.reshape(-1, 5).mean(0), c.reshape(-1, 5).std(0) + 1e-9
    motion = data.motion(episodes=ok)
    gen = torch.Generator().manual_seed(args.seed)  # the CNN modes' stream (their own when the decoder is cached)

    def train() -> nn.Module:
        model, gen_after = _train_decoder(args, motion, (c - mean) / std, per_step=True)
        gen.set_state(gen_after.get_state())
        return model

    model = _cached(args, "decoder", _Decoder(motion, args.layers, args.hidden), train, motion, c)
    modes = args.modes.split(",")
    cnns: dict[str, tuple] = {}
    if any(m.startswith("cnn") for m in modes):
        film = load_dataset(args.film)
        fok = np.flatnonzero(film.episodes["success"])[: args.demos]
        fsign, fbox = _side_and_shape(film, fok)
        frames = film.video[fok][:, :: args.frame_every].reshape(-1, 64, 64, 3)  # (N·F, 64, 64, 3)
        pose = film.motions["block_pose"][fok, :: every * args.frame_every]
        settings = CNNTraining(epochs=args.cnn_epochs, batch_size=32, seed=args.seed)
        for mode in modes:
            if mode == "cnn_every":  # regress the decoder's own features (sign·y) from every frame
                target, t_mean, t_std = features(fsign[:, None], fbox[:, None], pose), mean, std
            elif mode == "cnn":  # regress y itself; the side and shape are read once, from the first frame
                target = features(fsign[:, None], fbox[:, None], pose)
                target[..., 1] = pose[..., 1]
                t_mean, t_std = target.reshape(-1, 5).mean(0), target.reshape(-1, 5).std(0) + 1e-9
            else:
                continue
            normalized = ((target - t_mean) / t_std).reshape(-1, 5)
            cnns[mode] = (_train_pose_cnn(args, frames, normalized, gen, settings), t_mean, t_std)
    pose_net = None
    if "keypoint" in modes:
        pose_net = _cached(args, "pose", _PoseNet(), lambda: _train_pose_net(args), data.motions["block_pose"])
    errors: list = []

    def make(mode: str):  # noqa: ANN202
        def source(scene, position, variation):  # noqa: ANN001, ANN202
            side, box = np.array(position.sign, float), np.array(float(position.shape == "box"))
            state: list = [None]
            first: list = [None]  # (side, is box) read off the first frame (mode "cnn")
            opening: list = []  # mode "keypoint": the estimates of the first frames

            @torch.no_grad()
            def step(t: float, slave_state: ArmState) -> ArmState:
                true = (features(side, box, np.asarray(scene.block_pose)) - mean) / std
                c_now = true
                if mode == "keypoint":  # the frame now and the pen's tip → the object's pose
                    est = pose_net.estimate(scene.render("default"), forward_kinematics(slave_state.theta)[:2])
                    if first[0] is None:  # side and shape: the mean of the first frames' (the object still)
                        opening.append(est)
                        if len(opening) == args.opening_frames:
                            m = np.mean(opening, 0)
                            first[0] = _side_shape(m[1], m[2])
                    s, b = first[0] or _side_shape(est[1], est[2])
                    c_now = (np.array([s, s * est[1], est[0], b, b * est[3]]) - mean) / std
                    errors.append((c_now - true) * std)
                elif mode != "oracle":  # the webcam's frame now → the object's estimated pose
                    cnn, t_mean, t_std = cnns[mode]
                    seen = cnn(torch.as_tensor(scene.render("default"))[None])[0].numpy()
                    if mode == "cnn_every":
                        c_now = seen
                    else:
                        raw = seen * t_std + t_mean
                        if first[0] is None:
                            first[0] = _side_shape(raw[0], raw[3])
                        s, b = first[0]
                        c_now = (np.array([s, s * raw[1], raw[2], b, b * raw[4]]) - mean) / std
                    errors.append((c_now - true) * std)
                x = torch.as_tensor(slave_state.as_vector(), dtype=torch.float32)[None, None]
                inputs = torch.cat([torch.as_tensor(c_now, dtype=torch.float32)[None, None],
                                    model.scaler.normalize(x, SLAVE)], -1)
                y, state[0] = model.decoder.lstm(inputs, state[0])
                return _command(model.decoder.out(y), model.scaler)

            return step
        return source

    for mode in modes:
        errors.clear()
        _evaluate(args, make(mode), mode, errors)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="experiment", required=True)
    for name in ("replan", "placement", "feedback"):
        p = sub.add_parser(name)
        p.add_argument("--data", required=True, help="a hard set (hard.h5); replan needs a filmed one")
        p.add_argument("--out", required=True)
        p.add_argument("--demos", type=int, default=100, help="the first N successful demonstrations")
        p.add_argument("--epochs", type=int, default=2000, help="decoder (SeqAE) epochs")
        p.add_argument("--cnn-epochs", type=int, default={"replan": 60, "placement": 100, "feedback": 15}[name])
        p.add_argument("--trials", type=int, default=100)
        p.add_argument("--eval-seed", type=int, default=0)
        p.add_argument("--seed", type=int, default=0)
        if name == "replan":
            p.add_argument("--window", type=int, default=50, help="decoder steps (20 ms) between looks")
            p.add_argument("--switch", type=int, default=0, help="steps of --first before the first window")
            p.add_argument("--first", default=None, help="a proposed policy to run before --switch")
        else:
            p.add_argument("--layers", type=int, default=3)
            p.add_argument("--hidden", type=int, default=32)
            p.add_argument("--c-noise", type=float, default=0.1, help="std of the noise on c in training (normalised)")
            p.add_argument("--modes", default="cnn,oracle" if name == "placement" else "oracle,cnn",
                           help="cnn (estimated by a CNN from the webcam), oracle (the simulator's); feedback also "
                           "cnn_every (the side and shape estimated in every frame, not once), keypoint (a keypoint "
                           "network trained on demonstrated states re-rendered under new scene variation)")
        if name == "feedback":
            p.add_argument("--film", required=False, help="a filmed hard set (for the pose CNN)")
            p.add_argument("--frame-every", type=int, default=5, help="CNN training frames: every n-th 20 ms frame")
            p.add_argument("--pose-frames", type=int, default=60000, help="keypoint: frames rendered to train it")
            p.add_argument("--pose-epochs", type=int, default=12, help="keypoint: its training epochs")
            p.add_argument("--cache", default=None, help="keep the trained decoder and pose network here, and reuse "
                           "them when the data and settings match (a cached decoder gives the cnn modes a fresh "
                           "random stream)")
            p.add_argument("--opening-frames", type=int, default=10,
                           help="keypoint: side and shape from the mean estimate of this many first frames")
    args = parser.parse_args()
    torch.set_num_threads(1)
    {"replan": replan, "placement": placement, "feedback": feedback}[args.experiment](args)


if __name__ == "__main__":
    main()
