"""Chapter 2, reproduced: Figs. 2.5–2.7, the held-out table, and (with MuJoCo) Figs. 2.8–2.10.

``seqmotion reproduce ch2 [--model RUN] [--out DIR]`` writes:

* ``fig2_5_deformation.png`` — nine S-curve motions from the origin to y, z ∈ {0, ±0.2} m,
  θ = 2.5 rad: original dashed, deformed solid;
* ``fig2_6_psi.png`` — ψ of the (0.2, 0, 2.5) motion before/after, against the cone band;
* ``fig2_7_deformation_amount.png`` — deformed minus original, per coordinate;
* ``table2_heldout.md`` / ``.json`` — over fresh position-type inputs: share fully feasible
  (max F_c ≤ 0.01 rad), max and mean F_c, shape error (RMSE of D·position, input vs output)
  and end-pose error, for the inputs and for the deformed outputs; deformation speed;
* with the simulated robot: ``fig2_8_tracking.png``, ``fig2_9_psi_robot.png``,
  ``fig2_10_snapshots.png`` (see :mod:`seqmotion.sim`).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from ..io import atomic_write_text, pyplot, save_figure
from ..physics.integrator import implied_accel
from ..tasks.pancake import FEASIBLE_TOLERANCE, THETA_WEIGHT, Deformer, physics
from ..tasks.pancake import data as inputs

FIG25_TARGETS = [(y, z, 2.5) for y in (-0.2, 0.0, 0.2) for z in (-0.2, 0.0, 0.2)]
FIG26_TARGET = (0.2, 0.0, 2.5)
FIG_LENGTH = 500
D_WEIGHTS = np.array([1.0, 1.0, THETA_WEIGHT])


def load_deformer(model: str | None) -> Deformer:
    """The shipped deformer, or the one at ``model`` (a shipped name or a model/run directory)."""
    from ..api import resolve_model

    return resolve_model(model or "pancake", "pancake")


def heldout_metrics(deformer: Deformer, n: int, seed: int) -> dict:
    """Deform ``n`` fresh position-type inputs (K ∈ [100, 500]) and score inputs and outputs."""
    # Training draws from default_rng([seed, step]); this stream (a single int seed far away
    # from those) gives inputs the model never saw.
    batch = inputs.position_type(n, np.random.default_rng(7_000_000 + seed))
    rows = {"input": [], "output": []}
    seconds = 0.0
    for b in range(n):
        x = batch.states[b, : batch.lengths[b]]
        start = time.perf_counter()
        r = deformer.deform(x)
        seconds += time.perf_counter() - start
        fc_in = physics.violation_of_states(x, deformer.options.mu)
        for name, states, fc in (("input", x, fc_in), ("output", r.states, r.violation)):
            d_err = (states[:, :3] - x[:, :3]) * D_WEIGHTS
            rows[name].append(
                {
                    "max_fc": float(fc.max()),
                    "mean_fc": float(fc.mean()),
                    "shape_rmse": float(np.sqrt((d_err**2).sum(1).mean())),
                    "end_pos_mm": float(1000 * np.linalg.norm(states[-1, :2] - x[-1, :2])),
                    "end_theta_deg": float(np.degrees(abs(states[-1, 2] - x[-1, 2]))),
                    "end_d_error": float(np.linalg.norm(d_err[-1])),
                }
            )
    summary = {}
    for name, items in rows.items():
        arr = {k: np.array([it[k] for it in items]) for k in items[0]}
        summary[name] = {
            "feasible_share": float((arr["max_fc"] <= FEASIBLE_TOLERANCE).mean()),
            "max_fc_rad": float(arr["max_fc"].max()),
            "mean_max_fc_rad": float(arr["max_fc"].mean()),
            "mean_fc_rad": float(arr["mean_fc"].mean()),
            "shape_rmse_D": float(arr["shape_rmse"].mean()),
            "end_position_error_mm": float(arr["end_pos_mm"].mean()),
            "end_attitude_error_deg": float(arr["end_theta_deg"].mean()),
            "end_pose_error_D": float(arr["end_d_error"].mean()),
        }
    summary["n"] = n
    summary["seconds_per_trajectory"] = seconds / n
    summary["mean_length"] = float(batch.lengths.mean())
    return summary


def _table(summary: dict) -> str:
    lines = [
        f"Held-out position-type inputs: n = {summary['n']}, K ∈ [100, 500] (mean {summary['mean_length']:.0f}).",
        "",
        "| | fully feasible (max F_c ≤ 0.01 rad) | max F_c [rad] | mean of max F_c [rad] | mean F_c [rad] "
        "| shape RMSE of D·p | end position error [mm] | end attitude error [deg] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name in ("input", "output"):
        s = summary[name]
        lines.append(
            f"| {name} | {100 * s['feasible_share']:.1f} % | {s['max_fc_rad']:.4f} | {s['mean_max_fc_rad']:.4f} "
            f"| {s['mean_fc_rad']:.5f} | {s['shape_rmse_D']:.4f} | {s['end_position_error_mm']:.2f} "
            f"| {s['end_attitude_error_deg']:.2f} |"
        )
    ms = 1000 * summary["seconds_per_trajectory"]
    lines += ["", f"Deformation time: {ms:.2f} ms per trajectory (one at a time)."]
    return "\n".join(lines) + "\n"


def figures(deformer: Deformer, out: Path) -> dict:
    plt = pyplot()

    originals = np.stack([inputs.straight(t, FIG_LENGTH) for t in FIG25_TARGETS])
    deformed = deformer.deform(originals)
    colors = plt.cm.viridis(np.linspace(0, 0.9, len(FIG25_TARGETS)))
    red = FIG25_TARGETS.index(FIG26_TARGET)
    colors[red] = (0.85, 0.1, 0.1, 1.0)

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for i in range(len(FIG25_TARGETS)):
        axes[0].plot(originals[i, :, 0], originals[i, :, 1], "--", color=colors[i], lw=1)
        axes[0].plot(deformed.states[i, :, 0], deformed.states[i, :, 1], "-", color=colors[i], lw=1.6)
        t = np.arange(FIG_LENGTH)
        axes[1].plot(t, originals[i, :, 2], "--", color=colors[i], lw=1)
        axes[1].plot(t, deformed.states[i, :, 2], "-", color=colors[i], lw=1.6)
    axes[0].set(xlabel="y [m]", ylabel="z [m]", title="Fig. 2.5: paths (dashed original, solid deformed)")
    axes[0].set_aspect("equal", adjustable="datalim")
    axes[1].set(xlabel="time [ms]", ylabel="θ [rad]", title="attitude")
    fig.tight_layout()
    save_figure(fig, out / "fig2_5_deformation.png", dpi=130, close=True)

    x, r = originals[red], deformer.deform(originals[red])
    psi_in = physics.psi(x[:-1], implied_accel(x))
    fig, ax = plt.subplots(figsize=(7, 3.5))
    t = np.arange(FIG_LENGTH - 1)
    cone = deformer.options.cone_half_angle  # the μ this model was trained and is judged at
    ax.axhspan(-cone, cone, color="tab:blue", alpha=0.15,
               label=f"friction cone |ψ| < atan μ, μ = {deformer.options.mu:g}")
    ax.plot(t, psi_in, "--", color="gray", label="original")
    ax.plot(t, r.psi, "-", color="tab:red", label="deformed")
    ax.set(xlabel="time [ms]", ylabel="ψ = arg(g − u) − θ [rad]", ylim=(-math.pi, math.pi),
           title="Fig. 2.6: the (0.2, 0, 2.5) motion")
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    save_figure(fig, out / "fig2_6_psi.png", dpi=130, close=True)

    fig, ax = plt.subplots(figsize=(7, 3.5))
    for i, (name, unit) in enumerate((("y", "m"), ("z", "m"), ("θ", "rad"))):
        ax.plot(np.arange(FIG_LENGTH), r.states[:, i] - x[:, i], label=f"Δ{name} [{unit}]")
    ax.set(xlabel="time [ms]", ylabel="deformed − original", title="Fig. 2.7: amount of deformation")
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, out / "fig2_7_deformation_amount.png", dpi=130, close=True)
    return {
        "fig2_5_max_fc_deformed": float(deformed.violation.max()),
        "fig2_5_max_fc_original": float(physics.violation_of_states(originals).max()),
    }


def robot(deformer: Deformer, out: Path) -> dict:
    """Figs. 2.8–2.10: the Fig. 2.6 motion executed by the simulated arm (PD + DOB, ch. 2 gains).

    Our model deforms the Fig. 2.6 sketch downwards, out of the 0.53 m arm's reach; then the
    nearest target whose deformed motion the arm can execute is used instead (and recorded).
    """
    from .. import sim

    for target in (FIG26_TARGET, (FIG26_TARGET[0], 0.1, FIG26_TARGET[2]), (FIG26_TARGET[0], 0.2, FIG26_TARGET[2])):
        x = inputs.straight(target, FIG_LENGTH)
        r = deformer.deform(x)
        problem = sim.workspace_problem(sim.planar_reference(r.states), "pancake")
        if problem is None:
            break
    else:
        raise ValueError(f"no deformed Fig. 2.6-like motion fits the arm's workspace: {problem}")
    mu = deformer.options.mu  # the executed cone is judged at the model's μ
    original = sim.run_pancake(x, gains="ch2", mu=mu)
    result = sim.run_pancake(r.states, gains="ch2", snapshots=out / "fig2_10_snapshots.png", mu=mu)
    sim.plot_pancake_tracking(r.states, result, out / "fig2_8_tracking.png", original=x)
    sim.plot_pancake_psi(r, result, out / "fig2_9_psi_robot.png")
    return {"robot_target": list(target), "robot_deformed": result.summary(), "robot_original": original.summary()}


def run(out: Path, model: str | None = None, quick: bool = False, seed: int = 0) -> dict:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    deformer = load_deformer(model)
    results = figures(deformer, out)
    summary = heldout_metrics(deformer, 50 if quick else 500, seed)
    results["heldout"] = summary
    atomic_write_text(out / "table2_heldout.md", _table(summary))
    try:
        results.update(robot(deformer, out))
    except (ImportError, ValueError) as exc:  # no MuJoCo, or a motion the arm cannot execute
        results["robot_skipped"] = str(exc)
    atomic_write_text(out / "results.json", json.dumps(results, indent=2))
    print(_table(summary))
    return results
