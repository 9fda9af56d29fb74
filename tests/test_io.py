"""seqmotion.io: the one place files are written (atomically) and outputs checked before the work."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from seqmotion import io


def leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if io.TEMP_MARK in p.name)


def test_writers_replace_whole_files_and_leave_no_temporaries(tmp_path):
    target = tmp_path / "deep" / "a.json"
    io.atomic_write_json(target, {"b": 1, "a": [1.5, None]})
    assert target.read_bytes() == io.json_bytes({"a": [1.5, None], "b": 1})
    assert json.loads(target.read_text()) == {"a": [1.5, None], "b": 1}
    io.atomic_write_text(target, "second\n")
    assert target.read_text() == "second\n"
    arrays = io.atomic_write_npz(tmp_path / "x.npz", {"states": np.arange(6.0).reshape(3, 2), "k": np.int64(3)})
    with np.load(arrays) as f:
        np.testing.assert_array_equal(f["states"], np.arange(6.0).reshape(3, 2))
        assert int(f["k"]) == 3
    assert not leftovers(tmp_path) and not leftovers(tmp_path / "deep")


def test_json_that_cannot_be_written_is_refused_before_anything_is(tmp_path):
    target = tmp_path / "a.json"
    target.write_text("old")
    with pytest.raises(ValueError, match="as JSON"):
        io.atomic_write_json(target, {"x": object()})
    assert target.read_text() == "old" and not leftovers(tmp_path)


def test_a_failed_write_leaves_the_old_file(tmp_path):
    target = tmp_path / "f.bin"
    io.atomic_write_bytes(target, b"old")
    with pytest.raises(RuntimeError), io.atomic_path(target) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("killed")
    assert target.read_bytes() == b"old" and not leftovers(tmp_path)


def test_save_figure_takes_the_format_from_the_suffix_and_can_close(tmp_path):
    plt = io.pyplot()
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    png = io.save_figure(fig, tmp_path / "f.png", dpi=50)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    svg = io.save_figure(fig, tmp_path / "f.svg")
    assert b"<svg" in svg.read_bytes()[:400]
    with pytest.raises(ValueError, match="suffix"):
        io.save_figure(fig, tmp_path / "nosuffix")
    with pytest.raises(ValueError):  # matplotlib knows no such format
        io.save_figure(fig, tmp_path / "f.notaformat")
    assert plt.fignum_exists(fig.number)
    io.save_figure(fig, tmp_path / "g.png", close=True)
    assert not plt.fignum_exists(fig.number)
    assert not leftovers(tmp_path) and sorted(p.name for p in tmp_path.iterdir()) == ["f.png", "f.svg", "g.png"]


def test_outputs_are_checked_before_the_work(tmp_path):
    assert io.check_writable(tmp_path / "new" / "out.csv", (".csv",)) == tmp_path / "new" / "out.csv"
    assert not (tmp_path / "new").exists()  # nothing is created
    with pytest.raises(ValueError, match="unsupported file type"):
        io.check_writable(tmp_path / "out.txt", (".csv", ".npz"))
    with pytest.raises(ValueError, match="is a directory"):
        io.check_writable(tmp_path)
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError, match="not a directory"):
        io.check_writable_dir(tmp_path / "file" / "sub")
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        with pytest.raises(ValueError, match="not writable"):
            io.check_writable(locked / "x.png")


def test_replace_directory_swaps_a_folder_whole(tmp_path):
    target, aside = tmp_path / "bundle", tmp_path / "bundle.previous"
    io.replace_directory(target, {"a": b"1", "b": b"2"}, aside)
    io.replace_directory(target, {"c": b"3"}, aside)
    assert sorted(p.name for p in target.iterdir()) == ["c"] and not aside.exists() and not leftovers(tmp_path)


def test_io_is_the_lowest_layer():
    """io imports only the standard library and NumPy (matplotlib inside pyplot()): every layer may use it."""
    import ast
    from pathlib import Path

    tree = ast.parse(Path(io.__file__).read_text())
    top = {a.name.split(".")[0] for n in tree.body if isinstance(n, ast.Import) for a in n.names}
    top |= {n.module.split(".")[0] for n in tree.body if isinstance(n, ast.ImportFrom) and n.level == 0}
    assert top <= {"__future__", "io", "json", "os", "shutil", "uuid", "collections", "contextlib", "pathlib",
                   "typing", "numpy"}, top


@pytest.mark.parametrize("text, match", [
    ('{"a": NaN}', "a is nan, not a finite number"),
    ('{"a": {"b": [0, -Infinity]}}', r"a\.b\[1\] is -inf, not a finite number"),
    ('{"a": 1e999}', "a is inf, not a finite number"),
    ("[1, 2]", "must hold a JSON object, got list"),
    ('{"a": ', "not valid JSON"),
    (b'{"a": "\xff"}', "not valid JSON"),
])
def test_the_json_reader_is_strict_and_names_the_file(tmp_path, text, match):
    path = tmp_path / "c.json"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(ValueError, match=match) as caught:
        io.read_json(path, "--config")
    assert f"--config {path}" in str(caught.value)


def test_the_json_reader_caps_size_and_tells_a_missing_file_from_a_corrupt_one(tmp_path):
    path = tmp_path / "c.json"
    with pytest.raises(ValueError, match="does not exist"):
        io.read_json(path)
    assert io.read_json(path, missing=None) is None
    path.write_text('{"a": [1.5, null]}')
    assert io.read_json(path, missing=None) == {"a": [1.5, None]}
    assert io.read_json(path, max_bytes=10**6) == {"a": [1.5, None]}
    with pytest.raises(ValueError, match="larger than"):
        io.read_json(path, max_bytes=4)
    path.write_text("[1, 2]")
    assert io.read_json(path, object_required=False) == [1, 2]
    with pytest.raises(ValueError, match="is a directory"):
        io.read_json(tmp_path)

    class Mine(ValueError):
        pass

    path.write_text("{")
    with pytest.raises(Mine, match="not valid JSON"):
        io.read_json(path, error=Mine)


def test_the_trajectory_files_live_in_io():
    from seqmotion.io import trajectories

    assert io.read_trajectory is trajectories.read_trajectory and io.write_arrays is trajectories.write_arrays
    assert io.MAX_FILE_BYTES == trajectories.MAX_FILE_BYTES
