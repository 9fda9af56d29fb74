"""The README's Python examples run as written (each block in a fresh interpreter, in a scratch folder)."""

import os
import re
import shlex
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


# --- the newcomer check: every command line of the README, as written or by a named stand-in ---------------------

COMMAND_BLOCKS = re.findall(r"```bash\n(.*?)```", README.read_text(), flags=re.S)[2:]  # after the two install lines
SKETCH = ("python -c \"import seqmotion as sm, numpy as np; np.savetxt('sketch.csv', "
          "sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 500), delimiter=',', header='y,z,theta,v_y,v_z,v_theta', "
          "comments='')\"")


def readme_commands() -> list[str]:
    """Each command line of the README's command blocks, its comment stripped, continuation lines joined."""
    text = "\n".join(COMMAND_BLOCKS).replace("\\\n", " ")
    lines = [re.split(r"\s+#", line)[0].strip() for line in text.splitlines()]
    return [" ".join(line.split()) for line in lines if line and not line.startswith("#")]


# README line → (what runs here: "as written", a stand-in command (tiny, named so), or the test that runs it;
#                what the README says it prints, as a regex on the output, or None)
TINY = "--config tiny --epochs 1 --batches-per-epoch 1"
CHECKS: dict[str, tuple[str, str | None]] = {
    "seqmotion demo": ("stand-in: seqmotion demo --no-sim --out demo  (the arm's part: "
                       "tests/test_first_hour.py::test_demo_snapshot_labels_agree_with_what_it_prints)",
                       r"pancake stays on .*deformed +9\d\.\d %"),
    SKETCH: ("as written", None),
    "seqmotion deform --input sketch.csv --output deformed.npz --keep-end": (
        "as written", r"ends exactly at the input's end pose, at rest"),
    "seqmotion deform --input sketch.csv --output learned.npz --plot deform.png": (
        "as written", r"not executable as is(.|\n)*figure → deform.png"),
    "seqmotion plan --circle 0.05 --output plan.npz": ("as written", r"warning: tracking_rmse 42\.\d mm"),
    "seqmotion plan --circle 0.05 --length 900 --refine --output plan.npz": ("as written", r"object RMSE 2\.4 mm"),
    "seqmotion plan --circle 0.05 --length 900 --refine --mu 0.5 --mu-dyn 0.5 --output arm.npz": (
        "as written", r"object RMSE 2\.8 mm .*μ = 0\.5, μ' = 0\.5\)(.|\n)*warning: the input lies outside .*mu 0\.5 "
                      r"outside 0\.72-1\.32"),
    "seqmotion simulate sliding --trajectory arm.npz": ("as written", r"object RMSE 3\.6 mm"),
    "seqmotion optimize --target 0.1 0.0 3.14 --output adjusted.npz --plot adjusted.png [--exact]": (
        "stand-in: seqmotion optimize --target 0.1 0.0 3.14 --output adjusted.npz --plot adjusted.png --exact",
        r"polish: .*Solve_Succeeded"),
    "seqmotion optimize --preset j2 --output slow_turn.npz": ("as written", r"end attitude band: .* met"),
    "seqmotion simulate pancake --trajectory deformed.npz --video turn.mp4": ("as written", r"stayed on"),
    "seqmotion reproduce ch2|ch3|ch4|ch5": ("tests/test_reproduce.py (each chapter with --quick)", None),
    "seqmotion train pancake --config small": (f"stand-in: seqmotion train pancake {TINY} --out runs/p", None),
    "seqmotion train pancake --config paper": (f"stand-in: seqmotion train pancake {TINY} --out runs/p2", None),
    "seqmotion train sliding --config small --variant A|B|C": (
        f"stand-in: seqmotion train sliding {TINY} --variant B --out runs/s", None),
    "seqmotion train pancake --config paper --device cuda": ("tests/test_device.py (CUDA where present)", None),
    "torchrun --nproc_per_node=2 -m seqmotion.cli train pancake --config small": (
        "tests/test_training.py::test_torchrun_two_processes_matches_one", None),
    "torchrun --nproc_per_node=4 -m seqmotion.cli train sliding --config paper --device cuda": (
        "tests/test_device.py (CUDA where present)", None),
    "seqmotion export runs/pancake-small-seed0 --name pancake --metrics reproduce/ch2/results.json": (
        "stand-in: seqmotion export runs/p --name pancake-newcomer --to shipped", r"with MODEL_CARD.md"),
    "seqmotion export-onnx pancake onnx/pancake/": ("as written", r"parity with PyTorch"),
    "seqmotion export-c pancake c/pancake/": ("as written", r"parity with PyTorch .*states within"),
    "seqmotion bench-step pancake --rt": ("tests/test_realtime.py::test_bench_step_runs_the_stepper_in_a_paced_loop",
                                          None),
    "seqmotion lfd collect --out demos": ("tests/test_lfd_train.py::test_cli_train_and_evaluate", None),
    "seqmotion lfd train --data demos --out policies": ("tests/test_lfd_train.py::test_cli_train_and_evaluate", None),
    "seqmotion lfd evaluate policies/proposed_default --json eval.json": (
        "tests/test_lfd_train.py::test_cli_train_and_evaluate", None),
    "seqmotion lfd export-lerobot|import-lerobot": ("tests/test_lerobot.py::test_export_cli", None),
    "seqmotion lfd export-lerobot demos lerobot_demos [--repo-id me/pushing] [--videos] [--fps 50]": (
        "tests/test_lerobot.py::test_export_cli", None),
    "seqmotion lfd import-lerobot my_lerobot_dataset demos2 [--map slave_tau=observation.torque] [--trim]": (
        "tests/test_lerobot.py::test_import_cli_writes_a_seqmotion_dataset", None),
    "seqmotion lfd train --data lerobot_demos --out policies": (
        "tests/test_lerobot.py::test_train_accepts_lerobot_folders", None),
    "seqmotion lfd train --data my_robot_dataset --out my_models --methods seqae [--map slave_tau=observation.torque] "
    "[--preset smaller]": ("tests/test_lerobot.py::test_map_takes_other_keys", None),
    "python -c \"import seqmotion as sm; print(sm.load('my_models/seqae').seqae_config.joints)\"": (
        "tests/test_lerobot_other_robot.py", None),
    "seqmotion lfd train --data my_robot_dataset --out my_models --seqae-from my_models/seqae --cnn-targets pair "
    "[--map ...]": ("tests/test_lerobot_other_robot.py", None),
    "seqmotion lfd collect --benchmark hard --out hard_demos": (
        "tests/test_lfd_hard.py::test_cli_collect_train_evaluate_hard", None),
    "seqmotion lfd train --data hard_demos --benchmark hard --demos 25 --out hard_policies --methods proposed "
    "end_to_end": ("tests/test_lfd_hard.py::test_cli_collect_train_evaluate_hard", None),
    "seqmotion lfd evaluate hard_policies/proposed_default --benchmark hard --trials 30 --json hard.json": (
        "tests/test_lfd_hard.py::test_cli_collect_train_evaluate_hard", None),
    "seqmotion lfd collect --benchmark hard --episodes 900 --no-video --out hard_big": (
        "tests/test_lfd_hard.py::test_cli_collect_train_evaluate_hard", None),
    "seqmotion lfd train --data hard_big --benchmark hard --methods feedback --preset wide64 --seqae-epochs 700 "
    "--out hard_fb": ("tests/test_lfd_hard.py::test_cli_collect_train_evaluate_hard", None),
    "seqmotion lfd evaluate hard_fb/feedback_default --benchmark hard --trials 100 --seed 2": (
        "tests/test_lfd_hard.py::test_cli_collect_train_evaluate_hard", None),
    "pip install -e \".[view]\" && seqmotion view": ("tests/test_view.py::test_page_loads", None),
    "pip install -e \".[robots]\" && pip install --no-deps \"robosuite>=1.5,<1.6\"": (
        "tests/test_robots.py (.ci/run installs both, as the README's test command does)", None),
    "seqmotion robots": ("as written", r"panda +robosuite +7 joints"),
    "seqmotion simulate pancake --trajectory deformed.npz --robot ur5e": (
        "as written", r"pancake on ur5e \(robosuite\): "),
    "seqmotion train tray --config tiny --epochs 20 --batches-per-epoch 5 --out runs/tray-tiny": (
        "tests/test_plugin_task.py (installs examples/tray, runs this)", None),
    "seqmotion deform --model runs/tray-tiny --input path.csv --output smooth.csv": (
        "tests/test_plugin_task.py::test_cli_deform_and_optimize_on_the_plug_in", None),
    "seqmotion optimize --model runs/tray-tiny --target 0.02 0.01 --output reach.npz": (
        "tests/test_plugin_task.py::test_cli_deform_and_optimize_on_the_plug_in", None),
    "seqmotion export runs/tray-tiny --name tray-tiny": ("tests/test_plugin_task.py", None),
}


def test_every_readme_command_has_a_check():
    lines = readme_commands()
    missing = [line for line in lines if line not in CHECKS]
    stale = [line for line in CHECKS if line not in lines]
    assert not missing, "README command lines without a newcomer check:\n" + "\n".join(missing)
    assert not stale, "checks of lines the README no longer has:\n" + "\n".join(stale)
    for how, _ in CHECKS.values():  # a delegated line names a test that exists
        if how.startswith("tests/"):
            path, _, name = how.split(" ")[0].partition("::")
            source = (README.parent / path).read_text()
            assert not name or f"def {name}(" in source, how


def test_readme_commands_run_and_print_what_the_readme_says(tmp_path):
    """The newcomer's session: the command lines in README order, in one folder, each as written or by its named
    tiny stand-in, each exiting 0 and printing what its README comment promises."""
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    ran = 0
    for line in readme_commands():
        how, expect = CHECKS[line]
        if how.startswith("tests/"):
            continue
        command = line if how == "as written" else how.removeprefix("stand-in: ").split("  (")[0]
        if command.startswith("seqmotion "):
            argv = [sys.executable, "-m", "seqmotion.cli", *shlex.split(command)[1:]]
        else:
            argv = [sys.executable, *shlex.split(command)[1:]]
        done = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
        out = done.stdout + done.stderr
        assert done.returncode == 0, f"`{command}` (README: `{line}`) exited {done.returncode}:\n{out[-2000:]}"
        if expect is not None:
            assert re.search(expect, out), f"`{command}` did not print /{expect}/ as the README says:\n{out[-2000:]}"
        ran += 1
    assert ran >= 12


def test_the_readme_map_names_only_files_that_exist():
    """Every file the README's "How it is built" map names exists in the tree (under src/, or tests/ for the
    layering test): the map once named tasks/base.py and latent/tracking.py long after they had moved."""
    root = Path(__file__).resolve().parents[1]
    text = (root / "README.md").read_text()
    start = text.index("## How it is built")
    section = text[start:text.index("\n## ", start + 1)]
    named = set(re.findall(r"\b([a-z_0-9]+\.py)\b", section))
    files = {p.name for folder in ("src", "tests") for p in (root / folder).rglob("*.py")}
    assert named and not named - files, sorted(named - files)
    folders = set(re.findall(r"^  ([a-z_]+)/", section, flags=re.M))
    assert folders and all((root / "src" / "seqmotion" / f).is_dir() for f in folders), folders
