"""Issue 32 item 2: a CSV header's names are matched to the task's layout.

Before, a header ``z,y,theta,…`` was read as y, z (the end landed 593 mm off) and ``a,b,c,d,e,f`` was accepted.
"""

from __future__ import annotations

import numpy as np
import pytest

from seqmotion.cli import main
from seqmotion.io import parse_csv, read_trajectory
from seqmotion.tasks.pancake import data as sketches

NAMES = ("y", "z", "theta", "v_y", "v_z", "v_theta")


def write_csv(path, header, rows):
    lines = ([",".join(header)] if header else []) + [",".join(f"{v:.17g}" for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_permuted_header_is_read_by_name(tmp_path):
    sketch = sketches.straight((0.2, -0.1, 2.5), 120)
    order = [1, 0, 2, 5, 4, 3]  # z, y, theta, v_theta, v_z, v_y
    path = write_csv(tmp_path / "p.csv", [NAMES[i] for i in order], sketch[:, order])
    np.testing.assert_array_equal(read_trajectory(path, columns=NAMES), sketch)
    units = write_csv(tmp_path / "u.csv", [f"{NAMES[i]} [{'rad' if 'theta' in NAMES[i] else 'm'}]" for i in order],
                      sketch[:, order])
    np.testing.assert_array_equal(read_trajectory(units, columns=NAMES), sketch)
    spelt = write_csv(tmp_path / "s.csv", ["Z", "y", "θ", "vθ", "v z", "vy"], sketch[:, order])  # the help's spelling
    np.testing.assert_array_equal(read_trajectory(spelt, columns=NAMES), sketch)
    plain = write_csv(tmp_path / "n.csv", None, sketch)  # no header: the layout's order
    np.testing.assert_array_equal(read_trajectory(plain, columns=NAMES), sketch)


@pytest.mark.parametrize("header, match", [
    (["a", "b", "c", "d", "e", "f"], "header column 'a' is not one of y, z, theta"),
    (["y", "y", "theta", "v_y", "v_z", "v_theta"], "'y' appears more than once"),
    (["y", "z", "theta", "v_y", "v_z"], "has no column 'v_theta'"),
])
def test_a_header_that_does_not_name_the_layout_is_refused(tmp_path, header, match):
    path = write_csv(tmp_path / "bad.csv", header, np.zeros((10, len(header))))
    with pytest.raises(ValueError, match=match):
        read_trajectory(path, columns=NAMES)
    with pytest.raises(ValueError, match="header names 6 columns, the data rows hold 7"):
        parse_csv("y,z,theta,v_y,v_z,v_theta\n" + "0,0,0,0,0,0,0\n", columns=NAMES)


def test_deform_reads_a_permuted_header_by_name(tmp_path, capsys):
    sketch = sketches.straight((0.2, -0.1, 2.5), 200)
    write_csv(tmp_path / "ordered.csv", NAMES, sketch)
    write_csv(tmp_path / "permuted.csv", ["z", "y", "theta", "v_z", "v_y", "v_theta"], sketch[:, [1, 0, 2, 4, 3, 5]])
    for name in ("ordered", "permuted"):
        assert main(["deform", "--input", str(tmp_path / f"{name}.csv"), "--output", str(tmp_path / f"{name}.npz")
                     ]) == 0
    a, b = (np.load(tmp_path / f"{n}.npz")["states"] for n in ("ordered", "permuted"))
    np.testing.assert_array_equal(a, b)
    write_csv(tmp_path / "abc.csv", list("abcdef"), sketch)
    assert main(["deform", "--input", str(tmp_path / "abc.csv"), "--output", str(tmp_path / "abc.npz")]) == 2
    assert "header column 'a'" in capsys.readouterr().err and not (tmp_path / "abc.npz").exists()


def test_plan_reads_a_permuted_command_header_by_name(tmp_path):
    from seqmotion.tasks.sliding import data as commands

    command = commands.line(0.05, 300)
    write_csv(tmp_path / "c.csv", ["y", "x", "v_y", "v_x"], command[:, [1, 0, 3, 2]])
    write_csv(tmp_path / "d.csv", ["x", "y", "v_x", "v_y"], command)
    for name in ("c", "d"):
        assert main(["plan", "--command", str(tmp_path / f"{name}.csv"), "--output", str(tmp_path / f"{name}.npz")
                     ]) == 0
    np.testing.assert_array_equal(np.load(tmp_path / "c.npz")["pan_accel"], np.load(tmp_path / "d.npz")["pan_accel"])
