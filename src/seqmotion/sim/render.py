"""Offscreen rendering: MP4 videos and snapshot strips (like Figs. 2.10, 3.9 and 4.11).

Rendering is optional and off by default; it needs an OpenGL backend. On a headless Linux
machine :func:`seqmotion.sim.scene.import_mujoco` selects ``MUJOCO_GL=egl`` (Mesa's EGL with
the llvmpipe software rasteriser works without a GPU). MP4 encoding uses imageio with the
ffmpeg binary bundled in ``imageio-ffmpeg``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .scene import import_mujoco


class FrameRecorder:
    """Renders frames of a scene from one of its cameras.

    Args:
        model: the ``mujoco.MjModel``.
        camera: camera name in the scene (``"front"``, ``"oblique"``, ``"top"``).
        width, height: frame size [px] (at most the model's offscreen buffer, 1280 × 960).
    """

    def __init__(self, model, camera: str = "front", width: int = 640, height: int = 480) -> None:
        mujoco = import_mujoco()
        self._mujoco = mujoco
        self.camera = camera
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            raise ValueError(f"the scene has no camera named {camera!r}")
        try:
            self._renderer = mujoco.Renderer(model, height=height, width=width)
        except Exception as exc:  # the GL backend's own exceptions vary
            raise RuntimeError(
                "offscreen rendering failed; on a headless Linux machine install Mesa's EGL "
                "(libegl1, libegl-mesa0, libgl1-mesa-dri, libopengl0) and set MUJOCO_GL=egl: " + str(exc)
            ) from exc
        self.frames: list[np.ndarray] = []
        self.times: list[float] = []

    def capture(self, data, time: float) -> None:
        """Render the current state and keep the frame with its time [s]."""
        self._renderer.update_scene(data, camera=self.camera)
        self.frames.append(self._renderer.render().copy())
        self.times.append(float(time))

    def close(self) -> None:
        self._renderer.close()


def write_video(frames: list[np.ndarray], path: str | Path, fps: float = 30.0) -> Path:
    """Encode ``frames`` (H, W, 3) uint8 as an H.264 MP4 at ``fps``."""
    import imageio.v2 as imageio

    path = Path(path)
    if not frames:
        raise ValueError("no frames to write")
    path.parent.mkdir(parents=True, exist_ok=True)
    with imageio.get_writer(path, fps=fps, codec="libx264", quality=7, macro_block_size=8) as writer:
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
    path.parent.mkdir(parents=True, exist_ok=True)
    if labels is None:
        import imageio.v2 as imageio

        imageio.imwrite(path, strip)
        return path
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h, w = strip.shape[:2]
    fig = plt.figure(figsize=(w / 100, h / 100 + 0.35), dpi=100)
    ax = fig.add_axes((0, 0.35 / (h / 100 + 0.35), 1, 1 - 0.35 / (h / 100 + 0.35)))
    ax.imshow(strip)
    ax.axis("off")
    width = frames[0].shape[1] + gap.shape[1]
    for i, label in enumerate(labels):
        fig.text((i * width + frames[0].shape[1] / 2) / w, 0.02, label, ha="center", va="bottom", fontsize=10)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
