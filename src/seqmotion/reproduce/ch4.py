"""Chapter 4, reproduced: latent optimisation against the dissertation's figures and a solver peer.

``seqmotion reproduce ch4 [--model RUN] [--out DIR] [--quick]`` writes:

* ``fig4_2_objective.png`` — mean J1 per update with 95 % bands for cases 1, 2, 3 over the 27
  targets (y, z ∈ {−0.1, 0, 0.1} m, θ ∈ {−π, 0, π}; S-curve inputs, K = 500; 100 updates) by
  Levenberg–Marquardt with penalty continuation, beside plain gradient descent (eq. 4.2) with a
  line search and with the dissertation's η = 200, 200, 1000 (see :data:`METHODS`);
* ``fig4_3_theta_-pi.png``, ``fig4_4_theta_0.png``, ``fig4_5_theta_pi.png`` — case-1 results:
  time–position, y–z paths with targets, ψ against the cone;
* ``fig4_6_end_rmse.png`` and ``table4_end_rmse.md`` — end-position and end-attitude RMSE per case;
* ``fig4_8_j2_velocity.png``, ``fig4_9_j2_psi.png`` — the J2 study at updates 0, 10, 20;
* ``table4_timing.md`` — seconds per update per case (one trajectory, and all 27 in a batch);
* with CasADi: ``table4_peer.md`` — IPOPT by direct transcription vs latent optimisation;
* with MuJoCo: ``fig4_10_robot.png``, ``fig4_11_snapshots.png`` — the J2 motion on the arm.
"""

from __future__ import annotations

import importlib.util
import json
import math
import time
from pathlib import Path

import numpy as np

from ..data import pancake as inputs
from ..latent import optimize_latent, optimize_trajectory
from ..latent.objectives import EndPose, Ranges
from ..tasks.pancake import FEASIBLE_TOLERANCE, Deformer
from ..training.checkpoint import atomic_write_text, save_figure
from ..training.files import write_arrays
from .ch2 import load_deformer

TARGETS = np.array([(y, z, t) for y in (-0.1, 0.0, 0.1) for z in (-0.1, 0.0, 0.1) for t in (-math.pi, 0.0, math.pi)])
LENGTH = 500
CASES = {  # name: (how, the dissertation's step size η, §4.3.2)
    "case 1 (encoder z)": ("encoder", 200.0),
    "case 2 (random z)": ("random", 200.0),
    "case 3 (accelerations)": ("trajectory", 1000.0),
}
# How each case is optimised. "lm" (ours, the figures' solid lines): Levenberg–Marquardt on the
# end-pose residuals with the friction-cone penalty continued from weight 1e-3 to 1 over the first
# 4 updates. "line search": the dissertation's plain gradient descent (eq. 4.2) with η found by
# Armijo backtracking per trajectory. "dissertation η": eq. 4.2 with the fixed η above, which only
# means something in the dissertation's latent units (on ours it can diverge).
METHODS = ("lm", "line search", "dissertation η")
CONTINUATION = (1e-3, 4)


def starts(targets: np.ndarray = TARGETS) -> np.ndarray:
    """S-curve inputs from the origin to each target (eq. 4.8's trajectories), ``(N, K, 6)``."""
    return np.stack([inputs.straight(t, LENGTH) for t in targets])


def run_case(
    deformer: Deformer, case: str, method: str, steps: int, targets: np.ndarray = TARGETS, seed: int = 0
):
    """Run one of :data:`CASES` with one of :data:`METHODS` on ``targets``."""
    how, eta = CASES[case]
    x = starts(targets)
    objective = EndPose(targets)
    if method == "lm":
        kwargs: dict = {"optimizer": "lm", "continuation": CONTINUATION}
    elif method == "line search":
        kwargs = {"lr": "auto"}
    elif method == "dissertation η":
        kwargs = {"lr": eta}
    else:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if how == "trajectory":
        return optimize_trajectory(deformer, x, objective, steps=steps, **kwargs)
    return optimize_latent(deformer, x, objective, steps=steps, init=how, seed=seed, **kwargs)


def end_errors(states: np.ndarray, targets: np.ndarray = TARGETS) -> tuple[np.ndarray, np.ndarray]:
    """End-position error [mm] and end-attitude error [deg] per target."""
    pos = 1000 * np.linalg.norm(states[:, -1, :2] - targets[:, :2], axis=1)
    att = np.degrees(np.abs(states[:, -1, 2] - targets[:, 2]))
    return pos, att


def _band(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = values.mean(1)
    half = 1.96 * values.std(1, ddof=1) / math.sqrt(values.shape[1])
    return mean, half


def figures_cases(runs: dict[str, dict], out: Path, mu: float) -> None:
    """Figs. 4.2–4.6 from ``runs[method][case]``: the first method is drawn with bands and paths;
    the cone band is ±atan μ of the model's own μ."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    results = runs[next(iter(runs))]
    fig, ax = plt.subplots(figsize=(7, 4))
    for name, res in results.items():
        mean, half = _band(res.history)
        steps = np.arange(len(mean))
        line = ax.plot(steps, np.clip(mean, 1e-16, None), label=f"{name}, Levenberg–Marquardt")[0]
        ax.fill_between(steps, np.maximum(mean - half, 1e-16), mean + half, alpha=0.2, color=line.get_color())
        for method, style in (("line search", ":"), ("dissertation η", "--")):
            if name in runs.get(method, {}):
                label = "gradient descent, η by line search" if method == "line search" else \
                    f"the dissertation's η = {CASES[name][1]:g}"
                ax.plot(steps, np.clip(runs[method][name].history.mean(1), 1e-16, None), style,
                        color=line.get_color(), lw=1, label=f"{name}, {label}")
    ax.axhline(1e-3, color="gray", ls=":", lw=1)
    ax.set(yscale="log", xlabel="update", ylabel="J1 (mean of 27 targets)", title="Fig. 4.2: progress of the objective")
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, out / "fig4_2_objective.png", dpi=130)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(8, 3.5))
    names = list(results)
    for i, name in enumerate(names):
        pos, att = end_errors(results[name].states)
        for ax, err in zip(axes, (pos, att), strict=True):
            rmse = math.sqrt((err**2).mean())
            ax.bar(i, rmse, color=f"C{i}")
    axes[0].set(ylabel="end-position RMSE [mm]", xticks=range(3), xticklabels=["1", "2", "3"], xlabel="case")
    axes[1].set(ylabel="end-attitude RMSE [deg]", xticks=range(3), xticklabels=["1", "2", "3"], xlabel="case")
    fig.suptitle("Fig. 4.6: end-pose errors after 100 updates")
    fig.tight_layout()
    save_figure(fig, out / "fig4_6_end_rmse.png", dpi=130)
    plt.close(fig)

    res = results[names[0]]
    psi = _psi(res.states, res.accel)
    for theta, label, fname in ((-math.pi, "-π", "fig4_3_theta_-pi.png"), (0.0, "0", "fig4_4_theta_0.png"),
                                (math.pi, "π", "fig4_5_theta_pi.png")):
        idx = np.flatnonzero(np.isclose(TARGETS[:, 2], theta))
        fig, axes = plt.subplots(1, 3, figsize=(14, 3.8))
        t = np.arange(LENGTH)
        for i in idx:
            for j, style in enumerate(("-", "--", ":")):
                axes[0].plot(t, res.states[i, :, j], style, lw=0.8, color=f"C{j}")
            axes[1].plot(res.states[i, :, 0], res.states[i, :, 1], lw=1)
            axes[1].plot(*TARGETS[i, :2], "kx")
            axes[2].plot(t[:-1], psi[i], lw=0.8)
        axes[0].set(xlabel="time [ms]", ylabel="y, z [m] (–, --), θ [rad] (:)", title="(a) time–position")
        axes[1].set(xlabel="y [m]", ylabel="z [m]", title="(b) paths; × targets")
        axes[1].set_aspect("equal", adjustable="datalim")
        axes[2].axhspan(-math.atan(mu), math.atan(mu), color="tab:blue", alpha=0.15, label=f"cone, μ = {mu:g}")
        axes[2].set(xlabel="time [ms]", ylabel="ψ [rad]", ylim=(-math.pi, math.pi), title="(c) cone angle")
        fig.suptitle(f"Case 1 after 100 updates, final attitude {label}")
        fig.tight_layout()
        save_figure(fig, out / fname, dpi=120)
        plt.close(fig)


def _psi(states: np.ndarray, accel: np.ndarray) -> np.ndarray:
    from ..physics import pancake

    return pancake.psi(states[..., :-1, :], accel)


def j2_study(deformer: Deformer, out: Path) -> dict:
    """§4.4.2: J2 from a uniform motion to (0, 0, −3π/4) in 0.5 s, η = 100, updates 0, 10, 20."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = inputs.straight((0.0, 0.0, -3 * math.pi / 4), LENGTH, timing="linear")
    objective = Ranges()
    snapshots = {0: optimize_latent(deformer, x, objective, steps=0)}
    full = optimize_latent(deformer, x, objective, steps=20)  # η by line search
    for upto in (10, 20):
        # the state after `upto` updates: rerun (the line search's η sequence is deterministic)
        snapshots[upto] = full if upto == 20 else optimize_latent(deformer, x, objective, steps=upto)
    fixed = optimize_latent(deformer, x, objective, steps=20, lr=100.0)  # the dissertation's η
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    fig2, ax2 = plt.subplots(figsize=(7, 3.5))
    t = np.arange(LENGTH)
    for k, (update, res) in enumerate(snapshots.items()):
        for j, style in enumerate(("-", "--", ":")):
            axes[0].plot(t, res.states[:, j], style, color=f"C{k}", lw=1, label=f"update {update}" if j == 0 else None)
            axes[1].plot(t, res.states[:, 3 + j], style, color=f"C{k}", lw=1)
        ax2.plot(t[:-1], _psi(res.states, res.accel), color=f"C{k}", label=f"update {update}")
    axes[0].set(xlabel="time [ms]", ylabel="y, z [m], θ [rad]", title="(a) time–position")
    axes[1].set(xlabel="time [ms]", ylabel="v_y, v_z [m/s], v_θ [rad/s]", title="(b) time–velocity")
    axes[0].legend(fontsize=8)
    fig.suptitle("Fig. 4.8: optimising J2")
    fig.tight_layout()
    save_figure(fig, out / "fig4_8_j2_velocity.png", dpi=120)
    cone = deformer.options.cone_half_angle
    ax2.axhspan(-cone, cone, color="tab:blue", alpha=0.15, label=f"cone, μ = {deformer.options.mu:g}")
    ax2.set(xlabel="time [ms]", ylabel="ψ [rad]", ylim=(-math.pi, math.pi), title="Fig. 4.9: ψ while optimising J2")
    ax2.legend(fontsize=8)
    fig2.tight_layout()
    save_figure(fig2, out / "fig4_9_j2_psi.png", dpi=120)
    plt.close(fig)
    plt.close(fig2)
    final = snapshots[20]
    write_arrays(out / "j2_trajectory.npz",
                 {"states": final.states, "accel": final.accel, "latent": final.latent})
    return {
        f"update_{u}": {
            "J2": float(r.history[-1]),
            "max_speed_yz": float(np.abs(r.states[:, 3:5]).max()),
            "max_speed_theta": float(np.abs(r.states[:, 5]).max()),
            "max_fc": float(_fc(r.states, r.accel, deformer.options.mu).max()),
            "end": r.states[-1, :3].tolist(),
        }
        for u, r in snapshots.items()
    } | {"final_states": final.states, "dissertation_eta_100_final_J2": float(fixed.history[-1])}


def _fc(states: np.ndarray, accel: np.ndarray, mu: float) -> np.ndarray:
    from ..physics import pancake

    return pancake.violation(states[..., :-1, :], accel, mu)


def timing(deformer: Deformer) -> dict:
    """Seconds per update for one K = 500 trajectory and for all 27 in one batch, per case and method.

    A fixed step is one forward and one backward pass (the dissertation's update); the line
    search adds forward passes when it backtracks; Levenberg–Marquardt takes one backward pass
    per residual (3) and a forward pass per damping trial.
    """
    out = {}
    for name in CASES:
        row = {}
        for method in METHODS:
            try:
                one = run_case(deformer, name, method, 10, TARGETS[:1])
                batch = run_case(deformer, name, method, 10)
            except ValueError:  # a fixed η that diverges within 10 updates has no time per update
                continue
            row[method] = {"one_trajectory_s": one.seconds_per_update, "batch_of_27_s": batch.seconds_per_update}
        out[name] = row
    return out


def peer(deformer: Deformer, targets: np.ndarray, threshold: float = 1e-3) -> list[dict]:
    """IPOPT by direct transcription against case 1, target by target, timed in the same run."""
    from ..latent.transcription import solve_end_pose

    rows = []
    for target in targets:
        start = time.perf_counter()
        res = run_case(deformer, "case 1 (encoder z)", "lm", 100, target[None])
        total = time.perf_counter() - start
        history = res.history[:, 0]  # (updates + 1,) of this one target
        reached = np.flatnonzero(history < threshold)
        latent_time = None
        if reached.size:  # time a fresh run that stops at the first update below the threshold
            start = time.perf_counter()
            run_case(deformer, "case 1 (encoder z)", "lm", int(reached[0]), target[None])
            latent_time = time.perf_counter() - start
        ipopt = solve_end_pose(tuple(target), threshold=threshold, mu=deformer.options.mu)
        rows.append({
            "target": target.tolist(),
            "latent_seconds_to_threshold": latent_time,
            "latent_final_j1": float(history[-1]),
            "latent_max_fc": float(_fc(res.states, res.accel, deformer.options.mu).max()),
            "latent_total_seconds_100_updates": total,
            "ipopt_seconds_to_threshold": ipopt.seconds_to_threshold,
            "ipopt_final_j1": ipopt.j1,
            "ipopt_max_fc": ipopt.max_fc,
            "ipopt_solve_seconds": ipopt.solve_seconds,
            "ipopt_status": ipopt.status,
        })
    return rows


def _peer_table(rows: list[dict]) -> str:
    def fmt(v: float | None) -> str:
        return "never" if v is None else f"{v:.3g}"

    lines = [
        "| target (y, z, θ) | latent: s to J1<1e-3 | latent final J1 | latent max F_c | IPOPT: s to J1<1e-3 "
        "| IPOPT final J1 | IPOPT max F_c | IPOPT status |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        t = ", ".join(f"{v:.2f}" for v in r["target"])
        lines.append(
            f"| {t} | {fmt(r['latent_seconds_to_threshold'])} | {r['latent_final_j1']:.2e} | {r['latent_max_fc']:.4f} "
            f"| {fmt(r['ipopt_seconds_to_threshold'])} | {r['ipopt_final_j1']:.2e} | {r['ipopt_max_fc']:.4f} "
            f"| {r['ipopt_status']} |"
        )
    return "\n".join(lines) + "\n"


def robot(final_states: np.ndarray, out: Path, mu: float) -> dict:
    """Figs. 4.10–4.11: the J2 motion on the simulated arm (PD + DOB, ch. 4 gains, 2 Hz DOB), judged at ``mu``."""
    from .. import sim

    result = sim.run_pancake(final_states, gains="ch4", snapshots=out / "fig4_11_snapshots.png", mu=mu)
    sim.plot_pancake_tracking(final_states, result, out / "fig4_10_robot.png")
    return result.summary()


def run(out: Path, model: str | None = None, quick: bool = False, seed: int = 0) -> dict:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    deformer = load_deformer(model)
    steps = 20 if quick else 100
    runs: dict[str, dict] = {method: {} for method in METHODS}
    diverged = {}
    for method in METHODS:
        for name in CASES:
            try:
                runs[method][name] = run_case(deformer, name, method, steps, seed=seed)
            except ValueError as exc:  # a fixed step blew the objective up to NaN/inf
                diverged[f"{name}, {method}"] = str(exc)
    figures_cases(runs, out, deformer.options.mu)

    summary: dict = {"methods": {}, "diverged": diverged, "continuation": CONTINUATION}
    lines = ["| case | method | mean J1 at update 5 | mean J1 at the end | end-position RMSE [mm] "
             "| end-attitude RMSE [deg] | outputs with max F_c ≤ 0.01 rad |", "|---|---|---|---|---|---|---|"]
    for method, results in runs.items():
        summary["methods"][method] = {}
        for name, res in results.items():
            pos, att = end_errors(res.states)
            fc = _fc(res.states, res.accel, deformer.options.mu).max(axis=1)
            row = {
                "mean_j1_by_update": res.history.mean(1).tolist(),
                "end_position_rmse_mm": float(math.sqrt((pos**2).mean())),
                "end_attitude_rmse_deg": float(math.sqrt((att**2).mean())),
                "feasible_share": float((fc <= FEASIBLE_TOLERANCE).mean()),
                "max_fc": float(fc.max()),
            }
            summary["methods"][method][name] = row
            label = f"η = {CASES[name][1]:g}" if method == "dissertation η" else method
            lines.append(
                f"| {name} | {label} | {res.history[min(5, steps)].mean():.2e} | {res.history[-1].mean():.2e} "
                f"| {row['end_position_rmse_mm']:.3f} | {row['end_attitude_rmse_deg']:.3f} "
                f"| {100 * row['feasible_share']:.0f} % |"
            )
    atomic_write_text(out / "table4_end_rmse.md", "\n".join(lines) + "\n")

    j2 = j2_study(deformer, out)
    final_states = j2.pop("final_states")
    summary["j2"] = j2
    summary["timing"] = timing(deformer)
    timing_lines = ["| case | method | s/update, one K = 500 trajectory | s/update, 27 targets in one batch |",
                    "|---|---|---|---|"]
    for name, rows in summary["timing"].items():
        for label, t in rows.items():
            timing_lines.append(f"| {name} | {label} | {t['one_trajectory_s']:.4f} | {t['batch_of_27_s']:.4f} |")
    atomic_write_text(out / "table4_timing.md", "\n".join(timing_lines) + "\n")

    if quick:  # IPOPT needs minutes per hard target: the quick smoke test leaves it out
        summary["peer_skipped"] = "quick mode"
    elif importlib.util.find_spec("casadi") is None:
        summary["peer_skipped"] = "CasADi is not installed (pip install 'seqmotion[peer]')"
    else:
        summary["peer"] = rows = peer(deformer, TARGETS)
        atomic_write_text(out / "table4_peer.md", _peer_table(rows))
    try:
        summary["robot_j2"] = robot(final_states, out, deformer.options.mu)
    except (ImportError, ValueError) as exc:  # no MuJoCo, or a motion the arm cannot execute
        summary["robot_skipped"] = str(exc)
    atomic_write_text(out / "results.json", json.dumps(summary, indent=2))
    print((out / "table4_end_rmse.md").read_text())
    print((out / "table4_timing.md").read_text())
    return summary
