"""``seqmotion view`` against a hostile client: a scripted WebSocket client (``websockets`` + viser's message
format, no browser) sends what a page of another site, or a program, could send.

One server for the module (the pancake and sliding models, ``--no-sim``, port 0); each test talks to it
through its own connection. Nothing may be written outside the server's ``out`` folder: the folder is
three levels down in the module's temporary folder, which every test checks is otherwise empty.
"""

from __future__ import annotations

import http.client
import importlib.util
import math
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

if importlib.util.find_spec("viser") is None:
    pytest.skip("viser is not installed (pip install -e '.[dev]')", allow_module_level=True)

import msgspec
import viser
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import ClientConnection, connect

from seqmotion.view import guard


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    from seqmotion.view.app import ViewerApp

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("hostile")
    app = ViewerApp("pancake", port=0, out=root / "a" / "b" / "exports", latent_n=16, simulate=False)
    app.root = root
    try:
        assert app.wait_idle(120)
        yield app
    finally:
        app.stop()
        torch.set_num_threads(threads)


def client(app, origin: str | None = None, camera: bool = True) -> ClientConnection:
    """A scripted client of ``app`` (what viser's page would open), sending ``Origin: origin`` if given; with
    ``camera``, it reports its camera as a page does first (viser runs a client's callbacks only after that)."""
    ws = connect(app.url.replace("http://", "ws://"), origin=origin, proxy=None, open_timeout=10,
                 subprotocols=[f"viser-v{viser.__version__}"], max_size=None, max_queue=None, compression=None)
    if camera:
        before = set(app.server.get_clients())
        ws.send(msgspec.msgpack.encode({
            "type": "ViewerCameraMessage", "wxyz": (1.0, 0.0, 0.0, 0.0), "position": (1.0, 1.0, 1.0), "fov": 1.0,
            "near": 0.01, "far": 100.0, "image_height": 480, "image_width": 640, "look_at": (0.0, 0.0, 0.0),
            "up_direction": (0.0, 0.0, 1.0)}))
        wait_for(lambda: set(app.server.get_clients()) - before, what="the client's registration")
    return ws


def send(ws: ClientConnection, handle: Any, value: Any, prop: str = "value") -> None:
    """Send what viser's page sends when a control changes (a button: value True)."""
    ws.send(msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": handle._impl.uuid,
                                    "updates": {prop: value}}))


def wait_for(condition, timeout: float = 30.0, what: str = "the server") -> None:
    end = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > end:
            raise AssertionError(f"{what} did not get there within {timeout} s")
        time.sleep(0.01)


def settle(app, mark: str | None = None, since: float = 0.0) -> None:
    """Wait until ``mark`` was set after ``since`` (the event reached the panel), then until every worker idles."""
    if mark is not None:
        wait_for(lambda: app.marks.get(mark, 0.0) > since, what=f"{mark}")
    assert app.wait_idle(120)


def files_outside_out(app) -> list[Path]:
    out = Path(app.out).resolve()
    return [p for p in Path(app.root).rglob("*") if p.is_file() and out not in p.resolve().parents]


@pytest.fixture(autouse=True)
def _nothing_outside_out(app):
    yield
    assert files_outside_out(app) == []


# --- the handshake --------------------------------------------------------------------------------


def test_the_viewer_binds_to_this_machine_only_by_default(app):
    from seqmotion.cli import build_parser

    assert app.server.get_host() == "127.0.0.1"
    assert build_parser().parse_args(["view"]).host == "127.0.0.1"


def test_a_page_of_another_origin_is_refused_at_the_handshake(app):
    port = app.server.get_port()
    for origin in ("http://evil.example", f"http://evil.example:{port}", f"http://127.0.0.1:{port + 1}",
                   f"https://127.0.0.1:{port}", "null"):
        with pytest.raises(InvalidStatus) as refused:
            client(app, origin, camera=False).close()
        assert refused.value.response.status_code == 403, origin
    for origin in (f"http://127.0.0.1:{port}", f"http://localhost:{port}", f"http://LOCALHOST:{port}", None):
        client(app, origin).close()  # the page's own origins, and a program (no Origin) are let in


def test_the_allowed_origins_follow_the_host_and_the_address_served():
    assert guard.allowed_origins("127.0.0.1", ("127.0.0.1", 8080)) == {
        "http://127.0.0.1:8080", "http://localhost:8080", "http://[::1]:8080"}
    exposed = guard.allowed_origins("0.0.0.0", ("192.168.1.5", 8080))  # a page opened by the machine's address
    assert "http://192.168.1.5:8080" in exposed and "http://0.0.0.0:8080" not in exposed
    assert "http://viewer.lan:80" in guard.allowed_origins("viewer.lan", ("10.0.0.2", 80, 0, 0))
    assert "http://[fe80::1]:8080" in guard.allowed_origins("::", ("fe80::1", 8080, 0, 0))
    assert "http://192.168.1.5:8080" in guard.allowed_origins("::", ("::ffff:192.168.1.5", 8080, 0, 0))
    assert not guard.origin_allowed(["http://localhost:8080", "http://localhost:8080"], "127.0.0.1",
                                    ("127.0.0.1", 8080))  # one Origin only


# --- connections and messages -----------------------------------------------------------------------


@pytest.fixture
def bare_server():
    """A server of its own (no panels): a test that counts connections sees only its own."""
    server = guard.start_server("127.0.0.1", 0, verbose=False)
    try:
        yield server
    finally:
        server.stop()
        thread = server._websock_server._server_thread
        thread.join(30)
        assert not thread.is_alive()


def closed(ws: ClientConnection, timeout: float = 5.0) -> int | None:
    """The code the server closed ``ws`` with (what it sends before is read and dropped); None: still open after
    ``timeout`` seconds."""
    end = time.monotonic() + timeout
    try:
        while (left := end - time.monotonic()) > 0:
            ws.recv(timeout=left)
    except TimeoutError:
        return None
    except ConnectionClosed as exc:
        return None if exc.rcvd is None else exc.rcvd.code
    return None


def test_connections_beyond_the_cap_are_refused_before_the_upgrade(bare_server, monkeypatch):
    monkeypatch.setattr(guard, "MAX_CONNECTIONS", 3)
    port = bare_server.get_port()

    def opened() -> ClientConnection:
        return connect(f"ws://127.0.0.1:{port}", origin=f"http://127.0.0.1:{port}", proxy=None, open_timeout=10,
                       subprotocols=[f"viser-v{viser.__version__}"], compression=None)

    held = [opened() for _ in range(3)]
    try:
        with pytest.raises(InvalidStatus) as refused:
            opened().close()
        assert refused.value.response.status_code == 503
        page = http.client.HTTPConnection("127.0.0.1", port, timeout=5)  # the page itself is still served
        page.request("GET", "/")
        assert page.getresponse().status == 200
        page.close()
        held.pop().close()

        def admitted() -> bool:
            try:
                held.append(opened())
            except InvalidStatus:
                return False
            return True

        wait_for(admitted, timeout=10, what="a connection in the place of one that ended")
    finally:
        for ws in held:
            ws.close()


def test_a_message_over_the_cap_is_refused_before_it_is_decoded(app, monkeypatch):
    decoded: list[int] = []
    decode = msgspec.msgpack.decode

    def spy(raw: bytes, *args: Any, **kwargs: Any) -> Any:  # every message the server decodes, by its size
        decoded.append(len(raw))
        return decode(raw, *args, **kwargs)

    monkeypatch.setattr(msgspec.msgpack, "decode", spy)
    panel = app.panels["pancake"]
    big = 1 << 20  # over the cap, far under viser's own 50 MiB
    with client(app) as other:
        ws = client(app)
        send(ws, panel.length, "x" * big)
        assert closed(ws) == 1009  # message too big: the frame's header is enough to refuse it
        ws.close()
        assert all(n < big for n in decoded)
        since = time.perf_counter()  # the other page is still served
        send(other, panel.length, 600)
        settle(app, "pancake.event", since)
        assert panel.frame.controls.length == 600
    panel.length.value = 500
    assert app.wait_idle(60)


def test_a_message_that_does_not_decode_is_refused_quietly(app, caplog, capfd):
    encode = msgspec.msgpack.encode
    uuid = app.panels["pancake"].length._impl.uuid
    nested = (b"\x83" + encode("type") + encode("GuiUpdateMessage") + encode("uuid") + encode(uuid)
              + encode("updates") + b"\x81" + encode("value") + b"\x91" * 5000 + b"\xc0")
    hostile = {"a value nested 5,000 deep": nested, "an array nested 20,000 deep": b"\x91" * 20_000 + b"\xc0",
               "not msgpack": b"\xc1", "not a map": encode(7), "no such message": encode({"type": "NoSuchMessage"}),
               "a message with wrong fields": encode({"type": "GuiUpdateMessage", "nonsense": 1}),
               "a text frame": '{"type": "GuiUpdateMessage"}'}
    capfd.readouterr()
    for name, raw in hostile.items():
        ws = client(app, camera=False)
        ws.send(raw)
        assert closed(ws) == 1007, name  # invalid data
        ws.close()
    client(app).close()  # and the next page is let in
    assert app.wait_idle(60)
    assert not [r for r in caplog.records if r.exc_info or r.levelno >= 40], caplog.text
    err = capfd.readouterr().err
    assert "Traceback" not in err and "RecursionError" not in err, err


# --- files ------------------------------------------------------------------------------------------


def test_an_export_format_outside_the_options_writes_nothing(app):
    pancake, sliding = app.panels["pancake"], app.panels["sliding"]
    for exported in Path(app.out).glob("*.csv"):
        exported.unlink()
    with client(app) as ws:
        for count, panel in enumerate((pancake, sliding), start=1):
            errors = len(app.errors)
            send(ws, panel.format, "x/../../../victim.csv")
            wait_for(lambda n=errors: len(app.errors) > n, what="a refusal")  # on arrival: never stored
            assert "'format'" in app.errors[-1] and "not one of csv, npz" in app.errors[-1]
            assert panel.format.value == "csv"
            send(ws, panel.export_button, True)  # exports with what the server holds: inside --out
            # the click is a message in flight: wait for its file, not only for an idle worker
            wait_for(lambda n=count: len(list(Path(app.out).glob("*.csv"))) >= n, what="the export")
            assert app.wait_idle(60)
    for exported in Path(app.out).glob("*.csv"):
        exported.unlink()
    assert not list(Path(app.root).rglob("victim*"))


@pytest.mark.parametrize("name", ["../victim.csv", "x/../../victim.csv", "/tmp/victim.csv", "sub/file.csv", ".."])
def test_an_export_path_outside_out_is_refused(tmp_path, name):
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(ValueError, match="outside the output folder"):
        guard.inside(out, name)
    assert guard.inside(out, "pancake-learned.csv") == out.resolve() / "pancake-learned.csv"


def test_an_export_through_a_symlink_in_out_is_refused(app):
    target = Path(app.root) / "elsewhere.csv"
    link = Path(app.out) / "pancake-learned.csv"
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(target)
    try:
        with pytest.raises(ValueError, match="outside the output folder"):
            app.export_file(link.name, lambda p: p.write_text("x") and p)
        assert not target.exists()
    finally:
        link.unlink()


# --- values -----------------------------------------------------------------------------------------


def test_a_duration_beyond_its_slider_is_clamped(app):
    panel = app.panels["pancake"]
    with client(app) as ws:
        since = time.perf_counter()
        send(ws, panel.length, 1e8)
        send(ws, panel.end_y, -5.0)
        settle(app, "pancake.event", since)
        wait_for(lambda: panel.frame.controls.length == 1000 and panel.frame.controls.end_y == -0.3,
                 what="the clamped redraw")
        assert len(panel.frame.states) == 1000
        assert panel.length.value == 1000 and panel.end_y.value == -0.3  # written back: the page shows it
        send(ws, panel.length, 500)
        send(ws, panel.end_y, 0.2)
        wait_for(lambda: panel.frame.controls.length == 500 and panel.frame.controls.end_y == 0.2)
        assert app.wait_idle(60)


def test_lm_updates_beyond_the_slider_are_clamped(app):
    panel = app.panels["pancake"]
    sources = []
    draw = panel.draw

    def drawn(frame):  # after the adjustment's first update, ask for a redraw: it stops there
        draw(frame)
        if frame.source.startswith("latent"):
            sources.append(frame.source)
            panel.request()

    panel.draw = drawn
    try:
        with client(app) as ws:
            send(ws, panel.updates, 1e9)
            wait_for(lambda: panel.updates.value != 6, what="the slider's value")
            send(ws, panel.adjust_button, True)
            wait_for(lambda: sources, what="the adjustment")
            assert app.wait_idle(60)
    finally:
        panel.draw = draw
        panel.updates.value = 6
    assert sources == ["latent 1/20"]


def test_a_clients_adjustment_stops_when_it_leaves(app):
    panel = app.panels["pancake"]
    sources = []
    left = threading.Event()
    draw = panel.draw

    def drawn(frame):  # hold the adjustment's first update until its client has gone
        draw(frame)
        if frame.source.startswith("latent"):
            sources.append(frame.source)
            left.wait(30)

    panel.draw = drawn
    try:
        ws = client(app)
        send(ws, panel.updates, 20)
        wait_for(lambda: panel.updates.value == 20, what="the slider's value")
        send(ws, panel.adjust_button, True)
        wait_for(lambda: sources, what="the adjustment")
        ws.close()
        wait_for(lambda: panel.worker.stop_requested, what="the disconnect")
        assert not panel.worker.has_pending  # the stop comes from the client leaving, not from a newer job
        left.set()
        assert app.wait_idle(60)
    finally:
        left.set()
        panel.draw = draw
        panel.updates.value = 6
    assert sources == ["latent 1/20"]  # not 20 updates for nobody


def test_a_disabled_video_button_renders_nothing_under_no_sim(app):
    panel = app.panels["pancake"]
    assert panel.video_button.disabled
    with client(app) as ws:
        for button in (panel.video_button, panel.sim_button, app.panels["sliding"].sim_button):
            errors = len(app.errors)
            send(ws, button, True)
            wait_for(lambda n=errors: len(app.errors) > n, what="a refusal")
            assert "--no-sim" in app.errors[-1]
        assert app.wait_idle(60)
    assert not list(Path(app.root).rglob("*.mp4"))


def test_a_page_may_change_a_controls_value_only(app):
    panel = app.panels["pancake"]
    with client(app) as ws:
        send(ws, panel.video_button, False, prop="disabled")
        send(ws, panel.format, ["csv", "../x"], prop="options")
        send(ws, panel.length, [], prop="update_cb")  # would leave the slider without its callback
        since = time.perf_counter()
        send(ws, panel.length, 600)
        settle(app, "pancake.event", since)
    assert panel.video_button.disabled and tuple(panel.format.options) == ("csv", "npz")
    assert panel.frame.controls.length == 600
    panel.length.value = 500
    assert app.wait_idle(60)


HOSTILE = [1e308, -1e308, 1e8, -1e8, math.nan, math.inf, -math.inf, 0, -1, "x/../../../victim.csv", "../victim",
           "", [1, 2, 3], [math.nan, 0.0, 0.0], [1e9, -1e9, 1e9], {"a": 1}, None, True, "9" * 5000,
           "x" * (guard.MAX_MESSAGE // 2)]
"""Out of range, NaN, wrong types and huge values, as a client can send them to any control (a message over
``guard.MAX_MESSAGE`` closes its connection: see the tests of the connections)."""


def test_every_control_survives_hostile_values(app):
    # every input of the page, buttons too (viser's registry: a control added later is fuzzed as well)
    handles = list(app.server.gui._gui_input_handle_from_uuid.values())
    assert set(map(id, app.controls.handles)) <= set(map(id, handles)) and len(handles) > 25
    with client(app) as ws:
        for handle in handles:
            for value in HOSTILE:
                send(ws, handle, value)
        ws.ping().wait(30)  # every message has reached the server
    assert app.wait_idle(120)
    # it still answers, at once: the page, a new connection, and a control's next change
    start = time.monotonic()
    connection = http.client.HTTPConnection("127.0.0.1", app.server.get_port(), timeout=1)
    connection.request("GET", "/")
    assert connection.getresponse().status == 200
    client(app, f"http://127.0.0.1:{app.server.get_port()}").close()
    assert time.monotonic() - start < 1.0
    panel = app.panels["pancake"]
    with client(app) as ws:
        for handle, value in ((panel.keep_end, False), (panel.length, 500), (panel.end_y, 0.15)):
            send(ws, handle, value)
        wait_for(lambda: panel.frame.controls == type(panel.frame.controls)(end_y=0.15, end_z=panel.end_z.value,
                                                                             end_theta=panel.end_theta.value,
                                                                             timing=panel.timing.value),
                 what="the redraw after the fuzzing")
    # a control still holding a hostile value is refused by name when read, and holds a valid one after
    for handle in app.controls.handles:
        try:
            app.controls.read(handle)
        except ValueError as exc:
            assert repr(handle.label) in str(exc)
        app.controls.read(handle)
    assert np.all(np.isfinite(panel.frame.states))
    assert app.wait_idle(120)


def test_a_value_that_is_not_a_number_is_refused_by_name(app):
    panel = app.panels["pancake"]
    before = panel.end_z.value, panel.frame.controls.end_z, panel.target_in.value
    with client(app) as ws:
        for handle, value, label in ((panel.end_z, math.nan, "'end z [m]'"),
                                     (panel.target_in, [math.nan, 0.0, 1.0], "'target y, z, θ'")):
            errors = len(app.errors)
            send(ws, handle, value)
            wait_for(lambda n=errors: len(app.errors) > n, what="a refusal")
            assert label in app.errors[-1] and "not a number" in app.errors[-1]
            assert app.wait_idle(60)
    assert (panel.end_z.value, panel.frame.controls.end_z) == before[:2]  # refused on arrival: never stored
    assert panel.target_in.value == pytest.approx(before[2]) and all(map(math.isfinite, panel.target))
