"""The viewer's connections (defect 12): repros for benchmarks/hostile.py, each run after its PRELUDE.

Each snippet starts the viewer in its own process (``ViewerApp`` on 127.0.0.1, a free port, ``--no-sim``), attacks
it with ``websockets``' asyncio client carrying the page's own Origin, stops it, and prints ``held(ok, why)``.
Loopback only. The snippets name no constant of ``seqmotion.view.guard``, so they run on an older tree too.
"""

_VIEWER = '''
import asyncio, io, logging, resource
import msgspec, viser
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus
from seqmotion.view.app import ViewerApp

app = ViewerApp("pancake", port=0, out="out", latent_n=16, simulate=False)
assert app.wait_idle(120)
PORT = app.server.get_port()

def opening():  # what a page of the viewer's own origin opens
    return connect(f"ws://127.0.0.1:{PORT}", origin=f"http://127.0.0.1:{PORT}", proxy=None, open_timeout=30,
                   subprotocols=[f"viser-v{viser.__version__}"], max_size=None, compression=None)

async def close_code(ws, timeout=15.0):
    """The code the server closed ws with (what it sends before is dropped); None: still open after timeout."""
    async def drain():
        while True:
            await ws.recv()
    try:
        await asyncio.wait_for(drain(), timeout)
    except ConnectionClosed as exc:
        return None if exc.rcvd is None else exc.rcvd.code
    except asyncio.TimeoutError:
        return None

async def serves():
    """A page still gets in and is answered."""
    async with opening() as ws:
        await asyncio.wait_for(await ws.ping(), 10)
    return True

def peak_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

def run(attack):
    try:
        ok, why = asyncio.run(attack())
    except BaseException as exc:
        ok, why = False, f"{type(exc).__name__}: {exc}"[:200]
    finally:
        app.stop()
    held(ok, why)
'''

_QUIET = '''
records = []
class Keep(logging.Handler):
    def emit(self, record):
        records.append(record)
logging.getLogger().addHandler(Keep())

async def quietly_refused(raw):
    """(held, why) for one message sent on its own connection: closed by the server, nothing logged with a
    traceback (on the log or stderr), and the next page served."""
    sys.stderr = err = io.StringIO()
    try:
        ws = await opening()
        try:
            await ws.send(raw)
        except Exception:  # a message over the cap is closed mid-send (websockets' client may fail its own abort)
            pass
        code = await close_code(ws)
        try:
            await ws.close()
        except Exception:  # the client's own transport, aborted when the server closed mid-send
            pass
    finally:
        sys.stderr = sys.__stderr__
    loud = [r for r in records if r.exc_info or r.levelno >= logging.ERROR]
    text = err.getvalue() + "".join(logging.Formatter().format(r) for r in loud)
    ok = code is not None and not loud and "Traceback" not in text and await serves()
    return ok, f"close code {code}, {len(loud)} error(s) logged: {text.strip().splitlines()[-1:] or ''}"
'''

ATTEMPTS = {12: [
    ("300 idle connections with the page's Origin", _VIEWER + '''
async def attack():
    async def one():
        return await opening()
    before = peak_mb()
    results = await asyncio.gather(*(one() for _ in range(300)), return_exceptions=True)
    kept = [r for r in results if not isinstance(r, BaseException)]
    refused = [r for r in results if isinstance(r, InvalidStatus) and r.response.status_code == 503]
    other = [repr(r)[:80] for r in results if isinstance(r, BaseException) and r not in refused]
    grown = peak_mb() - before
    await asyncio.gather(*(ws.close() for ws in kept))
    ok = len(kept) <= 64 and len(refused) == 300 - len(kept) and await serves()
    return ok, f"{len(kept)} kept open, {len(refused)} refused (503), other {other[:2]}, peak RSS +{grown:.0f} MB"
run(attack)
'''),
    ("8 connections x 4 messages of 45 MB", _VIEWER + '''
uuid = app.panels["pancake"].length._impl.uuid  # any control: the size is the attack
big = msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": uuid, "updates": {"value": "x" * 45_000_000}})

async def attack():
    before = peak_mb()  # with the 90 MB of the message itself
    async def flood(ws):
        try:
            for _ in range(4):
                await ws.send(big)
        except Exception:  # the server closed it mid-send (websockets' client may then fail its own abort)
            pass
        return await close_code(ws, 30)
    connections = [await opening() for _ in range(8)]
    codes = await asyncio.gather(*(flood(ws) for ws in connections))
    grown = peak_mb() - before
    ok = all(code == 1009 for code in codes) and grown < 400 and await serves()
    return ok, f"close codes {codes}, peak RSS +{grown:.0f} MB"
run(attack)
'''),
    ("a 5 MB nested msgpack", _VIEWER + _QUIET + '''
async def attack():
    return await quietly_refused(b"\\x91" * 5_000_000 + b"\\xc0")
run(attack)
'''),
    ("a control's value nested 5,000 deep (5 kB)", _VIEWER + _QUIET + '''
async def attack():
    encode = msgspec.msgpack.encode
    uuid = app.panels["pancake"].length._impl.uuid
    return await quietly_refused(b"\\x83" + encode("type") + encode("GuiUpdateMessage") + encode("uuid")
                                 + encode(uuid) + encode("updates") + b"\\x81" + encode("value")
                                 + b"\\x91" * 5000 + b"\\xc0")
run(attack)
'''),
]}
