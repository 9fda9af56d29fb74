"""Sliding commands the viewer offers: a line, an arc, a circle, a figure-eight, or a spline through points.

Every command is an object path relative to the pan, ``(K, 4)`` ``[x, y, vx, vy]`` [m, m/s] at 1 ms,
starting at the origin at rest and ending at rest (an S-curve in time along the path:
:func:`seqmotion.tasks.sliding.data.along_s_curve`). Points are entered in millimetres as text
(``"30,0; 40,20; 20,40"``); the path starts at (0, 0) and passes through each in turn.
"""

from __future__ import annotations

import math
import re

import numpy as np

from ..tasks.sliding import data as sliding_data

SHAPES = ("line", "arc", "circle", "figure-eight", "spline")
"""The command shapes, in the order the page lists them."""
MAX_POINTS = 50
"""The most points a spline command takes."""


def parse_points(text: str) -> np.ndarray:
    """Points ``(N, 2)`` [m] from ``"x,y; x,y; …"`` in millimetres (``;``, new lines or ``|`` between points,
    ``,`` or spaces between coordinates). ``ValueError`` naming the bad piece."""
    pieces = [p.strip() for p in re.split(r"[;|\n]+", text or "") if p.strip()]
    if not pieces:
        raise ValueError("enter at least one point as 'x,y' in millimetres, e.g. '30,0; 40,20'")
    if len(pieces) > MAX_POINTS:
        raise ValueError(f"at most {MAX_POINTS} points, got {len(pieces)}")
    points = []
    for piece in pieces:
        parts = [p for p in re.split(r"[,\s]+", piece) if p]
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise ValueError(f"point {piece!r} is not two numbers 'x,y' (mm)") from None
        if len(values) != 2 or not all(math.isfinite(v) for v in values):
            raise ValueError(f"point {piece!r} is not two finite numbers 'x,y' (mm)")
        points.append(values)
    return np.asarray(points, dtype=np.float64) / 1000.0


def format_points(points: np.ndarray) -> str:
    """The text :func:`parse_points` reads back (millimetres)."""
    return "; ".join(f"{1000 * x:.0f},{1000 * y:.0f}" for x, y in np.asarray(points))


def _spline_path(points: np.ndarray):  # noqa: ANN202 - a path(s) -> (pos, dpos/ds) callable
    """A C² path through (0, 0) and ``points`` with s ∈ [0, 1] spaced by chord length."""
    from scipy.interpolate import CubicSpline

    knots = np.concatenate([np.zeros((1, 2)), points])
    keep = np.concatenate([[True], np.linalg.norm(np.diff(knots, axis=0), axis=1) > 1e-6])
    knots = knots[keep]
    if len(knots) < 2:
        raise ValueError("the points must move away from the start (0, 0)")
    chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(knots, axis=0), axis=1))])
    s_knots = chord / chord[-1]
    if len(knots) == 2:  # a straight segment
        delta = knots[1] - knots[0]
        return lambda s: (knots[0] + s[:, None] * delta, np.broadcast_to(delta, (len(s), 2)).copy())
    spline = CubicSpline(s_knots, knots, axis=0, bc_type="natural")
    return lambda s: (spline(s), spline(s, 1))


def command(shape: str, size: float, length: int, angle_deg: float = 0.0, points: str | np.ndarray = "") -> np.ndarray:
    """A command ``(length, 4)`` of ``shape``.

    Args:
        shape: one of :data:`SHAPES`.
        size: line length, arc/circle radius or figure-eight half width [m] (unused by ``spline``).
        length: K, samples at 1 ms (≥ 2).
        angle_deg: line: its direction; arc: the angle it sweeps (counter-clockwise; negative: clockwise);
            circle / figure-eight: the direction the path starts in [deg].
        points: spline: the points it passes through, as text (mm) or ``(N, 2)`` [m].
    """
    if shape not in SHAPES:
        raise ValueError(f"shape must be one of {SHAPES}, got {shape!r}")
    length = int(length)
    if length < 2:
        raise ValueError(f"need length >= 2, got {length}")
    if shape != "spline" and not (size > 0 and math.isfinite(size)):
        raise ValueError(f"need size > 0 [m], got {size}")
    a = math.radians(angle_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    if shape == "line":
        return _rotate(sliding_data.line(size, length), rot)
    if shape == "circle":  # the data module's circle starts heading +y
        return _rotate(sliding_data.circle(size, length), rot)
    if shape == "figure-eight":
        return _rotate(sliding_data.figure_eight(size, length), rot)
    if shape == "arc":
        sweep = a if abs(a) > 1e-6 else math.pi / 2
        sign = 1.0 if sweep > 0 else -1.0

        def arc(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # starts at 0 heading +x, centre at (0, ±r)
            phi = sweep * s
            pos = size * np.stack([sign * np.sin(phi), sign * (1 - np.cos(phi))], 1)
            dpos = size * sweep * np.stack([sign * np.cos(phi), sign * np.sin(phi)], 1)
            return pos, dpos

        return sliding_data.along_s_curve(arc, length)
    pts = parse_points(points) if isinstance(points, str) else np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return sliding_data.along_s_curve(_spline_path(pts), length)


def _rotate(cmd: np.ndarray, rot: np.ndarray) -> np.ndarray:
    out = cmd.copy()
    out[:, :2] = cmd[:, :2] @ rot.T
    out[:, 2:] = cmd[:, 2:] @ rot.T
    return out
