"""Hardening, second round (issue 31), input files and sizes: defects 5, 6 and 7.

5. An output that is its own input destroyed the input (``deform --input in.csv --output in.csv``).
6. Nothing capped the size of what was read: a small ``.npz`` or HDF5 file declaring a huge array
   was allocated in full, a CSV was read whole, ``generate``/``deform`` took any K.
7. A ``MemoryError`` ended in a traceback (exit 1) instead of one line.

Files declaring huge arrays are crafted from headers alone (no data), so nothing here allocates
more than the 144 MB of one API input of K = 3e6 samples.
"""

from __future__ import annotations

import io
import os
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest

import seqmotion as sm
from seqmotion.cli import main
from seqmotion.errors import MAX_LENGTH
from seqmotion.io import read_trajectory
from seqmotion.io import trajectories as files


def npz_declaring(path: Path, shape: tuple[int, ...], key: str = "states", descr: str = "<f8") -> Path:
    """An ``.npz`` whose member ``key`` has an ``.npy`` header declaring ``shape`` and (almost) no data."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": descr, "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr(f"{key}.npy", header.getvalue() + bytes(64))
    return path


def one_line_error(capsys, command: str) -> str:
    err = capsys.readouterr().err
    assert err.startswith(f"seqmotion {command}: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    return err


# --- 5. an output that is its own input ------------------------------------------------------------


def test_an_output_that_is_an_input_is_refused_before_the_work(tmp_path, capsys, monkeypatch):
    """Defect 5: `deform --input in.csv --output in.csv` (and npz, plan --command, optimize --input,
    simulate --json, lfd evaluate --json) overwrote the input. Refused before any work, exit 2, the input
    byte for byte as it was, whichever path (a link, `..`) names it."""
    import seqmotion.api

    def no_work(*args, **kwargs):
        raise AssertionError("the work started before the outputs were checked")

    monkeypatch.setattr(seqmotion.api, "resolve_model", no_work)
    monkeypatch.setattr(files, "read_arrays", no_work)
    monkeypatch.setattr(files, "read_trajectory", no_work)
    states = np.linspace(0, 1, 60).reshape(10, 6)
    np.savetxt(tmp_path / "in.csv", states, delimiter=",")
    np.savez(tmp_path / "in.npz", states=states)
    (tmp_path / "data.h5").write_bytes(b"an hdf5 dataset")
    (tmp_path / "sub").mkdir()
    (tmp_path / "link.csv").symlink_to(tmp_path / "in.csv")
    (tmp_path / "shot.png").symlink_to(tmp_path / "in.npz")
    os.link(tmp_path / "in.npz", tmp_path / "hard.npz")
    originals = {p: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    csv, npz = str(tmp_path / "in.csv"), str(tmp_path / "in.npz")
    cases = [
        ["deform", "--input", csv, "--output", csv],
        ["deform", "--input", npz, "--output", npz],
        ["deform", "--input", csv, "--output", str(tmp_path / "sub" / ".." / "in.csv")],
        ["deform", "--input", str(tmp_path / "link.csv"), "--output", csv],
        ["deform", "--input", str(tmp_path / "hard.npz"), "--output", npz],
        ["plan", "--command", npz, "--output", npz],
        ["optimize", "--target", "0.1", "0", "1", "--input", csv, "--output", csv],
        ["optimize", "--target", "0.1", "0", "1", "--input", npz, "--output", str(tmp_path / "o.npz"),
         "--plot", str(tmp_path / "shot.png")],
        ["simulate", "pancake", "--trajectory", npz, "--json", npz],
        ["simulate", "pancake", "--trajectory", npz, "--snapshots", str(tmp_path / "shot.png")],
        ["lfd", "evaluate", "--oracle-latents", str(tmp_path / "data.h5"), "--json", str(tmp_path / "data.h5")],
    ]
    for argv in cases:
        assert main(argv) == 2, argv
        assert "same file" in one_line_error(capsys, argv[0]), argv
    assert {p: p.read_bytes() for p in originals} == originals
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["sub", *(p.name for p in originals)])


# --- 6. sizes are checked before reading -----------------------------------------------------------


@pytest.mark.parametrize("shape, descr, match", [
    ((30_000_000, 6), "<f8", "30000000 along an axis"),  # the 1.4 MB savez_compressed of (3e7, 6)
    ((10**9, 6), "<f8", "1000000000 along an axis"),  # the item 7: MemoryError, traceback
    ((6, 400_000_000), "<f8", "400000000 along an axis"),
    ((1000, 1000, 1000), "<f8", "GiB once read"),  # no axis too long, 8 GB in all
    ((1000, 1000, 300), "<f4", "GiB once read"),  # 1.2 GB as float32, 2.4 GB as the float64 it is read as
])
def test_an_npz_declaring_a_huge_array_is_refused_from_its_header(tmp_path, shape, descr, match):
    """Defects 6 and 7: np.load allocated whatever the header declared (minutes at 6 GB, or MemoryError)."""
    path = npz_declaring(tmp_path / "x.npz", shape, descr=descr)
    with pytest.raises(ValueError, match=re.escape(f"array 'states' declares shape {shape}")) as caught:
        read_trajectory(path)
    assert str(path) in str(caught.value) and re.search(match, str(caught.value))


def test_arrays_of_an_npz_are_bounded_together_and_members_must_be_arrays(tmp_path, monkeypatch):
    """Defect 6: several arrays each within the cap must not add up to more than it; a member that is not an
    .npy array was returned as raw bytes (the whole member read into memory)."""
    monkeypatch.setattr(files, "MAX_FILE_BYTES", 2**20)
    np.savez_compressed(tmp_path / "two.npz", pan_states=np.zeros((20_000, 4)), rel_states=np.zeros((20_000, 4)))
    assert files.read_arrays(tmp_path / "two.npz", ("pan_states",))["pan_states"].shape == (20_000, 4)
    with pytest.raises(ValueError, match="'rel_states' declares shape \\(20000, 4\\): with the arrays before it"):
        files.read_arrays(tmp_path / "two.npz", ("pan_states", "rel_states"))
    with zipfile.ZipFile(tmp_path / "raw.npz", "w") as archive:
        archive.writestr("states.npy", b"not an array" * 100)
    with pytest.raises(ValueError, match="'states' is not an .npy array"):
        read_trajectory(tmp_path / "raw.npz")


def test_the_cli_refuses_a_huge_declared_array_in_one_line(tmp_path, capsys):
    """Defect 7: `deform --input` of an npz declaring (1e9, 6) gave rc 1 and a MemoryError traceback."""
    path = npz_declaring(tmp_path / "huge.npz", (10**9, 6))
    for argv in (["deform", "--input", str(path), "--output", str(tmp_path / "o.npz")],
                 ["optimize", "--target", "0.1", "0", "1", "--input", str(path), "--output", str(tmp_path / "o.npz")],
                 ["simulate", "pancake", "--trajectory", str(path)]):
        assert main(argv) == 2, argv
        err = one_line_error(capsys, argv[0])
        assert "huge.npz" in err and "(1000000000, 6)" in err
    assert not (tmp_path / "o.npz").exists()


def test_a_csv_is_refused_at_the_first_row_too_many(tmp_path):
    """Defect 6: a CSV was read whole into memory and parsed to the end, however many rows. Now rows are
    counted as they are read: MAX_LENGTH rows are fine, the next one is refused and the rest never read."""
    rows = "0.5\n" * MAX_LENGTH
    (tmp_path / "full.csv").write_text("x\n" + rows)
    assert read_trajectory(tmp_path / "full.csv").shape == (MAX_LENGTH, 1)
    (tmp_path / "long.csv").write_text("x\n" + rows + "0.5\nnot a number, never read\n")
    with pytest.raises(ValueError, match=f"long.csv, line {MAX_LENGTH + 2}: more than {MAX_LENGTH} data rows"):
        read_trajectory(tmp_path / "long.csv")


def test_a_csv_line_without_end_is_refused_as_it_is_read(tmp_path):
    """Defect 6: a text file without line breaks was read as one string (and split into one row)."""
    (tmp_path / "one_line.csv").write_text("0," * files.MAX_CSV_LINE)
    with pytest.raises(ValueError, match="one_line.csv, line 1: longer than"):
        read_trajectory(tmp_path / "one_line.csv")
    (tmp_path / "wide.csv").write_text(",".join(["1"] * 1000) + "\n")  # wide, within the line cap: fine
    assert read_trajectory(tmp_path / "wide.csv").shape == (1, 1000)


def _h5_declaring(path: Path, huge: dict[str, tuple[tuple[int, ...], str]]) -> Path:
    """A complete-looking pushing dataset whose ``huge`` datasets declare their shapes (chunked, never written:
    HDF5 allocates nothing for them)."""
    h5py = pytest.importorskip("h5py")
    from seqmotion.lfd.data.dataset import FORMAT, MOTION_KEYS, VERSION

    with h5py.File(path, "w") as f:
        f.attrs.update(format=FORMAT, version=VERSION, complete=True)
        for group in ("motions", "episodes/variation", "operator"):
            f.require_group(group)
        for key in MOTION_KEYS:
            if f"motions/{key}" not in huge:
                f["motions"].create_dataset(key, shape=(1, 10, 3), dtype="f4")
        for name, (shape, dtype) in huge.items():
            f.create_dataset(name, shape=shape, dtype=dtype, chunks=tuple(min(n, 1000) for n in shape))
    return path


@pytest.mark.parametrize("name, shape", [
    ("motions/master_theta", (6, MAX_LENGTH + 1, 3)),
    ("episodes/distance", (6, MAX_LENGTH + 1)),
    ("operator/stiffness", (MAX_LENGTH + 1,)),
])
def test_an_hdf5_dataset_declaring_too_much_is_refused_from_its_shape(tmp_path, name, shape, capsys):
    """Defect 6: an HDF5 file declaring (6, 4e8) f8 tried to allocate 17.9 GiB on `lfd info` / `load_dataset`."""
    from seqmotion.lfd.data.dataset import load_dataset

    path = _h5_declaring(tmp_path / "big.h5", {name: (shape, "f8")})
    with pytest.raises(ValueError, match=re.escape(f"big.h5: dataset /{name} declares shape {shape}")):
        load_dataset(path)
    assert main(["lfd", "info", str(path)]) == 2
    assert f"/{name} declares shape" in one_line_error(capsys, "lfd")


def test_hdf5_datasets_are_bounded_together(tmp_path, monkeypatch):
    """Defect 6: datasets each within the cap must not add up to more than it once read."""
    monkeypatch.setattr(files, "MAX_FILE_BYTES", 2**20)
    path = _h5_declaring(tmp_path / "sum.h5", {"images": ((50, 64, 64, 3), "u1"),  # 0.6 MiB
                                               "operator/stiffness": ((80_000,), "f4")})  # 0.6 MiB as float64
    from seqmotion.lfd.data.dataset import load_dataset

    with pytest.raises(ValueError, match="sum.h5: its datasets take"):
        load_dataset(path)


def test_generate_and_deform_refuse_more_than_the_length_cap(deformer, planner):
    """Defect 6: API `deform` with K = 3e6 was not refused, although `decode` caps K at 1e6."""
    too_long = np.zeros((3_000_000, 6))
    for call in (deformer.deform, deformer.generate):
        with pytest.raises(ValueError, match=f"K = 3000000 samples, more than the {MAX_LENGTH}"):
            call(too_long)
    with pytest.raises(ValueError, match=f"K = {MAX_LENGTH + 1} samples"):
        planner.plan(np.zeros((1, MAX_LENGTH + 1, 4)))
    with pytest.raises(ValueError, match="length"):
        deformer.decode(np.zeros(deformer.model.latent_dim), np.zeros(6), MAX_LENGTH + 1)


def test_there_is_one_length_cap():
    """Defect 6: MAX_LENGTH was defined twice (tasks/base.py, tasks/options.py) beside literal 1_000_000s."""
    root = Path(sm.__file__).parent
    defined = sorted(p.relative_to(root).as_posix() for p in root.rglob("*.py")
                     if re.search(r"^MAX_LENGTH\s*=", p.read_text(), re.MULTILINE))
    assert defined == ["errors.py"]
    from seqmotion.core import options, trained

    assert trained.MAX_LENGTH is options.MAX_LENGTH is MAX_LENGTH


# --- 7. MemoryError ----------------------------------------------------------------------------------


@pytest.mark.parametrize("argv, target", [
    (["deform", "--input", "{dir}/in.npz", "--output", "{dir}/o.npz"], "seqmotion.core.trained.TrainedModel.generate"),
    (["lfd", "info", "{dir}/in.h5"], "seqmotion.lfd.data.dataset.load_dataset"),
])
def test_an_allocation_failure_in_the_work_is_one_line_and_exit_1(tmp_path, capsys, monkeypatch, argv, target):
    """Defect 7: a MemoryError ended in a traceback; `seqmotion lfd` goes through the same handler."""
    np.savez(tmp_path / "in.npz", states=np.zeros((50, 6)))

    def out_of_memory(*args, **kwargs):
        return np.empty(10**13)  # 80 TB: numpy refuses it at once with a real MemoryError

    monkeypatch.setattr(target, out_of_memory)
    argv = [a.format(dir=tmp_path) for a in argv]
    assert main(argv) == 1
    err = one_line_error(capsys, argv[0])
    assert "out of memory" in err and "Unable to allocate" in err
    assert not (tmp_path / "o.npz").exists()
