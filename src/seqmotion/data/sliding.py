"""Command trajectories for sliding manipulation (ch. 3 §3.4.2, SPEC §4).

A command is the object's state relative to the pan, ``x_d = [x, y, vx, vy]`` (K, 4), from
rest at 0. Two families, seeded and vectorised:

* **physics type** — random pan shaking rolled out through the contact model; the pan
  trajectory that produced the command is kept (``extras["pan_states"]``) for the supervised
  loss L'. Half of them are *ratchet* shaking: a sawtooth pan velocity along a slowly turning
  direction, with a short slip phase whose acceleration exceeds μg (the object slides) and a
  long stick phase below it (the object rides along), zero-mean so the pan stays near home —
  the way shaking moves an object, for L' to teach. The other half are smooth random shaking:
  the pan's position is a cubic B-spline through random control points 40–120 ms apart and
  5–30 mm in amplitude, so its acceleration sometimes exceeds μg.
* **B-spline type** — the object's relative acceleration ``u_d`` is a uniform cubic B-spline
  through random control points 100–300 ms apart, integrated to ``x_d`` and scaled so the
  object travels at most 10–80 mm from its start: arbitrary paths with no pan behind them.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..physics import sliding as contact
from ..physics.integrator import DT, integrate
from .trajectories import (
    TrajectoryBatch,
    combine,
    draw_lengths,
    normalized_time,
    repeat_last,
    s_curve,
    uniform_bspline,
)

DEFAULT_LENGTH = (500, 1500)
SHAKE_SPACING_MS = (40, 120)
SHAKE_AMPLITUDE = (0.005, 0.03)  # m
RATCHET_PERIOD_MS = (40, 120)
RATCHET_SLIP_ACCEL = (1.2, 2.5)  # × μ g during the slip phase
RATCHET_STICK_ACCEL = (0.3, 0.8)  # × μ g during the stick phase
TURN_SPACING_MS = (150, 400)  # how fast the ratchet's direction and strength change
COMMAND_SPACING_MS = (100, 300)
COMMAND_REACH = (0.01, 0.08)  # m: the farthest the object gets from its start


def _knots(rng: np.random.Generator, lengths: np.ndarray, spacing_ms: tuple[int, int], dt: float):
    """Per trajectory: samples per B-spline segment and the parameter u of every sample."""
    samples_per_segment = rng.uniform(*spacing_ms, size=len(lengths)) * 1e-3 / dt
    k = np.arange(int(lengths.max()) - 1)[None, :]
    u = np.minimum(k, lengths[:, None] - 2) / samples_per_segment[:, None]
    n_control = int(np.ceil(u.max())) + 4
    return samples_per_segment, u, n_control


def _smooth_shaking(rng: np.random.Generator, lengths: np.ndarray, dt: float) -> np.ndarray:
    """Pan accelerations whose position is a random cubic B-spline (starts at rest): ``(n, K_max-1, 2)``."""
    n = len(lengths)
    per_segment, u, n_control = _knots(rng, lengths, SHAKE_SPACING_MS, dt)
    control = rng.uniform(*SHAKE_AMPLITUDE, size=(n, 1, 1)) * rng.normal(size=(n, n_control, 2))
    control[:, :3] = 0.0  # start at rest at the origin
    _, _, d2 = uniform_bspline(control, u)
    return d2 / (per_segment[:, None, None] * dt) ** 2


def _ratchet_shaking(rng: np.random.Generator, lengths: np.ndarray, mu: float, dt: float) -> np.ndarray:
    """Sawtooth-velocity pan shaking that ratchets the object along a turning direction: ``(n, K_max-1, 2)``.

    The pan velocity is ``e(t) S(t) d(t)``: a zero-mean sawtooth S rising slowly (stick phase,
    |u_p| below μg) and dropping fast (slip phase, |u_p| above μg), switched on and off by a
    smooth gate e ∈ [0, 1] that starts at 0, along a smoothly turning unit direction d. Accelerations
    are its exact discrete derivative, so the pan's velocity (and position) stay bounded.
    """
    n, k_max = len(lengths), int(lengths.max())
    mu_g = mu * contact.GRAVITY
    period = rng.uniform(*RATCHET_PERIOD_MS, size=(n, 1)) * 1e-3
    slip = rng.uniform(*RATCHET_SLIP_ACCEL, size=(n, 1)) * mu_g
    stick = rng.uniform(*RATCHET_STICK_ACCEL, size=(n, 1)) * mu_g
    slip_fraction = stick / (slip + stick)  # zero-mean acceleration over a period
    amplitude = slip * slip_fraction * period  # velocity drop across the slip phase
    t = np.minimum(np.arange(k_max)[None, :], lengths[:, None] - 1) * dt
    phase = np.mod(t / period + rng.uniform(size=(n, 1)), 1.0)
    rise = phase >= slip_fraction
    sawtooth = np.where(rise, (phase - slip_fraction) / (1 - slip_fraction), 1 - phase / slip_fraction) - 0.5
    per_segment, u, n_control = _knots(rng, lengths, TURN_SPACING_MS, dt)
    u = np.concatenate([u, u[:, -1:]], axis=1)  # one value per state sample
    angle_control = rng.uniform(-np.pi, np.pi, size=(n, 1, 1)) + rng.normal(scale=0.8, size=(n, n_control, 1))
    # mostly on, sometimes paused: scaling the sawtooth down would push its slip phase below μg
    strength_control = (rng.random(size=(n, n_control, 1)) < 0.8).astype(np.float64)
    strength_control[:, :2] = 0.0  # start at rest
    angle, _, _ = uniform_bspline(angle_control, u)
    strength, _, _ = uniform_bspline(strength_control, u)
    direction = np.concatenate([np.cos(angle), np.sin(angle)], axis=-1)
    velocity = np.clip(strength, 0.0, 1.0) * (amplitude[..., None] * sawtooth[..., None]) * direction
    velocity -= velocity[:, :1]  # exactly at rest at the start
    return np.diff(velocity, axis=1) / dt


def physics_type(
    n: int,
    rng: np.random.Generator,
    *,
    length: int | tuple[int, int] | np.ndarray = DEFAULT_LENGTH,
    mu: float = contact.MU,
    mu_dyn: float = contact.MU_DYN,
    dt: float = DT,
) -> TrajectoryBatch:
    """Commands produced by random pan shaking (returns the pan's states too, in ``extras``)."""
    lengths = draw_lengths(rng, n, length)
    ratchet = rng.random(n) < 0.5
    pan_accel = np.zeros((n, int(lengths.max()) - 1, 2))
    for idx, make in ((np.flatnonzero(ratchet), _ratchet_shaking), (np.flatnonzero(~ratchet), None)):
        if idx.size:
            part = _ratchet_shaking(rng, lengths[idx], mu, dt) if make else _smooth_shaking(rng, lengths[idx], dt)
            pan_accel[idx, : part.shape[1]] = part
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
    dt: float = DT,
) -> TrajectoryBatch:
    """B-spline type with probability ``bspline_prob``, else physics type (the ch. 3 curriculum's mixture).

    ``extras["pan_states"]`` holds the pan trajectory where one exists (zeros otherwise) and
    ``extras["has_pan"]`` (n,) says where.
    """
    if not 0.0 <= bspline_prob <= 1.0:
        raise ValueError(f"bspline_prob must be in [0, 1], got {bspline_prob}")
    pick_bspline = rng.random(n) < bspline_prob
    lengths = draw_lengths(rng, n, length)
    parts = []
    for use_bspline in (True, False):
        idx = np.flatnonzero(pick_bspline == use_bspline)
        if idx.size:
            make = bspline_type if use_bspline else physics_type
            parts.append((idx, make(idx.size, rng, length=lengths[idx], dt=dt)))
    batch = combine(lengths, parts, extras=("pan_states",))
    if batch.extras is None:  # only B-spline commands: no pan behind any of them
        batch.extras = {"pan_states": np.zeros_like(batch.states)}
    batch.extras["has_pan"] = ~pick_bspline
    return batch


def circle(radius: float = 0.05, length: int = 1200, dt: float = DT) -> np.ndarray:
    """A command moving the object once around a circle of ``radius`` [m], rest to rest: ``(K, 4)``.

    It starts at the origin (the circle's centre is at ``(-radius, 0)``) and follows an S-curve in angle.
    """
    if not radius > 0 or length < 2:
        raise ValueError("need radius > 0 and length >= 2")
    tau = normalized_time(np.array([length]))[0]
    s, ds, _ = s_curve(tau)
    phi, dphi = 2 * math.pi * s, 2 * math.pi * ds / ((length - 1) * dt)
    pos = radius * np.stack([np.cos(phi) - 1.0, np.sin(phi)], axis=1)
    vel = radius * dphi[:, None] * np.stack([-np.sin(phi), np.cos(phi)], axis=1)
    return np.concatenate([pos, vel], axis=1)
