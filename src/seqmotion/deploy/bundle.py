"""An exported bundle's ``contract.json``: its schema, its seal, and reading a bundle safely.

``export-onnx`` writes OUT/ whole (see :mod:`seqmotion.deploy.export`); this module is what the
runner trusts of it, and it is copied beside the graphs (standard library only), so the
standalone runner checks the same things.

**The schema** (:data:`FIELDS`, then :func:`_check_relations`): every field the runner reads,
with its type and range — counts are integers ≥ 1, times and limits finite and > 0, layouts
lists of names with one unit each, the dynamics' physics a list of field names, the ones its
graph reads among them and a finite value for each, ``stop.outputs`` with the ``outputs_for`` graph
when it names it (a contract from before that field is read as ``"accelerations"`` only where the
outputs' units say so: :func:`_check_stop_outputs`), and each graph in ``files`` a plain file
name ending in ``.onnx`` (no folder, not absolute, no ``..``) of a file inside the bundle.
Fields the runner does not read (``semantics``, ``graphs``, ``model``, …) are only covered by
the seal.

**The seal.** ``sha256`` holds the SHA-256 of each graph file (keyed like ``files``) and
``contract_sha256`` that of the contract itself: of its canonical JSON (sorted keys, separators
``","`` and ``":"``) without ``contract_sha256``. :func:`read_contract` verifies the seal before
the schema (an edited contract is reported as edited), and :func:`read_graphs` reads each graph
once and checks its hash, so onnxruntime loads the very bytes that were checked. A bundle without
a seal (exported before it existed), or of another format (one exported before the dynamics
were a graph of the bundle), is refused with the advice to re-export it.

The seal detects accidents — a partial write, a damaged file, two exports mixed — not intent:
anyone who can write the folder can re-seal it (:func:`seal`). So loading also checks what a
re-sealed bundle could hide, and bounds the damage of one that passes:

* **Each graph** is scanned before onnxruntime sees it (:func:`check_graph`, standard library
  only): at most :data:`MAX_GRAPH_BYTES`; parsable; only the op types the exporter writes
  (:data:`GRAPH_OPS`: no ``Loop``, no custom domains or functions); no external or sparse data;
  no tensor declaring more elements than its file has bytes; no constant shape (of
  ``ConstantOfShape``, ``Expand``, ``Tile``, ``Pad``, ``Range``) beyond :data:`MAX_CONSTANT_ELEMENTS`.
* **Its inputs and outputs** are the contract's: names, dtypes, ranks and static dimensions
  (:func:`graph_interface`, :func:`check_interface`).
* **The runner** (``onnx_stepper.py``) runs the sessions in an arena capped at
  :data:`MAX_RUN_BYTES` without onnxruntime's load-time constant folding (which allocates up to
  1 GB outside any cap), wraps onnxruntime's errors into ``ValueError`` naming the file, and
  refuses an output of the wrong shape or with NaN or inf.
* **Physics overrides** are checked against ``physics_ranges``: the ranges and orderings of the
  fields the dynamics graph reads, read off the task's physics class at export
  (:func:`check_physics`, the one check of both the package and the standalone runner).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import struct
import warnings
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

try:  # inside the seqmotion package
    from ..core.stepper import CLOSED_FORMS, CONTRACT_FORMAT, STOP_OUTPUTS, outputs_are_accelerations
except ImportError:  # the standalone copy beside the graphs
    from stepper import (  # type: ignore[no-redef]
        CLOSED_FORMS,
        CONTRACT_FORMAT,
        STOP_OUTPUTS,
        outputs_are_accelerations,
    )

CONTRACT = "contract.json"
SEAL = "contract_sha256"
"""The contract's own hash (of its canonical JSON without this key)."""
HASHES = "sha256"
"""The graphs' hashes, keyed like ``files``."""
GRAPHS = ("encoder", "decoder_step", "dynamics", "violation", "decoder_step_int8", "outputs_for",
          "dynamics_sample")
"""The keys of ``files`` a bundle may have (``violation`` may be null; ``decoder_step_int8``, ``outputs_for`` and
``dynamics_sample`` absent)."""
OPTIONAL_GRAPHS = ("decoder_step_int8", "outputs_for", "dynamics_sample")
"""Graphs a bundle may lack; where the key is there, the file must be."""
MAX_CONTRACT_BYTES = 2**20
"""A ``contract.json`` larger than this (exported ones are ~10 kB) is refused before it is parsed."""
MAX_GRAPH_BYTES = 2**28
"""A graph file larger than this is refused before it is read (exported graphs are kB to tens of MB)."""
MAX_CONSTANT_ELEMENTS = 2**24
"""The most elements a constant shape in a graph may ask for (exported graphs' constant shapes are a few dozen)."""
MAX_RUN_BYTES = 2**31
"""What the runner's sessions may hold at once (their shared onnxruntime arena's cap)."""
MAX_GRAPH_DEPTH = 8
"""How deeply graphs may nest (a Scan's body is one level; the exporter writes two)."""
RANGES = "physics_ranges"
"""The ranges and orderings of the physics fields the dynamics graph reads (:func:`check_physics`)."""
PREVIOUS = ".previous"
"""Where ``export-onnx`` sets the old bundle aside while it swaps a new one in: ``.<OUT name>.previous``."""

Check = tuple[Callable[[Any], bool], str]
"""A field's test and what it must be, in words (for the error message)."""


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_real(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def is_plain_graph_name(name: Any) -> bool:
    """Whether ``name`` is a file name in the bundle folder itself: no separator, not ``.``/``..``, ``*.onnx``."""
    return (isinstance(name, str) and name.endswith(".onnx") and not any(c in name for c in "/\\:\0")
            and name.strip() == name)


OBJECT: Check = (lambda v: isinstance(v, dict), "an object")
TEXT: Check = (lambda v: isinstance(v, str) and v != "", "a non-empty string")
FLAG: Check = (lambda v: isinstance(v, bool), "true or false")
COUNT: Check = (lambda v: _is_int(v) and v >= 1, "an integer >= 1")
POSITIVE: Check = (lambda v: _is_real(v) and v > 0, "a finite number > 0")
NON_NEGATIVE: Check = (lambda v: _is_real(v) and v >= 0, "a finite number >= 0")
FRACTION: Check = (lambda v: _is_real(v) and 0 < v <= 1, "a number in (0, 1]")
INDEX: Check = (lambda v: _is_int(v) and v >= 0, "an integer >= 0")
NAMES: Check = (lambda v: isinstance(v, list) and len(v) > 0 and all(isinstance(x, str) for x in v),
                "a non-empty list of strings")
FIELD_NAMES: Check = (lambda v: isinstance(v, list) and all(isinstance(x, str) and x.isidentifier() for x in v)
                      and len(set(v)) == len(v), "a list of distinct field names (possibly empty)")
DIGEST: Check = (lambda v: isinstance(v, str) and len(v) == 64 and all(c in "0123456789abcdef" for c in v),
                 "a SHA-256 hex digest (64 lowercase hex digits)")
GRAPH: Check = (is_plain_graph_name, "a plain file name ending in .onnx (no folder, not absolute, no '..')")


def optional(check: Check) -> Check:
    return (lambda v: v is None or check[0](v), f"null or {check[1]}")


def list_of(check: Check) -> Check:
    return (lambda v: isinstance(v, list) and len(v) > 0 and all(check[0](x) for x in v),
            f"a non-empty list, each {check[1]}")


LAYOUTS = ("state_layout", "accel_layout", "input_layout")
FIELDS: dict[str, Check] = {  # in order: a parent object before its fields
    "task": TEXT,
    "chunk": COUNT,  # C, samples per decoder step
    "dt": POSITIVE,  # [s]
    "layers": COUNT,
    "hidden": COUNT,
    "latent_dim": COUNT,
    **{f"{layout}{key}": check for layout in LAYOUTS
       for key, check in (("", OBJECT), (".kind", TEXT), (".names", NAMES), (".units", NAMES))},
    "velocity_columns": optional(list_of(INDEX)),
    "constraint": FLAG,
    "default_length": optional((lambda v: _is_int(v) and v >= 2, "an integer >= 2")),
    "dynamics": OBJECT,
    "dynamics.graph": GRAPH,
    "dynamics.dt": POSITIVE,  # [s]
    "dynamics.chunk": COUNT,
    "dynamics.physics": OBJECT,
    "dynamics.physics.class": TEXT,
    "dynamics.physics.names": FIELD_NAMES,  # every field of the task's physics, in order
    "dynamics.physics.inputs": FIELD_NAMES,  # those the graph reads (its ``physics`` input, in this order)
    "dynamics.physics.values": OBJECT,  # the default of each field
    "dynamics.closed_form": optional((lambda v: v in CLOSED_FORMS, f"one of {list(CLOSED_FORMS)}")),
    "stop": OBJECT,
    "stop.tau": POSITIVE,  # [s]
    "stop.shrink": list_of(FRACTION),
    "stop.accel_limit": list_of(POSITIVE),  # per velocity column, in its unit per second (m/s², rad/s²)
    "stop.rest_velocity": NON_NEGATIVE,
    "stop.violation_tolerance": NON_NEGATIVE,
    "files": OBJECT,
    "files.encoder": GRAPH,
    "files.decoder_step": GRAPH,
    "files.dynamics": GRAPH,
    "files.violation": optional(GRAPH),
    HASHES: OBJECT,
    SEAL: DIGEST,
}
"""Every field the runner reads, with what it must be (a dotted name is a field of an object)."""

_MISSING = object()


def _get(contract: dict, field: str) -> Any:
    value: Any = contract
    for key in field.split("."):
        value = value.get(key, _MISSING)  # parents were checked to be objects first
        if value is _MISSING:
            break
    return value


def _format_message(where: str, found: Any, directory: str | Path | None = None) -> str:
    """Why a contract of another format is refused, and what to do."""
    folder = directory if directory is not None else "OUT"
    return (f"{where} has format {found!r}; this runner reads {CONTRACT_FORMAT!r}: the bundle was exported by "
            f"another seqmotion (before {CONTRACT_FORMAT!r}, the dynamics were not a graph of the bundle); "
            f"re-export the model: seqmotion export-onnx MODEL {folder}")


def canonical_json(data: Any) -> bytes:
    """The bytes the contract's hash is taken of: sorted keys, no spaces (the same form as
    ``seqmotion.training.checkpoint.canonical_json``, repeated here because this file runs without seqmotion)."""
    return json.dumps(data, sort_keys=True, separators=(",", ":")).encode()


def contract_digest(contract: dict) -> str:
    """SHA-256 of ``contract``'s canonical JSON without its ``contract_sha256``."""
    return hashlib.sha256(canonical_json({k: v for k, v in contract.items() if k != SEAL})).hexdigest()


def seal(contract: dict, graphs: dict[str, bytes]) -> dict:
    """``contract`` with the hash of each graph (``graphs``: key of ``files`` → the file's bytes) and its own hash.

    The self-hash is taken of the contract as JSON will give it back (tuples as lists), so that
    what a reader parses hashes the same.
    """
    sealed = json.loads(json.dumps({k: v for k, v in contract.items() if k not in (HASHES, SEAL)}))
    sealed[HASHES] = {key: hashlib.sha256(data).hexdigest() for key, data in graphs.items()}
    sealed[SEAL] = contract_digest(sealed)
    return sealed


def check_contract(contract: Any, where: str) -> None:
    """Check ``contract`` against the schema (module docstring); ``where`` names it in the errors.

    Raises:
        ValueError: the first field that is missing or wrong, by its dotted name.
    """
    if not isinstance(contract, dict):
        raise ValueError(f"{where} must hold a JSON object, got {type(contract).__name__}")
    if contract.get("format") != CONTRACT_FORMAT:
        raise ValueError(_format_message(where, contract.get("format")))
    fields = dict(FIELDS)
    for key in OPTIONAL_GRAPHS:
        if isinstance(contract.get("files"), dict) and key in contract["files"]:
            fields[f"files.{key}"] = GRAPH
    for field, (ok, what) in fields.items():
        value = _get(contract, field)
        if value is _MISSING:
            raise ValueError(f"{where} lacks the field {field!r} ({what})")
        if not ok(value):
            raise ValueError(f"{where}: field {field!r} must be {what}, got {value!r}")
    _check_relations(contract, where)


def _check_relations(c: dict, where: str) -> None:
    """What the fields must agree on (each field alone is already of its type and range)."""

    def fail(message: str) -> None:
        raise ValueError(f"{where}: {message}")

    if c["latent_dim"] != c["layers"] * c["hidden"]:
        fail(f"field 'latent_dim' ({c['latent_dim']}) must be layers * hidden = {c['layers'] * c['hidden']}")
    for layout in LAYOUTS:
        if len(c[layout]["units"]) != len(c[layout]["names"]):
            fail(f"field '{layout}.units' must hold one unit per name ({len(c[layout]['names'])}), "
                 f"got {len(c[layout]['units'])}")
    dynamics, files = c["dynamics"], c["files"]
    if dynamics["dt"] != c["dt"]:
        fail(f"field 'dynamics.dt' ({dynamics['dt']}) differs from 'dt' ({c['dt']}): one time step per sample")
    if dynamics["chunk"] != c["chunk"]:
        fail(f"field 'dynamics.chunk' ({dynamics['chunk']}) differs from 'chunk' ({c['chunk']}): the dynamics graph "
             "runs one decoder chunk")
    if dynamics["graph"] != files["dynamics"]:
        fail(f"field 'dynamics.graph' ({dynamics['graph']!r}) differs from 'files.dynamics' ({files['dynamics']!r})")
    physics = dynamics["physics"]
    names, inputs, values = physics["names"], physics["inputs"], physics["values"]
    if [n for n in names if n in inputs] != inputs:
        fail(f"field 'dynamics.physics.inputs' ({inputs}) must be fields of 'dynamics.physics.names' ({names}), "
             "in their order")
    if set(values) != set(names):
        fail(f"field 'dynamics.physics.values' must hold one value for each of {names}, got {sorted(values)}")
    for name, value in values.items():
        if not _is_real(value):
            fail(f"field 'dynamics.physics.values.{name}' must be a finite number, got {value!r}")
    s, d = len(c["state_layout"]["names"]), len(c["accel_layout"]["names"])
    if dynamics["closed_form"] == "double_integrator" and (2 * d != s or inputs):
        fail(f"field 'dynamics.closed_form' names the double integrator, which has 2 states per output and reads no "
             f"physics: not {s} states for {d} outputs reading {inputs}")
    if len(c["stop"]["accel_limit"]) != d:
        fail(f"field 'stop.accel_limit' must hold {d} limits (one per output), got {len(c['stop']['accel_limit'])}")
    velocity = c["velocity_columns"]
    if velocity is not None and (len(velocity) != d or len(set(velocity)) != d or max(velocity) >= s):
        fail(f"field 'velocity_columns' must be null or {d} distinct state columns below {s}, got {velocity}")
    _check_stop_outputs(c, fail)
    _check_ranges(c, fail)
    for key in files:
        if key not in GRAPHS:
            fail(f"field 'files.{key}' is not a graph of the bundle (known: {', '.join(GRAPHS)})")
    if c["constraint"] != (files["violation"] is not None):
        fail(f"field 'constraint' is {str(c['constraint']).lower()} but 'files.violation' is "
             f"{'null' if files['violation'] is None else repr(files['violation'])}")
    named = {key for key, name in files.items() if name is not None}
    if set(c[HASHES]) != named:
        fail(f"field 'sha256' must hold a hash for each graph ({', '.join(sorted(named))}), "
             f"got {', '.join(sorted(c[HASHES])) or 'none'}")
    for key, value in c[HASHES].items():
        if not DIGEST[0](value):
            fail(f"field 'sha256.{key}' must be {DIGEST[1]}, got {value!r}")


def _check_stop_outputs(c: dict, fail: Callable[[str], None]) -> None:
    """``stop.outputs`` names how the stop makes its outputs, with the graph it needs; a contract without the
    field (exported before it) is read as ``"accelerations"`` only where the outputs' units are the velocity
    columns' per second (m/s² of m/s): a torque task's bundle from then would apply accelerations as torques."""
    stop, files, velocity = c["stop"], c["files"], c["velocity_columns"]
    state_units, accel_units = c["state_layout"]["units"], c["accel_layout"]["units"]
    if "outputs" not in stop:
        if velocity is not None and not outputs_are_accelerations(state_units, accel_units, velocity):
            fail(f"field 'stop.outputs' is missing and the outputs ({', '.join(accel_units)}) are not accelerations "
                 "of the velocity columns: the bundle was exported before the stop went through the task's "
                 "dynamics, and its stop would apply accelerations as outputs; re-export the model: seqmotion "
                 "export-onnx MODEL OUT")
        outputs = "accelerations"
    else:
        outputs = stop["outputs"]
        if outputs is not None and outputs not in STOP_OUTPUTS:
            fail(f"field 'stop.outputs' must be null or one of {list(STOP_OUTPUTS)}, got {outputs!r}")
    if outputs == "accelerations" and velocity is not None and not outputs_are_accelerations(
            state_units, accel_units, velocity):
        fail(f"field 'stop.outputs' is 'accelerations' but the outputs ({', '.join(accel_units)}) are not "
             "the velocity columns' units per second")
    graph = files.get("outputs_for")
    if (outputs == "outputs_for") != (graph is not None):
        fail(f"field 'stop.outputs' is {outputs!r} but 'files.outputs_for' is "
             f"{'absent' if graph is None else repr(graph)}: the outputs_for graph goes with 'outputs_for'")


BOUNDS = {"above": ">", "at_least": ">=", "below": "<", "at_most": "<="}
"""The bounds a field of ``physics_ranges`` may have, and how a message writes them."""


def _check_ranges(c: dict, fail: Callable[[str], None]) -> None:
    """``physics_ranges``, where the contract has it (a bundle exported before it has none: it runs at its own
    physics only): null (the physics class's rules are not ranges: the same) or ``{"fields": {name: {bound: value}},
    "order": [[a, b], ...]}`` (``a <= b``) over the fields the graph reads, which the contract's values satisfy."""
    if RANGES not in c or c[RANGES] is None:
        return
    ranges, inputs = c[RANGES], c["dynamics"]["physics"]["inputs"]
    if not isinstance(ranges, dict) or set(ranges) != {"fields", "order"} or not isinstance(ranges["fields"], dict) \
            or not isinstance(ranges["order"], list):
        fail(f"field '{RANGES}' must be null or an object of 'fields' and 'order', got {ranges!r}")
    for name, bounds in ranges["fields"].items():
        if name not in inputs:
            fail(f"field '{RANGES}.fields.{name}' is not a physics input of the dynamics graph ({inputs})")
        if not isinstance(bounds, dict) or not bounds or not set(bounds) <= set(BOUNDS) \
                or not all(_is_real(v) for v in bounds.values()) or {"above", "at_least"} <= set(bounds) \
                or {"below", "at_most"} <= set(bounds):
            fail(f"field '{RANGES}.fields.{name}' must map at most one lower and one upper bound of "
                 f"{list(BOUNDS)} to finite numbers, got {bounds!r}")
    for pair in ranges["order"]:
        if not (isinstance(pair, list) and len(pair) == 2 and pair[0] != pair[1] and set(pair) <= set(inputs)):
            fail(f"field '{RANGES}.order' must hold pairs of distinct physics inputs ({inputs}), got {pair!r}")
    values = c["dynamics"]["physics"]["values"]
    wrong = physics_violation(ranges, {name: values[name] for name in inputs})
    if wrong is not None:
        fail(f"field 'dynamics.physics.values' breaks its own '{RANGES}': {wrong}")


def physics_violation(ranges: dict, values: Mapping[str, float]) -> str | None:
    """Why ``values`` (every physics input → a finite number) break ``ranges`` (``physics_ranges``), or None."""
    for name, bounds in ranges["fields"].items():
        value = values[name]
        for bound, limit in bounds.items():
            held = {"above": value > limit, "at_least": value >= limit, "below": value < limit,
                    "at_most": value <= limit}[bound]
            if not held:
                return f"physics {name} = {value!r} must be {BOUNDS[bound]} {limit!r}"
    for small, large in ranges["order"]:
        if not values[small] <= values[large]:
            return (f"physics must satisfy {small} <= {large}, got {small} = {values[small]!r}, "
                    f"{large} = {values[large]!r}")
    return None


def check_physics(contract: dict, overrides: Mapping[str, float], where: str) -> None:
    """Refuse ``overrides`` (physics input → a finite number) that the bundle's physics class would refuse: the one
    check of both runners (the standalone copy has no physics classes; the contract carries their ranges).

    Raises:
        ValueError: naming ``where`` (the contract) and the field: out of its range, out of order with another,
            or any override of a bundle whose contract records no ranges (exported before them: re-export), or
            whose physics class's rules are not ranges (null: export at the physics needed).
    """
    if not overrides:
        return
    physics = contract["dynamics"]["physics"]
    if RANGES not in contract:
        raise ValueError(f"{where} records no '{RANGES}' (it was exported before the contract carried them), so "
                         f"physics {sorted(overrides)} cannot be checked: it runs at its own physics only; re-export "
                         "the model to run it at others")
    if contract[RANGES] is None:
        raise ValueError(f"{where}: the rules of {physics['class']} are not ranges of its fields ('{RANGES}' is "
                         f"null), so physics {sorted(overrides)} cannot be checked: the bundle runs at its own "
                         "physics only; export at the physics needed (export_onnx(model, OUT, physics=...))")
    values = {name: float(physics["values"][name]) for name in physics["inputs"]}
    values.update(overrides)
    wrong = physics_violation(contract[RANGES], values)
    if wrong is not None:
        kind = physics["class"].rsplit(".", 1)[-1]
        raise ValueError(f"{where}: {wrong} (the ranges the contract records for {kind})")


def previous_path(directory: str | Path) -> Path:
    """Where an export sets the bundle at ``directory`` aside while it swaps the new one in."""
    # absolute and normalised first: "." or "dir/.." (a runner started inside the bundle) has no name of its own
    directory = Path(os.path.abspath(directory))
    return directory.with_name(f".{directory.name}{PREVIOUS}")


def locate(directory: str | Path) -> Path:
    """The bundle folder to read for ``directory``: itself, or — when it is missing because an export was
    killed between setting the old bundle aside and renaming the new one in — the old bundle, set aside."""
    directory = Path(os.path.abspath(directory))  # "." names no folder to find a sibling of
    aside = previous_path(directory)
    if not directory.exists() and (aside / CONTRACT).is_file():
        warnings.warn(f"{directory} is missing: an export into it was interrupted; loading the previous bundle "
                      f"from {aside} (the next export puts it back in place)", stacklevel=3)
        return aside
    return directory


def read_contract(directory: str | Path) -> dict[str, Any]:
    """The verified contract of the bundle in ``directory``: parsed, sealed, unedited, and valid.

    Raises:
        ValueError: no contract, too large, not JSON or not an object, another format, no seal (a
            bundle from before the seal: re-export it), edited after export, or a field the schema refuses.
    """
    directory = Path(directory)
    path = directory / CONTRACT
    # A standalone copy of seqmotion.io.read_json (size cap, UTF-8 JSON, an object at the top): this file ships
    # inside every bundle, whose runner works without seqmotion installed. A NaN or an infinity is refused below
    # by the schema (check_contract), which names its field.
    try:
        size = path.stat().st_size
        if size > MAX_CONTRACT_BYTES:
            raise ValueError(f"{path} is {size} bytes, larger than any contract ({MAX_CONTRACT_BYTES})")
        data = path.read_bytes()
    except FileNotFoundError:
        raise ValueError(f"{directory} holds no exported model (no {CONTRACT})") from None
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    try:
        contract = json.loads(data)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise ValueError(f"{path} is not valid JSON: {exc}") from None
    if not isinstance(contract, dict):
        raise ValueError(f"{path} must hold a JSON object, got {type(contract).__name__}")
    if contract.get("format") != CONTRACT_FORMAT:
        raise ValueError(_format_message(str(path), contract.get("format"), directory))
    if SEAL not in contract:
        raise ValueError(f"{path} is not sealed (no {SEAL}): it was exported by an older seqmotion, which did not "
                         f"record the graphs' hashes; re-export the model: seqmotion export-onnx MODEL {directory}")
    if contract[SEAL] != contract_digest(contract):
        raise ValueError(f"{path} was edited after export (its contents do not match its {SEAL}); re-export the "
                         "model instead of editing the contract")
    check_contract(contract, str(path))
    return contract


def read_graphs(directory: str | Path, contract: dict[str, Any]) -> dict[str, bytes]:
    """The bytes of every graph ``contract`` names (key of ``files`` → bytes), each checked against its hash.

    Raises:
        ValueError: a graph that is missing, resolves outside the bundle (a link), is larger than
            :data:`MAX_GRAPH_BYTES`, does not match its hash, or holds what the exporter never writes
            (:func:`check_graph`).
    """
    directory = Path(directory)
    root = directory.resolve()
    graphs = {}
    for key, name in contract["files"].items():
        if name is None:
            continue
        path = directory / name  # a plain file name (the schema): in the folder itself
        if not path.exists():
            raise ValueError(f"{path} ({key}) is missing from the bundle; re-export the model")
        if path.resolve().parent != root:  # a link in the bundle to a file elsewhere
            raise ValueError(f"{path} ({key}) resolves outside the bundle ({path.resolve()}): refused")
        if not path.is_file():  # a fifo or device would block or never end
            raise ValueError(f"{path} ({key}) is not a regular file")
        try:
            size = path.stat().st_size
            if size > MAX_GRAPH_BYTES:  # before reading: the hash would have to read it all
                raise ValueError(f"{path} ({key}) is {size} bytes, larger than any graph the exporter writes "
                                 f"({MAX_GRAPH_BYTES}): refused")
            data = path.read_bytes()
        except OSError as exc:
            raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
        if hashlib.sha256(data).hexdigest() != contract[HASHES][key]:
            raise ValueError(f"{path} does not match its hash in {CONTRACT}: the file was replaced or damaged "
                             "after export (or the bundle mixes two exports); re-export the model")
        check_graph(data, f"{path} ({key})")  # the seal holds for anyone who re-seals: the graph itself is checked
        graphs[key] = data
    return graphs


# --- what a graph may be -----------------------------------------------------------------------------------
# The standalone runner has no onnx package, and onnxruntime lists no nodes: the scan reads ONNX's protobuf wire
# format itself, only the few fields it needs (onnx.proto: ModelProto, GraphProto, NodeProto, AttributeProto,
# TensorProto), and refuses whatever it cannot read.

GRAPH_OPS = frozenset("""
    Abs Acos Acosh Add And Asin Asinh Atan Atanh BitwiseAnd BitwiseNot BitwiseOr BitwiseXor Ceil Celu Clip Cos
    Cosh Div Elu Equal Erf Exp Floor Greater GreaterOrEqual HardSigmoid HardSwish IsInf IsNaN LeakyRelu Less
    LessOrEqual Log Max Mean Min Mod Mul Neg Not Or Pow PRelu Reciprocal Relu Round Selu Sigmoid Sign Sin Sinh
    Softplus Softsign Sqrt Sub Sum Tan Tanh Where Xor
    Cast CastLike Concat Constant ConstantOfShape Expand Flatten Gather GatherElements GatherND Identity NonZero Pad
    Range Reshape ScatterElements ScatterND Shape Size Slice Split Squeeze Tile Transpose Trilu Unsqueeze
    ArgMax ArgMin CumSum LogSoftmax ReduceL1 ReduceL2 ReduceLogSum ReduceLogSumExp ReduceMax ReduceMean ReduceMin
    ReduceProd ReduceSum ReduceSumSquare Softmax TopK
    BatchNormalization Einsum Gemm InstanceNormalization LayerNormalization MatMul MatMulInteger
    DynamicQuantizeLinear QuantizeLinear DequantizeLinear
    If Scan
    """.split())
"""The op types a graph may hold: those the exporter writes (the LN-LSTM steps, traced dynamics and constraints,
onnxruntime's int8 quantisation) and the arithmetic, shape and reduction ops traced torch code becomes. Not
``Loop`` (its trip count is a number in the graph: 2⁶² iterations hang the runner), random ops, custom domains."""
SHAPE_INPUTS = {"ConstantOfShape": 0, "Expand": 1, "Tile": 1, "Pad": 1}
"""Ops whose output size an input sets (by its index): a constant one is bounded by :data:`MAX_CONSTANT_ELEMENTS`."""
_SMALL = 64
"""Constant tensors of at most this many elements are read (a shape is a few numbers; weights are never needed)."""
_DTYPES = {1: ("<f", 4), 6: ("<i", 4), 7: ("<q", 8), 11: ("<d", 8)}
"""TensorProto data types read as numbers: FLOAT, INT32, INT64, DOUBLE (struct format, size)."""


class _Unreadable(Exception):
    """The bytes are not the protobuf the scan expects."""


def _varint(buf: memoryview, i: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        if i >= len(buf) or shift > 63:
            raise _Unreadable("a truncated or overlong number")
        byte = buf[i]
        i += 1
        result |= (byte & 0x7F) << shift
        if byte < 0x80:
            return result, i
        shift += 7


def _fields(buf: memoryview) -> Iterator[tuple[int, int, Any]]:
    """``(field number, wire type, value)`` of a protobuf message: an int (varint), or the bytes (the others)."""
    i, n = 0, len(buf)
    while i < n:
        key, i = _varint(buf, i)
        field, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(buf, i)
        elif wire == 2:
            size, i = _varint(buf, i)
            value, i = buf[i:i + size], i + size
        elif wire in (1, 5):
            width = 8 if wire == 1 else 4
            value, i = buf[i:i + width], i + width
        else:
            raise _Unreadable(f"a field of wire type {wire}")
        if i > n or field == 0:
            raise _Unreadable("a truncated field")
        yield field, wire, value


def _signed(value: int) -> int:
    return value - (1 << 64) if value >= 1 << 63 else value


def _ints(wire: int, value: Any) -> list[int]:
    """A repeated int64 field's entries: one (unpacked) or all of a packed run."""
    if wire == 0:
        return [_signed(value)]
    if wire != 2:
        raise _Unreadable("an integer of the wrong wire type")
    out, i = [], 0
    while i < len(value):
        number, i = _varint(value, i)
        out.append(_signed(number))
    return out


def _text(value: Any) -> str:
    return bytes(value).decode("utf-8", "replace") if isinstance(value, memoryview) else ""


class _GraphScan:
    """One graph file's scan (:func:`check_graph`); raises ValueError naming ``where`` and the node."""

    def __init__(self, where: str, size: int) -> None:
        self.where, self.size = where, size

    def refuse(self, why: str) -> None:
        raise ValueError(f"{self.where}: {why}: refused (the runner loads only the ops and sizes the exporter "
                         "writes: bundle.GRAPH_OPS, MAX_CONSTANT_ELEMENTS)")

    def model(self, buf: memoryview) -> None:
        graphs = 0
        for field, wire, value in _fields(buf):
            if field == 7 and wire == 2:
                graphs += 1
                self.graph(value, {}, 0)
            elif field == 25:
                self.refuse("it defines functions (local operators)")
        if graphs != 1:
            raise _Unreadable(f"{graphs} graphs in the model")

    def graph(self, buf: memoryview, outer: dict[str, list[float]], depth: int) -> None:
        if depth > MAX_GRAPH_DEPTH:
            self.refuse(f"graphs nest deeper than {MAX_GRAPH_DEPTH}")
        constants = dict(outer)  # a subgraph reads its outer scope's names
        nodes = []
        for field, wire, value in _fields(buf):
            if wire != 2:
                continue
            if field == 1:
                nodes.append(value)
            elif field == 5:
                name, numbers = self.tensor(value)
                if numbers is not None:
                    constants[name] = numbers
            elif field == 15:
                self.refuse("it has a sparse initializer")
        for node in nodes:
            self.node(node, constants, depth)

    def node(self, buf: memoryview, constants: dict[str, list[float]], depth: int) -> None:
        inputs, outputs, op, domain, attributes = [], [], "", "", []
        for field, wire, value in _fields(buf):
            if field == 1:
                inputs.append(_text(value))
            elif field == 2:
                outputs.append(_text(value))
            elif field == 4:
                op = _text(value)
            elif field == 7:
                domain = _text(value)
            elif field == 5 and wire == 2:
                attributes.append(value)
        if domain not in ("", "ai.onnx") or op not in GRAPH_OPS:
            self.refuse(f"node {outputs[:1]} is a {domain + '.' if domain else ''}{op or '(no op type)'}")
        for attribute in attributes:
            self.attribute(attribute, op, outputs, constants, depth)
        index = SHAPE_INPUTS.get(op)
        if index is not None and index < len(inputs) and inputs[index] in constants:
            numbers = constants[inputs[index]]
            count = math.prod(abs(v) for v in numbers) if op != "Pad" else sum(abs(v) for v in numbers)
            # "not <=": a NaN in a float constant compares False both ways, and is refused too
            if not (count <= MAX_CONSTANT_ELEMENTS and all(abs(v) <= MAX_CONSTANT_ELEMENTS for v in numbers)):
                self.refuse(f"the {op} node {outputs[:1]} asks for {numbers} (at most {MAX_CONSTANT_ELEMENTS} "
                            "elements)")
        if op == "Range" and len(inputs) == 3 and all(name in constants for name in inputs):
            (start,), (limit,), (delta,) = (constants[name][:1] or [0.0] for name in inputs)
            count = (limit - start) / delta if delta else math.inf
            if not count <= MAX_CONSTANT_ELEMENTS:
                self.refuse(f"the Range node {outputs[:1]} asks for {count} elements (at most "
                            f"{MAX_CONSTANT_ELEMENTS})")

    def attribute(self, buf: memoryview, op: str, outputs: list[str], constants: dict[str, list[float]],
                  depth: int) -> None:
        name, ints, single = "", [], None
        for field, wire, value in _fields(buf):
            if field == 1:
                name = _text(value)
            elif field in (5, 10) and wire == 2:  # a tensor (t, tensors)
                _, numbers = self.tensor(value)
                if op == "Constant" and field == 5 and numbers is not None and outputs:
                    constants[outputs[0]] = numbers
            elif field in (6, 11) and wire == 2:  # a graph (g, graphs): a Scan's or an If's body
                self.graph(value, constants, depth + 1)
            elif field in (22, 23):
                self.refuse(f"node {outputs[:1]} holds a sparse tensor")
            elif field == 8:
                ints.extend(_ints(wire, value))
            elif field == 3 and wire == 0:
                single = _signed(value)
        if op == "Constant" and outputs and name in ("value_ints", "value_int"):
            constants[outputs[0]] = ints if name == "value_ints" else [single or 0]

    def tensor(self, buf: memoryview) -> tuple[str, list[float] | None]:
        """A tensor's name and, for a small numeric one, its numbers; refuses data outside the file and a tensor
        declaring more elements than the file has bytes (each element takes at least one)."""
        name, dims, dtype, raw, typed = "", [], 0, None, []
        for field, wire, value in _fields(buf):
            if field == 1:
                dims.extend(_ints(wire, value))
            elif field == 2 and wire == 0:
                dtype = value
            elif field == 8:
                name = _text(value)
            elif field == 9 and wire == 2:
                raw = bytes(value)
            elif field in (4, 5, 7, 10):  # float_data, int32_data, int64_data, double_data
                typed.append((field, wire, value))
            elif field in (3, 13) or (field == 14 and value != 0):
                self.refuse(f"tensor {name!r} keeps its data outside the file (or in segments)")
        if any(d < 0 for d in dims):
            raise _Unreadable(f"tensor {name!r} has a negative dimension")
        count = math.prod(dims)
        if count > self.size:
            self.refuse(f"tensor {name!r} declares {dims} ({count} elements) in a file of {self.size} bytes")
        if count > _SMALL or dtype not in _DTYPES:
            return name, None
        code, width = _DTYPES[dtype]
        if raw is not None:
            if len(raw) != count * width:
                raise _Unreadable(f"tensor {name!r} holds {len(raw)} bytes for {count} elements")
            return name, list(struct.unpack(f"<{count}{code[1]}", raw))
        numbers: list[float] = []
        for field, wire, value in typed:
            if field in (5, 7):  # int32 as well as int64 entries are varints, negatives sign-extended to 64 bits
                numbers.extend(_ints(wire, value))
            else:
                data = bytes(value)
                width = 4 if field == 4 else 8
                if wire != 2 or len(data) % width:
                    raise _Unreadable(f"tensor {name!r} has a malformed list of numbers")
                numbers.extend(v for (v,) in struct.iter_unpack("<f" if field == 4 else "<d", data))
        return name, numbers if len(numbers) == count else None


def check_graph(data: bytes, where: str) -> None:
    """Refuse a graph the exporter cannot have written, before onnxruntime reads it (module docstring): ``where``
    names the file in the message.

    Raises:
        ValueError: not parsable, an op type outside :data:`GRAPH_OPS` or of another domain, local functions,
            external, segmented or sparse data, a tensor declaring more elements than the file has bytes, a
            constant shape beyond :data:`MAX_CONSTANT_ELEMENTS`, graphs nested beyond :data:`MAX_GRAPH_DEPTH`.
    """
    try:
        _GraphScan(where, len(data)).model(memoryview(data))
    except _Unreadable as exc:
        raise ValueError(f"{where} is not an ONNX graph ({exc}); re-export the model") from None


# --- what a graph takes and gives ---------------------------------------------------------------------------

FLOAT, DOUBLE = "tensor(float)", "tensor(double)"
Tensor = tuple[tuple[int | None, ...], str]
"""A tensor of the contract: its dimensions (None: any size, the batch or the length) and onnxruntime's type."""


def graph_interface(contract: dict, key: str) -> tuple[dict[str, Tensor], tuple[str, ...], dict[str, Tensor]]:
    """What the graph ``key`` of ``contract``'s bundle takes and gives (``contract["graphs"]`` in words): its
    inputs by name, those it must take (a graph may drop one it does not read), and its outputs, in order."""
    c = contract
    big_l, h, chunk = c["layers"], c["hidden"], c["chunk"]
    s, d, width = len(c["state_layout"]["names"]), len(c["accel_layout"]["names"]), len(c["input_layout"]["names"])
    physics = len(c["dynamics"]["physics"]["inputs"])
    states: Tensor = ((None, chunk, s), DOUBLE)
    rollout = {"x": ((None, s), DOUBLE), "accel": ((None, chunk, d), DOUBLE),
               **({"physics": ((physics,), DOUBLE)} if physics else {})}
    if key == "encoder":
        return ({"chunks": ((None, None, chunk * width), DOUBLE)}, ("chunks",),
                {"z": ((None, big_l * h), FLOAT), "x0": ((None, s), DOUBLE)})
    if key in ("decoder_step", "decoder_step_int8"):
        state: Tensor = ((big_l, None, h), FLOAT)
        return ({"h": state, "c": state, "window": ((None, chunk, s), FLOAT)}, ("h", "c", "window"),
                {"h_out": state, "c_out": state, "accel": ((None, chunk, d), FLOAT)})
    if key == "dynamics":
        return rollout, tuple(rollout), {"states": states}
    if key == "outputs_for":
        return rollout, (), {"outputs": ((None, chunk, d), DOUBLE)}
    if key == "dynamics_sample":  # one sample of the dynamics (a graph may not read every input)
        return {**rollout, "accel": ((None, 1, d), DOUBLE)}, (), {"states": ((None, 1, s), DOUBLE)}
    if key == "violation":
        return ({"states": ((None, None, s), FLOAT), "accel": ((None, None, d), FLOAT)}, (),
                {"violation": ((None, None), FLOAT)})
    raise ValueError(f"no graph {key!r} in a bundle (known: {', '.join(GRAPHS)})")


def check_interface(where: str, expected: tuple[dict[str, Tensor], tuple[str, ...], dict[str, Tensor]],
                    inputs: list[tuple[str, list, str]], outputs: list[tuple[str, list, str]]) -> None:
    """Refuse a graph whose ``inputs``/``outputs`` (name, shape, type, as onnxruntime lists them) are not
    ``expected`` (:func:`graph_interface`): a name it does not know or lacks, another type or rank, or a static
    dimension that differs (a named one is checked when the graph runs).

    Raises:
        ValueError: naming ``where`` (the file) and the tensor.
    """
    takes, required, gives = expected

    def compare(kind: str, name: str, shape: list, dtype: str, tensor: Tensor) -> None:
        dims, want = tensor
        shown = "(" + ", ".join("any" if v is None else str(v) for v in dims) + ")"
        if dtype != want or len(shape) != len(dims) or any(
                isinstance(got, int) and isinstance(v, int) and got != v for got, v in zip(shape, dims, strict=True)):
            raise ValueError(f"{where}: its {kind} {name!r} is {dtype} {tuple(shape)}, the contract's is {want} "
                             f"{shown}: the graph is not this bundle's; re-export the model")

    names = [name for name, _, _ in inputs]
    for name, shape, dtype in inputs:
        if name not in takes:
            raise ValueError(f"{where}: it takes an input {name!r} the contract does not name (it names "
                             f"{list(takes)}): refused")
        compare("input", name, shape, dtype, takes[name])
    missing = [name for name in required if name not in names]
    if missing:
        raise ValueError(f"{where}: it lacks the input {missing[0]!r} the contract names: refused")
    if [name for name, _, _ in outputs] != list(gives):
        raise ValueError(f"{where}: its outputs are {[name for name, _, _ in outputs]}, the contract's "
                         f"{list(gives)}: refused")
    for name, shape, dtype in outputs:
        compare("output", name, shape, dtype, gives[name])


__all__ = ["CONTRACT", "FIELDS", "GRAPH_OPS", "MAX_CONSTANT_ELEMENTS", "MAX_GRAPH_BYTES", "MAX_RUN_BYTES", "RANGES",
           "check_contract", "check_graph", "check_interface", "check_physics", "contract_digest", "graph_interface",
           "is_plain_graph_name", "locate", "physics_violation", "previous_path", "read_contract", "read_graphs",
           "seal"]
