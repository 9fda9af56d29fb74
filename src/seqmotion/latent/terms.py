"""The algebra of latent-adjustment objectives, for any task: :class:`Objective` (``+``, ``*``, least-squares
form), :class:`Function` (a callable), :class:`TaskConstraint` (the task's own constraint as a term) and
:class:`Term` (how a term is judged on a motion).

:mod:`seqmotion.latent.objectives` (``sm.objectives``) is the public namespace: it re-exports these beside the
objectives that reach for a task's fields (``EndPose``, ``AtRest``, ``Ranges``); objectives beside one task
(:mod:`seqmotion.tasks.pancake.latent`) build on this module.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..core.results import FEASIBLE_TOLERANCE
from ..errors import check_number
from ..physics.layout import StateLayout
from ..physics.transcription import Constraint

ObjectiveFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass
class Term:
    """One term of an objective, judged on a motion (:meth:`Objective.report`).

    Attributes:
        value: the term's measure, a float or ``(B,)`` (e.g. the end error [m], the largest cone
            violation [rad], the largest excess over a velocity limit).
        limit: the largest value at which the term counts as met.
        unit: ``value``'s unit.
    """

    value: Any
    limit: float
    unit: str = ""

    @property
    def met(self) -> Any:
        """Whether ``value ≤ limit`` (per trajectory for a batch)."""
        ok = np.asarray(self.value) <= self.limit
        return bool(ok) if ok.ndim == 0 else ok

    def __str__(self) -> str:
        values = np.atleast_1d(np.asarray(self.value, dtype=float))
        worst = float(values.max()) if values.size else 0.0
        verdict = "met" if bool(np.all(values <= self.limit)) else "MISSED"
        return f"{worst:.3g} {self.unit} (limit {self.limit:.3g}) {verdict}".replace("  ", " ")


_NO_EXACT = (
    "{self!r} has no exact form, so exact=True cannot make it exact; exact=True takes EndPose, AtRest, Ranges "
    "and their weighted sums (or an Objective subclass with exact_constraints)"
)


_NO_RESIDUALS = (
    "{self!r} has no least-squares residuals; use optimizer='sgd' or 'adam', or give them: "
    "sm.objectives.Function(residuals=f) with f(states, accel) -> (B, m) residuals r (J = |r|²), "
    "optionally penalty=g with g -> (B,)"
)


class Objective:
    """Base class: callable on ``(states, accel)``, composable with ``+`` and ``*``.

    Objectives of least-squares form ``J = |r|² + p`` may also expose ``residuals`` (B, m) and
    ``penalty`` (B,); the Levenberg–Marquardt optimiser (``optimizer="lm"``) needs them.

    ``layout``: the state layout the objective reads (None: any). :meth:`bind` returns the
    objective set up for a trained model and refuses a model of another layout.
    """

    layout: StateLayout | None = None

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    @property
    def least_squares(self) -> bool:
        """Whether the objective has least-squares form (``residuals``, ``penalty``): then the default
        optimiser is Levenberg–Marquardt."""
        return False

    @property
    def keeps_constraint(self) -> bool:
        """Whether the objective penalises the task's constraint itself (:class:`EndPose`, :class:`Ranges`,
        :class:`TaskConstraint`); :func:`for_model` adds :class:`TaskConstraint` to one that does not."""
        return False

    @property
    def end_fields(self) -> frozenset[str]:
        """The state fields whose end value the objective itself aims for (an end pose, bands, rest): the
        optimisation reports how far the task's other end-pose fields moved from the input's
        (``OptimizationResult.end_shift``). Default: none (a plain function names no field)."""
        return frozenset()

    def exact_constraints(self) -> list[tuple[Constraint, np.ndarray]]:
        """The objective as hard constraints for the exact polish: ``(constraint, parameters (B, n))`` pairs.

        Only objectives whose goal is a set (an end pose, rest, bands) have one; ``ValueError`` otherwise.
        """
        raise ValueError(_NO_EXACT.format(self=self))

    def report(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, Term]:
        """Each term of the objective on the motions ``states`` ``(B, K, S)``, ``accel`` ``(B, K-1, d)``:
        name → :class:`Term` (value, limit, whether met). Default: none (a plain function has no terms)."""
        return {}

    def residuals(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        raise ValueError(_NO_RESIDUALS.format(self=self))

    def penalty(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        raise ValueError(_NO_RESIDUALS.format(self=self))

    def bind(self, model: Any) -> Objective:
        """This objective for ``model`` (a trained seqmotion model): checks the layout; subclasses
        also take the model's options (μ) and task-declared fields."""
        check_layout(self, model)
        return self

    def __add__(self, other: object) -> Objective:
        return Sum([self, as_objective(other)])

    def __radd__(self, other: object) -> Objective:
        if isinstance(other, (int, float)) and other == 0:  # so sum([...]) works
            return self
        return Sum([as_objective(other), self])

    def __mul__(self, weight: float) -> Objective:
        if not isinstance(weight, (int, float)):
            raise ValueError(f"objectives can only be scaled by numbers, got {type(weight).__name__}")
        return Scaled(float(weight), self)

    __rmul__ = __mul__


class Sum(Objective):
    def __init__(self, parts: Sequence[Objective]) -> None:
        self.parts = list(parts)

    def bind(self, model: Any) -> Objective:
        return Sum([part.bind(model) for part in self.parts])

    @property
    def least_squares(self) -> bool:
        # a penalty-only part (TaskConstraint) adds no residuals: least squares when another part has them
        real = [part for part in self.parts if not _penalty_only(part)]
        return bool(real) and all(part.least_squares for part in real)

    @property
    def keeps_constraint(self) -> bool:
        return any(part.keeps_constraint for part in self.parts)

    @property
    def end_fields(self) -> frozenset[str]:
        return frozenset().union(*(part.end_fields for part in self.parts))

    def exact_constraints(self) -> list[tuple[Constraint, np.ndarray]]:
        return [c for part in self.parts for c in part.exact_constraints()]

    def report(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, Term]:
        return {name: term for part in self.parts for name, term in part.report(states, accel).items()}

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return sum(part(states, accel) for part in self.parts)  # type: ignore[return-value]

    def residuals(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return torch.cat([part.residuals(states, accel) for part in self.parts], dim=-1)

    def penalty(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return sum(part.penalty(states, accel) for part in self.parts)  # type: ignore[return-value]

    def __repr__(self) -> str:
        return " + ".join(map(repr, self.parts))


class Scaled(Objective):
    def __init__(self, weight: float, inner: Objective) -> None:
        self.weight, self.inner = float(check_number("an objective's weight", weight)), inner

    def bind(self, model: Any) -> Objective:
        return Scaled(self.weight, self.inner.bind(model))

    @property
    def least_squares(self) -> bool:
        return self.weight >= 0 and self.inner.least_squares

    @property
    def keeps_constraint(self) -> bool:
        return self.weight > 0 and self.inner.keeps_constraint

    @property
    def end_fields(self) -> frozenset[str]:
        return self.inner.end_fields if self.weight > 0 else frozenset()  # weighted ≤ 0 it aims away, or nowhere

    def exact_constraints(self) -> list[tuple[Constraint, np.ndarray]]:
        if self.weight <= 0:
            raise ValueError(_NO_EXACT.format(self=self))
        return self.inner.exact_constraints()

    def report(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, Term]:
        return self.inner.report(states, accel)

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return self.weight * self.inner(states, accel)

    def residuals(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        if self.weight < 0:
            raise ValueError("a negatively weighted objective has no least-squares form")
        return self.weight**0.5 * self.inner.residuals(states, accel)

    def penalty(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return self.weight * self.inner.penalty(states, accel)

    def __repr__(self) -> str:
        return f"{self.weight:g} * {self.inner!r}"


class Function(Objective):
    """A plain callable as an objective, optionally in least-squares form.

    It knows nothing of the task's constraint: :func:`seqmotion.optimize_latent` optimises it together
    with :class:`TaskConstraint` (``f + Σ_k F[k]``), which reports whether the constraint holds.

    Args:
        fn: ``f(states, accel) -> scalar or (B,)`` tensor, differentiable. Optional when
            ``residuals`` is given (then ``J = |r|² + penalty``).
        residuals: ``r(states, accel) -> (B, m)`` residuals: with them, ``optimizer="lm"``
            (Levenberg–Marquardt) works on this objective.
        penalty: ``p(states, accel) -> (B,)``, a non-negative term added to ``|r|²`` (LM takes
            its gradient as is).
        layout: the state layout ``fn`` reads (refuse models of another layout), or None.
    """

    def __init__(
        self, fn: ObjectiveFn | None = None, *, residuals: ObjectiveFn | None = None,
        penalty: ObjectiveFn | None = None, layout: StateLayout | None = None,
    ) -> None:
        if fn is None and residuals is None:
            raise ValueError("Function needs fn, residuals, or both")
        for name, value in (("fn", fn), ("residuals", residuals), ("penalty", penalty)):
            if value is not None and not callable(value):
                raise ValueError(f"Function's {name} must be callable, got {type(value).__name__}")
        self.fn, self.residual_fn, self.penalty_fn, self.layout = fn, residuals, penalty, layout

    @property
    def least_squares(self) -> bool:
        return self.residual_fn is not None

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        if self.fn is None:
            return (self.residuals(states, accel) ** 2).sum(-1) + self.penalty(states, accel)
        value = self.fn(states, accel)
        if not torch.is_tensor(value):
            raise ValueError(f"objective {self.fn!r} must return a torch tensor, got {type(value).__name__}")
        if value.ndim > 1 or (value.ndim == 1 and value.shape[0] != states.shape[0]):
            shape = tuple(value.shape)
            raise ValueError(f"objective must return a scalar or one value per trajectory, got shape {shape}")
        return value

    def residuals(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        if self.residual_fn is None:
            return super().residuals(states, accel)
        r = self.residual_fn(states, accel)
        if not torch.is_tensor(r) or r.ndim != 2 or r.shape[0] != states.shape[0]:
            raise ValueError(f"residuals must return a (B, m) tensor with B = {states.shape[0]}, got "
                             f"{tuple(r.shape) if torch.is_tensor(r) else type(r).__name__}")
        return r

    def penalty(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        if self.residual_fn is None:
            return super().penalty(states, accel)
        if self.penalty_fn is None:
            return torch.zeros(states.shape[0], dtype=states.dtype, device=states.device)
        p = self.penalty_fn(states, accel)
        if not torch.is_tensor(p) or p.shape != (states.shape[0],):
            raise ValueError(f"penalty must return a (B,) tensor with B = {states.shape[0]}")
        return p

    def __repr__(self) -> str:
        fn = self.fn if self.fn is not None else self.residual_fn
        return getattr(fn, "__name__", repr(fn))


def check_layout(objective: Objective, model: Any) -> None:
    """``ValueError`` naming both when ``objective`` reads another state layout than ``model`` generates."""
    layout = getattr(objective, "layout", None)
    if layout is not None and model.state_layout != layout:
        raise ValueError(
            f"{objective!r} applies to {layout}, but the {model.task_def.name!r} model generates {model.state_layout}"
        )


def as_objective(value: object) -> Objective:
    if isinstance(value, Objective):
        return value
    if callable(value):
        return Function(value)  # type: ignore[arg-type]
    raise ValueError(f"an objective must be an Objective or a callable f(states, accel), got {type(value).__name__}")


ViolationFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor | None]


def unbound(objective: Objective) -> ValueError:
    """The refusal of an objective evaluated before :meth:`Objective.bind`: what it reads comes from the model."""
    return ValueError(f"{objective!r} is not bound to a model: its columns and the task's constraint come from "
                      "the model it adjusts (objective.bind(model); optimize_latent binds it)")


def _task_violation(model: Any, mu: float | None, who: str) -> ViolationFn:
    """The task's constraint violation ``(B, K-1)`` at the model's options (or at ``mu``, for a task with one)."""
    task, options = model.task_def, model.options
    if mu is not None:
        if "mu" not in options.names():
            raise ValueError(f"{who}(mu=...) needs a task with a friction option mu; {task.name!r} has none")
        options = options.replace(mu=mu)
    return lambda states, accel: task.violation(states, accel, options)


def _constraint_term(violation: torch.Tensor) -> Term:
    """The reported constraint term: the largest violation per trajectory (≤ 0.01, the feasibility tolerance)."""
    return Term(as_numpy(max_per_trajectory(violation)), FEASIBLE_TOLERANCE, "(violation)")


class TaskConstraint(Objective):
    """The task's own constraint as a term: ``J = α Σ_k F[k]`` with ``F`` the task's violation
    (``Task.violation`` at the model's options; pancake: the friction cone F_c [rad]).

    :func:`seqmotion.optimize_latent` adds it, α = 1, to every objective that does not penalise the
    constraint itself (a plain callable, :class:`AtRest`): J then weighs the constraint the way
    :class:`EndPose` does. Add it yourself to choose α (``f + TaskConstraint(alpha=100)``); ``alpha=0``
    leaves the constraint out of J, and it is still reported (``res.terms["constraint"]``, a warning
    when missed). It has no residuals, only the penalty ``α Σ F``: added to a least-squares objective
    the sum stays least-squares (Levenberg–Marquardt works on it); alone it is gradient descent's.

    Args:
        alpha: weight α ≥ 0 of the constraint's penalty.
    """

    def __init__(self, alpha: float = 1.0) -> None:
        self.alpha = check_weight("alpha", alpha)
        self._violation: ViolationFn | None = None

    def bind(self, model: Any) -> TaskConstraint:
        bound = TaskConstraint(self.alpha)
        bound._violation = _task_violation(model, None, "TaskConstraint")
        return bound

    def empty(self, model: Any) -> bool:
        """Whether ``model``'s task has no constraint (its ``violation`` returns None)."""
        s, d = model.state_layout.dim, model.accel_layout.dim
        return model.violation_torch(torch.zeros(1, 2, s, dtype=torch.float64),
                                     torch.zeros(1, 1, d, dtype=torch.float64)) is None

    def violation(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor | None:
        """``F`` per transition ``(B, K-1)``, or None for a task without a constraint."""
        if self._violation is None:
            raise unbound(self)
        return self._violation(states, accel)

    @property
    def least_squares(self) -> bool:
        return False  # no residuals: alone, Levenberg–Marquardt has nothing to fit (in a sum it adds its penalty)

    @property
    def keeps_constraint(self) -> bool:
        return True

    def exact_constraints(self) -> list[tuple[Constraint, np.ndarray]]:
        """None of its own: the polish always holds the task's constraint."""
        return []

    def residuals(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return states.new_zeros(states.shape[0], 0)

    def penalty(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        violation = self.violation(states, accel)
        if violation is None or self.alpha == 0:
            return states.new_zeros(states.shape[0])
        return self.alpha * violation.sum(1)

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return self.penalty(states, accel)

    def report(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, Term]:
        """``constraint``: the largest violation (≤ 0.01, the feasibility tolerance); none without a constraint."""
        with torch.no_grad():
            violation = self.violation(states, accel)
            return {} if violation is None else {"constraint": _constraint_term(violation)}

    def __repr__(self) -> str:
        return f"TaskConstraint(alpha={self.alpha:g})"


def _penalty_only(objective: Objective) -> bool:
    """Whether ``objective`` is a penalty without residuals (a non-negatively weighted :class:`TaskConstraint`)."""
    if isinstance(objective, Scaled):
        return objective.weight >= 0 and _penalty_only(objective.inner)
    return isinstance(objective, TaskConstraint)


def _check_fields(fields: object) -> None:
    if fields is not None and (
        isinstance(fields, str) or not hasattr(fields, "__len__") or len(fields) == 0  # type: ignore[arg-type]
        or not all(isinstance(f, str) for f in fields)  # type: ignore[attr-defined]
    ):
        raise ValueError(f"fields must be a non-empty sequence of state field names, got {fields!r}")


def check_weight(name: str, value: Any, positive: bool = False) -> float:
    """``value`` as a float; ``ValueError`` naming ``name`` unless it is a finite number ≥ 0 (> 0 if ``positive``)."""
    return float(check_number(name, value, minimum=0.0, strict_minimum=positive))


def as_numpy(value: torch.Tensor) -> np.ndarray:
    """``value`` as a float64 NumPy array (detached, on the CPU)."""
    return value.detach().double().cpu().numpy()


def max_per_trajectory(violation: torch.Tensor) -> torch.Tensor:
    """The largest value per trajectory of ``(B, N)`` (0 for N = 0)."""
    if violation.shape[-1] == 0:
        return torch.zeros(violation.shape[0], dtype=violation.dtype, device=violation.device)
    return violation.amax(-1)
