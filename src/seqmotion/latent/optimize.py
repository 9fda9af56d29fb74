"""Adjusting generated motions by gradient descent (ch. 4, §4.2.3).

The procedure (eq. 4.2): encode the input into z; decode z into states and inputs through the
task's differentiable physics; evaluate J; backpropagate ∂J/∂z through the decoder and the
physics; ``z ← z − η ∂J/∂z``; repeat. Three cases:

* case 1 — :func:`optimize_latent` with ``init="encoder"``: start from the encoder's z;
* case 2 — :func:`optimize_latent` with ``init="random"``: start from z ~ N(0, I);
* case 3 — :func:`optimize_trajectory`: optimise the decoder's output accelerations directly
  (starting from what the decoder produced), states by integration.

Everything is batched: many input motions (and per-trajectory targets) in one call. Only z
(or the accelerations) change: gradients are taken with respect to them alone
(``torch.autograd.grad(J, z)``), so the model's weights are never touched — not even their
``requires_grad`` flags, which makes concurrent calls on one model from several threads safe.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from ..core.execution import BindingLimit, ExecutionCheck, arm_form_for, execution_check_for
from ..core.polish import POLISH_VIOLATION_TOLERANCE, ArmForm
from ..core.results import FEASIBLE_TOLERANCE, Motion
from ..core.trained import TrainedModel
from ..errors import as_float_array, as_trajectories, check_finite_result, check_number
from ..physics.parameters import Physics
from .objectives import Objective, Term, for_model

MAX_STEPS = 1_000_000
"""More updates than this in one call is a typo."""

RESULT_PARTS = (BindingLimit, ExecutionCheck)
"""The dataclasses a saved result of this module holds besides itself (a robot's verdict): ``load_result`` rebuilds
them from this module's names."""


@dataclass
class Stage:
    """One stage of an adjustment and where it ended.

    Attributes:
        name: ``"latent"`` (updates of z), ``"trajectory"`` (updates of the inputs, case 3) or
            ``"polish"`` (the exact stage: IPOPT on the motion closest to the previous stage's).
        steps: updates (latent / trajectory) or IPOPT iterations (polish), ``(B,)`` for a batch
            where they differ per trajectory.
        seconds: wall time of the stage.
        objective: the objective after the stage, per trajectory.
        status: per trajectory: ``"converged"`` / ``"ran all updates"`` (latent), IPOPT's return
            status (polish).
    """

    name: str
    steps: Any
    seconds: float
    objective: np.ndarray
    status: list[str]

    def __str__(self) -> str:
        steps = np.atleast_1d(self.steps)
        span = f"{int(steps.min())}" if steps.min() == steps.max() else f"{int(steps.min())}–{int(steps.max())}"
        unit = "iterations" if self.name == "polish" else "updates"
        statuses = ", ".join(sorted(set(self.status)))
        return (f"{self.name}: {span} {unit}, {self.seconds:.3f} s, objective ≤ {float(np.max(self.objective)):.3g} "
                f"({statuses})")


@dataclass
class OptimizationResult(Motion):
    """The adjusted motion(s): a :class:`~seqmotion.core.trained.Motion` with how it was reached; a leading B
    axis when the input was batched.

    Attributes:
        states: ``(K, S)`` states after the last stage.
        accel: ``(K-1, d)`` their inputs.
        latent: ``(L·H,)`` the optimised z (None for case 3). After an exact polish the motion is
            the polished one, near (not equal to) what z decodes to.
        violation: ``(K-1,)`` the task's constraint violation per transition at the model's options (0 where
            it holds; None for a task without a constraint), as :class:`Motion`; ``feasible``: its largest
            ≤ 0.01. A motion that breaks it is also warned about (``RuntimeWarning``).
        history: ``(updates + 1,)`` the objective before each update and after the last
            (``(updates + 1, B)`` for a batch; a scalar objective gives ``(updates + 1,)``).
        seconds_per_update: mean wall time of one update (backward, step, forward; with
            ``lr="auto"`` also the line search's extra forward passes).
        stages: where each stage ended (:class:`Stage`): the updates, then the polish with ``exact=True``.
        terms: each term of the objective on the final motion, name → :class:`~.objectives.Term`
            (value, limit, ``met``); the task's constraint is always one (``"constraint"``; the pancake's
            ``Ranges()``: ``"friction cone"``).
        exact: with ``exact=True``: whether the polish made the objective's constraints and the task's
            constraint hold exactly (IPOPT converged, violation ≤ 1e-6), per trajectory; None otherwise.
        end_shift: the task's end-pose fields (``Task.end_pose``; pancake: y, z, θ) that the objective leaves
            free — it aims for no end value of them (:attr:`~.objectives.Objective.end_fields`: a limit alone, bands
            on other fields, a plain function) — → how far the motion's end lies from the input's on each,
            ``|x[K-1] − input[K-1]|`` [the field's unit] (``(B,)`` for a batch), as a :class:`~.objectives.Term`
            whose limit is :data:`END_SHIFT_TOLERANCE` over the field's end-pose weight (pancake: 0.05 m, 0.5 rad).
            Not ``met``: the motion no longer does the input's task on that field (e.g. the spatula no longer turns
            as the input does: a limit alone lets the polish drop the turn), which a ``RuntimeWarning`` says too;
            name the field in the objective to keep it. Not part of the objective (``met`` ignores it). Empty
            when the objective names every end-pose field, or the task's inputs are not its states.
        errors, uncertainty, out_of_distribution, ood_reasons (:class:`~seqmotion.core.trained.TrustSignals`):
            the trust signals of the final motion against the input
            (:meth:`~seqmotion.tasks.TrainedModel.assess`; uncertainty for cases 1–2: the predicted std of
            what the optimised z decodes to).
    """

    history: np.ndarray = field(kw_only=True)
    seconds_per_update: float = field(kw_only=True)
    stages: list[Stage] = field(default_factory=list, kw_only=True)
    terms: dict[str, Term] = field(default_factory=dict, kw_only=True)
    end_shift: dict[str, Term] = field(default_factory=dict, kw_only=True)
    robot_check: ExecutionCheck | None = field(default=None, kw_only=True)  # with robot=...; see Motion.feasible

    @property
    def met(self) -> bool:
        """Whether every term of the objective is met, for every trajectory (True when it has no terms)."""
        return all(bool(np.all(term.met)) for term in self.terms.values())

    def describe(self) -> str:
        """One line per stage and per term: what was reached and what was missed; then one per end-pose field the
        objective left free: whether the motion still ends where the input does (:attr:`end_shift`)."""
        lines = [str(stage) for stage in self.stages]
        lines += [f"{name}: {term}" for name, term in self.terms.items()]
        for name, term in self.end_shift.items():
            moved = float(np.max(np.asarray(term.value, dtype=float)))
            verdict = "kept" if bool(np.all(term.met)) else "NOT KEPT"
            lines.append(f"{name} end, left free by the objective: {moved:.3g} {term.unit} from the input's "
                         f"(limit {term.limit:.3g}) {verdict}")
        return "\n".join(lines)


def _make_optimizer(name: str, params: list[torch.Tensor], lr: float) -> torch.optim.Optimizer:
    if name == "sgd":  # plain gradient descent, eq. 4.2
        return torch.optim.SGD(params, lr=lr)
    if name == "adam":
        return torch.optim.Adam(params, lr=lr)
    raise ValueError(f"optimizer must be 'sgd' or 'adam', got {name!r}")


def _prepare(
    model: object, states: object, objective: object, steps: int | None, lr: float | str, physics: Physics | None
) -> tuple[Any, torch.Tensor, torch.Tensor, int, bool, Physics]:
    """Validate the arguments; return ``(objective bound to the model, inputs (B, K, S), x0 (B, S'), K,
    was_single)``."""
    if not isinstance(model, TrainedModel):
        raise ValueError(f"model must be a trained seqmotion model (e.g. sm.load_pretrained(...)), got {type(model)}")
    physics = model.resolve_physics(physics)
    if steps is not None:
        _check_steps(steps)
    if not (isinstance(lr, str) and lr == "auto"):
        check_number("lr", lr, minimum=0, strict_minimum=True)
    batch, single = as_trajectories(states, model.input_dim, "states")
    x = torch.from_numpy(batch)  # stays on the CPU (the trust signals read it); x0 goes to the model's device
    return for_model(objective, model), x, model.start_state(x).to(model.device), x.shape[1], single, physics


def _check_method(optimizer: object, lr: object, continuation: object) -> None:
    """Refuse a bad optimiser choice before any work (the same checks :func:`_descend` makes)."""
    if not isinstance(optimizer, str) or optimizer not in ("sgd", "adam", "lm"):
        raise ValueError(f"optimizer must be 'auto', 'sgd', 'adam' or 'lm', got {optimizer!r}")
    if lr == "auto" and optimizer == "adam":
        raise ValueError("optimizer='adam' needs a numeric lr (lr='auto' is gradient descent with a line search)")
    _continuation(continuation, optimizer)


def _descend(
    variable: torch.Tensor,
    evaluate: Any,
    objective: Any,
    steps: int,
    lr: float | str,
    optimizer: str,
    relax: tuple[float, int] = (1.0, 0),
    tol: float = 0.0,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, np.ndarray, float]:
    """Minimise ``objective(*evaluate(variable))`` over ``variable``; return the final motion and history.

    ``lr="auto"``: gradient descent with Armijo backtracking (see :func:`_armijo_step`). A
    fixed η is meaningful only in units of a particular latent space; this needs none.
    Stops early once every trajectory's objective is ≤ ``tol`` (after the continuation's ramp).
    """
    variable = variable.detach().clone().requires_grad_(True)
    states, accel = evaluate(variable)
    value = objective(states, accel)
    history = [value.detach().double().cpu().numpy().copy()]
    if optimizer not in ("sgd", "adam", "lm"):
        raise ValueError(f"optimizer must be 'sgd', 'adam' or 'lm', got {optimizer!r}")
    if lr == "auto" and optimizer == "adam":
        raise ValueError("optimizer='adam' needs a numeric lr (lr='auto' is gradient descent with a line search)")
    opt = None if lr == "auto" or optimizer == "lm" else _make_optimizer(optimizer, [variable], float(lr))
    eta: torch.Tensor | None = None  # step sizes of the line search, or damping of Levenberg–Marquardt
    start = time.perf_counter()
    for step in range(steps):
        if tol > 0 and step >= relax[1] and bool((value.detach() <= tol).all()):
            break
        if optimizer == "lm":
            # continuation: the penalty's weight grows geometrically from relax[0] to 1 over relax[1] updates
            weight, ramp = relax
            w = 1.0 if step >= ramp else weight ** (1.0 - step / ramp)
            variable, value, states, accel, eta = _lm_step(variable, states, accel, eta, evaluate, objective, w)
            history.append(value.detach().double().cpu().numpy().copy())
            continue
        (grad,) = torch.autograd.grad(value.sum(), variable)
        if not torch.isfinite(grad).all():
            raise ValueError(f"the objective's gradient became NaN/inf at update {step}; try a smaller lr")
        if opt is not None:  # a fixed step size (eq. 4.2 with the given η), or Adam
            variable.grad = grad
            opt.step()
            next_variable = variable
        else:
            variable, value, states, accel, eta = _armijo_step(variable, value, grad, eta, evaluate, objective)
            history.append(value.detach().double().cpu().numpy().copy())
            continue
        states, accel = evaluate(next_variable)
        value = objective(states, accel)
        history.append(value.detach().double().cpu().numpy().copy())
    seconds = (time.perf_counter() - start) / max(len(history) - 1, 1)
    return variable.detach(), states.detach(), accel.detach(), np.stack(history), seconds


def _armijo_step(
    variable: torch.Tensor, value: torch.Tensor, grad: torch.Tensor, eta: torch.Tensor | None, evaluate: Any,
    objective: Any,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """One gradient step per trajectory with its own step size, chosen by Armijo backtracking.

    Trajectories are independent problems, so each gets its own η: start from twice its last
    accepted η (the first time, from a step of half the variable's norm) and halve it until
    ``J_b(v_b − η_b g_b) ≤ J_b(v_b) − 1e-4 η_b |g_b|²``. A scalar objective (one value for the
    whole batch) gets one shared η. Returns the new variable, its objective, states, inputs and η.
    """
    b = grad.shape[0]
    shape = (b,) + (1,) * (grad.dim() - 1)
    per_trajectory = value.ndim == 1
    grad_sq = (grad.reshape(b, -1) ** 2).sum(1)
    norm = variable.detach().reshape(b, -1).norm(dim=1)
    if not per_trajectory:
        grad_sq, norm = grad_sq.sum().expand(b), norm.norm().expand(b)
    if eta is None:
        step = 0.5 * norm.clamp_min(1.0) / grad_sq.sqrt().clamp_min(1e-30)
    else:
        # a trajectory without a gradient (its objective flat there: a met limit, no violation) moves nowhere, so
        # its η is kept, not doubled: doubled at every update it overflows to inf, and inf · 0 is NaN
        step = torch.where(grad_sq > 0, 2 * eta, eta)
    current = value.detach().expand(b)
    for _ in range(60):
        candidate = (variable.detach() - step.view(shape) * grad).requires_grad_(True)
        states, accel = evaluate(candidate)
        new_value = objective(states, accel)
        ok = (new_value.detach().expand(b) <= current - 1e-4 * step * grad_sq) | (step < 1e-12)
        if bool(ok.all()):
            break
        step = torch.where(ok, step, step / 2)  # accepted trajectories keep their step (same value again)
    return candidate, new_value, states, accel, step


def _lm_step(
    variable: torch.Tensor, states: torch.Tensor, accel: torch.Tensor, damping: torch.Tensor | None,
    evaluate: Any, objective: Any, penalty_weight: float = 1.0,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """One Levenberg–Marquardt step per trajectory for ``J_w = |r|² + w·p`` (least-squares objectives).

    With the residual Jacobian ``G = ∂r/∂v`` (one backward pass per residual component) and the
    penalty's gradient ``g``: ``Δ = −(GᵀG + λI)⁻¹ (Gᵀr + w·g/2)``, solved through the m × m system
    of the Woodbury identity. Each trajectory has its own damping λ: a step that does not lower
    its ``J_w`` is retried with 4λ; an accepted one makes the next λ/3. Returns the true
    objective (``w = 1``) of the new motion.
    """
    b = variable.shape[0]
    residuals = objective.residuals(states, accel)  # (B, m)
    penalty = penalty_weight * objective.penalty(states, accel)  # (B,)
    jac = _jacobian(residuals, variable)  # (B, m, n), the linear algebra in float64
    if penalty.requires_grad:
        (g_pen,) = torch.autograd.grad(penalty.sum(), variable)
        g_pen = g_pen.reshape(b, -1).double()
    else:
        g_pen = torch.zeros_like(jac[:, 0])
    rhs = (jac.transpose(1, 2) @ residuals.detach().double().unsqueeze(-1)).squeeze(-1) + 0.5 * g_pen  # (B, n)
    gram = jac @ jac.transpose(1, 2)  # (B, m, m)
    eye = torch.eye(gram.shape[-1], dtype=gram.dtype, device=gram.device)
    lam = 1e-3 * gram.diagonal(dim1=1, dim2=2).mean(-1).clamp_min(1e-12) if damping is None else damping
    current = ((residuals.detach() ** 2).sum(-1) + penalty.detach()).double()
    for _ in range(40):
        inner = torch.linalg.solve(gram + lam.view(-1, 1, 1) * eye, (jac @ rhs.unsqueeze(-1)))  # (B, m, 1)
        delta = -(rhs - (jac.transpose(1, 2) @ inner).squeeze(-1)) / lam.view(-1, 1)
        candidate = (variable.detach() + delta.view_as(variable).to(variable.dtype)).requires_grad_(True)
        states, accel = evaluate(candidate)
        new_r, new_p = objective.residuals(states, accel), objective.penalty(states, accel)
        new_value = (new_r.detach() ** 2).sum(-1) + penalty_weight * new_p.detach()
        ok = (new_value.double() <= current) | (lam > 1e12)
        if bool(ok.all()):
            break
        lam = torch.where(ok, lam, 4 * lam)  # accepted trajectories keep their λ (same step again)
    return candidate, (new_r**2).sum(-1) + new_p, states, accel, lam / 3


def _jacobian(residuals: torch.Tensor, variable: torch.Tensor) -> torch.Tensor:
    """``∂r_b/∂v_b`` ``(B, m, n)`` in float64: the m backward passes vectorised into one (vmap over the
    backward graph), or one after another where an operation has no batching rule."""
    b, m = residuals.shape
    try:
        seeds = torch.eye(m, dtype=residuals.dtype, device=residuals.device)  # seed j picks residual j
        seeds = seeds.unsqueeze(1).expand(m, b, m)
        (jac,) = torch.autograd.grad(residuals, variable, grad_outputs=seeds, retain_graph=True,
                                     is_grads_batched=True)
        return jac.reshape(m, b, -1).transpose(0, 1).double()
    except RuntimeError:
        rows = [torch.autograd.grad(residuals[:, i].sum(), variable, retain_graph=True)[0] for i in range(m)]
        return torch.stack([r.reshape(b, -1) for r in rows], dim=1).double()


def _continuation(continuation: tuple[float, int] | None, optimizer: str) -> tuple[float, int]:
    if continuation is None:
        return (1.0, 0)
    if optimizer != "lm":
        raise ValueError("continuation is a Levenberg–Marquardt option (optimizer='lm')")
    bad = ValueError(f"continuation must be (initial penalty weight in (0, 1], updates ≥ 0), got {continuation!r}")
    if isinstance(continuation, str) or not hasattr(continuation, "__len__") or len(continuation) != 2:
        raise bad
    weight, ramp = continuation
    try:
        check_number("continuation weight", weight, minimum=0, strict_minimum=True, maximum=1)
        check_number("continuation updates", ramp, minimum=0, maximum=MAX_STEPS, integer=True)
    except ValueError:
        raise bad from None
    return float(weight), int(ramp)


DEFAULT_CONTINUATION = (1e-3, 4)
"""Levenberg–Marquardt's default: the penalty weighted 1e-3 at the first update, 1 from the 4th."""
EXACT_LATENT_TOL = 1e-3
"""With ``exact=True`` the latent stage stops once the objective is below this: the polish does the rest."""
END_SHIFT_TOLERANCE = 0.05
"""How far the end of an end-pose field the objective leaves free may lie from the input's, times the field's
end-pose weight, before the result says the task's outcome changed (:attr:`OptimizationResult.end_shift`): the
pancake's 0.05 m end-position tolerance, and 0.5 rad (its θ weight 0.1), J2's attitude band."""


def _resolve_method(
    objective: Objective, optimizer: str, lr: float | str, continuation: object, steps: int | None,
    exact: bool, tol: float | None,
) -> tuple[str, tuple[float, int] | None, int, float]:
    """``(optimizer, continuation, steps, tol)`` with the defaults filled in (see :func:`optimize_latent`)."""
    if not isinstance(exact, bool):
        raise ValueError(f"exact must be True or False, got {exact!r}")
    if optimizer == "auto":
        optimizer = "lm" if objective.least_squares and lr == "auto" else "sgd"
    if isinstance(continuation, str):
        if continuation != "auto":
            raise ValueError(f"continuation must be 'auto', None or (w0, n), got {continuation!r}")
        continuation = DEFAULT_CONTINUATION if optimizer == "lm" else None
    _check_method(optimizer, lr, continuation)
    if optimizer == "lm" and not objective.least_squares:
        raise ValueError(f"optimizer='lm' needs residuals: {objective!r} is not of least-squares form; use "
                         "optimizer='sgd' or 'adam', or give residuals: sm.objectives.Function(residuals=f)")
    if steps is None:  # exact: the latent stage only has to come near (≤ 7 updates on ch. 4's targets)
        steps = 10 if exact else 20 if optimizer == "lm" else 100
    if tol is None:
        tol = EXACT_LATENT_TOL if exact else 0.0
    check_number("tol", tol, minimum=0)
    return optimizer, continuation, steps, float(tol)  # type: ignore[return-value]


def optimize_latent(
    model: TrainedModel,
    states: object,
    objective: object,
    steps: int | None = None,
    lr: float | str = "auto",
    init: str | np.ndarray = "encoder",
    optimizer: str = "auto",
    seed: int = 0,
    continuation: tuple[float, int] | str | None = "auto",
    exact: bool = False,
    tol: float | None = None,
    device: str | torch.device | None = None,
    physics: Physics | None = None,
    robot: object = None,
) -> OptimizationResult:
    """Cases 1 and 2: optimise the latent z of ``states`` for ``objective``; with ``exact=True``, then polish.

    The defaults are the method that works: Levenberg–Marquardt with penalty continuation for
    least-squares objectives (``EndPose``, ``AtRest``, residual ``Function`` objectives: J1 < 1e-3 within 5
    updates on ch. 4's targets), gradient descent with a line search otherwise.

    Args:
        model: a trained model (``Deformer``, ``SlidingPlanner``...).
        states: ``(K, input_dim)`` or ``(B, K, input_dim)`` input motions (for case 2 only
            their start state and length are used).
        objective: an :class:`~seqmotion.latent.objectives.Objective` or a callable
            ``f(states, accel) -> tensor``. It keeps the task's constraint: one that does not penalise
            it itself (a callable, ``AtRest``) is optimised as ``objective + TaskConstraint()`` (J plus
            ``Σ_k F[k]``, as ``EndPose`` does), and ``res.terms["constraint"]``, ``res.violation`` and a
            ``RuntimeWarning`` say whether the result keeps it.
        steps: the most updates (default 20 with Levenberg–Marquardt, 100 with gradient descent; 10
            with ``exact=True``).
        lr: step size η, or ``"auto"`` (default): Armijo backtracking at every update. The
            dissertation's η = 200 (cases 1, 2) is tied to its latent scale; on ours it diverges.
        init: ``"encoder"`` (case 1), ``"random"`` (case 2: z ~ N(0, I), seeded by ``seed``), or
            latents to continue from (``(L·H,)`` / ``(B, L·H)``, e.g. a previous result's ``latent``).
        optimizer: ``"auto"`` (default: ``"lm"`` for least-squares objectives, else ``"sgd"``),
            ``"sgd"`` (plain gradient descent, eq. 4.2: the dissertation's method), ``"adam"``, or
            ``"lm"`` (Levenberg–Marquardt; ``lr`` unused).
        continuation: ``(w0, n)`` for ``optimizer="lm"``: the objective's penalty (e.g. the
            friction cone's) is weighted ``w0`` at the first update, growing geometrically to 1 at
            update ``n`` and after. The end pose moves first, the penalty then pulls the motion
            back inside the constraint: this passes the penalty's ridges that stall plain descent.
            ``"auto"`` (default): ``(1e-3, 4)`` with LM; None: no continuation. ``history``
            always holds the true objective.
        exact: after the updates, polish the motion so the objective's goal and the task's
            constraint hold exactly (pancake: end pose to J1 ≤ 1e-9, F_c ≤ 1e-6 rad): IPOPT finds the
            motion closest to the latent stage's that meets them (:meth:`TrainedModel.polish`).
            Needs a task with an exact form (pancake) and an objective with one (``EndPose``,
            ``AtRest``, ``Ranges`` and sums of them); others are refused by name. A trajectory the
            polish cannot make exact (e.g. an unreachable target) keeps the latent stage's motion,
            ``res.exact`` is False for it and a warning names it. The polish keeps only what the objective
            names: a task's end-pose field it leaves free (a limit alone) may move far from the input's end —
            ``res.end_shift`` and a warning say so.
        tol: stop updating once every objective is ≤ ``tol`` (default 0, run all updates;
            ``exact=True``: 1e-3, the polish does the rest).
        physics: the task's physics to decode at (default ``model.physics``; sliding:
            ``planner.physics.replace(mu=0.8)``); another task's kind is refused (``ValueError``). The
            pancake's μ is the model's (``model.options.mu``); ``EndPose(..., mu=...)`` judges at another μ.
        device: run the decoder and the updates there (``"auto"``, ``"cpu"``, ``"cuda"``, ``"cuda:N"``; default
            None: where ``model`` runs). ``model`` itself is not moved (a copy on ``device`` is used). The
            polish and the trust signals run on the CPU; results are NumPy arrays either way.
        robot: the robot the motion is for (``"ur5e"``, …; one trajectory). With ``exact=True`` the polish also keeps
            its rated limits where the robot layer states them as constraints (the UR5e's: joint speeds, ranges,
            torques; the motion may take longer), as ``deform(..., keep_end=True, robot=...)`` does; either way the
            result is judged on the robot (``res.robot_check``; ``res.feasible`` False and a ``RuntimeWarning``
            naming the binding limit where one is broken).
    """
    model = _on_device(model, device)
    objective, x, x0, length, single, physics = _prepare(model, states, objective, steps, lr, physics)
    check_number("seed", seed, minimum=0, maximum=2**63 - 1, integer=True)
    optimizer, relax, steps, tol = _resolve_method(objective, optimizer, lr, continuation, steps, exact, tol)
    _check_steps(steps)
    constraints = _exact_constraints(model, objective, physics) if exact else None
    with torch.no_grad():
        if isinstance(init, str) and init == "encoder":
            z0 = model.encode_torch(x)
        elif isinstance(init, str) and init == "random":
            gen = torch.Generator().manual_seed(seed)
            z0 = torch.randn(len(x), model.model.latent_dim, generator=gen).to(x0.device)  # the CPU's draw anywhere
        elif not isinstance(init, str):  # continue from given latents
            with np.errstate(over="ignore"):
                z0 = torch.as_tensor(np.atleast_2d(as_float_array(init, "init").astype(np.float32)))
            if z0.shape != (len(x), model.model.latent_dim) or not torch.isfinite(z0).all():
                raise ValueError(f"init latent must be finite with shape ({len(x)}, {model.model.latent_dim})")
            z0 = z0.to(x0.device)
        else:
            raise ValueError(f"init must be 'encoder', 'random' or a latent array, got {init!r}")
    start = time.perf_counter()
    z, out_states, out_accel, history, seconds = _descend(
        z0, lambda z: model.decode_torch(z, x0, length, physics), objective, steps, lr, optimizer,
        _continuation(relax, optimizer), tol,
    )
    stages = [_stage("latent", history, time.perf_counter() - start, steps, tol)]
    return _finish(model, objective, x, x0, out_states, out_accel, z, history, seconds, stages, constraints, single,
                   physics, robot)


def optimize_trajectory(
    model: TrainedModel,
    states: object,
    objective: object,
    steps: int | None = None,
    lr: float | str = "auto",
    optimizer: str = "auto",
    continuation: tuple[float, int] | str | None = "auto",
    exact: bool = False,
    tol: float | None = None,
    device: str | torch.device | None = None,
    physics: Physics | None = None,
    robot: object = None,
) -> OptimizationResult:
    """Case 3: optimise the decoder's output accelerations directly (states by integration).

    Starts from the motion the decoder generates for ``states``; ``lr`` is η (1000 in the
    dissertation) or ``"auto"``. Arguments (``device`` too) and defaults as :func:`optimize_latent`.
    """
    model = _on_device(model, device)
    objective, x, x0, length, single, physics = _prepare(model, states, objective, steps, lr, physics)
    optimizer, relax, steps, tol = _resolve_method(objective, optimizer, lr, continuation, steps, exact, tol)
    _check_steps(steps)
    constraints = _exact_constraints(model, objective, physics) if exact else None
    with torch.no_grad():
        _, accel0 = model.decode_torch(model.encode_torch(x), x0, length, physics)
    start = time.perf_counter()
    accel, out_states, out_accel, history, seconds = _descend(
        accel0, lambda u: (model.integrate_torch(x0, u, physics), u), objective, steps, lr, optimizer,
        _continuation(relax, optimizer), tol,
    )
    stages = [_stage("trajectory", history, time.perf_counter() - start, steps, tol)]
    return _finish(model, objective, x, x0, out_states, out_accel, None, history, seconds, stages, constraints,
                   single, physics, robot)


def _on_device(model: object, device: object) -> Any:
    """``model`` (a copy of it) on ``device``; None: as it is. Checks the model and the device by name."""
    if device is None:
        return model
    if not isinstance(model, TrainedModel):
        raise ValueError(f"model must be a trained seqmotion model (e.g. sm.load_pretrained(...)), got {type(model)}")
    return model.on_device(device)


def _check_steps(steps: object) -> None:
    check_number("steps", steps, minimum=0, maximum=MAX_STEPS, integer=True)


def _exact_constraints(model: TrainedModel, objective: Objective, physics: Physics) -> list:
    """The objective's constraints for the polish; refuse, before any work, what cannot be made exact."""
    model.exact_form()  # ValueError naming the task when it has no exact polish
    if physics != model.physics:
        raise ValueError(f"exact=True polishes at the model's own physics ({model.physics.describe()}); "
                         f"got {physics.describe()}")
    return objective.exact_constraints()


def _stage(name: str, history: np.ndarray, seconds: float, steps: int, tol: float) -> Stage:
    last = np.atleast_1d(history[-1])
    updates = len(history) - 1
    status = "reached tol" if tol > 0 and bool(np.all(last <= tol)) else "ran all updates" if updates == steps \
        else "stopped"
    return Stage(name, updates, seconds, last, [status] * len(last))


def _finish(
    model: TrainedModel, objective: Objective, inputs: torch.Tensor, x0: torch.Tensor, states: torch.Tensor,
    accel: torch.Tensor, latent: torch.Tensor | None, history: np.ndarray, seconds: float, stages: list[Stage],
    constraints: list | None, single: bool, physics: Physics, robot: object = None,
) -> OptimizationResult:
    """Polish (with ``exact=True``, within ``robot``'s limits where given), judge each term, the trust signals and
    the robot's verdict, and shape the result."""
    # back on the CPU (a no-op there): the polish, the terms and the result are host-side
    states, accel, x0 = states.double().cpu(), accel.double().cpu(), x0.cpu()
    latent = None if latent is None else latent.cpu()
    exact = None
    arm = None
    if robot is not None:
        if not single:
            raise ValueError("robot=... optimises one trajectory at a time: pass states of one motion")
        execution_check_for(model.task_def.name)  # ValueError naming the task
        if constraints is not None:
            arm = arm_form_for(model.task_def.name, robot, float(model.exact_form().dt))
    if constraints is not None:
        states, accel, exact, polish_stage = _polish(model, objective, x0, states, accel, constraints, arm)
        stages.append(polish_stage)
    terms = objective.report(states, accel)
    with torch.no_grad():
        violation = model.violation_torch(states, accel)
    res = _result(states, accel, latent, None if violation is None else violation.double().numpy(), history,
                  seconds, single)
    res.stages, res.terms, res.task, res.physics = stages, terms, model.task_def.name, physics
    _warn_if_infeasible(violation)
    res.end_shift = _end_shift(model, objective, inputs, states)
    _warn_if_outcome_changed(res.end_shift, model, inputs, states)
    res.exact = None if exact is None else (bool(exact[0]) if single else exact)
    if states.shape[1] > inputs.shape[1]:  # a polish for a robot took longer: the input holds its end meanwhile
        inputs = torch.cat([inputs, inputs[:, -1:].expand(-1, states.shape[1] - inputs.shape[1], -1)], dim=1)
    trust = model.assess(inputs.numpy()[0] if single else inputs.numpy(), res.states, res.accel,
                         None if latent is None else res.latent, physics)
    res.errors, res.out_of_distribution, res.ood_reasons, res.uncertainty = trust
    if single:
        res.terms = {name: Term(np.asarray(t.value).reshape(-1)[0], t.limit, t.unit) for name, t in terms.items()}
        res.end_shift = {name: Term(float(np.asarray(t.value).reshape(-1)[0]), t.limit, t.unit)
                         for name, t in res.end_shift.items()}
        for stage in res.stages:
            stage.objective = stage.objective[:1]
    if robot is not None:
        model._judge_on_robot(res, robot)
    return res


def _polish(
    model: TrainedModel, objective: Objective, x0: torch.Tensor, states: torch.Tensor, accel: torch.Tensor,
    constraints: list, arm: ArmForm | None = None,
) -> tuple[torch.Tensor, torch.Tensor, np.ndarray, Stage]:
    """Each trajectory's motion closest to the latent stage's that meets ``constraints`` and the task's exactly;
    with ``arm`` (one trajectory), within a robot's limits too (:meth:`TrainedModel.polish_on_arm`: the result may be
    longer; where the polish fails, it is the last try's motion, judged as it is)."""
    start = time.perf_counter()
    b = len(states)
    x0_np, accel_np = x0.double().numpy(), accel.numpy()
    out_states, out_accel = states.clone(), accel.clone()
    exact, iterations, status = np.zeros(b, bool), np.zeros(b, int), []
    for i in range(b):
        params = [p[i] if len(p) > 1 else p[0] for _, p in constraints]
        if arm is None:
            solution = model.polish(x0_np[i], accel_np[i], [c for c, _ in constraints], params)
        else:  # one trajectory, which may take longer than the latent stage's: the result holds what was found
            solution = model.polish_on_arm(x0_np[i], accel_np[i], arm,
                                           [c for c, _ in constraints], params)
            out_states, out_accel = (torch.from_numpy(a)[None] for a in (solution.states, solution.accel))
        iterations[i], found = solution.iterations, solution.status
        new_states = torch.from_numpy(solution.states)[None]
        new_accel = torch.from_numpy(solution.accel)[None]
        violation = model.violation_torch(new_states, new_accel)
        worst = 0.0 if violation is None or violation.numel() == 0 else float(violation.max())
        if solution.success and worst <= POLISH_VIOLATION_TOLERANCE:
            out_states[i], out_accel[i], exact[i] = new_states[0], new_accel[0], True
        else:
            found += f" (violation {worst:.2g})" if solution.success else ""
            reason = "the constraints cannot all hold (target unreachable?)" if solution.infeasible else found
            warnings.warn(f"exact polish failed on trajectory {i}: {reason}; it keeps the unpolished motion",
                          RuntimeWarning, stacklevel=3)
        status.append(found)
    with torch.no_grad():
        value = objective(out_states, out_accel).double().expand(b).numpy()
    return out_states, out_accel, exact, Stage("polish", iterations, time.perf_counter() - start, value, status)


def _warn_if_infeasible(violation: torch.Tensor | None) -> None:
    """Say which trajectories break the task's constraint (largest violation > :data:`FEASIBLE_TOLERANCE`)."""
    if violation is None or violation.shape[-1] == 0:
        return
    worst = violation.amax(-1)
    broken = torch.nonzero(worst > FEASIBLE_TOLERANCE).flatten().tolist()
    if broken:
        which = "the motion" if len(worst) == 1 else f"trajectories {broken}"
        warnings.warn(
            f"the task's constraint is missed on {which}: largest violation {float(worst.max()):.3g} > "
            f"{FEASIBLE_TOLERANCE} (res.violation, res.terms); weigh it up (objective + "
            f"sm.objectives.TaskConstraint(alpha=...)), run more updates, or polish it with exact=True",
            RuntimeWarning, stacklevel=4,
        )


def _end_shift(
    model: TrainedModel, objective: Objective, inputs: torch.Tensor, states: torch.Tensor
) -> dict[str, Term]:
    """:attr:`OptimizationResult.end_shift` of ``states`` ``(B, K, S)`` against ``inputs`` ``(B, K, S)``."""
    task, layout = model.task_def, model.state_layout
    if task.end_pose is None or model.input_layout.names != layout.names:
        return {}  # no end pose, or inputs in other terms than the states: nothing to compare the end with
    named, shift = objective.end_fields, {}
    for name, weight in zip(*task.end_pose, strict=True):
        if name in named or weight <= 0:
            continue
        col = layout.index(name)
        moved = (states[:, -1, col] - inputs[:, -1, col].double()).abs().numpy()
        shift[name] = Term(moved, END_SHIFT_TOLERANCE / float(weight), layout.units[col])
    return shift


def _warn_if_outcome_changed(shift: dict[str, Term], model: TrainedModel, inputs: torch.Tensor,
                             states: torch.Tensor) -> None:
    """Say which end-pose fields the objective left free ended away from the input's (:func:`_end_shift`)."""
    changed = {name: np.atleast_1d(~np.asarray(term.met)) for name, term in shift.items()
               if not bool(np.all(term.met))}
    if not changed:
        return
    layout, parts = model.state_layout, []
    for name, off in changed.items():
        col = layout.index(name)
        unit = layout.units[col]
        if len(states) == 1:
            parts.append(f"{name} {float(inputs[0, -1, col]):.3g} → {float(states[0, -1, col]):.3g} {unit}")
        else:
            parts.append(f"{name} on trajectories {np.flatnonzero(off).tolist()}")
    names = list(changed)
    warnings.warn(
        f"the objective aims for no end value of {', '.join(names)}, and the motion does not end where the input "
        f"does there ({'; '.join(parts)}): it no longer does the input's task (res.end_shift); name "
        f"{'it' if len(names) == 1 else 'them'} in the objective to keep {'it' if len(names) == 1 else 'them'}, "
        f"e.g. Ranges(end={{{names[0]!r}: (low, high)}})", RuntimeWarning, stacklevel=4,
    )


def _result(
    states: torch.Tensor, accel: torch.Tensor, latent: torch.Tensor | None, violation: np.ndarray | None,
    history: np.ndarray, seconds: float, single: bool,
) -> OptimizationResult:
    states_np = check_finite_result(states.double().numpy(), "optimisation")
    accel_np = accel.double().numpy()
    latent_np = None if latent is None else latent.float().numpy()
    if single:
        states_np, accel_np = states_np[0], accel_np[0]
        latent_np = None if latent_np is None else latent_np[0]
        violation = None if violation is None else violation[0]
        history = history[:, 0] if history.ndim == 2 else history
    return OptimizationResult(states_np, accel_np, latent_np, violation, history=history,  # type: ignore[arg-type]
                              seconds_per_update=seconds)
