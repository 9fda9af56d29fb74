"""Learning from demonstration, chapter 5: pushing a block from one webcam image.

Kept apart as LeRobot keeps them (each room imports only the rooms above it in this list):

* :mod:`seqmotion.lfd.env` — the worlds and the people in them: the Touch-arm pushing world
  (:mod:`~seqmotion.lfd.env.pushing`), the standard-arm world and its Touch twin (:mod:`~seqmotion.lfd.env.robot`),
  4-channel bilateral control and teleoperation (:mod:`~seqmotion.lfd.env.teleop`), the scripted operator
  (:mod:`~seqmotion.lfd.env.operator`) and the Gymnasium environment ``seqmotion/Pushing-v0``
  (:mod:`~seqmotion.lfd.env.gym_env`).
* :mod:`seqmotion.lfd.policy` — the networks and their typed configs (:mod:`~seqmotion.lfd.policy.networks`), the
  per-step interface (:mod:`~seqmotion.lfd.policy.interface`: ``Observation``, ``Controller``) and
  :class:`PushingPolicy` with ``reset()`` / ``select_action(observation)`` (:mod:`~seqmotion.lfd.policy.policy`).
* :mod:`seqmotion.lfd.data` — the HDF5 datasets (:func:`collect`, :func:`load_dataset`), LeRobotDataset v3.0
  export and import, slicing, and rendering training frames.
* :mod:`seqmotion.lfd.rollout` — the one closed loop every episode runs through (:func:`rollout`,
  :func:`run_episode`; :func:`run_trial` on a standard arm).
* :mod:`seqmotion.lfd.evaluation` — closed-loop success rates (:func:`evaluate`, :func:`run_on_robot`).
* :mod:`seqmotion.lfd.fitting`, :mod:`seqmotion.lfd.train` — the trainings (``train.train`` from a dataset
  directory; :func:`train_seqae`, :func:`train_cnn`, :func:`train_end_to_end`, :func:`train_feedback`).
* :mod:`seqmotion.lfd.export` — shipping a policy with its model card (:func:`export_policy`).
* :mod:`seqmotion.lfd.task` — the ``pushing`` task's registry entry (entry point ``seqmotion.tasks``).
* :mod:`seqmotion.lfd.timing` — the decoder's period Δt_NN (:data:`COMMAND_INTERVAL`, 20 ms).

Names are loaded lazily so that ``import seqmotion.lfd`` does not import MuJoCo, h5py or torch.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "collect": "data.dataset",
    "collect_set": "data.dataset",
    "load_dataset": "data.dataset",
    "PushingDataset": "data.dataset",
    "SETS": "data.dataset",
    "CHAPTER_SETS": "data.dataset",
    "MOTION_KEYS": "data.dataset",
    "episode_rng": "data.dataset",
    "teleoperate": "env.teleop",
    "run_autonomous": "rollout",
    "ReplayMaster": "env.teleop",
    "BilateralGains": "env.teleop",
    "ArmState": "env.teleop",
    "Demonstration": "env.teleop",
    "AutonomousRun": "rollout",
    "MOTION_COLUMNS": "env.teleop",
    "ScriptedOperator": "env.operator",
    "OperatorParams": "env.operator",
    "SeqAE": "policy.networks",
    "SeqAEConfig": "policy.networks",
    "CNNConfig": "policy.networks",
    "ImageEncoder": "policy.networks",
    "PushingPolicy": "policy.policy",
    "PolicyConfig": "policy.policy",
    "PRESETS": "policy.networks",
    "PoseNet": "policy.networks",
    "PoseNetConfig": "policy.networks",
    "FeedbackSource": "policy.policy",
    "object_features": "policy.networks",
    "motion_loss": "policy.networks",
    "COMMAND_INTERVAL": "timing",
    "train_seqae": "train",
    "train_cnn": "train",
    "train_end_to_end": "train",
    "train_feedback": "train",
    "SeqAETraining": "train",
    "CNNTraining": "train",
    "evaluate": "evaluation",
    "Evaluation": "evaluation",
    "TrialOutcome": "evaluation",
    "position_latents": "evaluation",
    "export_policy": "export",
    "to_lerobot": "data.lerobot",
    "from_lerobot": "data.lerobot_import",
    "import_lerobot": "data.lerobot_import",
    "save_dataset": "data.dataset",
    "Observation": "policy.interface",
    "Controller": "policy.interface",
    "CommandSource": "policy.interface",
    "run_episode": "rollout",
    "run_trial": "rollout",
    "run_on_robot": "evaluation",
    "RobotEvaluation": "evaluation",
    "PushingEnv": "env.gym_env",
    "RobotPushingScene": "env.robot",
    "PushingScene": "env.pushing",
    "fit": "fitting",
}

_SUBMODULES = ("cli", "data", "env", "evaluation", "export", "fitting", "policy", "rollout", "task", "timing", "train")
# No exported name equals a submodule's name: importing ``seqmotion.lfd.X`` sets the package's
# attribute X to the module, which would shadow a function of the same name.

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> object:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)  # e.g. "env.teleop"
    if name in _SUBMODULES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
