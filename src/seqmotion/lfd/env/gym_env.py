"""A Gymnasium environment for the chapter-5 pushing task: ``seqmotion/Pushing-v0``.

The world is the Touch-arm pushing scene (:class:`~seqmotion.lfd.env.pushing.PushingScene`) with the slave
arm under its half of the 4-channel bilateral law at 1 ms (:class:`~seqmotion.lfd.env.teleop.TouchSlave`);
an agent stands in the master's place, as a trained policy does (Fig. 5.7). One environment step is one
decision: the action, a master command, is held for ``command_interval`` (20 ms: 20 control periods).
An episode steps exactly as :func:`seqmotion.lfd.rollout.rollout` does (one sense per period, the same
bodies, the same placements), so an external policy evaluated here meets the seqmotion policies' trials.

Observation (``Dict``):

* ``"state"`` ``(9,)`` float64: the slave's measured θ [rad], θ̇ [rad/s], τ [N m] (yaw, shoulder, elbow each);
* ``"image"`` ``(64, 64, 3)`` uint8: the webcam (``camera``) at this decision.

Action ``(9,)`` float64: the master command θ [rad], θ̇ [rad/s], τ [N m] (what
:meth:`~seqmotion.lfd.policy.policy.PushingPolicy.select_action` returns, as one vector).

Reward: 1 at the episode's last step if the task succeeded (:meth:`PushingScene.success`), else 0. The
episode is truncated after ``duration`` seconds (the benchmark's: 4 s chapter, 6 s hard); it never
terminates early. ``info``: ``"success"`` (as the object lies now), ``"block_pose"`` ``(7,)``, ``"t"`` [s],
and at reset the placement (``"position"``, a :class:`~seqmotion.lfd.env.pushing.BlockPosition`).

Placements are drawn from the reset's seed: the chapter's six positions with small variation, or with
``hard=True`` the hard benchmark's (:func:`~seqmotion.lfd.env.pushing.sample_hard_placement`);
``options={"position": BlockPosition, "variation": SceneVariation}`` sets them instead.

>>> import gymnasium as gym
>>> import seqmotion
>>> env = gym.make("seqmotion/Pushing-v0", hard=True)
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ..timing import COMMAND_INTERVAL, samples_per_command
from . import pushing
from .state import ArmState
from .teleop import BilateralGains, TouchSlave

ENV_ID = "seqmotion/Pushing-v0"

ACTION_BOUNDS = np.array([np.pi] * 3 + [20.0] * 3 + [2.0] * 3)
"""Largest |θ| [rad], |θ̇| [rad/s], |τ| [N m] of a master command (beyond every demonstration's by far)."""


class PushingEnv(gym.Env):
    """The pushing task as a Gymnasium environment (see the module docstring).

    Args:
        hard: the hard benchmark (objects anywhere, turned, boxes or cylinders, distractors) instead of the
            chapter's six positions.
        camera: the webcam of the image observations (a key of :data:`~seqmotion.lfd.env.pushing.CAMERAS`).
        duration: episode length [s] (default the benchmark's).
        command_interval: seconds an action is held (a whole multiple of the 1 ms control period).
        render_mode: ``"rgb_array"`` (the webcam image) or ``None``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": round(1.0 / COMMAND_INTERVAL)}

    def __init__(self, hard: bool = False, camera: str = "default", duration: float | None = None,
                 command_interval: float = COMMAND_INTERVAL, render_mode: str | None = None) -> None:
        if camera not in pushing.CAMERAS:
            raise ValueError(f"unknown camera {camera!r}; choose one of {sorted(pushing.CAMERAS)}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.benchmark = "hard" if hard else "chapter"
        self.camera, self.render_mode = camera, render_mode
        self.gains = BilateralGains()
        self.every = samples_per_command(self.gains.dt, command_interval)
        self.duration = pushing.EPISODE_SECONDS[self.benchmark] if duration is None else float(duration)
        self.steps = round(self.duration / self.gains.dt)
        self.metadata = {**self.metadata, "render_fps": round(1.0 / (self.every * self.gains.dt))}
        self.observation_space = spaces.Dict({
            "state": spaces.Box(-np.inf, np.inf, (9,), np.float64),
            "image": spaces.Box(0, 255, (pushing.IMAGE_SIZE, pushing.IMAGE_SIZE, 3), np.uint8),
        })
        self.action_space = spaces.Box(-ACTION_BOUNDS, ACTION_BOUNDS, dtype=np.float64)
        self.scene = pushing.PushingScene(benchmark=self.benchmark)
        self._body: TouchSlave | None = None
        self._state: ArmState | None = None
        self._k = 0
        self.position: pushing.BlockPosition | None = None

    def _observation(self) -> dict[str, np.ndarray]:
        return {"state": self._state.as_vector(), "image": self.scene.render(self.camera)}

    def _info(self) -> dict[str, Any]:
        return {"success": self.scene.success(), "block_pose": self.scene.block_pose, "t": self._k * self.gains.dt}

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        options = options or {}
        if "position" in options:
            position, variation = options["position"], options.get("variation")
        elif self.benchmark == "hard":
            position, variation = pushing.sample_hard_placement(self.np_random)
        else:
            position = pushing.POSITIONS[int(self.np_random.integers(len(pushing.POSITIONS)))]
            variation = pushing.SceneVariation.sample(self.np_random)
        self.position = position
        self.scene.reset(position, variation or pushing.SceneVariation())
        self._body = TouchSlave(self.scene, self.gains)
        self._k = 0
        self._state = self._body.sense()  # the first period's state, as the rollout senses it
        return self._observation(), {**self._info(), "position": position}

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        if self._body is None or self._state is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        if self._k >= self.steps:
            raise gym.error.ResetNeeded("the episode is over: call reset()")
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (9,) or not np.all(np.isfinite(a)):
            raise ValueError(f"action must be 9 finite numbers (θ, θ̇, τ of the master), got shape {a.shape}")
        command = ArmState(a[0:3].copy(), a[3:6].copy(), a[6:9].copy())
        for j in range(min(self.every, self.steps - self._k)):
            if j > 0:  # one sense per period, at its start (the first one's was the observation's)
                self._state = self._body.sense()
            self._body.act(self._k, command, self._state, j == 0)
            self._k += 1
        truncated = self._k >= self.steps
        if not truncated:
            self._state = self._body.sense()  # the next decision's period
        success = self.scene.success()
        reward = 1.0 if truncated and success else 0.0
        return self._observation(), reward, False, truncated, self._info()

    def render(self) -> np.ndarray | None:
        return self.scene.render(self.camera) if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        self.scene.close()


def register() -> None:
    """Register :data:`ENV_ID` with Gymnasium (``hard=True`` as a keyword of ``gym.make``); safe to call again.

    ``import seqmotion`` registers it with the simulator's other ids (:mod:`seqmotion.sim.registration`, a string
    entry point: nothing is imported until ``gym.make``); this is for a registry that was cleared since."""
    from gymnasium.envs.registration import register as gym_register
    from gymnasium.envs.registration import registry

    if ENV_ID not in registry:
        gym_register(id=ENV_ID, entry_point="seqmotion.lfd.env.gym_env:PushingEnv")

