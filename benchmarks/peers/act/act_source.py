"""LeRobot's ACT as a seqmotion command source (the master's stand-in of Fig. 5.7).

Runs in the LeRobot venv with seqmotion installed (``pip install --no-deps -e /work/main``, see
README.md). Loading follows ``lerobot/scripts/lerobot_eval.py::eval_main`` (``from_pretrained`` +
``make_pre_post_processors(..., pretrained_path=...)``); each call follows
``lerobot/utils/control_utils.py::predict_action``, LeRobot's path for a policy on a real robot
(``lerobot-record --policy.path``): numpy observation -> ``prepare_observation_for_inference``
(image uint8 HWC -> float32 [0, 1] CHW, batch dimension) -> preprocessor (normalise) ->
``policy.select_action`` -> postprocessor (unnormalise).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")
os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

STATE, EFFORT, WEBCAM, ACTION = "observation.state", "observation.effort", "observation.images.webcam", "action"
IMAGE_MODES = ("live", "first")
"""``live``: render the webcam at every call (what a LeRobot dataset with per-frame video trains on);
``first``: the image taken at the episode's start on every call (what seqmotion's export stores when
the dataset has one image per episode: the same image on all of an episode's frames)."""


def load_act(model_dir: str | Path, device: str = "cpu"):
    """``(policy, preprocessor, postprocessor)`` from a folder written by ``train_act.py``."""
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors

    policy = ACTPolicy.from_pretrained(str(model_dir))
    policy.config.device = device
    policy.to(device)
    policy.eval()
    preprocessor, postprocessor = make_pre_post_processors(
        policy_cfg=policy.config,
        pretrained_path=str(model_dir),
        preprocessor_overrides={"device_processor": {"device": device},
                                "rename_observations_processor": {"rename_map": {}}},
    )
    return policy, preprocessor, postprocessor


class ActSource:
    """ACT as the master's stand-in: one ACT action per decision (every 20 ms, the dataset's 50 fps).

    Two ways in: :meth:`command` ``(slave_state, image) -> ArmState`` (the image handed in, as
    seqmotion's rollout does for a :class:`~seqmotion.lfd.policy.interface.Controller`: see
    ``eval_act.ActPolicy``), or ``source(t, slave_state) -> ArmState`` (a plain command source; it then
    renders the webcam from ``scene`` itself). One instance per episode, or call :meth:`reset`. The 9
    numbers of ``action`` are the master's θ, θ̇, τ (seqmotion's export, ``yaw.pos`` ... ``elbow.effort``).

    Attributes:
        select_ms: wall time of each ``policy.select_action`` call [ms].
        call_ms: wall time of each whole call (pre + select_action + post, and the render when this
            object renders) [ms].
    """

    def __init__(self, policy, preprocessor, postprocessor, scene=None, camera: str = "default",
                 image: str = "live") -> None:
        if image not in IMAGE_MODES:
            raise ValueError(f"image must be one of {IMAGE_MODES}, got {image!r}")
        from lerobot.utils.control_utils import predict_action

        from seqmotion.lfd.env.teleop import ArmState

        self._predict, self._arm_state = predict_action, ArmState
        self.policy, self.preprocessor, self.postprocessor = policy, preprocessor, postprocessor
        self.scene, self.camera, self.image_mode = scene, camera, image
        self.device = __import__("torch").device(policy.config.device or "cpu")
        self.use_effort = EFFORT in (policy.config.input_features or {})
        self.select_ms: list[float] = []
        self.call_ms: list[float] = []
        self.reset()

    def reset(self, first_image: np.ndarray | None = None) -> None:
        """New episode: ``policy.reset()`` (clears the temporal ensemble) and the episode's first image
        (rendered from ``scene`` if not given and there is a scene; else the first call's image)."""
        self.policy.reset()
        if first_image is None and self.scene is not None:
            first_image = self.scene.render(self.camera)
        self.first_image = first_image
        self.calls = 0

    def _image(self, image: np.ndarray | None) -> np.ndarray:
        """The image this call shows ACT: ``first`` mode the episode's first; ``live`` the one handed in,
        else a fresh render."""
        if self.first_image is None:
            self.first_image = image
        if self.image_mode == "first" or self.calls == 0:
            return self.first_image
        if image is not None:
            return image
        return self.scene.render(self.camera)

    def observation(self, slave_state, image: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The robot observation as LeRobot's record loop hands it to ``predict_action`` (numpy, no batch)."""
        obs = {
            STATE: np.concatenate([slave_state.theta, slave_state.dtheta]).astype(np.float32),
            WEBCAM: np.ascontiguousarray(self._image(image), dtype=np.uint8),
        }
        if self.use_effort:  # in the policy's input features; normalised, then ignored by ACT
            obs[EFFORT] = np.asarray(slave_state.tau, dtype=np.float32)
        return obs

    def command(self, slave_state, image: np.ndarray | None = None):
        """One decision: observation -> ``predict_action`` (LeRobot's) -> ``ArmState`` (θ, θ̇, τ)."""
        start = time.perf_counter()
        obs = self.observation(slave_state, image)
        select = self.policy.select_action
        timings = self.select_ms

        def timed_select(batch):
            t0 = time.perf_counter()
            out = select(batch)
            timings.append((time.perf_counter() - t0) * 1e3)
            return out

        self.policy.select_action = timed_select  # instance attribute: times the call inside predict_action
        try:
            action = self._predict(obs, self.policy, self.device, self.preprocessor, self.postprocessor,
                                    use_amp=False, task="", robot_type="")
        finally:
            del self.policy.select_action
        a = action.squeeze(0).to("cpu").numpy().astype(np.float64)
        if a.shape != (9,):
            raise ValueError(f"ACT returned an action of shape {a.shape}, expected (9,)")
        self.calls += 1
        self.call_ms.append((time.perf_counter() - start) * 1e3)
        return self._arm_state(a[0:3].copy(), a[3:6].copy(), a[6:9].copy())

    def __call__(self, t: float, slave_state):
        return self.command(slave_state)
