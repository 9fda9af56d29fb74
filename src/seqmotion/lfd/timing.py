"""The chapter-5 decoder's clock: Δt_NN, defined once.

The policy's decoder is called every :data:`COMMAND_INTERVAL` (20 ms) in closed loop
(:func:`seqmotion.lfd.rollout.run_autonomous`), is trained on demonstrations sampled at that
period (:meth:`seqmotion.lfd.data.dataset.PushingDataset.motion` with
:func:`samples_per_command` of the recording's 1 ms period) and predicts the master's state
one period ahead (:class:`seqmotion.lfd.env.teleop.ReplayMaster` replays that same target).
This module imports nothing, so the networks can use it without pulling in MuJoCo.
"""

from __future__ import annotations

COMMAND_INTERVAL = 0.02
"""Δt_NN [s]: the decoder's period (dissertation 5.2.1), stored with every policy."""


def samples_per_command(dt: float, interval: float = COMMAND_INTERVAL) -> int:
    """How many samples of period ``dt`` [s] make one decoder period ``interval`` [s] (20 at 1 ms).

    Raises:
        ValueError: ``interval`` is not a positive whole multiple of ``dt``.
    """
    every = round(interval / dt)
    if every < 1 or abs(every * dt - interval) > 1e-9:
        raise ValueError(f"command_interval must be a positive multiple of dt={dt} s, got {interval!r}")
    return every
