"""The double integrator every task is built on (SPEC §2, eqs. 2.1–2.5 and 3.3–3.8).

State per axis is ``[position, velocity]``; a state vector stacks all positions, then all
velocities: ``x = [p_1..p_d, v_1..v_d]``. One step of ``dt`` seconds under acceleration ``u``::

    x[k+1] = A x[k] + B u[k],   A = [[I, dt I], [0, I]],   B = [[dt²/2 I], [dt I]]

Sequences are integrated in closed form with cumulative sums instead of a Python loop over
samples: with ``S1[n] = Σ_{j<n} u[j]`` and ``S2[n] = Σ_{m<n} S1[m]``::

    v[n] = v[0] + dt S1[n]
    p[n] = p[0] + n dt v[0] + dt² (S2[n] + S1[n] / 2)

Covariances follow ``S_x[k+1] = A S_x[k] Aᵀ + B S_u[k] Bᵀ`` (eq. 2.14). Inputs are
independent across samples, so the position block after ``n`` steps is::

    P[n] = P0 + n dt (X0 + X0ᵀ) + n² dt² V0 + dt⁴ Σ_{j<n} (n - j - 1/2)² S_u[j]

(X = position–velocity cross covariance, V = velocity covariance) and the sum is a fixed
lower-triangular ``C × C`` matrix applied along time: exact, with no cancellation.

Every integration and covariance propagation of a double integrator in the library is one of these:

* states: :func:`integrate` (tensors) and :func:`integrate_numpy` (the same operations in NumPy), and for a
  decoder's chunk :func:`integrate_chunk` (the same closed form as two matrix products instead of ~15 small
  operations: the decoder's step is the training's hot loop);
* covariances: :func:`propagate_covariance` (one chunk from a carried covariance: the decoder's step),
  :func:`propagate_entrywise` (all N·C samples of a rollout at once, each non-zero entry of ``S_u`` alike, with
  the carries at the chunk boundaries and teacher forcing's restarts: the training's fast path) and
  :func:`integrate_covariance` (a whole motion from a known state in O(K), for the predicted std after a
  rollout; the chunk forms' C × C weights would be K × K there);
* the definitions sample by sample, which the closed forms agree with: :func:`step_reference`,
  :func:`propagate_covariance_reference`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import torch

DT = 1e-3
"""Sampling interval used everywhere in the dissertation [s]."""


def transition_matrices(dim: int, dt: float = DT) -> tuple[np.ndarray, np.ndarray]:
    """``A`` (2d × 2d) and ``B`` (2d × d) of the discrete double integrator."""
    eye = np.eye(dim)
    a = np.block([[eye, dt * eye], [np.zeros((dim, dim)), eye]])
    b = np.vstack([0.5 * dt**2 * eye, dt * eye])
    return a, b


def integrate(x0: torch.Tensor, accel: torch.Tensor, dt: float = DT) -> torch.Tensor:
    """Integrate accelerations from ``x0`` in closed form.

    Args:
        x0: ``(..., 2d)`` initial states.
        accel: ``(..., N, d)`` accelerations ``u[0..N-1]``.

    Returns:
        ``(..., N + 1, 2d)`` states ``x[0..N]`` (``x[0] = x0``).
    """
    d = accel.shape[-1]
    p0, v0 = x0[..., :d].unsqueeze(-2), x0[..., d:].unsqueeze(-2)
    zero = torch.zeros_like(accel[..., :1, :])
    s1 = torch.cat([zero, accel.cumsum(-2)], dim=-2)  # S1[n], n = 0..N
    s2 = torch.cat([zero, s1[..., :-1, :].cumsum(-2)], dim=-2)  # S2[n]
    n = torch.arange(accel.shape[-2] + 1, dtype=accel.dtype, device=accel.device).unsqueeze(-1)
    v = v0 + dt * s1
    p = p0 + n * dt * v0 + dt**2 * (s2 + 0.5 * s1)
    return torch.cat([p, v], dim=-1)


def integrate_numpy(x0: np.ndarray, accel: np.ndarray, dt: float = DT) -> np.ndarray:
    """:func:`integrate` in NumPy float64 (same shapes, the same operations in the same order: bit for bit
    what :func:`integrate` gives in float64), for callers without tensors (the simulator's references,
    transcriptions, deployment)."""
    x0, accel = np.asarray(x0, dtype=np.float64), np.asarray(accel, dtype=np.float64)
    d = accel.shape[-1]
    p0, v0 = x0[..., None, :d], x0[..., None, d:]
    zero = np.zeros_like(accel[..., :1, :])
    s1 = np.concatenate([zero, np.cumsum(accel, axis=-2)], axis=-2)  # S1[n], n = 0..N
    s2 = np.concatenate([zero, np.cumsum(s1[..., :-1, :], axis=-2)], axis=-2)  # S2[n]
    n = np.arange(accel.shape[-2] + 1, dtype=np.float64)[:, None]
    v = v0 + dt * s1
    p = p0 + n * dt * v0 + dt**2 * (s2 + 0.5 * s1)
    return np.concatenate([p, v], axis=-1)


def implied_accel(states: np.ndarray, dt: float = DT) -> np.ndarray:
    """The inputs ``u[0..K-2]`` a double integrator needs to follow the velocities of ``(..., K, 2d)`` states.

    Exact for states produced by :func:`integrate` (``v[k+1] = v[k] + dt u[k]``); for any
    other trajectory, the velocity's finite difference.
    """
    d = states.shape[-1] // 2
    return np.diff(states[..., d:], axis=-2) / dt


def reach_end(
    x0: np.ndarray, accel: np.ndarray, columns: list[int], values: np.ndarray, weights: np.ndarray | None = None,
    dt: float = DT,
) -> np.ndarray:
    """The inputs nearest ``accel`` (``min Σ_k w ⊙ |Δu[k]|²``) whose motion from ``x0`` ends at ``values``.

    The end state is linear in the inputs — per axis j, ``p[N] = p0 + N dt v0 + dt² Σ_k (N − k − 1/2) u[k]``
    and ``v[N] = v0 + dt Σ_k u[k]`` — so the nearest inputs are a closed-form, per-axis correction
    (a ramp in k), here with the least-squares solution of the (at most 2 × 2) system per axis.

    Args:
        x0: ``(2d,)`` start state; ``accel``: ``(N, d)`` inputs.
        columns: state columns that must end at ``values`` (positions ``j``, velocities ``d + j``).
        weights: ``(d,)`` the metric per input component (default 1).
    """
    accel = np.asarray(accel, dtype=np.float64)
    n, d = accel.shape
    end = integrate_numpy(x0, accel, dt)[-1]
    k = np.arange(n)
    out = accel.copy()
    for j in range(d):
        rows, gap = [], []
        for c, value in zip(columns, np.asarray(values, dtype=np.float64), strict=True):
            if c == j:  # position of axis j
                rows.append(dt**2 * (n - k - 0.5))
                gap.append(value - end[c])
            elif c == d + j:  # velocity of axis j
                rows.append(np.full(n, dt))
                gap.append(value - end[c])
        if not rows:
            continue
        g = np.stack(rows) / (1.0 if weights is None else weights[j])  # W⁻¹ Gᵀ, transposed
        gram = np.stack(rows) @ g.T
        out[:, j] += g.T @ np.linalg.lstsq(gram, np.asarray(gap), rcond=None)[0]
    return out


def step_reference(x: np.ndarray, u: np.ndarray, dt: float = DT) -> np.ndarray:
    """One explicit ``A x + B u`` step: the definition (eq. 2.13) sample by sample, which the closed forms
    agree with."""
    a, b = transition_matrices(u.shape[-1], dt)
    return x @ a.T + u @ b.T


@lru_cache(maxsize=32)
def _covariance_weights(chunk: int, dt: float, dtype: torch.dtype, device: str) -> torch.Tensor:
    """``W[n-1, j] = dt⁴ (n - j - 1/2)²`` for ``j < n``, n = 1..C (the position block)."""
    n = torch.arange(1, chunk + 1, dtype=torch.float64).unsqueeze(1)
    j = torch.arange(chunk, dtype=torch.float64).unsqueeze(0)
    w = torch.where(j < n, (n - j - 0.5) ** 2, torch.zeros(()))
    return (dt**4 * w).to(dtype=dtype, device=device)


@dataclass
class CovarianceCarry:
    """Covariance of the state at a chunk boundary, as position/cross/velocity blocks.

    All fields are ``(B, d, d)``: ``pos`` = Cov(p), ``cross`` = Cov(p, v), ``vel`` = Cov(v).
    """

    pos: torch.Tensor
    cross: torch.Tensor
    vel: torch.Tensor

    @classmethod
    def zeros(cls, batch: int, dim: int, dtype: torch.dtype, device: torch.device) -> CovarianceCarry:
        z = torch.zeros(batch, dim, dim, dtype=dtype, device=device)
        return cls(z, z, z)

    def narrow(self, rows: int) -> CovarianceCarry:
        """The covariances of the first ``rows`` trajectories."""
        return CovarianceCarry(self.pos[:rows], self.cross[:rows], self.vel[:rows])

    def reset_where(self, mask: torch.Tensor) -> CovarianceCarry:
        """Zero the covariance of the trajectories where ``mask`` (B,) is true (a known state)."""
        keep = (~mask).to(self.pos.dtype).view(-1, 1, 1)
        return CovarianceCarry(self.pos * keep, self.cross * keep, self.vel * keep)


def propagate_covariance(
    carry: CovarianceCarry, accel_cov: torch.Tensor, dt: float = DT
) -> tuple[torch.Tensor, CovarianceCarry]:
    """Propagate eq. 2.14 across one chunk.

    Args:
        carry: covariance at the chunk's first state.
        accel_cov: ``(B, C, d, d)`` covariances ``S_u`` of the chunk's accelerations.

    Returns:
        ``(pos_cov, new_carry)``: ``pos_cov`` is ``(B, C, d, d)``, the position covariance of
        the C states that follow, and ``new_carry`` the covariance at the chunk's last state.
    """
    b, c, d, _ = accel_cov.shape
    w = _covariance_weights(c, dt, accel_cov.dtype, str(accel_cov.device))
    n = torch.arange(1, c + 1, dtype=accel_cov.dtype, device=accel_cov.device).view(1, c, 1, 1)
    flat = accel_cov.reshape(b, c, d * d).transpose(1, 2)  # (B, d², C)
    driven = (flat @ w.T).transpose(1, 2).reshape(b, c, d, d)
    cross_sym = carry.cross + carry.cross.transpose(-1, -2)
    pos = (
        carry.pos.unsqueeze(1)
        + n * dt * cross_sym.unsqueeze(1)
        + (n * dt) ** 2 * carry.vel.unsqueeze(1)
        + driven
    )
    # Carry to the chunk's last state: cross and velocity blocks need first/zeroth moments.
    j = torch.arange(c, dtype=accel_cov.dtype, device=accel_cov.device).view(1, c, 1, 1)
    sum_s = accel_cov.sum(1)
    sum_ws = ((c - j - 0.5) * accel_cov).sum(1)
    cross = carry.cross + c * dt * carry.vel + dt**3 * sum_ws
    vel = carry.vel + dt**2 * sum_s
    return pos, CovarianceCarry(pos[:, -1], cross, vel)


def integrate_covariance(accel_cov: torch.Tensor, dt: float = DT) -> torch.Tensor:
    """Position covariances ``(B, N, d, d)`` of states ``1..N`` of a double integrator started from a known
    state under independent inputs with covariances ``accel_cov`` ``(B, N, d, d)`` (eq. 2.14), in one pass:
    ``P[n] = dt⁴ Σ_{j<n} (n - j - ½)² S[j] = dt⁴ (n² C0[n] - 2n C1[n] + C2[n])`` with the cumulative sums
    ``C_m[n] = Σ_{j<n} (j + ½)^m S[j]``. Run it in float64 (the three terms cancel to about a sixth)."""
    n_steps = accel_cov.shape[1]
    a = torch.arange(n_steps, dtype=accel_cov.dtype, device=accel_cov.device).view(1, -1, 1, 1) + 0.5
    n = a + 0.5  # n = j + 1 for the state after input j
    c0, c1, c2 = accel_cov.cumsum(1), (a * accel_cov).cumsum(1), (a * a * accel_cov).cumsum(1)
    return dt**4 * (n * n * c0 - 2 * n * c1 + c2)


@lru_cache(maxsize=32)
def _integration_maps(steps: int, dim: int, dt: float, dtype: torch.dtype, device: str) -> tuple[torch.Tensor, ...]:
    """``(X, U)`` with ``x[1..N] = (x0 @ X + u_flat @ U).view(N, 2d)`` for the double integrator: ``X``
    ``(2d, N·2d)`` carries the start state, ``U`` ``(N·d, N·2d)`` the inputs (``u_flat`` = ``u`` ``(N, d)``
    flattened), entries ``dt² (n - j - 1/2)`` (position) and ``dt`` (velocity) for ``j < n``."""
    n = np.arange(1, steps + 1)
    x_map = np.zeros((2 * dim, steps, 2 * dim))
    u_map = np.zeros((steps, dim, steps, 2 * dim))
    lower = np.arange(steps)[:, None] < n[None, :]  # [j, n-1]: input j acts on state n
    for a in range(dim):
        x_map[a, :, a] = 1.0
        x_map[dim + a, :, a] = n * dt
        x_map[dim + a, :, dim + a] = 1.0
        u_map[:, a, :, a] = np.where(lower, dt**2 * (n[None, :] - np.arange(steps)[:, None] - 0.5), 0.0)
        u_map[:, a, :, dim + a] = np.where(lower, dt, 0.0)
    as_t = {"dtype": dtype, "device": device}
    with torch.inference_mode(False):  # cached: must be usable by autograd even if first made in inference mode
        return (torch.tensor(x_map.reshape(2 * dim, -1), **as_t),
                torch.tensor(u_map.reshape(steps * dim, -1), **as_t))


def integrate_chunk(x0: torch.Tensor, accel: torch.Tensor, dt: float = DT) -> torch.Tensor:
    """The states ``x[1..N]`` ``(B, N, 2d)`` that accelerations ``(B, N, d)`` produce from ``x0`` ``(B, 2d)``:
    :func:`integrate` without its first state, as two matrix products (the closed form is linear in the start
    state and the inputs). The same numbers as :func:`integrate` up to float rounding, with 2 operations
    (and 2 in the backward pass) instead of ~15 (cumulative sums, concatenations) for a decoder's chunk."""
    b, steps, dim = accel.shape
    x_map, u_map = _integration_maps(steps, dim, dt, accel.dtype, str(accel.device))
    return torch.addmm(x0.to(accel.dtype) @ x_map, accel.reshape(b, -1), u_map).view(b, steps, 2 * dim)


@lru_cache(maxsize=32)
def _chunk_covariance_map(chunk: int, dt: float, dtype: torch.dtype, device: str) -> torch.Tensor:
    """``(C + 2, C)``: rows ``0..C-1`` the driven position block :func:`_covariance_weights`, row C the plain
    sum ``Σ_j S[j]``, row C+1 ``Σ_j (C - j - 1/2) S[j]`` — everything one chunk's inputs contribute, as one
    matrix applied along time."""
    with torch.inference_mode(False):  # cached: must be usable by autograd even if first made in inference mode
        n = torch.arange(1, chunk + 1, dtype=torch.float64).unsqueeze(1)
        j = torch.arange(chunk, dtype=torch.float64).unsqueeze(0)
        w = dt**4 * torch.where(j < n, (n - j - 0.5) ** 2, torch.zeros(()))
        extra = torch.stack([torch.ones(chunk, dtype=torch.float64), chunk - j[0] - 0.5])
        return torch.cat([w, extra]).to(dtype=dtype, device=device)


@lru_cache(maxsize=32)
def _carry_basis(chunk: int, dt: float, dtype: torch.dtype, device: str) -> torch.Tensor:
    """``(3, C)``: how a chunk's starting ``P0, X0 + X0ᵀ, V0`` reach its n = 1..C positions (1, n dt, (n dt)²)."""
    with torch.inference_mode(False):  # cached: must be usable by autograd even if first made in inference mode
        t = dt * torch.arange(1, chunk + 1, dtype=torch.float64)
        return torch.stack([torch.ones_like(t), t, t**2]).to(dtype=dtype, device=device)


def propagate_entrywise(
    entries: torch.Tensor, known: torch.Tensor, chunk: int, dt: float = DT
) -> torch.Tensor:
    """Eq. 2.14 over N whole chunks at once, entry by entry: the position covariance of every sample.

    The double integrator's covariance recursion acts on every entry of ``S_u`` alike (per axis pair it
    is the same fixed linear map along time), so the non-zero entries of ``S_u`` are propagated
    independently. Within chunk k (``n = 1..C`` steps into it)::

        P[n] = P0 + n dt (X0 + X0ᵀ) + n² dt² V0 + dt⁴ Σ_{j<n} (n - j - 1/2)² S[j]

    as in :func:`propagate_covariance`; the carries ``P0, X0, V0`` at chunk boundaries follow a short
    recursion over the N chunks (zero where a chunk starts from a known state). X stays symmetric (it
    starts at 0 and only symmetric terms are added), so ``X0 + X0ᵀ = 2 X0``.

    Args:
        entries: ``(B, E, N·C)`` E entries of ``S_u`` per sample (e.g. ``σ_y², σ_z², σ_θ², ρ σ_y σ_z``), each
            entry's series along time.
        known: ``(B, N)`` bool, chunk k starts from a known state (covariance zero).
        chunk: C.

    Returns:
        ``(B, E, N·C)``: the same entries of the position covariance of the states that follow each input.
    """
    b, e, total = entries.shape
    n_chunks = total // chunk
    if n_chunks * chunk != total or known.shape != (b, n_chunks):
        raise ValueError(f"entries of {total} samples are not {known.shape[-1]} chunks of {chunk}")
    m = _chunk_covariance_map(chunk, dt, entries.dtype, str(entries.device))
    # time innermost: the map is one plain matrix product (B·E·N, C) @ (C, C + 2)
    local = (entries.reshape(-1, chunk) @ m.T).view(b, e, n_chunks, chunk + 2)  # driven block, Σ S, Σ (C-j-½) S
    # Split and unbound once (their gradients are one concatenation or stack each; a slice or select per
    # chunk would each fill a zero tensor the size of the whole).
    driven, sums = local.split([chunk, 2], dim=-1)  # (B, E, N, C), (B, E, N, 2)
    sum_s, sum_ws = (s.unbind(2) for s in sums.unbind(-1))  # N × (B, E) each
    ends = driven[..., -1].unbind(2)  # N × (B, E): the driven term at each chunk's last sample
    keep = (~known).to(entries.dtype).unbind(1)  # N × (B,)
    pos = cross = vel = torch.zeros_like(ends[0])
    starts = []
    for k in range(n_chunks):  # carries at the chunk boundaries: (B, E) each, a handful of small operations
        if k:
            pos = pos + chunk * dt * (2 * cross) + (chunk * dt) ** 2 * vel + ends[k - 1]
            cross, vel = cross + chunk * dt * vel + dt**3 * sum_ws[k - 1], vel + dt**2 * sum_s[k - 1]
            still = keep[k].unsqueeze(1)
            pos, cross, vel = pos * still, cross * still, vel * still
        starts.append(torch.stack([pos, 2 * cross, vel], dim=-1))
    carry = torch.stack(starts, dim=2)  # (B, E, N, 3): P0, X0 + X0ᵀ, V0 per chunk
    # P0 + n dt (X0 + X0ᵀ) + n² dt² V0 for n = 1..C: one product with the (3, C) basis [1, n dt, (n dt)²]
    pos_all = carry @ _carry_basis(chunk, dt, entries.dtype, str(entries.device)) + driven  # (B, E, N, C)
    return pos_all.reshape(b, e, total)


def propagate_covariance_reference(accel_cov: np.ndarray, dt: float = DT) -> np.ndarray:
    """Eq. 2.14 by its definition, sample by sample from ``S_x[0] = 0``: the full ``(N+1, 2d, 2d)`` covariances
    the closed forms (:func:`propagate_covariance`, :func:`integrate_covariance`) agree with."""
    n, d, _ = accel_cov.shape
    a, b = transition_matrices(d, dt)
    out = np.zeros((n + 1, 2 * d, 2 * d))
    for k in range(n):
        out[k + 1] = a @ out[k] @ a.T + b @ accel_cov[k] @ b.T
    return out


class DoubleIntegratorDynamics:
    """The double integrator as a decoder's :class:`~seqmotion.models.seq2seq.ChunkDynamics`.

    The carry is ``(x, cov)``: the state ``(B, 2d)`` at the chunk boundary and its
    :class:`CovarianceCarry`. Each step integrates C mean inputs in closed form and, when
    covariances are given, propagates them (eq. 2.14) to the positions of the C new states.
    """

    def __init__(self, dim: int, dt: float = DT) -> None:
        self.dim, self.dt = dim, dt

    def start(self, x0: torch.Tensor) -> tuple[torch.Tensor, CovarianceCarry]:
        return x0, CovarianceCarry.zeros(x0.shape[0], self.dim, x0.dtype, x0.device)

    def step(
        self, carry: tuple[torch.Tensor, CovarianceCarry], mean: torch.Tensor, cov: torch.Tensor | None
    ) -> tuple[tuple[torch.Tensor, CovarianceCarry], dict[str, torch.Tensor]]:
        x, cov_carry = carry
        states = integrate_chunk(x, mean, self.dt)
        out = {"states": states}
        if cov is not None:
            out["pos_cov"], cov_carry = propagate_covariance(cov_carry, cov, self.dt)
        return (states[:, -1], cov_carry), out

    def decoder_input(self, states: torch.Tensor) -> torch.Tensor:
        return states

    def propagate_entrywise(self, entries: torch.Tensor, known: torch.Tensor, chunk: int) -> dict[str, torch.Tensor]:
        """All chunks' position covariances at once (:func:`propagate_entrywise`; the rollout's fast path)."""
        return {"pos_cov": propagate_entrywise(entries, known, chunk, self.dt)}

    def narrow(self, carry: tuple[torch.Tensor, CovarianceCarry], rows: int) -> tuple[torch.Tensor, CovarianceCarry]:
        """The carry of the first ``rows`` trajectories (the rollout stops those that have ended)."""
        x, cov = carry
        return x[:rows], cov.narrow(rows)

    def restart(
        self, carry: tuple[torch.Tensor, CovarianceCarry], state: torch.Tensor, mask: torch.Tensor
    ) -> tuple[torch.Tensor, CovarianceCarry]:
        x, cov_carry = carry
        return torch.where(mask.view(-1, 1), state.to(x.dtype), x), cov_carry.reset_where(mask)
