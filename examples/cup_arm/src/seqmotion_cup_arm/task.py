"""Carry an open cup on a two-link arm: joint torques that follow a rough joint-space sketch without spilling.

The arm and its physics are in :mod:`.arm` (the manipulator equation at 1 ms, the cup's spill angle).
The task: given a rough joint-space sketch of a move between two poses (an S-curve through a
wobbly middle pose), generate joint torques whose motion stays close to the sketch while the angle
between the cup's axis and the specific force it feels stays under ``spill_limit_deg``. A sketch
executed as drawn (a computed-torque controller tracking it exactly) often spills: the model learns
where to slow down, lag or lean the cup into the acceleration.

Everything seqmotion needs, written against its public pieces:

* **layouts** — state and input ``[q1, q2, q̇1, q̇2]`` (rad, rad/s), output ``[τ1, τ2]`` (N·m);
* **options** — a validated dataclass (``--set spill_limit_deg=15``, ``--set payload_mass=0.5``);
* **physics** — :class:`~.arm.CupArmPhysics` (payload mass, joint damping), taken from the options
  of the same names and recorded on every result; :class:`~.arm.CupArmDynamics` reads both as
  attributes, so an exported dynamics graph takes them as inputs;
* **data** — random moves between poses with the cup upright (``seqmotion.data.trajectories``);
* **presets** — the model's size, data volume and options per preset, as data (``preset_table``), the
  network's scales beside the layouts;
* **loss** — seqmotion's standard one (``Task.standard_loss``: the joint angles' likelihood under the
  covariance propagated through the arm, plus the weighted spill violation) and the end-state error;
  teacher forcing fades out over seqmotion's standard curriculum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from seqmotion.core.options import check_length_range, check_positive
from seqmotion.core.task import Preset, TeacherForcingParams
from seqmotion.data.trajectories import TensorBatch, TrajectoryBatch, draw_lengths, path_states
from seqmotion.errors import MAX_LENGTH, check_number
from seqmotion.models.seq2seq import ChunkedSeq2Seq
from seqmotion.physics.integrator import DT, CovarianceCarry
from seqmotion.physics.layout import StateLayout
from seqmotion.tasks import Task, TaskOptions

from . import arm
from .arm import HOME, CupArmDynamics, CupArmPhysics

STATE = StateLayout(("q1", "q2", "dq1", "dq2"), ("rad", "rad", "rad/s", "rad/s"), "arm state")
TORQUE = StateLayout(("tau_1", "tau_2"), ("N·m", "N·m"), "joint torques")
SHOULDER = (0.2, 1.0)
"""The range of the shoulder angle q1 [rad] the moves start from."""


@dataclass(frozen=True)
class CupArmOptions(TaskOptions):
    """Options of the cup-arm task.

    Attributes:
        spill_limit_deg: the largest angle between the cup's axis and the specific force [deg].
        length: ``[K_min, K_max]`` of the training moves (1 ms samples).
        move: the shoulder moves by up to ``±move`` [rad]; the elbow keeps the cup near upright.
        rest_tilt: start and end poses tilt the cup by up to ``±rest_tilt`` [rad].
        wobble: the sketch's middle pose strays up to ``±wobble`` per joint from the straight move [rad].
        payload_mass, joint_damping: the physics (:class:`~.arm.CupArmPhysics`) [kg], [N·m·s/rad].
        alpha_shape, alpha_constraint: weights of the joint angles' likelihood and of the violation.
        alpha_end, end_horizon: weight of the squared end-state error: the angles' [rad²] plus the speeds'
            times ``end_horizon`` [s] (the angle a speed error makes over that time). The likelihood alone
            lets the end drift: the propagated covariance is widest there.
        variance_floor: added to the propagated covariance before scoring [rad²].
    """

    spill_limit_deg: float = 20.0
    length: tuple[int, int] = (300, 500)
    move: float = 0.6
    rest_tilt: float = 0.1
    wobble: float = 0.1
    payload_mass: float = 0.3
    joint_damping: float = 0.02
    alpha_shape: float = 1.0
    alpha_constraint: float = 1000.0
    alpha_end: float = 100.0
    end_horizon: float = 0.1
    variance_floor: float = 1e-8

    def __post_init__(self) -> None:
        check_positive("spill_limit_deg", self.spill_limit_deg)
        if self.spill_limit_deg >= 90:
            raise ValueError(f"option spill_limit_deg must be below 90, got {self.spill_limit_deg}")
        check_length_range("length", self.length)
        object.__setattr__(self, "length", tuple(self.length))
        for name in ("move", "end_horizon", "variance_floor"):
            check_positive(name, getattr(self, name))
        for name in ("rest_tilt", "wobble", "alpha_shape", "alpha_constraint", "alpha_end"):
            check_positive(name, getattr(self, name), allow_zero=True)
        if self.rest_tilt >= self.spill_limit:
            raise ValueError(f"option rest_tilt ({self.rest_tilt} rad) must be below the spill limit "
                             f"({self.spill_limit:.3f} rad): a cup that tilted spills at rest")
        CupArmPhysics(self.payload_mass, self.joint_damping)  # checked where it is defined

    @property
    def spill_limit(self) -> float:
        return math.radians(self.spill_limit_deg)


def hold_torques() -> tuple[float, ...]:
    """The gravity torques [N·m] that hold the arm at :data:`~.arm.HOME` with the default payload, to 1 mN·m: the
    model's output offset, so the untrained decoder starts by roughly holding the arm up."""
    home = torch.tensor([HOME], dtype=torch.float64)
    hold = arm.bias_torques(home, torch.zeros_like(home), CupArmPhysics())[0]
    return tuple(round(float(v), 3) for v in hold)


class CupArmTask(Task):
    """Follow joint-space sketches with torques that keep the liquid in the cup."""

    name = "cup_arm"
    options_class = CupArmOptions
    physics_class = CupArmPhysics
    params_class = TeacherForcingParams
    input_layout = STATE
    state_layout = STATE
    accel_layout = TORQUE
    end_pose = (("q1", "q2"), (1.0, 1.0))
    preset_table = {
        "tiny": Preset(layers=1, hidden=16, chunk=10, batches_per_epoch=2, batch_size=8, epochs=4,  # seconds: tests
                       options={"length": (60, 100), "move": 0.2}),
        "small": Preset(layers=2, hidden=64, chunk=25, batches_per_epoch=16, batch_size=32),
    }
    input_scale = state_scale = (1.0, 1.0, 2.0, 2.0)  # rad, rad, rad/s, rad/s
    output_scale = (2.0, 1.0)  # N·m: a couple for accelerating, about the gravity torques at home
    output_offset = hold_torques()
    correlated_pairs = ((0, 1),)

    def sample(self, n: int, rng: np.random.Generator, params: TeacherForcingParams,
               options: CupArmOptions) -> TrajectoryBatch:
        """Moves from rest to rest between two poses with the cup near upright, through a wobbly middle pose."""
        opt = options
        lengths = draw_lengths(rng, n, opt.length)
        start = rng.uniform(*SHOULDER, size=n)
        shoulder = np.stack([start, start + rng.uniform(-opt.move, opt.move, size=n)], axis=1)  # (n, 2): from, to
        elbow = -shoulder + rng.uniform(-opt.rest_tilt, opt.rest_tilt, size=(n, 2))
        poses = np.stack([shoulder, elbow], axis=-1)  # (n, 2, 2): [from, to] × [q1, q2]
        middle = poses.mean(axis=1) + rng.uniform(-opt.wobble, opt.wobble, size=(n, 2))
        return TrajectoryBatch(path_states(np.stack([poses[:, 0], middle, poses[:, 1]], axis=1), lengths, DT), lengths)

    def example_inputs(self, n: int, seed: int = 0) -> np.ndarray:
        """``n`` whole training moves ``(n, K, 4)`` of the ``small`` preset, all of its middle length K."""
        options = self.options(self.train_config("small"))
        k = sum(options.length) // 2
        params, options = TeacherForcingParams(0.0), options.replace(length=(k, k))
        return self.sample(n, np.random.default_rng(seed), params, options).states

    def loss(self, model: ChunkedSeq2Seq, batch: TensorBatch, dynamics: CupArmDynamics, params: TeacherForcingParams,
             options: CupArmOptions, generator: torch.Generator) -> tuple[torch.Tensor, dict[str, float]]:
        """The standard loss (``Task.standard_loss``) plus ``alpha_end`` times the squared end-state error ``L3``."""
        opt, states, lengths = options, batch.states, batch.lengths  # on the model's device
        out = self.rollout(model, batch, dynamics, params, generator)
        loss, terms = self.standard_loss(out, batch, opt)
        last = (lengths - 1).view(-1, 1, 1).expand(-1, 1, 4)  # each move's own last sample
        gap = (out.states[:, : states.shape[1]].gather(1, last) - states.gather(1, last))[:, 0]
        end = (gap[:, :2] ** 2).sum(1) + ((opt.end_horizon * gap[:, 2:]) ** 2).sum(1)
        loss = loss + opt.alpha_end * end.mean()
        return loss, {"L1": terms["L1"], "L2": terms["L2"], "L3": float(end.detach().mean()),
                      "feasible": terms["feasible"]}

    def dynamics(self, options: CupArmOptions, physics: CupArmPhysics) -> CupArmDynamics:
        return CupArmDynamics.at(physics, DT)

    def physics_trained(self, options: CupArmOptions) -> dict[str, tuple[float, float]]:
        """The training ran at one payload and damping: the options'."""
        return {name: (getattr(options, name),) * 2 for name in CupArmPhysics.names()}

    def violation(self, states: torch.Tensor, accel: torch.Tensor, options: CupArmOptions) -> torch.Tensor:
        """``max(0, |spill angle| − limit)`` per transition [rad] (the accelerations from consecutive states)."""
        return arm.spill_violation(states, options.spill_limit, DT)

    def position_cov(self, accel_cov: torch.Tensor, states: torch.Tensor, accel: torch.Tensor,
                     outputs: dict[str, torch.Tensor], dynamics: CupArmDynamics) -> torch.Tensor:
        """The joint angles' covariance over the whole motion at once (:func:`~.arm.propagate_covariance`)."""
        joint = arm.accel_covariance(states[:, :-1, :2], accel_cov, dynamics.payload_mass)
        start = CovarianceCarry.zeros(states.shape[0], 2, joint.dtype, joint.device)
        return arm.propagate_covariance(start, joint, dynamics.dt, cache=False)[0]

    def errors(self, inputs: np.ndarray, states: np.ndarray, accel: np.ndarray, violation: np.ndarray | None,
               options: CupArmOptions) -> dict[str, np.ndarray]:
        """``shape_rmse_rad`` (RMS over samples of the joint-angle distance from the sketch), ``end_error_rad``,
        ``end_speed_rad_s`` (the joint speeds' norm at the end) and ``max_violation`` [rad], each ``(B,)``."""
        gap = np.linalg.norm(states[..., :2] - inputs[..., :2], axis=-1)
        out = {"shape_rmse_rad": np.sqrt((gap**2).mean(axis=-1)), "end_error_rad": gap[:, -1],
               "end_speed_rad_s": np.linalg.norm(states[:, -1, 2:], axis=-1)}
        if violation is not None:
            out["max_violation"] = violation.max(axis=-1) if violation.shape[-1] else np.zeros(len(states))
        return out

    def tolerances(self, options: CupArmOptions) -> dict[str, float]:
        """The liquid stays in (0.01 rad past the limit at most); the move ends within 0.05 rad of the sketch's end
        pose, nearly at rest (0.3 rad/s)."""
        return {"max_violation": 0.01, "end_error_rad": 0.05, "end_speed_rad_s": 0.3}

    def sketch(self, end: tuple[float, ...], length: int, timing: str = "s_curve") -> np.ndarray:
        """A straight S-curve joint move ``(length, 4)`` from rest at :data:`~.arm.HOME` to rest at ``end``
        ``= (q1, q2)`` [rad]."""
        if len(end) != 2:
            raise ValueError(f"a cup-arm sketch ends at joint angles (q1, q2), got {len(end)} values")
        length = check_number("length", length, minimum=2, maximum=MAX_LENGTH, integer=True)
        start, goal = np.asarray(HOME, dtype=np.float64), np.asarray(end, dtype=np.float64)
        if not np.all(np.isfinite(goal)):
            raise ValueError(f"a cup-arm sketch's end must be finite, got {list(end)}")
        waypoints = np.stack([start, (start + goal) / 2, goal])[None]
        return path_states(waypoints, np.array([length]), DT, timing)[0]


TASK = CupArmTask()
