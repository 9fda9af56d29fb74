"""Objectives for latent-space adjustment (ch. 4, eqs. 4.3–4.4 and 4.10), for any task.

An objective maps a batch of decoded motions to one value per trajectory::

    J(states (B, K, S), accel (B, K-1, d)) -> (B,)

:class:`EndPose` (J1) reaches for the end pose a task declares (``Task.end_pose``: the fields and
their weights) and penalises the task's own constraint (``Task.violation``) at the model's options;
:class:`AtRest` brings the layout's rate fields to 0; :class:`Ranges` puts bands on end values and
limits on any fields of a task's state layout, by name (without names it is the pancake's eq. 4.10,
:class:`seqmotion.tasks.pancake.latent.PancakeRanges`). Any differentiable callable with the signature
above is an objective too (returning ``(B,)`` or a scalar); :class:`Function` with ``residuals=``
gives least-squares form, which Levenberg–Marquardt (``optimizer="lm"``) needs. Objectives compose
with ``+`` and ``*``::

    objective = 2 * EndPose((0.1, 0.0, math.pi)) + my_callable

:class:`~seqmotion.sim.arm_limits.ArmLimits` (``sm.sim.ArmLimits("ur5e")``, in the robot layer) holds a robot's
rated joint speeds, accelerations and torques on pancake motions — ch. 4's velocity limits for a real arm.

**An objective is bound to a model before it is evaluated** (:meth:`Objective.bind`;
:func:`seqmotion.optimize_latent` does it): the fields' columns, the end pose, the constraint and its
physics come from the model's task, and an objective that declares a state layout refuses a model of
another (``ValueError`` naming both). An objective that needs the task and is called unbound refuses
by name; none falls back to another task's columns or physics.

**Every objective keeps the task's constraint** (:func:`for_model`): one that does not penalise it
itself (``EndPose`` and ``Ranges`` do; a plain callable, ``AtRest`` do not) gets :class:`TaskConstraint`
added — ``J + Σ_k F[k]``, reported as the term ``"constraint"``. Add ``TaskConstraint(alpha=...)``
yourself to weigh it (``alpha=0``: only report it).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import torch

from ..errors import as_float_array, check_finite_array
from ..physics.layout import StateLayout
from ..physics.transcription import Constraint, end_bands, end_values, state_limits
from .terms import (
    Function,
    Objective,
    ObjectiveFn,
    Scaled,
    Sum,
    TaskConstraint,
    Term,
    ViolationFn,
    _check_fields,
    _constraint_term,
    _task_violation,
    as_numpy,
    as_objective,
    check_layout,
    check_weight,
    unbound,
)


def for_model(objective: object, model: Any) -> Objective:
    """``objective`` (an :class:`Objective` or a callable) bound to ``model`` (:meth:`Objective.bind`), keeping
    the task's constraint: one that does not penalise it itself gets ``+ TaskConstraint()`` (a task without a
    constraint gets nothing added)."""
    bound = as_objective(objective).bind(model)
    if bound.keeps_constraint:
        return bound
    constraint = TaskConstraint().bind(model)
    return bound if constraint.empty(model) else bound + constraint


class EndPose(Objective):
    """J1 (eqs. 4.3–4.4): ``|D (p[K-1] − p_end)|² + α Σ_k F[k]`` for any task with an end pose.

    ``p`` are the task's end-pose fields and ``D`` their weights (``Task.end_pose``; pancake:
    ``(y, z, θ)`` with D = diag(1, 1, 0.1)), ``F`` the task's constraint violation (pancake: the
    friction cone F_c) at the model's options — both taken from the model it is bound to.

    Args:
        target: one value per end-pose field (pancake ``(y, z, θ)`` [m, m, rad]), or ``(B, n)``
            one target per trajectory.
        alpha: weight α of the constraint penalty (≥ 0).
        mu: judge the constraint at this μ instead of the model's own (a task with a friction option ``mu``;
            default: the model's).
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
        check_finite_array("target", target_arr)
        check_weight("alpha", alpha)
        if mu is not None:
            check_weight("mu", mu, positive=True)
        _check_fields(fields)
        if weights is not None:
            if fields is None or isinstance(weights, str) or len(weights) != len(fields):
                raise ValueError("weights need fields, one weight per field")
            for w in weights:
                check_weight("weights", w)
        check_weight("tolerance", tolerance)
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
            raise unbound(self)
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

    @property
    def end_fields(self) -> frozenset[str]:
        return frozenset(self.fields or ())  # bound: the task's end pose unless fields= were given

    def _column_list(self) -> list[int]:
        if self._columns is None:
            raise unbound(self)
        cols = self._columns
        return list(range(cols.start, cols.stop)) if isinstance(cols, slice) else list(cols)  # type: ignore[union-attr]

    def exact_constraints(self) -> list[tuple[Constraint, np.ndarray]]:
        """The end-pose fields equal the target at the last sample (the cone is the task's own constraint)."""
        return [(end_values(self._column_list(), "end pose"), np.atleast_2d(self.target))]

    def report(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, Term]:
        """``end error``: ``|D (p[K-1] − p_end)|`` (≤ ``tolerance``); ``constraint``: the largest violation
        (≤ 0.01, the feasibility tolerance)."""
        with torch.no_grad():
            terms = {"end error": Term(as_numpy(self.end_error(states).norm(dim=-1)), self.tolerance, "(D-weighted)")}
            violation = self._violation(states, accel) if self._violation is not None else None
            if violation is not None:
                terms["constraint"] = _constraint_term(violation)
        return terms

    def residuals(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        return self.end_error(states)

    def penalty(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        if self._columns is None:
            raise unbound(self)
        violation = self._violation(states, accel) if self._violation is not None else None
        if violation is None or self.alpha == 0:
            return torch.zeros(states.shape[0], dtype=states.dtype, device=states.device)
        return self.alpha * violation.sum(1)

    def __repr__(self) -> str:
        return f"EndPose(target={self.target.tolist()}, alpha={self.alpha:g})"


_FIELDLESS_RANGES: Callable[..., Objective] | None = None


def register_fieldless_ranges(factory: Callable[..., Objective]) -> None:
    """Say what :class:`Ranges` without field names builds: the dissertation's eq. 4.10 with its bands is the
    pancake's, so the pancake task registers its :class:`~seqmotion.tasks.pancake.latent.PancakeRanges` when it is
    imported (``import seqmotion`` imports it); the optimiser sits below the tasks and names none of them."""
    global _FIELDLESS_RANGES
    _FIELDLESS_RANGES = factory


class Ranges(Objective):
    """J2 (eq. 4.10) for any task: bands on end values, the task's constraint penalty and limits along the
    motion, by the names of the task's state fields::

        Ranges(end={"x": (0.025, 0.03)}, limits={"v_x": 0.4, "v_y": 0.4})   # the tray's [x, y, v_x, v_y]

    ``J = Σ_f w_f max(|x_f[K-1] − c_f| − h_f, 0) + α Σ_k F[k] + β/K Σ_{k≥1} Σ_g max(0, w_g (|x_g[k]| − l_g))²``

    with each end band ``[low, high] = [c − h, c + h]``, the limits ``l`` from sample 1 (the start
    state is given), ``w = 0.1`` for a field in rad or rad/s (D's weighting) and 1 otherwise, and ``F``
    the task's constraint at the model's options. Terms: ``"end <field> band"`` and ``"limits"`` (the
    excess, met at 0) and ``"constraint"``.

    **Without field names** (``Ranges()``, ``Ranges(p_lim, theta_end, theta_lim, alpha, beta, v_lim, mu)``)
    it is the pancake's eq. 4.10 with the dissertation's bands: a
    :class:`~seqmotion.tasks.pancake.latent.PancakeRanges`, which refuses a model of another layout by name.

    Args:
        end: field name → ``(low, high)`` band on its last value [the field's unit].
        limits: field name → the largest ``|value|`` along the motion (> 0) [the field's unit].
        alpha: weight α ≥ 0 of the constraint's penalty; beta: weight β ≥ 0 of the limits.
        mu: judge the constraint at this μ instead of the model's own (tasks with a friction option ``mu``).
    """

    def __new__(cls, *args: Any, **kwargs: Any) -> Objective:  # type: ignore[misc]
        if cls is Ranges and kwargs.get("end") is None and kwargs.get("limits") is None:
            if _FIELDLESS_RANGES is None:  # only when this module is used without the seqmotion package's tasks
                raise ValueError("Ranges() without field names is the pancake task's eq. 4.10, which is not "
                                 "registered here; give the bands by field name (end=, limits=)")
            return _FIELDLESS_RANGES(*args, **{k: v for k, v in kwargs.items() if k not in ("end", "limits")})
        return super().__new__(cls)

    def __init__(
        self, *pancake_args: Any, end: Mapping[str, Sequence[float]] | None = None,
        limits: Mapping[str, float] | None = None, alpha: float = 1.0, beta: float = 0.01, mu: float | None = None,
        **pancake_kwargs: Any,
    ) -> None:
        given = [name for name, value in pancake_kwargs.items() if value is not None]
        if pancake_args or given:
            raise ValueError(f"{', '.join(given) or 'positional bands'}: the pancake's bands; with end=/limits= give "
                             f"every band by field name, e.g. Ranges(end={{'theta': (-2.9, -1.9)}}) (alpha=, beta=, "
                             "mu= by name)")
        self.alpha, self.beta = check_weight("alpha", alpha), check_weight("beta", beta)
        self.mu = None if mu is None else check_weight("mu", mu, positive=True)
        self.end, self.limits = _check_bands(end), _check_limits(limits)
        for name, (low, high) in (self.end or {}).items():
            limit = (self.limits or {}).get(name)
            if limit is not None and (low > limit or high < -limit):  # the limit holds at the last sample too
                raise ValueError(f"Ranges end band of {name!r} ({low:g}, {high:g}) lies outside its limit ±{limit:g}: "
                                 "no motion meets both")
        self.layout: StateLayout | None = None  # any task's: bound to the model's
        self._end_columns: list[int] | None = None
        self._limit_columns: list[int] | None = None
        self._violation: ViolationFn | None = None

    @property
    def keeps_constraint(self) -> bool:
        return True

    def bind(self, model: Any) -> Ranges:
        """The fields' columns in the model's layout (``ValueError`` naming its columns) and the task's constraint
        at the model's options."""
        bound = Ranges(alpha=self.alpha, beta=self.beta, mu=self.mu, end=self.end, limits=self.limits)
        layout = bound.layout = model.state_layout
        # the one mapping from field names to columns: the latent stage, the report and the polish all read it
        bound._end_columns = [layout.index(f) for f in self.end or {}]
        bound._limit_columns = [layout.index(f) for f in self.limits or {}]
        bound._violation = _task_violation(model, self.mu, "Ranges")
        return bound

    def _bound(self) -> tuple[StateLayout, list[tuple[str, int, float, float]], list[tuple[str, int, float]]]:
        """The bound layout, the end bands as ``(field, column, low, high)`` and the limits as ``(field, column,
        limit)``, each in the order given."""
        if self._end_columns is None or self._limit_columns is None or self.layout is None:
            raise unbound(self)
        bands = [(name, col, low, high)
                 for (name, (low, high)), col in zip((self.end or {}).items(), self._end_columns, strict=True)]
        limits = [(name, col, limit)
                  for (name, limit), col in zip((self.limits or {}).items(), self._limit_columns, strict=True)]
        return self.layout, bands, limits

    @property
    def end_fields(self) -> frozenset[str]:
        return frozenset(self.end or {})

    def _named(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, torch.Tensor]:
        """Each end band's excess ``(B, n)``, the limits' excess ``(B, K-1, m)``, their D weights and the
        constraint ``(B, K-1)`` (absent without one)."""
        layout, bands, limits = self._bound()
        like = {"dtype": states.dtype, "device": states.device}
        end_cols, limit_cols = [b[1] for b in bands], [lim[1] for lim in limits]
        low = torch.tensor([b[2] for b in bands], **like)
        high = torch.tensor([b[3] for b in bands], **like)
        out = {
            "end": torch.relu((states[:, -1, end_cols] - (low + high) / 2).abs() - (high - low) / 2),
            "limits": torch.relu(states[:, 1:, limit_cols].abs() - torch.tensor([lim[2] for lim in limits], **like)),
            "w_end": torch.tensor([_d_weight(layout.units[c]) for c in end_cols], **like),
            "w_limits": torch.tensor([_d_weight(layout.units[c]) for c in limit_cols], **like),
        }
        violation = self._violation(states, accel) if self._violation is not None else None
        if violation is not None:
            out["constraint"] = violation
        return out

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        parts = self._named(states, accel)
        value = (parts["w_end"] * parts["end"]).sum(-1)
        value = value + self.beta / states.shape[1] * ((parts["w_limits"] * parts["limits"]) ** 2).sum((1, 2))
        if "constraint" in parts:
            value = value + self.alpha * parts["constraint"].sum(1)
        return value

    def report(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, Term]:
        """Each band's excess [the field's unit] and the limits' largest excess (met at 0, to 1e-6), and the
        largest constraint violation (≤ 0.01)."""
        with torch.no_grad():
            parts = self._named(states, accel)
            layout, bands, _ = self._bound()
            terms = {f"end {name} band": Term(as_numpy(parts["end"][:, i]), 1e-6, layout.units[col])
                     for i, (name, col, _, _) in enumerate(bands)}
            if self.limits:
                terms["limits"] = Term(as_numpy(parts["limits"].flatten(1).amax(-1)), 1e-6, "(field units)")
            if "constraint" in parts:
                terms["constraint"] = _constraint_term(parts["constraint"])
            return terms

    def exact_constraints(self) -> list[tuple[Constraint, np.ndarray]]:
        """The bands and limits (from sample 1: the start state is given) as hard constraints (the task's
        constraint is the polish's own), on the columns the latent stage reads (:meth:`_bound`)."""
        _, bands, limits = self._bound()
        none = np.zeros((1, 0))
        out = []
        if bands:
            out.append((end_bands([b[1] for b in bands], [b[2] for b in bands], [b[3] for b in bands]), none))
        if limits:
            out.append((state_limits([lim[1] for lim in limits], [lim[2] for lim in limits]), none))
        return out

    def __repr__(self) -> str:
        return f"Ranges(end={self.end}, limits={self.limits})"


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
        out[name] = check_weight(f"Ranges limits[{name!r}]", value, positive=True)
    return out


class AtRest(Objective):
    """The motion ends at rest: ``J = Σ_j (w_j v_j[K-1])²`` over the layout's rate fields.

    Rate fields are those of the bound model's state layout whose unit ends in ``/s`` (pancake: v_y,
    v_z, v_θ); ``w`` is 1, and 0.1 for ``rad/s`` (D's weighting). Least-squares, so it composes with
    :class:`EndPose` for Levenberg–Marquardt, and has an exact form (the rate fields equal 0 at the
    last sample).

    Args:
        fields: the state fields that must end at 0 instead of the rate fields.
        tolerance: the largest end rate at which :meth:`report` counts the motion as at rest
            (default 0.01 m/s or rad/s).
    """

    def __init__(self, fields: Sequence[str] | None = None, tolerance: float = 0.01) -> None:
        _check_fields(fields)
        check_weight("tolerance", tolerance)
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
            raise unbound(self)
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

    @property
    def end_fields(self) -> frozenset[str]:
        if self._columns is None or self.layout is None:
            return frozenset(self.fields or ())
        return frozenset(self.layout.names[c] for c in self._columns)

    def exact_constraints(self) -> list[tuple[Constraint, np.ndarray]]:
        columns, _ = self._bound()
        return [(end_values(columns, "at rest"), np.zeros((1, len(columns))))]

    def report(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, Term]:
        columns, _ = self._bound()
        with torch.no_grad():
            return {"end rate": Term(as_numpy(states[:, -1, columns].abs().amax(-1)), self.tolerance, "(m/s, rad/s)")}

    def __repr__(self) -> str:
        return "AtRest()" if self.fields is None else f"AtRest(fields={list(self.fields)})"


__all__ = ["AtRest", "EndPose", "Function", "Objective", "ObjectiveFn", "Ranges", "Scaled", "Sum", "TaskConstraint",
           "Term", "as_objective", "check_layout", "for_model", "register_fieldless_ranges"]
