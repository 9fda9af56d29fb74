"""Chapter 3: shaking a frying pan so an object slides along a commanded path — the task, its options and planner.

Wiring: physics = pan double integrator + Coulomb stick/slip contact
(:mod:`seqmotion.tasks.sliding.physics`); commands = physics-type and B-spline-type
(:mod:`seqmotion.tasks.sliding.data`); the encoder reads the command ``x_d`` (object relative to
pan), the decoder reads the generated ``[x̂_p, x̂_d]`` and emits pan accelerations ``û_p``
with their 2 × 2 covariances, and the contact model runs inside the free-running loop.

Losses (per trajectory, k = 1..K-1, normalised by K-1):

* **L** (3.20–3.23): ``α1 NLL(p_d[k] | p̂_d[k], S_pd[k]) + α2 max(0, |p̂_p[k]| − p_lim)
  + α3 |û_p[k] − û_p[k−1]|`` with α1 = 1, α2 = 100 (the dissertation: 10; see
  :class:`SlidingOptions`), α3 = 1, p_lim = 0.2 m. Its gradient
  passes through the contact model (and vanishes wherever the object sticks).
* **L'** (3.24): ``NLL(p_p[k] | p̂_p[k], S_pp[k])`` against the pan trajectory that produced
  a physics-type command — supervised, and no gradient passes back through the contact model.

Curriculum (Table 3.1, read as SPEC §4 fixes it): epochs 1–10 L' on physics-type commands;
11–20 L' with probability 1 − (e−10)/10 per trajectory, else L; 21–30 L; 31–40 L with
B-spline commands with probability (e−30)/10; 41–50 L on B-spline commands.
Variants with the same budget: **A** that curriculum, **B** stage 3 only (L on physics-type
for 50 epochs), **C** stage 1 only (L' for 50 epochs).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import torch

from ...core.execution import BindingLimit, ExecutionCheck, check_execution
from ...core.options import TaskOptions, check_choice, check_length_range, check_positive
from ...core.results import Motion, View
from ...core.task import Preset, Task
from ...core.trained import TrainedModel
from ...data.trajectories import TensorBatch, TrajectoryBatch, tracking_rmse
from ...errors import as_trajectories
from ...models.seq2seq import ChunkedSeq2Seq, Seq2SeqConfig
from ...physics.integrator import DT, integrate_covariance
from ...training.config import TrainConfig
from ...training.curriculum import Curriculum, CurriculumParams, Stage
from ...training.losses import encode_and_rollout, gaussian_nll_2d, masked_mean, per_trajectory, sample_mask
from . import data as commands
from . import physics as contact
from .robot import (
    ACCEPT_CLEARANCE,
    ACCEPT_SHARE,
    ROBOT_KINDS,
    ROBOT_MARGIN,
    RUN_KINDS,
    PanJointLimits,
    SlidingExecutionCheck,
    check_limit_kinds,
    pan_acceleration_reach,
)

PAN_LIMIT = 0.2  # p_lim [m]
TRACKING_TOLERANCE = 0.005
"""A plan whose object strays more than this RMS from its command [m] gets a warning."""
VARIANTS = {
    "A": None,  # the full curriculum
    "B": {"loss_prime_prob": 0.0, "bspline_prob": 0.0},  # stage 3 only: L through the contact model
    "C": {"loss_prime_prob": 1.0, "bspline_prob": 0.0},  # stage 1 only: L' (no contact model)
}


def chapter3_curriculum() -> Curriculum:
    """Table 3.1 with L' and the physics-type commands fading out (SPEC §4)."""
    return Curriculum(
        epochs=50,
        initial={"loss_prime_prob": 1.0, "bspline_prob": 0.0},
        stages=[Stage(11, 20, {"loss_prime_prob": [1.0, 0.0]}), Stage(31, 40, {"bspline_prob": [0.0, 1.0]})],
    )


def model_config(layers: int, hidden: int, head_hidden: int, chunk: int = 100) -> Seq2SeqConfig:
    """The sliding task's model of this size (:meth:`SlidingTask.model_config`, its scales)."""
    return TASK.model_config(layers, hidden, chunk, head_hidden)


@dataclass(frozen=True)
class SlidingOptions(TaskOptions):
    """Options of the sliding task (``--set KEY=VALUE`` on ``seqmotion train sliding``).

    Attributes:
        length: ``[K_min, K_max]`` of the training commands.
        alpha_shape: α1, the weight of the object's likelihood.
        alpha_range: α2. The dissertation uses 10; with it our model A drove the pan up to 0.49 m
            from home on friction it had not seen (measured over the ch. 3 grid), far beyond p_lim.
        alpha_jerk: α3.
        pan_limit: p_lim [m].
        variance_floor: (1 mm)²: the object's position only needs millimetres, and the 0.1 mm
            default made the NLL ~1e4 whenever the object lagged its command.
        mu, mu_dyn: the nominal static and dynamic friction (μ, μ'): what the model is trained at
            (unless a range or pairs are given) and what ``plan`` rolls out at by default.
        friction_range: beyond the dissertation (off by default): draw each training
            trajectory's friction from ``[[μ_lo, μ_hi], [μ'_lo, μ'_hi]]`` (with μ' < μ).
        friction_pairs: beyond the dissertation (off by default): draw each training trajectory's
            friction from this list of ``[μ, μ']`` pairs.
        pan_shaking: how the physics-type commands' pans shake (:mod:`seqmotion.tasks.sliding.data`):
            ``"position"`` keeps the pan near home; ``"velocity"`` lets it random-walk.
        variant: which of the dissertation's models A, B, C the schedule is (informational).
    """

    length: tuple[int, int] = (500, 1500)
    alpha_shape: float = 1.0
    alpha_range: float = 100.0
    alpha_jerk: float = 1.0
    pan_limit: float = PAN_LIMIT
    variance_floor: float = 1e-6
    mu: float = contact.MU
    mu_dyn: float = contact.MU_DYN
    friction_range: list | None = None
    friction_pairs: list | None = None
    pan_shaking: str = "position"
    variant: str | None = None

    def __post_init__(self) -> None:
        check_length_range("length", self.length)
        object.__setattr__(self, "length", tuple(self.length))
        for name in ("alpha_shape", "alpha_range", "alpha_jerk"):
            check_positive(name, getattr(self, name), allow_zero=True)
        check_positive("pan_limit", self.pan_limit)
        check_positive("variance_floor", self.variance_floor)
        contact.check_pan_friction(self.mu, self.mu_dyn)
        if self.friction_pairs is not None and self.friction_range is not None:
            raise ValueError("set at most one of the options friction_range and friction_pairs")
        if self.friction_pairs is not None:
            pairs = np.asarray(self.friction_pairs, dtype=float)
            if pairs.ndim != 2 or pairs.shape[1] != 2 or len(pairs) == 0:
                raise ValueError(f"friction_pairs must be a list of [mu, mu_dyn], got {self.friction_pairs}")
            for mu, mu_dyn in pairs:
                _check_option_friction("friction_pairs", self.friction_pairs, mu, mu_dyn)
        if self.friction_range is not None:
            rng = np.asarray(self.friction_range, dtype=float)
            if rng.shape != (2, 2) or not np.all(np.isfinite(rng)) or np.any(rng[:, 0] > rng[:, 1]):
                raise ValueError(f"friction_range must be [[mu_lo, mu_hi], [mu_dyn_lo, mu_dyn_hi]], got "
                                 f"{self.friction_range}")
            # every pair drawn lies between the lowest and the highest: (mu_lo, mu_dyn_lo) and mu_hi
            _check_option_friction("friction_range", self.friction_range, rng[0, 0], rng[1, 0])
            _check_option_friction("friction_range", self.friction_range, rng[0, 1], None)
        check_choice("pan_shaking", self.pan_shaking, commands.PAN_SHAKINGS)
        if self.variant is not None:
            check_choice("variant", self.variant, tuple(VARIANTS))


def _check_option_friction(option: str, value: object, mu: float, mu_dyn: float | None) -> None:
    """``ValueError`` naming ``option`` (whose ``value`` holds ``mu``, ``mu_dyn``) unless they are friction the
    contact model runs at (:func:`~seqmotion.tasks.sliding.physics.check_pan_friction`)."""
    try:
        contact.check_pan_friction(mu, mu if mu_dyn is None else mu_dyn)
    except ValueError as exc:
        raise ValueError(f"{option} must hold friction with 0 < mu and 0 <= mu_dyn <= mu, got {value}: {exc}") from None


def friction_trained(opt: SlidingOptions) -> dict[str, tuple[float, float]]:
    """The lowest and highest static and dynamic friction the training draws (:func:`training_friction`)."""
    if opt.friction_pairs is not None:
        pairs = np.asarray(opt.friction_pairs, dtype=float)
        mu, mu_dyn = pairs[:, 0], pairs[:, 1]
    elif opt.friction_range is not None:
        (mu_lo, mu_hi), (mud_lo, mud_hi) = opt.friction_range
        mu, mu_dyn = np.array([mu_lo, mu_hi]), np.array([mud_lo, min(mud_hi, mu_hi)])
    else:
        mu, mu_dyn = np.array([opt.mu]), np.array([opt.mu_dyn])
    return {"mu": (float(mu.min()), float(mu.max())), "mu_dyn": (float(mu_dyn.min()), float(mu_dyn.max()))}


def training_friction(n: int, rng: np.random.Generator, opt: SlidingOptions) -> tuple[np.ndarray, np.ndarray]:
    """Static and dynamic friction ``(μ, μ')`` for ``n`` training trajectories, each ``(n,)``."""
    if opt.friction_pairs is not None:
        pairs = np.asarray(opt.friction_pairs, dtype=float)
        pick = pairs[rng.integers(len(pairs), size=n)]
        return pick[:, 0], pick[:, 1]
    if opt.friction_range is not None:
        (mu_lo, mu_hi), (mud_lo, mud_hi) = opt.friction_range
        mu = rng.uniform(mu_lo, mu_hi, size=n)
        return mu, rng.uniform(mud_lo, np.minimum(mud_hi, mu), size=n)  # μ' < μ
    return np.full(n, opt.mu), np.full(n, opt.mu_dyn)


@dataclass(frozen=True)
class SlidingParams(CurriculumParams):
    """The chapter-3 curriculum's parameters at one step (:func:`chapter3_curriculum`)."""

    loss_prime_prob: float
    bspline_prob: float


class SlidingTask(Task):
    """Learning to plan pan motions that slide an object along a commanded path."""

    name = "sliding"
    options_class = SlidingOptions
    input_layout = contact.REL_LAYOUT
    state_layout = contact.PLAN_LAYOUT
    accel_layout = contact.ACCEL_LAYOUT
    physics_class = contact.SlidingPhysics
    params_class = SlidingParams
    end_pose = (("x", "y"), (1.0, 1.0))
    uncertainty_fields = ("x", "y")  # the object's position relative to the pan

    # paper: 2 × 1024 + 500-unit linear, C = 100, 50 epochs × 8192 trajectories; small: trains on a 2-core CPU, the
    # dissertation's data volume (50 × 8192); tiny: seconds, for tests.
    preset_table = {
        "tiny": Preset(layers=1, hidden=16, chunk=20, batches_per_epoch=2, batch_size=8, epochs=10,
                       options={"length": (60, 120)}),
        "small": Preset(layers=2, hidden=128, chunk=100, head_hidden=128, batches_per_epoch=128, batch_size=64),
        "paper": Preset(layers=2, hidden=1024, chunk=100, head_hidden=500, batches_per_epoch=32, batch_size=256),
    }
    input_scale = (0.05, 0.05, 0.3, 0.3)  # the object relative to the pan: m, m, m/s, m/s
    state_scale = (0.05, 0.05, 0.5, 0.5) + input_scale  # the pan's, then the object's
    output_scale = (10.0, 10.0)  # m/s²: μ g ≈ 9.8
    correlated_pairs = ((0, 1),)  # ρ between the pan's x and y accelerations

    def preset_curriculum(self) -> Curriculum:
        """Table 3.1 (:func:`chapter3_curriculum`); :meth:`apply_variant` makes models B and C of it."""
        return chapter3_curriculum()

    def apply_variant(self, config: TrainConfig, variant: str) -> TrainConfig:
        """Model A, B or C of §3.5.2: same budget, different schedule."""
        if variant not in VARIANTS:
            raise ValueError(f"unknown variant {variant!r}; choose from {sorted(VARIANTS)}")
        fixed = VARIANTS[variant]
        if fixed is not None:
            epochs = int(config.curriculum["epochs"])
            config.curriculum = Curriculum(epochs, dict(fixed)).to_dict()
        config.options = {**config.options, "variant": variant}
        return config

    def sample(
        self, n: int, rng: np.random.Generator, params: SlidingParams, options: SlidingOptions
    ) -> TrajectoryBatch:
        opt = options
        mu, mu_dyn = training_friction(n, rng, opt)
        batch = commands.mixture(n, rng, bspline_prob=params.bspline_prob, length=opt.length,
                                 mu=mu, mu_dyn=mu_dyn, shaking=opt.pan_shaking)
        # which trajectories are scored with L' (only those with a pan trajectory behind them)
        use_prime = (rng.random(n) < params.loss_prime_prob) & batch.extras["has_pan"]
        batch.extras.update(loss_prime=use_prime, mu=mu, mu_dyn=mu_dyn)
        return batch.longest_first()  # the rollout then skips commands that have ended without reordering

    def loss(
        self, model: ChunkedSeq2Seq, batch: TensorBatch, dynamics: contact.SlidingDynamics, params: SlidingParams,
        options: SlidingOptions, generator: torch.Generator,
    ) -> tuple[torch.Tensor, dict[str, float]]:
        opt = options
        command, lengths, prime = batch.states, batch.lengths, batch.extras["loss_prime"]
        pan_true = batch.extras["pan_states"].float()
        device = command.device
        b, k_max, _ = command.shape

        # each training trajectory has its own friction (options.friction_range / friction_pairs)
        dynamics = dynamics.per_trajectory(batch.extras["mu"], batch.extras["mu_dyn"], detach_contact=prime)
        out = encode_and_rollout(model, command, lengths, torch.zeros(b, 8, device=device), dynamics)
        pan = out.states[:, 1:k_max, :4]  # states 1..K_max-1
        rel = out.states[:, 1:k_max, 4:]
        accel = out.accel[:, : k_max - 1]  # û_p[0..K_max-2]
        floor = opt.variance_floor
        valid = sample_mask(lengths, k_max)

        # L': the pan against the pan that generated the command (supervised).
        nll_pan = gaussian_nll_2d(pan_true[:, 1:, :2] - pan[..., :2], out.outputs["pan_pos_cov"][:, : k_max - 1], floor)
        # L: the object against the command, through the contact model, plus range and jerk.
        nll_rel = gaussian_nll_2d(command[:, 1:, :2] - rel[..., :2], out.outputs["pos_cov"][:, : k_max - 1], floor)
        over_range = torch.relu(pan[..., :2].norm(dim=-1) - opt.pan_limit)
        jerk = torch.cat([torch.zeros(b, 1, device=device), (accel[:, 1:] - accel[:, :-1]).norm(dim=-1)], dim=1)
        loss_main = opt.alpha_shape * nll_rel + opt.alpha_range * over_range + opt.alpha_jerk * jerk

        per_traj = torch.where(
            prime, per_trajectory(nll_pan, valid, lengths), per_trajectory(loss_main, valid, lengths)
        )
        with torch.no_grad():
            n_valid = valid.sum(1).clamp_min(1)
            err = (command[:, 1:, :2] - rel[..., :2]).norm(dim=-1)
            rmse = torch.sqrt(((err**2) * valid).sum(1) / n_valid)
            terms = {
                "L1": masked_mean(nll_rel, valid),
                "L2": masked_mean(over_range, valid),
                "L3": masked_mean(jerk, valid),
                "Lprime": masked_mean(nll_pan, valid),
                "rmse_mm": float(1000 * rmse.mean()),
                "pan_max_m": float((pan[..., :2].norm(dim=-1) * valid).amax(1).mean()),
                "loss_prime_share": float(prime.float().mean()),
            }
        return per_traj.mean(), terms

    # --- physics at inference -------------------------------------------------------------------

    def dynamics(self, options: SlidingOptions, physics: contact.SlidingPhysics) -> contact.SlidingDynamics:
        """The pan + contact physics at the friction ``physics``."""
        return contact.SlidingDynamics.at(physics, DT)

    def start_state(self, inputs: torch.Tensor) -> torch.Tensor:
        """The pan at rest at 0; the object where the command starts."""
        return torch.cat([torch.zeros_like(inputs[:, 0]), inputs[:, 0]], dim=1)

    def make_result(self, motion: Motion, model: TrainedModel) -> SlidingPlan:
        return SlidingPlan(motion.states, motion.accel, motion.latent, motion.violation, **motion.trust())

    def errors(
        self, inputs: np.ndarray, states: np.ndarray, accel: np.ndarray, violation: np.ndarray | None,
        options: TaskOptions,
    ) -> dict[str, np.ndarray]:
        """Against the command ``inputs`` ``(B, K, 4)``, each ``(B,)``: ``tracking_rmse_m`` (RMS distance of the
        object from its command), ``end_error_m``, ``end_speed_m_s`` (the object's, relative to the pan),
        ``travel_share`` (the object's farthest distance from its start over the command's) and
        ``pan_max_m`` (the pan's farthest excursion from home)."""
        rel, pan = states[..., 4:6], states[..., :2]
        gap = np.linalg.norm(rel - inputs[..., :2], axis=-1)
        command_travel = np.linalg.norm(inputs[..., :2] - inputs[:, :1, :2], axis=-1).max(axis=-1)
        travel = np.linalg.norm(rel - rel[:, :1], axis=-1).max(axis=-1)
        return {
            "tracking_rmse_m": tracking_rmse(rel, inputs[..., :2]),
            "end_error_m": gap[:, -1],
            "end_speed_m_s": np.linalg.norm(states[:, -1, 6:8], axis=-1),
            "travel_share": travel / np.maximum(command_travel, 1e-9),
            "pan_max_m": np.linalg.norm(pan, axis=-1).max(axis=-1),
        }

    def position_cov(
        self, accel_cov: torch.Tensor, states: torch.Tensor, accel: torch.Tensor, outputs: dict[str, torch.Tensor],
        dynamics: contact.SlidingDynamics,
    ) -> torch.Tensor:
        """The object's relative-position covariance ``(B, K-1, 2, 2)``: ``S_ud = J S_up Jᵀ`` with the contact
        model's ``J = ∂u_d/∂u_p`` per sample (−I sliding, 0 stuck or stopping, ``−I + μg (I − m mᵀ)/|u_p|``
        at breakaway; rebuilt from each sample's ``branch``), integrated in closed form — what
        :class:`~seqmotion.tasks.sliding.physics.SlidingDynamics` propagates chunk by chunk as ``pos_cov``."""
        branch = outputs["branch"]
        mu = torch.as_tensor(dynamics.mu, dtype=accel.dtype, device=accel.device).reshape(-1, 1, 1, 1)
        norm = accel.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        m = (accel / norm).unsqueeze(-1)  # (B, K-1, 2, 1)
        eye = torch.eye(2, dtype=accel.dtype, device=accel.device)
        breakaway = -eye + mu * contact.GRAVITY / norm.unsqueeze(-1) * (eye - m @ m.transpose(-1, -2))
        jac = torch.where((branch == contact.BREAKAWAY)[..., None, None], breakaway,
                          torch.where((branch == contact.SLIDE)[..., None, None], -eye, torch.zeros_like(eye)))
        return integrate_covariance(jac @ accel_cov @ jac.transpose(-1, -2), dynamics.dt)

    def physics_trained(self, options: SlidingOptions) -> dict[str, tuple[float, float]]:
        """The (lowest, highest) friction μ, μ' of the training trajectories (:func:`friction_trained`)."""
        return friction_trained(options)

    def tolerances(self, options: SlidingOptions) -> dict[str, float]:
        """Warn when the object strays more than 5 mm RMS from its command or the pan leaves ``pan_limit``."""
        return {"tracking_rmse_m": TRACKING_TOLERANCE, "pan_max_m": options.pan_limit}


TASK = SlidingTask()


RESULT_PARTS = (BindingLimit, ExecutionCheck, SlidingExecutionCheck)
"""The dataclasses a saved :class:`SlidingPlan` nests: ``load_result`` finds them by name in the plan's module,
:mod:`seqmotion.tasks.sliding` (which exports them)."""



def command_tracking(command: np.ndarray, alpha_end: float = 0.3, alpha_jerk: float = 10.0,
                     pan_limit: float = PAN_LIMIT, alpha_range: float = 10.0):  # noqa: ANN201 - a closure
    """``f(states, accel) -> (B,)``: the object's squared distance from ``command`` ``(K, 4)`` [mm²], averaged over
    the plan, plus ``refine_plan``'s default terms (end error, jerk, pan range;
    ``seqmotion.tasks.sliding.latent.Tracking`` with its default recipe)."""
    target = torch.from_numpy(np.asarray(command, dtype=np.float64))[None]

    def f(states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        c = target.to(states.dtype)
        value = 1e6 * ((states[..., 4:6] - c[..., :2]) ** 2).sum(-1).mean(-1)
        value = value + alpha_end * 1e6 * ((states[:, -1, 4:6] - c[:, -1, :2]) ** 2).sum(-1)
        if accel.shape[1] > 1:
            value = value + alpha_jerk * (accel[:, 1:] - accel[:, :-1]).norm(dim=-1).mean(-1)
        over = torch.relu(states[..., :2].norm(dim=-1) - pan_limit)
        return value + alpha_range * 1e6 * (over**2).mean(-1)

    return f


@dataclass
class SlidingPlan(Motion):
    """A planned pan motion (a leading B axis on every field for a batch): a
    :class:`~seqmotion.core.results.Motion` in ``PLAN_LAYOUT``, with the plan's names for its parts.

    Attributes:
        states: ``(K, 8)`` the pan ``[x, y, vx, vy]`` (from rest at 0) and the object relative to the pan
            ``[x, y, vx, vy]`` as the 2-D contact model predicts; ``pan_states`` and ``rel_states`` are its halves.
        accel: ``(K-1, 2)`` the pan accelerations ``û_p[0..K-2]`` [m/s²] (``pan_accel``).
        latent: ``(L·H,)`` the command's latent.
        robot_check: with ``plan(..., robot=…)`` / ``refine_plan(..., robot=…)``: whether that robot can execute the
            pan motion (:class:`SlidingExecutionCheck`: its joint speeds, accelerations, torques, ranges and reach
            against the robot's limits, and the binding one); None otherwise. ``feasible`` reads it.
        uncertainty: ``(K, 2)`` the model's predicted std of the object's x, y [m] per sample (its Gaussian
            head's covariance propagated through the pan integrator and the contact model's Jacobian).
        errors: ``tracking_rmse_m``, ``end_error_m``, ``end_speed_m_s``, ``travel_share``, ``pan_max_m``
            (:meth:`SlidingTask.errors`; ``(B,)`` each for a batch).
        out_of_distribution: whether the command lies outside what the model was trained on
            (:mod:`seqmotion.core.trust`; ``(B,)`` for a batch).
        ood_reasons: which command features were out, e.g. ``["peak_speed_m_s 1.9 > 0.62"]``.
        physics: the friction it was planned at (``SlidingPhysics``).
        (the last five, and ``exact``, are :class:`~seqmotion.core.results.TrustSignals`)
    """

    robot_check: ExecutionCheck | None = None

    __module__ = "seqmotion.tasks.sliding"
    """Its public home, the name saved plans know it by (``seqmotion.tasks.sliding.SlidingPlan``)."""

    views = {"pan_accel": View("accel"), "pan_states": View("states", 0, 4), "rel_states": View("states", 4, 8)}

    @property
    def feasible(self) -> np.ndarray | bool | None:
        """With a robot check (:attr:`robot_check`): whether that robot can execute the plan — False where a limit is
        broken, True where every needed limit is known and kept, None where some is unknown. Without one, None (the
        plan has no constraint of its own)."""
        if self.robot_check is None:
            return super().feasible
        return self.robot_check.ok


class SlidingPlanner(TrainedModel):
    """A trained chapter-3 model: commanded object path → pan motion (``sm.load_pretrained("sliding")``)."""

    task = "sliding"

    def plan(self, command: object, mu: float | None = None, mu_dyn: float | None = None, robot: object = None,
             limits: tuple[str, ...] = ROBOT_KINDS) -> SlidingPlan:
        """Plan pan accelerations that make the object follow ``command``.

        Args:
            command: ``(K, 4)`` or ``(B, K, 4)`` object states relative to the pan, any K ≥ 2.
            mu, mu_dyn: the friction of the 2-D physics the plan is rolled out in (default: the
                model's nominal ``options.mu``, ``options.mu_dyn``; the model is never told them,
                it reacts to the object's simulated motion). The plan records them: ``plan.physics``.
            robot: plan for this robot (``"panda"``, ``"ur5e"``, …; ``seqmotion.sim.robots()``): the plan is checked
                on the robot's joint path (the simulator's IK along the pan command of the run, its stop included;
                ``plan.robot_check``) and, where a limit is broken, its latent is refined with the robot's limits as
                objective terms (:meth:`fit_robot`) until they hold. ``plan.feasible`` is then whether the robot can
                execute it: False, with a ``RuntimeWarning`` naming the binding limit, where a rated limit is broken
                after all. One command at a time; seconds instead of milliseconds where the plain plan breaks a limit.
            limits: with ``robot``, the limits the plan is refined to keep, of :data:`ROBOT_KINDS` (default all:
                rated joint speeds, joint ranges with the reach, torque limits, rated joint accelerations where
                published). Every limit is judged whatever this says: :data:`RUN_KINDS` (``("speed", "range",
                "torque")``) keeps what a simulated run judges and leaves a plan that breaks the rated accelerations
                ``feasible`` False. On the Panda the rated accelerations cap the pan's acceleration at about μg for
                μ = 0.5, so a plan keeping them barely slides the object: a second ``RuntimeWarning`` says so when
                keeping the limits left the object much farther from the command than the plain plan
                (``benchmarks/bench_sliding_robot_limits.py``).

        Raises:
            ValueError: wrong shape, K < 2, NaN or inf; a batch with ``robot``; an unknown robot or limit kind.
        """
        physics = self.physics.replace(mu=mu, mu_dyn=mu_dyn)  # checked once, recorded on the plan
        _, single = as_trajectories(command, 4, "command")  # the planner's own wording for a bad input
        if robot is None:
            return self.generate(command, physics=physics)
        if not single:
            raise ValueError("plan(robot=...) plans one command at a time: pass a command of shape (K, 4)")
        check_limit_kinds(limits)
        plain = self.generate(command, physics=physics)
        plan = self.fit_robot(command, plain, robot, limits)
        warn_if_not_executable(plan, plain, tuple(limits))
        return plan

    def fit_robot(self, command: object, plan: SlidingPlan, robot: object, limits: tuple[str, ...] = ROBOT_KINDS,
                  objective: object = None, rounds: int = 24, steps: int = 10, lr: float = 0.02,
                  weight: float = 10.0, growth: float = 1.5, polish_rounds: int = 3,
                  margin: float = ROBOT_MARGIN) -> SlidingPlan:
        """Refine a plan's latent until ``robot`` can execute it: the robot's limits as latent objective terms (ch. 4).

        The plan is checked on the robot (the execution check the simulator registers: its IK along the pan command,
        the run's stop included). While a limit of ``limits`` is broken, ``steps`` Adam updates of the latent minimise
        ``objective + w · PanJointLimits`` (the rated joint speeds and accelerations, torque limits and ranges mapped
        through the arm's Jacobian and mass matrix along the checked joint path onto the pan's velocity, acceleration
        and position: :class:`PanJointLimits`), then the plan is checked again and the map rebuilt about it; ``w``
        grows ``growth``× after each round that did not keep them, and once they are kept ``polish_rounds`` more
        rounds at that weight lower the objective. A plan counts as keeping them with :data:`ACCEPT_SHARE` of each
        rated speed, torque and acceleration and :data:`ACCEPT_CLEARANCE` from each range end (a margin for the run's
        tracking). The limits a simulated run judges (:data:`RUN_KINDS`) come first, then the rest of ``limits`` on
        top. Of the plans made (the given one included), the one keeping most of ``limits`` — all of them, else the
        run's — with the lowest ``objective`` is returned; of plans keeping neither, the one breaking them least.

        Args:
            command: ``(K, 4)`` the command ``plan`` was made for.
            plan: a plan of it (one, not a batch) decoded from ``plan.latent``, at the physics it records.
            robot: the robot's name or object.
            limits: the limits to keep, of :data:`ROBOT_KINDS`.
            objective: ``f(states, accel) -> (B,)`` to keep low meanwhile (default: :func:`command_tracking`, the
                object's squared distance from the command in mm² with ``refine_plan``'s end, jerk and range terms).
            rounds: the most check-and-refine rounds per stage; ``steps``: Adam updates per round; ``lr``: their
                learning rate (latent units); ``weight``: the limit term's first weight; ``growth``: its factor per
                round; ``polish_rounds``: rounds after the limits are kept; ``margin``: the share of each rated speed
                and torque limit the term aims at.

        Returns:
            A :class:`SlidingPlan` with ``robot_check`` set (the given plan where it kept ``limits`` already, or where
            the robot's limits are unknown).
        """
        batch, single = as_trajectories(command, 4, "command")
        if not single:
            raise ValueError("fit_robot plans one command at a time: pass a command of shape (K, 4)")
        if np.ndim(plan.states) != 2 or len(plan.states) != batch.shape[1] or plan.latent is None:
            raise ValueError(f"plan must be one plan of the command's {batch.shape[1]} samples, decoded from a latent")
        check_limit_kinds(limits)
        for name, value in (("rounds", rounds), ("steps", steps), ("polish_rounds", polish_rounds)):
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {value!r}")
        check_positive("lr", lr)
        check_positive("weight", weight)
        check_positive("growth", growth)
        physics = plan.physics if plan.physics is not None else self.physics
        f = command_tracking(batch[0], pan_limit=float(self.options.pan_limit)) if objective is None else objective
        x0 = self.start_state(torch.from_numpy(batch)).double()
        k = batch.shape[1]
        first = tuple(kind for kind in RUN_KINDS if kind in limits)
        stages = [kinds for kinds in (first, tuple(limits)) if kinds]
        if len(stages) == 2 and set(stages[0]) == set(stages[1]):
            stages = stages[:1]

        def meets(check: SlidingExecutionCheck, kinds: tuple[str, ...]) -> bool:
            return bool(check.kept(kinds, ACCEPT_SHARE, ACCEPT_CLEARANCE))

        def rank(check: SlidingExecutionCheck) -> int:  # 2: every limit asked kept, 1: the first stage's, 0: neither
            return 2 if meets(check, tuple(limits)) else 1 if meets(check, stages[0]) else 0

        def judge(z: torch.Tensor) -> tuple[SlidingExecutionCheck, float]:
            with torch.no_grad():
                states, accel = self.decode_torch(z, x0, k, physics)
                value = float(f(states.double(), accel.double())[0])
            return check_execution(self.task, states[0].double().numpy(), robot, dt=DT), value

        z = torch.as_tensor(np.asarray(plan.latent, dtype=np.float32))[None]
        check, value = judge(z)
        if check.kept(tuple(limits)) is None or meets(check, tuple(limits)) or check.pan_map is None:
            plan.robot_check = check
            return plan
        best = (z, check, value, rank(check))
        for kinds in stages:
            if meets(check, kinds):
                continue
            w, kept_for = float(weight), 0
            z = best[0].clone().requires_grad_(True)
            opt = torch.optim.Adam([z], lr=lr)
            for _ in range(rounds):
                term = PanJointLimits(check, kinds, margin)
                for _ in range(steps):
                    s, u = self.decode_torch(z, x0, k, physics)
                    s, u = s.double(), u.double()
                    (grad,) = torch.autograd.grad((f(s, u) + w * term(s, u)).sum(), z)
                    if not torch.isfinite(grad).all():
                        break
                    z.grad = grad
                    opt.step()
                check, value = judge(z.detach())
                r = rank(check)
                if r > best[3] or (r == best[3] and (value < best[2] if r else _worst(check) < _worst(best[1]))):
                    best = (z.detach().clone(), check, value, r)
                if check.pan_map is None:
                    break
                if kept_for or meets(check, kinds):  # kept: a few more rounds at this weight for the objective
                    kept_for += 1
                    if kept_for > polish_rounds:
                        break
                else:
                    w *= growth
            check = best[1]
            if not meets(check, kinds):
                break  # the next stage adds limits to these: it would start from a plan that breaks them
        z, check = best[0], best[1]
        result = self.decode(z[0].numpy(), x0[0].numpy(), k, physics)
        trust = self.assess(batch[0], result.states, result.accel, z[0].numpy(), physics=physics)
        result.errors, result.out_of_distribution, result.ood_reasons, result.uncertainty = trust
        result.robot_check = check
        return result



def _worst(check: SlidingExecutionCheck) -> float:
    """The largest share of the limits a simulated run judges (speeds, ranges, reach)."""
    return max((check.worst_share.get(kind, 0.0) for kind in (*RUN_KINDS, "reach")), default=0.0)



TRADE_OFF = 1.5
"""A plan kept within a robot's limits whose object RMSE exceeds this many times the plain plan's (and
:data:`TRACKING_TOLERANCE`) gets a warning: keeping them cost the task."""


def warn_if_not_executable(plan: SlidingPlan, plain: SlidingPlan | None = None,
                           limits: tuple[str, ...] = ROBOT_KINDS) -> None:
    """A ``RuntimeWarning`` naming the binding limit when ``plan.robot_check`` says the robot cannot execute it, and
    one saying what keeping ``limits`` cost when the object strays far more than in ``plain`` (the plan without
    them; :data:`TRADE_OFF`)."""
    check = plan.robot_check
    problem = None if check is None else check.problem()
    if problem is not None:
        warnings.warn(problem, RuntimeWarning, stacklevel=3)
    if plain is None or plan is plain or check is None or not plan.errors or not plain.errors:
        return
    rmse, before = float(plan.errors["tracking_rmse_m"]), float(plain.errors["tracking_rmse_m"])
    if rmse > max(TRADE_OFF * before, TRACKING_TOLERANCE):
        hint = ""
        if set(limits) - set(RUN_KINDS):
            hint = f"; limits={RUN_KINDS} keeps only what a simulated run judges"
            reach = pan_acceleration_reach(check)
            mu = getattr(plan.physics, "mu", None)
            if reach is not None and mu is not None:
                hint = (f" (its rated joint accelerations let the pan accelerate at {reach[0]:.1f}–{reach[1]:.1f} m/s² "
                        f"by direction at its start; the object slips at μg = {mu * contact.GRAVITY:.1f} m/s²)"
                        + hint)
        warnings.warn(f"within {'/'.join(limits)} limits of {check.robot} the object stays {rmse * 1e3:.1f} mm RMS "
                      f"from its command (the plan without them: {before * 1e3:.1f} mm){hint}", RuntimeWarning,
                      stacklevel=3)


SlidingTask.model_class = SlidingPlanner
