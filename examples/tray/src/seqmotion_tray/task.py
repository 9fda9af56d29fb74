"""Carry a cup on a tray: a planar point mass whose acceleration must not tip the cup.

A tray held level and moved with horizontal acceleration ``a`` makes a cup on it feel the
specific force ``g − a``: tilted from the vertical by ``atan(|a| / g)``. The cup stays put while
that *tilt-equivalent angle* stays under a limit (15° here: a tall cup's tipping angle, or a
friction cone of μ = tan 15°). The task: given a rough planar path of the tray, generate a
motion close to it that never exceeds the limit.

Everything seqmotion needs is in this one module, written against seqmotion's public pieces:

* **layouts** — state ``[x, y, v_x, v_y]`` (m, m/s), input ``[a_x, a_y]`` (m/s²);
* **options** — a validated dataclass (``--set max_tilt_deg=10`` on ``seqmotion train tray``);
* **physics** — the double integrator (``seqmotion.physics.integrator``) and the violation
  ``max(0, atan(|a|/g) − limit)``;
* **data** — random quadratic paths with S-curve timing (``seqmotion.data.trajectories``);
* **presets** — the model's size, data volume and options per preset, as data (``preset_table``),
  the network's scales beside the layouts;
* **loss** and **curriculum** — seqmotion's standard ones (``Task.standard_loss``: the shape likelihood
  through the propagated covariance plus the weighted violation; teacher forcing fading out).

The package's ``pyproject.toml`` registers ``TASK`` under the entry-point group
``seqmotion.tasks``; nothing in seqmotion is edited.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from seqmotion.core.options import check_length_range, check_positive
from seqmotion.core.task import Preset, TeacherForcingParams
from seqmotion.data.trajectories import TrajectoryBatch, draw_lengths, path_states
from seqmotion.physics.integrator import DT, DoubleIntegratorDynamics
from seqmotion.physics.layout import StateLayout
from seqmotion.physics.parameters import Physics
from seqmotion.tasks import Task, TaskOptions

GRAVITY = 9.8  # [m/s²]
STATE = StateLayout(("x", "y", "v_x", "v_y"), ("m", "m", "m/s", "m/s"), "tray state")
ACCEL = StateLayout(("a_x", "a_y"), ("m/s²", "m/s²"), "tray acceleration")


def tilt_angle(accel: torch.Tensor) -> torch.Tensor:
    """The tilt-equivalent angle ``atan(|a| / g)`` [rad] of accelerations ``(..., 2)``.

    ``|a|`` is taken as ``sqrt(a·a + ε)`` so the gradient stays finite at rest.
    """
    return torch.atan(torch.sqrt((accel**2).sum(-1) + 1e-12) / GRAVITY)


@dataclass(frozen=True)
class TrayOptions(TaskOptions):
    """Options of the tray task.

    Attributes:
        max_tilt_deg: the largest tilt-equivalent angle the cup tolerates [deg].
        length: ``[K_min, K_max]`` of the training paths (1 ms samples).
        reach: the paths' waypoints are drawn from ``[-reach, reach]²`` [m].
        alpha_shape, alpha_constraint: weights of the shape likelihood and of the violation.
        variance_floor: added to the propagated covariance before scoring [m²].
    """

    max_tilt_deg: float = 15.0
    length: tuple[int, int] = (200, 400)
    reach: float = 0.1
    alpha_shape: float = 1.0
    alpha_constraint: float = 1000.0
    variance_floor: float = 1e-8

    def __post_init__(self) -> None:
        check_positive("max_tilt_deg", self.max_tilt_deg)
        if self.max_tilt_deg >= 90:
            raise ValueError(f"option max_tilt_deg must be below 90, got {self.max_tilt_deg}")
        check_length_range("length", self.length)
        object.__setattr__(self, "length", tuple(self.length))
        check_positive("reach", self.reach)
        check_positive("alpha_shape", self.alpha_shape, allow_zero=True)
        check_positive("alpha_constraint", self.alpha_constraint, allow_zero=True)
        check_positive("variance_floor", self.variance_floor)

    @property
    def max_tilt(self) -> float:
        return math.radians(self.max_tilt_deg)


class TrayTask(Task):
    """Deform planar tray motions so the cup never feels more than ``max_tilt_deg``."""

    name = "tray"
    options_class = TrayOptions
    params_class = TeacherForcingParams
    input_layout = STATE
    state_layout = STATE
    accel_layout = ACCEL
    end_pose = (("x", "y"), (1.0, 1.0))
    preset_table = {
        "tiny": Preset(layers=1, hidden=16, chunk=10, batches_per_epoch=2, batch_size=8, epochs=4,  # seconds: tests
                       options={"length": (100, 200), "reach": 0.03}),
        "small": Preset(layers=2, hidden=64, chunk=25, batches_per_epoch=32, batch_size=64),
    }
    input_scale = state_scale = (0.1, 0.1, 1.0, 1.0)  # m, m, m/s, m/s
    output_scale = (5.0, 5.0)  # m/s²
    correlated_pairs = ((0, 1),)

    def sample(self, n: int, rng: np.random.Generator, params: TeacherForcingParams, options: TrayOptions
               ) -> TrajectoryBatch:
        opt = options
        lengths = draw_lengths(rng, n, opt.length)
        waypoints = rng.uniform(-opt.reach, opt.reach, size=(n, 3, 2))
        waypoints[:, 0] = 0.0  # every path starts at the origin, at rest
        return TrajectoryBatch(path_states(waypoints, lengths, DT), lengths)

    def dynamics(self, options: TrayOptions, physics: Physics) -> DoubleIntegratorDynamics:
        return DoubleIntegratorDynamics(2, DT)

    def violation(self, states: torch.Tensor, accel: torch.Tensor, options: TrayOptions) -> torch.Tensor:
        """``max(0, atan(|a|/g) − limit)`` per transition [rad]."""
        return torch.relu(tilt_angle(accel) - options.max_tilt)

    def sketch(self, end: tuple[float, ...], length: int, timing: str = "s_curve") -> np.ndarray:
        """A straight S-curve path from rest at the origin to rest at ``end = (x, y)``."""
        if len(end) != 2:
            raise ValueError(f"a tray sketch ends at (x, y), got {len(end)} values")
        start, goal = np.zeros(2), np.asarray(end, dtype=np.float64)
        waypoints = np.stack([start, (start + goal) / 2, goal])[None]
        return path_states(waypoints, np.array([length]), DT, timing)[0]


TASK = TrayTask()
