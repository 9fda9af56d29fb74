"""Pancake motions made for a robot's rated limits, then executed on it in MuJoCo.

    python benchmarks/bench_robot_limits.py [--n 100] [--seed 2031] [--robots ur5e panda mh3f]
                                            [--out benchmarks/results_robot_limits.json]

Sets per robot, ``--n`` motions each:

* **turns**: README-style turn sketches, ``straight((y, z, θ), K)`` with θ ~ U(2, 3) rad, y, z ~ U(−0.2, 0.2) m and
  K ~ U(300, 800) samples (0.3–0.8 s) — :func:`turn_sketches`;
* **peer**: the whole-arm OCP peer's 20 sketches (``benchmarks/peers/arm_ocp.py``, its seed 0), for the side-by-side;
* **generator**: the task's own input generator, fresh position-type sketches (``tasks.pancake.data.position_type``, the
  chapter-2 inputs: ends up to ±0.3 m and ±π rad, 0.1–0.5 s).

Each is deformed by the shipped ``pancake`` model with ``deform(sketch, keep_end=True, robot=NAME)``: on an arm whose
placement turns the spatula with parallel joints (the UR5e) the polish keeps the rated joint speeds and ranges; on any
arm the result is judged (``result.robot_check``). Every motion called feasible is then executed on the robot's model
(``sim.run_pancake``, ch. 2 gains): it counts as **executable** when the pancake stays on through the motion and the
run's ``JointReport`` finds no limit broken (ranges, rated speeds, torque limits), and as **executable and exact**
when it also ends at the sketch's end pose (the polish converged; otherwise it ends at rest as near as the limits
allow, its end error recorded). A motion called feasible that
drops the pancake or breaks a limit when executed is a **false feasible** (the target is zero). Motions not called
feasible are counted by the binding limit their verdict names (a motion without a verdict would be silent). The
pancake's verdict itself runs the motion in MuJoCo where no limit is broken (``sim.pancake.check_pancake_executable``),
so a motion the polish made but the arm's tracking lost is flagged ``executed`` here rather than executed again;
those flags count how often the plan alone would have been wrong.
Times are wall seconds of ``deform`` (polish and verdict), per motion.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

import seqmotion as sm
from seqmotion.io import atomic_write_json
from seqmotion.training.provenance import machine_description


def turn_sketches(n: int, seed: int) -> list[np.ndarray]:
    """``n`` README-style turns: rest to rest from the origin to (y, z, θ), θ ~ U(2, 3) rad, y, z ~ U(−0.2, 0.2) m,
    over K ~ U(300, 800) samples at 1 ms."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        end = (rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(2.0, 3.0))
        out.append(sm.tasks.pancake.data.straight(end, int(rng.integers(300, 801))))
    return out


def generator_sketches(n: int, seed: int) -> list[np.ndarray]:
    """``n`` fresh position-type sketches of the chapter-2 input generator, each cut to its own length."""
    batch = sm.tasks.pancake.data.position_type(n, np.random.default_rng(seed))
    return [batch.states[i, : int(batch.lengths[i])] for i in range(n)]


def _binding(check: object) -> str | None:
    """The kind of limit a verdict names; ``"executed"`` where no limit is broken but the verdict's own simulated run
    lost the pancake or left the workspace (``ExecutionCheck.lost``)."""
    if check.lost is not None and (check.binding is None or check.binding.share <= 1.0):
        return "executed"
    return None if check.binding is None else check.binding.kind


def peer_sketches(n: int) -> list[np.ndarray]:
    """The whole-arm OCP peer's own ``n`` turn sketches (``benchmarks/peers/arm_ocp.py --n 20 --seed 0``): the same
    motions, for success and time side by side."""
    sys.path.insert(0, str(Path(__file__).parent / "peers"))
    from arm_ocp import turn_sketches as peer_turns

    return peer_turns(n, 0)


def one(deformer: object, sketch: np.ndarray, robot: str, execute: bool) -> dict:
    from seqmotion import sim

    started = time.perf_counter()
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        result = deformer.deform(sketch, keep_end=True, robot=robot)
    seconds = time.perf_counter() - started
    check = result.robot_check
    length = len(result.states) if result.length is None else int(result.length)
    row = {
        "seconds": seconds, "exact": bool(result.exact), "feasible": bool(result.feasible),
        "verdict": None if check.ok is None else bool(check.ok),
        "binding": _binding(check), "lost": check.lost,
        "binding_joint": None if check.binding is None else check.binding.joint,
        "duration_s": (length - 1) * 1e-3, "sketch_s": (len(sketch) - 1) * 1e-3,
        "speed_share_max": None if check.speed_share is None else float(np.max(check.speed_share)),
        "torque_share_max": None if check.torque_share is None else float(np.max(check.torque_share)),
        "warned": [str(w.message)[:160] for w in said if issubclass(w.category, RuntimeWarning)],
        "iterations": None if result.polish_iterations is None else int(result.polish_iterations),
        "end_error_m": float(np.asarray(result.errors["end_position_error_m"]).reshape(-1)[0]),
        "end_error_rad": float(np.asarray(result.errors["end_attitude_error_rad"]).reshape(-1)[0]),
    }
    if execute and result.feasible:
        run = sim.run_pancake(result.states[:length], gains="ch2", robot=None if robot == "mh3f" else robot)
        j = run.joints
        row |= {"kept": not run.contact_lost, "limits_ok": j is None or j.problem is None,
                "run_problem": None if j is None else j.problem,
                "run_torque_share_max": None if j is None or j.torque_share is None else float(np.max(j.torque_share)),
                "run_speed_share_max": None if j is None or j.speed_share is None else float(np.max(j.speed_share))}
        row["executable"] = bool(row["kept"] and row["limits_ok"] and row["verdict"] is True)
    return row


def summarise(rows: list[dict]) -> dict:
    seconds = np.array([r["seconds"] for r in rows])
    feasible = [r for r in rows if r["feasible"]]
    ran = [r for r in feasible if "kept" in r]
    flagged = [r for r in rows if not r["feasible"]]
    return {
        "n": len(rows), "exact": sum(r["exact"] for r in rows), "called_feasible": len(feasible),
        "executable": sum(r.get("executable", False) for r in rows),
        "executable_and_exact": sum(r.get("executable", False) and r["exact"] for r in rows),
        "inexact_end_error_median_m": float(np.median([r["end_error_m"] for r in rows if not r["exact"]] or [0.0])),
        "inexact_end_error_median_rad": float(np.median([r["end_error_rad"] for r in rows if not r["exact"]] or [0.0])),
        "false_feasible": sum(not (r["kept"] and r["limits_ok"]) for r in ran),
        "feasible_but_verdict_unknown": sum(r["verdict"] is None for r in feasible),
        "flagged": len(flagged),
        "flagged_by": dict(Counter(f"{r['binding']}:{r['binding_joint']}" for r in flagged)),
        # called feasible without a verdict that it is executable and without a warning saying why not
        "silent": sum(r["feasible"] and r["verdict"] is not True and not r["warned"] for r in rows),
        "kept_when_executed": sum(r.get("kept", False) for r in rows),
        "seconds_median": float(np.median(seconds)), "seconds_p95": float(np.percentile(seconds, 95)),
        "duration_median_s": float(np.median([r["duration_s"] for r in rows])),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100)
    parser.add_argument("--seed", type=int, default=2031)
    parser.add_argument("--robots", nargs="+", default=["ur5e", "panda", "mh3f"])
    parser.add_argument("--sets", nargs="+", default=["turns", "generator"])
    parser.add_argument("--no-execute", action="store_true", help="only the verdicts, no MuJoCo runs")
    parser.add_argument("--out", default="benchmarks/results_robot_limits.json")
    args = parser.parse_args()
    deformer = sm.load_pretrained("pancake")
    sets = {"turns": lambda: turn_sketches(args.n, args.seed),
            "generator": lambda: generator_sketches(args.n, args.seed), "peer": lambda: peer_sketches(args.n)}
    out: dict = {"machine": machine_description(), "n": args.n, "seed": args.seed, "results": {}}
    for robot in args.robots:
        for name in args.sets:
            rows = []
            for i, sketch in enumerate(sets[name]()):
                rows.append(one(deformer, sketch, robot, not args.no_execute))
                print(robot, name, i, {k: v for k, v in rows[-1].items() if k != "warned"}, flush=True)
                if (i + 1) % 10 == 0:
                    print(f"{robot} {name}: {i + 1}/{args.n}", summarise(rows), flush=True)
            out["results"][f"{robot}/{name}"] = {"summary": summarise(rows), "rows": rows}
            print(robot, name, json.dumps(summarise(rows)), flush=True)
            atomic_write_json(args.out, out)


if __name__ == "__main__":
    main()
