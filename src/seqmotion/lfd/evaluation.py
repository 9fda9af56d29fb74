"""Closed-loop evaluation of a pushing policy (dissertation 5.3.5: 5 trials at each of 6 positions).

Every trial is a fresh episode: the block is placed at one of the six positions with a new
random placement error (±4 mm, ±3°) and lighting/colour jitter, the webcam takes one image,
the policy's CNN turns it into ẑ and the decoder drives the slave under the bilateral
controller for 4 s (:func:`seqmotion.lfd.rollout.run_episode`). Success = the block's
centre ends on the other side of the robot's centre line.

``benchmark="hard"`` draws every trial's scene from
:func:`seqmotion.lfd.env.pushing.sample_hard_placement` instead (object anywhere in a wide region,
turned, box or cylinder, distractors, camera and lighting jitter) and judges success by
:meth:`~seqmotion.lfd.env.pushing.PushingScene.success` (the object put down at its goal line, on the
table).

Any controller with ``reset()`` and ``select_action(observation)`` can be evaluated
(:class:`~seqmotion.lfd.policy.interface.Controller`): seqmotion's own policies and, through an adapter,
a peer such as LeRobot's ACT (``benchmarks/peers/act/``); every trial runs through the one rollout loop.

:func:`run_on_robot` is the same protocol with a standard arm holding the pen (:func:`seqmotion.lfd.rollout.run_trial`).

Trial seeds come from ``SeedSequence(seed, spawn_key=(EVAL_STREAM, position, trial))`` (hard:
``position`` = :data:`HARD_KEY`); the datasets use stream ids 1–5 (``seqmotion.lfd.data.dataset.SETS``),
so no evaluation episode repeats a training episode, whatever the seeds.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import check_finite_array, check_number
from ..sim.arm import IK_TOLERANCE, JointReport
from .env import pushing
from .rollout import run_episode

EVAL_STREAM = 1000
"""Seed-stream id of evaluation trials (the datasets use 1–5)."""
HARD_KEY = 100
"""Second key of a hard-benchmark trial's seed (the chapter's trials use the position index 0..5)."""


@dataclass
class TrialOutcome:
    """One evaluation episode.

    Attributes:
        position_index: block position 0..5; ``position``: its name (e.g. ``"left_8cm"``).
        trial: index of the trial at this position.
        seed_key: ``(seed, EVAL_STREAM, position_index, trial)`` — regenerates the episode.
        success: the block's centre crossed the centre line (and is across at the end).
        crossed_time: first time it crossed [s] (NaN if never).
        final_block_y: block centre's final y [m] (+ = robot's left).
        latent: the CNN's ẑ for this trial's image ``(latent,)``.
        placement: hard benchmark: the object's ``shape``, ``distance``, ``reach`` [m], ``yaw`` [rad],
            ``distractors`` and where it ended, ``past`` [m] beyond the centre line (else empty).
        decision_ms: the policy's wall time per command (median over the episode) [ms].
        run: the :class:`~seqmotion.lfd.rollout.AutonomousRun` (only with ``keep_runs``).
        image: the webcam image (only with ``keep_runs``).
    """

    position_index: int
    position: str
    trial: int
    seed_key: tuple[int, int, int, int]
    success: bool
    crossed_time: float
    final_block_y: float
    latent: np.ndarray
    placement: dict = field(default_factory=dict)
    decision_ms: float = math.nan
    run: Any = None
    image: np.ndarray | None = None

    def as_dict(self) -> dict:
        return {
            "position_index": self.position_index,
            "position": self.position,
            "trial": self.trial,
            "seed_key": list(self.seed_key),
            "success": self.success,
            "crossed_time": None if math.isnan(self.crossed_time) else self.crossed_time,
            "final_block_y": self.final_block_y,
            "latent": self.latent.tolist(),
            **({"placement": self.placement} if self.placement else {}),
            "decision_ms": None if math.isnan(self.decision_ms) else self.decision_ms,
        }


@dataclass
class Evaluation:
    """Result of :func:`evaluate`.

    Attributes:
        success_rate: successes / trials over all positions.
        successes, n_trials: counts.
        per_position: ``{position name: (successes, trials)}`` (hard: per object shape).
        outcomes: every :class:`TrialOutcome`, in order.
        camera: the webcam pose the images came from.
        seconds: wall time [s].
        policy_kind, policy_preset: the evaluated policy's ``kind`` and size preset.
    """

    success_rate: float
    successes: int
    n_trials: int
    per_position: dict[str, tuple[int, int]]
    outcomes: list[TrialOutcome] = field(default_factory=list)
    camera: str = "default"
    seed: int = 0
    seconds: float = 0.0
    policy_kind: str = ""
    policy_preset: str = ""
    benchmark: str = "chapter"

    @property
    def wilson_interval(self) -> tuple[float, float]:
        """95 % Wilson score interval of the success rate."""
        return wilson_interval(self.successes, self.n_trials)

    @property
    def decision_ms(self) -> dict[str, float]:
        """The policy's wall time per command over all trials' medians [ms]: ``p50``, ``max``."""
        times = np.array([o.decision_ms for o in self.outcomes if not math.isnan(o.decision_ms)])
        return {"p50": float(np.median(times)), "max": float(times.max())} if len(times) else {}

    def as_dict(self) -> dict:
        low, high = self.wilson_interval
        return {
            "policy_kind": self.policy_kind,
            "policy_preset": self.policy_preset,
            "benchmark": self.benchmark,
            "success_rate": self.success_rate,
            "wilson_95": [low, high],
            "decision_ms": self.decision_ms,
            "successes": self.successes,
            "n_trials": self.n_trials,
            "per_position": {k: list(v) for k, v in self.per_position.items()},
            "camera": self.camera,
            "seed": self.seed,
            "seconds": self.seconds,
            "outcomes": [o.as_dict() for o in self.outcomes],
        }


def wilson_interval(successes: int, trials: int, z: float = 1.959964) -> tuple[float, float]:
    """95 % (``z``) Wilson score interval ``(low, high)`` of a success rate ``successes / trials``."""
    if trials <= 0:
        return (0.0, 1.0)
    p = successes / trials
    centre = (p + z * z / (2 * trials)) / (1 + z * z / trials)
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / (1 + z * z / trials)
    return (max(0.0, centre - half), min(1.0, centre + half))


def trial_rng(seed: int, position_index: int, trial: int) -> np.random.Generator:
    """The random generator of one evaluation trial (block placement, lighting)."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(EVAL_STREAM, position_index, trial)))


def check_trial_plan(
    policy: Any,
    camera: str | None,
    positions: Sequence[int] | None,
    trials: Any,
    seed: Any,
    trials_name: str = "trials",
) -> tuple[str, list[Any]]:
    """Check an evaluation's camera, block positions, trial count and seed (shared by :func:`evaluate`
    and the robot arm's evaluation).

    Returns:
        The camera (the policy's own when ``camera`` is None) and the chosen block positions (all six
        when ``positions`` is None).

    Raises:
        ValueError: naming the bad argument.
    """
    camera = policy.camera if camera is None else camera
    if camera not in pushing.CAMERAS:
        raise ValueError(f"unknown camera {camera!r}; choose one of {sorted(pushing.CAMERAS)}")
    positions = list(range(len(pushing.POSITIONS))) if positions is None else list(positions)
    if not positions:
        raise ValueError("positions is empty; give block position indices 0..5")
    chosen = [pushing.block_position(i) for i in positions]  # ValueError names a bad index
    check_number(trials_name, trials, minimum=1, integer=True)
    check_number("seed", seed, minimum=0, integer=True)
    return camera, chosen


def check_latents(latents: Any) -> np.ndarray:
    """One latent z per block position, ``(6, latent)`` finite numbers, as float64; ``ValueError`` otherwise."""
    arr = check_finite_array("latents", latents)
    if arr.ndim != 2 or arr.shape[0] != len(pushing.POSITIONS):
        raise ValueError(f"latents must be a finite ({len(pushing.POSITIONS)}, latent) array, got {arr.shape}")
    return arr


def evaluate(
    policy: Any,
    camera: str | None = None,
    positions: Sequence[int] | None = None,
    trials: int = 5,
    seed: int = 0,
    duration: float | None = None,
    progress: bool = False,
    keep_runs: bool = False,
    scene: Any = None,
    latents: Any = None,
    benchmark: str = "chapter",
) -> Evaluation:
    """Run closed-loop episodes and count the successes.

    Args:
        policy: a :class:`~seqmotion.lfd.policy.policy.PushingPolicy` (e.g. ``sm.load_pretrained("pushing")``)
            or any :class:`~seqmotion.lfd.policy.interface.Controller` (a peer's adapter).
        camera: webcam pose for the images (default: the one the policy's CNN was trained on).
        positions: block position indices 0..5 (default all six, see ``seqmotion.lfd.env.pushing.POSITIONS``);
            chapter benchmark only.
        trials: trials **per position** (default 5: 30 in all, as in the dissertation); on the hard
            benchmark the number of trials in all.
        seed: evaluation seed; trial seeds never coincide with the datasets' (see module doc).
        duration: episode length [s] (default: the benchmark's, 4 s chapter, 6 s hard: see
            :data:`seqmotion.lfd.env.pushing.EPISODE_SECONDS`).
        progress: print a progress line to stderr.
        keep_runs: keep each trial's run and image in its outcome (memory: ~0.5 MB per trial).
        scene: a :class:`~seqmotion.lfd.env.pushing.PushingScene` of this benchmark to reuse (one is made
            and closed otherwise).
        latents: ``(6, latent)``: decode ``latents[position]`` instead of the CNN's ẑ — a
            diagnostic that takes the CNN out of the loop (see :func:`position_latents`); chapter only.
        benchmark: ``"chapter"`` (the six positions) or ``"hard"`` (see the module doc).

    Returns:
        An :class:`Evaluation`.

    Raises:
        ValueError: an unknown camera or benchmark, a bad position index, ``trials < 1``, a negative
            seed; a policy whose SeqAE is not the 3-joint arm's (trained on another robot's motions:
            the simulated slave is the arm), or one without a CNN (kind ``seqae``) and no ``latents``;
            positions or latents on the hard benchmark; a scene of the other benchmark.
    """
    from .policy.policy import PushingPolicy, require_arm

    if not all(callable(getattr(policy, name, None)) for name in ("select_action", "reset")) or not hasattr(
            policy, "command_interval"):
        raise ValueError(
            "policy must be a PushingPolicy (e.g. sm.load_pretrained('pushing')) or a controller with reset(), "
            f"select_action(observation), command_interval, camera and images_every_step, got {type(policy).__name__}"
        )
    if isinstance(policy, PushingPolicy):
        require_arm(policy.seqae_config, "the closed-loop evaluation in MuJoCo")
        if policy.config.kind == "seqae" and latents is None:
            raise ValueError(
                "a 'seqae' model has no CNN to turn the webcam image into z: pass latents (--oracle-latents)"
            )
    if benchmark not in pushing.BENCHMARKS:
        raise ValueError(f"unknown benchmark {benchmark!r}; choose one of {pushing.BENCHMARKS}")
    hard = benchmark == "hard"
    if hard and (positions is not None or latents is not None):
        raise ValueError("the hard benchmark draws every placement itself: positions and latents are chapter-only")
    camera, chosen = check_trial_plan(policy, camera, positions, trials, seed)
    if duration is None:
        duration = pushing.EPISODE_SECONDS[benchmark]
    check_number("duration [s]", duration, minimum=0.0, strict_minimum=True)
    if scene is not None and getattr(scene, "benchmark", "chapter") != benchmark:
        raise ValueError(f"scene is the {scene.benchmark!r} benchmark's, not the {benchmark!r} one's")

    if latents is not None:
        latents = check_latents(latents)

    # (position index for the seed, trial): the chapter interleaves positions so a partial run is balanced
    episodes = (
        [(HARD_KEY, trial) for trial in range(trials)]
        if hard
        else [(position.index, trial) for trial in range(trials) for position in chosen]
    )
    own_scene = scene is None
    scene = pushing.PushingScene(benchmark=benchmark) if own_scene else scene
    outcomes: list[TrialOutcome] = []
    start = time.perf_counter()
    try:
        for key, trial in episodes:
            rng = trial_rng(int(seed), key, trial)
            if hard:
                position, variation = pushing.sample_hard_placement(rng)
            else:
                position, variation = pushing.POSITIONS[key], pushing.SceneVariation.sample(rng)
            z_given = None if latents is None else latents[position.index]
            run, image, z = run_episode(scene, policy, position, variation, duration, camera=camera, latent=z_given)
            placement = {}
            if hard:
                placement = {
                    "shape": position.shape, "side": position.side, "distance": position.distance,
                    "reach": position.reach, "yaw": variation.block_yaw,
                    "distractors": int(np.sum(variation.distractors)),
                    "past": float(-position.sign * run.block_pose[-1, 1]),
                }
            outcomes.append(
                TrialOutcome(
                    position.index,
                    position.name,
                    trial,
                    (int(seed), EVAL_STREAM, key, trial),
                    bool(run.success),
                    float(run.crossed_time),
                    float(run.block_pose[-1, 1]),
                    np.asarray(z, dtype=np.float64),
                    placement,
                    float(np.median(run.decision_seconds) * 1000) if len(run.decision_seconds) else math.nan,
                    run if keep_runs else None,
                    image if keep_runs else None,
                )
            )
            if progress:
                ok = sum(o.success for o in outcomes)
                print(
                    f"\r[evaluate {benchmark} {camera}] {len(outcomes)}/{len(episodes)} trials, {ok} successful, "
                    f"{time.perf_counter() - start:.0f} s",
                    end="" if len(outcomes) < len(episodes) else "\n",
                    file=sys.stderr,
                    flush=True,
                )
    finally:
        if own_scene:
            scene.close()
    per_position = {}
    if hard:
        for shape in pushing.SHAPES:
            mine = [o for o in outcomes if o.placement["shape"] == shape]
            per_position[shape] = (sum(o.success for o in mine), len(mine))
    else:
        outcomes.sort(key=lambda o: (o.position_index, o.trial))
        for position in chosen:
            mine = [o for o in outcomes if o.position_index == position.index]
            per_position[position.name] = (sum(o.success for o in mine), len(mine))
    successes = sum(o.success for o in outcomes)
    return Evaluation(
        successes / len(outcomes),
        successes,
        len(outcomes),
        per_position,
        outcomes,
        camera,
        int(seed),
        time.perf_counter() - start,
        str(getattr(getattr(policy, "config", None), "kind", "")),
        str(getattr(getattr(policy, "config", None), "preset", "")),
        benchmark,
    )


def position_latents(policy: Any, dataset: Any, successful_only: bool = True, medoid: bool = False) -> np.ndarray:
    """Mean encoder z of a dataset's (successful) demonstrations at each block position, ``(6, latent)``.

    With :func:`evaluate`'s ``latents`` this scores the decoder with the best z a perfect
    image-to-z map could give (no image can tell one operator's pass from another's).

    Args:
        policy: a proposed-method :class:`~seqmotion.lfd.policy.policy.PushingPolicy` (it has an encoder).
        dataset: a :class:`~seqmotion.lfd.data.dataset.PushingDataset` or the path of one.
        successful_only: leave failed demonstrations out (as training does).
        medoid: per position the z of the demonstration nearest the mean instead of the mean
            (the CNN's default targets, see :class:`~seqmotion.lfd.train.CNNTraining`).
    """
    from .data.dataset import PushingDataset, load_dataset
    from .data.slicing import mean_latent_per_position

    data = dataset if isinstance(dataset, PushingDataset) else load_dataset(dataset)
    ok = data.episodes["success"].astype(bool) if successful_only else np.ones(len(data), bool)
    return mean_latent_per_position(
        policy.encode(data.motion()[ok]), data.episodes["position_index"][ok], medoid=medoid
    )


# ----------------------------------------------------------------------------------------------------------------
# The evaluation protocol
# ----------------------------------------------------------------------------------------------------------------
@dataclass
class RobotEvaluation(Evaluation):
    """Result of :func:`run_on_robot`: an :class:`seqmotion.lfd.evaluation.Evaluation` plus the robot's fields.

    Attributes:
        success_rate, successes, n_trials, per_position, outcomes, camera, seed, seconds: as ``Evaluation``
            (``outcomes`` are :class:`~seqmotion.lfd.evaluation.TrialOutcome`; ``run`` holds the
            :class:`RobotRun` with ``keep_runs``).
        robot: ``"name (source)"``; ``mode``: how the commands reached it (:func:`run_trial`).
        latents: ``"cnn"`` (the policy's CNN on this world's images), ``"touch"`` (on the Touch scene's images of
            the same trials) or ``"given"``.
        limits_ok: every trial kept the arm's joint ranges and torque limits (speed limits reported apart).
        velocity_limits_ok: every trial kept the published joint speed limits (``None``: unknown).
        torque_share: ``(n,)`` peak |torque| / limit per joint over all trials.
        ik_error: largest IK residual over all trials ``(m, rad)``.
        problems: the trials' first limit problems, ``{"left_8cm#2": "..."}``.
        tracking_rmse: RMS tip-to-target distance over all trials [m]; ``tracking_max`` the largest [m].
        ik_ms_per_period: wall time of the differential IK per 1 ms period [ms].
        twin_clamped: periods (all trials) whose tip was beyond the Touch's reach.
    """

    robot: str = ""
    latents: str = "cnn"
    mode: str = "command"
    limits_ok: bool = True
    velocity_limits_ok: bool | None = None
    torque_share: np.ndarray | None = None
    ik_error: tuple[float, float] = (0.0, 0.0)
    problems: dict[str, str] = field(default_factory=dict)
    tracking_rmse: float = 0.0
    tracking_max: float = 0.0
    ik_ms_per_period: float = 0.0
    twin_clamped: int = 0

    def as_dict(self) -> dict:
        return {
            "robot": self.robot, "latents": self.latents, "mode": self.mode, "success_rate": self.success_rate,
            "successes": self.successes, "n_trials": self.n_trials,
            "per_position": {k: list(v) for k, v in self.per_position.items()}, "camera": self.camera,
            "seed": self.seed, "seconds": self.seconds, "limits_ok": self.limits_ok,
            "velocity_limits_ok": self.velocity_limits_ok,
            "torque_share": None if self.torque_share is None else [round(float(x), 4) for x in self.torque_share],
            "ik_error_m": self.ik_error[0], "ik_error_rad": self.ik_error[1], "problems": self.problems,
            "tracking_rmse_m": self.tracking_rmse, "tracking_max_m": self.tracking_max,
            "ik_ms_per_period": self.ik_ms_per_period, "twin_clamped_periods": self.twin_clamped,
            "outcomes": [o.as_dict() for o in self.outcomes],
        }


def run_on_robot(
    policy: Any,
    robot: Any = "panda",
    positions: Sequence[int] | None = None,
    trials: int = 5,
    seed: int = 0,
    latents: Any = None,
    camera: str | None = None,
    duration: float = 4.0,
    progress: bool = False,
    keep_runs: bool = False,
    scene: Any = None,
    mode: str = "command",
) -> RobotEvaluation:
    """The evaluation protocol of :func:`seqmotion.lfd.evaluation.evaluate` with ``robot`` holding the pen.

    The same trials (``trials`` per position, interleaved; each trial's block placement and lighting from
    ``trial_rng(seed, position, trial)``), the same success test (the block's centre across the centre line).

    Args:
        policy: the Touch arm's :class:`~seqmotion.lfd.policy.policy.PushingPolicy`.
        robot: a standard arm's name or :class:`~seqmotion.sim.robot_models.Robot` (placed at :data:`BASE`).
        positions: block position indices 0..5 (default all six).
        trials: trials per position (default 5: 30 in all).
        seed: evaluation seed.
        latents: ``(6, latent)``: decode ``latents[position]`` instead of the CNN's ẑ
            (e.g. :func:`seqmotion.lfd.evaluation.position_latents`); or ``"touch"``: the CNN's ẑ of the image
            the Touch's own scene gives of the same trial (separates the new images from the execution).
        camera: webcam pose (default the policy's).
        duration: episode length [s].
        progress: a progress line on stderr.
        keep_runs: keep each trial's :class:`RobotRun` and image in its outcome.
        scene: a :class:`RobotPushingScene` to reuse (one is made and closed otherwise; ``robot`` is then ignored).
        mode: ``"command"`` or ``"twin"`` (see :func:`run_trial`).

    Raises:
        ValueError: as ``evaluate`` (bad policy, camera, positions, trials, seed, latents), or an unknown robot.
    """
    from .env.robot import MODES, RobotPushingScene
    from .rollout import check_robot_policy, run_trial

    check_robot_policy(policy)
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if policy.cnn is None and latents is None:
        raise ValueError("a 'seqae' model has no CNN to turn the webcam image into z: pass latents")
    camera, chosen = check_trial_plan(policy, camera, positions, trials, seed, "trials (per position)")
    touch_view = isinstance(latents, str)
    if touch_view and latents != "touch":
        raise ValueError(f"latents must be a (6, latent) array or 'touch', got {latents!r}")
    if touch_view and policy.cnn is None:
        raise ValueError("latents='touch' needs the policy's CNN (a 'seqae' model has none)")
    if latents is not None and not touch_view:
        latents = check_latents(latents)
    own = scene is None
    scene = RobotPushingScene(robot) if own else scene
    touch_scene = pushing.PushingScene() if touch_view else None
    outcomes: list[Any] = []
    reports: list[tuple[str, JointReport]] = []
    square_error, samples, worst, ik_seconds, clamped = 0.0, 0, 0.0, 0.0, 0
    start = time.perf_counter()
    total = len(chosen) * trials
    try:
        for trial in range(trials):
            for position in chosen:
                variation = pushing.SceneVariation.sample(trial_rng(int(seed), position.index, trial))
                if touch_view:  # the CNN on the image the Touch's own scene gives of this very trial
                    touch_scene.reset(position, variation)
                    z_given = policy.latent(touch_scene.render(camera))
                else:
                    z_given = None if latents is None else latents[position.index]
                run, image, z = run_trial(policy, scene, position, variation, camera, duration, z_given, mode=mode)
                outcomes.append(TrialOutcome(
                    position.index, position.name, trial, (int(seed), EVAL_STREAM, position.index, trial),
                    bool(run.success), float(run.crossed_time), float(run.block_pose[-1, 1]), z,
                    run if keep_runs else None, image if keep_runs else None))
                reports.append((f"{position.name}#{trial}", run.joints))
                errors = np.linalg.norm(run.tip - run.tip_target, axis=1)
                square_error, samples = square_error + float(np.sum(errors**2)), samples + errors.size
                worst, clamped = max(worst, float(errors.max())), clamped + run.twin_clamped
                ik_seconds += run.ik_seconds_per_period
                if progress:
                    ok = sum(o.success for o in outcomes)
                    print(f"\r[{scene.robot.name} {camera}] {len(outcomes)}/{total} trials, {ok} successful, "
                          f"{time.perf_counter() - start:.0f} s", end="" if len(outcomes) < total else "\n",
                          file=sys.stderr, flush=True)
    finally:
        if own:
            scene.close()
        if touch_scene is not None:
            touch_scene.close()
    outcomes.sort(key=lambda o: (o.position_index, o.trial))
    per_position = {}
    for position in chosen:
        mine = [o for o in outcomes if o.position_index == position.index]
        per_position[position.name] = (sum(o.success for o in mine), len(mine))
    successes = sum(o.success for o in outcomes)
    speed = [rep.velocity_limits_ok for _, rep in reports]
    return RobotEvaluation(
        success_rate=successes / len(outcomes), successes=successes, n_trials=len(outcomes),
        per_position=per_position, outcomes=outcomes, camera=camera, seed=int(seed),
        seconds=time.perf_counter() - start, robot=scene.robot.label,
        latents="cnn" if latents is None else ("touch" if touch_view else "given"), mode=mode,
        limits_ok=all(bool(rep.joint_limits_ok) and bool(rep.torque_limits_ok) and rep.ik_error[0] <= IK_TOLERANCE[0]
                      for _, rep in reports),
        velocity_limits_ok=None if any(s is None for s in speed) else all(speed),
        torque_share=np.max([rep.torque_share for _, rep in reports], axis=0),
        ik_error=(max(rep.ik_error[0] for _, rep in reports), max(rep.ik_error[1] for _, rep in reports)),
        problems={name: rep.problem for name, rep in reports if rep.problem},
        tracking_rmse=math.sqrt(square_error / samples), tracking_max=worst,
        ik_ms_per_period=1e3 * ik_seconds / len(reports), twin_clamped=clamped,
    )
