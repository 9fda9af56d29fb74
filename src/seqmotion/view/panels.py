"""The viewer's panels: Pancake, Sliding, any other task's, and Latent space; each moves a session's frames to
the page (:mod:`.sessions` computes them) and runs its work on its own :class:`~.worker.Worker`."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from . import commands, figures, guard, scene3d
from .arm_view import ArmView, SceneLine, about_x
from .sessions import (
    LatentSession,
    PancakeControls,
    PancakeFrame,
    PancakeSession,
    PushingLatentSession,
    SlidingControls,
    SlidingFrame,
    SlidingSession,
    TaskFrame,
    TaskSession,
)
from .worker import Worker

END_Y, END_Z, END_THETA = (-0.3, 0.3), (-0.3, 0.3), (-3.5, 3.5)
"""The pancake sketch's end poses [m, m, rad] (its sliders; the adjustment's target stays in them too)."""


class Host(Protocol):
    """What a panel uses of the app it is built in (:class:`seqmotion.view.app.ViewerApp`)."""

    server: Any
    controls: guard.Controls
    robot: str | None
    simulate: bool
    latent_n: int
    stopping: threading.Event
    threads: list[threading.Thread]

    @property
    def paths_in_3d(self) -> bool: ...

    @property
    def arm_label(self) -> str: ...

    def error(self, message: str) -> None: ...

    def reported(self, action: Callable[[], None]) -> None: ...

    def need_simulation(self, what: str) -> None: ...

    def show_scene(self, name: str) -> None: ...

    def record(self, what: str, seconds: float) -> None: ...

    def mark(self, what: str) -> None: ...

    def export_file(self, name: str, write: Callable[[Path], Path]) -> Path: ...


def _uplot_series(labels: list[tuple[str, str]], x_label: str = "t [s]") -> tuple[dict, ...]:
    import viser.uplot as up

    out = [up.Series(label=x_label)]
    for label, colour in labels:
        s = up.Series(label=label, stroke=colour, width=2)
        if label.startswith("·"):  # band edges: thin, dashed
            s = up.Series(label=label, stroke=colour, width=1, dash=[4, 4])
        out.append(s)
    return tuple(out)


NUMERIC_X = {"x": {"time": False}}
"""uPlot reads x as seconds since 1970 unless told otherwise."""


def _band(upper: int, lower: int, fill: str) -> Any:
    import viser.uplot as up

    return up.Band(series=(upper, lower), fill=fill)


class PancakePanel:
    """Sketch → deformed motion, θ(t), ψ(t) in the cone band, trust signals, latent adjustment, replay, export."""

    def __init__(self, app: Host, tab: Any, session: PancakeSession) -> None:
        self.app, self.session, self.server = app, session, app.server
        self.worker = Worker("pancake", app.error)
        self.controls = PancakeControls()
        self.frame: PancakeFrame | None = None
        self.target = (0.1, 0.0, math.pi)
        gui, declare = self.server.gui, app.controls.declare
        with tab:
            gui.add_markdown("Move the sketch's end pose: the model deforms it so the pancake stays on the spatula "
                             "(ch. 2). Drag the gizmo at the spatula in the 3-D view (arrows: y, z; ring: θ) to "
                             "adjust the motion's latent toward that end pose (ch. 4).")
            with gui.add_folder("Sketch"):
                self.end_y = declare(gui.add_slider("end y [m]", *END_Y, 0.005, self.controls.end_y))
                self.end_z = declare(gui.add_slider("end z [m]", *END_Z, 0.005, self.controls.end_z))
                self.end_theta = declare(gui.add_slider("end θ [rad]", *END_THETA, 0.05, self.controls.end_theta))
                self.length = declare(gui.add_slider("duration K [ms]", 100, 1000, 10, self.controls.length))
                self.timing = declare(gui.add_dropdown("timing", ("s_curve", "linear"), initial_value="s_curve"))
                self.keep_end = declare(gui.add_checkbox(
                    "keep_end (exact end, IPOPT)", False,
                    hint="polish the learned motion so it ends exactly at the sketch's end, at rest, inside the cone "
                         "(~0.3-1.5 s)"))
            self.readout = gui.add_markdown("computing…")
            self.path_image = gui.add_image(np.full((330, 440, 3), 255, np.uint8), label="path (z vs y)",
                                            format="png")
            k = np.arange(2, dtype=float)
            self.theta_plot = gui.add_uplot(
                (k, k, k, k, k),
                _uplot_series([("θ sketch", "#8c8c8c"), ("θ deformed", "#1f77b4"), ("·θ+2σ", "#9ecae1"),
                               ("·θ−2σ", "#9ecae1")]),
                bands=(_band(3, 4, "rgba(31,119,180,0.15)"),), title="θ(t) [rad] ± 2σ predicted", aspect=1.6,
                scales=NUMERIC_X)
            self.psi_plot = gui.add_uplot(
                (k, k, k, k, k),
                _uplot_series([("·+atan μ", "#2ca02c"), ("·−atan μ", "#2ca02c"), ("ψ sketch", "#8c8c8c"),
                               ("ψ deformed", "#d62728")]),
                bands=(_band(1, 2, "rgba(44,160,44,0.12)"),), title="ψ(t) [rad] in the friction cone", aspect=1.6,
                scales=NUMERIC_X)
            with gui.add_folder("Latent adjustment (ch. 4)"):
                self.target_in = declare(
                    gui.add_vector3("target y, z, θ", self.target, step=0.005,
                                    hint="the end pose to reach (also set by dragging the gizmo)"),
                    *zip(END_Y, END_Z, END_THETA, strict=True))  # the end poses the sketch sliders reach
                self.updates = declare(gui.add_slider("LM updates", 1, 20, 1, 6))
                self.adjust_button = gui.add_button("Adjust latent to target")
                self.learned_button = gui.add_button("Back to the learned motion")
            _replay_and_export(self, gui, app, speed=0.25, export="Export motion", video=True)
        self.root = self.server.scene.add_frame("/pancake", show_axes=False)
        self.lines = {"sketch": SceneLine(self.server, "/pancake/sketch", (140, 140, 140), 2.0),
                      "deformed": SceneLine(self.server, "/pancake/deformed", (31, 119, 180), 4.0)}
        self.arm = ArmView(self.server, "/pancake", "pancake", app.robot) if app.simulate else None
        self.gizmo = self.server.scene.add_transform_controls(
            "/pancake/target", scale=0.2, active_axes=(False, True, True), depth_test=False,
            position=scene3d.planar_to_world(np.array([self.target[:2]]))[0], wxyz=about_x(self.target[2]))
        for control in (self.end_y, self.end_z, self.end_theta, self.length, self.timing, self.keep_end):
            control.on_update(lambda e: self.request(e.client_id))
        self.gizmo.on_update(lambda e: app.reported(lambda: self._gizmo_event(e)))
        self.target_in.on_update(lambda _: app.reported(self._target_typed))
        self.adjust_button.on_click(lambda e: self.request_adjust(e.client_id))
        self.learned_button.on_click(lambda e: self.request(e.client_id))
        self.sim_button.on_click(lambda e: self.worker.submit(self._simulate, e.client_id))
        self.play_button.on_click(lambda _: self._play())
        self.export_button.on_click(lambda e: self.worker.submit(self._export, e.client_id))
        self.video_button.on_click(lambda e: self.worker.submit(self._video, e.client_id))
        self.request()

    # controls → jobs
    def read_controls(self) -> PancakeControls:
        read = self.app.controls.read
        return PancakeControls(read(self.end_y), read(self.end_z), read(self.end_theta), read(self.length),
                               read(self.timing), read(self.keep_end))

    def request(self, client: int | None = None) -> None:
        """Redraw the learned motion (``client``: the page whose event asked, whose leaving cancels it)."""
        self.app.mark("pancake.event")
        self.app.show_scene("pancake")
        self.worker.submit(self._redraw_learned, client)

    def request_adjust(self, client: int | None = None) -> None:
        self.app.show_scene("pancake")
        self.worker.submit(self._adjust, client)

    def _redraw_learned(self) -> None:
        start = time.perf_counter()
        self.controls = self.read_controls()
        frame = self.session.update(self.controls)
        self.draw(frame)
        self.app.record("pancake.keep_end" if self.controls.keep_end else "pancake.redraw", time.perf_counter() - start)

    def _adjust(self) -> None:
        self.controls = self.read_controls()

        def show(frame: PancakeFrame) -> bool:
            self.draw(frame)
            return self.worker.stop_requested  # a newer request, or its page left: stop here

        start = time.perf_counter()
        self.session.adjust(self.controls, self.target, self.app.controls.read(self.updates), on_update=show)
        self.app.record("pancake.adjust", time.perf_counter() - start)

    def _gizmo_event(self, event: Any) -> None:
        self._gizmo_moved()
        if getattr(event, "phase", "end") == "end":  # released: adjust toward where it was left
            self.request_adjust(getattr(event, "client_id", None))

    def _gizmo_moved(self) -> None:
        p, q = np.asarray(self.gizmo.position), np.asarray(self.gizmo.wxyz)
        origin = scene3d.planar_to_world(np.zeros((1, 2)))[0]
        theta = 2 * math.atan2(q[1], q[0])
        if math.isfinite(theta):
            theta += 2 * math.pi * round((self.target[2] - theta) / (2 * math.pi))  # continuous with the last value
        # the gizmo's pose comes from the page too: checked like the typed target (NaN refused, far clamped)
        self.target = self.app.controls.check(self.target_in, (float(p[1] - origin[1]), float(p[2] - origin[2]),
                                                               float(theta)))
        self.target_in.value = tuple(round(v, 4) for v in self.target)

    def _target_typed(self) -> None:
        t = self.app.controls.read(self.target_in)
        if np.allclose(t, self.target, atol=1e-4):
            return
        self.target = t
        self.gizmo.position = scene3d.planar_to_world(np.array([t[:2]]))[0]
        self.gizmo.wxyz = about_x(t[2])

    # frame → page
    def draw(self, frame: PancakeFrame) -> None:
        self.frame = frame
        t, st, sk = frame.time, frame.states, frame.sketch
        lo, hi = frame.std_band(2)
        img = figures.path_figure(
            [figures.Line(sk[:, :2], figures.GREY, "sketch", dashed=True),
             figures.Line(st[:, :2], figures.BLUE, f"{frame.source} (±1σ)",
                          band=None if frame.std is None else np.hypot(frame.std[:, 0], frame.std[:, 1]))],
            "y", "z", markers=[((sk[-1, 0], sk[-1, 1]), figures.GREY, "sketch end")]
            + ([((frame.target[0], frame.target[1]), figures.ORANGE, "target")] if frame.target else []))
        tp = t[:-1]
        cone = np.full(len(tp), frame.cone)
        world = scene3d.planar_to_world
        with self.server.atomic():
            self.readout.content = frame.readout()
            self.path_image.image = img
            self.theta_plot.data = (t, sk[:, 2], st[:, 2], hi, lo)
            self.psi_plot.data = (tp, cone, -cone, frame.sketch_psi, frame.psi)
        self.server.flush()  # the panel first: the 3-D view redraws after it (slow in software WebGL)
        with self.server.atomic():
            self.lines["sketch"].set(world(sk), self.app.paths_in_3d)
            self.lines["deformed"].set(world(st), self.app.paths_in_3d)
        self.server.flush()
        self.app.mark("pancake.pushed")

    # replay, export
    def _simulate(self) -> None:
        self.app.need_simulation("a replay on the arm")
        if self.frame is None or self.arm is None:
            return
        self.app.show_scene("pancake")
        self.sim_readout.content = f"simulating on {self.app.arm_label}…"
        start = time.perf_counter()
        try:
            self.arm.replay = scene3d.replay("pancake", self.frame.states, robot=self.app.robot)
        except ValueError as exc:
            self.sim_readout.content = f"⚠ {exc}"
            return
        self.app.record("pancake.simulate", time.perf_counter() - start)
        self.sim_readout.content = replay_line(self.arm.replay)
        self._play()

    def _play(self) -> None:
        play(self.app, self.arm, self.speed)

    def _export(self) -> None:
        if self.frame is None:
            return
        fmt = self.app.controls.read(self.format)
        name = f"pancake-{self.frame.source.replace(' ', '-').replace('/', 'of')}.{fmt}"
        path = self.app.export_file(name, lambda p: self.session.export(self.frame, p))
        self.export_readout.content = f"wrote `{path}` ({len(self.frame.states)} samples; also sent to the browser)"

    def _video(self) -> None:
        self.app.need_simulation("a video")  # the button is disabled then, but a page can send its click anyway
        if self.frame is None:
            return
        from ..sim import run_pancake

        self.export_readout.content = "rendering the video…"
        states = self.frame.states
        try:
            path = self.app.export_file(
                "pancake.mp4", lambda p: (run_pancake(states, video=p, robot=self.app.robot), Path(p))[1])
        except ValueError as exc:  # e.g. a motion that leaves the arm's workspace
            self.export_readout.content = f"⚠ no video: {exc}"
            return
        self.export_readout.content = (f"wrote `{path}` (MuJoCo render of {self.app.arm_label}, 4× slowed; also "
                                       "sent to the browser)")


def replay_line(replay: scene3d.Replay) -> str:
    """The replay's readout: the runner's verdict, the arm that ran it, how fast it simulated."""
    return f"{replay.summary} — on {replay.robot}, simulated {replay.realtime:.1f}× real time"


def play(app: Host, arm: ArmView | None, speed: Any) -> None:
    """Play the arm's latest replay in a thread (joined by ``app.stop()``), at the ``speed`` control's value ×
    real time (read, and so checked, at every pose: the page may change it while it plays)."""
    if arm is None or arm.replay is None or arm.playing:
        return
    replay = arm.replay

    def run() -> None:
        arm.playing = True
        try:
            dt = float(replay.time[1] - replay.time[0]) if len(replay.time) > 1 else 0.01
            for i in range(len(replay.time)):
                began = time.perf_counter()
                arm.pose(replay.pos[i], replay.quat[i])
                pause = dt / app.controls.read(speed) - (time.perf_counter() - began)
                if app.stopping.wait(max(0.0, pause)):
                    return
        except ValueError as exc:  # a refused speed: say so, stop playing
            app.error(f"ValueError: {exc}")
        finally:
            arm.playing = False

    thread = threading.Thread(target=run, daemon=True, name="seqmotion-view-replay")
    app.threads = [t for t in app.threads if t.is_alive()] + [thread]
    thread.start()


class SlidingPanel:
    """Command path → planned pan motion, the object's path under (μ, μ'), tracking error; replay and export."""

    def __init__(self, app: Host, tab: Any, session: SlidingSession) -> None:
        self.app, self.session, self.server = app, session, app.server
        self.worker = Worker("sliding", app.error)
        c = session.defaults()
        self.frame: SlidingFrame | None = None
        gui, declare = self.server.gui, app.controls.declare
        with tab:
            gui.add_markdown("Choose or draw the path the object should slide along on the pan: the planner (ch. 3) "
                             "shakes the pan so that it does, under the friction you set.")
            with gui.add_folder("Command"):
                self.shape = declare(gui.add_dropdown("shape", commands.SHAPES, initial_value=c.shape))
                self.size = declare(gui.add_slider("size [mm]", 10, 100, 1, round(1000 * c.size),
                                                   hint="line length, arc/circle radius, figure-eight half width"))
                self.angle = declare(gui.add_slider("angle [deg]", -180, 180, 5, 0,
                                                    hint="line/circle: direction; arc: the angle it sweeps (0 = 90°)"))
                self.length = declare(gui.add_slider("duration K [ms]", 200, 1500, 50, c.length))
                self.points = declare(gui.add_text("points x,y [mm]", c.points,
                                                   hint="spline: the points it passes through from (0, 0), e.g. "
                                                        "'30,0; 40,20; 20,40'"))
                self.draw_mode = declare(gui.add_checkbox(
                    "click the pan to add points", False,
                    hint="each click on the pan in the 3-D view appends a point to the spline"))
                self.clear_button = gui.add_button("Clear points")
            with gui.add_folder("Friction of the 2-D physics"):
                self.mu = declare(gui.add_slider("μ (static)", 0.1, 1.0, 0.01, c.mu))
                self.mu_dyn = declare(gui.add_slider("μ' (dynamic)", 0.0, 1.0, 0.01, c.mu_dyn))
            self.readout = gui.add_markdown("computing…")
            self.path_image = gui.add_image(np.full((330, 440, 3), 255, np.uint8), label="paths on the pan (y vs x)",
                                            format="png")
            k = np.arange(2, dtype=float)
            self.error_plot = gui.add_uplot(
                (k, k, k, k), _uplot_series([("|object − command| [mm]", "#d62728"), ("·2σ x [mm]", "#9ecae1"),
                                             ("·2σ y [mm]", "#c6dbef")]),
                title="tracking error and predicted std", aspect=1.6, scales=NUMERIC_X)
            self.accel_plot = gui.add_uplot(
                (k, k, k), _uplot_series(list(zip(session.model.accel_layout.labels(), ("#ff7f0e", "#9467bd"),
                                                  strict=True))),
                title="planned pan acceleration", aspect=1.6, scales=NUMERIC_X)
            _replay_and_export(self, gui, app, speed=0.5, export="Export plan", video=False)
        self.root = self.server.scene.add_frame("/sliding", show_axes=False)
        self.lines = {"command": SceneLine(self.server, "/sliding/command", (140, 140, 140), 2.0),
                      "object": SceneLine(self.server, "/sliding/object", (31, 119, 180), 4.0),
                      "pan": SceneLine(self.server, "/sliding/pan", (255, 127, 14), 2.0)}
        self.arm = ArmView(self.server, "/sliding", "sliding", app.robot) if app.simulate else None
        for control in (self.shape, self.size, self.angle, self.length, self.points, self.mu, self.mu_dyn):
            control.on_update(lambda e: self.request(e.client_id))
        self.clear_button.on_click(lambda _: self._clear())
        self.sim_button.on_click(lambda e: self.worker.submit(self._simulate, e.client_id))
        self.play_button.on_click(lambda _: play(app, self.arm, self.speed))
        self.export_button.on_click(lambda e: self.worker.submit(self._export, e.client_id))
        self.draw_mode.on_update(lambda _: app.reported(self._toggle_drawing))
        self.request()

    def read_controls(self) -> SlidingControls:
        read = self.app.controls.read
        mu = read(self.mu)
        return SlidingControls(read(self.shape), read(self.size) / 1000, read(self.angle), read(self.length),
                               read(self.points), mu, min(read(self.mu_dyn), mu))

    def request(self, client: int | None = None) -> None:
        """Plan again (``client``: the page whose event asked, whose leaving cancels it)."""
        self.app.mark("sliding.event")
        self.app.show_scene("sliding")
        self.worker.submit(self._redraw, client)

    def _redraw(self) -> None:
        start = time.perf_counter()
        try:
            frame = self.session.update(self.read_controls())
        except ValueError as exc:  # a bad point list, friction out of range: say so, keep the last plan
            self.readout.content = f"⚠ {exc}"
            return
        self.draw(frame)
        self.app.record("sliding.redraw", time.perf_counter() - start)

    def draw(self, frame: SlidingFrame) -> None:
        self.frame = frame
        std = frame.std
        img = figures.path_figure(
            [figures.Line(frame.command[:, :2], figures.GREY, "command", dashed=True),
             figures.Line(frame.obj[:, :2], figures.BLUE, "object, planned (±1σ)",
                          band=None if std is None else np.hypot(std[:, 0], std[:, 1])),
             figures.Line(frame.pan[:, :2], figures.ORANGE, "pan centre", width=1)],
            "x", "y", markers=[((frame.command[-1, 0], frame.command[-1, 1]), figures.GREY, "command end")])
        zeros = np.zeros(len(frame.time))
        sx = zeros if std is None else 2000 * std[:, 0]
        sy = zeros if std is None else 2000 * std[:, 1]
        with self.server.atomic():
            self.readout.content = frame.readout()
            self.path_image.image = img
            self.error_plot.data = (frame.time, 1000 * frame.tracking, sx, sy)
            self.accel_plot.data = (frame.time[:-1], frame.pan_accel[:, 0], frame.pan_accel[:, 1])
        self.server.flush()  # the panel first: the 3-D view redraws after it (slow in software WebGL)
        with self.server.atomic():
            shown = self.app.paths_in_3d
            self.lines["command"].set(scene3d.pan_to_world(np.zeros_like(frame.command), frame.command), shown)
            self.lines["object"].set(scene3d.pan_to_world(frame.pan, frame.obj, lift=0.008), shown)
            self.lines["pan"].set(scene3d.pan_to_world(frame.pan, lift=0.012), shown)
        self.server.flush()
        self.app.mark("sliding.pushed")

    def _toggle_drawing(self) -> None:
        if self.app.controls.read(self.draw_mode):
            self.server.scene.on_pointer_event("click")(lambda e: self.app.reported(lambda: self._clicked(e)))
        else:
            self.server.scene.remove_pointer_callback()

    def _clicked(self, event: Any) -> None:
        from ..sim.scene import PAN_ORIGIN

        o, d = np.asarray(event.ray_origin), np.asarray(event.ray_direction)
        if abs(d[2]) < 1e-9:
            return
        s = (PAN_ORIGIN[2] - o[2]) / d[2]
        hit = o + s * d
        x, y = hit[0] - PAN_ORIGIN[0], hit[1] - PAN_ORIGIN[1]
        if not math.hypot(x, y) <= 0.1:  # off the pan, or NaN from a page's ray
            return
        text = self.app.controls.read(self.points).strip()
        if self.app.controls.read(self.shape) != "spline":
            self.shape.value, text = "spline", ""
        self.points.value = (text + "; " if text else "") + f"{1000 * x:.0f},{1000 * y:.0f}"

    def _clear(self) -> None:
        self.points.value = ""

    def _simulate(self) -> None:
        self.app.need_simulation("a replay on the arm")
        if self.frame is None or self.arm is None:
            return
        self.app.show_scene("sliding")
        self.sim_readout.content = f"simulating on {self.app.arm_label}…"
        try:
            self.arm.replay = scene3d.replay("sliding", self.frame.pan, self.frame.command, robot=self.app.robot)
        except ValueError as exc:
            self.sim_readout.content = f"⚠ {exc}"
            return
        self.sim_readout.content = replay_line(self.arm.replay)
        play(self.app, self.arm, self.speed)

    def _export(self) -> None:
        if self.frame is None:
            return
        path = self.app.export_file(f"sliding-{self.frame.controls.shape}.{self.app.controls.read(self.format)}",
                                    lambda p: self.session.export(self.frame, p))
        self.export_readout.content = f"wrote `{path}` (also sent to the browser)"


class TaskPanel:
    """Any task (a plug-in with its own physics too): its example inputs, the generated motion field by field (the
    layouts' names and units, the decoder's outputs too), the path of its first two metre fields where it has
    them, its constraint and trust signals, and export. No 3-D scene: only the built-in tasks have one."""

    def __init__(self, app: Host, tab: Any, session: TaskSession) -> None:
        self.app, self.session, self.server = app, session, app.server
        self.worker = Worker("task", app.error)
        self.root = None
        self.arm = None
        self.frame: TaskFrame | None = None
        gui, declare = self.server.gui, app.controls.declare
        fields = session.fields
        name = session.model.task_def.name
        with tab:
            gui.add_markdown(f"Task `{name}`: inputs like those it trains on (its `example_inputs`), and what the "
                             "model generates from each, field by field as the task's layouts name them.")
            self.index = declare(gui.add_slider("input #", 0, len(session.inputs) - 1, 1, 0))
            self.field = declare(gui.add_dropdown("field", fields, initial_value=fields[0]))
            self.readout = gui.add_markdown("computing…")
            self.path_image = gui.add_image(np.full((330, 440, 3), 255, np.uint8), label="path", format="png",
                                            visible=session.path is not None)
            k = np.arange(2, dtype=float)
            self.plot = gui.add_uplot((k, k, k), _uplot_series([("input", "#8c8c8c"), ("generated", "#1f77b4")]),
                                      title="the chosen field over time", aspect=1.6, scales=NUMERIC_X)
            self.violation_plot = gui.add_uplot(
                (k, k, k), _uplot_series([("violation", "#d62728"), ("·limit", "#2ca02c")]),
                title="the task's constraint violation", aspect=1.6, scales=NUMERIC_X, visible=False)
            with gui.add_folder("Export"):
                self.format = declare(gui.add_dropdown("format", ("csv", "npz"), initial_value="csv"))
                self.export_button = gui.add_button("Export motion")
                self.export_readout = gui.add_markdown("")
        for control in (self.index, self.field):
            control.on_update(lambda e: self.worker.submit(self._redraw, e.client_id))
        self.export_button.on_click(lambda e: self.worker.submit(self._export, e.client_id))
        self.worker.submit(self._redraw)

    def _redraw(self) -> None:
        start = time.perf_counter()
        frame = self.frame = self.session.update(self.app.controls.read(self.index))
        name = self.app.controls.read(self.field)
        gen, inp = frame.series(name)
        t = frame.time[: len(gen)]
        with self.server.atomic():
            self.readout.content = frame.readout() + f"\n\nplotted: **{name}** [{frame.unit(name)}]"
            self.plot.data = (t, gen if inp is None else inp, gen)
            if frame.state_path is not None and frame.path_names is not None:
                lines = [figures.Line(frame.state_path, figures.BLUE, "generated")]
                if frame.input_path is not None:
                    lines.insert(0, figures.Line(frame.input_path, figures.GREY, "input", dashed=True))
                self.path_image.image = figures.path_figure(lines, *frame.path_names)
            self.path_image.visible = frame.state_path is not None
            if frame.violation is not None:
                # no tolerance named: the second series repeats the violation (uPlot draws no NaN line)
                limit = frame.violation if frame.violation_limit is None else np.full(len(frame.violation),
                                                                                      frame.violation_limit)
                self.violation_plot.data = (frame.time[: len(frame.violation)], frame.violation, limit)
            self.violation_plot.visible = frame.violation is not None
        self.app.record("task.redraw", time.perf_counter() - start)

    def _export(self) -> None:
        if self.frame is None:
            return
        frame, fmt = self.frame, self.app.controls.read(self.format)
        name = f"{self.session.model.task_def.name}-input{frame.index}.{fmt}"
        path = self.app.export_file(name, lambda p: self.session.export(frame, p))
        self.export_readout.content = f"wrote `{path}` ({len(frame.states)} samples; also sent to the browser)"


class LatentPanel:
    """Sliders over the main PCA directions of a model's latents (encodings of its task's data), decoded live;
    for the pushing model its 64×64 webcam images, ẑ and the six position clusters."""

    def __init__(self, app: Host, tab: Any, models: dict[str, Any], pushing: Any = None) -> None:
        self.app, self.server = app, app.server
        self.worker = Worker("latent", app.error)
        self.root = None
        self.arm = None
        self.models, self.pushing_model = dict(models), pushing
        self.sessions: dict[str, Any] = {}
        names = list(models) + (["pushing"] if pushing is not None or "pushing" not in models else [])
        gui = self.server.gui
        with tab:
            gui.add_markdown("The latent z of each input a model encodes; the sliders move along the main "
                             "directions of a set of encodings (in standard deviations) and decode live.")
            self.choice = app.controls.declare(gui.add_dropdown("model", tuple(names), initial_value=names[0]))
            self.sliders = [app.controls.declare(gui.add_slider(f"PC{i + 1} [σ]", -3.0, 3.0, 0.1, 0.0))
                            for i in range(5)]
            self.reset_button = gui.add_button("Back to the mean")
            self.readout = gui.add_markdown("computing…")
            self.path_image = gui.add_image(np.full((330, 440, 3), 255, np.uint8), label="decoded path", format="png")
            self.scatter = gui.add_image(np.full((330, 440, 3), 255, np.uint8), label="encodings (PC1, PC2)",
                                         format="png")
            self.webcam = gui.add_image(np.full((192, 192, 3), 255, np.uint8), label="webcam 64×64", format="png",
                                        visible=False)
            k = np.arange(2, dtype=float)
            self.plot = gui.add_uplot((k, k, k, k), _uplot_series([("field 1", "#1f77b4"), ("field 2", "#ff7f0e"),
                                                                   ("field 3", "#2ca02c")]),
                                      title="decoded: the first three state fields", aspect=1.6, scales=NUMERIC_X)
        self.choice.on_update(lambda e: self.request(e.client_id))
        for s in self.sliders:
            s.on_update(lambda e: self.request(e.client_id))
        self.reset_button.on_click(lambda _: self._reset())
        self.worker.submit(self._redraw)

    def request(self, client: int | None = None) -> None:
        self.app.mark("latent.event")
        self.worker.submit(self._redraw, client)

    def _reset(self) -> None:
        for s in self.sliders:
            s.value = 0.0

    def session(self, name: str) -> Any:
        if name not in self.sessions:
            self.readout.content = f"encoding a data set with `{name}`…"
            if name == "pushing":
                from ..api import load_pretrained

                policy = self.pushing_model or load_pretrained("pushing")
                self.sessions[name] = PushingLatentSession(policy)
            else:
                self.sessions[name] = LatentSession(self.models[name], n=self.app.latent_n)
        return self.sessions[name]

    def _redraw(self) -> None:
        start = time.perf_counter()
        name = self.app.controls.read(self.choice)
        session = self.session(name)
        coords = tuple(self.app.controls.read(s) for s in self.sliders)
        if isinstance(session, PushingLatentSession):
            self._draw_pushing(session, coords[:3])
        else:
            self._draw_seq2seq(session, coords)
        self.server.flush()
        self.app.mark("latent.pushed")
        self.app.record("latent.redraw", time.perf_counter() - start)

    def _draw_seq2seq(self, session: LatentSession, coords: tuple[float, ...]) -> None:
        frame = session.update(coords)
        scores = session.pca.scores / session.pca.std
        point = np.array(coords[:2])
        lines = []
        if frame.path is not None:
            near = session.input_path(frame.nearest)
            if near is not None:
                lines.append(figures.Line(near, figures.GREY, f"nearest encoded input #{frame.nearest}", dashed=True))
            lines.append(figures.Line(frame.path, figures.BLUE, "decoded"))
        names = frame.state_names[:3]
        with self.server.atomic():
            for i, s in enumerate(self.sliders):
                s.visible = i < len(session.pca.std)
            self.readout.content = frame.readout(session.pca) + f" Fields 1–3: {', '.join(names)}."
            if lines and frame.path_names is not None:
                self.path_image.image = figures.path_figure(lines, *frame.path_names)
            self.path_image.visible = bool(lines)
            self.scatter.image = scatter_figure(scores[:, :2], None, point)
            self.webcam.visible = False
            self.plot.data = (frame.time, *(frame.states[:, i] if i < frame.states.shape[1] else
                                            np.zeros(len(frame.time)) for i in range(3)))
            if not self.plot.visible:
                self.plot.visible = True

    def _draw_pushing(self, session: PushingLatentSession, coords: tuple[float, ...]) -> None:
        from ..lfd.env.pushing import POSITIONS

        nearest = session.nearest_position(coords)
        scores = session.pca.scores / session.pca.std
        image = np.kron(session.image_for(nearest), np.ones((3, 3, 1), np.uint8))
        with self.server.atomic():
            for i, s in enumerate(self.sliders):
                s.visible = i < 3
            self.readout.content = (
                f"pushing model: ẑ = CNN(64×64 webcam image), {session.z.shape[1]} numbers; "
                f"{len(session.z)} images (6 block positions × scene variations). The point "
                f"({', '.join(f'{v:+.1f}σ' for v in coords)}) is nearest the cluster of **{POSITIONS[nearest].name}**."
                " Variance explained: " + ", ".join(f"PC{i + 1} {100 * e:.0f} %"
                                                     for i, e in enumerate(session.pca.explained)))
            self.webcam.image = image
            self.webcam.visible = True
            self.path_image.visible = False
            self.scatter.image = scatter_figure(scores[:, :2], session.labels, np.array(coords[:2]))
            if self.plot.visible:
                self.plot.visible = False


PALETTE = [figures.BLUE, figures.ORANGE, figures.GREEN, figures.RED, figures.PURPLE, (140, 86, 75)]


def scatter_figure(points: np.ndarray, labels: np.ndarray | None, current: np.ndarray,
                   size: tuple[int, int] = (440, 330)) -> np.ndarray:
    """Encodings in the first two principal directions (σ units), coloured by ``labels``, and the current point."""
    from PIL import Image, ImageDraw

    w, h = size
    img = Image.new("RGB", size, (255, 255, 255))
    draw = ImageDraw.Draw(img)
    lim = max(3.2, float(np.abs(points).max()) * 1.05 if len(points) else 3.2)

    def px(p: np.ndarray) -> tuple[float, float]:
        return (w / 2 + p[0] / lim * (w / 2 - 20), h / 2 - p[1] / lim * (h / 2 - 20))

    draw.line([(20, h / 2), (w - 20, h / 2)], fill=(220, 220, 220))
    draw.line([(w / 2, 20), (w / 2, h - 20)], fill=(220, 220, 220))
    draw.text((w - 60, h / 2 + 4), "PC1 [σ]", fill=(60, 60, 60))
    draw.text((w / 2 + 4, 6), "PC2 [σ]", fill=(60, 60, 60))
    for i, p in enumerate(points):
        x, y = px(p)
        rgb = figures.GREY if labels is None else PALETTE[int(labels[i]) % len(PALETTE)]
        draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=rgb)
    x, y = px(current)
    draw.ellipse([x - 7, y - 7, x + 7, y + 7], outline=figures.RED, width=3)
    if labels is not None:
        from ..lfd.env.pushing import POSITIONS

        for i, pos in enumerate(POSITIONS):
            draw.text((8, 8 + 13 * i), f"● {pos.name}", fill=PALETTE[i % len(PALETTE)])
    return np.asarray(img)


def _replay_and_export(panel: Any, gui: Any, app: Any, *, speed: float, export: str, video: bool) -> None:
    """The arm-replay and export folders a panel with an arm shares: sets ``panel.sim_button``, ``speed``,
    ``play_button``, ``sim_readout``, ``format``, ``export_button`` (labelled ``export``), ``video_button``
    (with ``video``) and ``export_readout``."""
    with gui.add_folder("Arm replay (MuJoCo)"):
        panel.sim_button = gui.add_button("Simulate on the arm", disabled=not app.simulate)
        panel.speed = app.controls.declare(gui.add_slider("speed × real time", 0.05, 1.0, 0.05, speed))
        panel.play_button = gui.add_button("Play again")
        panel.sim_readout = gui.add_markdown("")
    with gui.add_folder("Export"):
        panel.format = app.controls.declare(gui.add_dropdown("format", ("csv", "npz"), initial_value="csv"))
        panel.export_button = gui.add_button(export)
        if video:
            panel.video_button = gui.add_button("Export video (MP4)", disabled=not app.simulate)
        panel.export_readout = gui.add_markdown("")


__all__ = ["END_THETA", "END_Y", "END_Z", "Host", "LatentPanel", "PancakePanel", "SlidingPanel", "TaskPanel", "play",
           "replay_line", "scatter_figure"]
