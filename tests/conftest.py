"""Fixtures shared across the test files: the shipped models (read-only) and a one-thread torch."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch

import seqmotion as sm


@pytest.fixture(scope="session")
def deformer():
    """The shipped Deformer (``sm.load_pretrained("pancake")``); tests must not modify it. Test files
    that train their own tiny model define their own ``deformer``, which takes precedence."""
    return sm.load_pretrained("pancake")


@pytest.fixture(scope="session")
def planner():
    """The shipped SlidingPlanner (``sm.load_pretrained("sliding")``); tests must not modify it."""
    return sm.load_pretrained("sliding")


@pytest.fixture(scope="session")
def shipped_bundles(tmp_path_factory):
    """A folder holding ``pancake/`` and ``sliding/``: the shipped models exported with ``export-onnx`` (source =
    their names), once per run; tests read them or copy them (``shutil.copytree``) before changing anything."""
    from seqmotion.deploy import export_onnx

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the export's parity check, as the deploy tests run it
    try:
        root = tmp_path_factory.mktemp("shipped-bundles")
        for name in ("pancake", "sliding"):
            export_onnx(sm.load_pretrained(name), root / name, source=name)
    finally:
        torch.set_num_threads(threads)
    return root


@pytest.fixture(scope="module")
def one_thread():
    """torch on one thread for the module, restored afterwards: a control loop steps a batch of one,
    where one thread is fastest and least disturbed by a busy machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def install_example(name: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, dict]]:
    """Install ``examples/<name>`` into a fresh folder the way a user would (pip) and put it on the path, in this
    process and for subprocesses; yields ``(folder, env)`` and takes it off again (a module fixture's body)."""
    example = Path(__file__).resolve().parents[1] / "examples" / name
    target, build = tmp_path_factory.mktemp("site"), tmp_path_factory.mktemp("build")
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--target",
                    str(target), str(example)], check=True, cwd=build, capture_output=True)
    sys.path.insert(0, str(target))
    sm.tasks.refresh()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(target), os.environ.get("PYTHONPATH", "")])}
    yield target, env
    sys.path.remove(str(target))
    package = f"seqmotion_{name}"
    for module in [m for m in sys.modules if m == package or m.startswith(package + ".")]:
        del sys.modules[module]
    sm.tasks.refresh()


def seqmotion_cli(env: dict, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    """``python -m seqmotion.cli ARGS`` in ``cwd`` with ``env`` (an installed example's path), output captured."""
    return subprocess.run([sys.executable, "-m", "seqmotion.cli", *args], env=env, cwd=cwd, capture_output=True,
                          text=True)
