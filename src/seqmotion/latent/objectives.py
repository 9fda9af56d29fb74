"""Objectives for latent-space adjustment (ch. 4, eqs. 4.3–4.4 and 4.10).

An objective maps a batch of decoded motions to one value per trajectory::

    J(states (B, K, S), accel (B, K-1, d)) -> (B,)

:class:`EndPose` (J1) works for any task that declares an end pose (``Task.end_pose``: the
fields it reaches for and their weights) and penalises the task's own constraint
(``Task.violation``) at the model's options — the pancake's friction cone at the μ the model
was trained with. :class:`Ranges` (J2) puts bands on end values and limits on any fields of a
task's state layout, by name (without names: the pancake's bands of eq. 4.10). Any
differentiable callable with the signature above is an objective too (returning ``(B,)`` or a
scalar); :class:`Function` with ``residuals=`` gives least-squares form, which
Levenberg–Marquardt (``optimizer="lm"``) needs. Objectives compose with ``+`` and ``*``::

    objective = 2 * EndPose((0.1, 0.0, math.pi)) + my_callable

**Every objective keeps the task's constraint.** :func:`seqmotion.optimize_latent` *binds* an
objective to the model first (:func:`for_model`): an objective that declares a state layout refuses
a model of another layout (``ValueError`` naming both), μ and the end-pose fields come from the
model, and an objective that does not penalise the task's constraint itself (``EndPose`` and
``Ranges`` do; a plain callable, ``AtRest`` do not) gets :class:`TaskConstraint` added — ``J + Σ_k
F[k]``, reported as the term ``"constraint"``. Add ``TaskConstraint(alpha=...)`` yourself to weigh it
(``alpha=0``: only report it).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..core.results import FEASIBLE_TOLERANCE
from ..errors import as_float_array, check_number
from ..physics.layout import StateLayout
from ..physics.pancake import MU, STATE_LAYOUT, violation_torch
from ..physics.transcription import Constraint, end_values, scale_rows

D_WEIGHTS = (1.0, 1.0, 0.1)
"""D = diag(1, 1, 0.1): metres against radians (eqs. 2.25, 4.3)."""

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
        if not math.isfinite(weight):
            raise ValueError(f"an objective's weight must be finite, got {weight}")
        self.weight, self.inner = weight, inner

    def bind(self, model: Any) -> Objective:
        return Scaled(self.weight, self.inner.bind(model))

    @property
    def least_squares(self) -> bool:
        return self.weight >= 0 and self.inner.least_squares

    @property
    def keeps_constraint(self) -> bool:
        return self.weight > 0 and self.inner.keeps_constraint

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


def Residuals(  # noqa: N802 - reads as the objective it builds
    residuals: ObjectiveFn, penalty: ObjectiveFn | None = None, layout: StateLayout | None = None
) -> Function:
    """``J = |r(states, accel)|² (+ penalty)``: a least-squares objective from a residual function."""
    return Function(residuals=residuals, penalty=penalty, layout=layout)


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


def dynamic_penalty(states: torch.Tensor, accel: torch.Tensor, mu: float = MU) -> torch.Tensor:
    """``f_dyn = Σ_k F_c[k]`` per trajectory (eq. 4.4) [rad]."""
    return violation_torch(states[:, : accel.shape[1], 2], accel, mu).sum(1)


def for_model(objective: object, model: Any) -> Objective:
    """``objective`` (an :class:`Objective` or a callable) bound to ``model`` (:meth:`Objective.bind`), keeping
    the task's constraint: one that does not penalise it itself gets ``+ TaskConstraint()`` (a task without a
    constraint gets nothing added)."""
    bound = as_objective(objective).bind(model)
    if bound.keeps_constraint:
        return bound
    constraint = TaskConstraint().bind(model)
    return bound if constraint.empty(model) else bound + constraint


ViolationFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor | None]


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
    return Term(_np(_max_per_trajectory(violation)), FEASIBLE_TOLERANCE, "(violation)")


class TaskConstraint(Objective):
    """The task's own constraint as a term: ``J = α Σ_k F[k]`` with ``F`` the task's violation
    (``Task.violation`` at the model's options; pancake: the friction cone F_c [rad]).

    :func:`seqmotion.optimize_latent` adds it, α = 1, to every objective that does not penalise the
    constraint itself (a plain callable, :class:`AtRest`): J then weighs the constraint the way
    :class:`EndPose` does. Add it yourself to choose α (``f + TaskConstraint(alpha=100)``); ``alpha=0``
    leaves the constraint out of J, and it is still reported (``res.terms["constraint"]``, a warning
    when missed). It has no residuals, only the penalty ``α Σ F``: added to a least-squares objective
    the sum stays least-squares (Levenberg–Marquardt works on it); alone it is gradient descent's.
    Unbound (called directly) it reads pancake states at μ = 1.

    Args:
        alpha: weight α ≥ 0 of the constraint's penalty.
    """

    def __init__(self, alpha: float = 1.0) -> None:
        self.alpha = _check_weight("alpha", alpha)
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
        if self._violation is None:  # unbound: the pancake's cone at μ = 1
            return violation_torch(states[:, : accel.shape[1], 2], accel, MU)
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


class EndPose(Objective):
    """J1 (eqs. 4.3–4.4): ``|D (p[K-1] − p_end)|² + α Σ_k F[k]`` for any task with an end pose.

    ``p`` are the task's end-pose fields and ``D`` their weights (``Task.end_pose``; pancake:
    ``(y, z, θ)`` with D = diag(1, 1, 0.1)), ``F`` the task's constraint violation (pancake: the
    friction cone F_c) at the model's options. Unbound (called directly), it reads pancake states.

    Args:
        target: one value per end-pose field (pancake ``(y, z, θ)`` [m, m, rad]), or ``(B, n)``
            one target per trajectory.
        alpha: weight α of the constraint penalty (≥ 0).
        mu: judge the cone at this μ instead of the model's own (pancake; default: the model's).
        fields, weights: reach for these state fields with these weights instead of the task's.
        tolerance: the end error ``|D (p[K-1] − p_end)|`` at which :meth:`report` counts the
            target as reached (default 1e-3: 1 mm, or 0.01 rad with D's 0.1).
    """

    def __init__(
        self, target: Sequence[float] | np.ndarray, alpha: float = 1.0, mu: float | None = None,
        fields: Sequence[str] | None = None, weights: Sequence[float] | None = None, tolerance: float = 1e-3,
    ) -> None:
        target_arr = as_float_array(target, "target")
        if target_arr.ndim not in (1, 2) or target_arr.shape[-1] < 1 or target_arr.size == 0:
            raise ValueError(f"target must be one value per end-pose field or (B, n), got shape {target_arr.shape}")
        if not np.all(np.isfinite(target_arr)):
            raise ValueError(f"target must be finite, got {target_arr.tolist()}")
        _check_weight("alpha", alpha)
        if mu is not None:
            _check_weight("mu", mu, positive=True)
        _check_fields(fields)
        if weights is not None:
            if fields is None or isinstance(weights, str) or len(weights) != len(fields):
                raise ValueError("weights need fields, one weight per field")
            for w in weights:
                _check_weight("weights", w)
        _check_weight("tolerance", tolerance)
        self.target, self.alpha, self.mu = target_arr, float(alpha), None if mu is None else float(mu)
        self.tolerance = float(tolerance)
        self.fields = None if fields is None else tuple(fields)
        self.weights = None if weights is None else tuple(float(w) for w in weights)
        self._columns: list[int] | slice | None = None
        self._violation: ViolationFn | None = None

    def _bind_columns(self, layout: StateLayout, fields: Sequence[str], weights: Sequence[float], task: str) -> None:
        if self.target.shape[-1] != len(fields):
            raise ValueError(
                f"EndPose target has {self.target.shape[-1]} values, but the {task!r} task's end pose is "
                f"{list(fields)} in {layout}"
            )
        columns = [layout.index(f) for f in fields]
        # a run of neighbouring columns is read as a slice: a view, cheaper to differentiate than a gather
        contiguous = columns == list(range(columns[0], columns[0] + len(columns)))
        self._columns = slice(columns[0], columns[-1] + 1) if contiguous else columns
        self.weights = tuple(float(w) for w in weights)
        self._field_names = tuple(fields)

    def bind(self, model: Any) -> EndPose:
        task = model.task_def
        if self.fields is not None:
            fields, weights = self.fields, self.weights or (1.0,) * len(self.fields)
        elif task.end_pose is not None:
            fields, weights = task.end_pose
        else:
            raise ValueError(f"task {task.name!r} declares no end pose; give EndPose(target, fields=[...]) of "
                             f"{model.state_layout}")
        bound = EndPose(self.target, self.alpha, self.mu, fields, weights, self.tolerance)
        bound.layout = model.state_layout
        bound._bind_columns(model.state_layout, fields, weights, task.name)
        bound._violation = _task_violation(model, self.mu, "EndPose")
        return bound

    def end_error(self, states: torch.Tensor) -> torch.Tensor:
        """``D (p[K-1] − p_end)`` per trajectory, ``(B, n)``."""
        if self._columns is None:
            if self.fields is not None:
                raise ValueError("EndPose with fields= must be bound to a model first (optimize_latent does)")
            # called directly, unbound: the dissertation's J1 on pancake states
            self._bind_columns(STATE_LAYOUT, ("y", "z", "theta"), D_WEIGHTS, "pancake")
        target = torch.as_tensor(self.target, dtype=states.dtype, device=states.device)
        d = torch.tensor(self.weights, dtype=states.dtype, device=states.device)
        return d * (states[:, -1, self._columns] - target)

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return (self.end_error(states) ** 2).sum(-1) + self.penalty(states, accel)

    @property
    def least_squares(self) -> bool:
        return True

    @property
    def keeps_constraint(self) -> bool:
        return True

    def _column_list(self) -> list[int]:
        if self._columns is None:
            self.end_error(torch.zeros(1, 2, STATE_LAYOUT.dim, dtype=torch.float64))  # binds the pancake default
        cols = self._columns
        return list(range(cols.start, cols.stop)) if isinstance(cols, slice) else list(cols)  # type: ignore[union-attr]

    def exact_constraints(self) -> list[tuple[Constraint, np.ndarray]]:
        """The end-pose fields equal the target at the last sample (the cone is the task's own constraint)."""
        return [(end_values(self._column_list(), "end pose"), np.atleast_2d(self.target))]

    def report(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, Term]:
        """``end error``: ``|D (p[K-1] − p_end)|`` (≤ ``tolerance``); ``constraint``: the largest violation
        (≤ 0.01, the feasibility tolerance)."""
        with torch.no_grad():
            terms = {"end error": Term(_np(self.end_error(states).norm(dim=-1)), self.tolerance, "(D-weighted)")}
            violation = self._violation(states, accel) if self._violation is not None else \
                violation_torch(states[:, : accel.shape[1], 2], accel, MU if self.mu is None else self.mu)
            if violation is not None:
                terms["constraint"] = _constraint_term(violation)
        return terms

    def residuals(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return self.end_error(states)

    def penalty(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        if self._violation is None:  # unbound: the pancake's cone at the given μ (1 by default)
            return self.alpha * dynamic_penalty(states, accel, MU if self.mu is None else self.mu)
        violation = self._violation(states, accel)
        if violation is None or self.alpha == 0:
            return torch.zeros(states.shape[0], dtype=states.dtype, device=states.device)
        return self.alpha * violation.sum(1)

    def __repr__(self) -> str:
        return f"EndPose(target={self.target.tolist()}, alpha={self.alpha:g})"


def _check_fields(fields: object) -> None:
    if fields is not None and (
        isinstance(fields, str) or not hasattr(fields, "__len__") or len(fields) == 0  # type: ignore[arg-type]
        or not all(isinstance(f, str) for f in fields)  # type: ignore[attr-defined]
    ):
        raise ValueError(f"fields must be a non-empty sequence of state field names, got {fields!r}")


def _check_weight(name: str, value: Any, positive: bool = False) -> float:
    """``value`` as a float; ``ValueError`` naming ``name`` unless it is a finite number ≥ 0 (> 0 if ``positive``)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    if value < 0 or (positive and value == 0):
        raise ValueError(f"{name} must be {'>' if positive else '≥'} 0, got {value!r}")
    return float(value)


class Ranges(Objective):
    """J2 (eq. 4.10): bands on end values, the task's constraint penalty and limits along the motion.

    **By field name, for any task** (``end=`` and/or ``limits=``, names of the task's state layout)::

        Ranges(end={"x": (0.025, 0.03)}, limits={"v_x": 0.4, "v_y": 0.4})   # the tray's [x, y, v_x, v_y]

    ``J = Σ_f w_f max(|x_f[K-1] − c_f| − h_f, 0) + α Σ_k F[k] + β/K Σ_{k≥1} Σ_g max(0, w_g (|x_g[k]| − l_g))²``

    with each end band ``[low, high] = [c − h, c + h]``, the limits ``l`` from sample 1 (the start
    state is given), ``w = 0.1`` for a field in rad or rad/s (D's weighting) and 1 otherwise, and ``F``
    the task's constraint at the model's options. Terms: ``"end <field> band"`` and ``"limits"`` (the
    excess, met at 0) and ``"constraint"``.

    **Without names: the pancake's** (the dissertation's eq. 4.10; refuses a model of another layout)::

        max(|p_yz[K-1]| − p_lim, 0) + 0.1 max(|θ[K-1] − θ_end| − θ_lim, 0) + α f_dyn
        + β/K Σ_k |max(0, D(|ṗ[k]| − v_lim))|²

    with the dissertation's defaults p_lim = 0.2 m, θ_end = −3π/4, θ_lim = 0.5 rad, α = 1, β = 0.01,
    v_lim = (1.5 m/s, 1.5 m/s, 4.5 rad/s). Terms: ``"end position band"``, ``"end attitude band"``,
    ``"velocity limits"``, ``"friction cone"``.

    Args:
        p_lim, theta_end, theta_lim, v_lim: the pancake's bands [m, rad, rad, (m/s, m/s, rad/s)]; not
            with ``end``/``limits``.
        alpha: weight α ≥ 0 of the constraint's penalty; beta: weight β ≥ 0 of the limits.
        mu: judge the cone at this μ instead of the model's own (tasks with a friction option ``mu``).
        end: field name → ``(low, high)`` band on its last value [the field's unit].
        limits: field name → the largest ``|value|`` along the motion (> 0) [the field's unit].
    """

    def __init__(
        self,
        p_lim: float | None = None,
        theta_end: float | None = None,
        theta_lim: float | None = None,
        alpha: float = 1.0,
        beta: float = 0.01,
        v_lim: Sequence[float] | None = None,
        mu: float | None = None,
        *,
        end: Mapping[str, Sequence[float]] | None = None,
        limits: Mapping[str, float] | None = None,
    ) -> None:
        self.alpha, self.beta = _check_weight("alpha", alpha), _check_weight("beta", beta)
        self.mu = None if mu is None else _check_weight("mu", mu, positive=True)
        self.end, self.limits = _check_bands(end), _check_limits(limits)
        self.named = self.end is not None or self.limits is not None
        if self.named:
            given = [n for n, v in (("p_lim", p_lim), ("theta_end", theta_end), ("theta_lim", theta_lim),
                                    ("v_lim", v_lim)) if v is not None]
            if given:
                raise ValueError(f"{', '.join(given)}: the pancake's bands; with end=/limits= give every band by "
                                 f"field name, e.g. Ranges(end={{'theta': (-2.9, -1.9)}})")
            self.layout: StateLayout | None = None  # any task's: bound to the model's
            self._end_columns: list[int] | None = None
            self._limit_columns: list[int] | None = None
            self._violation: ViolationFn | None = None
            return
        p_lim = 0.2 if p_lim is None else p_lim
        theta_end = -3 * math.pi / 4 if theta_end is None else theta_end
        theta_lim = 0.5 if theta_lim is None else theta_lim
        v_lim = (1.5, 1.5, 4.5) if v_lim is None else v_lim
        for name, value in (("p_lim", p_lim), ("theta_lim", theta_lim)):
            _check_weight(name, value)
        check_number("theta_end", theta_end)
        if isinstance(v_lim, str) or not hasattr(v_lim, "__len__") or len(v_lim) != 3:
            raise ValueError(f"Ranges needs three velocity limits (v_y, v_z, v_theta), got {v_lim!r}")
        for value in v_lim:
            _check_weight("v_lim", value)
        self.layout = STATE_LAYOUT
        self.p_lim, self.theta_end, self.theta_lim = float(p_lim), float(theta_end), float(theta_lim)
        self.v_lim = tuple(map(float, v_lim))

    @property
    def keeps_constraint(self) -> bool:
        return True

    def bind(self, model: Any) -> Ranges:
        """The pancake's bands: checks the model generates pancake states (μ defaults to the model's). By
        field name: the fields' columns in the model's layout (``ValueError`` naming its columns) and the
        task's constraint at the model's options."""
        if not self.named:
            try:
                check_layout(self, model)
            except ValueError as exc:
                raise ValueError(f"{exc}; for its layout give the bands by field name: "
                                 f"Ranges(end={{field: (low, high)}}, limits={{field: limit}})") from None
            mu = self.mu if self.mu is not None else model.options.mu
            return Ranges(self.p_lim, self.theta_end, self.theta_lim, self.alpha, self.beta, self.v_lim, mu)
        bound = Ranges(alpha=self.alpha, beta=self.beta, mu=self.mu, end=self.end, limits=self.limits)
        layout = bound.layout = model.state_layout
        bound._end_columns = [layout.index(f) for f in self.end or {}]
        bound._limit_columns = [layout.index(f) for f in self.limits or {}]
        bound._violation = _task_violation(model, self.mu, "Ranges")
        return bound

    def _named(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, torch.Tensor]:
        """By field name: each end band's excess ``(B, n)`` (w-weighted with ``weighted``), the limits' excess
        ``(B, K-1, m)`` and the constraint ``(B, K-1)`` (absent without one)."""
        if self._end_columns is None or self._limit_columns is None or self.layout is None:
            raise ValueError("Ranges(end=..., limits=...) must be bound to a model first (optimize_latent does)")
        like = {"dtype": states.dtype, "device": states.device}
        units = self.layout.units
        bands = torch.tensor(list((self.end or {}).values()), **like).reshape(-1, 2)
        limits = torch.tensor(list((self.limits or {}).values()), **like)
        out = {
            "end": torch.relu((states[:, -1, self._end_columns] - bands.mean(-1)).abs()
                              - (bands[:, 1] - bands[:, 0]) / 2),
            "limits": torch.relu(states[:, 1:, self._limit_columns].abs() - limits),
            "w_end": torch.tensor([_d_weight(units[c]) for c in self._end_columns], **like),
            "w_limits": torch.tensor([_d_weight(units[c]) for c in self._limit_columns], **like),
        }
        violation = self._violation(states, accel) if self._violation is not None else None
        if violation is not None:
            out["constraint"] = violation
        return out

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        if self.named:
            parts = self._named(states, accel)
            value = (parts["w_end"] * parts["end"]).sum(-1)
            value = value + self.beta / states.shape[1] * ((parts["w_limits"] * parts["limits"]) ** 2).sum((1, 2))
            if "constraint" in parts:
                value = value + self.alpha * parts["constraint"].sum(1)
            return value
        end = states[:, -1]
        position_band = torch.relu(torch.sqrt(end[:, 0] ** 2 + end[:, 1] ** 2 + 1e-30) - self.p_lim)
        attitude_band = 0.1 * torch.relu((end[:, 2] - self.theta_end).abs() - self.theta_lim)
        d = torch.tensor(D_WEIGHTS, dtype=states.dtype, device=states.device)
        v_lim = torch.tensor(self.v_lim, dtype=states.dtype, device=states.device)
        excess = torch.relu(d * (states[..., 3:].abs() - v_lim))
        velocity = self.beta / states.shape[1] * (excess**2).sum((1, 2))
        cone = dynamic_penalty(states, accel, MU if self.mu is None else self.mu)
        return position_band + attitude_band + self.alpha * cone + velocity

    def _excess(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, torch.Tensor]:
        """How far each of the pancake's bands is overstepped, ``(B,)`` each (0 where it holds)."""
        end = states[:, -1]
        v_lim = torch.tensor(self.v_lim, dtype=states.dtype, device=states.device)
        return {
            "end position band": torch.relu(torch.sqrt(end[:, 0] ** 2 + end[:, 1] ** 2) - self.p_lim),
            "end attitude band": torch.relu((end[:, 2] - self.theta_end).abs() - self.theta_lim),
            # from sample 1: the start state is given, not generated (a linear sketch starts moving)
            "velocity limits": torch.relu(states[:, 1:, 3:].abs() - v_lim).amax((1, 2)),
        }

    def report(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, Term]:
        """Each band's excess [the field's unit] and the limits' largest excess (met at 0, to 1e-6), and the
        largest constraint violation (≤ 0.01; the pancake's: its friction cone [rad])."""
        with torch.no_grad():
            if self.named:
                parts = self._named(states, accel)
                assert self.layout is not None and self._end_columns is not None
                terms = {f"end {name} band": Term(_np(parts["end"][:, i]), 1e-6, self.layout.units[col])
                         for i, (name, col) in enumerate(zip(self.end or {}, self._end_columns, strict=True))}
                if self.limits:
                    terms["limits"] = Term(_np(parts["limits"].flatten(1).amax(-1)), 1e-6, "(field units)")
                if "constraint" in parts:
                    terms["constraint"] = _constraint_term(parts["constraint"])
                return terms
            units = {"end position band": "m", "end attitude band": "rad", "velocity limits": "(m/s, rad/s)"}
            terms = {name: Term(_np(v), 1e-6, units[name]) for name, v in self._excess(states, accel).items()}
            cone = violation_torch(states[:, : accel.shape[1], 2], accel, MU if self.mu is None else self.mu)
            terms["friction cone"] = Term(_np(_max_per_trajectory(cone)), FEASIBLE_TOLERANCE, "rad")
        return terms

    def exact_constraints(self) -> list[tuple[Constraint, np.ndarray]]:
        """The bands and limits (from sample 1: the start state is given) as hard constraints (the task's
        constraint is the polish's own)."""
        none = np.zeros((1, 0))
        if self.named:
            if self._end_columns is None or self._limit_columns is None:
                raise ValueError("Ranges(end=..., limits=...) must be bound to a model first (optimize_latent does)")
            out = []
            if self.end:
                cols, bands = tuple(self._end_columns), tuple(tuple(b) for b in self.end.values())
                low, high = tuple(b[0] for b in bands), tuple(b[1] for b in bands)
                out.append((Constraint("end bands", ("ranges_end", cols, bands),
                                       lambda x, u, p: x[list(cols), -1], low, high), none))
            if self.limits:
                cols, lims = tuple(self._limit_columns), np.array(list(self.limits.values()))
                out.append((Constraint("limits", ("ranges_limits", cols, *lims.tolist()),
                                       lambda x, u, p: scale_rows(x[list(cols), 1:], 1 / lims), -1.0, 1.0), none))
            return out
        p_lim, theta_end, theta_lim, v_lim = self.p_lim, self.theta_end, self.theta_lim, np.array(self.v_lim)
        return [
            (Constraint("end position band", ("ranges_position", p_lim),
                        lambda x, u, p: x[0, -1] ** 2 + x[1, -1] ** 2, -math.inf, p_lim**2), none),
            (Constraint("end attitude band", ("ranges_attitude", theta_end, theta_lim),
                        lambda x, u, p: x[2, -1], theta_end - theta_lim, theta_end + theta_lim), none),
            # |v| ≤ v_lim per field, scaled so every bound is ±1
            (Constraint("velocity limits", ("ranges_velocity", *self.v_lim),
                        lambda x, u, p: scale_rows(x[3:6, 1:], 1 / np.maximum(v_lim, 1e-12)), -1.0, 1.0), none),
        ]

    def __repr__(self) -> str:
        if self.named:
            return f"Ranges(end={self.end}, limits={self.limits})"
        return f"Ranges(p_lim={self.p_lim}, theta_end={self.theta_end:.4f}, theta_lim={self.theta_lim})"


def _d_weight(unit: str) -> float:
    """D's weighting of a field: 0.1 for an angle or angular rate (rad against metres), 1 otherwise."""
    return 0.1 if unit in ("rad", "rad/s") else 1.0


def _check_bands(end: object) -> dict[str, tuple[float, float]] | None:
    """``Ranges(end=...)``: field name → ``(low, high)``, finite, low ≤ high."""
    if end is None:
        return None
    if not isinstance(end, Mapping) or not end:
        raise ValueError(f"Ranges end= must be a non-empty mapping field name → (low, high), got {end!r}")
    out = {}
    for name, band in end.items():
        values = np.asarray(band, dtype=object)
        if not isinstance(name, str) or values.shape != (2,) or not all(
            isinstance(v, int | float | np.floating) and not isinstance(v, bool) and math.isfinite(v) for v in values
        ) or values[0] > values[1]:
            raise ValueError(f"Ranges end band of {name!r} must be finite (low, high) with low ≤ high, got {band!r}")
        out[name] = (float(values[0]), float(values[1]))
    return out


def _check_limits(limits: object) -> dict[str, float] | None:
    """``Ranges(limits=...)``: field name → the largest |value|, finite and > 0."""
    if limits is None:
        return None
    if not isinstance(limits, Mapping) or not limits:
        raise ValueError(f"Ranges limits= must be a non-empty mapping field name → limit, got {limits!r}")
    out = {}
    for name, value in limits.items():
        if not isinstance(name, str):
            raise ValueError(f"Ranges limits= must map field names to limits, got key {name!r}")
        out[name] = _check_weight(f"Ranges limits[{name!r}]", value, positive=True)
    return out


class AtRest(Objective):
    """The motion ends at rest: ``J = Σ_j (w_j v_j[K-1])²`` over the layout's rate fields.

    Rate fields are those whose unit ends in ``/s`` (pancake: v_y, v_z, v_θ); ``w`` is 1, and 0.1
    for ``rad/s`` (D's weighting). Least-squares, so it composes with :class:`EndPose` for
    Levenberg–Marquardt, and has an exact form (the rate fields equal 0 at the last sample).

    Args:
        fields: the state fields that must end at 0 instead of the rate fields.
        tolerance: the largest end rate at which :meth:`report` counts the motion as at rest
            (default 0.01 m/s or rad/s).
    """

    def __init__(self, fields: Sequence[str] | None = None, tolerance: float = 0.01) -> None:
        _check_fields(fields)
        _check_weight("tolerance", tolerance)
        self.fields, self.tolerance = None if fields is None else tuple(fields), float(tolerance)
        self._columns: list[int] | None = None
        self._weights: torch.Tensor | None = None

    def bind(self, model: Any) -> AtRest:
        bound = AtRest(self.fields, self.tolerance)
        bound.layout = model.state_layout
        bound._set_columns(model.state_layout)
        return bound

    def _set_columns(self, layout: StateLayout) -> None:
        names = self.fields or tuple(n for n, u in zip(layout.names, layout.units, strict=True) if u.endswith("/s"))
        if not names:
            raise ValueError(f"{layout} has no rate fields (units ending in /s); give AtRest(fields=[...])")
        self._columns = [layout.index(n) for n in names]
        self._weights = torch.tensor([0.1 if layout.units[c] == "rad/s" else 1.0 for c in self._columns])

    def _bound(self) -> tuple[list[int], torch.Tensor]:
        if self._columns is None:
            self._set_columns(STATE_LAYOUT)  # unbound: pancake states
        assert self._columns is not None and self._weights is not None
        return self._columns, self._weights

    def residuals(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        columns, weights = self._bound()
        return weights.to(states.device, states.dtype) * states[:, -1, columns]

    def penalty(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return torch.zeros(states.shape[0], dtype=states.dtype, device=states.device)

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return (self.residuals(states, accel) ** 2).sum(-1)

    @property
    def least_squares(self) -> bool:
        return True

    def exact_constraints(self) -> list[tuple[Constraint, np.ndarray]]:
        columns, _ = self._bound()
        return [(end_values(columns, "at rest"), np.zeros((1, len(columns))))]

    def report(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, Term]:
        columns, _ = self._bound()
        with torch.no_grad():
            return {"end rate": Term(_np(states[:, -1, columns].abs().amax(-1)), self.tolerance, "(m/s, rad/s)")}

    def __repr__(self) -> str:
        return "AtRest()" if self.fields is None else f"AtRest(fields={list(self.fields)})"


def _np(value: torch.Tensor) -> np.ndarray:
    return value.detach().double().cpu().numpy()


def _max_per_trajectory(violation: torch.Tensor) -> torch.Tensor:
    """The largest value per trajectory of ``(B, N)`` (0 for N = 0)."""
    if violation.shape[-1] == 0:
        return torch.zeros(violation.shape[0], dtype=violation.dtype, device=violation.device)
    return violation.amax(-1)
