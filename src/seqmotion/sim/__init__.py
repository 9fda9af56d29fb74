"""MuJoCo scenes, controllers and runners that execute generated motions on simulated robots.

Entry points (MuJoCo is imported on first use, so ``import seqmotion.sim`` stays cheap):

* :func:`run_pancake` — execute planar spatula states on the MH3F-like arm (chs. 2, 4).
* :func:`run_sliding` — shake the frying pan along planned pan states (ch. 3).
* :data:`GAINS` — the experiments' PD/DOB gain presets ``"ch2"``, ``"ch3"``, ``"ch4"``.
* Gymnasium environments ``seqmotion/PancakeArm-v0`` and ``seqmotion/SlidingArm-v0``: registered
  by ``import seqmotion.sim.envs`` (or ``gymnasium.make("seqmotion.sim.envs:seqmotion/PancakeArm-v0")``).
"""

from __future__ import annotations

from typing import Any

_LAZY = {
    "run_pancake": ("runner", "run_pancake"),
    "run_sliding": ("runner", "run_sliding"),
    "PancakeResult": ("runner", "PancakeResult"),
    "SlidingResult": ("runner", "SlidingResult"),
    "workspace_problem": ("runner", "workspace_problem"),
    "SLIP_LIMIT": ("runner", "SLIP_LIMIT"),
    "GAP_LIMIT": ("runner", "GAP_LIMIT"),
    "GAINS": ("control", "GAINS"),
    "Gains": ("control", "Gains"),
    "TaskSpaceController": ("control", "TaskSpaceController"),
    "build_scene": ("scene", "build_scene"),
    "planar_reference": ("kinematics", "planar_reference"),
    "plot_pancake_tracking": ("plots", "plot_pancake_tracking"),
    "plot_pancake_psi": ("plots", "plot_pancake_psi"),
    "plot_sliding": ("plots", "plot_sliding"),
    "motions": ("motions", None),
    "pan_reference": ("kinematics", "pan_reference"),
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        mod = importlib.import_module(f"{__name__}.{module}")
        value = mod if attr is None else getattr(mod, attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
