"""Command trajectories for sliding manipulation (ch. 3 §3.4.2, SPEC §4).

A command is the object's state relative to the pan, ``x_d = [x, y, vx, vy]`` (K, 4), from
rest at 0. Two families, seeded and vectorised:

* the *physics type* — random pan shaking rolled out through the contact model, so its
  acceleration often exceeds μg and the object slides; the pan trajectory that produced the
  command is kept (``extras["pan_states"]``) for the supervised loss L'. Two shakings:

  - ``"position"`` (default): the pan's position is a uniform cubic B-spline through random
    control points 40–120 ms apart with a random amplitude of 5–30 mm. The pan always stays
    near home (99 % of shakes within 7 cm), so the pan's return is predictable from the past.
  - ``"velocity"``: the pan's *velocity* is such a B-spline (amplitude 0.2–0.8 m/s), so its
    position random-walks (median farthest 0.16 m, 10 % beyond 0.34 m) with about the same
    share of accelerations above μg. Each slip displaces the pan and nothing brings it back,
    so a model imitating these pans (L' alone: model C) learns to let the pan drift with the
    object's travel — the dissertation's model C, which drove the pan past its range.

  (A ratchet-like, zero-mean sawtooth shaking was tried too: L' then learned its mean, a
  nearly still pan, and training never left the gradient-vanishing zone.)
* **B-spline type** — the object's relative acceleration ``u_d`` is a uniform cubic B-spline
  through random control points 100–300 ms apart, integrated to ``x_d`` and scaled so the
  object travels at most 10–80 mm from its start: arbitrary paths with no pan behind them.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from ...data.trajectories import (
    TrajectoryBatch,
    combine,
    draw_lengths,
    normalized_time,
    repeat_last,
    s_curve,
    uniform_bspline,
)
from ...errors import check_number
from ...physics.integrator import DT, integrate
from . import physics as contact

DEFAULT_LENGTH = (500, 1500)
SHAKE_SPACING_MS = (40, 120)
SHAKE_AMPLITUDE = (0.005, 0.03)  # m: control-point spread of the "position" shaking
SHAKE_VELOCITY = (0.2, 0.8)  # m/s: control-point spread of the "velocity" shaking
PAN_SHAKINGS = ("position", "velocity")
COMMAND_SPACING_MS = (100, 300)
COMMAND_REACH = (0.01, 0.08)  # m: the farthest the object gets from its start


def _knots(rng: np.random.Generator, lengths: np.ndarray, spacing_ms: tuple[int, int], dt: float):
    """Per trajectory: samples per B-spline segment and the parameter u of every sample."""
    samples_per_segment = rng.uniform(*spacing_ms, size=len(lengths)) * 1e-3 / dt
    k = np.arange(int(lengths.max()) - 1)[None, :]
    u = np.minimum(k, lengths[:, None] - 2) / samples_per_segment[:, None]
    n_control = int(np.ceil(u.max())) + 4
    return samples_per_segment, u, n_control


def check_shaking(shaking: str) -> None:
    """``ValueError`` unless ``shaking`` names one of :data:`PAN_SHAKINGS`."""
    if shaking not in PAN_SHAKINGS:
        raise ValueError(f"unknown pan shaking {shaking!r}; choose from {PAN_SHAKINGS}")


def _smooth_shaking(rng: np.random.Generator, lengths: np.ndarray, dt: float, shaking: str = "position") -> np.ndarray:
    """Pan accelerations whose position (or velocity) is a random cubic B-spline: ``(n, K_max-1, 2)``.

    The pan starts at rest at the origin either way.
    """
    check_shaking(shaking)
    n = len(lengths)
    per_segment, u, n_control = _knots(rng, lengths, SHAKE_SPACING_MS, dt)
    spread = SHAKE_AMPLITUDE if shaking == "position" else SHAKE_VELOCITY
    control = rng.uniform(*spread, size=(n, 1, 1)) * rng.normal(size=(n, n_control, 2))
    control[:, :3] = 0.0  # start at rest (and, for "position", at the origin)
    _, d1, d2 = uniform_bspline(control, u)
    seconds_per_segment = per_segment[:, None, None] * dt
    if shaking == "position":
        return d2 / seconds_per_segment**2
    return d1 / seconds_per_segment


def physics_type(
    n: int,
    rng: np.random.Generator,
    *,
    length: int | tuple[int, int] | np.ndarray = DEFAULT_LENGTH,
    mu: float | np.ndarray = contact.MU,
    mu_dyn: float | np.ndarray = contact.MU_DYN,
    dt: float = DT,
    shaking: str = "position",
) -> TrajectoryBatch:
    """Commands produced by random pan shaking (returns the pan's states too, in ``extras``).

    ``mu``, ``mu_dyn``: the friction the shaking is rolled out with, scalars or ``(n,)``.
    ``shaking``: ``"position"`` (a bounded shake around home) or ``"velocity"`` (a drifting one).
    """
    lengths = draw_lengths(rng, n, length)
    pan_accel = _smooth_shaking(rng, lengths, dt, shaking)
    valid = np.arange(pan_accel.shape[1])[None, :] < (lengths[:, None] - 1)
    pan_accel = np.where(valid[..., None], pan_accel, 0.0)
    pan_states, rel_states = contact.rollout(pan_accel, mu, mu_dyn, dt)
    return TrajectoryBatch(
        states=repeat_last(rel_states, lengths),
        lengths=lengths,
        extras={"pan_states": repeat_last(pan_states, lengths), "pan_accel": pan_accel},
    )


def bspline_type(
    n: int,
    rng: np.random.Generator,
    *,
    length: int | tuple[int, int] | np.ndarray = DEFAULT_LENGTH,
    dt: float = DT,
) -> TrajectoryBatch:
    """Commands whose relative acceleration is a random cubic B-spline (no pan behind them)."""
    lengths = draw_lengths(rng, n, length)
    per_segment, u, n_control = _knots(rng, lengths, COMMAND_SPACING_MS, dt)
    control = rng.normal(size=(n, n_control, 2))
    control[:, :2] = 0.0  # u_d starts from 0
    accel, _, _ = uniform_bspline(control, u)
    valid = np.arange(accel.shape[1])[None, :] < (lengths[:, None] - 1)
    accel = np.where(valid[..., None], accel, 0.0)
    states = integrate(torch.zeros(n, 4, dtype=torch.float64), torch.from_numpy(accel), dt).numpy()
    states = repeat_last(states, lengths)
    reach = np.linalg.norm(states[..., :2], axis=-1).max(axis=1)
    scale = rng.uniform(*COMMAND_REACH, size=n) / np.maximum(reach, 1e-12)
    return TrajectoryBatch(states=states * scale[:, None, None], lengths=lengths, accel=accel * scale[:, None, None])


def mixture(
    n: int,
    rng: np.random.Generator,
    *,
    bspline_prob: float,
    length: int | tuple[int, int] = DEFAULT_LENGTH,
    mu: float | np.ndarray = contact.MU,
    mu_dyn: float | np.ndarray = contact.MU_DYN,
    dt: float = DT,
    shaking: str = "position",
) -> TrajectoryBatch:
    """B-spline type with probability ``bspline_prob``, else physics type (the ch. 3 curriculum's mixture).

    ``extras["pan_states"]`` holds the pan trajectory where one exists (zeros otherwise) and
    ``extras["has_pan"]`` (n,) says where. ``mu``, ``mu_dyn`` (scalars or ``(n,)``) are the
    friction the physics-type commands are rolled out with; ``shaking`` is their pan shaking.
    """
    check_number("bspline_prob", bspline_prob, minimum=0.0, maximum=1.0)
    pick_bspline = rng.random(n) < bspline_prob
    lengths = draw_lengths(rng, n, length)
    mu_all, mud_all = np.broadcast_to(mu, (n,)), np.broadcast_to(mu_dyn, (n,))
    parts = []
    for use_bspline in (True, False):
        idx = np.flatnonzero(pick_bspline == use_bspline)
        if idx.size == 0:
            continue
        if use_bspline:
            parts.append((idx, bspline_type(idx.size, rng, length=lengths[idx], dt=dt)))
        else:
            parts.append((idx, physics_type(idx.size, rng, length=lengths[idx], mu=mu_all[idx], mu_dyn=mud_all[idx],
                                            dt=dt, shaking=shaking)))
    batch = combine(lengths, parts, extras=("pan_states",))
    if batch.extras is None:  # only B-spline commands: no pan behind any of them
        batch.extras = {"pan_states": np.zeros_like(batch.states)}
    batch.extras["has_pan"] = ~pick_bspline
    return batch


def along_s_curve(path: Any, length: int, dt: float = DT) -> np.ndarray:
    """A command ``(K, 4)`` following ``path(s) -> (position (K, 2), d position / ds (K, 2))`` for s from 0
    to 1 on an S-curve in time: rest to rest, ``length`` samples."""
    check_number("length", length, minimum=2, integer=True)
    tau = normalized_time(np.array([length]))[0]
    s, ds, _ = s_curve(tau)
    pos, dpos = path(s)
    return np.concatenate([pos, dpos * (ds / ((length - 1) * dt))[:, None]], axis=1)


def circle(radius: float = 0.05, length: int = 1200, dt: float = DT) -> np.ndarray:
    """A command moving the object once around a circle of ``radius`` [m], rest to rest: ``(K, 4)``.

    It starts at the origin (the circle's centre is at ``(-radius, 0)``) and follows an S-curve in angle.
    """
    check_number("radius", radius, minimum=0.0, strict_minimum=True)
    return along_s_curve(lambda s: (radius * np.stack([np.cos(2 * math.pi * s) - 1.0, np.sin(2 * math.pi * s)], 1),
                                    2 * math.pi * radius * np.stack([-np.sin(2 * math.pi * s),
                                                                     np.cos(2 * math.pi * s)], 1)), length, dt)


def line(distance: float = 0.05, length: int = 500, dt: float = DT) -> np.ndarray:
    """A command moving the object ``distance`` [m] along x, rest to rest: ``(K, 4)``."""
    check_number("distance", distance, minimum=0.0, strict_minimum=True)
    return along_s_curve(lambda s: (np.stack([distance * s, 0 * s], 1), np.stack([distance + 0 * s, 0 * s], 1)),
                         length, dt)


def figure_eight(half_width: float = 0.02, length: int = 1200, dt: float = DT) -> np.ndarray:
    """A figure-eight ``x = a sin φ, y = (a/2) sin 2φ``, φ from 0 to 2π, from the crossing at the origin:
    ``(K, 4)``, ``a = half_width`` [m]."""
    check_number("half_width", half_width, minimum=0.0, strict_minimum=True)

    def path(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        phi = 2 * math.pi * s
        pos = np.stack([half_width * np.sin(phi), 0.5 * half_width * np.sin(2 * phi)], 1)
        return pos, 2 * math.pi * half_width * np.stack([np.cos(phi), np.cos(2 * phi)], 1)

    return along_s_curve(path, length, dt)
