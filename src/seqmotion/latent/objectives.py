"""Objectives for latent-space adjustment (ch. 4, eqs. 4.3–4.4 and 4.10).

An objective maps a batch of decoded motions to one value per trajectory::

    J(states (B, K, S), accel (B, K-1, d)) -> (B,)

:class:`EndPose` (J1) works for any task that declares an end pose (``Task.end_pose``: the
fields it reaches for and their weights) and penalises the task's own constraint
(``Task.violation``) at the model's options — the pancake's friction cone at the μ the model
was trained with. :class:`Ranges` (J2) is the pancake's. Any differentiable callable with the
signature above is an objective too (returning ``(B,)`` or a scalar); :class:`Function` with
``residuals=`` gives least-squares form, which Levenberg–Marquardt (``optimizer="lm"``) needs.
Objectives compose with ``+`` and ``*``::

    objective = 2 * EndPose((0.1, 0.0, math.pi)) + my_callable

:func:`seqmotion.optimize_latent` *binds* an objective to the model first
(:meth:`Objective.bind`): an objective that declares a state layout refuses a model of another
layout (``ValueError`` naming both), and μ and the end-pose fields come from the model.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..errors import as_float_array, check_number
from ..physics.layout import StateLayout
from ..physics.pancake import MU, STATE_LAYOUT, violation_torch
from ..physics.transcription import Constraint, end_values, scale_rows
from ..tasks.base import FEASIBLE_TOLERANCE

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
        return all(part.least_squares for part in self.parts)

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
        self._violation: Callable[[torch.Tensor, torch.Tensor], torch.Tensor | None] | None = None

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
        options = model.options
        if self.mu is not None:
            if "mu" not in options.names():
                raise ValueError(f"EndPose(mu=...) needs a task with a friction option mu; {task.name!r} has none")
            options = options.replace(mu=self.mu)
        bound._violation = lambda states, accel: task.violation(states, accel, options)
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
                terms["constraint"] = Term(_np(_max_per_trajectory(violation)), FEASIBLE_TOLERANCE, "(violation)")
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
    """J2 (eq. 4.10): bands on the end pose, the cone penalty and velocity limits.

    ``max(|p_yz[K-1]| − p_lim, 0) + 0.1 max(|θ[K-1] − θ_end| − θ_lim, 0) + α f_dyn
    + β/K Σ_k |max(0, D(|ṗ[k]| − v_lim))|²``

    Defaults are the dissertation's: p_lim = 0.2 m, θ_end = −3π/4, θ_lim = 0.5 rad, α = 1,
    β = 0.01, v_lim = (1.5 m/s, 1.5 m/s, 4.5 rad/s).
    """

    layout = STATE_LAYOUT

    def __init__(
        self,
        p_lim: float = 0.2,
        theta_end: float = -3 * math.pi / 4,
        theta_lim: float = 0.5,
        alpha: float = 1.0,
        beta: float = 0.01,
        v_lim: Sequence[float] = (1.5, 1.5, 4.5),
        mu: float | None = None,
    ) -> None:
        for name, value in (("p_lim", p_lim), ("theta_lim", theta_lim), ("alpha", alpha), ("beta", beta)):
            _check_weight(name, value)
        check_number("theta_end", theta_end)
        if mu is not None:
            _check_weight("mu", mu, positive=True)
        if isinstance(v_lim, str) or not hasattr(v_lim, "__len__") or len(v_lim) != 3:
            raise ValueError(f"Ranges needs three velocity limits (v_y, v_z, v_theta), got {v_lim!r}")
        for value in v_lim:
            _check_weight("v_lim", value)
        self.p_lim, self.theta_end, self.theta_lim = float(p_lim), float(theta_end), float(theta_lim)
        self.alpha, self.beta, self.v_lim = float(alpha), float(beta), tuple(map(float, v_lim))
        self.mu = None if mu is None else float(mu)

    def bind(self, model: Any) -> Ranges:
        """Checks the model generates pancake states; μ defaults to the model's."""
        check_layout(self, model)
        mu = self.mu if self.mu is not None else model.options.mu
        return Ranges(self.p_lim, self.theta_end, self.theta_lim, self.alpha, self.beta, self.v_lim, mu)

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
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
        """How far each band is overstepped, ``(B,)`` each (0 where it holds)."""
        end = states[:, -1]
        v_lim = torch.tensor(self.v_lim, dtype=states.dtype, device=states.device)
        return {
            "end position band": torch.relu(torch.sqrt(end[:, 0] ** 2 + end[:, 1] ** 2) - self.p_lim),
            "end attitude band": torch.relu((end[:, 2] - self.theta_end).abs() - self.theta_lim),
            # from sample 1: the start state is given, not generated (a linear sketch starts moving)
            "velocity limits": torch.relu(states[:, 1:, 3:].abs() - v_lim).amax((1, 2)),
        }

    def report(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, Term]:
        """Each band's excess [m, rad, SI velocity] (met at 0, to 1e-6) and the largest cone violation (≤ 0.01 rad)."""
        with torch.no_grad():
            units = {"end position band": "m", "end attitude band": "rad", "velocity limits": "(m/s, rad/s)"}
            terms = {name: Term(_np(v), 1e-6, units[name]) for name, v in self._excess(states, accel).items()}
            cone = violation_torch(states[:, : accel.shape[1], 2], accel, MU if self.mu is None else self.mu)
            terms["friction cone"] = Term(_np(_max_per_trajectory(cone)), FEASIBLE_TOLERANCE, "rad")
        return terms

    def exact_constraints(self) -> list[tuple[Constraint, np.ndarray]]:
        """The bands and velocity limits (from sample 1: the start state is given) as hard constraints (the
        cone is the task's own)."""
        none = np.zeros((1, 0))
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
        return f"Ranges(p_lim={self.p_lim}, theta_end={self.theta_end:.4f}, theta_lim={self.theta_lim})"


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
