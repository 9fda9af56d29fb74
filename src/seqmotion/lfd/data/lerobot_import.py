"""Import of LeRobotDataset v3.0 folders as pushing demonstrations, hardened (no ``lerobot`` import needed).

:func:`from_lerobot` reads a LeRobot v3.0 folder (the layout and features :mod:`seqmotion.lfd.data.lerobot` describes
and :func:`~seqmotion.lfd.data.lerobot.to_lerobot` writes, or another robot's dataset through ``mapping``) into a
:class:`~seqmotion.lfd.data.dataset.PushingDataset` (in memory; :func:`import_lerobot` writes it as ``<set>.h5``), so
that ``seqmotion lfd train --data`` takes either. Readers are pyarrow (parquet) and PyAV (mp4), the ``lerobot``
extra.

Import reads a folder as untrusted input (a dataset downloaded from anywhere): nothing outside it is opened,
every size is bounded before it is read or decoded, every value is checked, and anything else is a
``ValueError`` of one line naming the file and the field; :func:`from_lerobot` lists the rules.
"""

from __future__ import annotations

import io
import json
import math
import re
import stat
import string
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from ...errors import MAX_LENGTH, check_json_number, check_number
from .dataset import FORMAT, MAX_MOTION_VALUE, SETS, VERSION, PushingDataset
from .lerobot import ACTION, EFFORT, ENVIRONMENT, IMAGE_SHAPE, INFO_PATH, STATE, WEBCAM, _av, _pyarrow

MAX_META_BYTES = 16 * 2**20
"""The largest ``info.json`` / ``stats.json`` read [bytes]."""
MAX_PARQUET_BYTES = 2**30
"""The most bytes the columns an import reads may take uncompressed, over all data files (each file's footer
says it before a page is read: a parquet file of a few KB can inflate to gigabytes)."""
MAX_TASKS_PER_EPISODE = 1000
"""The most task strings an episode's ``tasks`` may list (LeRobot's episodes have one or a few); the column is
never read, but a file that declares more is refused."""
FPS_RANGE = (1, 10_000)
"""The frame rates [Hz] an import accepts (LeRobot records at 10-50 Hz; seqmotion up to 1 kHz)."""
VIDEO_SLACK_FRAMES = 3
"""How far [frames] a video's timestamps, frame count and duration may go past what its episodes declare
(encoders pad a frame or two)."""
VIDEO_DECODER_DELAY = 32
"""Packets a decoder may take in before it gives out a frame (B-frames, frame threads): the decoding margin."""
MAX_TEMPLATE = 1024
"""The longest path template (``data_path``, ``video_path``) of an ``info.json``."""
BLOCK_POSITIONS = 6
"""How many block positions ``seqmotion/position_index`` numbers (``seqmotion.lfd.env.pushing.POSITIONS``; -1: none):
counted here so that an import needs no simulator."""
SET_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}")
"""A set name: the ``.h5`` file's stem, a plain name (no separator, no ``..``, not hidden)."""

FIELDS = ("master_theta", "master_dtheta", "master_tau", "slave_theta", "slave_dtheta", "slave_tau", "block_pose",
          "image")
"""What :func:`from_lerobot` fills, each from a LeRobot feature (``mapping`` overrides :data:`DEFAULT_MAP`)."""
DEFAULT_MAP = {
    "master_theta": ACTION, "master_dtheta": ACTION, "master_tau": ACTION,
    "slave_theta": STATE, "slave_dtheta": STATE, "slave_tau": EFFORT,
    "block_pose": ENVIRONMENT, "image": WEBCAM,
}
_QUANTITY = {"theta": "pos", "dtheta": "vel", "tau": "effort"}
"""Name suffix of each quantity's columns inside a feature (``yaw.pos``, ``yaw.vel``, ``yaw.effort``)."""



def is_lerobot_dataset(path: str | Path) -> bool:
    """Whether ``path`` is a folder with a ``meta/info.json`` (a LeRobot dataset of some version)."""
    return (Path(path) / INFO_PATH).is_file()


def check_set_name(name: object, what: str = "name") -> str:
    """``name`` if it is a plain set name (the ``.h5`` file's stem: :data:`SET_NAME`), else ``ValueError``: a
    name with a separator, ``..`` or a leading ``/`` would put the file elsewhere than the output folder."""
    if not isinstance(name, str) or not SET_NAME.fullmatch(name):
        raise ValueError(f"{what}: the set name must be a plain name of letters, digits, '_', '.' and '-' (not a "
                         f"path, at most 100 characters), got {name!r}")
    return name


def _allowed_roots(root: Path) -> tuple[Path, ...]:
    """Where the files of the dataset ``root`` may lead once symlinks are followed: the folder itself and, when
    it is (inside) a snapshot of a Hugging Face hub cache (``<repo>/snapshots/<revision>/``, whose files are
    symlinks to ``../../blobs/<hash>``), that repository's ``blobs`` folder."""
    real = root.resolve()
    for folder in (real, *real.parents):
        blobs = folder.parent.parent / "blobs"
        if folder.parent.name == "snapshots" and blobs.is_dir():
            return real, blobs.resolve()
    return (real,)


def _input_file(root: Path, path: Path, what: str, limit: int | None = None) -> Path:
    """``path``, a file of the dataset ``root``, resolved and checked before it is opened: a regular file (a
    FIFO or a device would block or never end), inside :func:`_allowed_roots` once symlinks are followed, at
    most ``limit`` bytes. Returns the resolved path, which is what is opened."""
    try:
        real = path.resolve(strict=True)
        status = real.stat()
    except FileNotFoundError:
        raise ValueError(f"{path} is missing ({what})") from None
    except (OSError, RuntimeError) as exc:  # RuntimeError: a symlink loop (Python < 3.13)
        raise ValueError(f"{path} cannot be read ({what}): {getattr(exc, 'strerror', None) or exc}") from None
    if not any(real.is_relative_to(allowed) for allowed in _allowed_roots(root)):
        raise ValueError(f"{path} ({what}) leads outside the dataset folder {root} (to {real}); a dataset's files "
                         "must be inside it")
    if not stat.S_ISREG(status.st_mode):
        raise ValueError(f"{path} ({what}) is not a regular file")
    if limit is not None and status.st_size > limit:
        raise ValueError(f"{path} ({what}) is {status.st_size} bytes, more than it may be ({limit} bytes)")
    return real


def _template_path(root: Path, info: dict, field: str, **values: int | str) -> Path:
    """The file the path template ``info[field]`` (``data_path``, ``video_path``) names for ``values``.

    A template comes from the file, so it is parsed, not trusted: only the placeholders in ``values``, plain
    (no attribute, index or conversion: ``{video_key.__class__}`` must not reach Python objects), with an
    integer format no more than ``:099d``; the formatted path relative, without ``..``, so it stays inside the
    folder (:func:`_input_file` then checks where its symlinks lead).
    """
    where = root / INFO_PATH
    template = info.get(field)
    if not isinstance(template, str) or not 0 < len(template) <= MAX_TEMPLATE:
        raise ValueError(f"{where}: field {field!r} must be a path template (a string of 1..{MAX_TEMPLATE} "
                         f"characters), got {str(template)[:80]!r}")
    allowed = ", ".join(f"{{{name}}}" for name in values)
    try:
        parts = list(string.Formatter().parse(template))
    except ValueError as exc:  # unbalanced braces
        raise ValueError(f"{where}: field {field!r} is not a valid template ({exc}): {template[:80]!r}") from None
    for _, name, spec, conversion in parts:
        if name is None:
            continue
        simple = spec == "" if isinstance(values.get(name), str) else re.fullmatch(r"(0?[1-9][0-9]?)?d?", spec or "")
        if name not in values or conversion is not None or not simple:
            raise ValueError(f"{where}: field {field!r} may only use the placeholders {allowed} (with an integer "
                             f"format such as :03d), got {template[:80]!r}")
    relative = template.format(**values)
    parts_of = PurePosixPath(relative).parts
    if relative.startswith("/") or ".." in parts_of or "\x00" in relative or not parts_of:
        raise ValueError(f"{where}: field {field!r} gives {relative[:120]!r}, which is not a path inside the "
                         "dataset folder (absolute, empty or with '..')")
    return root / relative


def read_info(root: str | Path) -> dict[str, Any]:
    """``meta/info.json`` of a LeRobot v3.0 dataset, checked (version, fps, totals, features) before any data
    is read; ``ValueError`` naming the file and field otherwise."""
    root = Path(root)
    if not root.is_dir():
        if not root.exists() and re.fullmatch(r"[\w.-]+/[\w.-]+", str(root)):
            raise ValueError(f"{root} is not a folder; Hub ids are not downloaded here: fetch it first "
                             f"(huggingface-cli download --repo-type dataset {root} --local-dir DIR) and pass DIR")
        raise ValueError(f"{root} is not a folder")
    path = root / INFO_PATH
    if not path.is_file():
        raise ValueError(f"{root} is not a LeRobot dataset: it has no {INFO_PATH}")
    real = _input_file(root, path, "info.json", MAX_META_BYTES)
    try:
        info = json.loads(real.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise ValueError(f"{path} is not valid JSON: {' '.join(str(exc).split())[:200]}") from None
    if not isinstance(info, dict):
        raise ValueError(f"{path} must hold a JSON object")
    version = info.get("codebase_version")
    if not isinstance(version, str) or not version.startswith("v3."):
        hint = (" Convert it with LeRobot (python -m lerobot.scripts.convert_dataset_v21_to_v30 --repo-id=ID) "
                "and import the converted folder." if isinstance(version, str) and version.startswith("v2") else "")
        raise ValueError(f"{path}: codebase_version is {str(version)[:40]!r}; this reads LeRobot v3.0 datasets.{hint}")
    fps = info.get("fps")
    low, high = FPS_RANGE
    check_json_number(f"{path}: field 'fps' (a frame rate [Hz])", fps, minimum=low, maximum=high)
    _count(info, "total_episodes", path, MAX_LENGTH)
    _count(info, "total_frames", path, 2**31)
    features = info.get("features")
    if not isinstance(features, dict) or not features:
        raise ValueError(f"{path}: field 'features' must be a non-empty object")
    for key, feature in features.items():
        shape = feature.get("shape") if isinstance(feature, dict) else None
        if (not isinstance(shape, list) or not shape or len(shape) > 3
                or not all(isinstance(s, int) and not isinstance(s, bool) and 0 < s <= 10_000 for s in shape)):
            raise ValueError(f"{path}: feature {key!r} has no valid 'shape' (1-3 sizes up to 10000), got {shape!r}")
    return info


def _count(info: dict, key: str, path: Path, limit: int) -> int:
    return int(check_json_number(f"{path}: field {key!r}", info.get(key), minimum=1, maximum=limit, integer=True))


def _names(feature: dict) -> list[str]:
    names = feature.get("names")
    if isinstance(names, dict):  # older datasets: {"motors": [...]}
        names = next(iter(names.values()), None)
    return [str(n) for n in names] if isinstance(names, list) else []


def _columns(field: str, key: str, feature: dict, explicit: bool) -> np.ndarray:
    """Which columns of feature ``key`` hold ``field`` (by the ``.pos``/``.vel``/``.effort`` suffixes of its
    names; a feature without names, or mapped explicitly without such names, is taken whole: see
    :func:`_resolve_map` for when that is ambiguous)."""
    width = math.prod(feature["shape"])
    quantity = field.split("_", 1)[1] if field not in ("block_pose", "image") else None
    names = _names(feature)
    if quantity is not None and len(names) == width:
        suffix = _QUANTITY[quantity]
        picked = [i for i, n in enumerate(names) if n.rsplit(".", 1)[-1] == suffix or n.endswith(f"_{suffix}")]
        if picked:
            return np.array(picked)
        if not explicit:
            raise ValueError(f"cannot map {field}: feature {key!r} has no '.{suffix}' columns (names {names}); "
                             f"name the feature that holds it with --map {field}=KEY")
    return np.arange(width)


def _resolve_map(info: dict, mapping: Mapping[str, str] | None, root: Path) -> dict[str, tuple[str, np.ndarray]]:
    """``{field: (feature key, column indices)}`` for every field found; ``ValueError`` naming what is missing,
    and when two fields would read the same columns (a feature without names cannot be split into θ, θ̇, τ:
    taking it whole for each would copy one quantity into the others)."""
    mapping = dict(mapping or {})
    unknown = sorted(set(mapping) - set(FIELDS))
    if unknown:
        raise ValueError(f"--map names unknown fields {unknown}; choose from {list(FIELDS)}")
    features = info["features"]
    resolved: dict[str, tuple[str, np.ndarray]] = {}
    for field in FIELDS:
        key = mapping.get(field, DEFAULT_MAP[field])
        if field == "image" and field not in mapping and key not in features:
            cameras = [k for k, f in features.items() if f.get("dtype") in ("image", "video")]
            key = cameras[0] if len(cameras) == 1 else ""
        if not key:  # "--map image=": no images
            continue
        if key not in features:
            if field in ("block_pose", "image") and field not in mapping:
                continue  # optional: a dataset without block pose or camera imports as motions only
            raise ValueError(f"{root}: cannot map {field}: the dataset has no feature {key!r} "
                             f"(it has {sorted(features)}); pass --map {field}=KEY")
        feature = features[key]
        if field == "image":
            if feature.get("dtype") not in ("image", "video"):
                raise ValueError(f"{root}: feature {key!r} is {feature.get('dtype')!r}, not an image or video")
            if tuple(feature["shape"]) not in (IMAGE_SHAPE, (3, 64, 64)):
                raise ValueError(f"{root}: camera {key!r} is {feature['shape']}; seqmotion's CNN takes 64 x 64 RGB "
                                 f"images (pass --map image= to import the motions only)")
            resolved[field] = (key, np.arange(0))
        else:
            if feature.get("dtype") not in ("float32", "float64"):
                raise ValueError(f"{root}: feature {key!r} is {feature.get('dtype')!r}; {field} needs float32/64")
            resolved[field] = (key, _columns(field, key, feature, field in mapping))
    shared: dict[str, list[str]] = {}
    for field, (key, cols) in resolved.items():
        if field != "image" and any(set(cols) & set(c) for f, (k, c) in resolved.items() if k == key and f != field):
            shared.setdefault(key, []).append(field)
    if shared:
        groups = "; ".join(f"{', '.join(fields)} (all from {key!r})" for key, fields in shared.items())
        raise ValueError(f"{root / INFO_PATH}: cannot map {groups}: the same columns would serve several fields "
                         "(a feature needs names ending in .pos, .vel, .effort to be split); give each field a "
                         "feature of its own with --map FIELD=KEY")
    joints = {f: len(c) for f, (_, c) in resolved.items() if f not in ("block_pose", "image")}
    if len(set(joints.values())) != 1:
        raise ValueError(f"{root}: the motion fields have different joint counts {joints}; fix them with --map")
    if "block_pose" in resolved and len(resolved["block_pose"][1]) != 7:
        raise ValueError(f"{root}: block pose {resolved['block_pose'][0]!r} has {len(resolved['block_pose'][1])} "
                         "values, not 7 (x, y, z, qw, qx, qy, qz)")
    return resolved


# ----------------------------------------------------------------------------------------------
# Parquet: the footer checked before any page is read
# ----------------------------------------------------------------------------------------------
def _leaves(arrow_type: Any) -> int:
    """How many parquet leaf columns an Arrow type is stored as (depth first, as the writer lays them out)."""
    pa = _pyarrow()
    if pa.types.is_struct(arrow_type):
        return sum(_leaves(arrow_type.field(i).type) for i in range(arrow_type.num_fields))
    if pa.types.is_map(arrow_type):
        return _leaves(arrow_type.key_type) + _leaves(arrow_type.item_type)
    if pa.types.is_list(arrow_type) or pa.types.is_large_list(arrow_type) or pa.types.is_fixed_size_list(arrow_type):
        return _leaves(arrow_type.value_type)
    return 1


def _open_parquet(path: Path, target: Path) -> tuple[Any, Any, dict[str, range]]:
    """``(footer metadata, Arrow schema, {column: its leaf column indices})`` of the parquet file ``target``
    (``path`` in messages), reading the footer only."""
    pa = _pyarrow()
    try:
        parquet = pa.parquet.ParquetFile(target)
        meta, schema = parquet.metadata, parquet.schema_arrow
    except (OSError, pa.ArrowException) as exc:
        raise ValueError(f"{path} is not a readable parquet file: {str(exc).splitlines()[0]}") from None
    if len(set(schema.names)) != len(schema.names):
        raise ValueError(f"{path} is not a usable parquet file: it repeats column names")
    leaves, start = {}, 0
    for field in schema:
        count = _leaves(field.type)
        leaves[field.name], start = range(start, start + count), start + count
    if start != meta.num_columns:
        raise ValueError(f"{path} is not a usable parquet file: its schema has {start} leaf columns, its footer "
                         f"{meta.num_columns}")
    return meta, schema, leaves


def _values_in(meta: Any, leaves: range) -> tuple[int, int]:
    """``(values, uncompressed bytes)`` the footer declares for a column (its leaves), over all row groups."""
    values = size = 0
    for r in range(meta.num_row_groups):
        group = meta.row_group(r)
        for i in leaves:
            values += group.column(i).num_values
            size += group.column(i).total_uncompressed_size
    return values, size


def _check_footer(path: Path, meta: Any, leaves: dict[str, range], per_row: Mapping[str, int]) -> int:
    """Every column of ``per_row`` holds exactly ``per_row[column]`` values per row in each of its leaves (a
    null or a list of another length shows up in the counts too); returns the uncompressed bytes they take."""
    total = 0
    for column, width in per_row.items():
        for leaf in leaves[column]:
            values, size = _values_in(meta, range(leaf, leaf + 1))
            if values != meta.num_rows * width:
                raise ValueError(f"{path}: column {column!r} holds {values} values in {meta.num_rows} rows, not "
                                 f"{width} per row as {INFO_PATH} declares")
            total += size
    return total


def _check_uncompressed(path: Path, size: int) -> None:
    if size > MAX_PARQUET_BYTES:
        raise ValueError(f"{path}: the columns read take {size} bytes uncompressed (its footer says), more than "
                         f"{MAX_PARQUET_BYTES} bytes")


def _read_columns(path: Path, target: Path, columns: list[str]) -> Any:
    pa = _pyarrow()
    try:
        return pa.parquet.read_table(target, columns=columns)
    except (OSError, pa.ArrowException) as exc:
        raise ValueError(f"{path} is not a readable parquet file: {str(exc).splitlines()[0]}") from None


def _first_null(array: Any) -> int:
    return int(np.flatnonzero(np.asarray(array.is_null().to_numpy(zero_copy_only=False)))[0])


_KINDS = {"int": "an integer", "number": "a number", "bool": "a boolean (true/false)"}


def _is_kind(arrow_type: Any, kind: str) -> bool:
    pa = _pyarrow()
    if kind == "bool":
        return pa.types.is_boolean(arrow_type)
    if kind == "int":
        return pa.types.is_integer(arrow_type)
    return pa.types.is_integer(arrow_type) or pa.types.is_floating(arrow_type)


def _read_episodes(root: Path, info: dict, video_keys: Sequence[str]) -> list[dict]:
    """The episodes table's rows, sorted by episode index, checked: only the columns the import uses are read
    (``stats/``, ``tasks`` are not), each of the type it must have, from footers checked first. Each row
    carries the file it came from as ``"_path"`` (for messages)."""
    total = info["total_episodes"]
    files = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
    if not files:
        raise ValueError(f"{root}: no meta/episodes/chunk-*/file-*.parquet: not a complete LeRobot v3.0 dataset")
    required = {"episode_index": "int", "length": "int"}
    for key in video_keys:
        required.update({f"videos/{key}/chunk_index": "int", f"videos/{key}/file_index": "int",
                         f"videos/{key}/from_timestamp": "number", f"videos/{key}/to_timestamp": "number"})
    optional = {"seqmotion/position_index": "int", "seqmotion/success": "bool"}
    rows: list[dict] = []
    for path in files:
        target = _input_file(root, path, "episodes file")
        meta, schema, leaves = _open_parquet(path, target)
        if len(rows) + meta.num_rows > total:
            raise ValueError(f"{path}: more episode rows than total_episodes = {total} in {INFO_PATH}")
        missing = [c for c in required if c not in leaves]
        if missing:
            raise ValueError(f"{path} has no column(s) {missing}")
        kinds = {**required, **{c: kind for c, kind in optional.items() if c in leaves}}
        for column, kind in kinds.items():
            if not _is_kind(schema.field(column).type, kind):
                raise ValueError(f"{path}: column {column!r} is {schema.field(column).type}, not {_KINDS[kind]}")
        if "tasks" in leaves:  # never read; refused when it declares more strings than any episode has tasks
            values, _ = _values_in(meta, leaves["tasks"])
            if values > meta.num_rows * MAX_TASKS_PER_EPISODE:
                raise ValueError(f"{path}: column 'tasks' holds {values} values for {meta.num_rows} episodes, more "
                                 f"than {MAX_TASKS_PER_EPISODE} an episode")
        _check_uncompressed(path, _check_footer(path, meta, leaves, dict.fromkeys(kinds, 1)))
        table = _read_columns(path, target, list(kinds))
        for column in kinds:
            if table.column(column).null_count:
                row = _first_null(table.column(column).combine_chunks())
                raise ValueError(f"{path}: column {column!r} is null in row {row}")
        rows.extend({**row, "_path": str(path)} for row in table.to_pylist())
    if len(rows) != total:
        raise ValueError(f"{root}: {len(rows)} episode rows in meta/episodes but total_episodes = {total}")
    ranges = {"episode_index": (0, MAX_LENGTH), "length": (0, MAX_LENGTH), "seqmotion/position_index":
              (-1, BLOCK_POSITIONS - 1), **{c: (0, MAX_LENGTH) for c in required if c.endswith("_index")}}
    for row in rows:
        for column, (low, high) in ranges.items():
            if column in row:
                check_number(f"{row['_path']}: column {column!r}", row[column], minimum=low, maximum=high,
                             integer=True)
    rows.sort(key=lambda r: r["episode_index"])
    if [r["episode_index"] for r in rows] != list(range(total)):
        raise ValueError(f"{root}: meta/episodes does not number its episodes 0..{total - 1}")
    return rows


def _numeric_type(arrow_type: Any, width: int) -> bool:
    """Whether a column of this type can hold a feature of ``width`` numbers per frame: a number (width 1) or a
    list of numbers (a fixed-size one of that size). Booleans, strings, structs, nested lists cannot."""
    pa = _pyarrow()

    def number(t: Any) -> bool:
        return pa.types.is_integer(t) or pa.types.is_floating(t)

    if pa.types.is_fixed_size_list(arrow_type):
        return arrow_type.list_size == width and number(arrow_type.value_type)
    if pa.types.is_list(arrow_type) or pa.types.is_large_list(arrow_type):
        return number(arrow_type.value_type)
    return width == 1 and number(arrow_type)


def _numbers(path: Path, key: str, column: Any, width: int) -> np.ndarray:
    """A numeric feature's column as ``(rows, width)`` float64, refused (naming the file, the feature and the
    row) when a row is null, holds another number of values or a value that is not finite or beyond
    :data:`MAX_MOTION_VALUE`."""
    pa = _pyarrow()
    import pyarrow.compute as pc

    values = column.combine_chunks() if column.num_chunks else pa.array([], column.type)
    if values.null_count:
        raise ValueError(f"{path}: feature {key!r} is null in row {_first_null(values)}")
    if pa.types.is_list(values.type) or pa.types.is_large_list(values.type) or pa.types.is_fixed_size_list(
            values.type):
        lengths = np.asarray(pc.list_value_length(values).to_numpy(zero_copy_only=False))
        bad = np.flatnonzero(lengths != width)
        if bad.size:
            raise ValueError(f"{path}: feature {key!r} row {bad[0]} holds {lengths[bad[0]]} values, not {width} as "
                             f"{INFO_PATH} declares")
        flat = values.flatten()
    else:
        flat = values
    if flat.null_count:
        raise ValueError(f"{path}: feature {key!r} has a null value in row {_first_null(flat) // width}")
    x = np.asarray(flat.to_numpy(zero_copy_only=False), dtype=np.float64).reshape(len(values), width)
    bad = np.argwhere(~(np.abs(x) <= MAX_MOTION_VALUE))  # NaN compares false: caught with inf and the huge
    if bad.size:
        row, col = bad[0]
        raise ValueError(f"{path}: feature {key!r} row {row} holds {x[row, col]:g} (value {col}); values must be "
                         f"finite and within +-{MAX_MOTION_VALUE:g}")
    return x


def _integers(path: Path, key: str, column: Any) -> np.ndarray:
    pa = _pyarrow()
    if not pa.types.is_integer(column.type):
        raise ValueError(f"{path}: column {key!r} is {column.type}, not integers")
    values = column.combine_chunks() if column.num_chunks else pa.array([], column.type)
    if values.null_count:
        raise ValueError(f"{path}: column {key!r} is null in row {_first_null(values)}")
    return np.asarray(values.to_numpy(zero_copy_only=False)).astype(np.int64)


def _read_frames(root: Path, info: dict, numeric: Mapping[str, int], image_key: str | None,
                 rows: list[dict]) -> dict[str, Any]:
    """The data files' frames, in episode order, checked against the episodes: ``values`` ``{key: (frames,
    width)}`` for the numeric features ``numeric`` (``{key: width}``), ``images`` the column ``image_key``
    (or ``None``), ``lengths`` and ``starts`` per episode. Each file's footer is checked (types, value
    counts, uncompressed size) before its pages are read."""
    from ...io.trajectories import MAX_FILE_BYTES

    pa = _pyarrow()
    if info.get("data_path") is not None:  # the files are found by LeRobot's layout; a template must still be sane
        _template_path(root, info, "data_path", chunk_index=0, file_index=0)
    files = sorted((root / "data").glob("chunk-*/file-*.parquet"))
    if not files:
        raise ValueError(f"{root}: no data/chunk-*/file-*.parquet: not a complete LeRobot v3.0 dataset")
    targets = [_input_file(root, path, "data file") for path in files]
    size = sum(target.stat().st_size for target in targets)
    if size > MAX_FILE_BYTES:
        raise ValueError(f"{root}: its data files take {size / 2**30:.1f} GiB, more than an input may take "
                         f"({MAX_FILE_BYTES / 2**30:.0f} GiB)")
    total, seen, uncompressed = info["total_frames"], 0, 0
    per_row = {**numeric, "episode_index": 1, "frame_index": 1, **({image_key: 1} if image_key else {})}
    parts: dict[str, list] = {key: [] for key in (*per_row, "file")}
    for number, (path, target) in enumerate(zip(files, targets, strict=True)):
        meta, schema, leaves = _open_parquet(path, target)
        seen += meta.num_rows
        if seen > total:
            raise ValueError(f"{path}: more frames than total_frames = {total} in {INFO_PATH}")
        missing = [c for c in per_row if c not in leaves]
        if missing:
            raise ValueError(f"{path} has no column(s) {missing} (declared in {INFO_PATH})")
        for key, width in numeric.items():
            if not _numeric_type(schema.field(key).type, width):
                raise ValueError(f"{path}: column {key!r} is not numeric: it is {schema.field(key).type}, where "
                                 f"{INFO_PATH} declares {width} number(s) per frame")
        if image_key:
            image_type = schema.field(image_key).type
            if not (pa.types.is_struct(image_type) and image_type.get_field_index("bytes") >= 0
                    and (pa.types.is_binary(image_type.field("bytes").type)
                         or pa.types.is_large_binary(image_type.field("bytes").type))):
                raise ValueError(f"{path}: column {image_key!r} is {image_type}, not an image (a struct of 'bytes' "
                                 "and 'path')")
        uncompressed += _check_footer(path, meta, leaves, per_row)
        _check_uncompressed(path, uncompressed)
        table = _read_columns(path, target, list(per_row))
        for key, width in numeric.items():
            parts[key].append(_numbers(path, key, table.column(key), width))
        for key in ("episode_index", "frame_index"):
            parts[key].append(_integers(path, key, table.column(key)))
        if image_key:
            parts[image_key].extend(table.column(image_key).chunks)
        parts["file"].append(np.full(meta.num_rows, number))
    if seen != total:
        raise ValueError(f"{root}: the data files hold {seen} frames but total_frames = {total}")
    episode, frame = np.concatenate(parts["episode_index"]), np.concatenate(parts["frame_index"])
    order = np.lexsort((frame, episode))
    episode, frame = episode[order], frame[order]
    lengths = np.bincount(episode, minlength=len(rows)) if len(episode) and episode.min() >= 0 else None
    if lengths is None or len(lengths) != len(rows):
        raise ValueError(f"{root}: the data's episode_index values do not match meta/episodes (0..{len(rows) - 1})")
    for e, row in enumerate(rows):
        if lengths[e] != row["length"]:
            raise ValueError(f"{root}: episode {e} has {lengths[e]} frames in data/ but length {row['length']} "
                             "in meta/episodes")
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    if not np.array_equal(frame, np.arange(len(frame)) - np.repeat(starts, lengths)):
        raise ValueError(f"{root}: frame_index is not 0, 1, 2, ... within every episode")
    images = None
    if image_key:
        try:  # each episode's first frame only
            images = pa.chunked_array(parts[image_key]).take(pa.array(order[starts]))
        except (pa.ArrowException, TypeError) as exc:  # files whose image columns differ in type
            raise ValueError(f"{root}: the data files' {image_key!r} columns are unusable: "
                             f"{str(exc).splitlines()[0]}") from None
    image_files = [files[i] for i in np.concatenate(parts["file"])[order[starts]]]  # for messages
    return {"values": {key: np.concatenate(parts[key])[order] for key in numeric}, "images": images,
            "image_files": image_files, "lengths": lengths, "starts": starts}


# ----------------------------------------------------------------------------------------------
# Images and videos
# ----------------------------------------------------------------------------------------------
def _decode_png(blob: Any, where: str) -> np.ndarray:
    """One embedded image (PNG or JPEG, as LeRobot stores them), refused unless it is 64 x 64: its size is read
    from the header and checked before any pixel is decoded (a header may declare 20000 x 20000)."""
    from PIL import Image, UnidentifiedImageError

    if not isinstance(blob, dict) or not isinstance(blob.get("bytes"), bytes):
        raise ValueError(f"{where}: image is not stored as embedded bytes (struct of 'bytes', 'path')")
    failures = (UnidentifiedImageError, OSError, SyntaxError, EOFError, ValueError, TypeError,
                Image.DecompressionBombError, Image.DecompressionBombWarning)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)  # raised, not printed
            image = Image.open(io.BytesIO(blob["bytes"]), formats=["PNG", "JPEG"])
    except failures as exc:
        raise ValueError(f"{where}: image cannot be decoded: {' '.join(str(exc).split())[:200]}") from None
    with image:
        if image.size != IMAGE_SHAPE[:2][::-1]:
            raise ValueError(f"{where}: image is {image.size[0]} x {image.size[1]}, not 64 x 64")
        try:
            return np.asarray(image.convert("RGB"), dtype=np.uint8)
        except failures as exc:
            raise ValueError(f"{where}: image cannot be decoded: {' '.join(str(exc).split())[:200]}") from None


def _video_starts(root: Path, info: dict, key: str, rows: list[dict]) -> dict[Path, tuple[dict[int, int], float]]:
    """``{video file: ({frame index of an episode's start: episode}, end of its last episode [s])}``, from the
    episodes' ``videos/<key>/...`` columns, each checked: finite timestamps inside the data's duration, an
    episode's span its length (within :data:`VIDEO_SLACK_FRAMES`)."""
    fps, total = info["fps"], info["total_frames"]
    wanted: dict[Path, tuple[dict[int, int], float]] = {}
    paths: dict[tuple[int, int], Path] = {}  # the template is parsed once per file, not once per episode
    for e, row in enumerate(rows):
        start, stop = (float(row[f"videos/{key}/{t}_timestamp"]) for t in ("from", "to"))
        where = f"{row['_path']}: episode {e}, videos/{key}/from_timestamp and to_timestamp"
        if not (math.isfinite(start) and math.isfinite(stop) and 0 <= start < stop
                and stop * fps <= total + VIDEO_SLACK_FRAMES):
            raise ValueError(f"{where} are {start!r}..{stop!r}; they must lie in 0..{total / fps:g} s (total_frames "
                             f"/ fps), from before to")
        if abs((stop - start) * fps - row["length"]) > VIDEO_SLACK_FRAMES:
            raise ValueError(f"{where} span {(stop - start) * fps:g} frames, but the episode has {row['length']}")
        chunk, file = row[f"videos/{key}/chunk_index"], row[f"videos/{key}/file_index"]
        if (chunk, file) not in paths:
            paths[chunk, file] = _template_path(root, info, "video_path", video_key=key, chunk_index=chunk,
                                                file_index=file)
        path = paths[chunk, file]
        starts, end = wanted.get(path, ({}, 0.0))
        starts[round(start * fps)] = e
        wanted[path] = (starts, max(end, stop))
    return wanted


def _first_video_frames(root: Path, info: dict, key: str, rows: list[dict]) -> np.ndarray:
    """Each episode's first frame of the video feature ``key``, found by its ``from_timestamp``.

    Bounded before and while decoding: the file at most :data:`~seqmotion.io.trajectories.MAX_FILE_BYTES`, read as
    mp4 only (FFmpeg would otherwise guess the format from the content: a playlist could point it at other
    files), its stream 64 x 64, no more frames nor seconds than its episodes end at (plus
    :data:`VIDEO_SLACK_FRAMES`); then no more packets demuxed than the last start needs plus that slack and
    :data:`VIDEO_DECODER_DELAY`.
    """
    from ...io.trajectories import MAX_FILE_BYTES

    av = _av()
    fps = info["fps"]
    images = np.zeros((len(rows), *IMAGE_SHAPE), dtype=np.uint8)
    found: set[int] = set()
    for path, (starts, end) in _video_starts(root, info, key, rows).items():
        target = _input_file(root, path, f"video of {key!r}", MAX_FILE_BYTES)
        try:
            with av.open(str(target), format="mp4", options={"protocol_whitelist": "file"}) as container:
                if not container.streams.video:
                    raise ValueError(f"{path} holds no video stream ({key!r})")
                stream = container.streams.video[0]
                width, height = stream.codec_context.width, stream.codec_context.height
                if (width or height) and (height, width) != IMAGE_SHAPE[:2]:
                    raise ValueError(f"{path}: the video is {width} x {height}, not 64 x 64 as feature {key!r} is")
                last = round(end * fps)
                if stream.frames > last + VIDEO_SLACK_FRAMES:
                    raise ValueError(f"{path}: the video holds {stream.frames} frames, but its episodes end at frame "
                                     f"{last} (their to_timestamp)")
                seconds = float(stream.duration * stream.time_base) if stream.duration and stream.time_base else 0.0
                if seconds > end + VIDEO_SLACK_FRAMES / fps:
                    raise ValueError(f"{path}: the video lasts {seconds:g} s, but its episodes end at {end:g} s "
                                     "(their to_timestamp)")
                last_start = max(starts)
                budget = last_start + VIDEO_SLACK_FRAMES + VIDEO_DECODER_DELAY
                index = -1
                for packet in container.demux(stream):
                    budget -= 1
                    if budget < 0 or index > last_start:
                        break
                    for frame in packet.decode():
                        if (frame.height, frame.width) != IMAGE_SHAPE[:2]:
                            raise ValueError(f"{path}: the video is {frame.width} x {frame.height}, not 64 x 64 as "
                                             f"feature {key!r} is")
                        if frame.time is None or not math.isfinite(frame.time):
                            raise ValueError(f"{path}: a frame has no timestamp (not an mp4 as LeRobot writes them)")
                        index = round(frame.time * fps)
                        if index in starts:
                            images[starts[index]] = frame.to_ndarray(format="rgb24")
                            found.add(starts[index])
        except av.error.FFmpegError as exc:
            raise ValueError(f"{path} cannot be decoded: {' '.join(str(exc).split())[:200]}") from None
    missing = sorted(set(range(len(rows))) - found)
    if missing:
        raise ValueError(f"{root}: no video frame at the start of episodes {missing[:10]} of {key!r}")
    return images


def from_lerobot(
    path: str | Path, mapping: Mapping[str, str] | None = None, name: str | None = None, trim: bool = False,
) -> PushingDataset:
    """Read a LeRobot v3.0 dataset folder as a :class:`PushingDataset` (sampled at the dataset's fps).

    Features are mapped by name (:data:`DEFAULT_MAP`: what :func:`to_lerobot` writes): the slave's
    θ and θ̇ are the ``.pos`` and ``.vel`` columns of ``observation.state``, its τ
    ``observation.effort``, the master's θ, θ̇, τ the ``.pos``, ``.vel``, ``.effort`` columns of
    ``action``; block pose and webcam are optional. ``mapping`` (``--map FIELD=KEY``) points a
    field of :data:`FIELDS` at another feature (another robot's keys); ``image=""`` drops the
    camera. A feature without names is taken whole, so it can serve one field only. The joint count is
    the dataset's. Episodes without seqmotion's columns count as successful, at an unknown block
    position (``-1``).

    The folder is read as untrusted input. Files: every file opened is a regular file whose path, once
    symlinks are followed, is inside the folder, or inside the hub cache's ``blobs`` folder of the same
    repository when the folder is a snapshot of one (``<repo>/snapshots/<rev>/``); the path templates of
    ``info.json`` (``data_path``, ``video_path``) take only their known placeholders and must give a relative
    path without ``..``. Sizes: ``info.json`` at most :data:`MAX_META_BYTES`; each parquet file's footer is
    checked before its pages are read (column types, exactly the declared number of values per row, at most
    :data:`MAX_PARQUET_BYTES` uncompressed); videos as in :func:`_first_video_frames`. Values: integers and
    booleans of their own types and ranges, numeric features finite and within :data:`MAX_MOTION_VALUE`.

    Args:
        path: the dataset folder (``meta/info.json`` inside).
        mapping: ``{field: feature key}`` overrides.
        name: the set name recorded in ``attrs`` and, by :func:`import_lerobot`, the file's name (a plain name:
            :func:`check_set_name`; default: the folder's name if it is one of seqmotion's sets, else
            ``pairs_default`` with images and ``motions`` without).
        trim: cut every episode to the shortest (otherwise unequal lengths are an error).

    Raises:
        ValueError: not a folder, not v3.0 (a v2.x one gets the conversion command), a feature
            that cannot be mapped, counts or lengths that disagree, declared sizes over the caps, any check
            above; one line naming the file and the field.
    """
    from ...io.trajectories import check_declared_size

    if name is not None:
        check_set_name(name)
    root = Path(path)
    info = read_info(root)
    resolved = _resolve_map(info, mapping, root)
    features = info["features"]
    # what will be read, as float64, refused by its declared size before anything is read
    numeric = {k: math.prod(features[k]["shape"]) for k in sorted({k for f, (k, _) in resolved.items()
                                                                     if f != "image"})}
    check_declared_size((info["total_frames"], sum(numeric.values())), 8, f"{root / INFO_PATH}: total_frames")
    if "image" in resolved:  # one 64 x 64 RGB image an episode
        check_declared_size((info["total_episodes"], math.prod(IMAGE_SHAPE)), 1,
                            f"{root / INFO_PATH}: total_episodes (images)")
    for key in ("episode_index", "frame_index"):
        if key not in features:
            raise ValueError(f"{root / INFO_PATH}: feature {key!r} is missing")
    image_key = resolved.get("image", ("", None))[0]
    image_in_data = bool(image_key) and features[image_key]["dtype"] == "image"
    rows = _read_episodes(root, info, [image_key] if image_key and not image_in_data else [])
    frames = _read_frames(root, info, numeric, image_key if image_in_data else None, rows)
    lengths = frames["lengths"]
    if len(set(lengths.tolist())) != 1 and not trim:
        raise ValueError(f"{root}: episodes have different lengths ({lengths.min()}..{lengths.max()} frames); "
                         "seqmotion's datasets are rectangular: pass trim=True (--trim) to cut all to the shortest")
    k = int(lengths.min())
    if k < 2:
        raise ValueError(f"{root}: an episode has {k} frame(s); a motion needs at least 2")
    take = (frames["starts"][:, None] + np.arange(k)[None]).reshape(-1)
    n = len(rows)
    taken = {key: values[take] for key, values in frames["values"].items()}
    motions = {field: taken[key][:, cols].reshape(n, k, len(cols)) for field, (key, cols) in resolved.items()
               if field != "image"}
    images = None
    if image_key:
        if image_in_data:
            images = np.stack([_decode_png(b, f"{frames['image_files'][e]}: episode {e}, {image_key!r}")
                               for e, b in enumerate(frames["images"].to_pylist())])
        else:
            images = _first_video_frames(root, info, image_key, rows)
    joints = len(resolved["slave_theta"][1])
    episodes = {
        "position_index": np.array([r.get("seqmotion/position_index", -1) for r in rows], dtype=np.int8),
        "success": np.array([r.get("seqmotion/success", True) for r in rows], dtype=bool),
    }
    if name is None:
        name = root.name if root.name in SETS else ("pairs_default" if images is not None else "motions")
    camera = name.removeprefix("pairs_") if images is not None and name.startswith("pairs_") else ""
    attrs = {"format": FORMAT, "version": VERSION, "set_name": name, "seed": -1, "dt": 1.0 / info["fps"],
             "duration": k / info["fps"], "n_episodes": n, "samples": k, "camera": camera,
             "image_size": IMAGE_SHAPE[0], "complete": True, "joints": joints, "source": f"lerobot:{root}"}
    return PushingDataset(root, attrs, motions, episodes, {}, images)


def import_lerobot(
    path: str | Path, out_dir: str | Path, mapping: Mapping[str, str] | None = None, name: str | None = None,
    trim: bool = False, overwrite: bool = False,
) -> Path:
    """:func:`from_lerobot`, written as ``out_dir/<name>.h5`` (seqmotion's format; atomically). ``name`` is a
    plain name (:func:`check_set_name`), checked before anything is read."""
    from .dataset import save_dataset

    data = from_lerobot(path, mapping, name, trim)
    return save_dataset(data, Path(out_dir) / f"{check_set_name(data.attrs['set_name'])}.h5", overwrite=overwrite)


def parse_map(items: Sequence[str] | None) -> dict[str, str]:
    """``["FIELD=KEY", ...]`` (the ``--map`` option) → ``{field: key}``; ``ValueError`` on a malformed item."""
    mapping = {}
    for item in items or ():
        field, sep, key = item.partition("=")
        if not sep or field not in FIELDS:
            raise ValueError(f"--map needs FIELD=KEY with FIELD one of {list(FIELDS)}, got {item!r}")
        mapping[field] = key
    return mapping
