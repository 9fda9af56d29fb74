"""The hostile sets of the hardening rounds, rerun as an attacker would: each attempt in its own process, on any
source tree.

    python benchmarks/hostile.py                       # this checkout's src/, every round
    python benchmarks/hostile.py --round 3             # the third round's repros only
    python benchmarks/hostile.py --src /tmp/old/src    # another tree (e.g. a worktree of an older commit)
    python benchmarks/hostile.py --json out.json

Round 2 (defects 5-14): inputs, plug-ins, ONNX contracts, checkpoints, friction out of distribution. Round 3
(defects 1-17 of its own list): LeRobot datasets, robot models under ``MENAGERIE_ROOT``, ONNX bundles, plug-in
shapes, saved results, the viewer's connections.

Every attempt runs a short Python snippet in a fresh interpreter (``PYTHONPATH=<src>``) in a fresh temporary
folder, under a 4 GiB address-space limit and a 180 s timeout. The snippet builds the hostile input, attacks the
public API or the command line, and prints ``HELD`` when the library refused by name (``ValueError`` /
``CheckpointError``, or the CLI's one line and exit code 2) and left every file as it was; anything else — a
traceback, a ``MemoryError``, a timeout, a silent success, a file written or destroyed — counts as a defect.

The viewer's attempts (foreign Origin, traversal through the export format, out-of-range controls, the disabled
video button) need a browser-side client: they are the scripted hostile client of ``tests/test_view_hostile.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

PRELUDE = """
import hashlib, json, os, shutil, sys, io, zipfile
from pathlib import Path
import numpy as np
def held(ok, why=""):
    print("HELD" if ok else "DEFECT " + why)
def cli(*argv):
    import contextlib
    from seqmotion.cli import main
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            rc = main(list(argv))
        except SystemExit as exc:
            rc = exc.code
    return rc, err.getvalue()
def refused(call, *args, **kwargs):
    try:
        call(*args, **kwargs)
    except ValueError as exc:
        return str(exc)
    return None
def sha(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
def npz_declaring(path, shape, key="states"):
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr(f"{key}.npy", header.getvalue() + bytes(64))
import seqmotion as sm
from seqmotion.tasks.pancake import data as sketches
from seqmotion.tasks.sliding import data as commands
"""

# round 2: defect number → [(name, snippet)]
ROUND_2: dict[int, list[tuple[str, str]]] = {
    5: [(f"{cmd} --output is its --input ({suffix})", f"""
sketch = sketches.straight((0.1, 0.0, 2.0), 150) if "{cmd}" == "deform" else commands.line(0.05, 300)
path = Path("in{suffix}")
if "{suffix}" == ".csv":
    np.savetxt(path, sketch, delimiter=",")
else:
    np.savez(path, states=sketch)
before = sha(path)
flag = "--input" if "{cmd}" == "deform" else "--command"
rc, err = cli("{cmd}", flag, str(path), "--output", "./sub/../in{suffix}" if "{cmd}" == "plan" else str(path))
kept = sha(path) == before
held(rc == 2 and kept and "error" in err, f"rc {{rc}}, input {{'kept' if kept else 'destroyed'}}")
""") for cmd, suffix in (("deform", ".csv"), ("deform", ".npz"), ("plan", ".npz"))],
    6: [
        ("npz of (3e7, 6) zeros, 1.4 MB compressed", """
zeros = np.zeros((30_000_000, 6))
np.savez_compressed("big.npz", states=zeros)  # 1.4 MB on disk, 1.4 GB in memory
del zeros
rc, err = cli("deform", "--input", "big.npz", "--output", "o.npz")
held(rc == 2 and "30000000" in err and not Path("o.npz").exists(), f"rc {rc}: {err[-200:]}")
"""),
        ("HDF5 declaring (6, 4e8) f8", """
import h5py
from seqmotion.lfd.data.dataset import FORMAT, MOTION_KEYS, VERSION
with h5py.File("d.h5", "w") as f:  # a complete-looking pushing dataset; the big one is chunked, never written
    f.attrs.update(format=FORMAT, version=VERSION, complete=True)
    for group in ("motions", "episodes/variation", "operator"):
        f.require_group(group)
    for key in MOTION_KEYS:
        f["motions"].create_dataset(key, shape=(1, 10, 3), dtype="f4")
    f.create_dataset("episodes/distance", shape=(6, 400_000_000), dtype="f8", chunks=(6, 1000))
rc, err = cli("lfd", "info", "d.h5")
held(rc == 2 and err.count("\\n") == 1, f"rc {rc}: {err[-200:]}")
"""),
        ("API deform with K = 3e6", """
message = refused(sm.load_pretrained("pancake").deform, np.zeros((3_000_000, 6)))
held(message is not None and "1000000" in message, str(message))
"""),
        ("CSV of 1e6 + 1 rows", """
with open("long.csv", "w") as f:
    f.write("0,0,0,0,0,0\\n" * 1_000_001)
rc, err = cli("deform", "--input", "long.csv", "--output", "o.npz")
held(rc == 2 and not Path("o.npz").exists(), f"rc {rc}: {err[-200:]}")
"""),
    ],
    7: [("npz whose header claims (1e9, 6)", """
npz_declaring("huge.npz", (1_000_000_000, 6))
rc, err = cli("deform", "--input", "huge.npz", "--output", "o.npz")
held(rc == 2 and "Traceback" not in err and err.count("\\n") == 1, f"rc {rc}: {err[-200:]}")
""")],
    8: [(f"a plug-in that {what}", f"""
Path("badplug.py").write_text({source!r})
info = Path("badplug-0.1.dist-info"); info.mkdir()
(info / "METADATA").write_text("Metadata-Version: 2.1\\nName: badplug\\nVersion: 0.1\\n")
(info / "entry_points.txt").write_text("[seqmotion.tasks]\\nbad = badplug:TASK\\n")
sys.path.insert(0, os.getcwd())
from seqmotion.core import registry
registry.refresh()
np.savez("in.npz", states=sketches.straight((0.1, 0.0, 2.0), 150))
print("deform:", cli("deform", "--input", "in.npz", "--output", "o.npz")[0])
names = registry.names()
held(Path("o.npz").is_file() and "pancake" in names, "the built-in tasks broke")
""") for what, source in (("fails to import", "raise ImportError('x')\n"), ("is not a task", "TASK = 42\n"),
                          ("reuses a built-in name",
                           "class T:\n    name = 'pancake'\n    def load(self, d): pass\nTASK = T()\n"),
                          ("calls sys.exit on import", "import sys\nsys.exit(3)\n"))],
    9: [(f"ONNX contract: {what}", f"""
from seqmotion.deploy import OnnxStepper, export_onnx
export_onnx(sm.load_pretrained("pancake"), "b")
contract = json.loads(Path("b/contract.json").read_text())
{edit}
Path("b/contract.json").write_text(json.dumps(contract))
try:
    OnnxStepper("b", sketches.straight((0.1, 0.0, 2.0), 150)).step()
    held(False, "loaded and stepped")
except ValueError as exc:  # by name: the contract, not (as before) "the measured states"
    held("contract" in str(exc), str(exc))
except Exception as exc:
    held(False, f"{{type(exc).__name__}}: {{exc}}")
""") for what, edit in (("dynamics.dt edited to 1.0", 'contract["dynamics"]["dt"] = 1.0'),
                        ("no 'files' key", 'contract.pop("files")'),
                        ("chunk 0", 'contract["chunk"] = 0'),
                        ("an absolute graph name", 'contract["files"]["encoder"] = "/etc/passwd"'),
                        ("a ../ graph name", 'contract["files"]["encoder"] = "../b/encoder.onnx"'),
                        ("a NaN limit", 'contract["stop"]["accel_limit"][0] = float("nan")'))],
    10: [("export-onnx killed after encoder.onnx is replaced", """
from seqmotion.deploy import OnnxStepper, export_onnx
export_onnx(sm.load_pretrained("pancake"), "b")
export_onnx(sm.load_pretrained("pancake-end"), "c")
graphs = lambda d: {p.name: sha(p) for p in Path(d).glob("*.onnx")}
old, new = graphs("b"), graphs("c")
# the export of pancake-end over b in another process, killed right after the rename that puts encoder.onnx
# (or b) in place (a process of its own, not a fork: torch's threads do not survive a fork)
Path("child.py").write_text('''
import os
from pathlib import Path
real = os.replace
def replace(src, dst, *a, **k):
    real(src, dst, *a, **k)
    if Path(str(dst)).name in ("encoder.onnx", "b"):
        os.kill(os.getpid(), 9)
os.replace = replace
import seqmotion as sm
from seqmotion.deploy import export_onnx
export_onnx(sm.load_pretrained("pancake-end"), "b")
''')
import subprocess
subprocess.run([sys.executable, "child.py"], check=False)
now = graphs("b")
try:
    OnnxStepper("b", sketches.straight((0.1, 0.0, 2.0), 150)).step()
    held(now in (old, new), "a mixed bundle loaded")
except ValueError as exc:
    held(now not in (old, new), f"a whole bundle refused: {exc}")
""")],
    11: [
        ("config_sha256 deleted and mu edited", """
shutil.copytree(sm.api.pretrained_dir("sliding"), "m")
config = json.loads(Path("m/config.json").read_text())
config.pop("config_sha256", None)
config["training"]["options"]["mu"] = 0.9
Path("m/config.json").write_text(json.dumps(config))
held(refused(sm.load, "m") is not None, "loaded with the edited mu")
"""),
        ("weights swapped, weights_sha256 deleted", """
shutil.copytree(sm.api.pretrained_dir("pancake"), "m")
shutil.copy(sm.api.pretrained_dir("pancake-end") / "model.safetensors", "m/model.safetensors")
config = json.loads(Path("m/config.json").read_text())
config.pop("weights_sha256", None)
from seqmotion.training.checkpoint import config_digest
config.pop("config_sha256", None)
config["config_sha256"] = config_digest(config)
Path("m/config.json").write_text(json.dumps(config))
held(refused(sm.load, "m") is not None, "loaded the swapped weights")
"""),
    ],
    12: [("runs/x/.lock is a symlink to a victim", """
Path("runs/x").mkdir(parents=True)
Path("victim.txt").write_text("precious")
os.symlink(os.path.abspath("victim.txt"), "runs/x/.lock")
rc, err = cli("train", "pancake", "--config", "tiny", "--max-steps", "1", "--out", "runs/x", "--quiet")
held(Path("victim.txt").read_text() == "precious" and rc == 2, f"rc {rc}, victim {Path('victim.txt').read_text()!r}")
""")],
    13: [
        ("plan(line, mu=1e300)", """
planner = sm.load_pretrained("sliding")
try:
    plan = planner.plan(commands.line(0.05, 500), mu=1e300)
    held(bool(plan.out_of_distribution), f"in distribution, end std {plan.uncertainty[-1]}")
except ValueError:
    held(True)
"""),
        ("plan(line, mu=5): beyond training", """
plan = sm.load_pretrained("sliding").plan(commands.line(0.05, 500), mu=5.0)
held(bool(plan.out_of_distribution), "in distribution")
"""),
    ],
    14: [("output_scale x1000, re-hashed", """
shutil.copytree(sm.api.pretrained_dir("pancake"), "m")
config = json.loads(Path("m/config.json").read_text())
config["model"]["output_scale"] = [1000 * s for s in config["model"]["output_scale"]]
from seqmotion.training.checkpoint import config_digest
config.pop("config_sha256", None)
config["config_sha256"] = config_digest(config)
Path("m/config.json").write_text(json.dumps(config))
try:
    limit = sm.load("m").generator(sketches.straight((0.1, 0.0, 2.0), 150)).contract()["stop"]["accel_limit"]
    held(False, f"loaded; stop accel_limit {limit}")
except ValueError:
    held(True)
""")],
}

# round 3: defect number → [(name, snippet)], one module a surface in hostile_round3/ (each an ATTEMPTS dict)
ROUND_3_PARTS = ("lerobot", "robots", "bundle", "results", "viewer")


def _round_3() -> dict[int, list[tuple[str, str]]]:
    import importlib.util

    attempts: dict[int, list[tuple[str, str]]] = {}
    for part in ROUND_3_PARTS:
        path = Path(__file__).resolve().parent / "hostile_round3" / f"{part}.py"
        spec = importlib.util.spec_from_file_location(f"hostile_round3_{part}", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        for defect, found in module.ATTEMPTS.items():
            attempts.setdefault(defect, []).extend(found)
    return dict(sorted(attempts.items()))


ROUND_3 = _round_3()
ROUNDS = {2: ROUND_2, 3: ROUND_3}


def limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (4 * 2**30, 4 * 2**30))


def attempt(snippet: str, src: Path, timeout: float) -> tuple[bool, str, float]:
    """Run one attempt: (held, what happened, seconds)."""
    with tempfile.TemporaryDirectory(prefix="hostile-") as folder:
        env = {**os.environ, "PYTHONPATH": str(src), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"),
               "PYTHONWARNINGS": "ignore"}
        start = time.perf_counter()
        try:
            done = subprocess.run([sys.executable, "-c", PRELUDE + textwrap.dedent(snippet)], cwd=folder, env=env,
                                  capture_output=True, text=True, timeout=timeout, preexec_fn=limit_memory)
        except subprocess.TimeoutExpired:
            return False, f"timeout after {timeout:.0f} s", time.perf_counter() - start
        seconds = time.perf_counter() - start
    lines = [line for line in done.stdout.splitlines() if line.startswith(("HELD", "DEFECT"))]
    if done.returncode == 0 and lines == ["HELD"]:
        return True, "held", seconds
    tail = (lines[-1] if lines else done.stderr.strip().splitlines()[-1:] or ["?"])
    return False, f"rc {done.returncode}: {tail if isinstance(tail, str) else tail[0]}"[:300], seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--src", type=Path, default=Path(__file__).resolve().parents[1] / "src")
    parser.add_argument("--round", type=int, choices=sorted(ROUNDS), action="append",
                        help="run this round's repros (repeatable; default: every round)")
    parser.add_argument("--timeout", type=float, default=180.0)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    rows = []
    for round_ in args.round or sorted(ROUNDS):
        for defect, attempts in ROUNDS[round_].items():
            for name, snippet in attempts:
                ok, what, seconds = attempt(snippet, args.src.resolve(), args.timeout)
                rows.append({"round": round_, "defect": defect, "attempt": name, "held": ok, "what": what,
                             "seconds": round(seconds, 1)})
                print(f"{'held  ' if ok else 'DEFECT'} {round_}#{defect:<2} {name:<55} {seconds:6.1f} s  "
                      f"{'' if ok else what}", flush=True)
    held = sum(r["held"] for r in rows)
    defects = sorted({f"{r['round']}#{r['defect']}" for r in rows if not r["held"]})
    print(f"{len(rows)} attempts, {held} held, {len(rows) - held} failed (defects {defects or 'none'})")
    if args.json:
        args.json.write_text(json.dumps({"src": str(args.src), "attempts": rows}, indent=1))


if __name__ == "__main__":
    main()
