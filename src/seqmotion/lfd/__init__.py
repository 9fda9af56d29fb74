"""Learning from demonstration, chapter 5: the pushing task, bilateral teleoperation, datasets.

Phase 1 (this package so far):

* :mod:`seqmotion.sim.pushing` — the MuJoCo scene (Touch-like arm, table, block, webcam).
* :mod:`seqmotion.lfd.teleop` — 4-channel bilateral control at 1 ms, the teleoperation loop
  and the slave-only loop with a command source in the master's place (Fig. 5.7).
* :mod:`seqmotion.lfd.operator` — the scripted human operator.
* :mod:`seqmotion.lfd.dataset` — the HDF5 datasets (:func:`collect`, :func:`load_dataset`).

Names are loaded lazily so that ``import seqmotion.lfd`` does not import MuJoCo or h5py.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "collect": "dataset",
    "collect_set": "dataset",
    "load_dataset": "dataset",
    "PushingDataset": "dataset",
    "SETS": "dataset",
    "MOTION_KEYS": "dataset",
    "episode_rng": "dataset",
    "teleoperate": "teleop",
    "run_autonomous": "teleop",
    "ReplayMaster": "teleop",
    "BilateralGains": "teleop",
    "ArmState": "teleop",
    "Demonstration": "teleop",
    "AutonomousRun": "teleop",
    "MOTION_COLUMNS": "teleop",
    "ScriptedOperator": "operator",
    "OperatorParams": "operator",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> object:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
