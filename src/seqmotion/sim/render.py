"""Offscreen rendering for every scene: frames, MP4 videos and snapshot strips (Figs. 2.10, 3.9, 4.11, 5.10).

:class:`Renderer` is the one wrapper of ``mujoco.Renderer`` (the arm runs' videos, the
Gymnasium envs, the pushing scene's webcam and its figure views); :class:`FrameRecorder` keeps
a run's frames; :func:`write_video` and :func:`write_strip` save them.

Rendering is optional and off by default; it needs an OpenGL backend. On a headless Linux
machine :func:`seqmotion.sim.backend.import_mujoco` selects ``MUJOCO_GL=egl`` (Mesa's EGL with
the llvmpipe software rasteriser works without a GPU). MP4 encoding uses imageio with the
ffmpeg binary bundled in ``imageio-ffmpeg``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..io import atomic_path, pyplot, save_figure
from .backend import import_mujoco


class Renderer:
    """An offscreen renderer of one model at one frame size: every scene renders through this.

    Args:
        model: the ``mujoco.MjModel``.
        width, height: frame size [px]; at most the model's offscreen buffer unless ``grow_buffer``.
        grow_buffer: enlarge the model's offscreen buffer (``vis.global_.offwidth/offheight``)
            to the frame size first. This modifies ``model``.

    Raises:
        RuntimeError: the OpenGL backend could not be started (with what to install).
        ValueError: the frame is larger than the model's offscreen buffer.
    """

    def __init__(self, model: Any, width: int = 640, height: int = 480, *, grow_buffer: bool = False) -> None:
        mujoco = import_mujoco()
        self.model = model
        if grow_buffer:
            model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
            model.vis.global_.offheight = max(model.vis.global_.offheight, height)
        try:
            self._renderer = mujoco.Renderer(model, height, width)
        except ValueError:  # the frame does not fit the buffer: MuJoCo's message says so
            raise
        except Exception as exc:  # the GL backend's own exceptions vary
            raise RuntimeError(
                "offscreen rendering failed; on a headless Linux machine install Mesa's EGL "
                "(libegl1, libegl-mesa0, libgl1-mesa-dri, libopengl0) and set MUJOCO_GL=egl: " + str(exc)
            ) from exc
        self._cameras: set[str] = set()  # named cameras already checked (once each, not per frame)

    def render(self, data: Any, camera: str | Any) -> np.ndarray:
        """The current state of ``data`` seen from ``camera`` (a camera name or a ``mujoco.MjvCamera``).

        Returns:
            ``(height, width, 3)`` uint8 RGB, a copy (the renderer reuses its buffer).
        """
        if isinstance(camera, str) and camera not in self._cameras:
            check_camera(self.model, camera)
            self._cameras.add(camera)
        self._renderer.update_scene(data, camera=camera)
        return self._renderer.render().copy()

    def close(self) -> None:
        """Release the OpenGL context."""
        self._renderer.close()


def check_camera(model: Any, camera: str) -> None:
    """Raise ``ValueError`` unless ``model`` has a camera named ``camera``."""
    mujoco = import_mujoco()
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
        raise ValueError(f"the scene has no camera named {camera!r}")


def free_camera(lookat: tuple[float, float, float], distance: float, azimuth: float, elevation: float) -> Any:
    """A ``mujoco.MjvCamera`` looking at ``lookat`` [m] from ``distance`` [m], ``azimuth`` and ``elevation`` [deg]."""
    mujoco = import_mujoco()
    camera = mujoco.MjvCamera()
    camera.lookat[:] = lookat
    camera.distance, camera.azimuth, camera.elevation = distance, azimuth, elevation
    return camera


class FrameRecorder:
    """Renders frames of a scene from one of its named cameras and keeps them with their times.

    Args:
        model: the ``mujoco.MjModel``.
        camera: camera name in the scene (``"front"``, ``"oblique"``, ``"top"``).
        width, height: frame size [px] (at most the model's offscreen buffer, 1280 × 960).
    """

    def __init__(self, model: Any, camera: str = "front", width: int = 640, height: int = 480) -> None:
        check_camera(model, camera)  # fail now, before a GL context is opened
        self.camera = camera
        self._renderer = Renderer(model, width, height)
        self.frames: list[np.ndarray] = []
        self.times: list[float] = []

    def capture(self, data: Any, time: float) -> None:
        """Render the current state and keep the frame with its time [s]."""
        self.frames.append(self._renderer.render(data, self.camera))
        self.times.append(float(time))

    def close(self) -> None:
        """Release the OpenGL context (the frames are kept)."""
        self._renderer.close()


def write_video(frames: list[np.ndarray], path: str | Path, fps: float = 30.0) -> Path:
    """Encode ``frames`` (H, W, 3) uint8 as an H.264 MP4 at ``fps``."""
    import imageio.v2 as imageio

    path = Path(path)
    if not frames:
        raise ValueError("no frames to write")
    with atomic_path(path) as tmp:  # a killed encoder leaves the old video, not a broken one
        with imageio.get_writer(tmp, fps=fps, codec="libx264", quality=7, macro_block_size=8) as writer:
            for frame in frames:
                writer.append_data(frame)
    return path


def write_strip(frames: list[np.ndarray], path: str | Path, labels: list[str] | None = None) -> Path:
    """Save frames side by side as one PNG (a snapshot strip), optionally with a label under each."""
    path = Path(path)
    if not frames:
        raise ValueError("no frames to write")
    gap = np.full((frames[0].shape[0], 6, 3), 255, dtype=np.uint8)
    strip = np.concatenate([x for f in frames for x in (f, gap)][:-1], axis=1)
    if labels is None:
        import imageio.v2 as imageio

        with atomic_path(path) as tmp:
            imageio.imwrite(tmp, strip)
        return path
    plt = pyplot()
    h, w = strip.shape[:2]
    fig = plt.figure(figsize=(w / 100, h / 100 + 0.35), dpi=100)
    ax = fig.add_axes((0, 0.35 / (h / 100 + 0.35), 1, 1 - 0.35 / (h / 100 + 0.35)))
    ax.imshow(strip)
    ax.axis("off")
    width = frames[0].shape[1] + gap.shape[1]
    for i, label in enumerate(labels):
        fig.text((i * width + frames[0].shape[1] / 2) / w, 0.02, label, ha="center", va="bottom", fontsize=10)
    return save_figure(fig, path, close=True, dpi=100)
