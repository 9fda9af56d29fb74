"""Slicing the demonstrations: which episodes to train on, a subset or a union of sets, latents per position.

Everything here reads a :class:`~seqmotion.lfd.data.dataset.PushingDataset` and returns a new one (or arrays);
nothing steps a simulation or trains a network.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ..env.pushing import POSITIONS


def usable_episodes(data: Any, successful_only: bool) -> np.ndarray:
    """Indices of the demonstrations to train on (by default the successful ones); ``ValueError`` if < 2."""
    keep = np.flatnonzero(data.episodes["success"]) if successful_only else np.arange(len(data))
    if len(keep) < 2:
        raise ValueError(
            f"{data.path} has {len(keep)} usable demonstration(s) of {len(data)}; need at least 2 "
            "(successful_only=False keeps failed ones)"
        )
    return keep


def subset(data: Any, episodes: np.ndarray) -> Any:
    """The ``PushingDataset`` of these episodes only (every per-episode array indexed by them)."""
    def pick(tree: Any) -> Any:
        return {k: pick(v) for k, v in tree.items()} if isinstance(tree, dict) else np.asarray(tree)[episodes]

    return replace(
        data,
        motions=pick(data.motions),
        episodes=pick(data.episodes),
        operator=pick(data.operator),
        images=None if data.images is None else data.images[episodes],
        video=None if data.video is None else data.video[episodes],
    )


def concatenate(first: Any, second: Any) -> Any:
    """One ``PushingDataset`` of both sets' motions and episode records (no images: it trains a SeqAE)."""
    def join(a: Any, b: Any) -> Any:
        if isinstance(a, dict):
            return {k: join(a[k], b[k]) for k in a if k in b}
        return np.concatenate([np.asarray(a), np.asarray(b)])

    return replace(first, motions=join(first.motions, second.motions), episodes=join(first.episodes, second.episodes),
                   operator=join(first.operator, second.operator), images=None, video=None)


def mean_latent_per_position(z: np.ndarray, position_index: np.ndarray, medoid: bool = False) -> np.ndarray:
    """Mean of latents ``z (N, latent)`` over the demonstrations at each block position → ``(6, latent)``.

    ``position_index (N,)``: each demonstration's block position index 0..5. ``medoid``: instead
    of the mean, the z of the demonstration nearest it (see :class:`seqmotion.lfd.train.CNNTraining`). ``ValueError``
    when a position has no demonstration (its mean would be NaN).
    """
    z, where = np.asarray(z), np.asarray(position_index)
    missing = [i for i in range(len(POSITIONS)) if not np.any(where == i)]
    if missing:
        raise ValueError(f"no (successful) demonstration at block positions {missing}: their mean z is undefined")
    rows = []
    for i in range(len(POSITIONS)):
        here = z[where == i]
        mean = here.mean(0)
        rows.append(here[np.linalg.norm(here - mean, axis=1).argmin()] if medoid else mean)
    return np.stack(rows)
