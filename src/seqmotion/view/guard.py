"""What the viewer accepts from a page, checked on the server (a page, or any program, can send anything).

viser trusts its page: a WebSocket from any Origin gets every control, a control's value arrives as the
client sent it (a number far outside its slider, NaN, a dropdown value that is none of its options), and
a ``GuiUpdateMessage`` may rewrite any property of a control (``disabled``, ``options``, its callbacks).
Each defence is in one place here:

* :func:`start_server` — a viser server whose WebSocket handshake answers **403** to a page of a foreign
  origin and **503** beyond :data:`MAX_CONNECTIONS` open connections, which closes a connection whose message
  is over :data:`MAX_MESSAGE` bytes before reading it, or is not one of viser's messages (undecodable,
  nested too deep) before viser decodes it (:func:`guarding`), and whose pages may change a control's
  ``value`` and nothing else (:func:`values_only`).
* :class:`Controls` — every control the server reads is declared with its range (sliders, vectors),
  options (dropdowns) or length (text); :meth:`Controls.read` clamps a number into its range and
  refuses, by the control's name, what is not a number or not an option.
* :func:`inside` — an export's path, resolved, must be a file directly in the output folder.
"""

from __future__ import annotations

import contextlib
import http
import ipaddress
import logging
import math
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "[::1]")
"""Hosts whose origin (at the served port) a page may always come from."""
WILDCARD_HOSTS = ("", "0.0.0.0", "::")
"""Bind addresses that mean "every interface" (not a host a page can be served from)."""
MAX_TEXT = 2000
"""The most characters a text control takes unless declared otherwise (the spline's 50 points fit easily)."""
MAX_CONNECTIONS = 32
"""The most WebSocket connections one viewer keeps open (a page holds one): a further handshake is answered
HTTP 503 before the upgrade, so idle connections cannot pile up (1,500 held half a gigabyte). A program that
holds them all keeps pages out, as it could by any other load on this machine. Read at each handshake."""
MAX_MESSAGE = 64 * 1024
"""The most bytes one message from a page may have (viser allows 50 MiB; the largest a page of this viewer
sends, a text of :data:`MAX_TEXT` characters, is under 8 kB): a longer one closes its connection (code 1009)
on its frame's header, before its payload is read. With websockets' queue of 16 messages a connection, the
open connections buffer about 32 MiB at most. Read when a server starts."""


# --- the WebSocket handshake -----------------------------------------------------------------------


def _url_host(host: str) -> str:
    """``host`` as it appears in a URL: an IPv6 address in brackets (an IPv4 one a dual-stack socket reports
    as ``::ffff:a.b.c.d``: as IPv4), names lower case."""
    host = host.strip().lower()
    if host.startswith("["):
        return host
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return host
    if ip.version == 6 and ip.ipv4_mapped is not None:
        return str(ip.ipv4_mapped)
    return f"[{ip}]" if ip.version == 6 else str(ip)


def allowed_origins(host: str, local_address: Sequence[Any]) -> set[str]:
    """The origins a page may have to connect: ``http://`` + a loopback name, the address the connection
    arrived at (so a page opened by IP, e.g. ``http://192.168.1.5:8080`` under ``--host 0.0.0.0``, works),
    or ``host`` itself (``--host``), each at the port served (``local_address``: the socket's ``(ip, port)``)."""
    port = int(local_address[1])
    hosts = {*LOOPBACK_HOSTS, _url_host(str(local_address[0]))}
    if host not in WILDCARD_HOSTS:
        hosts.add(_url_host(host))
    origins = {f"http://{h}:{port}" for h in hosts}
    if port == 80:  # a browser leaves out the default port
        origins |= {f"http://{h}" for h in hosts}
    return origins


def origin_allowed(origins: Sequence[str], host: str, local_address: Sequence[Any]) -> bool:
    """Whether a WebSocket handshake with these ``Origin`` header values may proceed.

    No ``Origin`` header: allowed — every browser sends one on a WebSocket, so such a client is a program
    on a machine that can reach the port (on the default 127.0.0.1: this machine), which could as well
    write the files itself; more than one: refused (RFC 6454 allows one)."""
    if not origins:
        return True
    return len(origins) == 1 and origins[0].strip().lower() in allowed_origins(host, local_address)


_SERVE_LOCK = threading.Lock()
_log = logging.getLogger(__name__)


def start_server(host: str, port: int, controls: Controls | None = None,
                 on_refused: Callable[[str], None] | None = None, **kwargs: Any) -> Any:
    """A ``viser.ViserServer`` at ``host:port`` (``kwargs``: its other arguments) that refuses foreign origins,
    connections beyond :data:`MAX_CONNECTIONS` and messages that are too long or not viser's (:func:`guarding`),
    and lets a page change values only, each checked on arrival against ``controls`` (:func:`values_only`;
    ``on_refused`` gets the message of a value refused); RuntimeError, and no server left running, where either
    cannot be installed (a viser version that works differently)."""
    import viser
    from viser._messages import Message

    wrapped: list[int] = []
    with guarding(host, wrapped):
        server = viser.ViserServer(host=host, port=port, **kwargs)
    try:
        if not wrapped:
            raise RuntimeError("viser did not start its server through websockets.asyncio.server.serve: the "
                               "viewer's Origin check could not be installed (an unsupported viser version?)")
        if getattr(server._websock_server, "_message_class", None) is not Message:
            raise RuntimeError("viser decodes its messages with another class than viser._messages.Message: the "
                               "viewer's message check could not be installed (an unsupported viser version?)")
        values_only(server, controls, on_refused)
    except BaseException:
        server.stop()
        raise
    return server


@contextlib.contextmanager
def guarding(host: str, wrapped: list[int]) -> Iterator[None]:
    """Start a ``viser.ViserServer`` inside this block and its WebSocket connections are bounded and checked.

    viser has no hook for its handshake: its server thread calls ``websockets.asyncio.server.serve(...,
    process_request=...)`` (every attempt at a port, before the constructor returns). While this block
    runs, that function is replaced by one that

    * wraps viser's ``process_request``: a WebSocket upgrade whose Origin :func:`origin_allowed` refuses
      gets HTTP 403, one beyond :data:`MAX_CONNECTIONS` open connections HTTP 503, before viser sees it;
    * sets ``max_size`` to :data:`MAX_MESSAGE` (websockets refuses a longer message on its frame's header);
    * checks each message of an admitted connection before viser's reader gets it (:func:`checking_messages`).

    Each wrapped call appends to ``wrapped`` (empty afterwards: viser started its server some other way,
    unchecked).
    """
    import websockets.asyncio.server as ws_server
    from websockets.protocol import State

    original = ws_server.serve

    def serve(*args: Any, **kwargs: Any) -> Any:
        inner = kwargs.get("process_request")
        # this server's upgrades let through, until their connection is closed: counted from the handshake on,
        # since a burst of handshakes all pass this check before any of them reaches viser's handler
        admitted: set[Any] = set()

        def process_request(connection: Any, request: Any) -> Any:
            if any("websocket" in v.lower() for v in request.headers.get_all("Upgrade")):
                origins = request.headers.get_all("Origin")
                if not origin_allowed(origins, host, connection.local_address):
                    return connection.respond(http.HTTPStatus.FORBIDDEN,
                                              f"seqmotion view: origin {', '.join(origins)} refused\n")
                admitted.difference_update([c for c in admitted if c.state is State.CLOSED])
                if len(admitted) >= MAX_CONNECTIONS:
                    return connection.respond(http.HTTPStatus.SERVICE_UNAVAILABLE,
                                              f"seqmotion view: {MAX_CONNECTIONS} connections are open already\n")
                admitted.add(connection)
                checking_messages(connection)
            return None if inner is None else inner(connection, request)

        kwargs["process_request"] = process_request
        kwargs["max_size"] = MAX_MESSAGE
        wrapped.append(1)
        return original(*args, **kwargs)

    with _SERVE_LOCK:  # one server starts at a time: the replacement is never seen by anyone else's
        ws_server.serve = serve
        try:
            yield
        finally:
            ws_server.serve = original


def checking_messages(connection: Any) -> None:
    """Close ``connection`` (code 1007, one warning logged) at its first message that is not one of viser's:
    a text frame, bytes that are not msgpack, msgpack nested too deep to decode (msgspec recurses once per
    level: a kilobyte of nested arrays, far under :data:`MAX_MESSAGE`, raises RecursionError), an unknown
    message type, wrong fields.

    viser's reader (``recv()``, then ``Message.deserialize``) lets such a message's exception end the
    connection's handler, which websockets logs with its traceback. Here ``recv`` is wrapped: a message is
    passed on only once ``Message.deserialize`` has taken it, and viser's own call on the same bytes,
    from a shallower stack, cannot fail then. After a refusal nothing more is passed on, messages already
    queued included: the wrapper waits for the end of the connection, whose ConnectionClosed viser expects.
    """
    from viser._messages import Message
    from websockets.frames import CloseCode

    recv = connection.recv

    async def checked_recv(*args: Any, **kwargs: Any) -> Any:
        raw = await recv(*args, **kwargs)
        if not isinstance(raw, bytes):
            why = "a text message (viser's are binary)"
        else:
            try:
                Message.deserialize(raw)
                return raw
            except RecursionError:
                why = "a message nested too deep"
            except Exception as exc:  # whatever viser's decoder raises on it, viser's reader would raise too
                why = f"not a viser message ({type(exc).__name__}: {_short(str(exc))})"
        _log.warning("seqmotion view: closed a connection from %s: %s", _peer(connection), why)
        await connection.close(CloseCode.INVALID_DATA, "seqmotion view: not a viser message")
        while True:  # ends in ConnectionClosed
            await recv(*args, **kwargs)

    connection.recv = checked_recv


def _peer(connection: Any) -> str:
    try:
        return str(connection.remote_address[0])
    except Exception:  # a connection already gone has no address
        return "?"


def values_only(server: Any, controls: Controls | None = None,
                on_refused: Callable[[str], None] | None = None) -> None:
    """Let a page change a control's ``value`` only: viser applies every property a ``GuiUpdateMessage``
    names (``disabled``, ``options``, ``min``, the callback list …), while its own page only ever sends
    ``value``. Wraps viser's one handler of that message (RuntimeError if it is not where expected).

    A declared control's value (``controls``) is checked on arrival, on the server's message thread, before
    viser stores it: a number out of range is stored clamped, a refused value is not stored at all
    (``on_refused`` gets the message naming the control), and the page is sent back what the server holds.
    Checking here, in message order, means no later value from the page can be overwritten by a correction
    of an earlier one (a check when a panel's worker reads the control would race with new messages)."""
    from viser._messages import GuiUpdateMessage

    websock, handler = server._websock_server, server.gui._handle_gui_updates
    if handler not in websock._incoming_handlers.get(GuiUpdateMessage, []):
        raise RuntimeError("viser's GuiUpdateMessage handler was not found: the viewer cannot restrict what a "
                           "page may change (an unsupported viser version?)")
    websock.unregister_handler(GuiUpdateMessage, handler)

    def show(uuid: str, value: Any) -> None:  # to the pages, without calling the control's callbacks again
        websock.queue_message(GuiUpdateMessage(uuid, {"value": value}))

    async def only_value(client_id: Any, message: Any) -> None:
        if not isinstance(message.updates, dict):
            return
        message.updates = {k: v for k, v in message.updates.items() if k == "value"}
        if not message.updates:
            return
        handle = None if controls is None else controls.by_uuid(message.uuid)
        sent = message.updates["value"]
        if handle is not None:
            try:
                message.updates["value"] = controls.check(handle, sent)
            except ValueError as exc:
                if on_refused is not None:
                    on_refused(str(exc))
                show(message.uuid, handle.value)  # the page shows what the server still holds
                return
        try:
            await handler(client_id, message)
        except (TypeError, ValueError, OverflowError) as exc:  # viser cannot even cast it to the control's type
            _log.warning("seqmotion view: dropped a value for control %s: %s", message.uuid, _short(str(exc)))
            return
        if handle is not None and message.updates["value"] != sent:
            show(message.uuid, message.updates["value"])  # clamped: the page shows what the server uses

    websock.register_handler(GuiUpdateMessage, only_value)


# --- control values -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Declared:
    """What the server declared for a control when it built it (a page cannot change this copy).

    Attributes:
        label: the control's label (named in every refusal).
        initial: the value it started with (a refused value is replaced by it).
        lo, hi: per component bounds of a number or vector (a number: one component), or None.
        integer: its values are whole numbers (an int slider, an index).
        options: a dropdown's values, or None.
        max_chars: a text's most characters, or None.
    """

    label: str
    initial: Any
    lo: tuple[float, ...] | None = None
    hi: tuple[float, ...] | None = None
    integer: bool = False
    options: tuple[str, ...] | None = None
    max_chars: int | None = None

    def check(self, value: Any) -> Any:
        """``value`` made valid: a number clamped into ``[lo, hi]``; ValueError naming the control for a value
        that is not a finite/infinite number, not an option, or too long a text."""
        if self.options is not None:
            if not isinstance(value, str) or value not in self.options:
                raise ValueError(f"control {self.label!r}: {_short(value)} is not one of {', '.join(self.options)}")
            return value
        if isinstance(self.initial, bool):
            return bool(value)
        if isinstance(self.initial, str):
            text = str(value)
            if self.max_chars is not None and len(text) > self.max_chars:
                raise ValueError(f"control {self.label!r}: {len(text)} characters, at most {self.max_chars}")
            return text
        vector = isinstance(self.initial, tuple)
        values = tuple(value) if vector and isinstance(value, (tuple, list)) else (value,)
        if self.lo is None or self.hi is None or len(values) != len(self.lo):
            raise ValueError(f"control {self.label!r}: {_short(value)} is not {len(self.lo or ())} number(s)")
        out = []
        for v, lo, hi in zip(values, self.lo, self.hi, strict=True):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v):
                raise ValueError(f"control {self.label!r}: {_short(value)} is not a number in [{lo:g}, {hi:g}]")
            v = min(max(float(v), lo), hi)  # out of range (±inf too): the nearest end of the slider
            out.append(int(round(v)) if self.integer else v)
        return tuple(out) if vector else out[0]


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class Controls:
    """The controls the server reads, each with what it declared (:class:`Declared`); the one place a
    control's value from the page is checked."""

    def __init__(self) -> None:
        self._declared: dict[int, tuple[Any, Declared]] = {}
        self._uuids: dict[str, Any] = {}  # viser's id of each declared control → its handle

    def declare(self, handle: Any, lo: Sequence[float] | float | None = None, hi: Sequence[float] | float | None = None,
                max_chars: int = MAX_TEXT) -> Any:
        """Record ``handle``'s range/options as built (a slider's min/max/step, a dropdown's options; a vector's
        ``lo``/``hi`` per component) and return it."""
        initial = handle.value
        options = getattr(handle, "options", None)
        if options is not None:
            spec = Declared(handle.label, initial, options=tuple(options))
        elif isinstance(initial, (bool, str)):
            spec = Declared(handle.label, initial, max_chars=max_chars if isinstance(initial, str) else None)
        else:
            if lo is None and hasattr(handle, "min"):
                lo, hi = handle.min, handle.max
            if lo is None or hi is None:
                raise ValueError(f"control {handle.label!r}: declare its range")
            lo_t = tuple(float(v) for v in (lo if isinstance(lo, Sequence) else (lo,)))
            hi_t = tuple(float(v) for v in (hi if isinstance(hi, Sequence) else (hi,)))
            integer = isinstance(initial, int) and float(getattr(handle, "step", 1) or 1).is_integer()
            spec = Declared(handle.label, initial, lo_t, hi_t, integer)
        self._declared[id(handle)] = (handle, spec)
        uuid = getattr(getattr(handle, "_impl", None), "uuid", None)
        if uuid is not None:
            self._uuids[uuid] = handle
        return handle

    def by_uuid(self, uuid: str) -> Any | None:
        """The declared control viser knows as ``uuid`` (None: not declared, e.g. a button)."""
        return self._uuids.get(uuid)

    def check(self, handle: Any, value: Any) -> Any:
        """``value`` made valid for ``handle`` (:meth:`Declared.check`), without touching the control."""
        return self._declared[id(handle)][1].check(value)

    def read(self, handle: Any) -> Any:
        """The control's value made valid. A clamped value is written back, a refused one replaced by the
        initial value (and ValueError raised): either way the page then shows what the server uses."""
        spec = self._declared[id(handle)][1]
        value = handle.value
        try:
            checked = spec.check(value)
        except ValueError:
            handle.value = spec.initial
            raise
        if checked != value:
            handle.value = checked
        return checked

    @property
    def handles(self) -> list[Any]:
        """Every declared control (the tests send each of them hostile values)."""
        return [h for h, _ in self._declared.values()]


# --- files ------------------------------------------------------------------------------------------


def inside(out: Path, name: str) -> Path:
    """``out / name`` resolved; ValueError unless it is a file directly in ``out`` (resolved too), so no
    ``..``, absolute path or symlink in a name can place an export elsewhere."""
    root = Path(out).resolve()
    path = (root / name).resolve()
    if path.parent != root:
        raise ValueError(f"export {_short(name)} would be written outside the output folder {root} (--out): "
                         "refused")
    return path
