"""Adjusting generated motions by gradient descent (ch. 4, §4.2.3).

The procedure (eq. 4.2): encode the input into z; decode z into states and inputs through the
task's differentiable physics; evaluate J; backpropagate ∂J/∂z through the decoder and the
physics; ``z ← z − η ∂J/∂z``; repeat. Three cases:

* case 1 — :func:`optimize_latent` with ``init="encoder"``: start from the encoder's z;
* case 2 — :func:`optimize_latent` with ``init="random"``: start from z ~ N(0, I);
* case 3 — :func:`optimize_trajectory`: optimise the decoder's output accelerations directly
  (starting from what the decoder produced), states by integration.

Everything is batched: many input motions (and per-trajectory targets) in one call. The
model's weights are frozen during optimisation; only z (or the accelerations) change.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..errors import as_trajectories, check_finite_result
from ..tasks.base import TrainedModel
from .objectives import as_objective


@dataclass
class OptimizationResult:
    """The adjusted motion(s); a leading B axis when the input was batched.

    Attributes:
        states: ``(K, S)`` states after the last update.
        accel: ``(K-1, d)`` their inputs.
        latent: ``(L·H,)`` the optimised z (None for case 3).
        history: ``(steps + 1,)`` the objective before each update and after the last
            (``(steps + 1, B)`` for a batch; a scalar objective gives ``(steps + 1,)``).
        seconds_per_update: mean wall time of one update (forward, backward, step).
    """

    states: np.ndarray
    accel: np.ndarray
    latent: np.ndarray | None
    history: np.ndarray
    seconds_per_update: float


@contextmanager
def _frozen(model: torch.nn.Module):
    """Weights take no gradient while latents are optimised (and are restored afterwards)."""
    flags = [p.requires_grad for p in model.parameters()]
    for p in model.parameters():
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p, flag in zip(model.parameters(), flags, strict=True):
            p.requires_grad_(flag)


def _make_optimizer(name: str, params: list[torch.Tensor], lr: float) -> torch.optim.Optimizer:
    if name == "sgd":  # plain gradient descent, eq. 4.2
        return torch.optim.SGD(params, lr=lr)
    if name == "adam":
        return torch.optim.Adam(params, lr=lr)
    raise ValueError(f"optimizer must be 'sgd' or 'adam', got {name!r}")


def _prepare(
    model: object, states: object, objective: object, steps: int, lr: float
) -> tuple[Any, torch.Tensor, torch.Tensor, int, bool]:
    """Validate the arguments; return ``(objective, inputs (B, K, S), x0 (B, S'), K, was_single)``."""
    if not isinstance(model, TrainedModel):
        raise ValueError(f"model must be a trained seqmotion model (e.g. sm.load_pretrained(...)), got {type(model)}")
    if steps < 0 or not lr > 0:
        raise ValueError(f"need steps >= 0 and lr > 0, got steps={steps}, lr={lr}")
    batch, single = as_trajectories(states, model.input_dim, "states")
    x = torch.from_numpy(batch)
    return as_objective(objective), x, model.start_state(x), x.shape[1], single


def _descend(
    variable: torch.Tensor,
    evaluate: Any,
    objective: Any,
    steps: int,
    lr: float,
    optimizer: str,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, np.ndarray, float]:
    """Minimise ``objective(*evaluate(variable))`` over ``variable``; return the final motion and history."""
    variable = variable.detach().clone().requires_grad_(True)
    opt = _make_optimizer(optimizer, [variable], lr)
    history = []
    seconds = 0.0
    for step in range(steps + 1):
        start = time.perf_counter()
        states, accel = evaluate(variable)
        value = objective(states, accel)
        history.append(value.detach().double().numpy().copy())
        if step == steps:
            break
        opt.zero_grad(set_to_none=True)
        value.sum().backward()  # independent trajectories: d(Σ J_b)/d z_b = d J_b / d z_b
        if not torch.isfinite(variable.grad).all():
            raise ValueError(f"the objective's gradient became NaN/inf at update {step}; try a smaller lr")
        opt.step()
        seconds += time.perf_counter() - start
    return variable.detach(), states.detach(), accel.detach(), np.stack(history), seconds / max(steps, 1)


def optimize_latent(
    model: TrainedModel,
    states: object,
    objective: object,
    steps: int = 100,
    lr: float = 200.0,
    init: str | np.ndarray = "encoder",
    optimizer: str = "sgd",
    seed: int = 0,
    **physics: Any,
) -> OptimizationResult:
    """Cases 1 and 2: optimise the latent z of ``states`` for ``objective``.

    Args:
        model: a trained model (``Deformer``, ``SlidingPlanner``...).
        states: ``(K, input_dim)`` or ``(B, K, input_dim)`` input motions (for case 2 only
            their start state and length are used).
        objective: an :class:`~seqmotion.latent.objectives.Objective` or a callable
            ``f(states, accel) -> tensor``.
        steps: number of updates.
        lr: step size η (200 in the dissertation for cases 1 and 2).
        init: ``"encoder"`` (case 1), ``"random"`` (case 2: z ~ N(0, I), seeded by ``seed``), or
            latents to continue from (``(L·H,)`` / ``(B, L·H)``, e.g. a previous result's ``latent``).
        optimizer: ``"sgd"`` (plain gradient descent, eq. 4.2) or ``"adam"``.
        physics: passed to the task's dynamics (e.g. ``mu``, ``mu_dyn`` for sliding).
    """
    objective, x, x0, length, single = _prepare(model, states, objective, steps, lr)
    with torch.no_grad():
        if isinstance(init, str) and init == "encoder":
            z0 = model.encode_torch(x)
        elif isinstance(init, str) and init == "random":
            gen = torch.Generator().manual_seed(seed)
            z0 = torch.randn(len(x), model.model.latent_dim, generator=gen)
        elif not isinstance(init, str):  # continue from given latents
            z0 = torch.as_tensor(np.atleast_2d(np.asarray(init, dtype=np.float32)))
            if z0.shape != (len(x), model.model.latent_dim) or not torch.isfinite(z0).all():
                raise ValueError(f"init latent must be finite with shape ({len(x)}, {model.model.latent_dim})")
        else:
            raise ValueError(f"init must be 'encoder', 'random' or a latent array, got {init!r}")
    with _frozen(model.model):
        z, out_states, out_accel, history, seconds = _descend(
            z0, lambda z: model.decode_torch(z, x0, length, **physics), objective, steps, lr, optimizer
        )
    return _result(out_states, out_accel, z, history, seconds, single)


def optimize_trajectory(
    model: TrainedModel,
    states: object,
    objective: object,
    steps: int = 100,
    lr: float = 1000.0,
    optimizer: str = "sgd",
    **physics: Any,
) -> OptimizationResult:
    """Case 3: optimise the decoder's output accelerations directly (states by integration).

    Starts from the motion the decoder generates for ``states``; ``lr`` is η (1000 in the
    dissertation). Arguments as :func:`optimize_latent`.
    """
    objective, x, x0, length, single = _prepare(model, states, objective, steps, lr)
    with torch.no_grad():
        _, accel0 = model.decode_torch(model.encode_torch(x), x0, length, **physics)
    with _frozen(model.model):
        accel, out_states, out_accel, history, seconds = _descend(
            accel0, lambda u: (model.integrate_torch(x0, u, **physics), u), objective, steps, lr, optimizer
        )
    return _result(out_states, out_accel, None, history, seconds, single)


def _result(
    states: torch.Tensor, accel: torch.Tensor, latent: torch.Tensor | None, history: np.ndarray, seconds: float,
    single: bool,
) -> OptimizationResult:
    states_np = check_finite_result(states.double().numpy(), "optimisation")
    accel_np = accel.double().numpy()
    latent_np = None if latent is None else latent.float().numpy()
    if single:
        states_np, accel_np = states_np[0], accel_np[0]
        latent_np = None if latent_np is None else latent_np[0]
        history = history[:, 0] if history.ndim == 2 else history
    return OptimizationResult(states_np, accel_np, latent_np, history, seconds)
