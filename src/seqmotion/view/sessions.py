"""What the viewer draws, computed without a browser: one session class per panel.

Each session holds a loaded model (loaded once, reused by every slider move) and turns the page's
controls into a *frame* — plain NumPy arrays and numbers (paths, time series, bands, trust signals)
that :mod:`seqmotion.view.app` hands to viser as they are. Frames are cached by their controls, so
moving a slider back to where it was costs nothing.

* :class:`PancakeSession` — a sketch from end-pose sliders (y, z, θ) and a duration K → the sketch
  and the deformed motion, θ(t), ψ(t) against the friction-cone band ±atan μ, the predicted std,
  the out-of-distribution flag and the errors; ``keep_end`` (the exact polish); latent adjustment
  toward a dragged end pose (:func:`seqmotion.optimize_latent` with :class:`~seqmotion.objectives.EndPose`,
  one update at a time so the page shows each); export as CSV or NPZ.
* :class:`SlidingSession` — a command path (:mod:`.commands`) and friction (μ, μ') → the planned pan
  motion, the object's path and the tracking error over time.
* :class:`TaskSession` — any task (a plug-in with its own physics too): inputs like those it trains on
  (``Task.example_inputs``), the generated motion, every state and output field's time series and the
  path of its first two metre fields, its constraint and trust signals, by the layouts' names; export.
* :class:`LatentSession` — the main PCA directions of the latents of a task's example inputs; a point in
  them decodes live. :class:`PushingLatentSession` does the same for the pushing model's 8-number ẑ.

Every array a frame exports is named by the task's layouts (:func:`seqmotion.core.results.columns_of`).
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..core.results import columns_of
from ..physics.integrator import DT
from ..physics.layout import StateLayout
from ..tasks.pancake.physics import violation_angle
from . import commands

TARGET_TOLERANCE = 1e-3
"""An adjusted motion reaches its target when ``|D (p[K-1] − target)|`` is at most this (EndPose's default)."""
CACHE_SIZE = 64
"""Frames kept per session (a slider moved back and forth redraws from the cache)."""


class FrameCache:
    """A small LRU cache of frames keyed by their controls."""

    def __init__(self, size: int = CACHE_SIZE) -> None:
        self.size, self.items = size, OrderedDict()
        self.hits = self.misses = 0

    def get(self, key: Hashable, make: Callable[[], Any]) -> Any:
        if key in self.items:
            self.items.move_to_end(key)
            self.hits += 1
            return self.items[key]
        self.misses += 1
        value = make()
        self.items[key] = value
        while len(self.items) > self.size:
            self.items.popitem(last=False)
        return value


def _float_errors(errors: dict[str, Any] | None) -> dict[str, float]:
    return {k: float(np.asarray(v)) for k, v in (errors or {}).items()}


ERROR_UNITS = (("_m_s", 1000.0, "mm/s"), ("_m", 1000.0, "mm"), ("_rad_s", 1.0, "rad/s"), ("_rad", 1.0, "rad"))
"""How an error's name ends → the factor and unit it is shown in (``Task.errors`` names carry their SI unit)."""


def std_at_end(std: np.ndarray | None, model: Any) -> dict[str, tuple[float, str]]:
    """The predicted std of the last sample by field: name → (value, unit) (:attr:`TrainedModel.uncertainty_names`)."""
    if std is None:
        return {}
    return {name: (float(v), unit) for name, unit, v in zip(model.uncertainty_names, model.uncertainty_units,
                                                             std[-1], strict=False)}


def format_trust(errors: dict[str, float], ood: bool | None, reasons: list | None,
                 std_end: dict[str, tuple[float, str]], tolerances: dict[str, float] | None = None) -> list[str]:
    """Markdown lines for the trust signals: each error (⚠ beyond its tolerance), the predicted std at the
    end (``std_end``: field → (value, unit); metres shown in mm), and the out-of-distribution flag with its
    reasons."""
    tolerances = tolerances or {}
    lines = []
    for name, value in errors.items():
        suffix, scale, unit = next((u for u in ERROR_UNITS if name.endswith(u[0])), ("", 1.0, ""))
        shown = f"{scale * value:.{1 if scale > 1 else 4}f} {unit}" if unit else f"{value:.3g}"
        flag = " ⚠" if name in tolerances and value > tolerances[name] else ""
        label = name.removesuffix(suffix).replace("_", " ")
        lines.append(f"- {label}: **{shown}**{flag}")
    if std_end:
        lines.append("- predicted std at the end: " + ", ".join(
            f"{k} {1000 * v:.1f} mm" if unit == "m" else f"{k} {v:.3g} {unit}" for k, (v, unit) in std_end.items()))
    if ood is None:
        lines.append("- out of distribution: not judged")
    elif ood:
        lines.append("- **out of distribution** ⚠: " + "; ".join(str(r) for r in (reasons or [])))
    else:
        lines.append("- in distribution ✓")
    return lines


# --- pancake (ch. 2 / 4) ---------------------------------------------------------------------------


@dataclass(frozen=True)
class PancakeControls:
    """The pancake panel's controls: the sketch's end pose, its duration and timing, and ``keep_end``."""

    end_y: float = 0.2
    end_z: float = 0.0
    end_theta: float = 2.5
    length: int = 500
    timing: str = "s_curve"
    keep_end: bool = False

    @property
    def end(self) -> tuple[float, float, float]:
        return (self.end_y, self.end_z, self.end_theta)


@dataclass
class PancakeFrame:
    """What the pancake panel draws (K samples at 1 ms).

    Attributes:
        controls: the controls it was computed for.
        time: ``(K,)`` [s].
        sketch: ``(K, 6)`` the input motion; ``states``: ``(K, 6)`` the deformed (or adjusted) one.
        psi: ``(K-1,)`` the cone angle ψ [rad] of ``states``; ``sketch_psi``: the sketch's own.
        cone: atan μ [rad], the band |ψ| ≤ cone where the pancake holds.
        std: ``(K, 3)`` predicted std of y, z, θ, or None.
        errors, out_of_distribution, ood_reasons, exact: the trust signals.
        source: ``"learned"``, ``"keep_end"`` or ``"latent k/N"`` (an adjustment's update k).
        seconds: the compute time of this frame (0 for a cached one is not recorded: the first time).
        target: the end pose the latent adjustment reached for, or None.
    """

    controls: PancakeControls
    time: np.ndarray
    sketch: np.ndarray
    states: np.ndarray
    accel: np.ndarray
    psi: np.ndarray
    sketch_psi: np.ndarray
    cone: float
    std: np.ndarray | None
    errors: dict[str, float]
    out_of_distribution: bool | None
    ood_reasons: list
    exact: bool | None
    latent: np.ndarray | None
    source: str = "learned"
    seconds: float = 0.0
    target: tuple[float, float, float] | None = None
    tolerances: dict[str, float] = field(default_factory=dict)
    objective: float | None = None
    """With a target: the objective J1 (end error² + the cone's penalty) of this motion."""
    std_end: dict[str, tuple[float, str]] = field(default_factory=dict)
    """The predicted std at the last sample by field (:func:`std_at_end`)."""

    @property
    def feasible(self) -> bool:
        return bool(np.max(np.abs(self.psi), initial=0.0) <= self.cone + 0.01)

    @property
    def target_error(self) -> float:
        """``|D (p[K-1] − target)|`` (y, z [m] and 0.1·θ: eq. 4.4's weighting), or inf without a target."""
        if self.target is None:
            return math.inf
        d = (self.states[-1, :3] - np.asarray(self.target)) * (1.0, 1.0, 0.1)
        return float(np.linalg.norm(d))

    def std_band(self, column: int, sigmas: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` = value ∓ sigmas·std of a state column (0 y, 1 z, 2 θ); zeros without a std."""
        s = np.zeros(len(self.states)) if self.std is None else self.std[:, column]
        return self.states[:, column] - sigmas * s, self.states[:, column] + sigmas * s

    def readout(self) -> str:
        """Markdown: where it ends, whether the cone holds, the trust signals."""
        y, z, th = self.states[-1, :3]
        head = (f"**{self.source}** motion, K = {len(self.states)} ({1000 * self.seconds:.0f} ms): "
                f"ends at y = {y:.3f} m, z = {z:.3f} m, θ = {th:.2f} rad; "
                f"max |ψ| = {np.max(np.abs(self.psi), initial=0):.3f} rad vs the cone {self.cone:.3f} rad "
                + ("✓" if self.feasible else "⚠ outside"))
        if self.exact is not None:
            head += " — exact end " + ("✓" if self.exact else "⚠ not reached")
            if len(self.states) > self.controls.length:
                head += f" (needs {len(self.states)} samples to stop within the arm's limits)"
        if self.target is not None:
            head += f" — target y = {self.target[0]:.3f}, z = {self.target[1]:.3f}, θ = {self.target[2]:.2f}: " + (
                "reached ✓" if self.target_error <= TARGET_TOLERANCE else
                f"⚠ not reached ({1000 * self.target_error:.0f} mm off, D-weighted)")
        lines = format_trust(self.errors, self.out_of_distribution, self.ood_reasons, self.std_end, self.tolerances)
        if self.target is not None:
            head += "\n\nerrors against the sketch (the target moves the end away from it):"
        return "\n".join([head, *lines])

    def columns(self, model: Any) -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:
        """Named per-sample arrays for export (``seqmotion.io.write_arrays``), each column named by
        ``model``'s layouts: states, accel (``a_y, …``), ψ, the sketch (``sketch.<field>``), the predicted std
        (``std.<field>``) and the latent."""
        cols: dict[str, np.ndarray] = {"states": self.states, "accel": self.accel, "psi": self.psi,
                                       "sketch": self.sketch}
        heads = {"states": list(model.state_layout.names), "accel": list(model.accel_layout.names), "psi": ["psi"],
                 "sketch": [f"sketch.{n}" for n in model.input_layout.names]}
        if self.std is not None:
            cols["uncertainty"], heads["uncertainty"] = self.std, [f"std.{n}" for n in model.uncertainty_names]
        if self.latent is not None:
            cols["latent"] = self.latent
        return cols, heads


class PancakeSession:
    """The pancake panel's server logic around a ``Deformer`` (``sm.load_pretrained("pancake")``)."""

    def __init__(self, model: Any) -> None:
        self.model = model
        self.cone = model.physics.cone_half_angle
        self.cache = FrameCache()
        self.tolerances = model.task_def.tolerances(model.options)

    def sketch(self, c: PancakeControls) -> np.ndarray:
        """The rough motion ``(K, 6)`` from rest at 0 to rest at the end pose."""
        return self.model.task_def.sketch(c.end, int(c.length), timing=c.timing)

    def update(self, c: PancakeControls) -> PancakeFrame:
        """The frame for these controls: the learned motion (``keep_end``: polished to end exactly)."""
        return self.cache.get(c, lambda: self._compute(c))

    def _compute(self, c: PancakeControls) -> PancakeFrame:
        start = time.perf_counter()
        sketch = self.sketch(c)
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a failed polish shows as exact = False
            r = self.model.deform(sketch, keep_end=c.keep_end)
        return self._frame(c, sketch, r.states, r.accel, r.psi, r.uncertainty, r.errors, r.out_of_distribution,
                           r.ood_reasons, r.exact, r.latent, "keep_end" if c.keep_end else "learned",
                           time.perf_counter() - start)

    def _frame(self, c: PancakeControls, sketch: np.ndarray, states: np.ndarray, accel: np.ndarray,
               psi: np.ndarray | None, std: np.ndarray | None, errors: Any, ood: Any, reasons: Any, exact: Any,
               latent: Any, source: str, seconds: float, target: Any = None) -> PancakeFrame:
        if psi is None:
            psi = violation_angle(torch.from_numpy(states[:-1, 2]), torch.from_numpy(accel)).numpy()
        if len(sketch) < len(states):  # keep_end extended a sketch too short to stop in time: hold its end
            sketch = np.concatenate([sketch, np.repeat(sketch[-1:], len(states) - len(sketch), axis=0)])
        u_sketch = np.diff(sketch[:, 3:6], axis=0) / self.model.dynamics().dt
        sketch_psi = violation_angle(torch.from_numpy(sketch[:-1, 2]), torch.from_numpy(u_sketch)).numpy()
        return PancakeFrame(
            controls=c, time=np.arange(len(states)) * 1e-3, sketch=sketch, states=states, accel=accel, psi=psi,
            sketch_psi=sketch_psi, cone=self.cone, std=std, errors=_float_errors(errors),
            out_of_distribution=None if ood is None else bool(ood), ood_reasons=list(reasons or []),
            exact=None if exact is None else bool(exact), latent=None if latent is None else np.asarray(latent),
            source=source, seconds=seconds, target=None if target is None else tuple(float(v) for v in target),
            tolerances=self.tolerances, std_end=std_at_end(std, self.model),
        )

    def adjust(self, c: PancakeControls, target: tuple[float, float, float], updates: int = 6,
               on_update: Callable[[PancakeFrame], bool | None] | None = None) -> PancakeFrame:
        """Move the sketch's deformed motion toward the end pose ``target`` through its latent.

        :func:`seqmotion.optimize_latent` with :class:`~seqmotion.objectives.EndPose`, run one
        Levenberg–Marquardt update at a time with the default penalty continuation (the cone's weight
        1e-3 → 1 over four updates), so ``on_update(frame)`` sees each; it may return True to stop early
        (e.g. the user dragged the target again).
        """
        from ..latent import objectives, optimize_latent

        sketch = self.sketch(c)
        objective = objectives.EndPose(tuple(float(v) for v in target))
        z: Any = "encoder"
        frame = best = self.update(replace(c, keep_end=False))
        start = time.perf_counter()
        for k in range(updates):
            weight = 1e-3 * (1e3 ** (k / 4)) if k < 4 else None
            res = optimize_latent(self.model, sketch, objective, steps=1, init=z, optimizer="lm",
                                  continuation=None if weight is None else (weight, 1))
            z = res.latent
            frame = self._frame(c, sketch, res.states, res.accel, None, res.uncertainty, res.errors,
                                res.out_of_distribution, res.ood_reasons, None, res.latent,
                                f"latent {k + 1}/{updates}", time.perf_counter() - start, target)
            frame.objective = float(np.ravel(res.history)[-1])  # J1 with the cone's full weight
            if k == 0:  # the learned motion is a candidate too
                best = replace(best, target=frame.target, objective=float(np.ravel(res.history)[0]),
                               source="learned: no update improved it")
            if best.objective is None or frame.objective <= best.objective:
                best = frame
            if on_update is not None and on_update(frame):
                return frame
        if best is not frame and best.objective is not None:  # the descent overshot: show the best motion it found
            if best.source.startswith("latent"):
                best = replace(best, source=f"{best.source} (best of {updates})")
            best = replace(best, seconds=time.perf_counter() - start)
            if on_update is not None:
                on_update(best)
            return best
        return frame

    def export(self, frame: PancakeFrame, path: str | Path) -> Path:
        """Write the frame's motion as ``.csv`` or ``.npz`` (atomically)."""
        from ..io import write_arrays

        cols, heads = frame.columns(self.model)
        return write_arrays(path, cols, heads)


# --- sliding (ch. 3) -------------------------------------------------------------------------------


@dataclass(frozen=True)
class SlidingControls:
    """The sliding panel's controls: the command's shape, size [m], direction/sweep [deg], K, the spline's
    points (text, mm) and the friction of the 2-D physics."""

    shape: str = "line"
    size: float = 0.05
    angle: float = 0.0
    length: int = 500
    points: str = "30,0; 40,20; 20,40"
    mu: float = 0.5
    mu_dyn: float = 0.4


@dataclass
class SlidingFrame:
    """What the sliding panel draws.

    Attributes:
        command: ``(K, 4)`` the object path asked for (relative to the pan).
        obj: ``(K, 4)`` the object's path under the chosen friction (relative to the pan), as planned.
        pan: ``(K, 4)`` the planned pan motion ``[x, y, vx, vy]``; ``pan_accel``: ``(K-1, 2)``.
        tracking: ``(K,)`` |object − command| [m].
        std: ``(K, 2)`` predicted std of the object's x, y, or None.
        plan: the :class:`~seqmotion.tasks.sliding.SlidingPlan` itself (what an export writes).
    """

    controls: SlidingControls
    time: np.ndarray
    command: np.ndarray
    obj: np.ndarray
    pan: np.ndarray
    pan_accel: np.ndarray
    tracking: np.ndarray
    std: np.ndarray | None
    errors: dict[str, float]
    out_of_distribution: bool | None
    ood_reasons: list
    seconds: float = 0.0
    tolerances: dict[str, float] = field(default_factory=dict)
    plan: Any = None
    std_end: dict[str, tuple[float, str]] = field(default_factory=dict)

    def readout(self) -> str:
        c = self.controls
        head = (f"**plan** for a {c.shape} command, K = {len(self.command)} ({1000 * self.seconds:.0f} ms), "
                f"μ = {c.mu:g}, μ' = {c.mu_dyn:g}: object RMSE **{1000 * self.errors.get('tracking_rmse_m', 0):.1f} "
                f"mm**, pan within {1000 * np.linalg.norm(self.pan[:, :2], axis=1).max():.0f} mm of home")
        return "\n".join([head, *format_trust(self.errors, self.out_of_distribution, self.ood_reasons, self.std_end,
                                             self.tolerances)])

    def columns(self, model: Any) -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:
        """The command (``command.<field>``), the plan by its views of ``model``'s layouts (``pan_states``:
        ``pan_x, …``, ``rel_states``: ``x, …``, ``pan_accel``: ``pan_a_x, pan_a_y``; its std and trust signals)
        and the tracking error per sample."""
        cols, heads = columns_of(self.plan, model.state_layout, model.accel_layout, model.uncertainty_names)
        cols = {"command": self.command, **cols, "tracking_error": self.tracking}
        heads = {"command": [f"command.{n}" for n in model.input_layout.names], **heads,
                 "tracking_error": ["tracking_error_m"]}
        return cols, heads


class SlidingSession:
    """The sliding panel's server logic around a ``SlidingPlanner`` (``sm.load_pretrained("sliding")``)."""

    def __init__(self, model: Any) -> None:
        self.model = model
        self.cache = FrameCache()
        self.tolerances = model.task_def.tolerances(model.options)

    def defaults(self) -> SlidingControls:
        return SlidingControls(mu=float(self.model.options.mu), mu_dyn=float(self.model.options.mu_dyn))

    def command(self, c: SlidingControls) -> np.ndarray:
        return commands.command(c.shape, c.size, c.length, c.angle, c.points)

    def update(self, c: SlidingControls) -> SlidingFrame:
        return self.cache.get(c, lambda: self._compute(c))

    def _compute(self, c: SlidingControls) -> SlidingFrame:
        start = time.perf_counter()
        cmd = self.command(c)
        plan = self.model.plan(cmd, mu=c.mu, mu_dyn=c.mu_dyn)
        tracking = np.linalg.norm(plan.rel_states[:, :2] - cmd[:, :2], axis=1)
        return SlidingFrame(c, np.arange(len(cmd)) * 1e-3, cmd, plan.rel_states, plan.pan_states, plan.pan_accel,
                            tracking, plan.uncertainty, _float_errors(plan.errors),
                            None if plan.out_of_distribution is None else bool(plan.out_of_distribution),
                            list(plan.ood_reasons or []), time.perf_counter() - start, self.tolerances, plan,
                            std_at_end(plan.uncertainty, self.model))

    def export(self, frame: SlidingFrame, path: str | Path) -> Path:
        """Write the frame's command, plan and tracking error as ``.csv`` or ``.npz`` (atomically)."""
        from ..io import write_arrays

        cols, heads = frame.columns(self.model)
        return write_arrays(path, cols, heads)


# --- any task (plug-ins) ---------------------------------------------------------------------------


def path_fields(layout: StateLayout) -> tuple[int, int] | None:
    """The columns of the first two metre fields of a layout (the path the viewer draws), or None."""
    metres = [i for i, u in enumerate(layout.units) if u == "m"]
    return (metres[0], metres[1]) if len(metres) >= 2 else None


def path_names(model: Any) -> tuple[str, str] | None:
    """The two fields whose path in their plane the viewer draws for ``model``: the first two metre fields of
    what the encoder reads that the generated states hold too (the object on the pan for the sliding planner, the
    spatula's y, z for the pancake), else the states' own first two metre fields; None for a task with none (e.g.
    joint angles only)."""
    ins, outs = model.input_layout, model.state_layout
    shared = [n for n, u in zip(ins.names, ins.units, strict=True) if u == "m" and n in outs.names]
    if len(shared) >= 2:
        return shared[0], shared[1]
    own = path_fields(outs)
    return None if own is None else (outs.names[own[0]], outs.names[own[1]])


def example_motions(model: Any, n: int, seed: int = 0) -> list[np.ndarray]:
    """``n`` inputs like those ``model``'s task trains on, each ``(K_i, input_dim)`` of its own length: one
    ``Task.example_inputs(1, seed + i)`` each (a draw of several is cut to its shortest)."""
    out = []
    for i in range(n):
        x = np.asarray(model.task_def.example_inputs(1, seed + i), dtype=np.float64)
        if x.ndim != 3 or x.shape[0] != 1 or x.shape[1] < 2 or x.shape[2] != model.input_layout.dim:
            raise ValueError(f"task {model.task_def.name!r}: example_inputs(1, {seed + i}) gave {x.shape}, not "
                             f"(1, K, {model.input_layout.dim})")
        out.append(x[0])
    return out


def _dt(model: Any) -> float:
    """The model's sample time [s] (its dynamics'; 1 ms where the dynamics do not say)."""
    return float(getattr(model.dynamics(), "dt", DT))


@dataclass
class TaskFrame:
    """A task's input and the motion generated from it, named by the task's layouts.

    Attributes:
        index: which example input.
        time: ``(K,)`` [s].
        inputs: ``(K, input_dim)`` the input motion; ``states`` ``(K, S)``, ``accel`` ``(K-1, d)`` the generated
            motion and the decoder's outputs (accelerations, torques, …); ``violation`` ``(K-1,)`` or None.
        input_names, state_names, state_units, accel_names, accel_units: the layouts' names and units.
        input_path, state_path: ``(K, 2)`` the path of :func:`path_names` (``path_names``), or None.
        std, errors, out_of_distribution, ood_reasons: the trust signals; ``std_end`` by field.
        result: the task's result (what an export writes, :func:`~seqmotion.core.results.columns_of`).
    """

    index: int
    time: np.ndarray
    inputs: np.ndarray
    states: np.ndarray
    input_names: tuple[str, ...]
    state_names: tuple[str, ...]
    state_units: tuple[str, ...]
    input_path: np.ndarray | None
    state_path: np.ndarray | None
    std: np.ndarray | None
    errors: dict[str, float]
    out_of_distribution: bool | None
    ood_reasons: list
    seconds: float = 0.0
    accel: np.ndarray | None = None
    accel_names: tuple[str, ...] = ()
    accel_units: tuple[str, ...] = ()
    violation: np.ndarray | None = None
    violation_limit: float | None = None
    path_names: tuple[str, str] | None = None
    std_end: dict[str, tuple[float, str]] = field(default_factory=dict)
    tolerances: dict[str, float] = field(default_factory=dict)
    result: Any = None

    @property
    def fields(self) -> tuple[str, ...]:
        """Every field the panel can plot: the state fields, then the decoder's outputs (an output named like a
        state field is listed as ``accel.<name>``)."""
        return self.state_names + tuple(f"accel.{n}" if n in self.state_names else n for n in self.accel_names)

    def unit(self, name: str) -> str:
        """The unit of field ``name`` (:attr:`fields`)."""
        if name in self.state_names:
            return self.state_units[self.state_names.index(name)]
        return self.accel_units[self.accel_names.index(name.removeprefix("accel."))]

    def series(self, name: str) -> tuple[np.ndarray, np.ndarray | None]:
        """The generated values of field ``name`` (``(K,)`` a state field, ``(K-1,)`` an output) and the input's,
        if the input has that field; ``ValueError`` naming the fields for another name."""
        if name in self.state_names:
            gen = self.states[:, self.state_names.index(name)]
            inp = self.inputs[:, self.input_names.index(name)] if name in self.input_names else None
            return gen, inp
        if self.accel is not None and name in self.fields:
            return self.accel[:, self.accel_names.index(name.removeprefix("accel."))], None
        raise ValueError(f"no field {name!r}; the fields: {list(self.fields)}")

    def readout(self) -> str:
        head = f"**input {self.index}**, K = {len(self.states)} ({1000 * self.seconds:.0f} ms)"
        if self.violation is not None:
            worst = float(np.max(self.violation, initial=0.0))
            ok = self.violation_limit is None or worst <= self.violation_limit
            head += f"; max constraint violation {worst:.4g} " + ("✓" if ok else "⚠")
        lines = format_trust(self.errors, self.out_of_distribution, self.ood_reasons, self.std_end, self.tolerances)
        return "\n".join([head, *lines])


class TaskSession:
    """Any trained seq2seq model: the generated motion for each of its task's example inputs
    (``Task.example_inputs``), field by field by the task's layouts, with its constraint and trust signals."""

    def __init__(self, model: Any, n: int = 32, seed: int = 0) -> None:
        self.model = model
        self.inputs = example_motions(model, n, seed)
        self.tolerances = model.task_def.tolerances(model.options)
        self.limit = next((v for k, v in self.tolerances.items() if k.startswith("max_violation")), None)
        self.path = path_names(model)
        self.dt = _dt(model)
        self.cache = FrameCache()

    @property
    def fields(self) -> tuple[str, ...]:
        """The state fields, then the decoder's outputs (:attr:`TaskFrame.fields`)."""
        states, accel = self.model.state_layout.names, self.model.accel_layout.names
        return tuple(states) + tuple(f"accel.{n}" if n in states else n for n in accel)

    def update(self, index: int) -> TaskFrame:
        index = int(np.clip(index, 0, len(self.inputs) - 1))
        return self.cache.get(index, lambda: self._compute(index))

    def _compute(self, index: int) -> TaskFrame:
        start = time.perf_counter()
        x = self.inputs[index]
        r = self.model.generate(x)
        motion = r.motion()
        ins, outs, acc = self.model.input_layout, self.model.state_layout, self.model.accel_layout
        ip = sp = None
        if self.path is not None:
            sp = motion.states[:, [outs.index(n) for n in self.path]]
            if all(n in ins.names for n in self.path):
                ip = x[:, [ins.index(n) for n in self.path]]
        return TaskFrame(
            index, np.arange(len(motion.states)) * self.dt, x, motion.states, tuple(ins.names), tuple(outs.names),
            tuple(outs.units), ip, sp, r.uncertainty, _float_errors(r.errors),
            None if r.out_of_distribution is None else bool(r.out_of_distribution), list(r.ood_reasons or []),
            time.perf_counter() - start, motion.accel, tuple(acc.names), tuple(acc.units), motion.violation,
            self.limit, self.path, std_at_end(r.uncertainty, self.model), self.tolerances, r)

    def export(self, frame: TaskFrame, path: str | Path) -> Path:
        """Write the frame's input (``input.<field>``) and result (:func:`~seqmotion.core.results.columns_of`: the
        layouts' names) as ``.csv`` or ``.npz`` (atomically)."""
        from ..io import write_arrays

        m = self.model
        cols, heads = columns_of(frame.result, m.state_layout, m.accel_layout, m.uncertainty_names)
        cols = {"input": frame.inputs, **cols}
        heads = {"input": [f"input.{n}" for n in m.input_layout.names], **heads}
        return write_arrays(path, cols, heads)


# --- latent space ----------------------------------------------------------------------------------


@dataclass
class Pca:
    """Principal directions of a set of latents: ``mean`` ``(D,)``, ``components`` ``(n, D)`` (rows, unit),
    ``std`` ``(n,)`` the spread along each, ``explained`` ``(n,)`` the share of variance each explains,
    ``scores`` ``(N, n)`` the latents' coordinates."""

    mean: np.ndarray
    components: np.ndarray
    std: np.ndarray
    explained: np.ndarray
    scores: np.ndarray

    @classmethod
    def fit(cls, z: np.ndarray, n: int = 5) -> Pca:
        z = np.asarray(z, dtype=np.float64)
        mean = z.mean(axis=0)
        _, s, vt = np.linalg.svd(z - mean, full_matrices=False)
        n = min(n, len(s))
        var = s**2 / max(len(z) - 1, 1)
        return cls(mean, vt[:n], np.sqrt(var[:n]), var[:n] / max(var.sum(), 1e-300), (z - mean) @ vt[:n].T)

    def latent(self, coords: np.ndarray) -> np.ndarray:
        """The latent at ``coords`` ``(n,)`` in units of each direction's std."""
        coords = np.asarray(coords, dtype=np.float64)
        return self.mean + (coords * self.std[: len(coords)]) @ self.components[: len(coords)]


@dataclass
class LatentFrame:
    coords: tuple[float, ...]
    latent: np.ndarray
    time: np.ndarray
    states: np.ndarray
    state_names: tuple[str, ...]
    path: np.ndarray | None
    nearest: int
    seconds: float = 0.0
    path_names: tuple[str, str] | None = None

    def readout(self, pca: Pca) -> str:
        shares = ", ".join(f"PC{i + 1} {100 * e:.0f} %" for i, e in enumerate(pca.explained))
        return (f"decoded z at ({', '.join(f'{v:+.1f}σ' for v in self.coords)}) in "
                f"{1000 * self.seconds:.0f} ms; nearest encoded input: #{self.nearest}. Variance explained: {shares}.")


class LatentSession:
    """The latent space of a seq2seq model: encodings of ``n`` of its task's example inputs
    (:func:`example_motions`), their PCA, and live decoding of a point in the main directions (from the inputs'
    typical start, at their median length)."""

    def __init__(self, model: Any, n: int = 96, seed: int = 0, directions: int = 5) -> None:
        self.model = model
        inputs = example_motions(model, n, seed)
        with torch.inference_mode():
            z = np.stack([model.encode_torch(torch.from_numpy(x[None])).cpu().numpy()[0] for x in inputs])
            x0 = model.start_state(torch.from_numpy(np.stack([x[:2] for x in inputs]))).double().numpy()
        self.inputs, self.z = inputs, z
        self.lengths = np.array([len(x) for x in inputs])
        self.x0 = np.median(x0, axis=0)
        self.length = int(np.median(self.lengths))
        self.dt = _dt(model)
        self.path = path_names(model)
        self.pca = Pca.fit(z, directions)
        self.cache = FrameCache()

    def input_path(self, index: int) -> np.ndarray | None:
        """``(K, 2)`` the path of example input ``index`` in the fields of :func:`path_names`, if it has them."""
        names = self.model.input_layout.names
        if self.path is None or not all(n in names for n in self.path):
            return None
        return self.inputs[index][:, [names.index(n) for n in self.path]]

    def update(self, coords: tuple[float, ...]) -> LatentFrame:
        coords = tuple(round(float(v), 3) for v in coords)
        return self.cache.get(coords, lambda: self._compute(coords))

    def _compute(self, coords: tuple[float, ...]) -> LatentFrame:
        start = time.perf_counter()
        z = self.pca.latent(np.array(coords))
        states = self.model.decode(z.astype(np.float32), self.x0, self.length).motion().states
        layout = self.model.state_layout
        path = None if self.path is None else states[:, [layout.index(n) for n in self.path]]
        scores = (z - self.pca.mean) @ self.pca.components.T
        nearest = int(np.argmin(np.linalg.norm(self.pca.scores - scores, axis=1)))
        return LatentFrame(coords, z, np.arange(self.length) * self.dt, states, tuple(layout.names), path, nearest,
                           time.perf_counter() - start, self.path)


POSITIONS = 6


class PushingLatentSession:
    """The pushing model (ch. 5): the webcam's 64×64 image of each of the six block positions, the CNN's ẑ of
    each (the six clusters, with a few random scene variations each), and sliders over ẑ's main directions
    that show which position's images a point is nearest (rendering the images needs MuJoCo's offscreen
    renderer: EGL or OSMesa)."""

    def __init__(self, policy: Any, variations: int = 3, seed: int = 0) -> None:
        from ..lfd.env import pushing

        self.policy = policy
        scene = pushing.PushingScene()
        rng = np.random.default_rng(seed)
        positions = pushing.POSITIONS
        self.images, self.labels = [], []
        for index, position in enumerate(positions):
            for v in range(variations):
                variation = pushing.SceneVariation() if v == 0 else pushing.SceneVariation.sample(rng)
                scene.reset(position, variation)
                self.images.append(scene.render(policy.config.camera))
                self.labels.append(index)
        self.images, self.labels = np.stack(self.images), np.asarray(self.labels)
        self.z = policy.latent(self.images)
        self.pca = Pca.fit(self.z, 3)
        self.centres = np.stack([self.pca.scores[self.labels == i].mean(0) for i in range(len(positions))])

    def nearest_position(self, coords: tuple[float, ...]) -> int:
        point = np.asarray(coords, dtype=np.float64) * self.pca.std[: len(coords)]
        return int(np.argmin(np.linalg.norm(self.centres[:, : len(coords)] - point, axis=1)))

    def image_for(self, position: int) -> np.ndarray:
        return self.images[int(np.flatnonzero(self.labels == position)[0])]
