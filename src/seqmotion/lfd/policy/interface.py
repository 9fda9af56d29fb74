"""The per-step interface between a pushing world and whatever drives it (a trained policy, a replay, a peer).

LeRobot keeps a policy to two calls, ``reset()`` at an episode's start and ``select_action(observation)``
at every decision; the pushing policies follow it:

* :class:`Observation` — what a controller sees at one decision: the time, the slave arm's measured state
  and (when the controller asks for it) the webcam image.
* :class:`Controller` — the protocol: ``reset()``, ``select_action(observation) -> ArmState`` (the master
  command), ``command_interval`` [s] between decisions, ``camera`` and ``images_every_step`` (which images
  the rollout must render).
* :class:`CommandSource` — wraps a plain ``source(t, slave_state) -> ArmState`` callable (a replayed
  demonstration, a test's stub) as a :class:`Controller`.

The one loop that drives a controller is :func:`seqmotion.lfd.rollout.rollout`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from ..env.state import ArmState
from ..timing import COMMAND_INTERVAL


@dataclass(frozen=True)
class Observation:
    """One decision step's input.

    Attributes:
        t: time since the episode's start [s] (a multiple of the controller's ``command_interval``).
        state: the slave's measured joint state (θ [rad], θ̇ [rad/s], τ [N m], ``(3,)`` each).
        image: the webcam image ``(64, 64, 3)`` uint8 at this step, or ``None`` where the controller
            asked for none (only the first step's, unless ``images_every_step``).
    """

    t: float
    state: ArmState
    image: np.ndarray | None = None


@runtime_checkable
class Controller(Protocol):
    """What :func:`seqmotion.lfd.rollout.rollout` drives (a :class:`~seqmotion.lfd.policy.policy.PushingPolicy`,
    a :class:`CommandSource`, an external policy)."""

    @property
    def command_interval(self) -> float:
        """Seconds between two decisions (a whole multiple of the world's 1 ms period)."""
        ...

    @property
    def camera(self) -> str | None:
        """The webcam to render for the observations (``None``: no image at all)."""
        ...

    @property
    def images_every_step(self) -> bool:
        """Whether every observation carries an image (else only the first of the episode)."""
        ...

    def reset(self) -> None:
        """Forget the previous episode."""
        ...

    def select_action(self, observation: Observation) -> ArmState:
        """The master command (θ, θ̇, τ) held until the next decision."""
        ...


class CommandSource:
    """A ``source(t, slave_state) -> ArmState`` callable as a :class:`Controller` (no images).

    Args:
        source: called at every decision with the time [s] and the slave's :class:`ArmState`.
        command_interval: seconds between decisions (Δt_NN, 20 ms by default).
        camera: a webcam whose first image the rollout should take (for the record), or ``None``.
    """

    def __init__(self, source: Callable[[float, ArmState], ArmState], command_interval: float = COMMAND_INTERVAL,
                 camera: str | None = None) -> None:
        self.source, self.command_interval, self.camera = source, float(command_interval), camera
        self.images_every_step = False

    def reset(self) -> None:
        """Nothing to forget: a source that keeps state is made fresh per episode by its owner."""

    def select_action(self, observation: Observation) -> ArmState:
        return self.source(observation.t, observation.state)
