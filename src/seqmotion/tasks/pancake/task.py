"""Chapter 2: deforming pancake-turning motions so the pancake stays on the spatula.

Wiring: physics = the planar double integrator + the friction cone
(:mod:`seqmotion.tasks.pancake.physics`); inputs = acceleration- and position-type trajectories
(:mod:`seqmotion.tasks.pancake.data`); loss = eqs. 2.17–2.25; curriculum = SPEC §3.

The loss of one trajectory of length K, generated states x̂ and inputs û::

    L = 1/(K-1) Σ_{k=0}^{K-2} ( α1[k+1] L1[k+1] + α2 L2[k] )
    L1[k] = -log N(D x[k] | D x̂[k], D S_x[k] Dᵀ + floor I)      (shape kept)
    L2[k] = F_c(θ̂[k], û[k])                                     (pancake kept on)

with α1 = 1 (10 on the last 10 samples), α2 = 1000 (the dissertation: 10; see
:class:`PancakeOptions`), D = [[1,0,0],[0,1,0],[0,0,0.1]] on the
positions (metres vs radians) and the variance floor of :mod:`seqmotion.training.losses`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ...core.execution import BindingLimit, ExecutionCheck
from ...core.options import TaskOptions, check_count, check_length_range, check_positive
from ...core.polish import ExactForm
from ...core.results import FEASIBLE_TOLERANCE, Motion
from ...core.task import Preset, Task
from ...core.trained import TrainedModel
from ...data.trajectories import TensorBatch, TrajectoryBatch
from ...errors import as_trajectories
from ...models.seq2seq import DEFAULT_CHUNK, ChunkedSeq2Seq
from ...physics.integrator import DT, DoubleIntegratorDynamics
from ...physics.transcription import within_reach
from ...training.curriculum import Curriculum, CurriculumParams, Stage
from ...training.losses import (
    DEFAULT_VARIANCE_FLOOR,
    encode_and_rollout,
    gaussian_nll_1d,
    gaussian_nll_2d_entries,
    masked_mean,
    per_trajectory,
    sample_mask,
)
from . import data as inputs
from .physics import (
    ACCEL_LAYOUT,
    MU,
    STATE_DIM,
    STATE_LAYOUT,
    PancakePhysics,
    cone_constraint,
    cone_half_angle,
    violation_angle,
    violation_torch,
)

THETA_WEIGHT = 0.1
"""D's scaling of the attitude against positions (eq. 2.25): 1 rad counts like 0.1 m."""
POLISH_NORMAL_FLOOR = 4.0
"""[m/s²] The exact polish keeps ``μ n ∓ t`` at least this, so the pancake is pressed on with ≥ 0.4 g.
An exact motion that sits at the edge (free fall, ``n → 0``) holds in the model's physics but not on an
arm that tracks it with any error (``benchmarks/RESULTS.md``: executed ``keep_end`` motions)."""
JOINT_POLISH_NORMAL_FLOOR = 3.0
"""[m/s²] The normal-force floor of a polish on a robot's joints (``deform(..., keep_end=True, robot="ur5e")``): a turn
within the joints' rated speeds is a loop that barely presses the pancake on at its top, and the arm follows its
planned joint path closely, so it can sit below :data:`POLISH_NORMAL_FLOOR`. Not much below: on 25 README-style turns
on the UR5e, executed under PD + DOB, one polished at 2 m/s² lost the pancake (the README's own turn, to the arm's
tracking error at the bottom of its loop) and none at 3."""
POLISH_ACCEL_LIMITS = (30.0, 30.0, 300.0)
"""[m/s², m/s², rad/s²] The exact polish keeps the spatula's accelerations within these: what the MuJoCo
arm under PD + DOB follows with the pancake on (motions it lost peaked far above them; ``benchmarks/RESULTS.md``).
A sketch too short to end where it ends, at rest, within them (e.g. 0.3 m and 3 rad in 0.15 s) gets the
time it needs (``keep_end``'s ``extend``)."""
POLISH_REACH = 0.40
"""[m] The exact polish keeps the spatula's (y, z) within this distance of the origin: inside the MuJoCo arm's
workspace at every attitude (the nearest (y, z) out of reach at some θ lies 0.409 m out, on a 5 mm grid).
Without it, a polish that turns the pancake over near the bottom of the workspace may drop the spatula out
of the arm's reach to keep the pancake pressed on."""
POLISH_TRAVEL_ACCEL = (12.0, 15.0, 60.0)
"""[m/s², m/s², rad/s²] The accelerations ``keep_end`` plans a too-short sketch's time on (bang-bang, rest to
rest): 40 %, 50 % and 20 % of the limits. The cone takes the rest — a level spatula can push the pancake
sideways or drop it at only (9.8 − 4) m/s² — and turning over takes the most: the spatula's normal has to
follow θ. Fitted on sketches of one seed, checked on another's (``benchmarks/RESULTS.md``): most first
polishes succeed, with motions no longer than after failed tries."""
END_SPEED_TOLERANCE = 0.5
"""[m/s] The fastest |(v_y, v_z)| a motion may end with and still be executed as it is. The arm does not stop
a motion that ends moving: ``seqmotion simulate pancake`` (:mod:`seqmotion.sim.kinematics`, §4.4.3) appends
0.1 s of constant deceleration, 10·v m/s² for 0.05·v m more travel. At 0.5 m/s that is 5 m/s², within the
g − :data:`POLISH_NORMAL_FLOOR` = 5.8 m/s² a spatula can brake with while still pressing the pancake on, and
25 mm of overshoot; at the 2.9 m/s a plain ``deform`` of the README's sketch ends with it is 29 m/s² (the
arm's limit, :data:`POLISH_ACCEL_LIMITS`) and 145 mm, which took the spatula out of the arm's workspace."""
END_POSITION_TOLERANCE = 0.05
"""[m] The farthest the motion's end (y, z) may lie from the input's end. The arm's workspace leaves little
room: :data:`POLISH_REACH` keeps polished motions within 0.40 m of the origin, and the arm cannot reach some
attitude 0.409 m out (``sim.arm.workspace_problem``), so a sketch drawn to the edge of the reach has ~1 cm
to spare; 50 mm plus the ≤ 25 mm stop of :data:`END_SPEED_TOLERANCE` is about the pancake's own radius
(55 mm, ``sim.scene.PANCAKE_RADIUS``): a motion farther off puts the pancake down somewhere else than asked,
and may leave the workspace (the README's sketch, plainly deformed, ends 348 mm off)."""
POLISH_SMOOTHNESS = 1000.0
"""λ of the polish's jerk term (starting and ending at zero acceleration): the correction spreads over
≈ 30 ms instead of steps an arm cannot follow."""


def chapter2_curriculum() -> Curriculum:
    """The dissertation's 100-epoch schedule (SPEC §3)."""
    return Curriculum(
        epochs=100,
        initial={"teacher_forcing_prob": 1.0, "phi_max": math.pi / 4, "accel_type_prob": 1.0},
        stages=[
            Stage(11, 20, {"teacher_forcing_prob": [1.0, 0.0]}),  # scheduled sampling
            Stage(31, 40, {"phi_max": [math.pi / 4, math.pi]}),  # inputs that need deforming
            Stage(61, 80, {"accel_type_prob": [1.0, 0.0]}),  # toward position-type inputs
        ],
    )


@dataclass(frozen=True)
class PancakeOptions(TaskOptions):
    """Options of the pancake task (``--set KEY=VALUE`` on ``seqmotion train pancake``).

    Attributes:
        length: ``[K_min, K_max]`` of the training inputs (samples at 1 ms).
        alpha_shape: α1, the weight of the shape likelihood.
        alpha_shape_end: α1 on the last ``end_samples`` samples.
        end_samples: how many final samples get ``alpha_shape_end``.
        alpha_constraint: α2. The dissertation uses 10; with our likelihood (variance floor 1e-8,
            per-sample σ) that balance leaves the constraint weak (``benchmarks/RESULTS.md``: the share
            of outputs inside the cone against α2). A large hinge weight acts as an exact penalty.
        variance_floor: added to every covariance before scoring (see :mod:`seqmotion.training.losses`).
        mu: the static friction coefficient μ of the cone (atan μ = 45° for μ = 1). The model is
            trained, judged, optimised and simulated at this μ.
        cone_margin: train against ``atan(μ) - margin`` [rad]; 0 = the dissertation's loss.
        alpha_end: weight of an end-position term: the mean over the last ``end_samples`` samples of
            ``|D (x[k] - x̂[k])|`` (y, z [m] and 0.1·θ [rad]), added once per trajectory. Unlike the
            likelihood, whose predicted σ may widen at the end and so discount the error there, this
            norm is an exact penalty. 0 (the default) leaves the loss as it was.
        alpha_rest: weight of an end-velocity term, the same on the velocities: the mean over the last
            ``end_samples`` samples of ``|D (v[k] - v̂[k])|`` [m/s] (the input's velocities: a sketch
            that ends at rest asks for rest). 0 (the default) leaves the loss as it was.
    """

    length: tuple[int, int] = (100, 500)
    alpha_shape: float = 1.0
    alpha_shape_end: float = 10.0
    end_samples: int = 10
    alpha_constraint: float = 1000.0
    variance_floor: float = DEFAULT_VARIANCE_FLOOR
    mu: float = MU
    cone_margin: float = 0.0
    alpha_end: float = 0.0
    alpha_rest: float = 0.0

    _OMITTED_AT_ZERO = ("alpha_end", "alpha_rest")
    """Options added after models were trained: left out of ``to_dict`` at their default 0, so configs
    (and run identities, checked on resume) written before them stay exactly what they were."""

    def to_dict(self) -> dict[str, Any]:
        data = super().to_dict()
        for name in self._OMITTED_AT_ZERO:
            if data.get(name) == 0:
                del data[name]
        return data

    def __post_init__(self) -> None:
        check_length_range("length", self.length)
        object.__setattr__(self, "length", tuple(self.length))
        for name in ("alpha_shape", "alpha_shape_end", "alpha_constraint", "alpha_end", "alpha_rest",
                     "variance_floor", "mu"):
            check_positive(name, getattr(self, name), allow_zero=name.startswith("alpha"))
        check_count("end_samples", self.end_samples, minimum=0)
        check_positive("cone_margin", self.cone_margin, allow_zero=True)
        if self.cone_margin >= self.cone_half_angle:
            raise ValueError(f"option cone_margin ({self.cone_margin} rad) leaves no cone at mu = {self.mu}")

    @property
    def cone_half_angle(self) -> float:
        """atan μ [rad]: the largest |ψ| at which the pancake holds."""
        return cone_half_angle(self.mu)


@dataclass(frozen=True)
class PancakeParams(CurriculumParams):
    """The chapter-2 curriculum's parameters at one step (:func:`chapter2_curriculum`)."""

    teacher_forcing_prob: float
    phi_max: float
    accel_type_prob: float


class PancakeTask(Task):
    """Learning to deform motions under the friction-cone constraint."""

    name = "pancake"
    options_class = PancakeOptions
    input_layout = STATE_LAYOUT
    state_layout = STATE_LAYOUT
    accel_layout = ACCEL_LAYOUT
    physics_class = PancakePhysics
    params_class = PancakeParams
    end_pose = (("y", "z", "theta"), (1.0, 1.0, THETA_WEIGHT))

    # The chapter-2/4 architecture: encoder on states, decoder on generated states, 3-D Gaussian outputs.
    # tiny: seconds on a laptop, for tests; small: the chapter-4 model, 2 × 64, full curriculum, paper data volume;
    # paper: ch. 2, 2 × 512 cells, 100 epochs × 64 × 256 = 1,638,400 trajectories.
    preset_table = {
        "tiny": Preset(layers=2, hidden=16, chunk=10, batches_per_epoch=2, batch_size=8, epochs=10,
                       options={"length": (20, 60)}),
        "small": Preset(layers=2, hidden=64, chunk=DEFAULT_CHUNK, batches_per_epoch=64, batch_size=256),
        "paper": Preset(layers=2, hidden=512, chunk=DEFAULT_CHUNK, batches_per_epoch=64, batch_size=256),
    }
    input_scale = state_scale = (0.1, 0.1, 1.0, 1.0, 1.0, 10.0)  # m, m, rad, m/s, m/s, rad/s
    output_scale = (10.0, 10.0, 100.0)  # m/s², m/s², rad/s²
    correlated_pairs = ((0, 1),)  # ρ_yz (eq. 2.11)

    def preset_curriculum(self) -> Curriculum:
        """The dissertation's 100-epoch schedule (:func:`chapter2_curriculum`)."""
        return chapter2_curriculum()

    def sample(
        self, n: int, rng: np.random.Generator, params: PancakeParams, options: PancakeOptions
    ) -> TrajectoryBatch:
        return inputs.mixture(
            n, rng, accel_type_prob=params.accel_type_prob, phi_max=params.phi_max, length=options.length,
        ).longest_first()

    def loss(
        self, model: ChunkedSeq2Seq, batch: TensorBatch, dynamics: DoubleIntegratorDynamics, params: PancakeParams,
        options: PancakeOptions, generator: torch.Generator,
    ) -> tuple[torch.Tensor, dict[str, float]]:
        opt = options
        states, lengths = batch.states, batch.lengths  # longest first, as sample() draws them
        device = states.device
        k_max = states.shape[1]
        out = encode_and_rollout(
            model, states, lengths, states[:, 0], dynamics, teacher=states,
            teacher_forcing_prob=params.teacher_forcing_prob, generator=generator, expand_cov=False,
        )
        gen_states = out.states[:, :k_max]

        def pos_cov(i: int, j: int) -> torch.Tensor:  # entry (i, j) of the covariance of states 1..K_max-1
            return out.cov_entry("pos_cov", i, j)[:, : k_max - 1]

        accel = out.accel[:, : k_max - 1]  # u[0..K_max-2]
        valid = sample_mask(lengths, k_max)  # samples 1..K-1 = transitions 0..K-2

        # L1[k], k = 1..K-1: Gaussian NLL of D x[k] under D x̂[k], D S_x[k] Dᵀ.
        diff = states[:, 1:, :3] - gen_states[:, 1:, :3]  # sliced first: half the memory traffic, both ways
        floor = opt.variance_floor
        nll = gaussian_nll_2d_entries(diff[..., :2], pos_cov(0, 0), pos_cov(0, 1), pos_cov(1, 1), floor) + \
            gaussian_nll_1d(THETA_WEIGHT * diff[..., 2], THETA_WEIGHT**2 * pos_cov(2, 2), floor)
        k = torch.arange(1, k_max, device=device).unsqueeze(0)
        near_end = k >= (lengths - opt.end_samples).unsqueeze(1)
        alpha1 = torch.where(near_end, opt.alpha_shape_end, opt.alpha_shape)

        # L2[k], k = 0..K-2: friction-cone violation of the generated motion.
        fc = violation_torch(gen_states[:, : k_max - 1, 2], accel, opt.mu) * valid
        if opt.cone_margin > 0:  # optionally aim inside the cone, leaving a safety margin
            angle = violation_angle(gen_states[:, : k_max - 1, 2], accel).abs()
            fc_train = torch.relu(angle - (opt.cone_half_angle - opt.cone_margin))
        else:
            fc_train = fc

        per_traj = per_trajectory(alpha1 * nll + opt.alpha_constraint * fc_train, valid, lengths)
        extra = {}
        if opt.alpha_end > 0 or opt.alpha_rest > 0:  # only then: the default loss stays bit for bit what it was
            end = (near_end & valid).float()
            weight = torch.tensor([1.0, 1.0, THETA_WEIGHT], device=device)
            for name, alpha, err in (("L_end", opt.alpha_end, diff),
                                     ("L_rest", opt.alpha_rest, states[:, 1:, 3:6] - gen_states[:, 1:, 3:6])):
                if alpha > 0:
                    dist = torch.sqrt(((weight * err) ** 2).sum(-1) + 1e-12)  # |D e| per sample; smooth at 0
                    term = (dist * end).sum(1) / end.sum(1).clamp_min(1)  # mean over the last end_samples
                    per_traj = per_traj + alpha * term
                    extra[name] = float(term.detach().mean())
        loss = per_traj.mean()
        max_fc = fc.detach().amax(1)
        terms = {
            "L1": masked_mean(nll, valid),
            "L2": masked_mean(fc, valid),
            **extra,
            "feasible": float((max_fc <= FEASIBLE_TOLERANCE).float().mean()),
        }
        return loss, terms

    # --- physics at inference -------------------------------------------------------------------

    def dynamics(self, options: PancakeOptions, physics: PancakePhysics) -> DoubleIntegratorDynamics:
        """The spatula's double integrator. μ acts through the friction cone, which the model was trained to
        keep at ``options.mu``: another μ is refused (train at it: ``--set mu=...``)."""
        if physics.mu != options.mu:
            raise ValueError(f"the pancake model keeps the friction cone at the mu it was trained at "
                             f"(options.mu = {options.mu:g}), got mu = {physics.mu:g}; train at that mu with "
                             "`seqmotion train pancake --set mu=...`")
        return DoubleIntegratorDynamics(3, DT)

    def violation(self, states: torch.Tensor, accel: torch.Tensor, options: PancakeOptions) -> torch.Tensor:
        """F_c per transition at the model's μ (eq. 2.18)."""
        return violation_torch(states[:, : accel.shape[1], 2], accel, options.mu)

    def exact_form(self, options: PancakeOptions) -> ExactForm:
        """The double integrator with the friction cone in force form at the model's μ (for ``exact=True``
        and ``keep_end=True``), pressing the pancake on with at least :data:`POLISH_NORMAL_FLOOR`, within
        :data:`POLISH_ACCEL_LIMITS`, smoothed by :data:`POLISH_SMOOTHNESS`."""
        cone = cone_constraint(options.mu, margin=POLISH_NORMAL_FLOOR)
        reach = within_reach((0, 1), POLISH_REACH, "within the arm's reach")
        return ExactForm(3, DT, (cone,), (1.0, 1.0, THETA_WEIGHT**2), POLISH_SMOOTHNESS, POLISH_ACCEL_LIMITS,
                         POLISH_TRAVEL_ACCEL, workspace=(reach,),
                         on_joints=(cone_constraint(options.mu, margin=JOINT_POLISH_NORMAL_FLOOR),))

    def sketch(self, end: tuple[float, ...], length: int, timing: str = "s_curve") -> np.ndarray:
        """A straight motion from rest at 0 to rest at ``end = (y, z, θ)`` (ch. 4's inputs)."""
        if len(end) != 3:
            raise ValueError(f"a pancake sketch ends at (y, z, theta), got {len(end)} values")
        return inputs.straight(tuple(end), length, timing=timing)

    def make_result(self, motion: Motion, model: TrainedModel) -> DeformResult:
        theta = torch.from_numpy(motion.states[:, :-1, 2])
        psi = violation_angle(theta, torch.from_numpy(motion.accel)).numpy()
        return DeformResult(motion.states, motion.accel, motion.latent, motion.violation, psi, **motion.trust())

    def errors(
        self, inputs: np.ndarray, states: np.ndarray, accel: np.ndarray, violation: np.ndarray | None,
        options: TaskOptions,
    ) -> dict[str, np.ndarray]:
        """``shape_rmse_m`` (y, z RMS distance from the input), ``end_position_error_m``,
        ``end_attitude_error_rad``, ``end_speed_m_s`` (|(v_y, v_z)| at the end), ``max_violation_rad``
        (largest F_c at the model's μ), each ``(B,)``."""
        out = super().errors(inputs, states, accel, violation, options)
        if "max_violation" in out:
            out["max_violation_rad"] = out.pop("max_violation")
        return out

    def tolerances(self, options: TaskOptions) -> dict[str, float]:
        """Warn when F_c exceeds 0.01 rad, or the motion ends farther than :data:`END_POSITION_TOLERANCE` from
        the input's end or faster than :data:`END_SPEED_TOLERANCE` (not executable on the arm as it is; the
        plain learned motion usually is not — a median 9 cm off at 1.2 m/s — which ``keep_end=True`` fixes).
        (No shape tolerance: keeping the pancake on moves the path by centimetres, by design.)"""
        return {"max_violation_rad": FEASIBLE_TOLERANCE, "end_position_error_m": END_POSITION_TOLERANCE,
                "end_speed_m_s": END_SPEED_TOLERANCE}


TASK = PancakeTask()


# --- user-facing API -------------------------------------------------------------------------


@dataclass
class DeformResult(Motion):
    """A deformed trajectory (or a batch of them: a leading B axis on every field): a
    :class:`~seqmotion.core.results.Motion` with the cone angle.

    Attributes:
        states: ``(K, 6)`` deformed states; ``states[0]`` is the input's first state and
            ``states[k+1] = A states[k] + B accel[k]``.
        accel: ``(K-1, 3)`` the generated inputs ``u[0..K-2]`` [m/s², m/s², rad/s²].
        latent: ``(L·H,)`` the latent z the motion was decoded from.
        violation: ``(K-1,)`` F_c per sample [rad] at the model's μ (0 where the pancake holds); ``feasible``:
            whether max F_c ≤ 0.01 rad.
        psi: ``(K-1,)`` the cone angle ψ per sample [rad] (Figs. 2.6, 4.3c).
        (and :class:`~seqmotion.core.results.TrustSignals`: ``uncertainty`` ``(K, 3)`` std of y, z, θ; ``errors``
        ``shape_rmse_m``, ``end_position_error_m``, ``end_attitude_error_rad``, ``end_speed_m_s``,
        ``max_violation_rad``; ``out_of_distribution``, ``ood_reasons``; ``exact`` with ``keep_end``)
        robot_check: with ``deform(..., robot=…)``: whether that robot can execute the motion
            (:class:`~seqmotion.core.execution.ExecutionCheck`: its joint speeds, accelerations, ranges and reach
            against the rated limits, the binding one, and the duration it would need); None otherwise.
    """

    psi: np.ndarray | None = None
    robot_check: ExecutionCheck | None = None  # feasible is False where it finds a limit broken (Motion.feasible)
    per_transition = ("violation", "psi")  # load_result checks each is (K-1,)

    __module__ = "seqmotion.tasks.pancake"
    """Its public home, the name saved results know it by (``seqmotion.tasks.pancake.DeformResult``). (dataclass
    looks a ``ClassVar`` annotation up in that module, still being imported here: ``per_transition`` has none.)"""


class Deformer(TrainedModel):
    """A trained chapter-2 model: turns rough motions into ones that keep the pancake on.

    Obtain one with ``sm.load_pretrained("pancake")`` or ``sm.load(run_dir)``. Its μ is
    ``self.options.mu`` (the μ it was trained at); every result is judged at it.

    One verb for every model: :meth:`~seqmotion.tasks.TrainedModel.generate` (encode a motion, decode it
    through the task's physics) works on this model as on any task's, plug-ins included, and returns the
    same :class:`DeformResult`. :meth:`deform` is the pancake's (chapter 2's) name for it, as ``plan`` is the
    sliding planner's; code meant for any task calls ``generate``.
    """

    task = "pancake"

    def deform(self, states: object, keep_end: bool = False, extend: bool = True,
               robot: object = None) -> DeformResult:
        """Deform ``(K, 6)`` or ``(B, K, 6)`` states (any K ≥ 2) into feasible ones: :meth:`generate` under the
        chapter's name (the same result; a bad shape is worded for pancake states).

        Args:
            states: the rough motion(s) [m, m, rad, m/s, m/s, rad/s] at 1 ms.
            keep_end: also make the motion end exactly where the input ends (y, z, θ of its last
                sample), at rest, with the cone held (F_c ≤ 1e-6 rad) and within the arm's acceleration
                limits (:data:`POLISH_ACCEL_LIMITS`): the learned motion is polished into the nearest one
                that does (IPOPT, a few iterations; see :meth:`TrainedModel.polish`). The learned motion
                alone (the default) keeps the cone but may end elsewhere and still moving;
                ``result.exact`` says which were polished. An end tilted past the cone's half-angle (atan μ,
                45° at μ = 1) cannot hold the pancake at rest: the cone holds through the motion's last
                acceleration, and the pancake leaves the spatula there (released: the flip).
            extend: with ``keep_end``, give a sketch too short to stop within the limits the time it needs
                (``result.length`` samples instead of K); ``False`` keeps K and flags such a motion instead.
            robot: the robot the motion is for (``"ur5e"``, ``"panda"``, ``"mh3f"``, …; see
                ``seqmotion.sim.robots()``). With ``keep_end``, the polish also keeps its rated joint speeds (and
                accelerations where published), ranges, torques and reach, where its placement turns the spatula with
                parallel joints (the UR5e's shoulder lift, elbow and wrist 1: ``seqmotion.sim.planar_chain``): a turn
                becomes a loop of the arm, at least 1 s long, that ends at rest as near the end pose as those limits
                allow, and exactly at it where the arm can (``result.exact``; a turn past the cone's half-angle has to
                end rising and braking at more than g, so it can end only higher and further out than it starts —
                a turn to 2.9 rad at the start point ends ~0.7 rad short, warned). Every motion is then judged on the
                robot: its joint path by
                the simulator's IK against the rated speeds, accelerations, ranges and reach
                (``result.robot_check``). Where a limit is broken, ``result.feasible`` is False and a
                ``RuntimeWarning`` names the binding limit and the duration the motion would need. One motion at a
                time.

        Raises:
            ValueError: wrong shape, K < 2, NaN or inf; a batch with ``robot``; an unknown robot.
        """
        _, single = as_trajectories(states, STATE_DIM, "states")  # the pancake's own wording for a bad input
        if robot is not None and not single:
            raise ValueError("deform(robot=...) makes one motion at a time: pass states of shape (K, 6)")
        return self.generate(states, keep_end=keep_end, extend=extend, robot=robot)


RESULT_PARTS = (BindingLimit, ExecutionCheck)
"""The dataclasses a saved :class:`DeformResult` nests: ``load_result`` finds them by name in its home,
:mod:`seqmotion.tasks.pancake` (which exports them)."""


PancakeTask.model_class = Deformer
