"""What a task is, and the task-generic model every task's training produces.

A **task** (:class:`Task`) is physics + input generators + loss + curriculum, wired to the shared
chunked seq2seq model. It declares:

* its **layouts** — the named columns and units of the motions the encoder reads
  (``input_layout``), of the states the decoder generates in closed loop (``state_layout``)
  and of the decoder's outputs (``accel_layout``);
* its **options** — a validated dataclass (:mod:`.options`) saved with the model;
* its **physics** — :meth:`Task.dynamics` (the differentiable ``ChunkDynamics`` the decoder runs
  with), :meth:`Task.start_state`, and optionally :meth:`Task.violation` (its constraint, 0 where
  satisfied) and ``end_pose`` (the fields and weights an end-pose objective reaches for);
* its **training** — presets (:meth:`Task.train_config`), data (:meth:`Task.sample`) and loss
  (:meth:`Task.loss`, built from :mod:`seqmotion.training.losses`).

A task lives in ``seqmotion/tasks/`` (one module defining ``TASK``) or in the user's own
package, registered through the entry-point group ``seqmotion.tasks`` (:mod:`.registry`).

A **trained model** (:class:`TrainedModel`) is task-generic: ``generate`` (encode a motion and
decode it through the task's physics), ``decode`` (from a latent), ``generator`` (the decoder as
an online stepper fed measured states of the task's own size) and the differentiable maps that
latent optimisation uses. Tasks may subclass it for friendly verbs (``Deformer.deform``,
``SlidingPlanner.plan``).
"""

from __future__ import annotations

import copy
import importlib
import json
import math
import sys
import warnings
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import numpy as np
import torch

from ..data.trajectories import TrajectoryBatch
from ..errors import MAX_LENGTH, CheckpointError, as_float_array, as_trajectories, check_finite_result, check_number
from ..models.seq2seq import ChunkDynamics, ChunkedSeq2Seq, Seq2SeqConfig, rollout
from ..physics.integrator import DoubleIntegratorDynamics, reach_end
from ..physics.layout import StateLayout
from ..physics.transcription import Constraint, Solution, end_values, input_limits, transcription
from ..training import checkpoint as ckpt
from ..training.config import TrainConfig
from ..training.curriculum import Curriculum
from ..training.device import model_device, resolve_device
from ..training.files import read_npz, write_arrays
from ..training.pretrained import PretrainedModel
from . import registry, trust
from .options import TaskOptions
from .stepper import OnlineGenerator, stepper_contract
from .trust import position_std

FEASIBLE_TOLERANCE = 0.01
"""A motion counts as feasible when its largest constraint violation is at most this."""


class Task(ABC):
    """A learning problem for the chunked seq2seq model (see the module docstring)."""

    name: ClassVar[str]
    presets: ClassVar[tuple[str, ...]] = ("tiny", "small", "paper")
    options_class: ClassVar[type[TaskOptions]] = TaskOptions
    input_layout: ClassVar[StateLayout]
    state_layout: ClassVar[StateLayout]
    accel_layout: ClassVar[StateLayout]
    physics_parameters: ClassVar[tuple[str, ...]] = ()
    """Keyword arguments :meth:`dynamics` accepts at inference (e.g. ``("mu", "mu_dyn")``); their
    defaults are the model's options."""
    end_pose: ClassVar[tuple[tuple[str, ...], tuple[float, ...]] | None] = None
    """``(state fields, weights)`` an end-pose objective reaches for, e.g. pancake
    ``(("y", "z", "theta"), (1, 1, 0.1))``; None: the task has no end pose."""
    model_class: ClassVar[type[TrainedModel] | None] = None
    """The user-facing class of the trained model (default :class:`TrainedModel`)."""
    uncertainty_fields: ClassVar[tuple[str, ...] | None] = None
    """The state fields whose covariance the dynamics' ``pos_cov`` output holds (a result's
    ``uncertainty`` columns); None: the first p fields of ``state_layout``."""

    # --- training ------------------------------------------------------------------------------

    @abstractmethod
    def train_config(self, preset: str) -> TrainConfig:
        """The named configuration (at least ``"tiny"`` for tests and ``"small"``)."""

    def curriculum(self, config: TrainConfig) -> Curriculum:
        """The run's schedule."""
        return Curriculum.from_dict(config.curriculum)

    @abstractmethod
    def sample(
        self, n: int, rng: np.random.Generator, params: dict[str, float], config: TrainConfig
    ) -> TrajectoryBatch:
        """Draw ``n`` training trajectories for the curriculum parameters ``params``."""

    @abstractmethod
    def loss(
        self,
        model: ChunkedSeq2Seq,
        batch: TrajectoryBatch,
        params: dict[str, float],
        config: TrainConfig,
        generator: torch.Generator,
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """Scalar loss to minimise and named terms to log (include ``"feasible"`` if meaningful)."""

    def build_model(self, config: TrainConfig) -> ChunkedSeq2Seq:
        model_config = Seq2SeqConfig.from_dict(config.model)
        self.check_model_config(model_config)
        return ChunkedSeq2Seq(model_config)

    def check_model_config(self, model_config: Seq2SeqConfig) -> None:
        """``ValueError`` unless the model reads the task's input layout and writes its accel layout."""
        reads, writes = model_config.encoder_input_dim, model_config.output_dim
        if reads != self.input_layout.dim or writes != self.accel_layout.dim:
            raise ValueError(
                f"task {self.name}: the model reads {model_config.encoder_input_dim} and writes "
                f"{model_config.output_dim} features, but the task's {self.input_layout} and {self.accel_layout} "
                "need " + f"{self.input_layout.dim} and {self.accel_layout.dim}"
            )

    # --- options ---------------------------------------------------------------------------------

    def options(self, config: TrainConfig | dict[str, Any] | None) -> TaskOptions:
        """The typed, checked options of a training config (or of an options dict)."""
        data = config.options if isinstance(config, TrainConfig) else config
        return self.options_class.from_dict(data)

    # --- physics ---------------------------------------------------------------------------------

    @abstractmethod
    def dynamics(self, options: TaskOptions, **physics: Any) -> ChunkDynamics:
        """The differentiable physics the decoder's loop runs through at inference."""

    def physics_trained(self, options: TaskOptions) -> dict[str, tuple[float, float]]:
        """The (lowest, highest) value of each of :attr:`physics_parameters` the training met: a generation at
        physics beyond them (by the trust margin) is out of distribution. Default: none known."""
        return {}

    def start_state(self, inputs: torch.Tensor) -> torch.Tensor:
        """Decoder start state ``(B, state_dim)`` for input motions ``(B, K, input_dim)``
        (default: their first sample)."""
        return inputs[:, 0]

    def violation(self, states: torch.Tensor, accel: torch.Tensor, options: TaskOptions) -> torch.Tensor | None:
        """The task's constraint violation per transition ``(B, K-1)`` (≥ 0, 0 where satisfied), differentiable.

        ``states`` ``(B, K, state_dim)``, ``accel`` ``(B, K-1, d)``. None: the task has no constraint.
        """
        return None

    def exact_form(self, options: TaskOptions) -> ExactForm | None:
        """What an exact polish needs (:class:`ExactForm`), or None: ``exact=True`` and ``keep_end=True``
        are then refused for this task."""
        return None

    def sketch(self, end: tuple[float, ...], length: int, timing: str = "s_curve") -> np.ndarray:
        """A rough input motion ``(K, input_dim)`` from the start to the end-pose values ``end`` (the
        CLI's default input for ``seqmotion optimize``); tasks without one refuse."""
        raise ValueError(f"task {self.name!r} has no default sketch; give the motion to adjust (--input)")

    def make_result(self, motion: Motion, model: TrainedModel) -> Any:
        """The result object ``generate`` returns (default: the :class:`Motion` itself)."""
        return motion

    # --- trust signals (:mod:`.trust`) ------------------------------------------------------------

    def input_features(self, inputs: np.ndarray, lengths: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Cheap features of ``(B, K, input_dim)`` inputs, each ``(B,)``, that the out-of-distribution flag
        compares with training (default: length, extent, peak speed and implied acceleration per unit
        group of ``input_layout``: :func:`seqmotion.tasks.trust.input_features`)."""
        from .trust import input_features

        return input_features(self.input_layout, inputs, lengths)

    def errors(
        self, inputs: np.ndarray, states: np.ndarray, accel: np.ndarray, violation: np.ndarray | None,
        options: TaskOptions,
    ) -> dict[str, np.ndarray]:
        """The errors a user judges a generated motion by, each ``(B,)`` (SI units in the name).

        ``inputs`` ``(B, K, input_dim)``, ``states`` ``(B, K, S)``, ``accel`` ``(B, K-1, d)``, ``violation``
        ``(B, K-1)`` or None. Default, for a task whose input layout is its state layout:
        ``shape_rmse_m`` (RMS over samples of the metre fields' distance from the input),
        ``end_position_error_m``, ``end_attitude_error_rad`` (largest over radian fields),
        ``end_speed_m_s`` (the generated motion's, metres per second fields) and ``max_violation``.
        """
        out: dict[str, np.ndarray] = {}
        units = self.state_layout.units
        if self.input_layout.names == self.state_layout.names:
            metres = [i for i, u in enumerate(units) if u == "m"]
            radians = [i for i, u in enumerate(units) if u == "rad"]
            if metres:
                gap = np.linalg.norm(states[..., metres] - inputs[..., metres], axis=-1)
                out["shape_rmse_m"] = np.sqrt((gap**2).mean(axis=-1))
                out["end_position_error_m"] = gap[:, -1]
            if radians:
                out["end_attitude_error_rad"] = np.abs(states[:, -1, radians] - inputs[:, -1, radians]).max(axis=-1)
        speeds = [i for i, u in enumerate(units) if u == "m/s"]
        if speeds:
            out["end_speed_m_s"] = np.linalg.norm(states[:, -1, speeds], axis=-1)
        if violation is not None:
            out["max_violation"] = violation.max(axis=-1) if violation.shape[-1] else np.zeros(len(states))
        return out

    def position_cov(
        self, accel_cov: torch.Tensor, states: torch.Tensor, accel: torch.Tensor, outputs: dict[str, torch.Tensor],
        dynamics: ChunkDynamics,
    ) -> torch.Tensor | None:
        """The covariance ``(B, K-1, p, p)`` of the positions of states ``1..K-1`` from the decoder's input
        covariances ``accel_cov`` ``(B, K-1, d, d)`` propagated through the physics from a known start —
        what the dynamics' ``pos_cov`` output holds, computed once over the whole motion.

        ``states`` ``(B, K, S)``, ``accel`` ``(B, K-1, d)`` and the dynamics' other ``outputs`` (first K-1
        samples) are the motion's. Default: the closed form of the double integrator
        (:func:`seqmotion.tasks.trust.integrate_covariance`) when the task's dynamics is one; None (the
        chunk-by-chunk propagation is used) otherwise.
        """
        if isinstance(dynamics, DoubleIntegratorDynamics):
            return trust.integrate_covariance(accel_cov, dynamics.dt)
        return None

    def tolerances(self, options: TaskOptions) -> dict[str, float]:
        """Error name → the largest value a user accepts; a result beyond one gets a warning (default:
        ``max_violation`` ≤ :data:`FEASIBLE_TOLERANCE`)."""
        return {"max_violation": FEASIBLE_TOLERANCE}

    # --- trained models ------------------------------------------------------------------------

    def wrap(self, model: ChunkedSeq2Seq, config: dict) -> TrainedModel:
        """The user-facing object for a trained model."""
        return (self.model_class or TrainedModel)(model, config, task=self)

    def load(self, directory: Any) -> TrainedModel:
        """The trained model stored in ``directory`` (verified)."""
        return (self.model_class or TrainedModel).from_pretrained(directory)


@dataclass(frozen=True)
class ExactForm:
    """A task's motion as an NLP, for the exact polish (:mod:`seqmotion.physics.transcription`).

    Attributes:
        dim: axes of the double integrator the task's states follow (state = the ``dim``
            positions, then their velocities; inputs = ``dim`` accelerations).
        dt: its sampling interval [s].
        constraints: the task's own constraints in CasADi form (pancake: the friction cone in force form).
        accel_weights: the polish's metric, ``Σ_k |√w ⊙ (u[k] − u_ref[k])|² / K`` (pancake: 1, 1, 0.01 —
            radians count a tenth of metres, as in D).
        smoothness: λ of the polish's jerk term (:func:`seqmotion.physics.transcription.transcription`).
        accel_limits: ``|u[k, j]| ≤ accel_limits[j]`` (the robot's), or None.
        travel_accel: the accelerations per axis a rest-to-rest move can plan on, where the task's
            constraint takes part of the limits — ``keep_end`` gives a too-short input the bang-bang time
            at these (default: :data:`EXTEND_MARGIN` × ``accel_limits``).
    """

    dim: int
    dt: float
    constraints: tuple[Constraint, ...]
    accel_weights: tuple[float, ...]
    smoothness: float = 0.0
    accel_limits: tuple[float, ...] | None = None
    travel_accel: tuple[float, ...] | None = None


POLISH_VIOLATION_TOLERANCE = 1e-6
"""A polished motion is exact when the task's constraint violation is at most this (pancake: F_c [rad])."""
WARM_ITERATIONS = 20
"""IPOPT iterations the warm (small-barrier) start gets before the polish falls back to a cold start:
a nearly feasible motion needs 2–5; a far one (e.g. J2's, 1.25 rad outside its band) is faster from
IPOPT's default barrier."""
COLD_ITERATIONS = 300
"""…and the cold start gets this many: J2's polish needs ~90; a sketch that cannot end at rest within
the constraints (the arm's limits) is proved locally infeasible in ~50–150, or given up on here."""


def _rest_to_rest_accel(
    x0: np.ndarray, columns: list[int], values: np.ndarray, steps: int, form: ExactForm
) -> tuple[float, ...] | None:
    """The accelerations an axis needs at least to go from rest at ``x0`` to rest at its end value in ``steps``
    samples (bang-bang: ``4 |Δp| / T²``), when some axis needs more than ``form.accel_limits``; else None.

    Only for axes that start and end at rest (otherwise no cheap bound is taken)."""
    if form.accel_limits is None:
        return None
    d, span = form.dim, steps * form.dt
    need, over = [], False
    for j, limit in enumerate(form.accel_limits):
        at_rest = d + j in columns and abs(x0[d + j]) < 1e-12 and abs(values[columns.index(d + j)]) < 1e-12
        if j not in columns or not at_rest:
            need.append(0.0)
            continue
        need.append(4 * abs(values[columns.index(j)] - x0[j]) / span**2)
        over |= need[-1] > limit * (1 + 1e-9)
    return tuple(round(float(n), 1) for n in need) if over else None


FALLBACK_END_WEIGHT = 1000.0
"""``keep_end``'s fallback, where no motion reaches the end pose exactly: the weight per metre (per radian,
times the axis's weight) of the end-pose error against the distance to the learned inputs (m/s²)."""

EXTEND_MARGIN = 0.5
"""``keep_end`` plans the time a too-short input needs as the bang-bang time at the task's
:attr:`ExactForm.travel_accel`, by default this share of the arm's acceleration limits (the task's constraint
takes part of them: measured on 40 pancake sketches, the full limits left most such polishes infeasible)…"""
EXTEND_GROWTH = 1.4
"""…and, when the polish is still infeasible, tries again with this many times more samples…"""
EXTEND_ATTEMPTS = 4
"""…up to this many polishes in all (the last 1.4³ ≈ 2.7× the first time)…"""
EXTEND_COLD_ITERATIONS = 100
"""…each but the last with this cap on IPOPT's iterations: a feasible polish converges in ~15–30, a local
proof of infeasibility takes 50–150, and a longer horizon is the cheaper way on. (Searching the time on a
coarser transcription first — inputs held for 3 or 10 samples — was tried: holding the inputs makes the
cone much harder to keep while the spatula turns, so it asked for far more time and took longer.)"""


def _steps_to_stop(x0: np.ndarray, columns: list[int], values: np.ndarray, steps: int, form: ExactForm) -> int:
    """Input samples (``K - 1``) a rest-to-rest motion needs so each axis's bang-bang acceleration,
    ``4 |Δp| / T²``, stays within ``form.travel_accel`` (default :data:`EXTEND_MARGIN` of
    ``form.accel_limits``): at least ``steps``."""
    travel = form.travel_accel
    if travel is None and form.accel_limits is not None:
        travel = tuple(EXTEND_MARGIN * limit for limit in form.accel_limits)
    if travel is None:
        return steps
    need = steps
    for j, accel in enumerate(travel):
        if j in columns:
            span = math.sqrt(4 * abs(values[columns.index(j)] - x0[j]) / accel)
            need = max(need, math.ceil(span / form.dt))
    return need


def first_of(result: Any) -> Any:
    """The same result dataclass with every array field indexed by ``[0]`` (drop a batch axis of 1)."""
    values = {f.name: getattr(result, f.name) for f in fields(result)}
    return type(result)(**{k: _first(v) for k, v in values.items()})


def _first(value: Any) -> Any:
    """``value[0]`` for a batched field (arrays, lists, the arrays of a dict); scalars and None as they are."""
    if value is None:
        return None
    if isinstance(value, dict):
        return {k: _first(v) for k, v in value.items()}
    if isinstance(value, list):
        return value[0]
    if np.ndim(value) == 0:
        return value
    first = value[0]
    return first.item() if isinstance(first, np.bool_) else first


RESULT_FORMAT = 1
"""Version of the layout :meth:`TrustSignals.save` writes (``result.layout``'s ``"format"``)."""
_CLASS_KEY, _LAYOUT_KEY = "result.class", "result.layout"
_RESULT_CLASSES: dict[str, type] = {}
"""Every result class defined (``module.QualName`` → class): all that :func:`load_result` rebuilds."""


def _class_key(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


@dataclass
class TrustSignals:
    """How far to trust a result: the fields every task's result shares (keyword-only, after the task's own).

    Attributes:
        uncertainty: ``(K, p)`` the predicted std of the generated positions per sample (the Gaussian
            head's covariance propagated through the physics; columns: the task's ``uncertainty_fields``,
            row 0 = 0), or None.
        errors: error name → value (``(B,)`` for a batch), :meth:`Task.errors`; None without an input.
        out_of_distribution: whether the input lies outside what the model was trained on (per motion
            for a batch; :mod:`.trust`); None when not judged (decoded from a latent).
        ood_reasons: which features were out, e.g. ``["length 2000 > 500"]`` (a list per motion for a batch).
        exact: with ``keep_end=True``: whether the polish made the motion end exactly at the input's end
            pose, at rest, with the task's constraint held (≤ 1e-6); None otherwise.
        length: with ``keep_end=True``: the motion's length in samples (``(B,)`` for a batch) — the input's K,
            or more where ending at rest within the arm's acceleration limits took longer than the input
            (a batch holds a shorter motion's end state, with zero input, up to its longest); None otherwise.
        task: the name of the task that made the result (it names the state fields in :meth:`plot`, and
            :func:`load_result` finds a plug-in's result class through it), or None.

    Every result saves itself (:meth:`save`, read back with :func:`load_result`) and plots itself (:meth:`plot`).
    """

    uncertainty: np.ndarray | None = field(default=None, kw_only=True)
    errors: dict[str, Any] | None = field(default=None, kw_only=True)
    out_of_distribution: Any = field(default=None, kw_only=True)
    ood_reasons: list | None = field(default=None, kw_only=True)
    exact: Any = field(default=None, kw_only=True)
    length: Any = field(default=None, kw_only=True)
    task: str | None = field(default=None, kw_only=True)

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        _RESULT_CLASSES[_class_key(cls)] = cls  # what :func:`load_result` may rebuild (never a name from a file)

    def trust(self) -> dict[str, Any]:
        """These fields by name, to pass on to another result (``Result(..., **motion.trust())``)."""
        return {f.name: getattr(self, f.name) for f in fields(TrustSignals)}

    def save(self, path: str | Path) -> Path:
        """Write this result to an ``.npz`` atomically, every field under its own name, no pickled objects.

        Arrays keep their name, dtype and shape (``states``, ``accel``, …); a dict's entries are
        ``<field>.<key>`` (``errors.end_position_error_m``), a list of dataclasses ``<field>.<i>.<attr>``
        (an optimisation's ``stages.0.seconds``), lists of strings one JSON string (``ood_reasons``),
        strings a text array (``task``). ``result.class`` names the class and ``result.layout`` (JSON) how
        to rebuild each field: :func:`load_result` returns an equal result. ``np.load(path)`` reads it
        as plain named arrays.

        Raises:
            ValueError: ``path`` is not a writable ``.npz`` path, or a field holds a value that cannot be
                stored without pickling (naming the field).
        """
        path = ckpt.check_writable(path, (".npz",), "result file")
        arrays: dict[str, np.ndarray] = {}
        layout = {f.name: _pack(getattr(self, f.name), f.name, arrays) for f in fields(self) if f.init}
        layout_json = json.dumps({"format": RESULT_FORMAT, "fields": layout})
        for key, value in ((_CLASS_KEY, _class_key(type(self))), (_LAYOUT_KEY, layout_json)):
            arrays[key] = np.array(value)
        return write_arrays(path, arrays)

    def plot(self, path: str | Path | None = None) -> Any:
        """A matplotlib figure (Agg) of the result over time: its state fields by name, one panel per unit
        (``m``, ``rad``, ``m/s``, …; one per field when the task is not known), and its constraint
        ``violation`` if it has one. Every motion of a batch is drawn (thin lines).

        Args:
            path: where to save the figure too (atomically; the format from the suffix, e.g. ``.png``).

        Returns:
            The ``matplotlib.figure.Figure`` (close it with ``matplotlib.pyplot.close(fig)`` when done).
        """
        return _plot(self, path)


def _put(arrays: dict[str, np.ndarray], key: str, array: np.ndarray) -> None:
    if key in arrays or key in (_CLASS_KEY, _LAYOUT_KEY):
        raise ValueError(f"cannot save the result: two of its values would both be stored as {key!r}")
    arrays[key] = array


def _strings(value: Any) -> bool:
    """Whether ``value`` is a (nested) list or tuple of strings only (stored as one JSON string)."""
    return isinstance(value, (list, tuple)) and all(isinstance(v, str) or _strings(v) for v in value)


def _pack(value: Any, key: str, arrays: dict[str, np.ndarray]) -> Any:
    """Store ``value`` under ``key`` (and ``key.<part>`` for its parts) in ``arrays``; return the JSON
    node that says how to rebuild it (:func:`_unpack`)."""
    if value is None:
        return None
    if isinstance(value, str):
        _put(arrays, key, np.array(value))
        return {"str": key}
    if is_dataclass(value) and not isinstance(value, type):  # e.g. an optimisation's stages and terms
        return {"dataclass": type(value).__name__,
                "fields": {f.name: _pack(getattr(value, f.name), f"{key}.{f.name}", arrays)
                           for f in fields(value) if f.init}}
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise ValueError(f"cannot save field {key!r}: a dict whose keys are not all strings")
        return {"dict": {k: _pack(v, f"{key}.{k}", arrays) for k, v in value.items()}}
    if isinstance(value, (list, tuple)):
        if _strings(value):  # ood_reasons, a stage's statuses: one JSON string array
            _put(arrays, key, np.array(json.dumps(value)))
            return {"json": key, "tuple": isinstance(value, tuple)}
        return {"list": [_pack(v, f"{key}.{i}", arrays) for i, v in enumerate(value)],
                "tuple": isinstance(value, tuple)}
    if isinstance(value, (np.ndarray, np.generic, bool, int, float)):
        array = np.asarray(value)
        if array.dtype.kind in "biuf":  # never objects (pickled), nor text or bytes posing as numbers
            _put(arrays, key, array)
            numpy = "numpy" if isinstance(value, np.generic) else "python"  # how it comes back: the same type
            return {"array": key, "as": "ndarray" if isinstance(value, np.ndarray) else numpy}
    raise ValueError(f"cannot save field {key!r}: a {type(value).__name__} is neither an array of numbers, a string, "
                     "a list, a dict nor a dataclass of them")


def _node_keys(node: Any) -> list[str]:
    """The array names a layout node refers to."""
    if node is None:
        return []
    if not isinstance(node, dict):
        raise ValueError(f"a layout entry is a {type(node).__name__}, not an object")
    for kind in ("array", "str", "json"):
        if kind in node:
            if not isinstance(node[kind], str):
                raise ValueError(f"a layout entry's {kind!r} is not an array name")
            return [node[kind]]
    parts = node.get("dict") or node.get("fields") or {}
    children = node.get("list", list(parts.values()) if isinstance(parts, dict) else None)
    if not isinstance(children, list):
        raise ValueError(f"a layout entry holds neither arrays nor parts: {json.dumps(node)[:80]}")
    return [key for child in children for key in _node_keys(child)]


def _text(array: np.ndarray, key: str) -> str:
    if array.ndim != 0 or array.dtype.kind != "U":
        raise ValueError(f"array {key!r} should be one string, got {array.dtype} {array.shape}")
    return str(array[()])


def _unpack(node: Any, arrays: dict[str, np.ndarray], home: Any) -> Any:
    """The value a layout node (:func:`_pack`) describes; nested dataclasses are found by name in the
    result class's module ``home`` (and must be dataclasses: nothing else is built)."""
    if node is None:
        return None
    if "array" in node:
        array = arrays[node["array"]]
        if array.dtype.kind not in "biuf":
            raise ValueError(f"array {node['array']!r} holds {array.dtype}, not numbers")
        kind = node.get("as")
        return array if kind == "ndarray" else array[()] if kind == "numpy" else array.item()
    if "str" in node:
        return _text(arrays[node["str"]], node["str"])
    if "json" in node:
        value = json.loads(_text(arrays[node["json"]], node["json"]))
        if not _strings(value):
            raise ValueError(f"array {node['json']!r} is not a JSON array of strings")
        return tuple(value) if node.get("tuple") else value
    if "list" in node:
        value = [_unpack(child, arrays, home) for child in node["list"]]
        return tuple(value) if node.get("tuple") else value
    if "dict" in node:
        return {str(k): _unpack(child, arrays, home) for k, child in node["dict"].items()}
    cls = getattr(home, str(node.get("dataclass")), None)
    if not (isinstance(cls, type) and is_dataclass(cls)):
        raise ValueError(f"{node.get('dataclass')!r} is not a dataclass of {home.__name__}")
    return cls(**{str(k): _unpack(child, arrays, home) for k, child in node["fields"].items()})


def _result_class(name: str, task: str | None, source: Path) -> type:
    """The result class saved as ``name`` (``module.QualName``): one already defined, or defined once its
    module (seqmotion's own only) or its ``task`` (a plug-in, through the task registry) is imported."""
    if name not in _RESULT_CLASSES and name.startswith("seqmotion."):
        module = name.rpartition(".")[0]
        if all(part.isidentifier() for part in module.split(".")):
            try:
                importlib.import_module(module)
            except ImportError:
                pass
    if name not in _RESULT_CLASSES and task:
        registry.get(task)
    if name not in _RESULT_CLASSES:
        raise ValueError(f"{source} holds a {name}, which is no result class of this installation "
                         f"(known: {', '.join(sorted(_RESULT_CLASSES))})")
    return _RESULT_CLASSES[name]


def load_result(path: str | Path) -> TrustSignals:
    """Read a result written by ``result.save(path)``: the same class (``Motion``, ``DeformResult``,
    ``SlidingPlan``, ``OptimizationResult``, a plug-in's) with equal fields.

    Read without pickle (:func:`seqmotion.training.files.read_npz`: sizes checked before anything is
    decompressed), and nothing but the result classes and their dataclasses is ever built.

    Raises:
        ValueError: a missing file, not an ``.npz``, a file that ``result.save`` did not write (e.g.
            ``np.savez`` of ``vars(result)``, whose object arrays need pickle), an array that holds objects
            (naming it), an unknown result class, or a malformed layout.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path} does not exist" if not path.exists() else f"{path} is not a file")
    head = read_npz(path, (_CLASS_KEY, _LAYOUT_KEY), required=0)
    if len(head) < 2:
        raise ValueError(f"{path} is not a result saved by result.save(path): it has no {_CLASS_KEY!r} and "
                         f"{_LAYOUT_KEY!r} (a file that np.savez wrote from vars(result) holds pickled objects, which "
                         "are never loaded)")
    name = _text(head[_CLASS_KEY], _CLASS_KEY)
    try:
        layout = json.loads(_text(head[_LAYOUT_KEY], _LAYOUT_KEY))
        if not isinstance(layout, dict) or layout.get("format") != RESULT_FORMAT or not isinstance(
                layout.get("fields"), dict):
            raise ValueError(f"not a format-{RESULT_FORMAT} layout")
        nodes = layout["fields"]
        keys = [key for node in nodes.values() for key in _node_keys(node)]
    except (ValueError, RecursionError) as exc:
        raise ValueError(f"{path}: malformed {_LAYOUT_KEY!r}: {exc}") from None
    task, task_name = nodes.get("task"), None
    if isinstance(task, dict) and isinstance(task.get("str"), str):  # a plug-in's class is found through its task
        task_name = _text(read_npz(path, (task["str"],))[task["str"]], "task")
    cls = _result_class(name, task_name, path)
    unknown = sorted(set(nodes) - {f.name for f in fields(cls) if f.init})
    if unknown:
        raise ValueError(f"{path}: a {cls.__name__} has no field(s) {unknown}")
    try:
        arrays = read_npz(path, keys, required=len(keys))
    except ValueError:
        for key in keys:  # read_npz names the file; name the array at fault too
            try:
                read_npz(path, (key,))
            except ValueError as exc:
                raise ValueError(f"{path}: array {key!r}: {str(exc).removeprefix(f'cannot read {path}: ')}") from None
        raise
    try:
        values = {name: _unpack(node, arrays, sys.modules[cls.__module__]) for name, node in nodes.items()}
        return cls(**values)
    except (ValueError, TypeError, KeyError, AttributeError, RecursionError) as exc:
        raise ValueError(f"{path}: cannot rebuild the {cls.__name__}: {exc}") from None


def _plot(result: TrustSignals, path: str | Path | None) -> Any:
    """:meth:`TrustSignals.plot`: the figure, saved atomically to ``path`` when given."""
    from matplotlib.figure import Figure  # no pyplot: no global backend switch, nothing kept alive

    if path is not None:
        path = ckpt.check_writable(path, None, "figure")
    own = [f.name for f in fields(result) if f.name not in {g.name for g in fields(TrustSignals)}]
    arrays = {n: getattr(result, n) for n in own if isinstance(getattr(result, n), np.ndarray)}
    top = max((a.ndim for a in arrays.values()), default=0)
    per_sample = {n: a for n, a in arrays.items() if a.ndim == top and top >= 2}
    k = max((a.shape[-2] for a in per_sample.values()), default=0)
    states = {n: a for n, a in per_sample.items() if a.shape[-2] == k}  # (K, n): states; (K-1, d) inputs are not
    if not states:
        raise ValueError(f"a {type(result).__name__} holds no per-sample states to plot")
    layout = None
    if result.task:  # the fields' names and units; a task not installed here: plotted by field and column
        try:
            layout = getattr(registry.get(result.task), "state_layout", None)
        except ValueError:
            layout = None
    width = sum(a.shape[-1] for a in states.values())
    columns = []  # (name, unit or the field's name, values (B, K)) per state column
    start = 0
    for field_name, array in states.items():
        batch = array.reshape(-1, *array.shape[-2:])
        for j in range(array.shape[-1]):
            if layout is not None and layout.dim == width:
                name, group = layout.names[start + j], layout.units[start + j]
            else:
                name, group = f"{field_name}[{j}]", field_name
            columns.append((name, group, batch[:, :, j]))
        start += array.shape[-1]
    groups = list(dict.fromkeys(group for _, group, _ in columns))
    violation = getattr(result, "violation", None)
    panels = len(groups) + (violation is not None)
    figure = Figure(figsize=(8, 1.9 * panels + 0.6), layout="constrained")
    axes = figure.subplots(panels, 1, sharex=True, squeeze=False)[:, 0]
    thin = 0.6 if len(columns[0][2]) > 1 else 1.2
    for ax, group in zip(axes, groups, strict=False):
        for c, (name, g, values) in enumerate(columns):
            if g == group:
                lines = ax.plot(np.arange(values.shape[1]), values.T, color=f"C{c % 10}", lw=thin)
                lines[0].set_label(name)
        ax.set_ylabel(group if layout is not None else "value")
        ax.legend(loc="best", fontsize="small")
    if violation is not None:
        values = np.asarray(violation, dtype=np.float64).reshape(-1, np.shape(violation)[-1])
        axes[-1].plot(np.arange(values.shape[1]), values.T, color="C3", lw=thin)
        axes[-1].axhline(FEASIBLE_TOLERANCE, color="0.5", ls="--", lw=0.8, label=f"feasible ≤ {FEASIBLE_TOLERANCE}")
        axes[-1].set_ylabel("violation")
        axes[-1].legend(loc="best", fontsize="small")
    axes[-1].set_xlabel("sample k")
    figure.suptitle(f"{type(result).__name__}" + (f" ({result.task})" if result.task else ""))
    if path is not None:
        ckpt.save_figure(figure, path)
    return figure


def feasible_of(violation: np.ndarray | None) -> np.ndarray | bool | None:
    """Whether the largest violation ``(..., K-1)`` is ≤ :data:`FEASIBLE_TOLERANCE` (per trajectory for a
    batch); None without a constraint."""
    if violation is None:
        return None
    ok = violation.max(axis=-1) <= FEASIBLE_TOLERANCE
    return bool(ok) if np.ndim(ok) == 0 else ok


@dataclass
class Motion(TrustSignals):
    """A generated motion (a leading B axis on every array for a batch), with its trust signals.

    Attributes:
        states: ``(K, S)`` states in the task's ``state_layout``; ``states[0]`` is the start state.
        accel: ``(K-1, d)`` the decoder's outputs ``u[0..K-2]`` in the task's ``accel_layout``.
        latent: ``(L·H,)`` the latent z the motion was decoded from.
        violation: ``(K-1,)`` the task's constraint violation per transition (0 where it holds),
            or None for a task without a constraint.
    """

    states: np.ndarray
    accel: np.ndarray
    latent: np.ndarray
    violation: np.ndarray | None = None

    @property
    def feasible(self) -> np.ndarray | bool | None:
        """Whether the largest violation is ≤ 0.01 (per trajectory for a batch); None without a constraint."""
        return feasible_of(self.violation)


class Assessment(NamedTuple):
    """Trust signals of a motion (:meth:`TrainedModel.assess`; a leading B axis / a list per motion for a batch).

    Attributes:
        errors: error name → value (:meth:`Task.errors`).
        out_of_distribution: whether the input lies outside the training distribution (None: not calibrated).
        ood_reasons: which features were out (e.g. ``"length 2000 > 500"``).
        uncertainty: ``(K, p)`` predicted position std, or None (no latent given).
    """

    errors: dict[str, Any]
    out_of_distribution: Any
    ood_reasons: list
    uncertainty: np.ndarray | None


class TrainedModel(PretrainedModel):
    """A trained chunked seq2seq model of any task: generate, decode, step online, optimise.

    Obtain one with ``sm.load(run_dir)`` or ``sm.load_pretrained(name)``. Everything task-specific
    (state size and names, physics, constraint, options) comes from ``self.task_def``.
    """

    config_class = Seq2SeqConfig

    def __init__(self, model: ChunkedSeq2Seq, config: dict, task: Task | None = None) -> None:
        self.model = model.eval()
        self.config = config
        self.task_def: Task = task if task is not None else registry.get(config["task"])
        if type(self).task is not None and self.task_def.name != type(self).task:
            raise CheckpointError(
                f"a {type(self).__name__} needs a {type(self).task!r} model, got {self.task_def.name!r}"
            )
        training = self.config.get("training", {})
        if not isinstance(training, dict):
            raise ValueError(f"the config's training record must be a JSON object, got {type(training).__name__}")
        self.options = self.task_def.options(training.get("options", {}))

    # --- the device ---------------------------------------------------------------------------

    @property
    def device(self) -> torch.device:
        """Where the network runs (the CPU unless moved with :meth:`to` or loaded with ``device=``)."""
        return model_device(self.model)

    def to(self, device: str | torch.device) -> TrainedModel:
        """Run the network (encoder, decoder, physics of the rollout) on ``device`` — ``"auto"``, ``"cpu"``,
        ``"cuda"``, ``"cuda:N"`` — from now on; returns ``self``. Inputs and results stay NumPy arrays on the
        host: inputs are copied to the device, results back. The exact polish, the trust signals' bookkeeping
        and the online generator (:meth:`generator`, batch 1, latency-bound) run on the CPU.

        Raises:
            ValueError: an unknown device, or a CUDA device this machine does not have.
        """
        target = resolve_device(device)
        if getattr(self, "is_quantized", False) and target.type != "cpu":
            raise ValueError("a quantized copy runs on the CPU only (int8 CPU kernels)")
        self.model.to(target)
        return self

    def on_device(self, device: str | torch.device | None) -> TrainedModel:
        """This model if it already runs on ``device`` (None: wherever it is), else a copy moved there (the
        ``device=`` argument of latent optimisation: the caller's model stays where it was)."""
        if device is None:
            return self
        target = resolve_device(device)
        if target == self.device:
            return self
        moved = object.__new__(type(self))
        moved.__dict__.update(self.__dict__)
        moved.model = copy.deepcopy(self.model)
        return moved.to(target)

    # --- the save/load contract --------------------------------------------------------------

    def weights(self) -> dict[str, torch.Tensor]:
        return self.model.state_dict()

    def config_json(self) -> dict[str, Any]:
        return {k: v for k, v in self.config.items() if k not in ckpt.HASH_FIELDS}

    @classmethod
    def from_checkpoint(cls, config: dict[str, Any], tensors: dict[str, torch.Tensor], source: str) -> TrainedModel:
        """Check the config as a schema (types, ranges, the task's layouts) and every size in it against the
        weights' shapes *before* the model is allocated; then build it and load the weights."""
        task_name = config.get("task")
        if not isinstance(task_name, str):
            raise CheckpointError(f"{source}/config.json names no task (task={task_name!r})")
        try:
            task = registry.get(task_name)
        except ValueError as exc:
            raise CheckpointError(f"{source}: {exc}") from None
        if task.model_class is not None and not issubclass(task.model_class, cls):
            raise CheckpointError(f"{source} holds a {task.name!r} model, not a {cls.__name__}")
        try:
            model_config = Seq2SeqConfig.from_dict(config.get("model"))
            task.check_model_config(model_config)
        except ValueError as exc:
            raise CheckpointError(f"{source}/config.json does not describe a valid model: {exc}") from None
        ckpt.check_shapes(model_config.parameter_shapes(), {k: tuple(v.shape) for k, v in tensors.items()}, source)
        model = ChunkedSeq2Seq(model_config)
        ckpt.load_state_dict_strict(model, tensors, source)
        try:
            wrapped = task.wrap(model, config)
        except ValueError as exc:  # options the task refuses
            raise CheckpointError(f"{source}/config.json: {exc}") from None
        wrapped.source_dir = source  # where trust.json (:mod:`.trust`) lives, if anywhere
        return wrapped

    def card_summary(self, name: str) -> list[str]:
        m = self.config["model"]
        head = f" + {m['head_hidden']}-unit linear" if m.get("head_hidden") else ""
        return [
            f"Task `{self.task_def.name}` — chunked seq2seq, {m['layers']} × {m['hidden']} LN-LSTM encoder and decoder"
            f"{head}, C = {m['chunk']}, latent {m['layers'] * m['hidden']} numbers. Reads {self.input_layout}; "
            f"generates {self.state_layout} through {self.accel_layout}.",
            "",
            "```python",
            "import seqmotion as sm",
            f"model = sm.load_pretrained({name!r})   # a {type(self).__name__}",
            "result = model.generate(motion)        # (K, "
            f"{self.input_layout.dim}) {', '.join(self.input_layout.names)} at 1 ms",
            "```",
        ]

    def card_training(self) -> list[str]:
        training = self.config.get("training", {})
        provenance = self.config.get("provenance", {})
        lines = [
            f"- Command: `{provenance.get('command', 'unknown')}`",
            f"- Seed: {training.get('seed')}; preset `{training.get('preset')}`; options "
            f"{json.dumps(self.options.to_dict())}",
            f"- Data: {training.get('curriculum', {}).get('epochs')} epochs × {training.get('batches_per_epoch')} "
            f"mini-batches × {training.get('batch_size')} trajectories, drawn fresh from the task's generators",
            f"- Wall time: {self.config.get('elapsed_seconds', 0) / 60:.1f} min ({self.config.get('step')} optimiser "
            "steps)",
            f"- Machine: {provenance.get('machine', 'unknown')}",
        ]
        if "resumed_with" in provenance:
            lines.append(f"- Resumed once from a checkpoint with `{provenance['resumed_with'].get('command')}`")
        return lines

    def check_finished(self) -> None:
        """Refuse to ship a run that stopped before the end of its curriculum."""
        training = self.config.get("training", {})
        total = training.get("batches_per_epoch", 0) * training.get("curriculum", {}).get("epochs", 0)
        if self.config.get("step") != total:
            raise ValueError(f"the run has not finished training (step {self.config.get('step')} of {total})")

    # --- what the task says --------------------------------------------------------------------

    @property
    def input_layout(self) -> StateLayout:
        return self.task_def.input_layout

    @property
    def state_layout(self) -> StateLayout:
        return self.task_def.state_layout

    @property
    def accel_layout(self) -> StateLayout:
        return self.task_def.accel_layout

    @property
    def input_dim(self) -> int:
        """Features per sample of the motions the encoder reads."""
        return self.input_layout.dim

    @property
    def uncertainty_names(self) -> tuple[str, ...]:
        """The state fields a result's ``uncertainty`` columns are the predicted std of."""
        fields_ = self.task_def.uncertainty_fields
        if fields_ is None:
            p = len(self.accel_layout.names)
            fields_ = self.state_layout.names[:p]
        return tuple(fields_)

    @property
    def uncertainty_units(self) -> tuple[str, ...]:
        """The units of :attr:`uncertainty_names`."""
        return tuple(self.state_layout.units[self.state_layout.index(n)] for n in self.uncertainty_names)

    def check_physics(self, physics: dict[str, Any]) -> None:
        """Refuse inference-time physics parameters the task's dynamics do not take, by name."""
        unknown = sorted(set(physics) - set(self.task_def.physics_parameters))
        if unknown:
            allowed = list(self.task_def.physics_parameters) or "none"
            raise ValueError(
                f"the {self.task_def.name!r} model's dynamics take no parameter(s) {unknown} (they take: {allowed}); "
                f"its options are {self.options.to_dict()} — options such as mu are fixed when the model is trained"
                + (" (objectives take their own mu=...)" if "mu" in unknown else "")
            )

    def dynamics(self, **physics: Any) -> ChunkDynamics:
        """The :class:`~seqmotion.models.seq2seq.ChunkDynamics` the decoder runs with (options' physics
        unless ``physics`` overrides what the task allows)."""
        self.check_physics(physics)
        return self.task_def.dynamics(self.options, **physics)

    def start_state(self, inputs: torch.Tensor) -> torch.Tensor:
        """Decoder start state ``(B, state_dim)`` for input trajectories ``(B, K, input_dim)``."""
        return self.task_def.start_state(inputs)

    def violation_torch(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor | None:
        """The task's constraint violation ``(B, K-1)`` at this model's options (None: no constraint)."""
        return self.task_def.violation(states, accel, self.options)

    # --- the exact polish --------------------------------------------------------------------------

    def exact_form(self) -> ExactForm:
        """The task's :class:`ExactForm` at this model's options; ``ValueError`` naming the task if it has none."""
        form = self.task_def.exact_form(self.options)
        if form is None:
            raise ValueError(
                f"task {self.task_def.name!r} has no exact polish (Task.exact_form returns None), so exact=True and "
                "keep_end=True are not available for it; drop them to get the learned motion as it is"
            )
        return form

    def polish(
        self, x0: np.ndarray, accel: np.ndarray, constraints: Sequence[Constraint] = (),
        params: Sequence[np.ndarray] = (), start: np.ndarray | None = None, cold_iterations: int = COLD_ITERATIONS,
        warm: bool = True, symbolic: str = "auto",
        end_cost: tuple[Sequence[int], Sequence[float], np.ndarray] | None = None,
    ) -> Solution:
        """The motion closest to ``accel`` that meets the task's constraint and ``constraints`` exactly.

        One trajectory: ``x0`` ``(S,)`` its start state, ``accel`` ``(K-1, d)`` the inputs to start from
        and stay near; ``params`` one array per constraint (its target). IPOPT starts at ``accel`` with a
        small barrier (a few iterations from a nearly feasible motion); if that does not converge (a
        start far from feasible can even look locally infeasible), it runs once more from the same
        motion with IPOPT's default barrier. ``start``: other inputs ``(K-1, d)`` to start IPOPT from
        (default ``accel``), e.g. ``accel`` already corrected to meet linear end conditions.
        ``cold_iterations``: IPOPT's iteration cap for the cold start; ``warm=False``: only the cold start (a
        start outside the acceleration limits, as ``keep_end``'s usually is, never converges warm);
        ``symbolic``: CasADi's graph type (:func:`~seqmotion.physics.transcription.transcription`; ``"MX"`` for
        lengths that will rarely recur, where SX's slower build never pays back);
        ``end_cost``: ``(columns, weights, target)`` adds ``|weights ⊙ (x[K-1, columns] − target)|²`` to the
        cost — an end condition asked for as nearly as the constraints allow instead of exactly.
        """
        form = self.exact_form()
        limits = () if form.accel_limits is None else (input_limits(form.accel_limits, "acceleration limits"),)
        every = form.constraints + limits + tuple(constraints)
        values = [np.zeros(0)] * (len(form.constraints) + len(limits)) + [np.asarray(p, np.float64) for p in params]
        length = len(accel) + 1
        kwargs = {"dt": form.dt, "accel_weights": form.accel_weights, "smoothness": form.smoothness,
                  "symbolic": symbolic}
        target = None
        if end_cost is not None:
            columns, weights, target = end_cost
            kwargs |= {"end_columns": tuple(int(c) for c in columns), "end_weights": tuple(map(float, weights))}
        guess = accel if start is None else start
        solution = None
        if warm:
            nlp = transcription(form.dim, length, every, warm=True, max_iter=WARM_ITERATIONS, **kwargs)
            solution = nlp.solve(x0, guess, values, reference=accel, end_target=target)
            if solution.success:
                return solution
        cold = transcription(form.dim, length, every, max_iter=cold_iterations, **kwargs)
        retry = cold.solve(x0, guess, values, reference=accel, end_target=target)
        if solution is not None:
            retry.iterations += solution.iterations
            retry.seconds += solution.seconds
        return retry

    # --- differentiable maps (latent optimisation works on these) -------------------------------

    def encode_torch(self, inputs: torch.Tensor) -> torch.Tensor:
        """``(B, K, input_dim)`` → latents ``(B, L·H)`` (on the model's device)."""
        return self.model.encode(inputs.float().to(self.device))

    def decode_torch(
        self, latent: torch.Tensor, x0: torch.Tensor, length: int, **physics: Any
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Decode latents from start states into ``(states (B, K, S), accel (B, K-1, d))``, differentiably.

        The physics runs in the dtype of ``x0`` (float64 gives exact bookkeeping).
        """
        out = rollout(self.model, latent, x0, self.dynamics(**physics), self.model.num_chunks(length), need_cov=False)
        return out.states[:, :length], out.accel[:, : length - 1].to(x0.dtype)

    def integrate_torch(self, x0: torch.Tensor, accel: torch.Tensor, **physics: Any) -> torch.Tensor:
        """States ``(B, N+1, S)`` that accelerations ``(B, N, d)`` produce from ``x0`` through the task's physics."""
        dynamics = self.dynamics(**physics)
        _, out = dynamics.step(dynamics.start(x0), accel.to(x0.dtype), None)
        return torch.cat([x0.unsqueeze(1), out["states"]], dim=1)

    # --- NumPy API -----------------------------------------------------------------------------

    def generate(self, inputs: object, keep_end: bool = False, extend: bool = True, **physics: Any) -> Any:
        """Encode ``(K, input_dim)`` or ``(B, K, input_dim)`` motions (any K ≥ 2) and decode them
        through the task's physics: the task's result (a :class:`Motion` unless the task says otherwise).

        ``keep_end=True``: then polish each motion (:meth:`polish`) so it ends exactly at the input's
        end pose (the task's ``end_pose`` fields of the input's last sample), at rest, with the task's
        constraint held and within the arm's acceleration limits (:attr:`ExactForm.accel_limits`) — the
        learned motion changed as little as possible. An input too short for that (e.g. 0.3 m and 3 rad
        in 0.15 s) gets the time it needs: the motion is longer than the input (``result.length``), unless
        ``extend=False``, which keeps the input's length and flags such a motion instead. Needs a task with
        an exact form and an end pose; ``result.exact`` says, per motion, whether the polish succeeded.
        One that fails (an end pose the constraint, limits or reach rule out) warns and ends at rest as
        near the end pose as they allow (its end error in ``result.errors``), still within them; only if
        even that fails does it keep the learned motion.

        Raises:
            ValueError: wrong shape, K < 2, NaN or inf, a physics parameter the task does not take,
                ``keep_end`` for a task without an exact form or end pose.
        """
        self.check_physics(physics)
        batch, single = as_trajectories(inputs, self.input_dim, self.input_layout.kind)
        for name, flag in (("keep_end", keep_end), ("extend", extend)):
            if not isinstance(flag, bool):
                raise ValueError(f"{name} must be True or False, got {flag!r}")
        end = self._end_constraint(batch, physics) if keep_end else None
        with torch.inference_mode():
            x = torch.from_numpy(batch)
            z = self.encode_torch(x)
            result = self._decode(z, self.start_state(x).double(), batch.shape[1], physics, inputs=batch, end=end,
                                  extend=extend)
        return first_of(result) if single else result

    def _end_constraint(self, inputs: np.ndarray, physics: dict[str, Any]) -> tuple[Constraint, np.ndarray]:
        """``keep_end``'s constraint — the end-pose fields at the inputs' last values, the rate fields
        (units ending in ``/s``) at 0 — and its values ``(B, n)``; refusals by name first."""
        self.exact_form()
        task = self.task_def
        if task.end_pose is None or self.input_layout.names != self.state_layout.names:
            raise ValueError(f"keep_end=True needs a task whose inputs are its states and that declares an end pose; "
                             f"{task.name!r} does not")
        if physics:
            raise ValueError(f"keep_end=True polishes at the model's own physics; drop {sorted(physics)}")
        layout = self.state_layout
        pose = [layout.index(f) for f in task.end_pose[0]]
        rates = [i for i, unit in enumerate(layout.units) if unit.endswith("/s") and i not in pose]
        values = np.concatenate([inputs[:, -1, pose], np.zeros((len(inputs), len(rates)))], axis=1)
        return end_values(pose + rates, "end at the input's end pose, at rest"), values

    def _polish_ends(
        self, states: torch.Tensor, accel: torch.Tensor, end: tuple[Constraint, np.ndarray], extend: bool = True,
    ) -> tuple[torch.Tensor, torch.Tensor, np.ndarray, np.ndarray]:
        """Polish each motion onto ``end`` (see :meth:`generate`): ``(states, accel, exact (B,), length (B,))``,
        padded to the longest motion by holding its end state with zero input."""
        constraint, values = end
        columns = list(constraint.key[1])
        exact = np.zeros(len(states), dtype=bool)
        x0, reference = states[:, 0].numpy(), accel.numpy()
        form = self.exact_form()
        motions = []
        for b in range(len(states)):
            motions.append((states[b].numpy(), reference[b]))
            steps = len(reference[b])
            if not extend:
                need = _rest_to_rest_accel(x0[b], columns, values[b], steps, form)
                if need is not None:  # no motion can do it within the limits in its time: say so without IPOPT
                    warnings.warn(f"keep_end: motion {b} cannot end at rest where its input ends within the "
                                  f"acceleration limits {form.accel_limits} (rest to rest in its time needs at least "
                                  f"{need}); it keeps the learned motion", RuntimeWarning, stacklevel=4)
                    continue
            steps = _steps_to_stop(x0[b], columns, values[b], steps, form) if extend else steps
            attempts = EXTEND_ATTEMPTS if extend else 1
            for attempt in range(attempts):
                # after the input's end the polish stays near rest (zero input) while it brings the motion to a stop
                ref = np.concatenate([reference[b], np.zeros((steps - len(reference[b]), reference.shape[2]))])
                # the end conditions are linear in the inputs: meet them first in closed form, so IPOPT
                # starts from a motion that only the task's constraint still separates from exact
                start = reach_end(x0[b], ref, columns, values[b], np.array(form.accel_weights), form.dt)
                last = attempt == attempts - 1  # a failing try is cut short: a longer one will likely succeed
                # MX: a motion's length (its input's, or an extended one) seldom recurs soon, and "auto" would
                # build the slow-to-build SX graph (0.18 s mean, 1 s at K = 1000) on its second request
                solution = self.polish(x0[b], ref, [constraint], [values[b]], start=start, warm=False,
                                       cold_iterations=COLD_ITERATIONS if last else EXTEND_COLD_ITERATIONS,
                                       symbolic="MX")
                if self._holds(solution):
                    motions[b], exact[b] = (solution.states, solution.accel), True
                    break
                steps = math.ceil(steps * EXTEND_GROWTH)
            if not exact[b]:  # at the longest time tried (``ref``)
                motions[b] = self._nearest_rest(b, x0[b], ref, columns, values[b], solution.status, motions[b])
        length = np.array([len(s) for s, _ in motions])
        longest = int(length.max())
        states = torch.from_numpy(np.stack([np.concatenate([s, np.repeat(s[-1:], longest - len(s), 0)])
                                            for s, _ in motions]))
        accel = torch.from_numpy(np.stack([np.concatenate([a, np.zeros((longest - 1 - len(a), a.shape[1]))])
                                           for _, a in motions]))
        return states, accel, exact, length

    def _holds(self, solution: Solution) -> bool:
        """Whether a polish converged with the task's constraint held (to :data:`POLISH_VIOLATION_TOLERANCE`)."""
        states, accel = torch.from_numpy(solution.states)[None], torch.from_numpy(solution.accel)[None]
        violation = self.violation_torch(states, accel)
        return solution.success and (violation is None or violation.numel() == 0
                                     or float(violation.max()) <= POLISH_VIOLATION_TOLERANCE)

    def _nearest_rest(
        self, b: int, x0: np.ndarray, ref: np.ndarray, columns: list[int], values: np.ndarray, status: str,
        learned: tuple[np.ndarray, np.ndarray],
    ) -> tuple[np.ndarray, np.ndarray]:
        """``keep_end``'s fallback for motion ``b``, whose end pose no polish reached (e.g. a pose that the
        arm can hold the pancake at only from beyond its reach): the motion as long as ``ref`` that
        ends at rest, keeps the task's constraint, limits and reach exactly, and ends as near the end pose as
        they allow (weighted by :data:`FALLBACK_END_WEIGHT`) — executable, and flagged (``exact`` stays False,
        the trust signals give its end error). If even that fails, the learned motion as it is."""
        form = self.exact_form()
        pose = [self.state_layout.index(f) for f in self.task_def.end_pose[0]]
        rates = [c for c in columns if c not in pose]
        target = np.array([values[columns.index(c)] for c in pose])
        weights = [FALLBACK_END_WEIGHT * math.sqrt(form.accel_weights[c]) if c < form.dim else FALLBACK_END_WEIGHT
                   for c in pose]
        rest = end_values(rates, "end at rest")
        # from standing still — feasible for the constraint, limits and reach from a start at rest — toward
        # the learned motion: from the learned motion itself (beyond reach, where the exact polish failed)
        # IPOPT failed to converge on 1 of the 5 such motions of 600 sketches; from rest on none
        solution = self.polish(x0, ref, [rest], [np.zeros(len(rates))], start=np.zeros_like(ref), warm=False,
                               symbolic="MX", end_cost=(pose, weights, target))
        if self._holds(solution):
            miss = np.abs(solution.states[-1, pose] - target)
            warnings.warn(f"keep_end: motion {b} cannot end at its input's end pose within the task's constraint, "
                          f"the acceleration limits and the reach ({status}); it ends at rest as near as they allow, "
                          f"{np.round(miss, 4).tolist()} from it ({', '.join(self.task_def.end_pose[0])})",
                          RuntimeWarning, stacklevel=5)
            return solution.states, solution.accel
        warnings.warn(f"keep_end: the polish failed on motion {b} ({status}; ending at rest near its end pose: "
                      f"{solution.status}); it keeps the learned motion", RuntimeWarning, stacklevel=5)
        return learned

    def decode(self, latent: object, x0: object, length: int, **physics: Any) -> Any:
        """Decode latents ``(L·H,)``/``(B, L·H)`` from start states ``(S,)``/``(B, S)`` into ``length`` samples."""
        length = check_number("length", length, minimum=2, maximum=MAX_LENGTH, integer=True)
        self.check_physics(physics)
        z, start, single = self._latent_and_start(latent, x0)
        with torch.inference_mode():
            result = self._decode(z, torch.from_numpy(start), int(length), physics)
        return first_of(result) if single else result

    def _latent_and_start(self, latent: object, x0: object) -> tuple[torch.Tensor, np.ndarray, bool]:
        with np.errstate(over="ignore"):  # a latent beyond float32 becomes inf: refused below
            z = as_float_array(latent, "latent").astype(np.float32)
        single = z.ndim == 1
        z, start = np.atleast_2d(z), np.atleast_2d(as_float_array(x0, "x0"))
        s = self.state_layout.dim
        if z.ndim != 2 or z.shape[1] != self.model.latent_dim or start.shape != (z.shape[0], s):
            raise ValueError(
                f"need latent (B, {self.model.latent_dim}) and x0 (B, {s}) [{self.state_layout}]; "
                f"got {z.shape} and {start.shape}"
            )
        if z.shape[0] == 0:
            raise ValueError("latent has an empty batch (B = 0)")
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(start))):
            raise ValueError("latent and x0 must be finite (NaN or inf given)")
        return torch.from_numpy(z), start, single

    def rollout_with_std(
        self, z: torch.Tensor, x0: torch.Tensor, length: int, **physics: Any
    ) -> tuple[torch.Tensor, torch.Tensor, np.ndarray | None]:
        """Decode latents ``(B, L·H)`` from ``x0`` ``(B, S)``: ``(states (B, K, S), accel (B, K-1, d), std)``
        with ``std`` ``(B, K, p)`` the predicted position std of :attr:`uncertainty_names` (None: the
        dynamics give no position covariance of that size).

        The decoder's loop runs without propagating covariances; the head's ``S_u`` are propagated once
        over the whole motion afterwards (:meth:`Task.position_cov`), which costs a fraction of doing it
        chunk by chunk. A task without that closed form gets the chunk-by-chunk propagation.
        """
        dynamics = self.dynamics(**physics)
        steps = self.model.num_chunks(length)
        device = self.device  # run where the network is; hand the results back on the CPU
        z, x0 = z.to(device), x0.to(device)
        out = rollout(self.model, z, x0, trust.HeadCovarianceOnly(dynamics), steps, need_cov=True)
        states, accel = out.states[:, :length], out.accel[:, : length - 1].to(x0.dtype)
        outputs = {k: v[:, : length - 1] for k, v in out.outputs.items()}
        cov = None
        if out.accel_cov is not None:
            cov = self.task_def.position_cov(out.accel_cov[:, : length - 1].to(x0.dtype), states, accel, outputs,
                                             dynamics)
        if cov is None:  # no closed form: the dynamics' own propagation
            cov = rollout(self.model, z, x0, dynamics, steps, need_cov=True).outputs.get("pos_cov")
        ok = cov is not None and cov.shape[-1] == len(self.uncertainty_names)
        return states.cpu(), accel.cpu(), position_std(cov, length) if ok else None

    def _decode(
        self, z: torch.Tensor, x0: torch.Tensor, length: int, physics: dict[str, Any], inputs: np.ndarray | None = None,
        end: tuple[Constraint, np.ndarray] | None = None, extend: bool = True,
    ) -> Any:
        """Decode (with the predicted std, :meth:`rollout_with_std`), polish onto ``end`` when given
        (``keep_end``; ``extend``: see :meth:`generate`), and judge the motion against ``inputs``
        ``(B, K, input_dim)`` when given (errors, out-of-distribution flag)."""
        x0 = x0.double()
        states, accel, std = self.rollout_with_std(z, x0, length, **physics)
        exact = own_length = None
        if end is not None:
            states, accel, exact, own_length = self._polish_ends(states, accel, end, extend)
        violation = self.violation_torch(states, accel)
        if own_length is not None and violation is not None:  # a batch's padding past a motion's end is not part of it
            past = torch.arange(violation.shape[1]) >= torch.from_numpy(own_length - 1)[:, None]
            violation = violation.masked_fill(past, 0.0)
        if std is not None and std.shape[1] < states.shape[1]:  # the model predicted the input's time only
            std = np.concatenate([std, np.repeat(std[:, -1:], states.shape[1] - std.shape[1], axis=1)], axis=1)
        states_np = check_finite_result(states.numpy(), f"{self.task_def.name} generation")
        latent_np = z.float().cpu().numpy()
        motion = Motion(states_np, accel.numpy(), latent_np, None if violation is None else violation.numpy(),
                        uncertainty=std, exact=exact, length=own_length, task=self.task_def.name)
        if inputs is not None:
            motion.errors, motion.out_of_distribution, motion.ood_reasons = self._judge(
                inputs, states_np, motion.accel, motion.violation, std, physics)
        return self.task_def.make_result(motion, self)

    def _judge(
        self, inputs: np.ndarray, states: np.ndarray, accel: np.ndarray, violation: np.ndarray | None,
        std: np.ndarray | None, physics: dict[str, Any],
    ) -> tuple[dict[str, np.ndarray], np.ndarray | None, list[list[str]]]:
        """Errors ``(B,)`` each, out-of-distribution flags ``(B,)`` and reasons for a batch (``keep_end`` may have
        made the motions longer than the inputs: the input then holds its end, where the motion comes to rest);
        ``physics`` given at inference beyond what the training met is a reason too."""
        inputs = np.asarray(inputs, dtype=np.float64)
        held = np.concatenate([inputs, np.repeat(inputs[:, -1:], states.shape[1] - inputs.shape[1], axis=1)], axis=1)
        errors = self.task_def.errors(held, states, accel, violation, self.options)
        try:
            calibration = trust.calibration_for(self)
        except Exception as exc:  # noqa: BLE001 - a task whose generator cannot calibrate: say so, never fail
            self.trust_calibration = trust.TrustCalibration(upper={}, source=f"not calibrated ({exc})")
            calibration = self.trust_calibration
        physics_out = self._physics_beyond_training(physics)
        if not calibration.upper:
            if physics_out:
                return errors, np.ones(len(states), dtype=bool), [[*physics_out, calibration.source] for _ in states]
            return errors, None, [[calibration.source] for _ in range(len(states))]
        flags, reasons = calibration.check(trust.features_of(self, inputs, None, std))
        if physics_out:
            flags, reasons = np.ones_like(flags), [[*physics_out, *r] for r in reasons]
        return errors, flags, reasons

    def _physics_beyond_training(self, physics: dict[str, Any]) -> list[str]:
        """Reasons (``"mu 1e+300 outside 0.72-1.32 (trained 0.8-1.2)"``) for each physics parameter beyond what the
        training met, widened by the trust margin: the model was never shown that physics."""
        reasons = []
        for name, (low, high) in self.task_def.physics_trained(self.options).items():
            value = physics.get(name)
            if value is None:
                continue
            lo, hi = low * (1 - trust.MARGIN), high * (1 + trust.MARGIN)
            if not lo <= float(value) <= hi:
                reasons.append(f"{name} {float(value):.4g} outside {lo:.4g}-{hi:.4g} (trained {low:.4g}-{high:.4g})")
        return reasons

    def trust_lines(self, result: Any, tolerances: dict[str, float] | None = None) -> list[str]:
        """The lines the command lines print under a result (a task's result, a :class:`Motion` or an
        :class:`Assessment`): errors, predicted std at the end, ``warning:`` lines for missed tolerances
        (:meth:`Task.tolerances`, updated by ``tolerances``) and an input out of distribution
        (:func:`.trust.summary_lines`)."""
        return trust.summary_lines(
            getattr(result, "errors", None), getattr(result, "uncertainty", None),
            getattr(result, "out_of_distribution", None), getattr(result, "ood_reasons", None),
            {**self.task_def.tolerances(self.options), **(tolerances or {})}, self.uncertainty_names,
            self.uncertainty_units,
        )

    def assess(
        self, inputs: object, states: object, accel: object, latent: object | None = None, **physics: Any
    ) -> Assessment:
        """Trust signals for a motion produced some other way (e.g. latent optimisation): its errors
        against ``inputs``, whether ``inputs`` lie outside the training distribution, and — given the
        ``latent`` it was decoded from — the predicted std (its end value joins the flag's features).

        Args:
            inputs: ``(K, input_dim)`` or ``(B, K, input_dim)`` the motion(s) the user gave.
            states: ``(K, S)``/``(B, K, S)`` the result's states; ``accel``: ``(K-1, d)``/``(B, K-1, d)``.
            latent: ``(L·H,)``/``(B, L·H)``, decoded from ``states[..., 0, :]`` for the uncertainty.
            physics: the physics the motion was generated in (e.g. ``mu=``).

        Returns:
            :class:`Assessment` (errors, out_of_distribution, ood_reasons, uncertainty); floats, a
            bool and a list of strings for one motion, ``(B,)`` arrays and a list per motion for a batch.
        """
        batch, single = as_trajectories(inputs, self.input_dim, self.input_layout.kind)
        states_b, accel_b = as_float_array(states, "states"), as_float_array(accel, "accel")
        if single:
            states_b, accel_b = states_b[None], accel_b[None]
        k = batch.shape[1]
        if states_b.shape != (len(batch), k, self.state_layout.dim) or accel_b.shape != (
            len(batch), k - 1, self.accel_layout.dim
        ):
            raise ValueError(
                f"need states (B, {k}, {self.state_layout.dim}) and accel (B, {k - 1}, {self.accel_layout.dim}) "
                f"for inputs {batch.shape}; got {states_b.shape} and {accel_b.shape}"
            )
        std = None
        if latent is not None:
            self.check_physics(physics)
            z, start, _ = self._latent_and_start(latent, states_b[:, 0])
            with torch.inference_mode():
                _, _, std = self.rollout_with_std(z, torch.from_numpy(start), k, **physics)
        with torch.inference_mode():
            violation = self.violation_torch(torch.from_numpy(states_b), torch.from_numpy(accel_b))
        self.check_physics(physics)
        errors, flags, reasons = self._judge(batch, states_b, accel_b, None if violation is None else violation.numpy(),
                                             std, physics)
        result = Assessment(errors, flags, reasons, std)
        if single:
            return Assessment(*(_first(v) for v in result))
        return result

    def generator(
        self, inputs: object | None = None, *, latent: object | None = None, x0: object | None = None,
        length: int | None = None, replan: bool = True, **physics: Any
    ) -> OnlineGenerator:
        """The decoder as an online motion generator for a control loop (contract: :mod:`.stepper`).

        Give either the ``inputs`` motion to encode (x0 = the task's start state for it, K = its
        length) or a ``latent`` and a start state ``x0`` of the task's ``state_layout`` (K = ``length``,
        default: the longest motion the model trained on). Past K the generator brings the robot to
        rest within the task's constraint, then holds. ``replan``: between chunk boundaries, correct
        the remaining outputs from the latest measured states.
        """
        if inputs is not None:
            if latent is not None or x0 is not None:
                raise ValueError("give either the input motion, or latent and x0 — not both")
            batch, single = as_trajectories(inputs, self.input_dim, self.input_layout.kind)
            with torch.inference_mode():
                x = torch.from_numpy(batch)
                z = self.encode_torch(x).cpu().numpy()
                start = self.start_state(x).double().numpy()
            length = batch.shape[1] if length is None else length
        elif latent is not None and x0 is not None:
            z_t, start, single = self._latent_and_start(latent, x0)
            z = z_t.numpy()
        else:
            raise ValueError("give either the input motion, or both latent and x0")
        dynamics = self.dynamics(**physics)
        # batch 1, one chunk at a time: latency-bound, so the online generator steps on the CPU
        network = self.model if self.device.type == "cpu" else copy.deepcopy(self.model).cpu()
        return OnlineGenerator(network, dynamics, stepper_contract(self, dynamics), z, start, single,
                               length=length, violation=self.violation_torch, replan=replan)

    def quantized(self, min_features: int = 256) -> TrainedModel:
        """A copy for fast CPU inference with the big linear layers in int8 (weight-only).

        Worth it for wide models (the paper-size sliding planner: ~2.5× faster generation);
        narrow layers stay float32. See :mod:`seqmotion.models.quantize` for the error it adds.
        """
        from ..models.quantize import quantize_int8

        copy = object.__new__(type(self))
        copy.__dict__.update(self.__dict__)
        copy.model = quantize_int8(self.model, min_features)
        copy.is_quantized = True
        return copy

    def __repr__(self) -> str:
        m = self.model.cfg
        return f"{type(self).__name__}(task={self.task_def.name!r}, {m.layers}x{m.hidden}, C={m.chunk})"


__all__ = [
    "FEASIBLE_TOLERANCE", "Assessment", "Motion", "OnlineGenerator", "Task", "TrainConfig", "TrainedModel",
    "TrustSignals", "first_of", "load_result",
]
