"""Loss terms shared by tasks: Gaussian negative log-likelihoods with a variance floor.

The likelihood terms (eqs. 2.22, 3.21, 3.24) score a target position against the generated
one under the propagated covariance. That covariance starts at exactly zero (``S_x[0] = 0``)
and the first samples' variances are ~dt⁴σ² ≈ 1e-12 σ², which makes the NLL explode and
overflow float32. We therefore add a **variance floor** ``floor · I`` to every covariance
before scoring; ``floor = 1e-8`` (a standard deviation of 0.1 mm, or 1 mrad after D's 0.1
scaling of θ) by default. Below that accuracy the loss stops rewarding precision, which is
far below what a robot can track. The closed forms below avoid batched Cholesky calls.
"""

from __future__ import annotations

import math

import torch

from ..models.seq2seq import ChunkDynamics, ChunkedSeq2Seq, Rollout, rollout

DEFAULT_VARIANCE_FLOOR = 1e-8
_LOG_2PI = math.log(2 * math.pi)


def gaussian_nll_1d(diff: torch.Tensor, var: torch.Tensor, floor: float = DEFAULT_VARIANCE_FLOOR) -> torch.Tensor:
    """``-log N(diff | 0, var + floor)`` elementwise."""
    v = var + floor
    return 0.5 * (diff**2 / v + torch.log(v) + _LOG_2PI)


def gaussian_nll_2d(diff: torch.Tensor, cov: torch.Tensor, floor: float = DEFAULT_VARIANCE_FLOOR) -> torch.Tensor:
    """``-log N(diff | 0, cov + floor I)`` for ``diff (..., 2)``, ``cov (..., 2, 2)`` → ``(...)``."""
    return gaussian_nll_2d_entries(diff, cov[..., 0, 0], 0.5 * (cov[..., 0, 1] + cov[..., 1, 0]), cov[..., 1, 1], floor)


def gaussian_nll_2d_entries(
    diff: torch.Tensor, xx: torch.Tensor, xy: torch.Tensor, yy: torch.Tensor, floor: float = DEFAULT_VARIANCE_FLOOR
) -> torch.Tensor:
    """:func:`gaussian_nll_2d` of the symmetric covariance ``[[xx, xy], [xy, yy]]`` given by its entries ``(...)``."""
    a = xx + floor
    b = xy
    c = yy + floor
    det = a * c - b * b
    dx, dy = diff[..., 0], diff[..., 1]
    quad = (c * dx * dx - 2 * b * dx * dy + a * dy * dy) / det
    return 0.5 * (quad + torch.log(det)) + _LOG_2PI


# --- what every task's loss needs (so a task module holds only what is specific to it) -------------


def sample_mask(lengths: torch.Tensor, k_max: int) -> torch.Tensor:
    """``(B, K_max-1)`` true where sample ``k+1`` (equivalently transition ``k → k+1``) lies inside
    its trajectory of length ``lengths[b]``: the mask of padded batches."""
    return torch.arange(1, k_max, device=lengths.device).unsqueeze(0) < lengths.unsqueeze(1)


def per_trajectory(terms: torch.Tensor, mask: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
    """``(B, K_max-1)`` per-sample terms → ``(B,)`` their mean over each trajectory's K-1 samples."""
    return (terms * mask).sum(1) / (lengths - 1)


def masked_mean(terms: torch.Tensor, mask: torch.Tensor) -> float:
    """The mean of ``terms`` over the valid samples of a batch (for logging)."""
    return float((terms.detach() * mask).sum() / mask.sum().clamp_min(1))


def pad_to(states: torch.Tensor, length: int) -> torch.Tensor:
    """``(B, K, S)`` → ``(B, length, S)`` by repeating each trajectory's last sample (teacher-forcing targets
    for a decoder that runs whole chunks past K)."""
    b, k, s = states.shape
    return states if length <= k else torch.cat([states, states[:, -1:].expand(b, length - k, s)], dim=1)


def weighted_gaussian_nll(
    diff: torch.Tensor, cov: torch.Tensor, weights: list[float] | tuple[float, ...] | None = None,
    floor: float = DEFAULT_VARIANCE_FLOOR,
) -> torch.Tensor:
    """``-log N(D diff | 0, D cov Dᵀ + floor I)``, ``D = diag(weights)``, for ``diff (..., p)``, ``cov (..., p, p)``.

    The Gaussian likelihood of a target position under the covariance propagated through the
    physics (eqs. 2.22, 3.21). p = 1 and 2 use closed forms; larger p a Cholesky factorisation.
    """
    if weights is not None:
        d = torch.as_tensor(weights, dtype=diff.dtype, device=diff.device)
        diff, cov = diff * d, cov * d.unsqueeze(-1) * d.unsqueeze(-2)
    p = diff.shape[-1]
    if p == 1:
        return gaussian_nll_1d(diff[..., 0], cov[..., 0, 0], floor)
    if p == 2:
        return gaussian_nll_2d(diff, cov, floor)
    eye = torch.eye(p, dtype=cov.dtype, device=cov.device)
    chol = torch.linalg.cholesky(cov + floor * eye)
    solved = torch.linalg.solve_triangular(chol, diff.unsqueeze(-1), upper=False).squeeze(-1)
    logdet = 2 * torch.log(torch.diagonal(chol, dim1=-2, dim2=-1)).sum(-1)
    return 0.5 * ((solved**2).sum(-1) + logdet + p * _LOG_2PI)


def encode_and_rollout(
    model: ChunkedSeq2Seq,
    inputs: torch.Tensor,
    lengths: torch.Tensor,
    x0: torch.Tensor,
    dynamics: ChunkDynamics,
    *,
    teacher: torch.Tensor | None = None,
    teacher_forcing_prob: float = 0.0,
    generator: torch.Generator | None = None,
    expand_cov: bool = True,
) -> Rollout:
    """What every seq2seq loss starts with: encode the padded input motions ``(B, K_max, input_dim)``
    (each of its own length), decode the latents from ``x0`` ``(B, S)`` through ``dynamics`` for enough
    chunks to cover K_max samples, with covariances, and — with ``teacher`` ``(B, K_max, S)`` true
    states — scheduled sampling at ``teacher_forcing_prob``; ``expand_cov`` as :func:`rollout`. Slice the
    result to ``[:, :K_max]`` (states) and ``[:, :K_max-1]`` (inputs, per-sample outputs), and read each
    trajectory's first K samples only: past its last chunk the rollout may be zero (``rollout(...,
    lengths=)``; a batch sorted longest first runs fastest)."""
    k_max = inputs.shape[1]
    n_chunks = model.num_chunks(k_max)
    z = model.encode(inputs, lengths)
    if teacher is not None:
        teacher = pad_to(teacher, n_chunks * model.chunk + 1)
    return rollout(
        model, z, x0, dynamics, n_chunks, teacher=teacher, teacher_forcing_prob=teacher_forcing_prob,
        generator=generator, expand_cov=expand_cov, lengths=lengths,
    )
