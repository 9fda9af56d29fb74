"""Checking a robot's MJCF model file before MuJoCo parses it (:func:`check_model_file`).

A model file is input the user may not have written: a model from a Menagerie tree (``MENAGERIE_ROOT``, a
download) is data from elsewhere, and MuJoCo's parser trusts its input. An include or asset path may point
anywhere on the machine, and a flexcomp, a replicate or an allocation size may make the parse or the compile take
minutes or gigabytes. So each file is read first with a plain XML parser and refused by name (one ``ValueError``
line) before MuJoCo sees it:

* sizes that bound the parse's time and memory: the MJCF files' bytes (:data:`MAX_XML_BYTES`), their elements
  counting includes and ``replicate`` copies (:data:`MAX_ELEMENTS`), include depth, flex and composite points
  (no flexcomp read from a file), textures, height fields, built-in meshes and ``<size>`` allocations;
* text MuJoCo can read safely: UTF-8, well-formed, no DOCTYPE or ENTITY (entity expansion has no bound);
* asset files (meshes, textures, height fields, skins): regular files (a pipe would block the parser), within
  :data:`MAX_ASSET_BYTES` each and :data:`MAX_ASSETS_BYTES` in all, a PNG's declared pixels within
  :data:`MAX_TEXTURE_PIXELS`, at most :data:`MAX_ASSET_NAMES` names and :data:`MAX_ASSET_DIRS` directories;
* given the robot's folder (robosuite's and Menagerie's arms): no absolute path, and every file or directory the
  model names, symbolic links followed, inside that folder (and the folder inside its root).

:mod:`seqmotion.sim.robot_models` calls it on every model file it loads.
"""

from __future__ import annotations

import math
import os
import re
import stat
import struct
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import NoReturn

MAX_XML_BYTES = 8 * 2**20
"""Largest sum of a model's MJCF files (the model and every file it includes) [bytes]; Menagerie's arm files are
under 100 kB."""

MAX_ELEMENTS = 20_000
"""Most XML elements a model may hold, counting every included file and every ``replicate`` copy (Menagerie's
arms hold a few hundred)."""

MAX_INCLUDE_DEPTH = 8
"""Deepest chain of ``include`` / ``model`` files."""

MAX_FLEX_POINTS = 1_000
"""Most points of all flexes and composites together: MuJoCo's parse of a flex grid grows as the fourth power of
its side (60 × 60 takes 0.4 s, 300 × 300 minutes)."""

MAX_TEXTURE_PIXELS = 4096 * 4096
"""Largest texture or height-field image, built in or a PNG's declared size [pixels]."""

MAX_HFIELD_SAMPLES = 4096 * 4096
"""Largest height field given by ``nrow × ncol``."""

MAX_MESH_RESOLUTION = 100
"""Largest parameter of a built-in mesh (its resolution: the vertices grow as its square)."""

MAX_MEMORY_BYTES = 2**30
"""Largest ``<size memory>`` (MuJoCo allocates it with every ``MjData``)."""

MAX_SIZE_COUNT = 1_000_000
"""Largest other ``<size>`` count (``njmax``, ``nuserdata``, ``nkey``, …: each sizes an allocation)."""

MAX_ASSET_BYTES = 64 * 2**20
"""Largest mesh, texture, height-field or skin file [bytes] (robosuite's are under 10 MB)."""

MAX_ASSETS_BYTES = 256 * 2**20
"""Largest sum of a model's asset files [bytes]."""

MAX_ASSET_NAMES = 2_000
"""Most distinct asset file names a model may give (each is looked up in every asset directory)."""

MAX_ASSET_DIRS = 8
"""Most distinct ``meshdir`` / ``texturedir`` / ``assetdir`` values a model may give (MuJoCo uses one of each)."""

_DIR_ATTRIBUTES = ("meshdir", "texturedir", "assetdir")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40, "P": 2**50, "E": 2**60}


def _stat(path: Path) -> os.stat_result | None:
    """``path``'s status (symbolic links followed), or ``None`` where there is nothing to read."""
    try:
        return path.stat()
    except (OSError, RuntimeError):
        return None


def check_model_file(path: str | Path, folder: str | Path | None = None, root: str | Path | None = None) -> None:
    """Refuse an MJCF model MuJoCo could not parse and compile in bounded time and memory, or, given ``folder``,
    one that reads any file outside it; read with a plain XML parser, before MuJoCo sees the file.

    Every file the model includes (``<include>``, ``<model>``) is read the same way, recursively. Refused: MJCF
    files over :data:`MAX_XML_BYTES` in all, a file not UTF-8, or declaring a DOCTYPE or ENTITY (entity expansion
    has no bound); more than :data:`MAX_ELEMENTS` elements counting includes and ``replicate`` copies; includes
    deeper than :data:`MAX_INCLUDE_DEPTH`; flexes and composites of more than :data:`MAX_FLEX_POINTS` points, or
    a flexcomp read from a file; textures, height fields, built-in meshes and ``<size>`` allocations over their
    limits; more than :data:`MAX_ASSET_NAMES` asset files or :data:`MAX_ASSET_DIRS` asset directories; an asset
    file that is not a regular file (a pipe would block the parser), over :data:`MAX_ASSET_BYTES`, or a PNG
    declaring more than :data:`MAX_TEXTURE_PIXELS`. With ``folder``: any
    absolute file or directory path, and any path (an include, an asset file, ``meshdir`` / ``texturedir`` /
    ``assetdir``, the model file itself) that resolves, symbolic links followed, outside ``folder``; with ``root``
    too, a ``folder`` that resolves outside ``root``.

    Raises:
        ValueError: one line naming the model file, the file and element at fault, and the limit.
    """
    _ModelCheck(Path(path), folder, root).run()


class _ModelCheck:
    """One pass of :func:`check_model_file` over a model and the files it names."""

    def __init__(self, path: Path, folder: str | Path | None, root: str | Path | None) -> None:
        self.path = path
        self.folder_arg = None if folder is None else Path(folder)
        self.root = None if root is None else Path(root)
        self.folder: Path | None = None  # resolved
        self.trees: dict[Path, ET.Element] = {}
        # Per main-file directory: its meshdir / texturedir / assetdir values; and the asset files named, as
        # (file, its main directory, tag, attribute, value). Dicts: an include read many times adds each once.
        self.dirs: dict[Path, dict[str, None]] = {}
        self.refs: dict[tuple[Path, Path, str, str, str], None] = {}
        self.elements = 0
        self.xml_bytes = 0
        self.flex_points = 0
        self.asset_bytes = 0
        self.assets: set[Path] = set()

    def fail(self, problem: str) -> NoReturn:
        raise ValueError(f"robot file {self.path}: {problem}")

    def show(self, file: Path) -> str:
        """``file`` as a message names it: relative to the model's directory where it lies below it."""
        return file.relative_to(self.path.parent).as_posix() if file.is_relative_to(self.path.parent) else str(file)

    def run(self) -> None:
        if self.folder_arg is not None:
            self.folder = self.resolve(self.folder_arg, f"its folder {self.folder_arg}")
            if self.root is not None:
                root = self.resolve(self.root, f"the root {self.root}")
                if not self.folder.is_relative_to(root):
                    self.fail(f"its folder {self.folder_arg} resolves to {self.folder}, outside {self.root}")
        self.inside(self.path, "the model file")
        self.walk(self.path, self.path.parent, 0, 1)
        for ref in self.refs:  # after the walk: every compiler directory is known
            self.check_asset(*ref)

    def resolve(self, path: Path, what: str) -> Path:
        try:
            return path.resolve()
        except (OSError, RuntimeError) as exc:  # a symbolic-link loop (RuntimeError before Python 3.13)
            self.fail(f"{what} cannot be resolved: {exc}")

    def inside(self, path: Path, what: str) -> None:
        """Refuse ``path`` if it resolves outside the folder (symbolic links followed)."""
        if self.folder is None:
            return
        resolved = self.resolve(path, what)
        if not resolved.is_relative_to(self.folder):
            self.fail(f"{what} resolves to {resolved}, outside {self.folder}")

    def relative(self, value: str, what: str) -> None:
        """Refuse an absolute path where the model must stay inside its folder."""
        if self.folder is not None and (Path(value).is_absolute() or value.startswith(("/", "\\"))):
            self.fail(f"{what} is an absolute path; a model from {self.folder} may read only files inside it")

    def read(self, file: Path) -> ET.Element:
        """``file`` parsed as XML, within :data:`MAX_XML_BYTES` and :data:`MAX_ELEMENTS`, with no DOCTYPE."""
        resolved = self.resolve(file, str(file))
        if resolved in self.trees:
            return self.trees[resolved]
        try:
            info = file.stat()
        except OSError as exc:
            self.fail(f"cannot read {self.show(file)}: {exc.strerror or exc}")
        if not stat.S_ISREG(info.st_mode):
            self.fail(f"{self.show(file)} is not a regular file")
        left = MAX_XML_BYTES - self.xml_bytes  # many files of a few bytes each must not add up without bound
        if info.st_size > left:
            self.fail(f"{self.show(file)} has {info.st_size} bytes, more than the {MAX_XML_BYTES} bytes of MJCF a "
                      "model may have in all")
        try:
            with open(file, "rb") as stream:
                data = stream.read(left + 1)  # it may have grown since the stat
        except OSError as exc:
            self.fail(f"cannot read {self.show(file)}: {exc.strerror or exc}")
        if len(data) > left:
            self.fail(f"{self.show(file)} has more than the {MAX_XML_BYTES} bytes of MJCF a model may have in all")
        self.xml_bytes += len(data)
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            self.fail(f"{self.show(file)} is not UTF-8 text (the encoding MuJoCo reads)")
        # Without a DOCTYPE no entity can be declared, so the parse below expands nothing (ElementTree alone does
        # not guard against entity bombs).
        if re.search(r"<!\s*(DOCTYPE|ENTITY)", text, re.IGNORECASE):
            self.fail(f"{self.show(file)} declares a DOCTYPE or ENTITY (refused: entities expand without bound)")
        parser = ET.XMLPullParser(events=("start",))
        top, count = None, 0
        try:
            for start in range(0, len(text), 1 << 16):
                parser.feed(text[start:start + (1 << 16)])  # a str: parsed as UTF-8 whatever it declares
                for _, element in parser.read_events():
                    top = element if top is None else top
                    count += 1
                if count > MAX_ELEMENTS:
                    self.fail(f"{self.show(file)} has more than the {MAX_ELEMENTS} elements a model may have")
            parser.close()
        except ET.ParseError as exc:
            self.fail(f"{self.show(file)} is not well-formed XML: {exc}")
        if top is None:
            self.fail(f"{self.show(file)} holds no XML element")
        self.trees[resolved] = top
        return top

    def walk(self, file: Path, base: Path, depth: int, copies: int) -> None:
        """Check ``file`` (its includes resolve against ``base``, its main file's directory), present ``copies``
        times in the model."""
        if depth > MAX_INCLUDE_DEPTH:
            self.fail(f"includes nested deeper than {MAX_INCLUDE_DEPTH} files, at {self.show(file)}")
        stack = [(self.read(file), copies)]
        while stack:
            element, n = stack.pop()
            # max(n, 1): a subtree replicated 0 times is still walked, so it still costs.
            self.elements += max(n, 1)
            if self.elements > MAX_ELEMENTS:
                self.fail(f"more than the {MAX_ELEMENTS} elements a model may have, counting included files and "
                          "replicate copies")
            tag = element.tag
            if tag in ("include", "model"):  # another MJCF file: an include is inlined, a model asset attached
                value = element.get("file")
                if value:
                    what = f"{tag} file={value!r} in {self.show(file)}"
                    self.relative(value, what)
                    for candidate in dict.fromkeys((base / value, file.parent / value)):
                        self.inside(candidate, what)
                        if _stat(candidate) is not None:
                            self.walk(candidate, base if tag == "include" else candidate.parent, depth + 1, n)
                continue
            self.check_sizes(file, element, n)
            if tag == "compiler":
                for name in _DIR_ATTRIBUTES:
                    value = element.get(name)
                    if value:
                        what = f"compiler {name}={value!r} in {self.show(file)}"
                        self.relative(value, what)
                        for directory in (base, file.parent):
                            self.inside(directory / value, what)
                        self.dirs.setdefault(base, {})[value] = None
                        if len(self.dirs[base]) > MAX_ASSET_DIRS:
                            self.fail(f"more than {MAX_ASSET_DIRS} different asset directories, at {what}")
            for name, value in element.attrib.items():
                if name.startswith("file") and value:  # file, fileright, fileleft, ... (a cube's faces)
                    self.relative(value, f"{tag} {name}={value!r} in {self.show(file)}")
                    self.refs[(file, base, tag, name, value)] = None
                    if len(self.refs) > MAX_ASSET_NAMES:
                        self.fail(f"more than {MAX_ASSET_NAMES} asset file names, at {tag} {name}={value!r} in "
                                  f"{self.show(file)}")
            times = int(self.counts(file, element, "count", "1")[0]) if tag == "replicate" else 1
            stack.extend((child, n * times) for child in element)

    def counts(self, file: Path, element: ET.Element, name: str, default: str) -> list[float]:
        """The attribute's numbers, each finite and ≥ 0 (a NaN would pass every ``>`` test)."""
        value = element.get(name, default)
        try:
            numbers = [float(x) for x in value.split()]
        except ValueError:
            numbers = [-1.0]
        if not numbers or not all(math.isfinite(x) and x >= 0 for x in numbers):
            label = element.get("name")
            self.fail(f"{element.tag}{'' if label is None else f' {label!r}'} {name} {value!r} in {self.show(file)} "
                      "is not a count")
        return numbers

    def check_sizes(self, file: Path, element: ET.Element, copies: int) -> None:
        """Refuse an element whose parse or compile would take unbounded time or memory."""
        tag, label = element.tag, repr(element.get("name", ""))
        where = f"{tag} {label} in {self.show(file)}"
        points = None
        if tag == "flexcomp":
            if element.get("file") or element.get("type") in ("mesh", "gmsh"):
                self.fail(f"{where} is read from a file: refused, its size is known only by parsing it")
            if element.get("type") == "direct":
                points = len(element.get("point", "").split()) // 3
            else:
                points = math.prod(self.counts(file, element, "count", "10 10 10"))
        elif tag == "composite":
            points = math.prod(self.counts(file, element, "count", "1"))
        elif tag == "flex":
            points = max(len(element.get("vertex", "").split()) // 3, len(element.get("body", "").split()))
        if points is not None:
            self.flex_points += points * max(copies, 1)
            if self.flex_points > MAX_FLEX_POINTS:
                count = f" (count {element.get('count')!r})" if element.get("count") else ""
                self.fail(f"{where} has {int(points)} points{count}: more than the {MAX_FLEX_POINTS} points of "
                          "flexes a robot model may have (MuJoCo's parse time grows as their number squared)")
        elif tag == "texture":
            width, height = (self.counts(file, element, k, "0")[0] for k in ("width", "height"))
            pixels = width * height * (6 if element.get("type") in ("cube", "skybox") else 1)
            if pixels > MAX_TEXTURE_PIXELS:
                self.fail(f"{where} has {int(pixels)} pixels: more than the {MAX_TEXTURE_PIXELS} a texture may have")
        elif tag == "hfield":
            rows, cols = (self.counts(file, element, k, "0")[0] for k in ("nrow", "ncol"))
            if rows * cols > MAX_HFIELD_SAMPLES:
                self.fail(f"{where} has {int(rows * cols)} samples: more than the {MAX_HFIELD_SAMPLES} a height "
                          "field may have")
        elif tag == "mesh" and element.get("builtin"):
            params = self.counts(file, element, "params", "0")
            if max(params) > MAX_MESH_RESOLUTION:
                self.fail(f"{where}: built-in {element.get('builtin')!r} with parameter {max(params):g}, more than "
                          f"the {MAX_MESH_RESOLUTION} a built-in mesh may have")
        elif tag == "size":
            for name, value in element.attrib.items():
                if name == "memory":
                    match = re.fullmatch(r"\s*(\d+)\s*([KMGTPE]?)\s*", value, re.IGNORECASE)
                    if value.strip() == "-1":  # MuJoCo's default
                        continue
                    if match is None:
                        self.fail(f"size memory={value!r} in {self.show(file)} is not a size in bytes")
                    if int(match[1]) * _UNITS[match[2].upper()] > MAX_MEMORY_BYTES:
                        self.fail(f"size memory={value!r} in {self.show(file)}: more than the {MAX_MEMORY_BYTES} "
                                  "bytes a robot model may ask for")
                elif name.startswith("n"):  # njmax, nconmax, nstack, nuserdata, nkey, nuser_*
                    number = self.counts(file, element, name, "0")[0] if value.strip() != "-1" else 0.0
                    if number > MAX_SIZE_COUNT:
                        self.fail(f"size {name}={value!r} in {self.show(file)}: more than {MAX_SIZE_COUNT}")

    def check_asset(self, file: Path, base: Path, tag: str, name: str, value: str) -> None:
        """An asset file the model names: inside the folder, a regular file, within the size limits."""
        what = f"{tag} {name}={value!r} in {self.show(file)}"
        directories = ["", *self.dirs.get(base, {})]
        candidates = dict.fromkeys(b / d / value for b in (base, file.parent) for d in directories)
        for candidate in candidates:  # each place MuJoCo may look: every one must stay inside the folder
            self.inside(candidate, what)
            info = _stat(candidate)
            if info is None:  # not there: MuJoCo cannot read it either (and says so)
                continue
            resolved = self.resolve(candidate, what)
            if resolved in self.assets:
                continue
            if not stat.S_ISREG(info.st_mode):
                self.fail(f"{what}: {self.show(candidate)} is not a regular file")
            if info.st_size > MAX_ASSET_BYTES:
                self.fail(f"{what}: {self.show(candidate)} has {info.st_size} bytes, more than the {MAX_ASSET_BYTES} "
                          "bytes an asset file may have")
            self.assets.add(resolved)
            self.asset_bytes += info.st_size
            if self.asset_bytes > MAX_ASSETS_BYTES:
                self.fail(f"{what}: the model's asset files pass {MAX_ASSETS_BYTES} bytes")
            try:
                with open(candidate, "rb") as stream:
                    head = stream.read(24)
            except OSError as exc:
                self.fail(f"{what}: cannot read {self.show(candidate)}: {exc.strerror or exc}")
            if head[:8] == _PNG_SIGNATURE and len(head) == 24:  # its IHDR: what a decoder would allocate
                width, height = struct.unpack(">II", head[16:24])
                if width * height > MAX_TEXTURE_PIXELS:
                    self.fail(f"{what}: a PNG of {width} x {height} = {width * height} pixels, more than the "
                              f"{MAX_TEXTURE_PIXELS} an image may have")
