"""Hostile LeRobot v3.0 folders against ``seqmotion lfd import-lerobot`` / ``lfd train --data``.

``ATTEMPTS`` has the shape of ``benchmarks/hostile.py``'s (defect number -> [(name, snippet)]); each snippet runs
after hostile.py's PRELUDE in an empty folder, builds its own base data with the CLI (collect, then
export-lerobot as PNGs and as H.264), crafts one hostile file from it and prints HELD when the import is refused
by name: exit 2, one line on stderr naming the file or field, nothing written.
"""

from __future__ import annotations

BASE = """
import pyarrow as pa, pyarrow.parquet as pq
rc, err = cli("lfd", "collect", "--out", "d", "--sets", "pairs_default", "--per-position", "1", "--duration", "0.6",
              "--quiet")
assert rc == 0, err
assert cli("lfd", "export-lerobot", "d", "lri")[0] == 0
assert cli("lfd", "export-lerobot", "d", "lrv", "--videos", "--codec", "h264")[0] == 0
IMAGES, VIDEOS = Path("lri/pairs_default"), Path("lrv/pairs_default")
DATA = "data/chunk-000/file-000.parquet"
EPISODES = "meta/episodes/chunk-000/file-000.parquet"
VIDEO = "videos/observation.images.webcam/chunk-000/file-000.mp4"
def edit_info(root, **changes):
    info = json.loads((root / "meta/info.json").read_text())
    info.update(changes)
    (root / "meta/info.json").write_text(json.dumps(info))
def edit_episodes(root, **columns):
    rows = pq.read_table(root / EPISODES).to_pylist()
    for row in rows:
        row.update(columns)
    pq.write_table(pa.Table.from_pylist(rows), root / EPISODES)
def set_column(root, name, array):
    table = pq.read_table(root / DATA)
    pq.write_table(table.set_column(table.column_names.index(name), name, array), root / DATA)
def import_held(root, *words, argv=()):
    rc, err = cli("lfd", "import-lerobot", str(root), "out", *argv)
    nothing = not Path("out").exists() or not any(Path("out").iterdir())
    ok = rc == 2 and err.count("\\n") == 1 and nothing and all(w in err for w in words)
    held(ok, f"rc {rc}, {'nothing' if nothing else 'something'} written: {err.strip()[-240:]}")
"""

ATTEMPTS: dict[int, list[tuple[str, str]]] = {
    1: [("LeRobot action value 1e20, trained on (lfd train --data)", BASE + """
table = pq.read_table(IMAGES / DATA)
action = np.asarray(table.column("action").to_pylist(), dtype=np.float32)
action[0, 1] = 1e20  # finite, but its square overflows float32: an infinite loss
set_column(IMAGES, "action", pa.FixedSizeListArray.from_arrays(pa.array(action.reshape(-1)), 9))
rc, err = cli("lfd", "train", "--data", str(IMAGES), "--out", "t8", "--preset", "tiny", "--methods", "seqae",
              "--seqae-epochs", "3", "--keep-failed", "--quiet")
held(rc == 2 and err.count("\\n") == 1 and "action" in err and not Path("t8").exists(), f"rc {rc}: {err[-200:]}")
"""),
        ("LeRobot action value 3e38", BASE + """
table = pq.read_table(IMAGES / DATA)
action = np.asarray(table.column("action").to_pylist(), dtype=np.float32)
action[7, 4] = 3e38
set_column(IMAGES, "action", pa.FixedSizeListArray.from_arrays(pa.array(action.reshape(-1)), 9))
import_held(IMAGES, DATA, "'action'", "row 7")
""")],
    2: [("LeRobot video_path ../elsewhere/private.mp4", BASE + """
Path("elsewhere").mkdir()
shutil.copy(VIDEOS / VIDEO, "elsewhere/private.mp4")  # a real video outside the dataset
edit_info(VIDEOS, video_path="../../elsewhere/private.mp4")
import_held(VIDEOS, "video_path", "meta/info.json")
""")],
    3: [("LeRobot action list of 2M zeros per row (zstd)", BASE + """
table = pq.read_table(IMAGES / DATA)
per_row, group = 2_000_000, 10
zeros = pa.array(np.zeros(per_row * group, np.float32))  # shared by every row group: little memory to build
fields = [pa.field("action", pa.list_(pa.float32())) if f.name == "action" else f for f in table.schema]
with pq.ParquetWriter(IMAGES / DATA, pa.schema(fields), compression="zstd") as writer:
    for start in range(0, table.num_rows, group):
        part = table.slice(start, group)
        offsets = pa.array(np.arange(part.num_rows + 1) * per_row, pa.int32())
        bomb = pa.ListArray.from_arrays(offsets, zeros.slice(0, part.num_rows * per_row))
        writer.write_table(part.set_column(part.column_names.index("action"), "action", bomb))
print("bomb file", (IMAGES / DATA).stat().st_size, "bytes")
import_held(IMAGES, DATA, "'action'")
""")],
    4: [("LeRobot mp4 of 200,000 skip packets at 1920x1088", BASE + """
import av
from fractions import Fraction
path = VIDEOS / VIDEO
with av.open(str(path), "w", format="mp4") as out:  # one IDR frame, then the same all-skip P frame re-muxed
    stream = out.add_stream("libx264", rate=50)
    stream.width, stream.height, stream.pix_fmt = 1920, 1088, "yuv420p"
    stream.time_base = Fraction(1, 50)
    stream.options = {"preset": "ultrafast", "bf": "0", "g": "1000000"}
    packets = []
    for i in range(2):
        frame = av.VideoFrame.from_ndarray(np.zeros((1088, 1920, 3), np.uint8), format="rgb24")
        frame.pts, frame.time_base = i, Fraction(1, 50)
        packets += list(stream.encode(frame))
    packets += list(stream.encode())
    first, skip = bytes(packets[0]), bytes(packets[1])
    for i in range(200_000):
        packet = av.Packet(first if i == 0 else skip)
        packet.pts = packet.dts = i
        packet.time_base, packet.stream = Fraction(1, 50), stream
        packet.is_keyframe = i == 0
        out.mux(packet)
print("video", path.stat().st_size, "bytes")
edit_episodes(VIDEOS, **{"videos/observation.images.webcam/from_timestamp": 1e5,
                         "videos/observation.images.webcam/to_timestamp": 1e5 + 0.6})
import_held(VIDEOS, "from_timestamp")
""")],
    5: [("LeRobot state/effort/action 3 wide with names null", BASE + """
info = json.loads((IMAGES / "meta/info.json").read_text())
for key in ("observation.state", "observation.effort", "action"):
    info["features"][key].update(names=None, shape=[3])
(IMAGES / "meta/info.json").write_text(json.dumps(info))
rows = pq.read_metadata(IMAGES / DATA).num_rows
for key in ("observation.state", "action"):
    set_column(IMAGES, key, pa.FixedSizeListArray.from_arrays(pa.array(np.arange(rows * 3, dtype=np.float32)), 3))
import_held(IMAGES, "cannot map", "slave_theta", "slave_dtheta")
""")],
    7: [
        ("LeRobot video_path {video_key.__class__.__init__.__globals__}", BASE + """
edit_info(VIDEOS, video_path="videos/{video_key.__class__.__init__.__globals__}.mp4")
import_held(VIDEOS, "video_path", "meta/info.json")
"""),
        ("LeRobot from_timestamp inf through lfd train --data", BASE + """
edit_episodes(VIDEOS, **{"videos/observation.images.webcam/from_timestamp": float("inf")})
rc, err = cli("lfd", "train", "--data", str(VIDEOS), "--out", "run", "--preset", "tiny", "--quiet")
held(rc == 2 and err.count("\\n") == 1 and "from_timestamp" in err and not Path("run").exists(),
     f"rc {rc}: {err.strip()[-240:]}")
"""),
        ("LeRobot PNG declaring 20000x20000", BASE + """
import struct, zlib
def chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
png = (b"\\x89PNG\\r\\n\\x1a\\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 20000, 20000, 8, 2, 0, 0, 0))
       + chunk(b"IEND", b""))
rows = pq.read_metadata(IMAGES / DATA).num_rows
set_column(IMAGES, "observation.images.webcam", pa.array([{"bytes": png, "path": None}] * rows,
                                                         pa.struct([("bytes", pa.binary()), ("path", pa.string())])))
import_held(IMAGES, DATA, "observation.images.webcam")
"""),
    ],
    8: [("LeRobot data parquet replaced by a FIFO", BASE + """
(IMAGES / DATA).unlink()
os.mkfifo(IMAGES / DATA)  # an open() for reading blocks until a writer comes: none will
import_held(IMAGES, DATA, "not a regular file")
""")],
    13: [("LeRobot seqmotion/success 'no'", BASE + """
edit_episodes(IMAGES, **{"seqmotion/success": "no"})
import_held(IMAGES, EPISODES, "seqmotion/success")
""")],
    15: [("LeRobot import --set ../../x", BASE + """
rc, err = cli("lfd", "import-lerobot", str(IMAGES), "a/b/out", "--set", "../../x")
written = [str(p) for p in Path(".").rglob("x.h5")] + [str(p) for p in Path(".").glob("a/**/*")]
held(rc == 2 and err.count("\\n") == 1 and "--set" in err and not written, f"rc {rc}, written {written}: {err[-200:]}")
""")],
}
