"""Chapter 3, reproduced: models A, B, C on the 2-D physics, across unseen friction, and on the arm.

``seqmotion reproduce ch3 [--model DIR] [--out DIR] [--quick]`` uses the shipped models
``sliding`` (A, the shipped planner), ``sliding-A-nominal`` (A trained at the nominal friction
only, the dissertation's protocol), ``sliding-A-velocity`` (A trained on the same drifting
pan shaking as B and C), ``sliding-B`` and ``sliding-C`` — all five on one equal budget
(50 epochs × 128 × 64 trajectories), the comparison of §3.5.2 — or, with ``--model DIR``, the
run directories ``DIR/A``, ``DIR/B``, ``DIR/C`` (and ``DIR/A-nominal``, ``DIR/A-velocity`` if
present) — and writes:

* ``fig3_7_paths.png`` — object and pan paths of A, B, C for one command (K = 1200);
* ``fig3_10_friction.png`` and ``table3_friction.md`` — reproduction RMSE of A, B, C over a
  grid of friction pairs none of them saw (μ ∈ {0.7, 0.9, 1.1, 1.3}, μ' ∈ {0.3, 0.4, 0.6, 0.7},
  μ' < μ; 10 B-spline commands each), beside the RMSE of leaving the object where it is;
* ``table3_range.md`` — the pan's range of motion and the training budget per model;
* ``table3_qualitative.md`` — Fig. 3.7's reading, measured at the training friction over the
  same commands: how far each model moves the object, how well, and how far its pan goes;
* ``table3_speed.md`` — generation speed (samples/s) of the shipped model;
* with MuJoCo: ``fig3_8_robot.png``, ``fig3_9_snapshots_{A,B,C}.png`` — the Fig. 3.7 command
  executed by the simulated arm.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..data.trajectories import tracking_rmse
from ..io import atomic_write_text, pyplot, save_figure
from ..tasks.sliding import PAN_LIMIT, SlidingPlanner
from ..tasks.sliding import data as commands

FRICTION_GRID = [(mu, mud) for mu in (0.7, 0.9, 1.1, 1.3) for mud in (0.3, 0.4, 0.6, 0.7) if mud < mu]
LENGTH = 1200
MODELS = ("A", "B", "C")
OPTIONAL_MODELS = ("A-nominal", "A-velocity")  # variants of A shipped beside it


def load_models(model: str | None) -> dict[str, SlidingPlanner]:
    """The shipped A, A-nominal, A-velocity, B, C, or the run directories ``DIR/{A,[A-nominal,A-velocity,]B,C}``."""
    import seqmotion as sm

    if model is None:
        return {"A": sm.load_pretrained("sliding"), **{name: sm.load_pretrained(f"sliding-{name}") for name in
                                                       (*OPTIONAL_MODELS, *MODELS[1:])}}
    names = [*MODELS[:1], *(n for n in OPTIONAL_MODELS if (Path(model) / n).is_dir()), *MODELS[1:]]
    return {name: sm.load(Path(model) / name, expected_task="sliding") for name in names}


def budget(planner: SlidingPlanner) -> int:
    """Training trajectories a model saw: epochs × mini-batches per epoch × batch size."""
    cfg = planner.config["training"]
    return int(cfg["curriculum"]["epochs"]) * int(cfg["batches_per_epoch"]) * int(cfg["batch_size"])


def eval_commands(n: int, seed: int) -> np.ndarray:
    """``n`` B-spline commands of K = 1200 the models never saw, ``(n, K, 4)``."""
    return commands.bspline_type(n, np.random.default_rng(9_000_000 + seed), length=LENGTH).states


def rmse_mm(rel_states: np.ndarray, command: np.ndarray) -> np.ndarray:
    """Reproduction RMSE between command and achieved object positions, per trajectory [mm]."""
    return 1000 * tracking_rmse(rel_states[..., :2], command[..., :2])


def farthest_m(states: np.ndarray) -> np.ndarray:
    """Farthest distance of the positions ``states[..., :2]`` from the origin, per trajectory [m]."""
    return np.linalg.norm(states[..., :2], axis=-1).max(-1)


def friction_study(models: dict[str, SlidingPlanner], n: int, seed: int) -> dict:
    cmds = eval_commands(n, seed)
    out: dict = {"grid": FRICTION_GRID, "models": {}, "still_pan_rmse_mm": float(rmse_mm(0 * cmds, cmds).mean())}
    for name, planner in models.items():
        cells, pan_max = [], 0.0
        for mu, mud in FRICTION_GRID:
            plan = planner.plan(cmds, mu=mu, mu_dyn=mud)
            cells.append(float(rmse_mm(plan.rel_states, cmds).mean()))
            pan_max = max(pan_max, float(farthest_m(plan.pan_states).max()))
        cells_arr = np.array(cells)
        out["models"][name] = {
            "rmse_mm": cells,
            "mean_rmse_mm": float(cells_arr.mean()),
            "worst_over_best": float(cells_arr.max() / max(cells_arr.min(), 1e-9)),
            "pan_max_m": pan_max,
            "budget": budget(planner),
        }
    return out


def qualitative(models: dict[str, SlidingPlanner], n: int, seed: int) -> dict:
    """Fig. 3.7's claims as numbers, at the training friction (μ = 1.0, μ' = 0.5) on ``n`` commands.

    Per model: mean RMSE, the object's travel (farthest distance from its start) as a share of
    the command's, and the pan's farthest excursion from home.
    """
    cmds = eval_commands(n, seed)
    command_travel = farthest_m(cmds)
    out = {}
    for name, planner in models.items():
        plan = planner.plan(cmds)
        travel = farthest_m(plan.rel_states)
        out[name] = {
            "rmse_mm": float(rmse_mm(plan.rel_states, cmds).mean()),
            "object_travel_share": float((travel / command_travel).mean()),
            "pan_max_m": float(farthest_m(plan.pan_states).max()),
        }
    return out


def _tables(study: dict, out: Path) -> None:
    names = list(study["models"])
    lines = ["| μ | μ' | " + " | ".join(f"model {n} RMSE [mm]" for n in names) + " |",
             "|---|---|" + "---|" * len(names)]
    for i, (mu, mud) in enumerate(study["grid"]):
        lines.append(f"| {mu} | {mud} | " + " | ".join(f"{study['models'][n]['rmse_mm'][i]:.2f}" for n in names) + " |")
    for label, key in (("mean", "mean_rmse_mm"), ("worst / best", "worst_over_best")):
        lines.append(f"| {label} | | " + " | ".join(f"{study['models'][n][key]:.2f}" for n in names) + " |")
    lines += ["", f"Leaving the object where it starts (a still pan) gives {study['still_pan_rmse_mm']:.2f} mm."]
    atomic_write_text(out / "table3_friction.md", "\n".join(lines) + "\n")
    lines = ["| model | training trajectories | max pan excursion [m] | inside p_lim = 0.2 m? |", "|---|---|---|---|"]
    for n in names:
        m = study["models"][n]["pan_max_m"]
        lines.append(f"| {n} | {study['models'][n]['budget']:,} | {m:.3f} | {'yes' if m <= PAN_LIMIT else 'no'} |")
    atomic_write_text(out / "table3_range.md", "\n".join(lines) + "\n")
    if "qualitative" in study:
        lines = ["| model | RMSE [mm] (still pan: {:.2f}) | object travel / command travel | max pan excursion [m] |"
                 .format(study["still_pan_rmse_mm"]), "|---|---|---|---|"]
        for n, q in study["qualitative"].items():
            lines.append(f"| {n} | {q['rmse_mm']:.2f} | {q['object_travel_share']:.2f} | {q['pan_max_m']:.3f} |")
        atomic_write_text(out / "table3_qualitative.md", "\n".join(lines) + "\n")


def figures(models: dict[str, SlidingPlanner], study: dict, out: Path, seed: int) -> np.ndarray:
    plt = pyplot()

    command = eval_commands(1, seed + 1)[0]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    axes[0].plot(command[:, 0], command[:, 1], "k--", lw=1.5, label="command")
    for i, (name, planner) in enumerate(models.items()):
        plan = planner.plan(command)
        axes[0].plot(plan.rel_states[:, 0], plan.rel_states[:, 1], color=f"C{i}", label=f"model {name}")
        axes[1].plot(plan.pan_states[:, 0], plan.pan_states[:, 1], color=f"C{i}", lw=0.8, label=f"model {name}")
    axes[1].add_patch(plt.Circle((0, 0), PAN_LIMIT, fill=False, ls=":", color="0.5", label="p_lim = 0.2 m"))
    axes[0].set(xlabel="x [m]", ylabel="y [m]", title="(a) object relative to the pan")
    axes[1].set(xlabel="x [m]", ylabel="y [m]", title="(b) frying pan")
    for ax in axes:
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(fontsize=8)
    fig.suptitle("Fig. 3.7: reproduced trajectories in the 2-D physics (K = 1200)")
    fig.tight_layout()
    save_figure(fig, out / "fig3_7_paths.png", dpi=130, close=True)

    fig, axes = plt.subplots(1, len(study["models"]), figsize=(4.2 * len(study["models"]), 3.8), squeeze=False)
    mus, muds = sorted({m for m, _ in FRICTION_GRID}), sorted({d for _, d in FRICTION_GRID})
    vmax = max(max(v["rmse_mm"]) for v in study["models"].values())
    for ax, (name, res) in zip(axes[0], study["models"].items(), strict=True):
        grid = np.full((len(mus), len(muds)), np.nan)
        for (mu, mud), value in zip(FRICTION_GRID, res["rmse_mm"], strict=True):
            grid[mus.index(mu), muds.index(mud)] = value
        im = ax.imshow(grid, origin="lower", vmin=0, vmax=vmax, cmap="viridis")
        ax.set(xticks=range(len(muds)), xticklabels=muds, yticks=range(len(mus)), yticklabels=mus,
               xlabel="μ' (dynamic)", ylabel="μ (static)", title=f"model {name}: mean {res['mean_rmse_mm']:.1f} mm")
        fig.colorbar(im, ax=ax, label="RMSE [mm]")
    fig.suptitle("Fig. 3.10: reproduction error across friction the models never saw")
    fig.tight_layout()
    save_figure(fig, out / "fig3_10_friction.png", dpi=130, close=True)
    return command


def speed(planner: SlidingPlanner, repeats: int = 10) -> dict:
    command = eval_commands(1, 123)[0]
    planner.plan(command)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        planner.plan(command)
        times.append(time.perf_counter() - start)
    t = float(np.median(times))
    batch = eval_commands(64, 124)
    start = time.perf_counter()
    planner.plan(batch)
    tb = time.perf_counter() - start
    return {"single_seconds": t, "single_samples_per_s": LENGTH / t, "batch64_samples_per_s": 64 * LENGTH / tb}


def robot(models: dict[str, SlidingPlanner], command: np.ndarray, out: Path) -> dict:
    """Figs. 3.8–3.9: each model's plan executed by the arm (PD + DOB, ch. 3 gains) in MuJoCo."""
    from .. import sim

    results = {}
    for name, planner in models.items():
        plan = planner.plan(command)
        try:
            res = sim.run_sliding(plan, command, snapshots=out / f"fig3_9_snapshots_{name}.png")
        except ValueError as exc:  # e.g. model C's pan leaves the arm's workspace
            results[name] = {"not_executable": str(exc)}
            continue
        results[name] = {"rmse_mm": 1000 * res.rmse, "pan_excursion_m": res.pan_excursion, "fell_off": res.fell_off}
        if name == next(iter(models)):
            sim.plot_sliding(res, out / "fig3_8_robot.png")
    return results


def run(out: Path, model: str | None = None, quick: bool = False, seed: int = 0) -> dict:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    models = load_models(model)
    study = friction_study(models, 3 if quick else 10, seed)
    study["qualitative"] = qualitative(models, 3 if quick else 10, seed)
    _tables(study, out)
    command = figures(models, study, out, seed)
    study["speed_shipped_model"] = speed(models[next(iter(models))])
    s = study["speed_shipped_model"]
    atomic_write_text(out / "table3_speed.md",
        "| model | single trajectory, K = 1200 [samples/s] | batch of 64 [samples/s] |\n|---|---|---|\n"
        f"| shipped A | {s['single_samples_per_s']:.0f} | {s['batch64_samples_per_s']:.0f} |\n"
    )
    try:
        study["robot"] = robot(models, command, out)
    except ImportError as exc:
        study["robot_skipped"] = str(exc)
    atomic_write_text(out / "results.json", json.dumps(study, indent=2))
    print((out / "table3_friction.md").read_text())
    return study
