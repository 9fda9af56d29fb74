"""``seqmotion demo``: what the shipped models do, in under a minute on a laptop CPU.

1. The pancake ``Deformer`` turns rough turning motions into ones that keep the pancake on
   the spatula: a table over fresh random sketches, and a figure.
2. If the ``sliding`` planner is shipped: it plans pan shaking that slides an object along a
   commanded path.
3. If MuJoCo is importable (and ``--no-sim`` is not given): a simulated arm executes one
   original and one deformed motion, and the demo reports whether the pancake stayed on.
4. Then, if ``pushing-hard`` is shipped: the learning-from-demonstration policy trained on the hard
   pushing benchmark pushes objects it sees in a 64×64 webcam image (a few fresh held-out scenes).
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np

from ..data.trajectories import tracking_rmse
from ..tasks.pancake import data as inputs
from ..tasks.pancake import physics


def _pancake(out: Path) -> None:
    import seqmotion as sm

    deformer = sm.load_pretrained("pancake")
    sketches = inputs.position_type(200, np.random.default_rng(2026))
    before, after, shape, seconds = [], [], [], []
    for b in range(len(sketches)):
        x = sketches.states[b, : sketches.lengths[b]]
        start = time.perf_counter()
        r = deformer.deform(x)
        seconds.append(time.perf_counter() - start)
        before.append(physics.violation_of_states(x).max())
        after.append(r.violation.max())
        shape.append(1000 * np.sqrt(((r.states[:, :2] - x[:, :2]) ** 2).sum(1).mean()))
    before, after = np.array(before), np.array(after)
    print("Pancake turning — 200 random sketched motions (K = 100…500 samples at 1 ms)")
    print(f"  pancake stays on (max F_c ≤ 0.01 rad): sketches {100 * np.mean(before <= 0.01):5.1f} %"
          f"  →  deformed {100 * np.mean(after <= 0.01):5.1f} %")
    print(f"  worst cone violation: sketches {before.max():.3f} rad  →  deformed {after.max():.4f} rad")
    print(f"  path change (RMSE of y, z): {np.mean(shape):.1f} mm;  "
          f"deformation time {1000 * np.median(seconds):.2f} ms per motion (median)")

    exact, end_mm, polish, longer = [], [], [], []
    for b in range(20):  # keep_end: the same motions, polished to end exactly at the sketch's end, at rest
        x = sketches.states[b, : sketches.lengths[b]]
        start = time.perf_counter()
        with warnings.catch_warnings():  # the ones it cannot polish are counted below
            warnings.simplefilter("ignore", RuntimeWarning)
            r = deformer.deform(x, keep_end=True)
        polish.append(time.perf_counter() - start)
        exact.append(bool(r.exact) and r.violation.max() <= 1e-6 and np.abs(r.states[-1, 3:]).max() <= 1e-6)
        end_mm.append(1000 * np.linalg.norm(r.states[-1, :2] - x[-1, :2]) if exact[-1] else 0.0)
        longer.append(r.length - len(x))
    print(f"  with keep_end=True (20 of them): {sum(exact)}/20 end exactly at the sketch's end (within "
          f"{max(end_mm):.0e} mm), at rest, inside the cone and the arm's acceleration limits; "
          f"{sum(n > 0 for n in longer)} of them needed more time than the sketch to stop within the limits "
          f"(median {np.median([n for n in longer if n > 0] or [0]):.0f} ms more); "
          f"{1000 * np.median(polish):.0f} ms per motion (median)")

    from .ch2 import figures

    figures(deformer, out)
    print(f"  figures: {out}/fig2_5_deformation.png, fig2_6_psi.png, fig2_7_deformation_amount.png")


def _sliding(out: Path) -> None:
    import seqmotion as sm
    from seqmotion.api import pretrained_dir

    try:
        pretrained_dir("sliding")
    except ValueError:
        return

    from .ch3 import eval_commands

    planner = sm.load_pretrained("sliding")
    command = eval_commands(1, 0)[0]  # a random B-spline path the model never saw (ch. 3's test set)
    planner.plan(command[:200])  # compiles the contact kernels once (numba), outside the timing
    start = time.perf_counter()
    plan = planner.plan(command)
    seconds = time.perf_counter() - start
    rmse = 1000 * tracking_rmse(plan.rel_states[:, :2], command[:, :2])
    reach = 1000 * np.abs(command[:, :2]).max()
    print(f"\nSliding an object on a frying pan — an unseen random path (1.2 s, within {reach:.0f} mm of the start)")
    print(f"  object follows the command within {rmse:.1f} mm RMSE; pan stays within "
          f"{1000 * np.abs(plan.pan_states[:, :2]).max():.0f} mm of its start; planned in {1000 * seconds:.1f} ms")


def _robot(out: Path) -> dict[str, tuple[str, list[str]]]:
    """Execute the sketch, the deformed and the keep_end motion on the arm; print what happened to each and
    write ``robot_snapshots.png``: one row of snapshots per run, over the turn itself, titled with the run's name and
    the line printed for it (the task, whether the turn carried the pancake, what happened after the motion), each
    frame labelled with its time and whether the pancake is still on.

    Returns:
        run name → (row title, frame labels) (empty where offscreen rendering is unavailable).
    """
    import tempfile

    import seqmotion as sm
    from seqmotion import sim
    from seqmotion.sim.plots import plot_snapshot_rows, snapshot_labels, snapshot_steps

    deformer = sm.load_pretrained("pancake")
    x = inputs.straight((0.2, 0.1, 2.5), 500)
    mu = deformer.options.mu
    runs = {
        "sketch": x,
        "deformed": deformer.deform(x).states,  # the learned motion alone: ends away from the sketch, moving
        "keep_end": deformer.deform(x, keep_end=True).states,  # ends at (0.2, 0.1, 2.5), at rest
    }
    results, strips = {}, {}
    render = True
    with tempfile.TemporaryDirectory() as tmp:
        for name, states in runs.items():
            strip = Path(tmp) / f"{name}.png"
            if render:
                try:
                    results[name] = sim.run_pancake(states, gains="ch2", snapshots=strip, mu=mu)
                    strips[name] = _read_png(strip)
                    continue
                except Exception as exc:  # noqa: BLE001 - no offscreen OpenGL here: run the arm without pictures
                    print(f"  (no snapshots: offscreen rendering failed: {exc})")
                    render = False
            results[name] = sim.run_pancake(states, gains="ch2", mu=mu)
    print("\nMuJoCo arm (PD + disturbance observer, 1 ms) turning the pancake to (y, z, θ) = (0.2 m, 0.1 m, 2.5 rad)")
    for name, result in results.items():
        print(f"  {name:8s}: {result.describe()}")
    labelled = {}
    if render:
        rows = []
        for name, result in results.items():
            title, labels = snapshot_labels(name, result, snapshot_steps(result))
            labelled[name] = (title, labels)
            rows.append((title, labels, strips[name]))
        snapshots = plot_snapshot_rows(rows, out / "robot_snapshots.png")
        print(f"  snapshots: {snapshots} (a row per run: {', '.join(results)}; frames during the turn, each with its "
              "time and whether the pancake is on; each row's title says what happened after the motion)")
    return labelled


def _pushing_hard(out: Path, trials: int = 4) -> list[bool]:
    """``trials`` held-out scenes of the hard pushing benchmark with the shipped ``pushing-hard`` policy: print
    each outcome beside the policy's measured rate, and write ``pushing_hard.png`` (each webcam image, titled).

    Returns each trial's success.
    """
    import json

    import matplotlib.pyplot as plt

    import seqmotion as sm
    from seqmotion.api import pretrained_dir
    from seqmotion.io import save_figure
    from seqmotion.lfd.evaluation import evaluate

    result = evaluate(sm.load_pretrained("pushing-hard"), trials=trials, seed=0, benchmark="hard", keep_runs=True)
    measured = json.loads((pretrained_dir("pushing-hard") / "evaluations.json").read_text())[0]
    print("\nPushing from a webcam image, hard benchmark (object anywhere in a wide region, turned ±30°, box or "
          "cylinder, distractors, camera and lighting jitter): success = the object put down 1.5–5.5 cm past the "
          "centre line")
    print(f"  pushing-hard: {result.successes}/{result.n_trials} of these scenes; measured on "
          f"{measured['n_trials']} held-out scenes: {measured['success_rate']:.0%} (its model card)")
    fig, axes = plt.subplots(1, trials, figsize=(2.2 * trials, 2.6))
    for ax, o in zip(np.atleast_1d(axes), result.outcomes, strict=True):
        ax.imshow(o.image)
        ax.set_title(f"{o.placement['shape']}\n{'at the goal' if o.success else 'missed'} "
                     f"({100 * o.placement['past']:.1f} cm past)", fontsize=8)
        ax.axis("off")
    print(f"  webcam images: {save_figure(fig, out / 'pushing_hard.png', close=True)}")
    return [o.success for o in result.outcomes]


def _read_png(path: Path) -> np.ndarray:
    import matplotlib.image

    return matplotlib.image.imread(str(path))


def run(out: Path, simulate: bool = True) -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    _pancake(out)
    _sliding(out)
    if simulate:
        _robot(out)
        from seqmotion.api import pretrained_models

        if "pushing-hard" in pretrained_models():
            _pushing_hard(out)
