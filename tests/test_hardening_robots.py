"""Robot models read from ``MENAGERIE_ROOT`` (or any model file) are checked before MuJoCo reads them: the
listing and the "unknown robot" message read no model file, a model whose parse would take unbounded time or
memory is refused by name, and no file the model names may lie outside the robot's folder."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo is first imported: offscreen rendering

from seqmotion.sim import model_files as mf  # noqa: E402
from seqmotion.sim import robot_models as rb  # noqa: E402
from seqmotion.sim.backend import import_mujoco  # noqa: E402

mm = pytest.importorskip("mujoco_menagerie", reason="mujoco-menagerie is not installed (seqmotion[robots])")

NAME = "trossen_wx250s"
"""A Menagerie arm outside seqmotion's tables (no published joint count, no placement)."""
ENTRY = "wx250s.xml"

# A 6-joint arm written as Menagerie writes arms (position servos with a forcerange, an attachment site);
# {compiler}, {top} (includes, top-level sections), {asset} and {world} take the hostile parts.
ARM = """<mujoco model="tiny">
  <compiler angle="radian" autolimits="true" {compiler}/>
  {top}
  <asset>{asset}</asset>
  <worldbody>
    {world}
    <body name="base">
      <body name="link1" pos="0 0 0.1">
        <joint name="s" axis="0 0 1" range="-2.8 2.8"/>
        <inertial pos="0 0 0.1" mass="3" diaginertia="0.03 0.03 0.01"/>
        <body name="link2" pos="0 0 0.25">
          <joint name="l" axis="0 1 0" range="-2.8 2.8"/>
          <inertial pos="0 0 0.15" mass="2" diaginertia="0.02 0.02 0.004"/>
          <body name="link3" pos="0 0 0.3">
            <joint name="u" axis="0 1 0" range="-2.8 2.8"/>
            <inertial pos="0.12 0 0" mass="1.5" diaginertia="0.002 0.008 0.008"/>
            <body name="link4" pos="0.1 0 0">
              <joint name="r" axis="1 0 0" range="-2.8 2.8"/>
              <inertial pos="0.1 0 0" mass="0.8" diaginertia="0.001 0.003 0.003"/>
              <body name="link5" pos="0.18 0 0">
                <joint name="b" axis="0 1 0" range="-2.8 2.8"/>
                <inertial pos="0.02 0 0" mass="0.4" diaginertia="0.0004 0.0004 0.0004"/>
                <body name="link6" pos="0.06 0 0">
                  <joint name="t" axis="1 0 0" range="-3 3"/>
                  <inertial pos="0.01 0 0" mass="0.2" diaginertia="0.0002 0.0002 0.0002"/>
                  <site name="attachment_site" pos="0.02 0 0" quat="1 0 1 0"/>
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="a_s" joint="s" kp="300" forcerange="-40 40"/>
    <position name="a_l" joint="l" kp="300" forcerange="-60 60"/>
    <position name="a_u" joint="u" kp="200" forcerange="-30 30"/>
    <position name="a_r" joint="r" kp="50" forcerange="-12 12"/>
    <position name="a_b" joint="b" kp="50" forcerange="-12 12"/>
    <position name="a_t" joint="t" kp="50" forcerange="-5 5"/>
  </actuator>
</mujoco>
"""
HUGE_FLEX = '<flexcomp name="sheet" type="grid" count="300 300 1" spacing="0.01 0.01 0.01" dim="2"/>'
"""90 000 points: MuJoCo's parse of it grows as n⁴ (minutes)."""
OBJ = "v 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nv 0 0 0.01\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n"
"""A 1 cm tetrahedron."""


def arm(**parts: str) -> str:
    return ARM.format(**{"compiler": "", "top": "", "asset": "", "world": "", **parts})


def png(width: int, height: int) -> bytes:
    """A PNG whose header declares ``width × height`` (a large one holds a few bytes only: a decoder would allocate
    the rest)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    rows = bytes((1 + 3 * width) * height if width * height <= 64 else 7)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b"")


@pytest.fixture
def root(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An empty MENAGERIE_ROOT with a folder for the arm (its placement fixed: loads skip the home-posture IK)."""
    tree = tmp_path / "menagerie"
    (tree / NAME).mkdir(parents=True)
    monkeypatch.setenv("MENAGERIE_ROOT", str(tree))
    monkeypatch.setitem(rb.PLACEMENTS, f"menagerie:{NAME}", rb.Placement(home=(0.0, 0.5, 1.0, 0.0, -1.0, 0.0)))
    rb.get_robot.cache_clear()
    yield tree
    rb.get_robot.cache_clear()


@pytest.fixture
def mujoco_reads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Every model file MuJoCo is asked to parse; the parse itself fails (a hostile file is never really read)."""
    mujoco = import_mujoco()
    calls: list[str] = []

    def spy(path: str, *args: object, **kwargs: object) -> None:
        calls.append(str(path))
        raise RuntimeError("MuJoCo was asked to parse it")

    monkeypatch.setattr(mujoco.MjSpec, "from_file", staticmethod(spy))
    return calls


def test_listing_and_the_unknown_robot_message_read_no_model_file(root, mujoco_reads, capsys):
    (root / NAME / ENTRY).write_text(arm(world=HUGE_FLEX))
    listed = {r.name: r for r in rb.robots()}
    assert f"menagerie:{NAME}" in listed  # what is on disk, by name
    assert listed[f"menagerie:{NAME}"].dof is None  # unknown without reading the file
    assert listed[f"menagerie:{NAME}"].path == root / NAME / ENTRY
    with pytest.raises(ValueError, match=f"unknown robot 'typo'.*menagerie:{NAME}"):
        rb.get_robot("typo")
    from seqmotion.cli import main

    assert main(["robots"]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith(f"menagerie:{NAME} "))
    assert "? joints" in row
    assert main(["robots", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows[f"menagerie:{NAME}"]["dof"] is None
    assert mujoco_reads == []


HOSTILE_SIZES = {
    # name: (the arm's parts, files written beside it {relative path: bytes}, words the refusal names)
    "a 300 x 300 flexcomp grid": (dict(world=HUGE_FLEX), {}, ["flexcomp", "'sheet'", "90000 points"]),
    "a flexcomp from a mesh file": (
        dict(world='<flexcomp name="skin" type="mesh" file="m.obj" dim="2"/>'), {"m.obj": OBJ.encode()},
        ["flexcomp", "'skin'", "file"]),
    "a flex of many vertices": (
        dict(top='<deformable><flex name="f" dim="1" body="world" vertex="' + "0 0 0 " * 5000 + '"/></deformable>'),
        {}, ["flex", "'f'", "5000 points"]),
    "nested replicates": (
        dict(world='<replicate count="1000" offset="0.01 0 0"><replicate count="1000" offset="0 0.01 0">'
                   '<body><geom size="0.001"/></body></replicate></replicate>'), {}, ["elements", "replicate"]),
    "a NaN replicate count": (
        dict(world='<replicate count="nan" offset="0.01 0 0"><body><geom size="0.001"/></body></replicate>'), {},
        ["replicate", "count", "'nan'"]),
    "a huge built-in texture": (
        dict(asset='<texture name="t" type="2d" builtin="checker" width="100000" height="100000"/>'), {},
        ["texture", "'t'", "10000000000 pixels"]),
    "a PNG declaring 100000 x 100000": (
        dict(asset='<texture name="t" type="2d" file="t.png"/>'), {"t.png": png(100_000, 100_000)},
        ["t.png", "10000000000 pixels"]),
    "a huge height field": (
        dict(asset='<hfield name="h" nrow="100000" ncol="100000" size="1 1 1 1"/>'), {},
        ["hfield", "'h'", "10000000000 samples"]),
    "a built-in mesh at a huge resolution": (
        dict(asset='<mesh name="m" builtin="supersphere" params="5000 1 1"/>'), {}, ["mesh", "'m'", "5000"]),
    "an arena of 100 GB": (dict(top='<size memory="100G"/>'), {}, ["size", "memory", "100G"]),
    "an entity bomb": (
        dict(), {}, ["DOCTYPE"]),
    "a UTF-16 file": (dict(), {}, ["UTF-8"]),
    "an include of itself": (dict(top=f'<include file="{ENTRY}"/>'), {}, ["include", "deeper"]),
}


def _write(folder: Path, parts: dict[str, str], files: dict[str, bytes], case: str) -> Path:
    for relative, data in files.items():
        (folder / relative).parent.mkdir(parents=True, exist_ok=True)
        (folder / relative).write_bytes(data)
    path = folder / ENTRY
    text = arm(**parts)
    if case == "an entity bomb":
        lol = "".join(f'<!ENTITY l{i} "{f"&l{i - 1};" * 10 if i else "lol"}">' for i in range(10))
        text = f'<?xml version="1.0"?>\n<!DOCTYPE m [{lol}]>\n' + text.replace('model="tiny"', 'model="&l9;"')
    path.write_bytes(text.encode("utf-16") if case == "a UTF-16 file" else text.encode())
    return path


@pytest.mark.parametrize("case", HOSTILE_SIZES)
def test_a_model_too_large_to_parse_in_bounded_time_is_refused_by_name(root, mujoco_reads, case):
    parts, files, words = HOSTILE_SIZES[case]
    path = _write(root / NAME, parts, files, case)
    with pytest.raises(ValueError) as err:
        rb.get_robot(f"menagerie:{NAME}")
    message = str(err.value)
    assert str(path) in message and all(w in message for w in words) and "\n" not in message, message
    assert mujoco_reads == []


def test_the_size_limits_cover_xml_and_asset_files(root, mujoco_reads, monkeypatch):
    folder = root / NAME
    (folder / "m.obj").write_text(OBJ * 40)
    path = folder / ENTRY
    path.write_text(arm(asset='<mesh name="m" file="m.obj"/>'))
    monkeypatch.setattr(mf, "MAX_ASSET_BYTES", 1000, raising=False)
    with pytest.raises(ValueError, match=rf"m\.obj.* {len(OBJ) * 40} bytes.*1000"):
        rb.get_robot(f"menagerie:{NAME}")
    monkeypatch.setattr(mf, "MAX_XML_BYTES", 500, raising=False)
    with pytest.raises(ValueError, match=rf"{path}.* \d+ bytes.*500"):
        rb.get_robot(f"menagerie:{NAME}")
    monkeypatch.setattr(mf, "MAX_XML_BYTES", 2**20, raising=False)
    path.write_text(arm(compiler='meshdir="a" texturedir="b"',
                        asset='<mesh name="m" file="m.obj"/><mesh name="n" file="n.obj"/>'))
    monkeypatch.setattr(mf, "MAX_ASSET_NAMES", 1, raising=False)
    with pytest.raises(ValueError, match=r"more than 1 asset file names, at mesh file='[mn]\.obj'"):
        rb.get_robot(f"menagerie:{NAME}")
    monkeypatch.setattr(mf, "MAX_ASSET_NAMES", 100, raising=False)
    monkeypatch.setattr(mf, "MAX_ASSET_DIRS", 1, raising=False)
    with pytest.raises(ValueError, match=r"more than 1 different asset directories, at compiler texturedir='b'"):
        rb.get_robot(f"menagerie:{NAME}")
    assert mujoco_reads == []


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
def test_a_mesh_that_is_a_pipe_is_refused_rather_than_read_forever(root, mujoco_reads):
    folder = root / NAME
    os.mkfifo(folder / "m.obj")
    (folder / ENTRY).write_text(arm(asset='<mesh name="m" file="m.obj"/>'))
    with pytest.raises(ValueError, match=r"m\.obj.*not a regular file"):
        rb.get_robot(f"menagerie:{NAME}")
    assert mujoco_reads == []


def _outside(tmp_path: Path) -> Path:
    """Files outside MENAGERIE_ROOT a hostile model points at."""
    out = tmp_path / "outside"
    out.mkdir(exist_ok=True)
    (out / "frag.xml").write_text('<mujoco><asset><texture name="stolen" type="2d" builtin="checker" width="8" '
                                  'height="8"/></asset></mujoco>')
    (out / "m.obj").write_text(OBJ)
    (out / "t.png").write_bytes(png(1, 1))
    return out


ESCAPES = {
    # name: (the arm's parts with {out} the outside folder, files beside the arm, words the refusal names)
    "an absolute include": (dict(top='<include file="{out}/frag.xml"/>'), {}, ["include", "absolute"]),
    "an include climbing out": (dict(top='<include file="../../outside/frag.xml"/>'), {}, ["include", "outside"]),
    "an absolute include inside an include": (
        dict(top='<include file="parts/inner.xml"/>'),
        {"parts/inner.xml": b'<mujoco><include file="{out}/frag.xml"/></mujoco>'}, ["inner.xml", "absolute"]),
    "an absolute mesh": (dict(asset='<mesh name="m" file="{out}/m.obj"/>'), {}, ["mesh", "absolute"]),
    "a mesh climbing out": (dict(asset='<mesh name="m" file="../../outside/m.obj"/>'), {}, ["mesh", "outside"]),
    "an absolute texture": (dict(asset='<texture name="t" type="2d" file="{out}/t.png"/>'), {}, ["texture"]),
    "an absolute cube face": (
        dict(asset='<texture name="t" type="cube" fileright="{out}/t.png" fileleft="t.png"/>'), {}, ["fileright"]),
    "an absolute height field": (
        dict(asset='<hfield name="h" file="{out}/t.png" size="1 1 1 1"/>'), {}, ["hfield", "absolute"]),
    "an absolute meshdir": (
        dict(compiler='meshdir="{out}"', asset='<mesh name="m" file="m.obj"/>'), {}, ["meshdir", "absolute"]),
    "a texturedir climbing out": (
        dict(compiler='texturedir="../../outside"', asset='<texture name="t" type="2d" file="t.png"/>'), {},
        ["texturedir", "outside"]),
    "an absolute assetdir": (dict(compiler='assetdir="{out}"'), {}, ["assetdir", "absolute"]),
    "an absolute sub-model": (dict(asset='<model name="sub" file="{out}/frag.xml"/>'), {}, ["model", "absolute"]),
    "a symlinked mesh": (dict(asset='<mesh name="m" file="assets/m.obj"/>'), {"assets/m.obj": "{out}/m.obj"},
                         ["assets/m.obj", "outside"]),
}


@pytest.mark.parametrize("case", ESCAPES)
def test_a_model_reading_files_outside_its_folder_is_refused_before_mujoco_reads_it(tmp_path, root, mujoco_reads,
                                                                                   case):
    out, (parts, files, words) = _outside(tmp_path), ESCAPES[case]
    folder = root / NAME
    for relative, data in files.items():
        (folder / relative).parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, str):  # a symbolic link to the outside
            (folder / relative).symlink_to(data.format(out=out))
        else:
            (folder / relative).write_bytes(data.replace(b"{out}", str(out).encode()))
    path = folder / ENTRY
    path.write_text(arm(**{k: v.format(out=out) for k, v in parts.items()}))
    with pytest.raises(ValueError) as err:
        rb.get_robot(f"menagerie:{NAME}")
    message = str(err.value)
    assert str(path) in message and all(w in message for w in words) and "\n" not in message, message
    assert mujoco_reads == []


def test_a_robot_folder_or_entry_file_linked_from_outside_the_root_is_refused(tmp_path, root, mujoco_reads):
    out = _outside(tmp_path)
    (out / ENTRY).write_text(arm())
    (root / NAME / ENTRY).symlink_to(out / ENTRY)
    with pytest.raises(ValueError, match=rf"{root / NAME / ENTRY}.*outside"):
        rb.get_robot(f"menagerie:{NAME}")
    (root / NAME / ENTRY).unlink()
    (root / NAME).rmdir()
    (root / NAME).symlink_to(out, target_is_directory=True)
    with pytest.raises(ValueError, match=rf"{root / NAME}.*outside"):
        rb.get_robot(f"menagerie:{NAME}")
    assert mujoco_reads == []


def test_an_absolute_include_that_mujoco_would_load_is_refused(tmp_path, root):
    out = _outside(tmp_path)
    (root / NAME / ENTRY).write_text(arm(top=f'<include file="{out}/frag.xml"/>'))
    with pytest.raises(ValueError, match="include.*absolute"):
        rb.get_robot(f"menagerie:{NAME}")


def test_a_model_with_its_parts_inside_its_folder_loads(root):
    folder = root / NAME
    (folder / "assets").mkdir()
    (folder / "assets" / "m.obj").write_text(OBJ)
    (folder / "assets" / "t.png").write_bytes(png(1, 1))
    (folder / "parts").mkdir()
    (folder / "parts" / "look.xml").write_text('<mujoco><asset><material name="mat" texture="t"/></asset></mujoco>')
    (folder / ENTRY).write_text(arm(compiler='meshdir="assets" texturedir="parts/../assets"',
                                    top='<include file="parts/look.xml"/>',
                                    asset='<mesh name="m" file="m.obj"/><texture name="t" type="2d" file="t.png"/>',
                                    world='<geom type="mesh" mesh="m" material="mat" contype="0" conaffinity="0"/>'))
    robot = rb.get_robot(f"menagerie:{NAME}")
    assert robot.joints == ("s", "l", "u", "r", "b", "t")
    assert robot.spec().compile().nmesh == 1


@pytest.mark.skipif(rb.robosuite_root() is None, reason="robosuite's robot model files are not installed")
def test_robosuites_arms_pass_the_checks():
    for arm_name in rb.ROBOSUITE_ARMS:
        path = rb.robosuite_root() / arm_name / "robot.xml"
        if path.is_file():
            mf.check_model_file(path, path.parent)


HANG = f"""
import contextlib, io, json, os
from pathlib import Path
import numpy as np
root = Path("menagerie") / "{NAME}"
root.mkdir(parents=True)
(root / "{ENTRY}").write_text({arm(world=HUGE_FLEX)!r})
os.environ["MENAGERIE_ROOT"] = str(root.parent.resolve())
np.savez("t.npz", states=np.zeros((50, 6)))
from seqmotion.cli import main
for argv in (["robots"], ["simulate", "pancake", "--trajectory", "t.npz", "--robot", "typo"],
             ["simulate", "pancake", "--trajectory", "t.npz", "--robot", "menagerie:{NAME}"]):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main(argv)
        except SystemExit as exc:
            rc = exc.code
    print("RESULT", json.dumps([argv[-1], rc, out.getvalue(), err.getvalue()]), flush=True)
"""


def test_robot_commands_answer_quickly_with_a_huge_model_in_the_root(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(Path(rb.__file__).parents[2]), "MUJOCO_GL": "egl"}
    env.pop("MENAGERIE_ROOT", None)
    try:
        done = subprocess.run([sys.executable, "-c", HANG], cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail("a robot command hung on the 300 x 300 flexcomp")
    results = {r[0]: r[1:] for r in (json.loads(line[7:]) for line in done.stdout.splitlines()
                                      if line.startswith("RESULT "))}
    assert set(results) == {"robots", "typo", f"menagerie:{NAME}"}, done.stderr[-2000:]
    rc, out, err = results["robots"]
    assert rc == 0 and f"menagerie:{NAME}" in out, (out, err)
    rc, out, err = results["typo"]
    assert rc == 2 and err.startswith("seqmotion simulate: error: unknown robot 'typo'") and err.count("\n") == 1
    assert f"menagerie:{NAME}" in err  # listed among the robots available here
    rc, out, err = results[f"menagerie:{NAME}"]
    assert rc == 2 and err.startswith("seqmotion simulate: error: ") and "90000 points" in err, err
