"""MuJoCo scenes, controllers and runners that execute generated motions on simulated robots.

Entry points (MuJoCo is imported on first use, so ``import seqmotion.sim`` stays cheap):

* :func:`run_pancake` — execute planar spatula states on the MH3F-like arm (chs. 2, 4).
* :func:`run_sliding` — shake the frying pan along planned pan states (ch. 3).
* :data:`GAINS` — the experiments' PD/DOB gain presets ``"ch2"``, ``"ch3"``, ``"ch4"``.
* :func:`check_executable` — whether a robot can execute a pancake motion: its joint path by the simulator's IK
  (kinematics only, fast) against the rated speeds, accelerations, ranges and reach, and the duration it needs;
  :func:`check_pancake_executable` also executes it with the pancake on (what ``deform(robot=…)`` judges by).
* :func:`attach_robot` — put a standard arm into a MuJoCo world spec at its placement (every scene's one way).
* :func:`robots` — the standard arm models available here (robosuite's bundled arms, MuJoCo Menagerie's);
  ``robot="panda"`` on the runners, the Gym envs and ``seqmotion simulate --robot`` runs a motion on one
  (:mod:`~seqmotion.sim.robot_models`), tracked by differential IK + joint-space PD + DOB.
* Gymnasium environments ``seqmotion/PancakeArm-v0`` and ``seqmotion/SlidingArm-v0``: registered
  by ``import seqmotion.sim.envs`` (or ``gymnasium.make("seqmotion.sim.envs:seqmotion/PancakeArm-v0")``).
  The chapter-5 pushing world and its environment ``seqmotion/Pushing-v0`` live with learning from
  demonstration, in :mod:`seqmotion.lfd.env`, built on this package.

Layout: :mod:`~seqmotion.sim.backend` (MuJoCo import, gravity, the one control step
:func:`~seqmotion.sim.backend.control_period` with its recording hook) and :mod:`~seqmotion.sim.render`
(one renderer) are shared by every scene; :mod:`~seqmotion.sim.arm` is the arm (scene cache, placing the
object, :class:`~seqmotion.sim.arm.Arm` and the execute loop) under :mod:`~seqmotion.sim.pancake`,
:mod:`~seqmotion.sim.sliding` and :mod:`~seqmotion.sim.envs`; :mod:`seqmotion.lfd.env` steps and renders
its pushing worlds through the same backend, arm and renderer.
"""

from __future__ import annotations

from typing import Any

_LAZY = {
    "run_pancake": ("pancake", "run_pancake"),
    "run_sliding": ("sliding", "run_sliding"),
    "PancakeResult": ("pancake", "PancakeResult"),
    "SlidingResult": ("sliding", "SlidingResult"),
    "workspace_problem": ("arm", "workspace_problem"),
    "SLIP_LIMIT": ("pancake", "SLIP_LIMIT"),
    "GAP_LIMIT": ("pancake", "GAP_LIMIT"),
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
    "PancakeArmEnv": ("envs", "PancakeArmEnv"),
    "SlidingArmEnv": ("envs", "SlidingArmEnv"),
    "run_episode": ("closed_loop", "run_episode"),
    "ClosedLoopResult": ("closed_loop", "ClosedLoopResult"),
    "PANCAKE_NOISE": ("closed_loop", "PANCAKE_NOISE"),
    "register_envs": ("registration", "register_envs"),
    "ArmLimits": ("arm_limits", "ArmLimits"),
    "robots": ("robot_models", "robots"),
    "get_robot": ("robot_models", "get_robot"),
    "JointReport": ("arm", "JointReport"),
    "LimitCrossing": ("arm", "LimitCrossing"),
    "JointLimits": ("limits", "JointLimits"),
    "check_executable": ("executable", "check_executable"),
    "check_pancake_executable": ("pancake", "check_pancake_executable"),
    "ExecutionCheck": ("executable", "ExecutionCheck"),
    "attach_robot": ("scene", "attach_robot"),
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
