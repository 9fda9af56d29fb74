"""What a trained model returns: a :class:`Motion` with its trust signals, saved and loaded without pickle.

Every result is a dataclass deriving from :class:`TrustSignals` (``errors``, ``uncertainty``,
``out_of_distribution``/``ood_reasons``, ``exact``, ``length``, ``task``, ``physics``). A generated motion is a
:class:`Motion` — ``states`` in the task's state layout, ``accel`` (the decoder's outputs) in its accel layout,
``latent``, ``violation`` — and a task's own result (``DeformResult``, ``SlidingPlan``, ``OptimizationResult``)
subclasses it, adding its fields and its names for parts of the arrays (:class:`View`: the sliding plan's
``pan_states`` are ``states[..., :4]``). Code meant for any task reads ``result.motion().states`` and
``.accel`` and names columns by the layouts (:func:`columns_of`); task code keeps its friendly names.
"""

from __future__ import annotations

import importlib
import json
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, ClassVar, NamedTuple

import numpy as np

from .. import io
from ..errors import check_json_number
from ..io import read_npz, write_arrays
from ..physics.layout import StateLayout
from ..physics.parameters import Physics
from . import registry

FEASIBLE_TOLERANCE = 0.01
"""A motion counts as feasible when its largest constraint violation is at most this."""


def first_of(result: Any) -> Any:
    """The same result dataclass with every array field indexed by ``[0]`` (drop a batch axis of 1)."""
    values = {f.name: getattr(result, f.name) for f in fields(result)}
    return type(result)(**{k: first_value(v) for k, v in values.items()})


def first_value(value: Any) -> Any:
    """``value[0]`` for a batched field (arrays, lists, the arrays of a dict); scalars and None as they are."""
    if value is None:
        return None
    if isinstance(value, dict):
        return {k: first_value(v) for k, v in value.items()}
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
        polish_iterations: with ``keep_end=True``: IPOPT's iterations for the motion (``(B,)`` for a batch), summed
            over every polish it took (a longer time tried, the fallback to the nearest rest); None otherwise.
            (An optimisation's polish reports its own in ``stages``.)
        task: the name of the task that made the result (it names the state fields in :meth:`plot`, and
            :func:`load_result` finds a plug-in's result class through it), or None.
        physics: the task's physics the result was computed at (:mod:`seqmotion.physics.parameters`, e.g.
            ``SlidingPhysics(mu=0.8, mu_dyn=0.4)``), or None.

    Every result saves itself (:meth:`save`, read back with :func:`load_result`) and plots itself (:meth:`plot`).
    """

    uncertainty: np.ndarray | None = field(default=None, kw_only=True)
    errors: dict[str, Any] | None = field(default=None, kw_only=True)
    out_of_distribution: Any = field(default=None, kw_only=True)
    ood_reasons: list | None = field(default=None, kw_only=True)
    exact: Any = field(default=None, kw_only=True)
    length: Any = field(default=None, kw_only=True)
    polish_iterations: Any = field(default=None, kw_only=True)
    task: str | None = field(default=None, kw_only=True)
    physics: Physics | None = field(default=None, kw_only=True)

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        _RESULT_CLASSES[_class_key(cls)] = cls  # what :func:`load_result` may rebuild (never a name from a file)

    def trust(self) -> dict[str, Any]:
        """These fields by name, to pass on to another result (``Result(..., **motion.trust())``)."""
        return {f.name: getattr(self, f.name) for f in fields(TrustSignals)}

    def motion(self) -> Motion:
        """This result as a :class:`Motion` (``states``, ``accel``, ``latent``, ``violation`` and these trust
        signals): how code meant for any task reads a result. A :class:`Motion` (every task's result that
        subclasses it) is returned as it is; another result class must hold ``states`` and ``accel`` fields.

        Raises:
            ValueError: a result class with neither (subclass :class:`Motion` instead, naming its parts with
                :class:`View`).
        """
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        if "states" not in values or "accel" not in values:
            raise ValueError(f"a {type(self).__name__} holds no states and accel fields: derive it from "
                             "seqmotion.core.results.Motion (its own names for parts of them: View)")
        return Motion(values["states"], values["accel"], values.get("latent"), values.get("violation"),
                      **self.trust())

    def save(self, path: str | Path, extra: Mapping[str, Any] | None = None) -> Path:
        """Write this result to an ``.npz`` atomically, every field under its own name, no pickled objects.

        Arrays keep their name, dtype and shape (``states``, ``accel``, …); a dict's entries are
        ``<field>.<key>`` (``errors.end_position_error_m``), a list of dataclasses ``<field>.<i>.<attr>``
        (an optimisation's ``stages.0.seconds``), lists of strings one JSON string (``ood_reasons``),
        strings a text array (``task``). ``result.class`` names the class and ``result.layout`` (JSON) how
        to rebuild each field: :func:`load_result` returns an equal result. ``np.load(path)`` reads it
        as plain named arrays.

        ``extra``: more named arrays of numbers to store beside the result's own for readers of plain arrays (the
        command line's plan keeps ``pan_accel``, ``command``, ``friction``); :func:`load_result` ignores them. A name
        the result already stores is skipped where it holds the same values.

        Raises:
            ValueError: ``path`` is not a writable ``.npz`` path, a field holds a value that cannot be
                stored without pickling (naming the field), or an ``extra`` array is not numbers or differs from
                the result's array of the same name.
        """
        path = io.check_writable(path, (".npz",), "result file")
        arrays: dict[str, np.ndarray] = {}
        layout = {f.name: _pack(getattr(self, f.name), f.name, arrays) for f in fields(self) if f.init}
        for key, value in (extra or {}).items():
            array = np.asarray(value)
            if array.dtype.kind not in "biuf":
                raise ValueError(f"cannot save extra array {key!r}: it holds {array.dtype}, not numbers")
            if key not in arrays:
                _put(arrays, key, array)
            elif not np.array_equal(arrays[key], array, equal_nan=array.dtype.kind == "f"):
                raise ValueError(f"cannot save extra array {key!r}: the result stores other values under that name")
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
    if isinstance(value, Physics):  # the physics a result was computed at: rebuilt as its own class, checked
        parts = {k: _pack(v, f"{key}.{k}", arrays) for k, v in value.to_dict().items()}
        return {"physics": value.key(), "fields": parts}
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
        if kind != "ndarray" and array.ndim:  # saved from one number: a file holding more was not written so
            raise ValueError(f"array {node['array']!r} has shape {array.shape}, expected () (one value)")
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
    if "physics" in node:
        return Physics.class_named(str(node["physics"])).from_dict(
            {str(k): _unpack(child, arrays, home) for k, child in node["fields"].items()})
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

    Read without pickle (:func:`seqmotion.io.read_npz`: sizes checked before anything is
    decompressed), and nothing but the result classes and their dataclasses is ever built.

    Raises:
        ValueError: a missing file, not an ``.npz``, a file that ``result.save`` did not write (e.g.
            ``np.savez`` of ``vars(result)``, whose object arrays need pickle), an array that holds objects
            (naming it), an unknown result class, a malformed layout, or arrays that do not fit the task's
            layout or each other (:func:`check_arrays`: naming the array, expected vs got shape).
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
    views = getattr(cls, "views", {})
    unknown = sorted(set(nodes) - {f.name for f in fields(cls) if f.init} - set(views))
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
        result = cls(**_join_views(values, views))
    except (ValueError, TypeError, KeyError, AttributeError, RecursionError) as exc:
        raise ValueError(f"{path}: cannot rebuild the {cls.__name__}: {exc}") from None
    check_arrays(result, path)
    return result


def _dims(*dims: object) -> str:
    """``(2, K, 6)`` / ``(9,)``: a shape for messages, with symbols where a size is free."""
    return f"({', '.join(map(str, dims))}{',' if len(dims) == 1 else ''})"


def _task_of(name: str | None) -> Any:
    """The installed task called ``name``, or None (no name, or a task not installed here)."""
    if not name:
        return None
    try:
        return registry.get(name)
    except ValueError:
        return None


def check_arrays(result: TrustSignals, source: str | Path) -> None:
    """``ValueError`` naming ``source`` and the array unless a result's arrays belong together: ``states``
    ``([B,] K, S)`` (floats, finite, K ≥ 2; S the task's state columns when the task is installed), ``accel``
    ``([B,] K-1, d)`` (d its accel columns), ``latent`` ``([B,] L)``, ``violation`` and the class's other
    :attr:`Motion.per_transition` fields ``([B,] K-1)``, ``uncertainty`` ``([B,] K, P)`` (≥ 0), and each error,
    ``out_of_distribution``, ``exact`` and ``length`` (2 … K) one value per motion.

    :func:`load_result` calls it: a file is data from anywhere, and arrays that do not fit each other would
    otherwise be plotted, written to CSV or fed to a robot as if they did. A result without ``states`` and
    ``accel`` has nothing sharing their time and is left as it is.
    """
    values = {f.name: getattr(result, f.name) for f in fields(result)}
    if "states" not in values or "accel" not in values:
        return
    task = _task_of(result.task)
    state_layout, accel_layout = (getattr(task, name, None) for name in ("state_layout", "accel_layout"))
    uncertainty_fields = getattr(task, "uncertainty_fields", None)

    def refuse(name: str, what: str) -> ValueError:
        return ValueError(f"{source}: array {name!r} {what}")

    def floats(name: str, finite: bool = True) -> np.ndarray:
        value = values[name]
        if not isinstance(value, np.ndarray):
            raise refuse(name, f"is a {type(value).__name__}, expected an array of floats")
        if value.dtype.kind != "f":  # bool or integer motions are no generator's output
            raise refuse(name, f"holds {value.dtype}, expected floats")
        if finite and not np.isfinite(value).all():
            raise refuse(name, "holds NaN or inf")
        return value

    states = floats("states")
    if states.ndim not in (2, 3):
        raise refuse("states", f"has shape {_dims(*states.shape)}, expected (K, S) or (B, K, S)")
    lead, k = states.shape[:-2], states.shape[-2]
    if k < 2:
        raise refuse("states", f"has {k} sample{'s' * (k != 1)}, expected K ≥ 2")
    if isinstance(state_layout, StateLayout) and states.shape[-1] != state_layout.dim:
        raise refuse("states", f"has shape {_dims(*states.shape)}, expected {_dims(*lead, 'K', state_layout.dim)}: "
                               f"the columns of {state_layout} (task {result.task!r})")
    accel = floats("accel")
    width = accel_layout.dim if isinstance(accel_layout, StateLayout) else None
    if accel.shape[:-1] != (*lead, k - 1) or width not in (None, accel.shape[-1]):
        names = "" if width is None else f": the columns of {accel_layout}"
        raise refuse("accel", f"has shape {_dims(*accel.shape)}, expected {_dims(*lead, k - 1, width or 'd')} (K-1 = "
                              f"{k - 1} transitions of the states {_dims(*states.shape)}){names}")
    if values.get("latent") is not None:
        latent = floats("latent")
        if latent.ndim != len(lead) + 1 or latent.shape[:-1] != lead:
            raise refuse("latent", f"has shape {_dims(*latent.shape)}, expected {_dims(*lead, 'L')} (one latent per "
                                   f"motion of the states {_dims(*states.shape)})")
    for name in getattr(type(result), "per_transition", ("violation",)):
        if values.get(name) is not None and floats(name).shape != (*lead, k - 1):
            raise refuse(name, f"has shape {_dims(*values[name].shape)}, expected {_dims(*lead, k - 1)} (one value "
                               f"per transition of the states {_dims(*states.shape)})")
    if values.get("uncertainty") is not None:
        std = floats("uncertainty", finite=False)  # an overflowed std is inf, and says so honestly
        # as TrainedModel.uncertainty_names: the task's fields, else the first states, one per accel column
        p = len(uncertainty_fields) if uncertainty_fields else width
        if std.shape[:-1] != (*lead, k) or not (std.shape[-1] == p if p else 1 <= std.shape[-1] <= states.shape[-1]):
            expected = _dims(*lead, k, p or f"P ≤ {states.shape[-1]}")
            raise refuse("uncertainty", f"has shape {_dims(*std.shape)}, expected {expected} (a std per sample of the "
                                        f"states {_dims(*states.shape)})")
        if not (std >= 0).all():
            raise refuse("uncertainty", "holds negative values or NaN, expected standard deviations")
    per_motion = {f"errors.{key}": value for key, value in (values.get("errors") or {}).items()}
    per_motion |= {name: values.get(name) for name in ("out_of_distribution", "exact", "length", "polish_iterations")}
    for name, value in per_motion.items():
        if value is None:
            continue
        if not isinstance(value, (np.ndarray, np.generic, bool, int, float)):
            raise refuse(name, f"is a {type(value).__name__}, expected a number per motion")
        if np.shape(value) != lead:
            raise refuse(name, f"has shape {_dims(*np.shape(value))}, expected {_dims(*lead)} (one value per motion "
                               f"of the states {_dims(*states.shape)})")
    if values.get("length") is not None:
        length = np.asarray(values["length"])
        if length.dtype.kind not in "iu":
            raise refuse("length", f"holds {length.dtype}, expected integers")
        wrong = length[(length < 2) | (length > k)]
        if wrong.size:
            raise refuse("length", f"is {int(wrong.flat[0])}, expected 2 … K = {k} (the states' samples)")
    if values.get("polish_iterations") is not None:
        spent = np.asarray(values["polish_iterations"])
        if spent.dtype.kind not in "iu" or (spent < 0).any():
            raise refuse("polish_iterations", f"holds {spent.dtype} {spent.ravel()[:3].tolist()}, expected counts ≥ 0")
    reasons = values.get("ood_reasons")
    if reasons is not None and lead and (len(reasons) != lead[0] or not all(isinstance(r, list) for r in reasons)):
        raise refuse("ood_reasons", f"holds {len(reasons)} entries, expected {lead[0]} lists (one per motion)")


def _join_views(values: dict[str, Any], views: Mapping[str, View]) -> dict[str, Any]:
    """``values`` with a result's views, saved as fields of their own (a file written before the class was a
    :class:`Motion`: a sliding plan's ``pan_states``, ``rel_states``, ``pan_accel``), joined back into the
    ``states`` and ``accel`` they are columns of."""
    given = [name for name in views if name in values]
    if not given:
        return values
    out = {k: v for k, v in values.items() if k not in views}
    for source in ("states", "accel"):
        parts = sorted((views[n].start, n) for n in given if views[n].source == source)
        if not parts:
            continue
        if source in out:
            raise ValueError(f"both {source!r} and its view(s) {[n for _, n in parts]} are saved")
        arrays = [np.asarray(values[n]) for _, n in parts]
        widths = [a.shape[-1] for a in arrays]
        starts = [int(np.sum(widths[:i])) for i in range(len(arrays))]
        if [start for start, _ in parts] != starts:
            raise ValueError(f"the saved views {[n for _, n in parts]} do not tile the {source!r} columns")
        out[source] = np.concatenate(arrays, axis=-1)
    return out


def _plot(result: TrustSignals, path: str | Path | None) -> Any:
    """:meth:`TrustSignals.plot`: the figure, saved atomically to ``path`` when given."""
    from matplotlib.figure import Figure  # no pyplot: no global backend switch, nothing kept alive

    if path is not None:
        path = io.check_writable(path, None, "figure")
    motion = result.motion()
    states = np.asarray(motion.states, dtype=np.float64)
    if states.ndim not in (2, 3):
        raise ValueError(f"a {type(result).__name__}'s states are {states.shape}, not (K, S) or (B, K, S)")
    layout = None
    if result.task:  # the fields' names and units; a task not installed here: plotted by column
        try:
            layout = getattr(registry.get(result.task), "state_layout", None)
        except ValueError:
            layout = None
    if layout is not None and layout.dim != states.shape[-1]:
        layout = None
    batch = states.reshape(-1, *states.shape[-2:])
    columns = []  # (name, unit or "states", values (B, K)) per state column
    for j in range(states.shape[-1]):
        name, group = (layout.names[j], layout.units[j]) if layout is not None else (f"states[{j}]", "states")
        columns.append((name, group, batch[:, :, j]))
    groups = list(dict.fromkeys(group for _, group, _ in columns))
    violation = motion.violation
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
        io.save_figure(figure, path)
    return figure


def feasible_of(violation: np.ndarray | None) -> np.ndarray | bool | None:
    """Whether the largest violation ``(..., K-1)`` is ≤ :data:`FEASIBLE_TOLERANCE` (per trajectory for a
    batch); None without a constraint."""
    if violation is None:
        return None
    ok = violation.max(axis=-1) <= FEASIBLE_TOLERANCE
    return bool(ok) if np.ndim(ok) == 0 else ok


@dataclass(frozen=True)
class View:
    """A task's name for some columns of a motion's ``states`` or ``accel``: ``source[..., start:stop]``.

    The sliding plan's ``pan_states`` are ``View("states", 0, 4)`` (the pan's ``x, y, v_x, v_y``) and its
    ``pan_accel`` ``View("accel")``; CSV headers name the columns by the layout's names of that slice.
    """

    source: str
    start: int = 0
    stop: int | None = None

    def __post_init__(self) -> None:
        if self.source not in ("states", "accel"):
            raise ValueError(f"a View reads 'states' or 'accel', got {self.source!r}")
        for name, value in (("start", self.start), ("stop", self.stop)):
            if value is not None:
                check_json_number(f"a View's {name}", value, minimum=0, integer=True)
        if self.stop is not None and self.stop <= self.start:
            raise ValueError(f"a View's stop ({self.stop}) must lie after its start ({self.start})")

    def of(self, motion: Motion) -> np.ndarray:
        """The columns ``(..., stop - start)`` of ``motion``'s source array."""
        return np.asarray(getattr(motion, self.source))[..., self.start : self.stop]

    def names(self, layout: StateLayout) -> tuple[str, ...]:
        """The layout's names of these columns."""
        return tuple(layout.names[self.start : self.stop])


@dataclass
class Motion(TrustSignals):
    """A generated motion (a leading B axis on every array for a batch), with its trust signals.

    Every task's result is one (a task's own result class subclasses it): code meant for any task reads these
    fields, a task's code may read its own names for parts of them (:attr:`views`).

    Attributes:
        states: ``(K, S)`` states in the task's ``state_layout``; ``states[0]`` is the start state.
        accel: ``(K-1, d)`` the decoder's outputs ``u[0..K-2]`` in the task's ``accel_layout`` (accelerations,
            or whatever the task's physics is driven by, e.g. joint torques).
        latent: ``(L·H,)`` the latent z the motion was decoded from (None where it was not decoded from one).
        violation: ``(K-1,)`` the task's constraint violation per transition (0 where it holds),
            or None for a task without a constraint.
    """

    states: np.ndarray
    accel: np.ndarray
    latent: np.ndarray | None
    violation: np.ndarray | None = None

    per_transition: ClassVar[tuple[str, ...]] = ("violation",)
    """The fields holding one value per transition, ``([B,] K-1)`` floats (:func:`check_arrays` checks them on
    load); a task's result class with more of them (an angle per transition, say) lists them all."""

    views: ClassVar[Mapping[str, View]] = MappingProxyType({})
    """A task's names for parts of ``states`` and ``accel`` (name → :class:`View`), each readable as an
    attribute (``plan.pan_states``) and written under that name by :func:`columns_of`."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("views")
        if own is None:
            return
        cls.views = MappingProxyType(dict(own))
        taken = {name for klass in cls.__mro__ for name in klass.__dict__.get("__annotations__", {})}
        for name, view in cls.views.items():
            if not isinstance(view, View) or not name.isidentifier() or name in taken:
                raise ValueError(f"{cls.__name__}.views[{name!r}] must be a View under a name that is no field")
            if name not in cls.__dict__:  # a task's own property of that name wins
                setattr(cls, name, property(view.of, doc=f"``{view.source}[..., {view.start}:{view.stop or ''}]``"))

    def motion(self) -> Motion:
        """This motion itself (see :meth:`TrustSignals.motion`)."""
        return self

    @property
    def feasible(self) -> np.ndarray | bool | None:
        """Whether the largest violation is ≤ 0.01 (per trajectory for a batch; None without a constraint) and,
        where a robot was checked (a result's ``robot_check``, an
        :class:`~seqmotion.core.execution.ExecutionCheck`), the robot would not stop on it: False when its limits
        are broken, whatever the constraint."""
        cone = feasible_of(self.violation)
        check = getattr(self, "robot_check", None)
        if cone is None or check is None or check.ok is not False:
            return cone
        return np.zeros_like(cone, dtype=bool) if np.ndim(cone) else False


_TRUST_COLUMNS = ("uncertainty", "errors", "out_of_distribution", "ood_reasons", "task", "physics")
"""Trust fields :func:`columns_of` writes its own way (or leaves to the printed summary)."""


def columns_of(
    result: TrustSignals, state_layout: StateLayout, accel_layout: StateLayout,
    uncertainty_names: tuple[str, ...] | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:
    """A result's arrays by name and, for CSV headers, one name per column — every name from the layouts.

    ``states`` and ``accel`` are written under the task's views of them (the sliding plan's ``pan_states``,
    ``rel_states``, ``pan_accel``; :attr:`Motion.views`), or as ``states``/``accel`` where no view reads them;
    their columns take the layout's names (``y, z, theta, …``, ``a_y, a_z, a_theta``). A task's other
    per-sample fields keep their field name (``violation``, ``psi``); ``uncertainty`` columns are
    ``std.<field>``; errors, the out-of-distribution flag and the physics are written as ``errors.<name>``,
    ``out_of_distribution``, ``physics.<name>`` (one value each: kept in an ``.npz``, left out of a CSV).
    """
    motion = result.motion()
    layouts = {"states": state_layout, "accel": accel_layout}
    columns: dict[str, np.ndarray] = {}
    names: dict[str, list[str]] = {}
    views = dict(getattr(type(result), "views", {}))
    read = {view.source for view in views.values()}
    for source in layouts:
        if source not in read:
            views[source] = View(source)
    for name, view in views.items():
        columns[name] = view.of(motion)
        names[name] = list(view.names(layouts[view.source]))
    skip = {"states", "accel", *_TRUST_COLUMNS}
    for f in fields(result):
        value = getattr(result, f.name)
        if value is None or f.name in skip or f.name in columns or is_dataclass(value):
            continue  # a verdict (a robot's execution check) is no column: .npz files keep it through save()
        columns[f.name] = value
        k = np.shape(motion.states)[-2]
        if np.ndim(value) == np.ndim(motion.states) - 1 and np.shape(value)[-1] in (k, k - 1):  # psi, violation
            names[f.name] = [f.name]
    if result.uncertainty is not None and uncertainty_names is not None:
        columns["uncertainty"] = result.uncertainty
        names["uncertainty"] = [f"std.{n}" for n in uncertainty_names]
    for key, value in (result.errors or {}).items():
        columns[f"errors.{key}"] = np.asarray(value)
    if result.out_of_distribution is not None:
        columns["out_of_distribution"] = np.asarray(result.out_of_distribution)
    for key, value in (result.physics.to_dict() if result.physics is not None else {}).items():
        columns[f"physics.{key}"] = np.asarray(value)
    return columns, names


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


