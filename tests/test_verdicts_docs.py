"""What a plug-in author's first hour ran into: a single-output model's default config, a runner started inside
its bundle, and the documentation and README statements that the first hour found missing or wrong."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

import seqmotion as sm
from seqmotion.core import registry
from seqmotion.data.trajectories import TrajectoryBatch, draw_lengths, path_states
from seqmotion.models.seq2seq import Seq2SeqConfig
from seqmotion.physics.integrator import DT, DoubleIntegratorDynamics
from seqmotion.physics.layout import StateLayout
from seqmotion.tasks import Task, TaskOptions
from seqmotion.training import losses
from seqmotion.training.config import TrainConfig
from seqmotion.training.curriculum import Curriculum, CurriculumParams

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
GUIDE = (ROOT / "docs" / "write-a-task.md").read_text()

# --- a single-output task: the default correlation pair follows the output size -----------------------------------

LINE = StateLayout(("x", "v_x"), ("m", "m/s"), "cart state")


@dataclass(frozen=True)
class LineParams(CurriculumParams):
    teacher_forcing_prob: float


class LineTask(Task):
    """A cart on a line (one output: its acceleration) — the shape of the first hour's mass-spring task."""

    name = "line-one-output"
    presets = ("tiny",)
    params_class = LineParams
    input_layout = state_layout = LINE
    accel_layout = StateLayout(("a_x",), ("m/s²",), "cart acceleration")

    def train_config(self, preset: str) -> TrainConfig:
        # no correlated_pairs: the default must not name a second output this model does not have
        model = Seq2SeqConfig(encoder_input_dim=2, decoder_input_dim=2, output_dim=1, chunk=10, layers=1, hidden=8,
                              encoder_input_scale=[0.1, 1.0], decoder_input_scale=[0.1, 1.0], output_scale=[5.0])
        return TrainConfig(task=self.name, preset=preset, model=model.to_dict(), batches_per_epoch=1, batch_size=4,
                           curriculum=Curriculum(epochs=1, initial={"teacher_forcing_prob": 0.0}).to_dict(),
                           options=TaskOptions().to_dict())

    def sample(self, n, rng, params, options) -> TrajectoryBatch:
        lengths = draw_lengths(rng, n, (40, 60))
        waypoints = rng.uniform(-0.05, 0.05, size=(n, 3, 1))
        waypoints[:, 0] = 0.0
        return TrajectoryBatch(path_states(waypoints, lengths, DT), lengths)

    def loss(self, model, batch, dynamics, params, options, generator):
        states, lengths = batch.states, batch.lengths
        out = losses.encode_and_rollout(model, states, lengths, states[:, 0], dynamics, teacher=states,
                                        teacher_forcing_prob=params.teacher_forcing_prob, generator=generator)
        k, valid = states.shape[1], losses.sample_mask(lengths, states.shape[1])
        shape = losses.weighted_gaussian_nll((states - out.states[:, :k])[:, 1:, :1],
                                             out.outputs["pos_cov"][:, : k - 1])
        loss = losses.per_trajectory(shape, valid, lengths).mean()
        return loss, {"L1": losses.masked_mean(shape, valid)}

    def dynamics(self, options, physics) -> DoubleIntegratorDynamics:
        return DoubleIntegratorDynamics(1, DT)


def test_a_single_output_model_needs_no_correlation_pair():
    assert Seq2SeqConfig(2, 2, 1).correlated_pairs == []
    assert Seq2SeqConfig(6, 6, 3).correlated_pairs == [[0, 1]]  # ρ_yz, as every shipped model was trained
    assert Seq2SeqConfig.from_dict(Seq2SeqConfig(2, 2, 1).to_dict()).correlated_pairs == []


@pytest.fixture
def line_task():
    """The task registered for the test only (another test file's refresh would drop one registered at import)."""
    task = registry.register(LineTask())
    yield task
    registry.refresh()


def test_a_single_output_task_trains_and_generates(line_task, tmp_path):
    run = sm.tasks.train(line_task.train_config("tiny"), tmp_path / "run", progress=False)
    model = sm.load(run)
    motion = model.generate(model.task_def.example_inputs(1)[0])
    assert motion.accel.shape[-1] == 1 and np.isfinite(motion.states).all()


@pytest.mark.parametrize("config", sorted((ROOT / "src" / "seqmotion" / "pretrained").glob("*/config.json")),
                         ids=lambda p: p.parent.name)
def test_shipped_model_configs_load_unchanged(config):
    """The default changed, the shipped configs did not: each names its pairs, and reads back as written."""
    model = json.loads(config.read_text())["model"]
    if "correlated_pairs" not in model:
        pytest.skip(f"{config.parent.name} is no chunked seq2seq model")
    assert Seq2SeqConfig.from_dict(model).to_dict() == model


# --- a runner started inside its bundle ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bundle(tmp_path_factory) -> Path:
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    from seqmotion.deploy import export_onnx

    out = tmp_path_factory.mktemp("bundle") / "pancake"
    export_onnx(sm.load_pretrained("pancake"), out, source="pancake")
    return out


def test_the_onnx_stepper_runs_from_inside_its_bundle(bundle, monkeypatch):
    monkeypatch.chdir(bundle)
    stepper = sm.deploy.OnnxStepper(".", sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 200))
    assert stepper.step().shape == (50, 3)


def test_the_standalone_runner_runs_from_inside_its_bundle(bundle):
    code = """
import sys
sys.modules["torch"] = None
sys.modules["seqmotion"] = None
sys.path.insert(0, ".")
import numpy as np
from onnx_stepper import OnnxStepper
x = np.zeros((200, 6))
x[:, 0] = np.linspace(0.0, 0.2, 200)
print(OnnxStepper(".", x).step().shape)
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=bundle, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "(50, 3)" in done.stdout


# --- the polish's iterations: recorded on every keep_end result, and stated in the README as measured -------------

FLAT = " ".join(README.split())  # the README's text with its line breaks undone


def test_keep_end_results_say_how_many_polish_iterations_they_took(deformer, tmp_path):
    sketch = sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 500)  # the README's own
    r = deformer.deform(sketch, keep_end=True)
    assert r.exact and int(r.polish_iterations) > 0
    assert f"the README's sketch {int(r.polish_iterations)})" in FLAT
    assert deformer.deform(sketch).polish_iterations is None  # no polish, no count
    r.save(tmp_path / "r.npz")
    assert sm.load_result(tmp_path / "r.npz").polish_iterations == r.polish_iterations


def test_readme_states_the_measured_polish_iterations():
    measured = json.loads((ROOT / "benchmarks" / "results_polish_iterations.json").read_text())["polish_iterations"]
    assert "2–10 iterations" not in FLAT
    for name, words in (("keep_end", "`keep_end` "), ("optimize_exact_polish", "`exact=True` ")):
        it = measured[name]["iterations"]
        stated = f"{words}{it['min']:.0f}–{it['max']:.0f}"
        assert stated in FLAT and f"(median {it['median']:.0f}" in FLAT.split(stated, 1)[1][:40], stated
    cli = measured["readme_cases"]["seqmotion optimize --target 0.1 0.0 3.14 --exact"]
    assert f"`--target 0.1 0.0 3.14` {cli}" in FLAT


# --- the plug-in guide documents every optional hook, and the trainer's checks ------------------------------------


def test_the_guide_documents_every_optional_hook_of_task():
    section = GUIDE.split("## Optional hooks", 1)[1].split("\n## ", 1)[0]
    hooks = [name for name, value in vars(Task).items()
             if not name.startswith("_") and not getattr(value, "__isabstractmethod__", False)]
    assert {"physics_trained", "exact_form", "violation", "end_pose"} <= set(hooks)
    missing = [name for name in hooks if f"`{name}" not in section]
    assert not missing, f"docs/write-a-task.md's optional hooks do not name {missing}"
    assert "check_batch" in GUIDE and "check_loss" in GUIDE


# --- the README says how to see the viewer without a GPU, with the flags the browser tests use -------------------


def test_readme_gives_the_viewer_the_browser_flags_the_tests_use():
    launch = (ROOT / "tests" / "test_view.py").read_text().split("pw.chromium.launch(", 1)[1].split("])", 1)[0]
    flags = [f for f in re.findall(r'"(--[^"]+)"', launch) if f != "--no-sandbox"]
    assert "--use-angle=swiftshader" in flags
    viewer = README.split("## Interactive viewer", 1)[1].split("\n## ", 1)[0]
    command = re.search(r"`chromium ([^`]+)`", viewer)
    assert command and all(f in command.group(1).split() for f in flags), flags
    assert "without a GPU" in viewer


# --- the README says what the robots extra costs, and the lighter route ------------------------------------------


def test_readme_gives_the_robots_extra_its_cost_and_the_lighter_route():
    from seqmotion.sim.robot_models import MENAGERIE_ARMS, ROBOSUITE_ARMS

    extra = re.search(r"^robots = \[(.*)\]", (ROOT / "pyproject.toml").read_text(), flags=re.M).group(1)
    assert "robosuite" not in extra and "mink" in extra and "mujoco-menagerie" in extra  # what the README says
    section = " ".join(README.split("## Standard robot arms", 1)[1].split("\n## ", 1)[0].split())
    assert "530 MB" in section and "MENAGERIE_ROOT" in section and "`--robot menagerie:panda`" in section
    others = re.search(r"\(likewise ([^;]+);", section).group(1)
    named = {"panda", *re.findall(r"`(\w+)`", others)}
    assert named == set(MENAGERIE_ARMS), named ^ set(MENAGERIE_ARMS)  # every Menagerie arm, and only those
    assert set(ROBOSUITE_ARMS) - set(MENAGERIE_ARMS) == {"jaco"} and "no Jaco" in section


# --- long-running commands say how long they took ----------------------------------------------------------------


def test_a_long_running_command_ends_with_its_elapsed_time(tmp_path, capsys):
    from seqmotion.cli import TIMED_COMMANDS, elapsed, main

    assert TIMED_COMMANDS == {"demo", "deform", "optimize", "plan", "simulate", "train", "reproduce"}
    sketch = tmp_path / "sketch.npz"
    np.savez(sketch, states=sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 200))
    assert main(["deform", "--input", str(sketch), "--output", str(tmp_path / "d.npz")]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert re.fullmatch(r"done in \d+\.\d s", last), last
    assert (elapsed(12.34), elapsed(199.2)) == ("12.3 s", "3 min 19 s")


def test_a_command_whose_stdout_is_data_stays_data(capsys):
    from seqmotion.cli import main

    assert main(["robots", "--json"]) == 0
    assert isinstance(json.loads(capsys.readouterr().out), list)  # no "done in" after the JSON


def test_readme_states_the_busy_machine_times_it_measured():
    from seqmotion.cli import TIMED_COMMANDS

    quiet = json.loads((ROOT / "benchmarks" / "results_readme_times.json").read_text())
    busy = json.loads((ROOT / "benchmarks" / "results_readme_times_busy.json").read_text())["busy"]
    assert all(f"`{name}`" in FLAT for name in TIMED_COMMANDS) and "ends with its own time" in FLAT
    for run, next_words in (("as_is", "load average"), ("with_hog", "(load")):
        rows = busy[run]
        assert f"{next_words} {rows['load_average_1min']:.1f}" in FLAT, run
        keep, refine = rows["deform keep_end"]["warm_median_s"], rows["refine_plan circle 900"]["warm_s"]
        assert f"{keep:.2f} s ({keep / quiet['deform keep_end']['warm_median_s']:.1f}×" in FLAT, run
        ratio = refine / quiet["refine_plan circle 900"]["warm_s"]
        assert f"{refine:.1f} s ({ratio:.1f}×" in FLAT or f"{refine:.1f} s ({ratio:.0f}×)" in FLAT, run
        assert f"`{rows['seqmotion plan --refine']['last_line']}`" in FLAT, run
