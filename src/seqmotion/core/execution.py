"""Whether a robot can execute a generated motion: the verdict's types and the hook that computes it.

A motion can keep the task's constraint (the pancake's friction cone) and still be one a real arm would stop on: its
joints would have to turn faster than they are rated for. The robot layer (:mod:`seqmotion.sim`) computes that
verdict, but tasks sit below it and may not import it, so the simulator registers its check here by a string entry
point (``"module:function"``, imported on first use, as Gymnasium's environments are):
:func:`register_execution_check` (``import seqmotion`` does it for the built-in tasks), and a task calls
:func:`check_execution`. The result types live here so that a result file holding a verdict loads without MuJoCo.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

LIMIT_UNITS = {"speed": "rad/s", "acceleration": "rad/s²", "torque": "N m", "range": "rad", "reach": "m"}
"""The unit of each kind of limit an :class:`ExecutionCheck` judges."""

_TIMING_KINDS = ("speed", "acceleration")
"""The limits a slower timing of the same joint paths keeps (speeds scale by 1/s, accelerations by 1/s²)."""


@dataclass(frozen=True)
class BindingLimit:
    """The limit a motion comes closest to (or goes furthest past) on a robot.

    Attributes:
        kind: ``"speed"`` (rated joint speed), ``"acceleration"`` (rated joint acceleration), ``"torque"`` (the
            model's torque limit, against the inverse dynamics), ``"range"`` (a joint's range) or ``"reach"`` (the
            tool pose out of the robot's reach: IK residual past its tolerance).
        joint: the joint (``None`` for ``"reach"``).
        needed: the peak the motion needs: |q̇| [rad/s], |q̈| [rad/s²], |τ| [N m], the joint's position [rad] or the
            IK position residual [m].
        rated: the limit: the rated speed [rad/s] or acceleration [rad/s²], the range end nearest the peak [rad], or
            the IK position tolerance [m].
        share: how much of the limit the motion uses (> 1: past it). Speed and acceleration: needed / rated; range:
            the excursion from the range's middle over half the range; reach: the IK residual over its tolerance.
        time: when the peak is reached [s] from the motion's first sample.
    """

    kind: str
    joint: str | None
    needed: float
    rated: float
    share: float
    time: float

    def describe(self) -> str:
        """One clause: the joint, what it needs against the limit, the share and when."""
        unit = LIMIT_UNITS.get(self.kind, "")
        if self.kind == "reach":
            return (f"the tool pose is out of reach at t = {self.time:.3f} s (IK residual {self.needed * 1e3:.1f} mm, "
                    f"{self.share:.2f}× the {self.rated * 1e3:.0f} mm tolerance)")
        if self.kind == "range":
            return (f"joint {self.joint!r} reaches {self.needed:.3f} rad at t = {self.time:.3f} s against its range "
                    f"end {self.rated:.3f} rad ({self.share:.2f}× its half-range from the middle)")
        return (f"joint {self.joint!r} needs {self.needed:.2f} {unit} at t = {self.time:.3f} s, {self.share:.2f}× its "
                f"rated {self.rated:.2f} {unit}")


@dataclass(frozen=True)
class ExecutionCheck:
    """Whether a robot can execute a motion, judged on the joint path its IK gives (kinematics only, no dynamics).

    Arrays are per joint, base → flange (``n`` joints); a share ``None`` where the limit is unknown (never treated
    as unlimited: :attr:`unknown` says why).

    Attributes:
        ok: ``True`` every needed limit (rated speeds, joint ranges, reach; rated accelerations where published) is
            known and kept; ``False`` one is broken (:attr:`binding` names it); ``None`` none broken, but rated
            speeds or joint ranges are unknown.
        robot: the robot, ``"name (source)"``.
        joints: ``(n,)`` joint names.
        duration: the motion's duration, (K - 1) dt [s].
        speed_peak: ``(n,)`` peak |q̇| [rad/s].
        speed_share: ``(n,)`` peak |q̇| / rated speed, or ``None``.
        accel_peak: ``(n,)`` peak |q̈| [rad/s²].
        accel_share: ``(n,)`` peak |q̈| / rated acceleration, or ``None`` (none published).
        range_margin: ``(n,)`` the smallest distance from a range end over the motion [rad] (negative: past it;
            ``inf`` for a continuous joint), or ``None``.
        ik_error: ``(2,)`` the largest IK residual, position [m] and attitude [rad].
        torque_peak: ``(n,)`` peak |τ| the path needs by inverse dynamics [N m], or ``None`` (not computed: the
            built-in arm, which tracks in task space).
        torque_share: ``(n,)`` peak |τ| / torque limit, or ``None``.
        binding: the limit with the largest share (the one broken worst where ``ok`` is False), or ``None``.
        time_scale: the smallest factor s ≥ 1 by which running the same joint paths s× slower keeps every speed
            and acceleration limit (max of the speed shares and the square roots of the acceleration shares);
            ``None`` where no timing can fix it (a range or reach limit broken) or the speeds are unknown.
        needed_duration: ``time_scale × duration`` [s], or ``None``.
        unknown: limit kind → why it is unknown (not checked).
        lost: where the robot layer also executes the motion in simulation (the pancake's check: PD + DOB in MuJoCo,
            the task's object on the tool), what the execution lost and what would cure it, in words (e.g. the
            pancake leaving the spatula at t = 0.62 s, or the tool down at the table); ``ok`` is then False whatever
            the limits. ``None``: kept, or not executed.
    """

    ok: bool | None
    robot: str
    joints: tuple[str, ...]
    duration: float
    speed_peak: np.ndarray
    speed_share: np.ndarray | None
    accel_peak: np.ndarray
    accel_share: np.ndarray | None
    range_margin: np.ndarray | None
    ik_error: np.ndarray
    binding: BindingLimit | None
    time_scale: float | None
    needed_duration: float | None
    unknown: dict[str, str] = field(default_factory=dict)
    torque_peak: np.ndarray | None = None
    torque_share: np.ndarray | None = None
    lost: str | None = None

    def fix(self) -> str:
        """What would make the motion executable, in words (``""`` where it already is or nothing is known)."""
        if self.ok is not False:
            return ""
        if self.binding is None or self.binding.share <= 1.0:  # none broken: `lost` says what failed and why
            return ""
        if self.time_scale is not None and self.needed_duration is not None:
            return (f"needs ≥ {self.needed_duration:.2f} s instead of {self.duration:.2f} s at these joint paths "
                    f"({self.time_scale:.2f}× slower; a slower motion also changes the pancake's physics, so the "
                    "task's constraint must be checked again)")
        return f"no slower timing fixes a {self.binding.kind} limit: the path itself must change"

    def problem(self) -> str | None:
        """``"not executable on <robot>: <binding limit or what was lost>; <what it needs>"``, or ``None`` where
        ``ok`` is not False."""
        if self.ok is not False:
            return None
        if self.binding is not None and self.binding.share > 1.0:
            return f"not executable on {self.robot}: {self.binding.describe()}; {self.fix()}"
        if self.lost is not None:
            return f"not executable on {self.robot}: {self.lost}"
        return None

    def describe(self) -> str:
        """One line for people: executable or not on the robot, the binding limit, what would fix it, unknowns."""
        problem = self.problem()
        if problem is not None:
            line = problem
        elif self.ok is True:
            line = f"executable on {self.robot}"
            if self.binding is not None:
                line += f" (closest: {self.binding.describe()})"
        else:
            line = f"executability on {self.robot} unknown"
        if self.unknown:
            line += "; " + "; ".join(self.unknown.values()) + " (not checked)"
        return line


def time_scale(speed_share: np.ndarray | None, accel_share: np.ndarray | None) -> float | None:
    """The slow-down s ≥ 1 that keeps every rated speed and acceleration on the same joint paths: speeds fall by
    1/s and accelerations by 1/s², so s = max(1, max speed share, √max acceleration share); ``None`` without
    speed shares."""
    if speed_share is None:
        return None
    scale = max(1.0, float(np.max(speed_share, initial=0.0)))
    if accel_share is not None:
        scale = max(scale, math.sqrt(float(np.max(accel_share, initial=0.0))))
    return scale


def fixable_by_timing(binding: BindingLimit | None) -> bool:
    """Whether running slower can cure ``binding`` (speeds and accelerations can; ranges and reach cannot)."""
    return binding is not None and binding.kind in _TIMING_KINDS


CheckFunction = Callable[..., ExecutionCheck]
"""``check(states, robot, dt=…) -> ExecutionCheck`` for one motion of a task."""

ArmFormFunction = Callable[..., Any]
"""``arm_form(robot, dt) -> ArmForm | None``: a robot's limits as constraints of a task's exact polish
(:class:`~seqmotion.core.polish.ArmForm`), ``None`` where it cannot give them (the motion is then only judged)."""

_CHECKS: dict[str, str | CheckFunction] = {}
"""Task name → its execution check, or the ``"module:function"`` string entry point that provides it."""

_ARM_FORMS: dict[str, str | ArmFormFunction] = {}
"""Task name → the function (or its ``"module:function"`` entry point) that turns a robot into polish constraints."""


def _entry_point(what: str, value: object) -> None:
    if isinstance(value, str) and value.count(":") != 1:
        raise ValueError(f"{what}'s entry point must be 'module:function', got {value!r}")
    if not isinstance(value, str) and not callable(value):
        raise ValueError(f"{what} must be a function or 'module:function', got {value!r}")


def register_execution_check(task: str, check: str | CheckFunction,
                             arm_form: str | ArmFormFunction | None = None) -> None:
    """Register how a robot's execution of ``task``'s motions is checked: a function or a ``"module:function"``
    string (imported on first use, so registering costs nothing), and optionally how a robot's limits become
    constraints of the task's exact polish (``arm_form``, the same way). The latest registration wins."""
    if not isinstance(task, str) or not task:
        raise ValueError(f"task must be a non-empty name, got {task!r}")
    _entry_point("an execution check", check)
    if arm_form is not None:
        _entry_point("an arm form", arm_form)
        _ARM_FORMS[task] = arm_form
    _CHECKS[task] = check


def execution_checks() -> list[str]:
    """The tasks with an execution check registered."""
    return sorted(_CHECKS)


def execution_check_for(task: str) -> CheckFunction:
    """The execution check registered for ``task``; ``ValueError`` where none is."""
    if task not in _CHECKS:
        raise ValueError(f"no robot execution check is registered for task {task!r} (known: {sorted(_CHECKS)})")
    return _resolve(_CHECKS, task)


def _resolve(table: dict[str, Any], task: str) -> Any:
    value = table[task]
    if isinstance(value, str):
        module, _, name = value.partition(":")
        value = getattr(importlib.import_module(module), name)
        table[task] = value
    return value


def arm_form_for(task: str, robot: Any, dt: float) -> Any:
    """``robot``'s limits as constraints of ``task``'s exact polish (an :class:`~seqmotion.core.polish.ArmForm`), or
    ``None`` where the robot layer cannot give them for this robot or registered nothing for the task."""
    if task not in _ARM_FORMS:
        return None
    return _resolve(_ARM_FORMS, task)(robot, dt)


def check_execution(task: str, states: Any, robot: Any, dt: float) -> ExecutionCheck:
    """Judge ``task``'s motion ``states`` ``(K, S)`` at ``dt`` [s] on ``robot`` (a name or a robot object) with
    the registered check (:func:`register_execution_check`)."""
    return execution_check_for(task)(states, robot, dt=dt)


__all__ = ["BindingLimit", "ExecutionCheck", "arm_form_for", "check_execution", "execution_check_for",
           "execution_checks", "fixable_by_timing", "register_execution_check", "time_scale"]
