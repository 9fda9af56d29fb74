"""Errors and input checks shared by the whole library.

Every public entry point validates what it is given and raises ``ValueError`` (or its
subclass :class:`CheckpointError`) naming the problem, so nothing fails silently or
returns NaN.
"""

from __future__ import annotations

import math
import sys
import warnings

import numpy as np

MAX_LENGTH = 1_000_000
"""The longest motion anything reads, generates or decodes: K samples (1000 s at 1 ms). The one cap on K,
checked before anything of size K is allocated (input files' declared shapes, ``generate``, ``decode``,
``--length``, task options)."""
EXIT_INEXACT = 3
"""The command lines' exit code for "made, but not what was asked": an exact motion was asked for (``deform
--keep-end``, ``optimize --exact``) and the polish could not make it, or a motion a robot can execute (``deform
--robot``) and that robot's limits are broken; the result is written all the same, marked (its ``exact`` or
``feasible`` False), and one ``seqmotion <command>: warning:`` line says why."""


def report_made(command: str, output: object, inexact: tuple[str, str] | None = None,
                robot: str | None = None) -> int:
    """A command line's warning lines (stderr) for a result it wrote that is not what was asked, and its exit code:
    ``inexact`` ``(option, why)`` where the option's exact motion could not be made; ``robot`` ``"<robot>: <why>"``
    where the robot cannot execute it. :data:`EXIT_INEXACT` where either, else 0."""
    npz = str(output).lower().endswith(".npz")
    code = 0
    if inexact is not None:
        option, why = inexact
        mark = "marked inexact (exact False)" if npz else "a .csv: no exact flag"
        print(f"seqmotion {command}: warning: {option} could not make the exact motion: {why}; {output} holds what "
              f"was made ({mark}); exit code {EXIT_INEXACT}", file=sys.stderr)
        code = EXIT_INEXACT
    if robot is not None:  # made, but not what was asked: a motion the robot would stop on
        mark = "feasible False" if npz else "a .csv: no feasible flag"
        print(f"seqmotion {command}: warning: not executable on {robot}; {output} holds what was made ({mark}); exit "
              f"code {EXIT_INEXACT}", file=sys.stderr)
        code = EXIT_INEXACT
    return code


def said_by(caught: list[warnings.WarningMessage], prefix: str) -> list[str]:
    """The messages of the warnings in ``caught`` (``warnings.catch_warnings(record=True)``) that start with
    ``prefix``, without it — for a command line's own one-line report instead of Python's warning text; any other
    warning is issued again, as it would have been without the catch."""
    said = []
    for w in caught:
        text = str(w.message)
        if text.startswith(prefix):
            said.append(text.removeprefix(prefix))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)
    return said


class CheckpointError(ValueError):
    """A checkpoint is missing, corrupt, mismatched, or belongs to another task."""


class RunInUseError(CheckpointError):
    """A training run directory is locked by another training writing into it."""


def as_trajectories(
    array: object,
    dim: int,
    name: str = "states",
    min_length: int = 2,
) -> tuple[np.ndarray, bool]:
    """Validate a trajectory array and return it as float64 ``(B, K, dim)``.

    Args:
        array: ``(K, dim)`` or ``(B, K, dim)``, anything ``np.asarray`` accepts.
        dim: the required size of the last axis.
        name: how the argument is called in error messages.
        min_length: the smallest acceptable K (the largest is :data:`MAX_LENGTH`).

    Returns:
        ``(batch, was_single)`` where ``was_single`` tells whether a leading batch axis
        was added (so callers can strip it again).
    """
    arr = as_float_array(array, name)
    if arr.ndim not in (2, 3):
        raise ValueError(f"{name} must have shape (K, {dim}) or (B, K, {dim}), got shape {arr.shape}")
    if arr.shape[-1] != dim:
        raise ValueError(f"{name} must have {dim} columns per sample, got shape {arr.shape}")
    if arr.shape[-2] < min_length:
        raise ValueError(f"{name} needs at least K = {min_length} samples, got K = {arr.shape[-2]}")
    if arr.shape[-2] > MAX_LENGTH:  # refused here, before the model builds anything of size K
        raise ValueError(f"{name} has K = {arr.shape[-2]} samples, more than the {MAX_LENGTH} a motion may have")
    if arr.ndim == 3 and arr.shape[0] == 0:
        raise ValueError(f"{name} has an empty batch (B = 0)")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0].tolist()
        raise ValueError(f"{name} contains NaN or inf (first at index {bad})")
    single = arr.ndim == 2
    return (arr[None] if single else arr), single


def as_float_array(array: object, name: str) -> np.ndarray:
    """``array`` as a float64 ndarray; ``ValueError`` naming ``name`` for anything that is not real numbers
    (strings, objects, complex numbers, ragged lists)."""
    if isinstance(array, (str, bytes)):
        raise ValueError(f"{name} must be a numeric array, got {type(array).__name__}")
    if np.iscomplexobj(array):
        raise ValueError(f"{name} must be real numbers, got a complex array")
    try:
        raw = np.asarray(array)
        if raw.dtype.kind not in "biuf":
            raise TypeError(f"dtype {raw.dtype} is not real numbers")
        return np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError, OverflowError, RuntimeError) as exc:
        raise ValueError(f"{name} must be a numeric array, got {type(array).__name__}: {exc}") from None


def check_number(
    name: str, value: object, *, minimum: float | None = None, maximum: float | None = None,
    strict_minimum: bool = False, integer: bool = False,
) -> float | int:
    """A finite real number (an integer with ``integer``) within the bounds, or ``ValueError`` naming ``name``."""
    kinds = (int, np.integer) if integer else (int, float, np.integer, np.floating)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, kinds):
        raise ValueError(f"{name} must be {'an integer' if integer else 'a number'}, got {value!r}")
    try:
        number = int(value) if integer else float(value)
    except OverflowError:  # an int beyond float range
        raise ValueError(f"{name} must be finite, got {value!r}") from None
    if not integer and not math.isfinite(number):  # (an int of any size is finite: np.isfinite fails beyond 2⁶⁴)
        raise ValueError(f"{name} must be finite, got {value!r}")
    if minimum is not None and (number < minimum or (strict_minimum and number == minimum)):
        raise ValueError(f"{name} must be {'>' if strict_minimum else '≥'} {minimum:g}, got {value!r}")
    if maximum is not None and number > maximum:
        raise ValueError(f"{name} must be ≤ {maximum:g}, got {value!r}")
    return number


def check_json_number(
    name: str, value: object, *, minimum: float | None = None, maximum: float | None = None,
    strict_minimum: bool = False, integer: bool = False,
) -> float | int:
    """:func:`check_number` for a value a JSON config stores: a NumPy scalar other than ``float64`` (which is a
    ``float``) is refused too, as ``json.dumps`` cannot write it."""
    if isinstance(value, np.generic) and not isinstance(value, float):
        raise ValueError(f"{name} must be a plain Python number, got the NumPy {type(value).__name__} {value!r}")
    return check_number(name, value, minimum=minimum, maximum=maximum, strict_minimum=strict_minimum, integer=integer)


def check_finite_array(
    name: str, values: object, *, minimum: float | None = None, strict_minimum: bool = False
) -> np.ndarray:
    """``values`` as a float64 array of finite real numbers (each ≥ ``minimum``, > with ``strict_minimum``), or
    ``ValueError`` naming ``name`` (and the first NaN or inf)."""
    arr = as_float_array(values, name)
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0].tolist()
        raise ValueError(f"{name} must be finite, got NaN or inf (first at index {bad})")
    if minimum is not None and (np.any(arr < minimum) or (strict_minimum and np.any(arr == minimum))):
        raise ValueError(f"{name} must be {'>' if strict_minimum else '≥'} {minimum:g} throughout, got {values!r}")
    return arr


def check_finite_result(value: np.ndarray, what: str) -> np.ndarray:
    """Raise instead of returning NaN/inf produced inside a computation."""
    if not np.all(np.isfinite(value)):
        raise ValueError(f"{what} produced NaN or inf; the input is probably far outside the model's range")
    return value


def check_friction(
    mu: object, mu_dyn: object = None, *, maximum: float | None = None, between: str = "two surfaces",
    note: str = "",
) -> tuple[float, float | None]:
    """Friction coefficients [dimensionless] as floats, or ``ValueError`` naming the rule broken: the static μ a
    finite number > 0 (and at most ``maximum`` when given), the dynamic μ' — when given — a finite number with
    ``0 ≤ μ' ≤ μ``. ``between`` names the surfaces and ``note`` is added to the message of a μ above ``maximum``.

    Returns:
        ``(mu, mu_dyn)``: ``mu_dyn`` None where it was not given.
    """
    static = float(check_number("mu", mu, minimum=0.0, strict_minimum=True))
    if maximum is not None and static > maximum:
        raise ValueError(f"mu = {static:g} is no friction coefficient {between} can have (at most {maximum:g}{note})")
    if mu_dyn is None:
        return static, None
    dynamic = float(check_number("mu_dyn", mu_dyn, minimum=0.0))
    if dynamic > static:
        raise ValueError(f"friction must satisfy mu > 0 and 0 <= mu_dyn <= mu, got mu = {static:g}, "
                         f"mu_dyn = {dynamic:g}")
    return static, dynamic
