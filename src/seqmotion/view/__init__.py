"""An interactive viewer in the browser: ``seqmotion view [MODEL]`` (viser).

Panels: **Pancake** (a sketch from end-pose sliders, the deformed motion, θ(t) and ψ(t) against the
friction-cone band, the trust signals, ``keep_end``, latent adjustment toward a dragged end pose, a 3-D
replay of the MuJoCo arm — the built-in one, or a standard robot's published model with its meshes
(``--robot panda``) — export as CSV/NPZ or MP4), **Sliding** (a command path → the planned pan
motion and the object's path under chosen friction), **Latent space** (sliders over the main PCA
directions of a model's latents, decoded live; the pushing model's images and ẑ clusters), and for
any other registered task (a plug-in with its own physics too) a panel built from its layouts: its
example inputs (``Task.example_inputs``), every state and output field over time, its constraint, the
path of its first two metre fields where it has them, and export. Only the built-in tasks have a 3-D scene.

What is drawn is computed by plain classes in :mod:`.sessions` (testable without a browser); the
viser layer (:mod:`.app`, imported only when the server starts) only moves their arrays to the page.
What a page sends is checked on the server (:mod:`.guard`): a WebSocket from a foreign origin is refused, so
are connections beyond a cap and messages too long or not viser's (before they are decoded), a control's value
is clamped to its slider or must be one of its options, and exports stay in ``out``.
"""

from __future__ import annotations

from typing import Any

from .sessions import (
    LatentSession,
    PancakeControls,
    PancakeSession,
    PushingLatentSession,
    SlidingControls,
    SlidingSession,
    TaskSession,
)

__all__ = [
    "LatentSession", "PancakeControls", "PancakeSession", "PushingLatentSession", "SlidingControls",
    "SlidingSession", "TaskSession", "serve",
]


def serve(model: str = "pancake", **kwargs: Any) -> Any:
    """Start the web app (:class:`seqmotion.view.app.ViewerApp`) and return it; the server runs in background
    threads until ``app.stop()``. Needs ``viser`` (``pip install 'seqmotion[view]'``)."""
    from .app import ViewerApp

    return ViewerApp(model, **kwargs)
