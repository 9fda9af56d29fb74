"""Rendering training frames: the pose network's images, re-rendered from the demonstrations' own states.

:func:`render_pose_frames` puts a recorded arm pose and object pose into the hard scene under fresh
scene variation and renders the webcam: the keypoint network (:class:`~seqmotion.lfd.policy.networks.PoseNet`)
of a ``feedback`` policy trains on these frames (no film needed).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...errors import check_number
from ..env.pushing import BlockPosition, PushingScene, sample_hard_placement
from ..policy.networks import PoseNet, object_yaw
from ..timing import samples_per_command

POSE_STREAM = 2000
"""Seed stream of a feedback policy's rendered training frames: never the evaluation's
(:data:`seqmotion.lfd.evaluation.EVAL_STREAM`, 1000) or the demonstrations' own."""
POSE_SHARD = 2500
"""Frames per rendering job: the frames depend on the seed and the count, not on the number of workers."""
POSE_FRAMES = 60000
"""Default number of frames the pose network trains on (9 min of rendering on two cores)."""


def _render_shard(job: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One rendering job of :func:`render_pose_frames`: ``(states, seed, shard, n)`` → frames, tips, targets."""
    states, seed, shard, n = job
    theta, poses, tips, side, shape = (states[k] for k in ("theta", "pose", "tip", "side", "shape"))
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(POSE_STREAM, shard)))
    scene = PushingScene(benchmark="hard")
    images, tip_xy, pose = np.zeros((n, 64, 64, 3), np.uint8), np.zeros((n, 2)), np.zeros((n, 7))
    is_box = np.zeros(n)
    try:
        for i in range(n):
            e, k = int(rng.integers(len(side))), int(rng.integers(theta.shape[1]))
            pose[i] = poses[e, k]
            if rng.random() < 0.5:  # a state a closed loop reaches and the demonstrations did not
                pose[i, :2] += rng.uniform(-0.015, 0.015, 2)
                yaw = float(object_yaw(pose[i])) + rng.uniform(-0.17, 0.17)
                pose[i, 3:] = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
            _, variation = sample_hard_placement(rng)  # a fresh camera jitter, lighting, colours, distractors
            scene.reset(BlockPosition(-1, str(side[e]), 0.08, 0.16, str(shape[e])), variation)
            scene.set_state(theta[e, k], pose[i])
            images[i], tip_xy[i], is_box[i] = scene.render("default"), tips[e, k, :2], float(shape[e] == "box")
    finally:
        scene.close()
    return images, tip_xy, PoseNet.targets(pose, is_box)


def render_pose_frames(
    data: Any, frames: int = POSE_FRAMES, seed: int = 0, workers: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Training frames for the pose network: the demonstrations' own states, re-rendered under fresh variation.

    Each frame is a random demonstration's arm and object at a random 20 ms step; in half of them
    the object is moved ±1.5 cm and turned ±10° off where it was; every frame has a new webcam
    jitter, lighting, colours and distractors (:func:`~seqmotion.lfd.env.pushing.sample_hard_placement`),
    drawn from the seed stream :data:`POSE_STREAM`. No film is needed: the hard set's recorded
    states (``hard.h5``, with or without video) are enough.

    Args:
        data: a hard-benchmark ``PushingDataset`` (the demonstrations to train on).
        frames: how many frames.
        seed: the training seed.
        workers: rendering processes (the frames do not depend on it); more than one are spawned, so a
            script calling this needs the ``if __name__ == "__main__":`` guard.

    Returns:
        ``(images (frames, 64, 64, 3) uint8, pen tips (frames, 2) [m], targets (frames, 4))``: the targets
        as :meth:`PoseNet.targets`.
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    frames = check_number("frames", frames, minimum=1, integer=True)
    workers = check_number("workers", workers, minimum=1, integer=True)
    every = samples_per_command(data.dt)
    states = {"theta": data.motions["slave_theta"][:, ::every], "pose": data.motions["block_pose"][:, ::every],
              "tip": data.motions["slave_tip"][:, ::every], "side": np.asarray(data.episodes["side"]).astype(str),
              "shape": np.asarray(data.episodes["shape"]).astype(str)}
    jobs = [(states, seed, shard, min(POSE_SHARD, frames - start))
            for shard, start in enumerate(range(0, frames, POSE_SHARD))]
    if workers == 1:
        parts = [_render_shard(job) for job in jobs]
    else:
        # spawned, not forked: a fork after torch has run can hang in OpenMP
        with ProcessPoolExecutor(min(workers, len(jobs)), mp_context=multiprocessing.get_context("spawn")) as pool:
            parts = list(pool.map(_render_shard, jobs))
    images, tips, targets = (np.concatenate(x) for x in zip(*parts, strict=True))
    return images, tips, targets
