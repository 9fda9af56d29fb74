"""Verdicts a new user can trust: the physics every model was trained over is recorded and checked, the command
line's `.npz` outputs are results `sm.load_result` reads, and the README's word on planning at the arm's friction is
true.

* A plug-in task that never wrote ``physics_trained`` by hand: ``generate(x, physics=...replace(mass=4.0))`` on a
  model trained at 2 kg came back in distribution. The trainer now records the physics it trained over in the
  model's ``config.json``; models saved without the record (the shipped ones) behave as before.
* ``seqmotion deform --output deformed.npz`` wrote plain arrays that ``sm.load_result`` refused.
* The README recommended planning at the arm's friction (μ = 0.5) without saying that it lies outside the shipped
  planner's training, which the command line then warned about.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion.cli import main
from seqmotion.core import registry, trust
from seqmotion.core.options import TaskOptions, check_length_range, check_positive
from seqmotion.data.trajectories import TensorBatch, TrajectoryBatch, draw_lengths, path_states
from seqmotion.errors import check_number
from seqmotion.models.seq2seq import ChunkedSeq2Seq, Seq2SeqConfig, rollout
from seqmotion.physics.integrator import DT, integrate_chunk
from seqmotion.physics.layout import StateLayout
from seqmotion.physics.parameters import Physics
from seqmotion.tasks import Task
from seqmotion.training.config import TrainConfig
from seqmotion.training.curriculum import Curriculum, CurriculumParams, Stage
from seqmotion.training.losses import masked_mean, sample_mask

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module", autouse=True)
def _one_thread(one_thread):
    """Every test here runs torch on one thread (see conftest)."""


# --- a plug-in task whose physics is a mass, registered by hand ----------------------------------------------------

STATE = StateLayout(("x", "y", "v_x", "v_y"), ("m", "m", "m/s", "m/s"), "cart state")
FORCE = StateLayout(("f_x", "f_y"), ("N", "N"), "cart force")


@dataclasses.dataclass(frozen=True)
class CartPhysics(Physics):
    """A planar cart of ``mass`` [kg] pushed by the decoder's force plus a constant ``drift`` along x [N] (a slope:
    negative, so the trust margin must widen a negative value the right way)."""

    mass: float = 2.0
    drift: float = -0.5

    def __post_init__(self) -> None:
        object.__setattr__(self, "mass", check_number("mass", self.mass, minimum=0.1, maximum=100.0))
        object.__setattr__(self, "drift", check_number("drift", self.drift, minimum=-100.0, maximum=100.0))


@dataclasses.dataclass(frozen=True)
class CartOptions(TaskOptions):
    length: tuple[int, int] = (30, 50)
    reach: float = 0.03
    mass: float = 2.0
    drift: float = -0.5

    def __post_init__(self) -> None:
        check_length_range("length", self.length)
        object.__setattr__(self, "length", tuple(self.length))
        check_positive("reach", self.reach)
        CartPhysics(self.mass, self.drift)


@dataclasses.dataclass(frozen=True)
class CartParams(CurriculumParams):
    teacher_forcing_prob: float


class CartDynamics:
    """Semi-closed-form double integrator of the acceleration ``(force + drift) / mass``."""

    def __init__(self, mass: float, drift: float) -> None:
        self.mass, self.drift = mass, drift

    def start(self, x0: torch.Tensor) -> torch.Tensor:
        return x0

    def step(self, carry: torch.Tensor, mean: torch.Tensor, cov: torch.Tensor | None) -> tuple[torch.Tensor, dict]:
        push = torch.tensor([self.drift, 0.0], dtype=carry.dtype, device=carry.device)
        states = integrate_chunk(carry, (mean.to(carry.dtype) + push) / self.mass, DT)
        return states[:, -1], {"states": states}

    def decoder_input(self, states: torch.Tensor) -> torch.Tensor:
        return states

    def restart(self, carry: torch.Tensor, state: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return torch.where(mask.view(-1, 1), state.to(carry.dtype), carry)

    def narrow(self, carry: torch.Tensor, rows: int) -> torch.Tensor:
        return carry[:rows]


class CartTask(Task):
    """Follow a rough planar path with a cart of some mass (a test task that writes no ``physics_trained``)."""

    name = "verdicts_trust_cart"
    presets = ("tiny",)
    options_class = CartOptions
    params_class = CartParams
    physics_class = CartPhysics
    input_layout = STATE
    state_layout = STATE
    accel_layout = FORCE

    def train_config(self, preset: str) -> TrainConfig:
        scale = [0.03, 0.03, 0.3, 0.3]
        model = Seq2SeqConfig(encoder_input_dim=4, decoder_input_dim=4, output_dim=2, chunk=10, layers=1, hidden=8,
                              encoder_input_scale=scale, decoder_input_scale=scale, output_scale=[5.0, 5.0])
        curriculum = Curriculum(epochs=1, initial={"teacher_forcing_prob": 0.5}, stages=[])
        return TrainConfig(task=self.name, preset=preset, model=model.to_dict(), curriculum=curriculum.to_dict(),
                           batches_per_epoch=2, batch_size=4, options=CartOptions().to_dict())

    def sample(self, n: int, rng: np.random.Generator, params: CartParams, options: CartOptions) -> TrajectoryBatch:
        lengths = draw_lengths(rng, n, options.length)
        waypoints = rng.uniform(-options.reach, options.reach, size=(n, 3, 2))
        waypoints[:, 0] = 0.0
        return TrajectoryBatch(path_states(waypoints, lengths, DT), lengths)

    def loss(self, model: ChunkedSeq2Seq, batch: TensorBatch, dynamics: CartDynamics, params: CartParams,
             options: CartOptions, generator: torch.Generator) -> tuple[torch.Tensor, dict[str, float]]:
        states, lengths = batch.states, batch.lengths
        k_max = states.shape[1]
        out = rollout(model, model.encode(states, lengths), states[:, 0], dynamics, model.num_chunks(k_max),
                      need_cov=False)
        valid = sample_mask(lengths, k_max)
        error = ((states - out.states[:, :k_max])[:, 1:, :2] ** 2).sum(-1)
        return (error * valid).sum() / valid.sum(), {"L1": masked_mean(error, valid)}

    def dynamics(self, options: CartOptions, physics: CartPhysics) -> CartDynamics:
        return CartDynamics(physics.mass, physics.drift)


@pytest.fixture(scope="module")
def cart(tmp_path_factory):
    """The cart task registered by hand and trained two steps by the library's trainer: ``(task, run directory)``."""
    task = registry.register(CartTask())
    try:
        run = tmp_path_factory.mktemp("cart") / "run"
        sm.tasks.train(task.train_config("tiny"), run, progress=False, device="cpu")
        yield task, run
    finally:
        registry.refresh()


def physics_reasons(result: object) -> list[str]:
    return [r for r in result.ood_reasons if "trained" in r]


def test_a_plug_in_is_checked_against_the_physics_it_was_trained_at(cart):
    _, run = cart
    model = sm.load(run)
    sketch = model.task_def.sample(1, np.random.default_rng(1), CartParams(0.0), model.options).states[0, :40]
    heavy = model.generate(sketch, physics=model.physics.replace(mass=4.0))
    assert heavy.out_of_distribution
    assert physics_reasons(heavy) == ["mass 4 outside 1.8-2.2 (trained 2-2)"]
    assert model.config["physics_trained"] == {"mass": [2.0, 2.0], "drift": [-0.5, -0.5]}  # recorded by the trainer
    # the physics it trained at, and within the trust margin, add no reason (the negative drift included)
    for physics in (None, model.physics.replace(mass=2.1), model.physics.replace(drift=-0.54)):
        assert physics_reasons(model.generate(sketch, physics=physics)) == []
    judged = model.assess(sketch, heavy.states, heavy.accel, physics=model.physics.replace(drift=0.5))
    assert judged.out_of_distribution
    assert physics_reasons(judged) == ["drift 0.5 outside -0.55--0.45 (trained -0.5--0.5)"]


def test_the_record_covers_what_the_curriculum_sweeps_and_a_bad_record_is_refused(cart):
    task, run = cart
    config = task.train_config("tiny")
    config.curriculum = Curriculum(2, {"teacher_forcing_prob": 0.5, "mass": 1.5},
                                   [Stage(2, 2, {"mass": [1.5, 3.0]})]).to_dict()
    assert task.physics_trained_over(config) == {"mass": (1.5, 3.0), "drift": (-0.5, -0.5)}
    model = sm.load(run)
    for bad, named in (({"mass": [3.0, 1.0]}, "mass"), ({"payload": [1.0, 1.0]}, "payload"),
                       ({"mass": [1.0, float("nan")]}, "mass"), ([1.0, 2.0], "physics_trained")):
        with pytest.raises(ValueError, match=named) as refused:
            task.wrap(model.model, {**model.config, "physics_trained": bad})
        assert "\n" not in str(refused.value)


def test_models_saved_without_the_record_behave_as_before(deformer, planner):
    assert "physics_trained" not in deformer.config and deformer.physics_trained == {}
    assert "physics_trained" not in planner.config
    assert planner.physics_trained == {"mu": (0.8, 1.2), "mu_dyn": (0.35, 0.65)}  # the task's own ranges
    line = sm.tasks.sliding.data.line(0.05, 500)
    assert physics_reasons(planner.plan(line, mu=0.73)) == []
    assert physics_reasons(planner.plan(line, mu=0.7)) == ["mu 0.7 outside 0.72-1.32 (trained 0.8-1.2)"]


# --- the command line's .npz outputs are results -------------------------------------------------------------------


def test_cli_npz_outputs_load_as_results_and_csv_stays_plain(tmp_path, capsys):
    sketch = sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 300)
    np.savetxt(tmp_path / "in.csv", sketch, delimiter=",", header="y,z,theta,v_y,v_z,v_theta", comments="")
    assert main(["deform", "--input", str(tmp_path / "in.csv"), "--output", str(tmp_path / "deformed.npz")]) == 0
    deformed = sm.load_result(tmp_path / "deformed.npz")
    assert type(deformed).__name__ == "DeformResult" and deformed.physics.mu == 1.0
    with np.load(tmp_path / "deformed.npz") as plain:  # still plain named arrays for other readers
        np.testing.assert_array_equal(plain["states"], deformed.states)
        assert "errors.end_position_error_m" in plain.files
    plan_args = ["--circle", "0.03", "--length", "300", "--mu", "0.9", "--output", str(tmp_path / "p.npz")]
    assert main(["plan", *plan_args]) == 0
    plan = sm.load_result(tmp_path / "p.npz")
    assert type(plan).__name__ == "SlidingPlan" and plan.physics.mu == 0.9
    with np.load(tmp_path / "p.npz") as plain:  # what `seqmotion simulate sliding` reads is kept
        np.testing.assert_array_equal(plain["pan_states"], plan.pan_states)
        assert plain["friction"].tolist() == [0.9, 0.5] and plain["command"].shape == (300, 4)
    assert main(["optimize", "--target", "0.1", "0.0", "3.14", "--steps", "1", "--output", str(tmp_path / "o.npz")
                 ]) == 0
    optimized = sm.load_result(tmp_path / "o.npz")
    assert type(optimized).__name__ == "OptimizationResult" and optimized.history.shape == (2,)
    assert main(["deform", "--input", str(tmp_path / "in.csv"), "--output", str(tmp_path / "deformed.csv")]) == 0
    assert (tmp_path / "deformed.csv").read_text().startswith("y,z,theta,")
    capsys.readouterr()


# --- the README on planning at the arm's friction --------------------------------------------------------------------


def test_readme_says_the_arms_friction_is_outside_the_planners_training_and_what_it_costs(planner):
    readme = " ".join((ROOT / "README.md").read_text().split())
    found = re.search(r"μ = 0\.5 lies outside the shipped planner's training friction \(μ ([\d.]+)–([\d.]+), flagged "
                      r"below ([\d.]+) with the trust margin\): a plan made at it is `out_of_distribution`", readme)
    assert found, "the README does not say that μ = 0.5 is outside the planner's training friction"
    low, high, flagged = map(float, found.groups())
    assert planner.physics_trained["mu"] == (low, high) and flagged == pytest.approx(low * (1 - trust.MARGIN))
    line = sm.tasks.sliding.data.line(0.05, 500)
    at_arm, default = planner.plan(line, mu=0.5, mu_dyn=0.5), planner.plan(line)
    assert at_arm.out_of_distribution and physics_reasons(at_arm)[0].startswith("mu 0.5 outside")
    cost = re.search(r"the 5 cm line planned ([\d.]+) mm off at μ = 0\.5 against ([\d.]+) mm at the default μ = 1, the "
                     r"refined 900-sample circle ([\d.]+) mm against ([\d.]+) mm\. On the arm, planning at its own "
                     r"friction still pays: ([\d.]+) mm against ([\d.]+) mm", readme)
    assert cost, "the README does not say what planning at μ = 0.5 costs"
    line_arm, line_default, circle_arm, circle_default, on_arm, on_arm_default = cost.groups()
    assert f"{1e3 * at_arm.errors['tracking_rmse_m']:.1f}" == line_arm
    assert f"{1e3 * default.errors['tracking_rmse_m']:.1f}" == line_default
    # the refined circle's numbers are the benchmark's (the refined 2.8 mm runs in tests/test_readme.py's session)
    results = (ROOT / "benchmarks" / "RESULTS.md").read_text()
    assert f"| circle 5 cm, K 900 | μ 0.5 / 0.5 | 39.5 | 39.5 | {circle_arm} | **{on_arm}** |" in results
    assert f"| circle 5 cm, K 900 | μ 1 / 0.5 | 41.9 | 43.1 | {circle_default} | {on_arm_default} |" in results
