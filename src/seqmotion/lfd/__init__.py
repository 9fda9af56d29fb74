"""Learning from demonstration, chapter 5: pushing a block from one webcam image.

* :mod:`seqmotion.sim.pushing` — the MuJoCo scene (Touch-like arm, table, block, webcam).
* :mod:`seqmotion.lfd.teleop` — 4-channel bilateral control at 1 ms, the teleoperation loop
  and the slave-only loop with a command source in the master's place (Fig. 5.7).
* :mod:`seqmotion.lfd.operator` — the scripted human operator.
* :mod:`seqmotion.lfd.dataset` — the HDF5 datasets (:func:`collect`, :func:`load_dataset`).
* :mod:`seqmotion.lfd.models` — the SeqAE, the CNN and the combined :class:`PushingPolicy`
  (saved and loaded like every trained model: ``save_pretrained`` / ``PushingPolicy.from_pretrained``);
  for the hard benchmark also its ``feedback`` kind (the keypoint :class:`PoseNet` reading the
  object's pose from every frame, :class:`FeedbackSource`).
* :mod:`seqmotion.lfd.train` — training (``train.train`` from a dataset directory;
  :func:`train_seqae`, :func:`train_cnn`, :func:`train_end_to_end`, :func:`train_feedback`).
* :mod:`seqmotion.lfd.evaluation` — closed-loop success rates (:func:`evaluate`).
* :mod:`seqmotion.lfd.export` — shipping a policy with its model card (:func:`export_policy`).
* :mod:`seqmotion.lfd.lerobot` — LeRobotDataset v3.0: the format and the export (:func:`to_lerobot`);
  :mod:`seqmotion.lfd.lerobot_import` — the hardened import (:func:`from_lerobot`, :func:`import_lerobot`).
* :mod:`seqmotion.lfd.task` — the ``pushing`` task's registry entry (entry point ``seqmotion.tasks``).
* :mod:`seqmotion.lfd.timing` — the decoder's period Δt_NN (:data:`COMMAND_INTERVAL`, 20 ms).

Names are loaded lazily so that ``import seqmotion.lfd`` does not import MuJoCo, h5py or torch.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "collect": "dataset",
    "collect_set": "dataset",
    "load_dataset": "dataset",
    "PushingDataset": "dataset",
    "SETS": "dataset",
    "CHAPTER_SETS": "dataset",
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
    "SeqAE": "models",
    "SeqAEConfig": "models",
    "CNNConfig": "models",
    "ImageEncoder": "models",
    "PushingPolicy": "models",
    "PolicyConfig": "models",
    "PRESETS": "models",
    "PoseNet": "models",
    "PoseNetConfig": "models",
    "FeedbackSource": "models",
    "object_features": "models",
    "motion_loss": "models",
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
    "to_lerobot": "lerobot",
    "from_lerobot": "lerobot_import",
    "import_lerobot": "lerobot_import",
    "save_dataset": "dataset",
}

_SUBMODULES = ("cli", "dataset", "evaluation", "export", "lerobot", "lerobot_import", "models", "operator", "task",
               "teleop", "timing", "train")
# No exported name equals a submodule's name: importing ``seqmotion.lfd.X`` sets the package's
# attribute X to the module, which would shadow a function of the same name.

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> object:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    if name in _SUBMODULES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
