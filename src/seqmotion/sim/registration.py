"""Registers seqmotion's Gymnasium environments under the ``seqmotion/`` namespace.

``import seqmotion`` calls :func:`register_envs`, so afterwards

>>> import gymnasium as gym
>>> import seqmotion
>>> env = gym.make("seqmotion/PancakeArm-v0")

works (``gym.register_envs(seqmotion)`` keeps linters from removing the import). The ids point
at string entry points, so registering imports neither MuJoCo nor the environments: only
Gymnasium's registry (a few milliseconds); :mod:`seqmotion.sim.envs` is imported by the first
``gym.make``.

Gymnasium 0.26–0.29 also discovers the ids through the plug-in entry point that seqmotion's
``pyproject.toml`` declares (group ``gymnasium.envs``, name ``seqmotion``, the namespace, value
``seqmotion.sim.registration:register_envs``) on ``import gymnasium``; Gymnasium ≥ 1.0 no
longer loads plug-ins, so there ``import seqmotion`` is what registers them.
"""

from __future__ import annotations

from ..core.execution import execution_check_for, execution_checks, register_execution_check

ENV_IDS = {
    "seqmotion/PancakeArm-v0": "seqmotion.sim.envs:PancakeArmEnv",
    "seqmotion/SlidingArm-v0": "seqmotion.sim.envs:SlidingArmEnv",
    "seqmotion/Pushing-v0": "seqmotion.lfd.env.gym_env:PushingEnv",
}
"""Environment id → the string entry point ``gymnasium.make`` imports."""


def register_envs() -> None:
    """Register every id of :data:`ENV_IDS` that is not registered yet (safe to call again).

    Episodes end by the environments' own time limit (``time_limit`` seconds, whatever the
    ``frame_skip``), so no ``max_episode_steps`` is registered.
    """
    try:
        from gymnasium.envs.registration import register, registry
    except ImportError:  # gymnasium is a dependency; a broken install must not break `import seqmotion`
        return
    for env_id, entry_point in ENV_IDS.items():
        if env_id not in registry:
            register(id=env_id, entry_point=entry_point)


EXECUTION_CHECKS = {"pancake": ("seqmotion.sim.pancake:check_pancake_executable",
                                "seqmotion.sim.planar_chain:arm_form"),
                    "sliding": ("seqmotion.sim.executable_sliding:check_sliding_executable", None)}
"""Task → the string entry points of its robot execution check and of its robot's polish constraints
(``deform(robot=…)``; MuJoCo imported on first use)."""


def register_execution_checks() -> None:
    """Register the simulator's execution checks (:data:`EXECUTION_CHECKS`) with the task layer's hook
    (:func:`seqmotion.core.execution.register_execution_check`): tasks sit below the simulator and may not import
    it, so the simulator tells them where its check is. A check registered already (a user's own) is kept."""
    for task, (check, arm_form) in EXECUTION_CHECKS.items():
        if task not in execution_checks():
            register_execution_check(task, check, arm_form)


def check_robot_option(task: str, robot: object, option: str = "--robot") -> None:
    """Refuse, before any work, a robot a command was asked to judge ``task``'s motion on but cannot: a task with no
    execution check registered, or a robot not available here (``ValueError`` naming ``option`` and why)."""
    from .robot_models import resolve_robot

    try:
        execution_check_for(task)
        resolve_robot(robot)
    except ValueError as exc:
        raise ValueError(f"{option} {robot}: {exc}") from None


__all__ = ["ENV_IDS", "EXECUTION_CHECKS", "check_robot_option", "register_envs", "register_execution_checks"]
