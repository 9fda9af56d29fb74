"""The one closed loop of chapter 5: a controller commanding a slave body, a decision every Δt_NN (Fig. 5.7).

* :func:`rollout` — the loop itself: every 1 ms period the body senses the slave's state; every
  ``controller.command_interval`` the controller gets an :class:`~seqmotion.lfd.policy.interface.Observation`
  (with the webcam image it asked for) and returns the master command, held until the next decision; the
  body acts on it for one period. It records what every evaluation reads (:class:`AutonomousRun`).
* :func:`run_episode` — one episode in a world: reset the world, take the first webcam image, reset the
  controller, :func:`rollout`. :func:`seqmotion.lfd.evaluation.evaluate`, the demo, ``reproduce ch5`` and
  the benchmarks run their episodes through it; the Gymnasium environment
  (:mod:`seqmotion.lfd.env.gym_env`) runs the same body one decision at a time.
* :func:`run_trial` — an episode with a standard arm holding the pen (the robot twin,
  :class:`~seqmotion.lfd.env.robot.PenRobot` as the body), through the same :func:`rollout`.
* :func:`run_autonomous` — a plain ``source(t, slave_state) -> command`` callable as the controller.

A body is the slave side a controller commands (:class:`Body`): the Touch's slave under its half of the
bilateral law (:class:`~seqmotion.lfd.env.teleop.TouchSlave`) or a standard arm following the Touch's tip
(:class:`~seqmotion.lfd.env.robot.PenRobot`). Both advance by the simulator's one control step
(:func:`seqmotion.sim.backend.control_period`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from .env import pushing
from .env.pushing import BlockPosition, PushingScene, SceneVariation
from .env.state import RunRecord
from .env.teleop import ArmState, BilateralGains, TouchSlave, check_duration
from .policy.interface import CommandSource, Controller, Observation
from .timing import COMMAND_INTERVAL, samples_per_command


class Body(Protocol):
    """The slave side of a closed loop (what :func:`rollout` steps)."""

    dt: float
    """The control period [s]."""

    def sense(self) -> ArmState:
        """The slave's measured state at the start of the period."""
        ...

    def act(self, k: int, command: ArmState, state: ArmState, new_command: bool) -> None:
        """Period ``k`` toward ``command`` (``new_command``: decided at this period), one control step."""
        ...

    @property
    def block_pose(self) -> np.ndarray: ...

    @property
    def tip(self) -> np.ndarray: ...

    def render(self, camera: str) -> np.ndarray: ...

    def success(self) -> bool: ...


@dataclass
class AutonomousRun(RunRecord):
    """A run with a controller in the master's place, sampled every ``dt``.

    ``slave_theta/dtheta/tau`` ``(K, 3)``, ``command_theta/dtheta/tau`` ``(K, 3)`` (the held
    command in force at each sample: :class:`~seqmotion.lfd.env.state.RunRecord`), ``block_pose`` ``(K, 7)``,
    ``slave_tip`` ``(K, 3)``; ``decision_seconds`` ``(calls,)``: the controller's wall time at each decision [s]
    (the policy's decision time per control step).
    """

    block_pose: np.ndarray
    slave_tip: np.ndarray
    success: bool
    crossed_time: float
    decision_seconds: np.ndarray = field(default_factory=lambda: np.zeros(0))


def rollout(
    body: Body,
    controller: Controller,
    position: BlockPosition,
    steps: int,
    first_image: np.ndarray | None = None,
) -> AutonomousRun:
    """Run ``steps`` control periods of ``body`` under ``controller`` (reset both first).

    Args:
        body: the slave side, at the episode's start.
        controller: called every ``controller.command_interval`` (a whole multiple of ``body.dt``) from t = 0.
        position: the placement (its side tells when the object crosses the centre line).
        steps: control periods to run (≥ 2).
        first_image: the webcam image ``(64, 64, 3)`` taken at the episode's start, handed in the first
            observation (rendered here if the controller has a camera and none is given); later observations
            carry a fresh image only if ``controller.images_every_step``.

    Raises:
        ValueError: a command that is not three finite numbers per field, or an interval that is not a
            multiple of the body's period.
    """
    every = samples_per_command(body.dt, controller.command_interval)
    camera = controller.camera
    if first_image is None and camera is not None:
        first_image = body.render(camera)
    each = bool(controller.images_every_step)
    names = ("st", "sdt", "stau", "ct", "cdt", "ctau", "block", "stip")
    rec = {name: np.zeros((steps, 7 if name == "block" else 3)) for name in names}
    crossed_time = math.nan
    command: ArmState | None = None
    decision = np.zeros(-(-steps // every))
    for k in range(steps):
        t = k * body.dt
        state = body.sense()
        decide = k % every == 0
        if decide:
            image = first_image if k == 0 else (body.render(camera) if each else None)
            begin = time.perf_counter()
            command = controller.select_action(Observation(t, state, image))
            decision[k // every] = time.perf_counter() - begin
            for name, value in (("theta", command.theta), ("dtheta", command.dtheta), ("tau", command.tau)):
                if np.shape(value) != (pushing.N_JOINTS,) or not np.all(np.isfinite(value)):
                    raise ValueError(f"command source returned a bad {name}: {value!r} (need 3 finite numbers)")
        block = body.block_pose
        rec["st"][k], rec["sdt"][k], rec["stau"][k] = state.theta, state.dtheta, state.tau
        rec["ct"][k], rec["cdt"][k], rec["ctau"][k] = command.theta, command.dtheta, command.tau
        rec["block"][k], rec["stip"][k] = block, body.tip
        if math.isnan(crossed_time) and position.sign * block[1] < 0:
            crossed_time = t
        body.act(k, command, state, decide)
    return AutonomousRun(
        position=position, dt=body.dt, slave_theta=rec["st"], slave_dtheta=rec["sdt"], slave_tau=rec["stau"],
        command_theta=rec["ct"], command_dtheta=rec["cdt"], command_tau=rec["ctau"], block_pose=rec["block"],
        slave_tip=rec["stip"], success=body.success(), crossed_time=crossed_time, decision_seconds=decision,
    )


def reset_controller(controller: Controller, latent: Any = None) -> None:
    """``controller.reset()``, handing ``latent`` to a controller that takes one (a :class:`PushingPolicy`)."""
    if latent is None:
        controller.reset()
    else:
        controller.reset(latent=latent)  # type: ignore[call-arg]


def run_episode(
    scene: PushingScene,
    controller: Controller,
    position: BlockPosition,
    variation: SceneVariation | None = None,
    duration: float = 4.0,
    *,
    camera: str | None = None,
    latent: Any = None,
    gains: BilateralGains | None = None,
) -> tuple[AutonomousRun, np.ndarray | None, np.ndarray]:
    """One closed-loop episode in the Touch scene: reset it, take the image, reset the controller, roll out.

    Args:
        scene: the slave world (reset here).
        controller: a :class:`~seqmotion.lfd.policy.policy.PushingPolicy` or any
            :class:`~seqmotion.lfd.policy.interface.Controller`.
        position, variation: the placement and the episode's nuisance variation (none if omitted).
        duration: episode length [s].
        camera: the webcam for the images (default the controller's own).
        latent: for a :class:`PushingPolicy`: decode this z ``(latent,)`` instead of the CNN's ẑ.
        gains: the slave's bilateral control parameters (Table 5.1 if omitted).

    Returns:
        ``(AutonomousRun, first image (64, 64, 3) uint8 or None, z)``: ``z`` the decoded latent ``(latent,)``
        (a ``feedback`` policy's first object features; empty for a controller without one).
    """
    gains = gains or BilateralGains()
    steps = check_duration(duration, gains.dt)
    variation = variation or SceneVariation()
    scene.reset(position, variation)
    camera = camera or controller.camera
    image = scene.render(camera) if camera is not None else None
    reset_controller(controller, latent)
    view = _CameraOverride(controller, camera)
    run = rollout(TouchSlave(scene, gains), view, position, steps, image)
    z = getattr(controller, "episode_latent", np.zeros(0))
    return run, image, z


class _CameraOverride:
    """``controller`` seen through another webcam (``evaluate(camera=...)``): the rollout renders that one."""

    def __init__(self, controller: Controller, camera: str | None) -> None:
        self.controller, self.camera = controller, camera
        self.command_interval = controller.command_interval
        self.images_every_step = controller.images_every_step

    def reset(self) -> None:  # pragma: no cover - run_episode resets the controller itself
        self.controller.reset()

    def select_action(self, observation: Observation) -> ArmState:
        return self.controller.select_action(observation)


def run_autonomous(
    scene: PushingScene,
    source: Callable[[float, ArmState], ArmState],
    position: BlockPosition,
    duration: float = 4.0,
    variation: SceneVariation | None = None,
    command_interval: float = COMMAND_INTERVAL,
    gains: BilateralGains | None = None,
    reset: bool = True,
) -> AutonomousRun:
    """Fig. 5.7 with a plain command source: ``source(t, slave_state) -> ArmState`` every ``command_interval``.

    Args:
        scene: the slave world; reset to ``position``/``variation`` unless ``reset`` is False
            (e.g. when an image was already taken of this very placement).
        source: the command source (a replayed master, :meth:`PushingPolicy.source`'s decoder, a stub).
        position, duration, variation, gains: as in :func:`run_episode`.
        command_interval: Δt_NN [s]; a whole multiple of ``dt``.
        reset: whether to reset the scene first.
    """
    gains = gains or BilateralGains()
    steps = check_duration(duration, gains.dt)
    if reset:
        scene.reset(position, variation or SceneVariation())
    return rollout(TouchSlave(scene, gains), CommandSource(source, command_interval), position, steps)


def check_robot_policy(policy: Any) -> None:
    from .policy.policy import PushingPolicy, require_arm

    if not isinstance(policy, PushingPolicy):
        raise ValueError(
            f"policy must be a PushingPolicy (e.g. sm.load_pretrained('pushing')), got {type(policy).__name__}")
    require_arm(policy.seqae_config, "the closed loop on a standard arm (the decoder speaks the Touch's joints)")
    if policy.config.kind == "feedback":  # its eye is trained on the Touch scene's webcam and pen tip
        raise ValueError(
            "a 'feedback' policy reads the object's pose from the Touch scene's webcam every 20 ms; the standard arms "
            "run one z from the first image (kinds 'proposed' and 'end_to_end'): not supported yet"
        )


def run_trial(
    policy: Any,
    scene: Any,
    position: BlockPosition,
    variation: SceneVariation | None = None,
    camera: str | None = None,
    duration: float = 4.0,
    latent: Any = None,
    gains: Any = None,
    touch_gains: Any = None,
    mode: str = "command",
) -> tuple[Any, np.ndarray, np.ndarray]:
    """One closed-loop episode on a standard arm: reset, webcam image, ẑ = CNN(image), decode every 20 ms.

    The same :func:`rollout` as every other episode, with :class:`~seqmotion.lfd.env.robot.PenRobot` as the body.

    Args:
        policy: a :class:`~seqmotion.lfd.policy.policy.PushingPolicy` of the Touch arm (``load_pretrained("pushing")``).
        scene: the world, a :class:`~seqmotion.lfd.env.robot.RobotPushingScene` (reset here).
        position, variation: the block placement and the episode's nuisance variation.
        camera: webcam pose (default: the one the policy's CNN was trained on).
        duration: episode length [s].
        latent: decode this z ``(latent,)`` instead of the CNN's ẑ (takes the CNN out of the loop).
        gains: the robot's joint PD gains and observer cutoff (default
            :data:`~seqmotion.lfd.env.robot.GAINS_PUSHING`).
        touch_gains: the Touch servo's :class:`~seqmotion.lfd.env.teleop.BilateralGains` (Table 5.1 if omitted).
        mode: ``"command"``: the pen tip follows the decoded command's tip (forward kinematics of θ_m),
            the decoder reads the Touch angles of the pen tip and the pen force (the twin);
            ``"twin"``: a simulated Touch slave runs the bilateral law with the decoder, its block kept at the
            robot world's block pose every period, and the pen tip follows the Touch's tip.

    Returns:
        ``(RobotRun, image (64, 64, 3) uint8, z (latent,))``.
    """
    from .env.robot import GAINS_PUSHING, MODES, PenRobot, RobotRun

    check_robot_policy(policy)
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    gains_touch = BilateralGains() if touch_gains is None else touch_gains
    if not isinstance(gains_touch, BilateralGains):
        raise ValueError(f"touch_gains must be a BilateralGains, got {type(touch_gains).__name__}")
    dt = float(scene.model.opt.timestep)
    steps = check_duration(duration, dt)
    every = samples_per_command(dt, float(policy.config.command_interval))
    started = time.perf_counter()
    scene.reset(position, variation)
    camera = camera or policy.config.camera
    image = scene.render(camera)
    reset_controller(policy, latent)  # the policy checks the latent
    body = PenRobot(scene, position, variation, steps, every, GAINS_PUSHING if gains is None else gains,
                    gains_touch, mode)
    try:
        run = rollout(body, _CameraOverride(policy, camera), position, steps, image)
    finally:
        body.close()
    r = body.loop.rec
    # The robot's crossing time is read after each period's step (the block where that period left it).
    after = np.vstack([r["block"][1:], scene.block_pose[None]])
    crossed_at = np.flatnonzero(position.sign * after[:, 1] < 0)
    crossed = float(crossed_at[0] * dt) if crossed_at.size else math.nan
    ctrl = body.loop.controller
    result = RobotRun(
        position=position, dt=dt, slave_theta=run.slave_theta, slave_dtheta=run.slave_dtheta,
        slave_tau=run.slave_tau, command_theta=run.command_theta, command_dtheta=run.command_dtheta,
        command_tau=run.command_tau, tip=r["tip"], tip_target=r["target"], block_pose=r["block"],
        joint_pos=r["q"], joint_vel=r["qd"], torque=r["tau"], ik_error=r["ik"], saturated=r["sat"],
        pen_force=r["force"], success=run.success, crossed_time=crossed, twin_clamped=body.twin.clamped,
        floored=body.floored, joints=body.loop.report(steps), seconds=time.perf_counter() - started,
        ik_seconds_per_period=ctrl.ik_seconds / max(ctrl.periods, 1),
    )
    return result, image, policy.episode_latent
