"""Object feedback on the hard pushing benchmark: what lifts the proposed policy towards 80 %.

The shipped proposed policy decodes one z, taken from the first image, for the whole episode: its
decoder never sees the object again. Here the decoder reads ``[c_k, slave state]`` every 20 ms, ``c_k``
the object's features *now* (``seqmotion.lfd.policy.networks.FEATURES``: side, distance, reach, is box,
yaw), trained on the demonstrations' recorded object poses (``seqmotion.lfd.train.train_feedback_decoder``),
and is scored on the same held-out trials as ``evaluate`` (``seqmotion.lfd.evaluation.evaluate(...,
benchmark="hard")``, evaluation seed ``--eval-seed``) in two modes:

* ``oracle``: the simulator's true object pose every step (the decoder's ceiling);
* ``keypoint``: the library's feedback policy (kind ``feedback``, what ``seqmotion lfd train --methods feedback``
  trains and ``pushing-hard`` ships): this decoder, and the pose from each frame by the keypoint network
  (``seqmotion.lfd.policy.networks.PoseNet``) trained on frames of the demonstrations' own states re-rendered
  under fresh scene variation (``seqmotion.lfd.data.frames.render_pose_frames``; no film needed)::

    seqmotion lfd collect --benchmark hard --episodes 900 --no-video --out runs/v2big
    python benchmarks/exp_lfd_hard_feedback.py --data runs/v2big/hard.h5 --demos 826 --epochs 700 \
        --hidden 64 --modes oracle,keypoint --eval-seed 1 --cache runs/exp/cache --out runs/exp/feedback826

It writes ``OUT/eval_<mode>.json`` (``evaluate``'s JSON plus the arguments); results in
``benchmarks/RESULTS_lfd.md`` ("What lifts the hard benchmark"). Everything here is library API: the
trainings, the policy and the rollout (the oracle is a :class:`~seqmotion.lfd.policy.policy.DecoderSource`
whose z slot reads the scene). The earlier experiments of that section (re-planning every window, the
placement as the decoder's input, pose CNNs on filmed frames) ran on networks of their own in this script
up to commit 069f645 (``git show 069f645:benchmarks/exp_lfd_hard_feedback.py``); their conclusions led to
the keypoint policy and they are not run any more.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load, save
from torch import nn

from seqmotion.io import atomic_write_bytes
from seqmotion.lfd.data.dataset import load_dataset
from seqmotion.lfd.data.frames import render_pose_frames
from seqmotion.lfd.data.slicing import subset
from seqmotion.lfd.env.pushing import PushingScene
from seqmotion.lfd.env.state import ArmState
from seqmotion.lfd.evaluation import evaluate
from seqmotion.lfd.policy.interface import Observation
from seqmotion.lfd.policy.networks import FEATURES, PoseNet, PoseNetConfig, SeqAE, SeqAEConfig, object_features
from seqmotion.lfd.policy.policy import DecoderSource, PolicyConfig, PushingPolicy
from seqmotion.lfd.train import SeqAETraining, pose_training, train_feedback_decoder, train_pose_net


def _side_and_shape(data, episodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN001
    sign = np.where(data.episodes["side"][episodes] == "left", 1.0, -1.0)  # load_dataset gives str
    is_box = (data.episodes["shape"][episodes] == "box").astype(float)
    return sign, is_box


class _OracleSource(DecoderSource):
    """The feedback decoder's step with the true object features of ``scene`` now in its z slot."""

    def __init__(self, policy: PushingPolicy, scene: PushingScene) -> None:
        super().__init__(policy, np.zeros(policy.seqae_config.latent))
        self.scene = scene

    def latent_now(self, observation: Observation) -> torch.Tensor:
        position = self.scene.position
        side, box = np.array(position.sign, float), np.array(float(position.shape == "box"))
        c = torch.as_tensor(object_features(side, box, np.asarray(self.scene.block_pose)), dtype=torch.float32)
        p = self.policy
        return ((c - p.feature_mean) / p.feature_std)[None]


class _Oracle:
    """A controller (``reset`` / ``select_action``) running :class:`_OracleSource` in the evaluation's scene."""

    camera, images_every_step = None, False

    def __init__(self, policy: PushingPolicy, scene: PushingScene) -> None:
        self.policy, self.scene, self.config = policy, scene, policy.config
        self.command_interval = policy.command_interval

    def reset(self) -> None:
        self.source = _OracleSource(self.policy, self.scene)

    def select_action(self, observation: Observation) -> ArmState:
        return self.source.step(observation)


def _evaluate(args: argparse.Namespace, policy, mode: str, scene: PushingScene) -> None:  # noqa: ANN001
    start = time.time()
    result = evaluate(policy, trials=args.trials, seed=args.eval_seed, benchmark="hard", scene=scene)
    seconds = time.time() - start
    line = f"eval {mode}: {result.successes}/{result.n_trials} = {result.success_rate:.0%} ({seconds:.0f} s)"
    print(line, flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    payload = {"args": vars(args), **result.as_dict()}
    atomic_write_bytes(out / f"eval_{mode}.json", (json.dumps(payload, indent=1, default=float) + "\n").encode())


def _cached(args: argparse.Namespace, name: str, settings: str, make: nn.Module, train, *key: np.ndarray):  # noqa: ANN001, ANN202
    """``train()``'s result, or its weights from ``args.cache`` if a run with the same data and settings left them.

    ``train()`` returns the network first (and anything else after it, kept in the cache's JSON side
    file). The file's name carries ``settings`` and a hash of ``key`` (the arrays the network learns
    from); the weights are safetensors, written atomically. ``make`` is an untrained network of the same layers.
    """
    if not args.cache:
        return train()
    digest = hashlib.sha256()
    for array in key:
        digest.update(np.ascontiguousarray(array).tobytes())
    path = Path(args.cache) / f"{name}_{settings}_seed{args.seed}_{digest.hexdigest()[:12]}.safetensors"
    side = path.with_suffix(".json")
    if path.exists() and side.exists():
        make.load_state_dict(load(path.read_bytes()))
        print(f"{name}: weights from {path}", flush=True)
        return (make.eval(), *(np.asarray(x) for x in json.loads(side.read_text())))
    net, *rest = train()
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, save({k: v.contiguous() for k, v in net.state_dict().items()}))
    atomic_write_bytes(side, json.dumps([np.asarray(x).tolist() for x in rest]).encode())
    return (net, *rest)


def feedback(args: argparse.Namespace) -> None:
    data = load_dataset(args.data)
    ok = np.flatnonzero(data.episodes["success"])[: args.demos]
    demos = subset(data, ok)
    sign, is_box = _side_and_shape(data, ok)
    c = object_features(sign[:, None], is_box[:, None], demos.motions["block_pose"][:, ::20])  # (N, 300, 5)
    motion = demos.motion()
    config = SeqAEConfig(args.layers, args.hidden, latent=len(FEATURES))
    settings = SeqAETraining(epochs=args.epochs, latent_noise=args.c_noise, seed=args.seed)

    def train_decoder() -> tuple:
        model, mean, std, history = train_feedback_decoder(motion, c, config, settings, progress=False)
        print(f"decoder: loss {history['loss'][-1]:.4f}, {history['seconds']:.0f} s", flush=True)
        return model, mean, std

    model, mean, std = _cached(args, "feedback_decoder", f"{args.layers}x{args.hidden}_{args.epochs}ep_noise"
                               f"{args.c_noise:g}", SeqAE(config), train_decoder, motion, c)
    modes = args.modes.split(",")
    pose_net = PoseNet()
    if "keypoint" in modes:
        pose_settings = pose_training(args.seed)
        pose_settings.epochs = args.pose_epochs

        def train_pose() -> tuple:
            start = time.time()
            images, tips, targets = render_pose_frames(demos, args.pose_frames, args.seed, workers=2)
            print(f"pose frames: {len(images)} rendered, {time.time() - start:.0f} s", flush=True)
            net, history = train_pose_net(images, tips, targets, PoseNetConfig(), pose_settings)
            print(f"pose network: loss {history['loss'][-1]:.4f}, {history['seconds']:.0f} s", flush=True)
            return (net,)

        (pose_net,) = _cached(args, "pose", f"{args.pose_frames}f_{args.pose_epochs}ep", PoseNet(), train_pose,
                              demos.motions["block_pose"])
    policy = PushingPolicy(PolicyConfig("feedback", seqae=asdict(config), pose=asdict(PoseNetConfig(
        opening_frames=args.opening_frames))), model, pose_net)
    policy.feature_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
    policy.feature_std.copy_(torch.as_tensor(std, dtype=torch.float32))
    scene = PushingScene(benchmark="hard")
    try:
        for mode in modes:
            if mode not in ("oracle", "keypoint"):
                raise SystemExit(f"unknown mode {mode!r}: oracle or keypoint")
            _evaluate(args, policy if mode == "keypoint" else _Oracle(policy, scene), mode, scene)
    finally:
        scene.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="a hard set (hard.h5)")
    p.add_argument("--out", required=True)
    p.add_argument("--demos", type=int, default=100, help="the first N successful demonstrations")
    p.add_argument("--epochs", type=int, default=2000, help="decoder epochs")
    p.add_argument("--trials", type=int, default=100)
    p.add_argument("--eval-seed", type=int, default=0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--layers", type=int, default=3)
    p.add_argument("--hidden", type=int, default=32)
    p.add_argument("--c-noise", type=float, default=0.1, help="std of the noise on c in training (normalised)")
    p.add_argument("--modes", default="oracle,keypoint", help="oracle (the simulator's pose), keypoint (the "
                   "keypoint network on demonstrated states re-rendered under new scene variation)")
    p.add_argument("--pose-frames", type=int, default=60000, help="keypoint: frames rendered to train it")
    p.add_argument("--pose-epochs", type=int, default=12, help="keypoint: its training epochs")
    p.add_argument("--cache", default=None, help="keep the trained decoder and pose network here, and reuse them "
                   "when the data and settings match")
    p.add_argument("--opening-frames", type=int, default=10,
                   help="keypoint: side and shape from the mean estimate of this many first frames")
    args = p.parse_args()
    torch.set_num_threads(1)
    feedback(args)


if __name__ == "__main__":
    main()
