"""The README's Python examples run as written (each block in a fresh interpreter, in a scratch folder)."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


def needs_a_trained_run(block: str) -> bool:
    """The plug-in task's walk-through loads ``runs/tray-tiny`` (trained in tests/test_plugin_task.py)."""
    return "runs/tray-tiny" in block


@pytest.mark.parametrize("index", [i for i, block in enumerate(BLOCKS) if not needs_a_trained_run(block)])
def test_readme_block_runs(index, tmp_path):
    script = tmp_path / f"readme_block_{index}.py"
    script.write_text(BLOCKS[index])
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, f"README block {index} failed:\n{BLOCKS[index]}\n{done.stderr[-3000:]}"
    assert "Traceback" not in done.stderr and "warning:" not in done.stdout.lower()


def test_readme_has_the_blocks_it_promises():
    assert len(BLOCKS) >= 3 and any("run_pancake" in b for b in BLOCKS) and any("keep_end=True" in b for b in BLOCKS)
