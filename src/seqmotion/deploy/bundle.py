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
"""

from __future__ import annotations

import hashlib
import json
import math
import warnings
from collections.abc import Callable
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
GRAPHS = ("encoder", "decoder_step", "dynamics", "violation", "decoder_step_int8", "outputs_for")
"""The keys of ``files`` a bundle may have (``violation`` may be null; ``decoder_step_int8`` and ``outputs_for``
absent)."""
OPTIONAL_GRAPHS = ("decoder_step_int8", "outputs_for")
"""Graphs a bundle may lack; where the key is there, the file must be."""
MAX_CONTRACT_BYTES = 2**20
"""A ``contract.json`` larger than this (exported ones are ~10 kB) is refused before it is parsed."""
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


def previous_path(directory: str | Path) -> Path:
    """Where an export sets the bundle at ``directory`` aside while it swaps the new one in."""
    directory = Path(directory)
    return directory.with_name(f".{directory.name}{PREVIOUS}")


def locate(directory: str | Path) -> Path:
    """The bundle folder to read for ``directory``: itself, or — when it is missing because an export was
    killed between setting the old bundle aside and renaming the new one in — the old bundle, set aside."""
    directory = Path(directory)
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
    try:
        size = path.stat().st_size
        if size > MAX_CONTRACT_BYTES:
            raise ValueError(f"{path} is {size} bytes, larger than any contract ({MAX_CONTRACT_BYTES})")
        contract = json.loads(path.read_bytes())
    except FileNotFoundError:
        raise ValueError(f"{directory} holds no exported model (no {CONTRACT})") from None
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
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
        ValueError: a graph that is missing, resolves outside the bundle (a link), or does not match its hash.
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
            data = path.read_bytes()
        except OSError as exc:
            raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
        if hashlib.sha256(data).hexdigest() != contract[HASHES][key]:
            raise ValueError(f"{path} does not match its hash in {CONTRACT}: the file was replaced or damaged "
                             "after export (or the bundle mixes two exports); re-export the model")
        graphs[key] = data
    return graphs


__all__ = ["CONTRACT", "FIELDS", "check_contract", "contract_digest", "is_plain_graph_name", "locate",
           "previous_path", "read_contract", "read_graphs", "seal"]
