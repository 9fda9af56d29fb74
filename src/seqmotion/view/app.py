"""The viser layer: the page's controls, plots and 3-D scene, wired to the sessions (:mod:`.sessions`).

Everything here only moves data between the page and a session: a control's callback posts a job to
the panel's :class:`~.worker.Worker` (one thread; a newer job replaces a pending one, so a dragged slider never
queues stale work), the job asks the session for a frame and pushes its arrays to the page. Timings of
every redraw are kept in :attr:`ViewerApp.timings` (the benchmark reads them).

This module is the app: its server, its scenes and its plumbing. The panels are in :mod:`.panels`, the 3-D
scene's pieces (the arm, polylines) in :mod:`.arm_view`, the worker thread in :mod:`.worker`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from . import guard
from .arm_view import ArmView
from .panels import LatentPanel, PancakePanel, SlidingPanel, TaskPanel
from .sessions import PancakeSession, SlidingSession, TaskSession
from .worker import Worker


def check_robot(robot: str | None, simulate: bool = True) -> str | None:
    """The viewer's ``robot`` argument checked: ``None`` for the built-in arm (``None`` or ``"mh3f"``), else the
    name, once :func:`seqmotion.sim.robot_models.resolve_robot` has found the robot here. ``ValueError`` (its message
    names what is available) for an unknown or unavailable robot, or a robot without the 3-D arm."""
    from ..sim.robot_models import BUILT_IN, resolve_robot

    if robot is None or robot == BUILT_IN:
        return None
    if not isinstance(robot, str):
        raise ValueError(f"robot must be a robot's name (see seqmotion.sim.robots()), got {robot!r}")
    if not simulate:
        raise ValueError(f"robot {robot!r} needs the MuJoCo arm: this viewer runs with --no-sim")
    resolve_robot(robot)
    return robot


class ViewerApp:
    """The ``seqmotion view`` web app.

    Args:
        model: the main model — a shipped name or a model/run directory (any task; ``"pushing"`` too).
        sliding_model: with the pancake model, the planner of the sliding panel (None: no sliding panel).
        host, port: where the server listens (port 0: a free one). The default 127.0.0.1 is this machine
            only; whatever the host, a WebSocket from a page of another origin is refused (:mod:`.guard`).
        out: where exports go (created on the first export); nothing is written outside it.
        latent_n: encodings behind the latent panel's PCA.
        simulate: show the 3-D arm (False: no MuJoCo, no scene).
        robot: the arm of the 3-D scene, its replays and videos: a standard arm's name (``"panda"``,
            ``"ur5e"``, ``"menagerie:<name>"``, …; :func:`seqmotion.sim.robot_models.robots`), or ``None`` /
            ``"mh3f"`` for the built-in arm. An unknown or unavailable robot is refused (``ValueError``)
            before the server starts.
    """

    def __init__(self, model: str = "pancake", *, sliding_model: str | None = "sliding", host: str = "127.0.0.1",
                 port: int = 8080, out: str | Path = "seqmotion-view", latent_n: int = 96,
                 simulate: bool = True, robot: str | None = None) -> None:
        from ..api import resolve_model

        self.out = Path(out)
        self.controls = guard.Controls()  # every control the server reads, with its declared range/options
        self.threads: list[threading.Thread] = []  # replays (joined by stop)
        self.stopping = threading.Event()
        self.timings: dict[str, list[float]] = {}
        self.marks: dict[str, float] = {}
        self.errors: list[str] = []
        self.robot = check_robot(robot, simulate)  # like the models: a bad robot starts nothing
        main = resolve_model(model)  # every model is loaded before the server starts: a bad name starts nothing
        if getattr(getattr(main, "config", None), "kind", "") == "feedback":
            raise ValueError("the viewer's pushing panel shows each webcam image's z; a 'feedback' policy (e.g. "
                             "pushing-hard) has none, it reads the object's pose every 20 ms: view 'pushing' instead")
        task = getattr(getattr(main, "task_def", None), "name", None)
        if sliding_model is not None and sliding_model.lower() == "none":
            sliding_model = None
        planner = resolve_model(sliding_model, "sliding") if task == "pancake" and sliding_model else None
        self.server = guard.start_server(host, port, self.controls, self.error, label="seqmotion view",
                                         verbose=False)
        self.panels: dict[str, Any] = {}
        self.server.on_client_disconnect(self._client_left)
        self.server.gui.configure_theme(control_width="large", show_logo=False, dark_mode=False)
        self.server.scene.set_up_direction("+z")
        self.server.initial_camera.position = (1.45, -1.35, 1.0)
        self.server.initial_camera.look_at = (0.5, 0.2, 0.15)
        self.server.scene.configure_environment_map(None)  # no HDRI download: plain lights, works offline
        self.server.scene.configure_default_lights(True, cast_shadow=False)
        self.server.scene.add_light_ambient("/light/ambient", intensity=0.6)
        self.server.scene.add_light_directional("/light/key", intensity=1.6, position=(0.8, -0.6, 2.0))
        self.server.scene.add_grid("/grid", width=2.0, height=2.0, cell_size=0.1, position=(0.35, 0.0, -0.2))
        self.simulate, self.latent_n = simulate, latent_n
        try:
            self._build(model, main, task, sliding_model, planner)
        except BaseException:
            self.stop()  # a panel that cannot be built leaves no server running
            raise

    def _build(self, model: str, main: Any, task: str | None, sliding_model: str | None, planner: Any) -> None:
        from ..tasks import TrainedModel

        self.status = self.server.gui.add_markdown("")
        tabs = self.server.gui.add_tab_group()
        latent_models: dict[str, Any] = {}
        if isinstance(main, TrainedModel):
            latent_models[model] = main
        if task == "pancake":
            self.panels["pancake"] = PancakePanel(self, tabs.add_tab("Pancake"), PancakeSession(main))
        elif task == "sliding":
            self.panels["sliding"] = SlidingPanel(self, tabs.add_tab("Sliding"), SlidingSession(main))
        elif isinstance(main, TrainedModel):
            self.panels["task"] = TaskPanel(self, tabs.add_tab(f"Task: {task}"), TaskSession(main))
        if planner is not None:
            self.panels["sliding"] = SlidingPanel(self, tabs.add_tab("Sliding"), SlidingSession(planner))
            latent_models[sliding_model] = planner
        pushing = main if not isinstance(main, TrainedModel) else None
        self.panels["latent"] = LatentPanel(self, tabs.add_tab("Latent space"), latent_models, pushing)
        self.scene_choice = None
        scenes = [name for name, p in self.panels.items() if getattr(p, "arm", None) is not None]
        if scenes:
            self.scene_choice = self.controls.declare(self.server.gui.add_dropdown(
                "3D scene", tuple(scenes), initial_value=scenes[0], order=-1))
            self.scene_choice.on_update(lambda _: self.reported(lambda: self.show_scene(
                self.controls.read(self.scene_choice))))
            self.paths_box = self.controls.declare(self.server.gui.add_checkbox(
                "paths in 3D", True, order=-0.5,
                hint="draw the paths in the 3-D view on every redraw (off: faster on a browser without a GPU)"))
            self.paths_box.on_update(lambda _: [p.request() for p in self.panels.values() if p.arm is not None])
            self.show_scene(scenes[0])

    # --- plumbing ----------------------------------------------------------------------------------

    @property
    def paths_in_3d(self) -> bool:
        box = getattr(self, "paths_box", None)
        return True if box is None else self.controls.read(box)

    @property
    def arm_label(self) -> str:
        """The 3-D scene's arm for people: ``"the arm"`` (built-in) or ``"panda"``."""
        return "the arm" if self.robot is None else self.robot

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    def show_scene(self, name: str) -> None:
        if getattr(self, "scene_choice", None) is None:  # still building
            return
        for key, panel in self.panels.items():
            root = getattr(panel, "root", None)
            if root is not None:
                root.visible = key == name
        if self.scene_choice.value != name:
            self.scene_choice.value = name

    def error(self, message: str) -> None:
        self.errors.append(message)
        self.status.content = f"⚠ {message}"

    def reported(self, action: Callable[[], None]) -> None:
        """Run a control's callback that works outside a panel's worker; a refused value is shown on the page."""
        try:
            action()
        except ValueError as exc:
            self.error(f"ValueError: {exc}")

    def need_simulation(self, what: str) -> None:
        """ValueError unless the 3-D arm is on (a disabled button's click can still be sent by a page)."""
        if not self.simulate:
            raise ValueError(f"{what} needs the MuJoCo arm: this viewer runs with --no-sim")

    def _client_left(self, client: Any) -> None:
        """A page closed or lost its connection: its pending and running work stops (an LM adjustment of
        many updates must not run on for nobody)."""
        for panel in self.panels.values():
            panel.worker.cancel(client.client_id)

    def record(self, what: str, seconds: float) -> None:
        self.timings.setdefault(what, []).append(seconds)

    def mark(self, what: str) -> None:
        """Note when ``what`` last happened (``time.perf_counter``): a control's event reached the server
        (``<panel>.event``), its redraw was pushed (``<panel>.pushed``)."""
        self.marks[what] = time.perf_counter()

    def wait_idle(self, timeout: float = 60.0) -> bool:
        return all(p.worker.idle(timeout) for p in self.panels.values())

    def export_file(self, name: str, write: Callable[[Path], Path]) -> Path:
        """Write an export into :attr:`out` and offer it to every browser as a download; ValueError for a
        ``name`` that would land anywhere but directly in :attr:`out` (:func:`.guard.inside`)."""
        self.out.mkdir(parents=True, exist_ok=True)
        path = write(guard.inside(self.out, name))
        for client in self.server.get_clients().values():
            client.send_file_download(path.name, path.read_bytes())
        return path

    def stop(self) -> None:
        """Stop the panels' work, the replays and the server, and join their threads: none may still run
        (in torch, MuJoCo) when the interpreter exits."""
        self.stopping.set()
        try:
            for panel in self.panels.values():
                panel.worker.close()
            for thread in self.threads:
                thread.join(timeout=10.0)
        finally:
            self.server.stop()


# --- panels --------------------------------------------------------------------------------------------


def serve(model: str = "pancake", **kwargs: Any) -> ViewerApp:
    """Start the viewer (returns at once; the server runs in background threads)."""
    return ViewerApp(model, **kwargs)


__all__ = ["ArmView", "LatentPanel", "PancakePanel", "SlidingPanel", "TaskPanel", "ViewerApp", "Worker", "check_robot",
           "serve"]
