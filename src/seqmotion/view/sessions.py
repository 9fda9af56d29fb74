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
* :class:`TaskSession` — any task (a plug-in too): inputs from the task's own generator, the generated
  motion, every state field's time series and the path of its first two metre fields, by layout name.
* :class:`LatentSession` — the main PCA directions of the latents of a data set; a point in them
  decodes live. :class:`PushingLatentSession` does the same for the pushing model's 8-number ẑ.
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

from ..core.trust import training_inputs
from ..physics.pancake import violation_angle
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


def format_trust(errors: dict[str, float], ood: bool | None, reasons: list | None, std_end: dict[str, float],
                 tolerances: dict[str, float] | None = None) -> list[str]:
    """Markdown lines for the trust signals: each error (⚠ beyond its tolerance), the predicted std at the
    end, and the out-of-distribution flag with its reasons."""
    tolerances = tolerances or {}
    lines = []
    for name, value in errors.items():
        unit = "mm" if name.endswith("_m") else ("mm/s" if name.endswith("_m_s") else "")
        shown = f"{1000 * value:.1f} {unit}" if unit else (f"{value:.4f} rad" if name.endswith("_rad") else
                                                            f"{value:.3g}")
        flag = " ⚠" if name in tolerances and value > tolerances[name] else ""
        label = name.removesuffix("_m_s").removesuffix("_m").removesuffix("_rad").replace("_", " ")
        lines.append(f"- {label}: **{shown}**{flag}")
    if std_end:
        lines.append("- predicted std at the end: " + ", ".join(
            f"{k} {1000 * v:.1f} mm" if k not in ("theta",) else f"{k} {v:.3f} rad" for k, v in std_end.items()))
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
        std_end = {} if self.std is None else dict(zip(("y", "z", "theta"), self.std[-1], strict=False))
        lines = format_trust(self.errors, self.out_of_distribution, self.ood_reasons, std_end, self.tolerances)
        if self.target is not None:
            head += "\n\nerrors against the sketch (the target moves the end away from it):"
        return "\n".join([head, *lines])

    def columns(self) -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:
        """Named per-sample arrays for export (``seqmotion.training.files.write_arrays``)."""
        names = ["y", "z", "theta", "v_y", "v_z", "v_theta"]
        cols: dict[str, np.ndarray] = {"states": self.states, "accel": self.accel, "psi": self.psi,
                                       "sketch": self.sketch}
        heads = {"states": names, "accel": ["u_y", "u_z", "u_theta"], "psi": ["psi"],
                 "sketch": [f"sketch.{n}" for n in names]}
        if self.std is not None:
            cols["uncertainty"], heads["uncertainty"] = self.std, ["std.y", "std.z", "std.theta"]
        if self.latent is not None:
            cols["latent"] = self.latent
        return cols, heads


class PancakeSession:
    """The pancake panel's server logic around a ``Deformer`` (``sm.load_pretrained("pancake")``)."""

    def __init__(self, model: Any) -> None:
        self.model = model
        self.cone = math.atan(float(model.options.mu))
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
            tolerances=self.tolerances,
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
        from ..training.files import write_arrays

        cols, heads = frame.columns()
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

    def readout(self) -> str:
        c = self.controls
        head = (f"**plan** for a {c.shape} command, K = {len(self.command)} ({1000 * self.seconds:.0f} ms), "
                f"μ = {c.mu:g}, μ' = {c.mu_dyn:g}: object RMSE **{1000 * self.errors.get('tracking_rmse_m', 0):.1f} "
                f"mm**, pan within {1000 * np.linalg.norm(self.pan[:, :2], axis=1).max():.0f} mm of home")
        std_end = {} if self.std is None else dict(zip(("x", "y"), self.std[-1], strict=False))
        return "\n".join([head, *format_trust(self.errors, self.out_of_distribution, self.ood_reasons, std_end,
                                             self.tolerances)])

    def columns(self) -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:
        return ({"command": self.command, "rel_states": self.obj, "pan_states": self.pan, "pan_accel": self.pan_accel,
                 "tracking_error": self.tracking},
                {"command": ["command.x", "command.y", "command.vx", "command.vy"],
                 "rel_states": ["x", "y", "vx", "vy"], "pan_states": ["pan.x", "pan.y", "pan.vx", "pan.vy"],
                 "pan_accel": ["pan.ux", "pan.uy"], "tracking_error": ["tracking_error_m"]})


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
                            list(plan.ood_reasons or []), time.perf_counter() - start, self.tolerances)

    def export(self, frame: SlidingFrame, path: str | Path) -> Path:
        from ..training.files import write_arrays

        cols, heads = frame.columns()
        return write_arrays(path, cols, heads)


# --- any task (plug-ins) ---------------------------------------------------------------------------


def path_fields(layout: Any) -> tuple[int, int] | None:
    """The columns of the first two metre fields of a layout (the path the viewer draws), or None."""
    metres = [i for i, u in enumerate(layout.units) if u == "m"]
    return (metres[0], metres[1]) if len(metres) >= 2 else None


@dataclass
class TaskFrame:
    """A generic task's input and generated motion, by its layouts' names."""

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

    def series(self, name: str) -> tuple[np.ndarray, np.ndarray | None]:
        """The generated values of state field ``name`` ``(K,)`` and the input's, if the input has that field."""
        gen = self.states[:, self.state_names.index(name)]
        inp = self.inputs[:, self.input_names.index(name)] if name in self.input_names else None
        return gen, inp

    def readout(self) -> str:
        head = f"**input {self.index}**, K = {len(self.states)} ({1000 * self.seconds:.0f} ms)"
        return "\n".join([head, *format_trust(self.errors, self.out_of_distribution, self.ood_reasons, {})])


class TaskSession:
    """Any trained seq2seq model: draws inputs from its task's training generator and shows the generated
    motion field by field (the state layout's names and units)."""

    def __init__(self, model: Any, n: int = 32, seed: int = 0) -> None:
        self.model = model
        self.inputs, self.lengths = training_inputs(model, n, seed=seed)
        self.cache = FrameCache()

    @property
    def fields(self) -> tuple[str, ...]:
        return tuple(self.model.state_layout.names)

    def update(self, index: int) -> TaskFrame:
        index = int(np.clip(index, 0, len(self.inputs) - 1))
        return self.cache.get(index, lambda: self._compute(index))

    def _compute(self, index: int) -> TaskFrame:
        start = time.perf_counter()
        x = self.inputs[index, : self.lengths[index]]
        r = self.model.generate(x)
        states = getattr(r, "states", None)
        if states is None:  # a task's own result type: rebuild the states from its arrays
            states = np.concatenate([np.asarray(getattr(r, f)) for f in ("pan_states", "rel_states")], axis=-1)
        ins, outs = self.model.input_layout, self.model.state_layout
        ip, sp = path_fields(ins), path_fields(outs)
        return TaskFrame(index, np.arange(len(x)) * 1e-3, x, states, tuple(ins.names), tuple(outs.names),
                         tuple(outs.units), None if ip is None else x[:, list(ip)],
                         None if sp is None else states[:, list(sp)], getattr(r, "uncertainty", None),
                         _float_errors(getattr(r, "errors", None)),
                         None if getattr(r, "out_of_distribution", None) is None else bool(r.out_of_distribution),
                         list(getattr(r, "ood_reasons", None) or []), time.perf_counter() - start)


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

    def readout(self, pca: Pca) -> str:
        shares = ", ".join(f"PC{i + 1} {100 * e:.0f} %" for i, e in enumerate(pca.explained))
        return (f"decoded z at ({', '.join(f'{v:+.1f}σ' for v in self.coords)}) in "
                f"{1000 * self.seconds:.0f} ms; nearest encoded input: #{self.nearest}. Variance explained: {shares}.")


class LatentSession:
    """The latent space of a seq2seq model: encodings of ``n`` inputs from its task's generator, their PCA,
    and live decoding of a point in the main directions (from the inputs' typical start, at their median
    length)."""

    def __init__(self, model: Any, n: int = 96, seed: int = 0, directions: int = 5) -> None:
        self.model = model
        inputs, lengths = training_inputs(model, n, seed=seed)
        with torch.inference_mode():
            z = np.stack([model.encode_torch(torch.from_numpy(inputs[i : i + 1, : lengths[i]])).numpy()[0]
                          for i in range(n)])
            x0 = model.start_state(torch.from_numpy(inputs[:, :2])).double().numpy()
        self.inputs, self.lengths, self.z = inputs, lengths, z
        self.x0 = np.median(x0, axis=0)
        self.length = int(np.median(lengths))
        self.pca = Pca.fit(z, directions)
        self.cache = FrameCache()

    def update(self, coords: tuple[float, ...]) -> LatentFrame:
        coords = tuple(round(float(v), 3) for v in coords)
        return self.cache.get(coords, lambda: self._compute(coords))

    def _compute(self, coords: tuple[float, ...]) -> LatentFrame:
        start = time.perf_counter()
        z = self.pca.latent(np.array(coords))
        out = self.model.decode(z.astype(np.float32), self.x0, self.length)
        states = getattr(out, "states", None)
        if states is None:
            states = np.concatenate([out.pan_states, out.rel_states], axis=-1)
        layout = self.model.state_layout
        pf = path_fields(layout)
        if self.model.task_def.name == "sliding":  # the object relative to the pan is the path that matters
            pf = (layout.index("x"), layout.index("y"))
        scores = (z - self.pca.mean) @ self.pca.components.T
        nearest = int(np.argmin(np.linalg.norm(self.pca.scores - scores, axis=1)))
        return LatentFrame(coords, z, np.arange(self.length) * 1e-3, states, tuple(layout.names),
                           None if pf is None else states[:, list(pf)], nearest, time.perf_counter() - start)


POSITIONS = 6


class PushingLatentSession:
    """The pushing model (ch. 5): the webcam's 64×64 image of each of the six block positions, the CNN's ẑ of
    each (the six clusters, with a few random scene variations each), and sliders over ẑ's main directions
    that show which position's images a point is nearest (rendering the images needs MuJoCo's offscreen
    renderer: EGL or OSMesa)."""

    def __init__(self, policy: Any, variations: int = 3, seed: int = 0) -> None:
        from ..sim import pushing

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
