"""Building blocks for trajectory generators: batches of variable length, S-curve timing.

A batch of trajectories of different lengths is stored padded to the longest one by
repeating each trajectory's last sample, with the true lengths beside it. Models and losses
mask the padding; :func:`unpad` gives the trajectories back.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import torch

from ..errors import check_number
from ..physics.integrator import DT


@dataclass(frozen=True)
class TensorBatch:
    """A :class:`TrajectoryBatch` on the model's device (:meth:`TrajectoryBatch.to`).

    Attributes:
        states: ``(B, K_max, state_dim)`` float32; ``lengths``: ``(B,)`` int64;
        accel: ``(B, K_max - 1, accel_dim)`` float32 or None; extras: name → tensor in its NumPy dtype.
    """

    states: torch.Tensor
    lengths: torch.Tensor
    accel: torch.Tensor | None
    extras: dict[str, torch.Tensor]


@dataclass
class TrajectoryBatch:
    """Padded trajectories.

    Attributes:
        states: ``(B, K_max, state_dim)``, padded by repeating each trajectory's last sample.
        lengths: ``(B,)`` true lengths K (number of samples, ≥ 2).
        accel: ``(B, K_max - 1, accel_dim)`` inputs that produced ``states`` where the generator
            knows them (zero in the padding), else ``None``.
        extras: named per-trajectory arrays a task needs beside the states (e.g. the pan
            trajectory that produced a sliding command), same leading axes as ``states``.
    """

    states: np.ndarray
    lengths: np.ndarray
    accel: np.ndarray | None = None
    extras: dict[str, np.ndarray] | None = None

    def __len__(self) -> int:
        return self.states.shape[0]

    def select(self, index: np.ndarray | slice) -> TrajectoryBatch:
        extras = None if self.extras is None else {k: v[index] for k, v in self.extras.items()}
        accel = None if self.accel is None else self.accel[index]
        return TrajectoryBatch(self.states[index], self.lengths[index], accel, extras)

    def to(self, device: torch.device | str) -> TensorBatch:
        """The batch as tensors on ``device`` (what the trainer hands a task's ``loss``): ``states`` and
        ``accel`` in float32 (the model's precision), ``lengths`` int64, ``extras`` in their own dtypes."""
        def tensor(array: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(array)).to(device)

        return TensorBatch(
            tensor(self.states).float(), tensor(self.lengths),
            None if self.accel is None else tensor(self.accel).float(),
            {k: tensor(v) for k, v in (self.extras or {}).items()},
        )

    def longest_first(self) -> TrajectoryBatch:
        """The same trajectories sorted by length, longest first (stable). A batch's order is free; sorted, the
        encoder and the rollout skip trajectories that have ended without reordering anything, and a
        data-parallel rank's share (rows ``rank, rank + N, …``) is sorted too."""
        return self.select(np.argsort(-self.lengths, kind="stable"))


def draw_lengths(rng: np.random.Generator, n: int, length: int | tuple[int, int] | np.ndarray) -> np.ndarray:
    """Lengths K: a fixed int, uniform integers in the inclusive range ``(lo, hi)``, or given per trajectory."""
    if isinstance(length, np.ndarray):
        if length.shape != (n,) or length.min(initial=2) < 2:
            raise ValueError(f"per-trajectory lengths must be ({n},) integers >= 2, got {length!r}")
        return length.astype(np.int64)
    if isinstance(length, (int, np.integer)):
        return np.full(n, check_number("trajectory length", length, minimum=2, integer=True))
    lo, hi = (int(v) for v in length)
    if not 2 <= lo <= hi:
        raise ValueError(f"length range must satisfy 2 <= lo <= hi, got ({lo}, {hi})")
    return rng.integers(lo, hi + 1, size=n)


def normalized_time(lengths: np.ndarray) -> np.ndarray:
    """``τ[b, k] = k / (K_b - 1)`` clipped to 1, for k < K_max: ``(B, K_max)`` in [0, 1].

    Clipping makes every quantity computed from τ repeat its last value in the padding.
    """
    k = np.arange(int(lengths.max()))
    return np.minimum(k[None, :] / (lengths[:, None] - 1.0), 1.0)


def repeat_last(values: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Overwrite the padding of ``(B, K_max, ...)`` with each trajectory's last real sample."""
    idx = np.minimum(np.arange(values.shape[1])[None, :], lengths[:, None] - 1)
    return np.take_along_axis(values, idx.reshape(idx.shape + (1,) * (values.ndim - 2)), axis=1)


def combine(lengths: np.ndarray, parts: list[tuple[np.ndarray, TrajectoryBatch]], extras: tuple[str, ...] = ()):
    """Assemble trajectories generated in groups (e.g. two families of a mixture) into one batch.

    Args:
        lengths: ``(B,)`` lengths of the whole batch.
        parts: ``(indices, batch)`` pairs that together cover ``0..B-1``.
        extras: names of per-sample extras to carry over (zeros where a part has none).

    Returns:
        A :class:`TrajectoryBatch` padded to ``max(lengths)`` by repeating last samples.
    """
    k_max = int(lengths.max())

    def padded(values: np.ndarray) -> np.ndarray:
        return np.concatenate([values, np.repeat(values[:, -1:], k_max - values.shape[1], axis=1)], axis=1)

    states: np.ndarray | None = None
    carried: dict[str, np.ndarray] = {}
    for idx, part in parts:
        part_states = padded(part.states)
        if states is None:
            states = np.zeros((len(lengths),) + part_states.shape[1:])
        states[idx] = part_states
        for name in extras:
            if part.extras is not None and name in part.extras:
                value = padded(part.extras[name])
                carried.setdefault(name, np.zeros((len(lengths),) + value.shape[1:]))[idx] = value
    return TrajectoryBatch(states=states, lengths=lengths, extras=carried or None)


def tracking_rmse(achieved: np.ndarray, target: np.ndarray | None = None) -> np.ndarray | float:
    """How closely a motion follows another: the root mean square over the samples of the Euclidean distance
    between them, ``√(mean_k |a[k] - t[k]|²)``.

    Args:
        achieved: ``(..., K, d)`` positions (or, without ``target``, their errors already).
        target: ``(..., K, d)`` what they should have been.

    Returns:
        ``(...)`` in the unit of the positions (a float for a single motion); NaN for a motion of no samples
        (nothing was tracked).
    """
    err = np.asarray(achieved, dtype=np.float64)
    if target is not None:
        err = err - np.asarray(target, dtype=np.float64)
    if err.ndim < 2:
        raise ValueError(f"tracking_rmse needs (..., K, d) positions, got shape {err.shape}")
    if err.shape[-2] == 0:
        out = np.full(err.shape[:-2], np.nan)
    else:
        out = np.sqrt(np.mean(np.sum(err**2, axis=-1), axis=-1))
    return float(out) if out.ndim == 0 else out


def unpad(batch: TrajectoryBatch) -> list[np.ndarray]:
    """The trajectories of a batch as a list of ``(K_b, state_dim)`` arrays."""
    return [batch.states[b, : batch.lengths[b]] for b in range(len(batch))]


@lru_cache(maxsize=8)
def _s_curve_table(accel_fraction: float, jerk_fraction: float, grid: int = 20001) -> tuple[np.ndarray, ...]:
    """Tabulate a normalised jerk-limited S-curve s(τ) on τ ∈ [0, 1] with s(0)=0, s(1)=1.

    The acceleration is a trapezoid over the first ``accel_fraction`` of the motion (its
    ramps take ``jerk_fraction`` of that phase, i.e. constant jerk), zero while cruising,
    and the mirrored trapezoid at the end, so velocity and acceleration are zero at both
    ends and jerk is bounded.
    """
    ta = accel_fraction
    tj = 0.5 * jerk_fraction * ta
    knots = np.array([0.0, tj, ta - tj, ta, 1 - ta, 1 - ta + tj, 1 - tj, 1.0])
    values = np.array([0.0, 1.0, 1.0, 0.0, 0.0, -1.0, -1.0, 0.0])
    tau = np.linspace(0.0, 1.0, grid)
    acc = np.interp(tau, knots, values)
    h = tau[1] - tau[0]
    vel = np.concatenate([[0.0], np.cumsum(0.5 * (acc[1:] + acc[:-1]) * h)])
    pos = np.concatenate([[0.0], np.cumsum(0.5 * (vel[1:] + vel[:-1]) * h)])
    scale = pos[-1]
    return tau, pos / scale, vel / scale, acc / scale


def s_curve(tau: np.ndarray, accel_fraction: float = 1 / 3, jerk_fraction: float = 0.5) -> tuple[np.ndarray, ...]:
    """S-curve progress along a path at normalised times ``tau`` ∈ [0, 1].

    Returns:
        ``(s, ds/dτ, d²s/dτ²)`` with the shape of ``tau``; s goes 0 → 1 with zero velocity and
        acceleration at both ends (jerk-limited acceleration/deceleration).
    """
    check_number("accel_fraction", accel_fraction, minimum=0.0, strict_minimum=True, maximum=0.5)
    check_number("jerk_fraction", jerk_fraction, minimum=0.0, strict_minimum=True, maximum=1.0)
    grid, s, ds, dds = _s_curve_table(float(accel_fraction), float(jerk_fraction))
    flat = np.asarray(tau, dtype=np.float64).ravel()
    out = [np.interp(flat, grid, table).reshape(np.shape(tau)) for table in (s, ds, dds)]
    return out[0], out[1], out[2]


def quadratic_through(points: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The quadratic curve through three points at parameters 0, ½ and 1, and its derivative.

    Args:
        points: ``(B, 3, dim)`` — the control points c0, c1, c2 of each curve.
        s: ``(B, K)`` curve parameters.

    Returns:
        ``(value, d value / ds)``, both ``(B, K, dim)``.
    """
    s = s[..., None]
    basis = (2 * (s - 0.5) * (s - 1), -4 * s * (s - 1), 2 * s * (s - 0.5))
    dbasis = (4 * s - 3, 4 - 8 * s, 4 * s - 1)
    c0, c1, c2 = (points[:, None, i, :] for i in range(3))
    value = basis[0] * c0 + basis[1] * c1 + basis[2] * c2
    deriv = dbasis[0] * c0 + dbasis[1] * c1 + dbasis[2] * c2
    return value, deriv


def path_states(
    waypoints: np.ndarray, lengths: np.ndarray, dt: float = DT, timing: str = "s_curve"
) -> np.ndarray:
    """States ``[p, ṗ]`` moving along the quadratic path through three waypoints.

    Args:
        waypoints: ``(B, 3, dim)`` start, middle and end of each path.
        lengths: ``(B,)`` samples per trajectory (duration ``(K - 1) dt``).
        timing: ``"s_curve"`` (rest to rest, jerk-limited) or ``"linear"`` (uniform speed).

    Returns:
        ``(B, K_max, 2 dim)`` padded by repeating the last sample.
    """
    tau = normalized_time(lengths)
    if timing == "s_curve":
        s, ds, _ = s_curve(tau)
    elif timing == "linear":
        s, ds = tau, np.ones_like(tau)
    else:
        raise ValueError(f"timing must be 's_curve' or 'linear', got {timing!r}")
    pos, dpos = quadratic_through(waypoints, s)
    duration = (lengths[:, None, None] - 1) * dt
    vel = dpos * ds[..., None] / duration
    return np.concatenate([pos, vel], axis=-1)


def uniform_bspline(control: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Evaluate uniform cubic B-splines and their first two derivatives.

    Args:
        control: ``(B, N, dim)`` control points, N ≥ 4, on a uniform knot grid.
        u: ``(B, K)`` spline parameters in ``[0, N - 3]`` (segment index plus fraction).

    Returns:
        ``(value, d/du, d²/du²)``, each ``(B, K, dim)``.
    """
    n = control.shape[1]
    seg = np.clip(np.floor(u).astype(np.int64), 0, n - 4)
    t = (u - seg)[..., None]
    basis = ((1 - t) ** 3 / 6, (3 * t**3 - 6 * t**2 + 4) / 6, (-3 * t**3 + 3 * t**2 + 3 * t + 1) / 6, t**3 / 6)
    d1 = (-((1 - t) ** 2) / 2, (3 * t**2 - 4 * t) / 2, (-3 * t**2 + 2 * t + 1) / 2, t**2 / 2)
    d2 = (1 - t, 3 * t - 2, -3 * t + 1, t)
    pts = [np.take_along_axis(control, (seg + j)[..., None], axis=1) for j in range(4)]
    return tuple(sum(w * p for w, p in zip(ws, pts, strict=True)) for ws in (basis, d1, d2))  # type: ignore[return-value]
