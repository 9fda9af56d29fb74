"""Issue 31, defects 9 and 10: the ONNX bundle's contract is validated and sealed, and ``export-onnx`` replaces
a bundle whole.

* 9: every field the runner reads is checked against a schema (types, finite, positive, known kinds, plain
  graph file names inside the bundle); ``contract.json`` carries the SHA-256 of each graph and of itself, so an
  edited contract, a swapped graph and an unsealed (pre-seal) bundle are named errors.
* 10: the bundle is written into a temporary sibling folder and swapped in; a failure or a kill at any step
  leaves the previous bundle or the new one loadable (never a mix), the next export cleans up, and a folder
  that is not a previous bundle is never replaced.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import seqmotion as sm
from seqmotion import io as sm_io
from seqmotion.cli import main as cli_main

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from seqmotion.deploy import OnnxModel, export_onnx  # noqa: E402
from seqmotion.deploy import export as export_module  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def _one_thread(one_thread):
    """Every test here runs torch on one thread (see conftest)."""


@pytest.fixture(scope="module")
def pristine(shipped_bundles):
    """Two exported bundles that differ in every graph: pancake (with a constraint graph) and sliding (without);
    the session's (conftest), read or copied, never changed."""
    return shipped_bundles


@pytest.fixture
def pancake(pristine, tmp_path):
    """A fresh copy of the pancake bundle that a test may damage."""
    return Path(shutil.copytree(pristine / "pancake", tmp_path / "bundle"))


def read(folder: Path) -> dict:
    return json.loads((folder / "contract.json").read_text())


def write(folder: Path, contract: object, *, reseal: bool = True) -> None:
    """Write ``contract`` into ``folder``; ``reseal``: with a fresh self-hash, as a (buggy) exporter would, so
    the schema, not the seal, has to catch what is wrong."""
    if reseal and isinstance(contract, dict):
        body = {k: v for k, v in contract.items() if k != "contract_sha256"}
        canonical = json.dumps(body, sort_keys=True, separators=(",", ":")).encode()
        contract["contract_sha256"] = hashlib.sha256(canonical).hexdigest()
    (folder / "contract.json").write_text(json.dumps(contract, indent=2))


def files_of(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def leftovers(parent: Path) -> list[str]:
    """Temporaries and set-aside bundles an export left beside its output."""
    return sorted(p.name for p in parent.iterdir() if sm_io.TEMP_MARK in p.name or p.name.endswith(".previous"))


# --- 9. the seal -------------------------------------------------------------------------------------------


def test_an_edited_contract_is_refused(pancake):
    """The issue's example: dynamics.dt = 1.0 changed the outputs by 127 m/s² and loaded silently."""
    contract = read(pancake)
    contract["dynamics"]["dt"] = 1.0
    write(pancake, contract, reseal=False)
    with pytest.raises(ValueError, match=r"contract\.json was edited after export"):
        OnnxModel(pancake)


def test_a_swapped_or_damaged_graph_is_refused(pristine, pancake):
    shutil.copyfile(pristine / "sliding" / "encoder.onnx", pancake / "encoder.onnx")
    with pytest.raises(ValueError, match=r"encoder\.onnx does not match its hash"):
        OnnxModel(pancake)
    shutil.copyfile(pristine / "pancake" / "encoder.onnx", pancake / "encoder.onnx")
    data = (pancake / "decoder_step.onnx").read_bytes()
    (pancake / "decoder_step.onnx").write_bytes(data[:-1] + bytes([data[-1] ^ 1]))  # one flipped bit
    with pytest.raises(ValueError, match=r"decoder_step\.onnx does not match its hash"):
        OnnxModel(pancake)
    (pancake / "decoder_step.onnx").unlink()
    with pytest.raises(ValueError, match=r"decoder_step\.onnx.*missing"):
        OnnxModel(pancake)


def test_a_bundle_without_hashes_is_refused_with_advice_to_re_export(pancake):
    """Bundles from before the seal carry no hashes: refused (not accepted silently), with what to do."""
    contract = read(pancake)
    contract.pop("contract_sha256", None)
    contract.pop("sha256", None)
    write(pancake, contract, reseal=False)
    with pytest.raises(ValueError, match=r"not sealed.*re-export.*export-onnx"):
        OnnxModel(pancake)


def test_a_bundle_of_the_former_format_is_refused_and_an_export_replaces_it(pancake):
    """A bundle exported before the dynamics were a graph (format 1: the dynamics named by kind for a NumPy copy of
    them, numpy_physics.py beside the runner) is refused with the advice to re-export; re-exporting replaces it."""
    contract = read(pancake)
    contract["format"] = "seqmotion-stepper/1"
    contract["dynamics"] = {"kind": "double_integrator", "dim": 3, "dt": 0.001}
    contract["files"].pop("dynamics")
    contract["sha256"].pop("dynamics")
    (pancake / "dynamics.onnx").unlink()
    (pancake / "numpy_physics.py").write_text("# the former runner's NumPy dynamics\n")
    write(pancake, contract)
    with pytest.raises(ValueError, match=r"format 'seqmotion-stepper/1'; this runner reads 'seqmotion-stepper/2'.*"
                                         r"re-export the model: seqmotion export-onnx MODEL"):
        OnnxModel(pancake)
    export_onnx(sm.load_pretrained("pancake"), pancake)
    assert OnnxModel(pancake).contract["format"] == "seqmotion-stepper/2" and "dynamics.onnx" in files_of(pancake)


def test_the_exported_contract_carries_the_hashes(pristine):
    folder = pristine / "pancake"
    contract = read(folder)
    for key, name in contract["files"].items():
        if name is not None:
            assert contract["sha256"][key] == hashlib.sha256((folder / name).read_bytes()).hexdigest()
    body = {k: v for k, v in contract.items() if k != "contract_sha256"}
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":")).encode()
    assert contract["contract_sha256"] == hashlib.sha256(canonical).hexdigest()


def test_the_standalone_runner_checks_the_seal_too(pancake):
    """The copy of the runner in the bundle (NumPy + onnxruntime, no seqmotion) refuses an edited contract."""
    contract = read(pancake)
    contract["chunk"] = 25
    write(pancake, contract, reseal=False)
    code = f"""
import sys
sys.modules["torch"] = None
sys.modules["seqmotion"] = None
sys.path.insert(0, {str(pancake)!r})
from onnx_stepper import OnnxModel
try:
    OnnxModel({str(pancake)!r})
except ValueError as exc:
    print(exc)
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=pancake.parent)
    assert done.returncode == 0, done.stderr
    assert "was edited after export" in done.stdout


# --- 9. the schema -----------------------------------------------------------------------------------------


def _set(path: str, value: object):
    def edit(c: dict) -> None:
        *parents, last = path.split(".")
        for key in parents:
            c = c[key]
        c[last] = value
    return edit


def _pop(path: str):
    def edit(c: dict) -> None:
        *parents, last = path.split(".")
        for key in parents:
            c = c[key]
        del c[last]
    return edit


def _both(*edits):
    def edit(c: dict) -> None:
        for e in edits:
            e(c)
    return edit


NAN = float("nan")
BAD = {  # what a sealed but wrong contract holds → what the error names
    "files missing (was KeyError)": (_pop("files"), r"lacks the field 'files'"),
    "files not an object": (_set("files", ["encoder.onnx"]), r"'files' must be an object"),
    "chunk 0 (was ZeroDivisionError)": (_set("chunk", 0), r"'chunk' must be an integer >= 1, got 0"),
    "chunk 2.5": (_set("chunk", 2.5), r"'chunk' must be an integer >= 1, got 2\.5"),
    "chunk true": (_set("chunk", True), r"'chunk' must be an integer >= 1, got True"),
    "layers as text": (_set("layers", "2"), r"'layers' must be an integer >= 1"),
    "dt negative": (_both(_set("dt", -0.001), _set("dynamics.dt", -0.001)), r"'dt' must be a finite number > 0"),
    "dt NaN": (_set("dt", NAN), r"'dt' must be a finite number > 0, got nan"),
    "dt differs from the dynamics'": (_set("dynamics.dt", 1.0), r"'dynamics\.dt' \(1\.0\) differs from 'dt'"),
    "NaN limit (was blamed on the measured states)": (_set("stop.accel_limit", [NAN, 10.0, 100.0]),
                                                      r"'stop\.accel_limit' must be a non-empty list"),
    "zero limit": (_set("stop.accel_limit", [0.0, 10.0, 100.0]), r"'stop\.accel_limit'"),
    "limits per output": (_set("stop.accel_limit", [10.0]), r"'stop\.accel_limit' must hold 3"),
    "shrink above 1": (_set("stop.shrink", [1.5]), r"'stop\.shrink'"),
    "tau 0": (_set("stop.tau", 0), r"'stop\.tau' must be a finite number > 0"),
    "rest velocity inf": (_set("stop.rest_velocity", float("inf")), r"'stop\.rest_velocity'"),
    "stop missing": (_pop("stop"), r"lacks the field 'stop'"),
    "default length 1": (_set("default_length", 1), r"'default_length' must be null or an integer >= 2"),
    "dynamics without a graph": (_pop("dynamics.graph"), r"lacks the field 'dynamics\.graph'"),
    "dynamics graph not the bundle's": (_set("dynamics.graph", "decoder_step.onnx"),
                                        r"'dynamics\.graph' \('decoder_step\.onnx'\) differs from 'files\.dynamics'"),
    "dynamics graph outside": (_set("dynamics.graph", "../dynamics.onnx"), r"'dynamics\.graph' must be a plain"),
    "dynamics chunk": (_set("dynamics.chunk", 25), r"'dynamics\.chunk' \(25\) differs from 'chunk' \(50\)"),
    "dynamics chunk 0": (_set("dynamics.chunk", 0), r"'dynamics\.chunk' must be an integer >= 1"),
    "no physics": (_pop("dynamics.physics"), r"lacks the field 'dynamics\.physics'"),
    "physics names as text": (_set("dynamics.physics.names", "mu"), r"'dynamics\.physics\.names' must be a list of"),
    "physics names twice": (_set("dynamics.physics.names", ["mu", "mu"]), r"'dynamics\.physics\.names'.*distinct"),
    "physics input not a field": (_set("dynamics.physics.inputs", ["gravity"]),
                                  r"'dynamics\.physics\.inputs' \(\['gravity'\]\) must be fields of"),
    "physics value missing": (_set("dynamics.physics.values", {}), r"'dynamics\.physics\.values' must hold one value "
                                                                   r"for each of \['mu'\]"),
    "physics value NaN": (_set("dynamics.physics.values.mu", NAN),
                          r"'dynamics\.physics\.values\.mu' must be a finite number, got nan"),
    "physics value text": (_set("dynamics.physics.values.mu", "1"), r"'dynamics\.physics\.values\.mu' must be"),
    "unknown closed form": (_set("dynamics.closed_form", "runge_kutta"),
                            r"'dynamics\.closed_form' must be null or one of \['double_integrator'\]"),
    "closed form missing": (_pop("dynamics.closed_form"), r"lacks the field 'dynamics\.closed_form'"),
    "no dynamics graph file": (_both(_pop("files.dynamics"), _pop("sha256.dynamics")),
                               r"lacks the field 'files\.dynamics'"),
    "latent size": (_set("latent_dim", 100), r"'latent_dim' \(100\) must be layers \* hidden = 128"),
    "empty layout": (_set("state_layout.names", []), r"'state_layout\.names' must be a non-empty list"),
    "units per name": (_set("input_layout.units", ["m"]), r"'input_layout\.units' must hold one unit per name"),
    "velocity column out of range": (_set("velocity_columns", [3, 4, 99]), r"'velocity_columns'"),
    "constraint without its graph": (_both(_set("files.violation", None), _pop("sha256.violation")),
                                     r"'constraint' is true but 'files\.violation' is null"),
    "absolute graph name": (_set("files.encoder", "/etc/passwd"), r"'files\.encoder' must be a plain file name"),
    "graph outside the bundle": (_set("files.encoder", "../pancake/encoder.onnx"), r"'files\.encoder' must be a plain"),
    "graph in a sub-folder": (_set("files.decoder_step", "graphs/decoder_step.onnx"), r"'files\.decoder_step' must"),
    "graph named ..": (_set("files.violation", ".."), r"'files\.violation' must be null or a plain file name"),
    "graph is not a graph": (_set("files.encoder", "onnx_stepper.py"), r"'files\.encoder' must be a plain file name"),
    "unknown graph": (_set("files.extra", "extra.onnx"), r"'files\.extra' is not a graph of the bundle"),
    "a graph without a hash": (_pop("sha256.encoder"), r"'sha256' must hold a hash for each graph"),
    "a hash that is not one": (_set("sha256.encoder", "zz"), r"'sha256\.encoder' must be a SHA-256 hex digest"),
    "another format": (_set("format", "seqmotion-stepper/0"), r"format 'seqmotion-stepper/0'.*re-export"),
    "unknown stop outputs": (_set("stop.outputs", "torques"),
                             r"'stop\.outputs' must be null or one of \['accelerations', 'outputs_for'\]"),
    "stop outputs_for without its graph": (_set("stop.outputs", "outputs_for"),
                                           r"'stop\.outputs' is 'outputs_for' but 'files\.outputs_for' is absent"),
    "accelerations that are not": (_set("accel_layout.units", ["N", "N", "N·m"]),
                                   r"'stop\.outputs' is 'accelerations' but the outputs \(N, N, N·m\) are not"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_the_schema_names_the_bad_field_and_the_bundle(pancake, case):
    edit, message = BAD[case]
    contract = read(pancake)
    edit(contract)
    write(pancake, contract)
    with pytest.raises(ValueError) as info:
        OnnxModel(pancake)
    assert re.search(message, str(info.value)), str(info.value)
    assert str(pancake) in str(info.value)


SLIDING_BAD = {
    "friction value missing": (_pop("dynamics.physics.values.mu_dyn"),
                                r"'dynamics\.physics\.values' must hold one value for each of \['mu', 'mu_dyn'\]"),
    "friction infinite": (_set("dynamics.physics.values.mu", float("inf")), r"'dynamics\.physics\.values\.mu'"),
    "inputs out of order": (_set("dynamics.physics.inputs", ["mu_dyn", "mu"]), r"in their order"),
    "an input twice": (_set("dynamics.physics.inputs", ["mu", "mu"]), r"'dynamics\.physics\.inputs' must be a list"),
    "not a double integrator": (_set("dynamics.closed_form", "double_integrator"),
                                r"names the double integrator.*not 8 states for 2 outputs reading \['mu', 'mu_dyn'\]"),
}


@pytest.mark.parametrize("case", list(SLIDING_BAD))
def test_the_schema_checks_the_physics_of_the_dynamics(pristine, tmp_path, case):
    folder = Path(shutil.copytree(pristine / "sliding", tmp_path / "bundle"))
    edit, message = SLIDING_BAD[case]
    contract = read(folder)
    edit(contract)
    write(folder, contract)
    with pytest.raises(ValueError, match=message):
        OnnxModel(folder)


def test_a_bundle_from_before_stop_outputs_still_runs_and_stops_alike(pristine, pancake):
    """Format-2 bundles exported before ``stop.outputs`` existed hold no such field: for a task whose outputs are
    accelerations (pancake) they load and stop exactly as a fresh export does (a torque task's are refused:
    test_cup_arm.py)."""
    from seqmotion.deploy import OnnxStepper

    contract = read(pancake)
    assert contract["stop"]["outputs"] == "accelerations" and "outputs_for" not in contract["files"]
    del contract["stop"]["outputs"]
    write(pancake, contract)
    sketch = sm.tasks.pancake.data.straight((0.0, 0.1, -0.3), 120)
    gens = [OnnxStepper(folder, sketch) for folder in (pristine / "pancake", pancake)]
    outputs = [[g.step()] for g in gens]
    x = sketch[:1]
    while gens[0].time < 119 + 300:
        states = gens[0].onnx.predict(x, outputs[0][-1][None])
        x = states[:, -1]
        for g, out in zip(gens, outputs, strict=True):
            out.append(g.step(states[0]))
    np.testing.assert_array_equal(np.concatenate(outputs[0]), np.concatenate(outputs[1]))
    assert np.abs(outputs[0][-1]).max() < np.abs(np.concatenate(outputs[0][:3])).max()  # it was stopping


def test_a_graph_name_that_leaves_the_bundle_reads_nothing_outside(pristine, pancake):
    """``../`` in a (sealed) contract loaded a valid graph from beside the bundle; now it is refused by name,
    and so is a graph in the bundle that is a link to a file outside it."""
    contract = read(pancake)
    contract["files"]["encoder"] = "../../bundles0/sliding/encoder.onnx"
    write(pancake, contract)
    with pytest.raises(ValueError, match="plain file name"):
        OnnxModel(pancake)
    contract["files"]["encoder"] = "encoder.onnx"
    write(pancake, contract)
    (pancake / "encoder.onnx").unlink()
    (pancake / "encoder.onnx").symlink_to(pristine / "pancake" / "encoder.onnx")
    with pytest.raises(ValueError, match=r"encoder\.onnx.*outside the bundle"):
        OnnxModel(pancake)


def test_not_json_or_not_an_object(pancake):
    (pancake / "contract.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match="must hold a JSON object"):
        OnnxModel(pancake)
    (pancake / "contract.json").write_text("{")
    with pytest.raises(ValueError, match="not valid JSON"):
        OnnxModel(pancake)


def test_export_refuses_a_contract_the_runner_would_refuse(pristine, tmp_path, monkeypatch):
    """A model with a NaN output scale was exported and its NaN stop limit later blamed on the measured states."""
    out = Path(shutil.copytree(pristine / "sliding", tmp_path / "out"))
    before = files_of(out)
    real = export_module.stepper_contract

    def nan_limit(model, dynamics, physics):
        contract = real(model, dynamics, physics)
        contract["stop"]["accel_limit"][0] = NAN
        return contract

    monkeypatch.setattr(export_module, "stepper_contract", nan_limit)
    with pytest.raises(ValueError, match=r"'stop\.accel_limit' must be a non-empty list.*finite"):
        export_onnx(sm.load_pretrained("pancake"), out)
    assert files_of(out) == before and not leftovers(tmp_path)


# --- 10. the whole bundle at once ----------------------------------------------------------------------------


def test_an_export_replaces_the_whole_previous_bundle(tmp_path):
    out = tmp_path / "out"
    export_onnx(sm.load_pretrained("pancake"), out, int8=True)
    assert {"violation.onnx", "decoder_step.int8.onnx"} <= set(files_of(out))
    export_onnx(sm.load_pretrained("sliding"), out)
    assert set(files_of(out)) == {"contract.json", "encoder.onnx", "decoder_step.onnx", "dynamics.onnx",
                                  "dynamics_sample.onnx", *export_module.RUNNER_FILES,
                                  "stepper.py"}  # no stale pancake graphs
    assert OnnxModel(out).contract["task"] == "sliding"
    assert not leftovers(tmp_path)
    empty = tmp_path / "empty"
    empty.mkdir()
    export_onnx(sm.load_pretrained("sliding"), empty)  # an empty folder is fine
    assert OnnxModel(empty).contract["task"] == "sliding"


def test_export_refuses_a_folder_that_is_not_a_bundle(pristine, tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match=r"not empty and not an exported model.*notes\.txt"):
        export_onnx(sm.load_pretrained("sliding"), mine)
    assert cli_main(["export-onnx", "sliding", str(mine)]) == 2
    err = capsys.readouterr().err
    assert "not an exported model" in err and len(err.strip().splitlines()) == 1
    assert [p.name for p in mine.iterdir()] == ["notes.txt"]
    bundle = Path(shutil.copytree(pristine / "pancake", tmp_path / "bundle"))
    (bundle / "robot.py").write_text("# the user's own script beside the graphs")
    with pytest.raises(ValueError, match=r"robot\.py"):
        export_onnx(sm.load_pretrained("sliding"), bundle)
    assert (bundle / "robot.py").exists() and read(bundle)["task"] == "pancake"
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="not a folder"):
        export_onnx(sm.load_pretrained("sliding"), tmp_path / "file")
    assert not leftovers(tmp_path)


def test_export_through_a_link_or_from_inside_the_bundle(pristine, tmp_path, monkeypatch):
    """A link to a bundle keeps pointing at the (replaced) bundle; the folder one works in is not moved away."""
    real = Path(shutil.copytree(pristine / "pancake", tmp_path / "real"))
    (tmp_path / "link").symlink_to(real, target_is_directory=True)
    export_onnx(sm.load_pretrained("sliding"), tmp_path / "link")
    assert (tmp_path / "link").is_symlink() and read(real)["task"] == "sliding"
    monkeypatch.chdir(real)
    with pytest.raises(ValueError, match="holds the current directory"):
        export_onnx(sm.load_pretrained("sliding"), ".")
    assert read(real)["task"] == "sliding" and not leftovers(tmp_path)


def _fail_at(n: int, real):
    calls = {"n": 0}

    def failing(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == n:
            raise OSError(28, "No space left on device")
        return real(*args, **kwargs)
    return failing


@pytest.mark.parametrize("where", ["replace1", "replace2", "fsync1", "fsync5"])
def test_a_failed_export_leaves_the_previous_bundle_whole(pristine, tmp_path, monkeypatch, where):
    """A failure at the n-th rename (the old code renamed each file into place: a failure at the second left a new
    encoder with the old decoder and contract) or the n-th flush: the previous bundle, byte for byte."""
    out = Path(shutil.copytree(pristine / "pancake", tmp_path / "out"))
    before = files_of(out)
    name, n = where[:-1], int(where[-1])
    monkeypatch.setattr(os, name, _fail_at(n, getattr(os, name)))
    with pytest.raises(OSError, match="No space left"):  # a re-export: its contract differs from the bundle's
        export_onnx(sm.load_pretrained("pancake"), out, source="a re-export")
    monkeypatch.undo()
    assert files_of(out) == before
    assert OnnxModel(out).contract["source"] == "pancake"
    assert not leftovers(tmp_path)


KILLED = 77


def _killed_swap(out: Path, files: dict[str, bytes], at: str, n: int) -> int:
    """Run ``write_bundle(out, files)`` in a forked child that dies (SIGKILL: no clean-up runs) at the n-th
    ``at``: a file write (half the bytes written), an ``os.replace`` or ``os.fsync`` (before it), or the
    removal of the set-aside bundle (after one file of it is deleted). Returns how the child ended: KILLED
    when the kill point was reached, 0 when the swap finished first."""
    pid = os.fork()
    if pid == 0:  # the child: only file operations, no torch
        code = 1
        try:
            count = {"n": 0}

            def hit() -> bool:
                count["n"] += 1
                return count["n"] == n

            def die() -> None:
                os.write(1, b"")  # nothing buffered to flush: die at once
                os.kill(os.getpid(), signal.SIGKILL)

            if at == "write":
                real_write = sm_io.write_durable

                def write_half(path, data):
                    if hit():
                        real_write(path, data[: len(data) // 2])
                        die()
                    real_write(path, data)
                sm_io.write_durable = write_half
            elif at == "remove":
                real_remove = shutil.rmtree

                def remove_some(path, *args, **kwargs):
                    first = next(p for p in Path(path).iterdir() if p.is_file())
                    first.unlink()
                    die()
                    real_remove(path, *args, **kwargs)
                shutil.rmtree = remove_some
            else:
                real = getattr(os, at)

                def before(*args, **kwargs):
                    if hit():
                        die()
                    return real(*args, **kwargs)
                setattr(os, at, before)
            export_module.write_bundle(out, files)
            code = 0
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    if os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL:
        return KILLED
    return os.WEXITSTATUS(status)


KILLS = ["write1", "write4", "fsync1", "fsync3", "replace1", "replace2", "replace3", "remove1"]


@pytest.mark.parametrize("kill", KILLS)
def test_a_kill_at_any_step_leaves_the_old_or_the_new_bundle(pristine, tmp_path, kill):
    """SIGKILL inside the swap (pancake's bundle replaced by sliding's): what is found at OUT afterwards loads and
    is one whole bundle, old or new (between the two renames the old one, set aside, is loaded from beside OUT);
    the next export finishes the job and leaves nothing behind."""
    out = Path(shutil.copytree(pristine / "pancake", tmp_path / "out"))
    old, new = files_of(out), files_of(pristine / "sliding")
    at, n = kill[:-1], int(kill[-1])
    assert _killed_swap(out, new, at, n) == KILLED
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the fallback to the set-aside bundle warns
        found = OnnxModel(out)
    assert files_of(found.directory) in (old, new)
    export_module.write_bundle(out, new)
    assert files_of(out) == new and OnnxModel(out).contract["task"] == "sliding"
    assert not leftovers(tmp_path)


def test_a_kill_between_the_renames_leaves_the_old_bundle_loadable_beside_out(pristine, tmp_path):
    out = Path(shutil.copytree(pristine / "pancake", tmp_path / "out"))
    assert _killed_swap(out, files_of(pristine / "sliding"), "replace", 2) == KILLED
    assert not out.exists()
    with pytest.warns(UserWarning, match="interrupted"):
        model = OnnxModel(out)
    assert model.contract["task"] == "pancake"
    np.testing.assert_allclose(model.generate(np.zeros((60, 6)))["accel"],
                               OnnxModel(pristine / "pancake").generate(np.zeros((60, 6)))["accel"])
    export_onnx(sm.load_pretrained("pancake"), out)  # the next export puts the bundle back in place first
    assert OnnxModel(out).contract["task"] == "pancake" and not leftovers(tmp_path)
