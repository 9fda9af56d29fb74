"""Hardening, second round (issue 31, item 8): one broken task plug-in must not break every task.

Each test installs fake distributions (a ``*.dist-info`` folder with ``entry_points.txt`` on
``sys.path``, which is all ``importlib.metadata`` needs) whose ``seqmotion.tasks`` entry points
are broken in one way each, then uses the built-in tasks as a user would.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import seqmotion as sm
from seqmotion.cli import main
from seqmotion.core import registry
from seqmotion.tasks.pancake import data as inputs

SOURCE = str(Path(sm.__file__).parents[1])  # the seqmotion under test, also in the subprocess
BROKEN = {
    # module name → (its source, the entry point's object)
    "sm_broken_import": ("raise ImportError('numpy 99 is required')\n", "TASK"),
    "sm_wrong_type": ("TASK = 42\n", "TASK"),
    "sm_duplicate": ("class T:\n    name = 'pancake'\n    def load(self, d):\n        raise RuntimeError\nTASK = T()\n",
                     "TASK"),
    "sm_exits": ("import sys\nsys.exit(3)\n", "TASK"),
}


def install_plugins(folder: Path, plugins: dict[str, tuple[str, str]]) -> None:
    """Write each plug-in module and one distribution declaring them all as ``seqmotion.tasks`` entry points."""
    for module, (source, _) in plugins.items():
        (folder / f"{module}.py").write_text(source)
    info = folder / "sm_bad_plugins-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: sm-bad-plugins\nVersion: 0.1\n")
    lines = [f"{module.removeprefix('sm_')} = {module}:{obj}" for module, (_, obj) in plugins.items()]
    (info / "entry_points.txt").write_text("[seqmotion.tasks]\n" + "\n".join(lines) + "\n")


@pytest.fixture
def broken_plugins(tmp_path, monkeypatch):
    install_plugins(tmp_path, BROKEN)
    monkeypatch.syspath_prepend(str(tmp_path))
    registry.refresh()
    yield tmp_path
    for module in BROKEN:
        sys.modules.pop(module, None)
    registry.refresh()


def test_builtin_tasks_load_without_importing_any_plugin(broken_plugins):
    """Lazy: a built-in name imports no plug-in, so nothing is even warned about."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any plug-in warning would fail here
        model = sm.load_pretrained("pancake")
        assert registry.get("sliding").name == "sliding"
    assert not [m for m in BROKEN if m in sys.modules]
    r = model.deform(inputs.straight((0.1, 0.0, 2.0), 150))
    assert r.states.shape == (150, 6)


def test_every_broken_plugin_is_skipped_with_a_warning_naming_it(broken_plugins):
    with pytest.warns(RuntimeWarning) as record:
        names = registry.names()
    messages = " | ".join(str(w.message) for w in record)
    for name in ("broken_import", "wrong_type", "duplicate", "exits"):
        assert f"plug-in {name!r}" in messages, messages
    assert "numpy 99 is required" in messages and "sys.exit(3)" in messages
    assert "a task called 'pancake' exists already" in messages
    assert {"pancake", "sliding", "pushing"} <= set(names)  # the good ones, the package's own plug-in too
    assert registry.get("pancake").__class__.__module__ == "seqmotion.tasks.pancake.task"  # the built-in is kept
    with pytest.raises(ValueError, match="unknown task 'broken_import'"):
        registry.get("broken_import")


def test_commands_work_beside_broken_plugins(broken_plugins, tmp_path, capsys):
    np.savez(tmp_path / "in.npz", states=inputs.straight((0.1, 0.0, 2.0), 150))
    assert main(["deform", "--input", str(tmp_path / "in.npz"), "--output", str(tmp_path / "out.npz")]) == 0
    assert main(["export-onnx", "pancake", str(tmp_path / "onnx")]) == 0
    assert (tmp_path / "onnx" / "contract.json").is_file()
    capsys.readouterr()


def test_a_plugin_calling_sys_exit_does_not_end_a_command(tmp_path):
    """Before, ``sys.exit`` inside a plug-in's import ended every command silently (with its exit code)."""
    install_plugins(tmp_path, {"sm_exits": BROKEN["sm_exits"], "sm_broken_import": BROKEN["sm_broken_import"]})
    np.savez(tmp_path / "in.npz", states=inputs.straight((0.1, 0.0, 2.0), 150))
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(tmp_path)!r})
        from seqmotion.cli import main
        from seqmotion.core import registry
        print("tasks:", registry.names())
        sys.exit(main(["deform", "--input", {str(tmp_path / 'in.npz')!r},
                       "--output", {str(tmp_path / 'out.npz')!r}]))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONWARNINGS": "default", "PYTHONPATH": SOURCE})
    assert done.returncode == 0, (done.returncode, done.stdout, done.stderr)  # not 3, the plug-in's code
    assert "tasks: [" in done.stdout and "'pancake'" in done.stdout
    assert "plug-in 'exits'" in done.stderr and "sys.exit(3)" in done.stderr
    assert "pancake: generated 150 samples" in done.stdout


def test_shipped_models_of_a_plugin_are_found_without_importing_it(tmp_path, monkeypatch):
    """``pretrained_roots`` finds a plug-in package's ``pretrained/`` folder from its entry point alone."""
    package = tmp_path / "sm_lazy_pkg"
    (package / "pretrained").mkdir(parents=True)
    (package / "__init__.py").write_text("raise RuntimeError('imported')\n")
    info = tmp_path / "sm_lazy-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: sm-lazy\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[seqmotion.tasks]\nlazy = sm_lazy_pkg.task:TASK\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    registry.refresh()
    try:
        assert package / "pretrained" in registry.pretrained_roots()
        assert "sm_lazy_pkg" not in sys.modules
    finally:
        registry.refresh()


def test_register_decorates_a_class_and_entries_satisfy_the_protocol():
    try:
        @registry.register
        class Toy:
            name = "toy-entry"

            def load(self, directory: str) -> str:
                return f"loaded {directory}"

        assert isinstance(Toy, type) and registry.get("toy-entry").load("d") == "loaded d"
        assert all(isinstance(registry.get(n), registry.TaskEntry) for n in ("pancake", "sliding", "toy-entry"))
        with pytest.raises(ValueError, match="TaskEntry"):
            registry.register(object())
        with pytest.raises(ValueError, match="already registered"):
            registry.register(Toy())
    finally:
        registry.refresh()
