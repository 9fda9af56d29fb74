"""Chapter 5, reproduced: Fig. 5.9 / Table 5.2, Table 5.3, Fig. 5.10-style snapshots, Fig. 5.11.

``seqmotion reproduce ch5 [--model MODELS] [--out DIR] [--seed S] [--quick]`` works in ``DIR``:

* ``data/`` — the demonstrations (``seqmotion lfd collect``: 90 motions, 3 × 18 image–motion
  pairs), collected if missing; ``data_unseen/pairs_default.h5`` — 18 more pairs from another
  seed, whose images no model saw (Fig. 5.11).
* ``models/<preset>/<method>_<camera>/`` — the policies (or ``MODELS/<preset>/...`` when
  ``--model MODELS`` is given); where one is missing, the shipped ``pushing`` policy stands in for
  its slot (``smaller``, proposed, default camera) and the others are left out of the tables
  ("not evaluated") — nothing is trained unless ``--retrain`` is given. With ``--retrain`` the
  missing ones are trained with the defaults of ``seqmotion lfd train`` for their preset
  (:func:`seqmotion.lfd.train.default_settings`: the dissertation's 2000 SeqAE epochs (1200 for
  ``larger``), so ``original`` takes about an hour and ``larger`` about two on a 2-core CPU); the
  estimated time (:func:`training_eta`) is printed before training starts.

and writes

* ``table5_2.md`` / ``.json`` and ``fig5_9_success.png`` — success over 30 trials (5 at each of
  the 6 positions; fresh block placement and lighting), proposed vs end-to-end, for the
  ``original``, ``larger`` and ``smaller`` models, with the dissertation's numbers beside ours;
* ``table5_3.md`` / ``.json`` — the proposed method with the camera moved (SeqAE reused, CNN
  retrained on that camera's 18 pairs): default, position 1, position 2, for the main preset
  (:func:`main_preset`: ``seqmotion lfd train``'s default, the shipped policy's size);
* ``fig5_10_snapshots_end_to_end.png`` / ``fig5_10_snapshots_proposed.png`` — frames of one
  evaluation trial of each method (the same block placement);
* ``fig5_11_latent_pca.png`` / ``fig5_11_latent_pca.json`` — PCA of ẑ of the 18 unseen
  images, coloured by block position, for both methods (main preset).

``--quick`` is a smoke test of the whole pipeline: 1 demonstration per position and set, a
few epochs (with ``--retrain``), 1 trial per position — the numbers mean nothing, and every table and
figure says "SMOKE TEST" (:data:`SMOKE_TEST`).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..io import atomic_write_text, pyplot, save_figure

PRESET_NAMES = ("original", "larger", "smaller")
CAMERA_NAMES = ("default", "position1", "position2")
DISSERTATION_TABLE_5_2 = {
    "proposed": {"original": 0.567, "larger": 0.300, "smaller": 0.467},
    "end_to_end": {"original": 0.067, "larger": 0.067, "smaller": 0.333},
}
DISSERTATION_TABLE_5_3 = {"default": 0.567, "position1": 0.400, "position2": 0.267}
UNSEEN_SEED_OFFSET = 1000
"""The unseen image set (Fig. 5.11) is collected with ``seed + UNSEEN_SEED_OFFSET``."""
SNAPSHOT_TIMES = (0.0, 0.6, 1.2, 1.8, 2.4, 3.0, 3.9)
"""Times [s] of the Fig. 5.10-style frames."""


SMOKE_TEST = "SMOKE TEST (--quick): tiny data, 1 trial per position; these numbers mean nothing"
"""The label of every ``--quick`` table and figure."""
SHIPPED_SLOT = ("smaller", "proposed", "default")
"""The slot the shipped ``pushing`` policy fills (its config: preset ``smaller``, kind ``proposed``, camera
``default``)."""
SEQAE_SECONDS_PER_EPOCH = {"tiny": 0.02, "smaller": 0.27, "original": 1.43, "larger": 4.5}
"""[s] One SeqAE epoch on the 87 motions, one core (``seqmotion.lfd.train.SEQAE_EPOCHS``'s measurements; the
shipped 3 × 32 took 534 s for 2000). An end-to-end epoch sees 17 pairs instead of 87 motions: ~1/5 of that
(the shipped size's 2000 took 108 s); a CNN's 100 epochs take seconds."""


def training_eta(missing: list[tuple[str, str, str]], quick: bool = False) -> float:
    """Estimated seconds to train the ``(preset, method, camera)`` policies in ``missing`` (one SeqAE per preset,
    shared by its cameras; one end-to-end model per camera) on a 2-core CPU."""
    from ..lfd import train as training

    seconds = 0.0
    for preset_name in {p for p, _, _ in missing}:
        seqae, e2e, _ = training.default_settings(preset_name)
        epochs = (3, 3) if quick else (seqae.epochs, e2e.epochs)
        per_epoch = SEQAE_SECONDS_PER_EPOCH.get(preset_name, SEQAE_SECONDS_PER_EPOCH["larger"])
        slots = [(m, c) for p, m, c in missing if p == preset_name]
        if any(m == "proposed" for m, _ in slots):
            seconds += epochs[0] * per_epoch + 5.0 * sum(m == "proposed" for m, _ in slots)  # + a CNN each
        seconds += sum(m == "end_to_end" for m, _ in slots) * epochs[1] * per_epoch * 17 / 87
    return seconds


def main_preset() -> str:
    """The preset of Table 5.3, Fig. 5.10 and Fig. 5.11: ``seqmotion lfd train``'s default (the shipped policy's)."""
    from ..lfd.train import DEFAULT_PRESET

    return DEFAULT_PRESET


def _needed() -> list[tuple[str, str, str]]:
    """(preset, method, camera) of every policy the chapter needs."""
    needed = [(p, m, "default") for p in PRESET_NAMES for m in ("proposed", "end_to_end")]
    needed += [(main_preset(), "proposed", c) for c in CAMERA_NAMES[1:]]
    return needed


def ensure_data(out: Path, seed: int, quick: bool, training: bool = True) -> tuple[Path, Path]:
    """Collect the training sets into ``out/data`` (only for ``training``) and the unseen images into
    ``out/data_unseen`` if missing."""
    from ..lfd.data.dataset import CHAPTER_SETS, collect

    data, unseen = out / "data", out / "data_unseen"
    per = {name: 1 for name in CHAPTER_SETS} if quick else None
    missing = [name for name in CHAPTER_SETS if not (data / f"{name}.h5").is_file()]
    if missing and training:
        collect(data, missing, seed=seed, per_position={k: v for k, v in (per or {}).items() if k in missing} or None)
    if not (unseen / "pairs_default.h5").is_file():
        collect(
            unseen,
            ["pairs_default"],
            seed=seed + UNSEEN_SEED_OFFSET,
            per_position={"pairs_default": 1} if quick else None,
        )
    return data, unseen


def ensure_models(models: Path, data: Path, seed: int, quick: bool) -> dict[tuple[str, str, str], Path]:
    """Train whatever policy of :func:`_needed` is missing under ``models/<preset>/``."""
    from ..lfd import train as training

    paths = {}
    for preset_name in PRESET_NAMES:
        root = models / preset_name
        wanted = [(m, c) for p, m, c in _needed() if p == preset_name]
        missing = [(m, c) for m, c in wanted if not (root / f"{m}_{c}" / "model.safetensors").is_file()]
        seqae, e2e, cnn = training.default_settings(preset_name)
        if quick:
            seqae.epochs = e2e.epochs = cnn.epochs = 3
        proposed_cams = tuple(c for m, c in missing if m == "proposed")
        if proposed_cams:
            donor = root / "proposed_default"
            reuse = donor if (donor / "model.safetensors").is_file() else None
            if reuse is None and "default" not in proposed_cams:
                proposed_cams = ("default", *proposed_cams)
            training.train(
                data,
                root,
                preset_name,
                ("proposed",),
                proposed_cams,
                seed,
                seqae,
                e2e,
                cnn,
                seqae_from=reuse,
                progress=True,
                command="seqmotion reproduce ch5",
            )
        e2e_cams = tuple(c for m, c in missing if m == "end_to_end")
        if e2e_cams:
            training.train(
                data,
                root,
                preset_name,
                ("end_to_end",),
                e2e_cams,
                seed,
                seqae,
                e2e,
                cnn,
                progress=True,
                command="seqmotion reproduce ch5",
            )
        for m, c in wanted:
            paths[(preset_name, m, c)] = root / f"{m}_{c}"
    return paths


def _cell(result: dict | None) -> str:
    if result is None:
        return NOT_EVALUATED
    return f"{result['success_rate']:.1%} ({result['successes']}/{result['n_trials']})"


def available_models(models: Path) -> tuple[dict[tuple[str, str, str], Path], list[tuple[str, str, str]]]:
    """The policies of :func:`_needed` found under ``models/<preset>/`` — the shipped ``pushing`` policy standing
    in for :data:`SHIPPED_SLOT` where that one is not there — and the slots still missing."""
    from ..api import pretrained_dir

    paths, missing = {}, []
    for slot in _needed():
        path = models / slot[0] / f"{slot[1]}_{slot[2]}"
        if (path / "model.safetensors").is_file():
            paths[slot] = path
        elif slot == SHIPPED_SLOT:
            paths[slot] = Path(pretrained_dir("pushing"))
        else:
            missing.append(slot)
    return paths, missing


def run(out: Path, model: str | None = None, quick: bool = False, seed: int = 0, retrain: bool = False) -> dict:
    """Reproduce the chapter's tables and figures into ``out`` (see the module docstring).

    Args:
        out: output directory.
        model: a directory holding ``<preset>/<method>_<camera>/`` policies to evaluate instead
            of ``out/models`` (with ``retrain``, missing ones are trained there).
        quick: smoke-test sizes (every output labelled :data:`SMOKE_TEST`).
        seed: seeds the data collection, the training and the evaluation trials.
        retrain: train the policies that are neither in ``model``/``out/models`` nor shipped (hours on a
            CPU for the full sizes; the estimate is printed first). Without it nothing is trained.

    Returns:
        The summary written to ``summary.json``.
    """
    import torch

    from ..lfd.data.dataset import load_dataset
    from ..lfd.env import pushing
    from ..lfd.evaluation import evaluate
    from ..lfd.policy.policy import PushingPolicy

    torch.set_num_threads(1)  # the LSTMs are small: one thread is fastest and reproducible
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    models = Path(model) if model is not None else out / "models"
    paths, missing = available_models(models)
    if missing and retrain:
        print(f"training {len(missing)} policies ({', '.join('/'.join(m) for m in missing)}): "
              f"estimated {training_eta(missing, quick) / 60:.0f} min on a 2-core CPU", flush=True)
    elif missing:
        print(f"evaluating {len(paths)} policies ({', '.join('/'.join(p) for p in paths)}); "
              f"{len(missing)} are neither in {models} nor shipped and are left out of the tables — "
              f"--retrain trains them (estimated {training_eta(missing, quick) / 60:.0f} min on a 2-core CPU)",
              flush=True)
    if quick:
        print(SMOKE_TEST, flush=True)
    data, unseen = ensure_data(out, seed, quick, training=bool(missing and retrain))
    if missing and retrain:
        paths = ensure_models(models, data, seed, quick)
    trials = 1 if quick else 5

    scene = pushing.PushingScene()
    results: dict[str, dict] = {}
    try:
        for (preset_name, method, camera), path in paths.items():
            policy = PushingPolicy.from_pretrained(path)
            ev = evaluate(policy, camera=camera, trials=trials, seed=seed, progress=True, scene=scene)
            results[f"{preset_name}/{method}_{camera}"] = ev.as_dict()
        snapshots = _snapshots(out, paths, results, scene, seed)
    finally:
        scene.close()

    table52 = {m: {p: results.get(f"{p}/{m}_default") for p in PRESET_NAMES} for m in ("proposed", "end_to_end")}
    table53 = {c: results.get(f"{main_preset()}/proposed_{c}") for c in CAMERA_NAMES}
    _write_tables(out, table52, table53, trials, quick)
    _plot_fig5_9(out, table52, quick)
    pca = _fig5_11(out, paths, load_dataset(unseen / "pairs_default.h5"), quick)
    summary = {
        "seed": seed,
        "quick": quick,
        "smoke_test": SMOKE_TEST if quick else None,
        "not_evaluated": ["/".join(slot) for slot in missing if slot not in paths],
        "models": str(models),
        "trials_per_position": trials,
        "main_preset": main_preset(),
        "table5_2": {m: {p: _brief(r) for p, r in row.items()} for m, row in table52.items()},
        "table5_3": {c: _brief(r) for c, r in table53.items()},
        "fig5_11_explained_variance": pca,
        "snapshots": snapshots,
        "seconds": time.perf_counter() - start,
    }
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    atomic_write_text(out / "evaluations.json", json.dumps(results, indent=1) + "\n")
    return summary


def _brief(result: dict | None) -> dict | None:
    """A result's numbers (None: the policy was not evaluated — not shipped, no ``--retrain``)."""
    return None if result is None else {k: result[k] for k in ("success_rate", "successes", "n_trials", "per_position")}


NOT_EVALUATED = "not evaluated (--retrain)"


def _write_tables(out: Path, table52: dict, table53: dict, trials: int, quick: bool = False) -> None:
    n = 6 * trials
    smoke = [f"**{SMOKE_TEST}**", ""] if quick else []
    lines = [
        f"# Table 5.2 — success rate over {n} trials ({trials} at each of 6 block positions)",
        "",
        *smoke,
        "| training method | " + " | ".join(f"{p} ({_shape(p)})" for p in PRESET_NAMES) + " |",
        "|---|---|---|---|",
    ]
    names = {
        "proposed": "proposed (SeqAE on the 90 motions + CNN on the 18 pairs)",
        "end_to_end": "end-to-end (the 18 pairs)",
    }
    for method, row in table52.items():
        lines.append(f"| {names[method]} | " + " | ".join(_cell(row[p]) for p in PRESET_NAMES) + " |")
    for method, row in DISSERTATION_TABLE_5_2.items():
        lines.append(
            f"| dissertation, {method.replace('_', '-')} | " + " | ".join(f"{row[p]:.1%}" for p in PRESET_NAMES) + " |"
        )
    lines += ["", "Failed demonstrations are left out of training (see the policies' config.json).", ""]
    lines += ["Per position (successes/trials):", ""]
    for method, row in table52.items():
        for p in PRESET_NAMES:
            if row[p] is None:
                continue
            cells = ", ".join(f"{k} {v[0]}/{v[1]}" for k, v in row[p]["per_position"].items())
            lines.append(f"* {method} {p}: {cells}")
    atomic_write_text(out / "table5_2.md", "\n".join(lines) + "\n")
    atomic_write_text(out / "table5_2.json",
        json.dumps(
            {
                "measured": {m: {p: _brief(r) for p, r in row.items()} for m, row in table52.items()},
                "dissertation": DISSERTATION_TABLE_5_2,
            },
            indent=2,
        )
        + "\n"
    )

    lines = [
        f"# Table 5.3 — camera moved: SeqAE reused, CNN retrained on 18 new pairs ({n} trials each)",
        "",
        f"Model size: {main_preset()} ({_shape(main_preset())}; the shipped default). The dissertation's "
        "numbers are for its 7-layer model.",
        "",
        *smoke,
        "| camera position | success rate | dissertation |",
        "|---|---|---|",
    ]
    for camera, result in table53.items():
        lines.append(f"| {camera} | {_cell(result)} | {DISSERTATION_TABLE_5_3[camera]:.1%} |")
    lines += ["", "Per position (successes/trials):", ""]
    for camera, result in table53.items():
        if result is None:
            continue
        lines.append(f"* {camera}: " + ", ".join(f"{k} {v[0]}/{v[1]}" for k, v in result["per_position"].items()))
    atomic_write_text(out / "table5_3.md", "\n".join(lines) + "\n")
    atomic_write_text(out / "table5_3.json",
        json.dumps(
            {"measured": {c: _brief(r) for c, r in table53.items()}, "dissertation": DISSERTATION_TABLE_5_3}, indent=2
        )
        + "\n"
    )


def _shape(preset_name: str) -> str:
    from ..lfd.policy.networks import preset

    config = preset(preset_name)
    return f"{config.layers}x{config.hidden}"


def _plot_fig5_9(out: Path, table52: dict, quick: bool = False) -> None:
    """Bars: measured success per model size and method; markers: the dissertation's values."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    x = np.arange(len(PRESET_NAMES))
    for i, (method, color) in enumerate((("proposed", "tab:blue"), ("end_to_end", "tab:orange"))):
        rates = [np.nan if table52[method][p] is None else 100 * table52[method][p]["success_rate"]
                 for p in PRESET_NAMES]  # NaN: not evaluated, no bar
        ax.bar(x + (i - 0.5) * 0.38, rates, 0.36, color=color, label=method.replace("_", "-") + " (ours)")
        ax.scatter(
            x + (i - 0.5) * 0.38,
            [100 * DISSERTATION_TABLE_5_2[method][p] for p in PRESET_NAMES],
            marker="_",
            s=400,
            color="k",
            zorder=3,
            label="dissertation" if i == 0 else None,
        )
    ax.set_xticks(x, [f"{p}" for p in PRESET_NAMES])
    ax.set_ylabel("success rate [%]")
    ax.set_ylim(0, 100)
    ax.set_title("Fig. 5.9 / Table 5.2: 18 image-motion pairs (30 trials each)" + (f"\n{SMOKE_TEST}" if quick else ""),
                 fontsize=8 if quick else None)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    save_figure(fig, out / "fig5_9_success.png", dpi=150, close=True)


def _fig5_11(out: Path, paths: dict, unseen: Any, quick: bool = False) -> dict:
    """PCA (2 components) of ẑ of the unseen images, both methods of the main (default) size (those evaluated)."""
    plt = pyplot()
    from ..lfd.env.pushing import POSITIONS
    from ..lfd.policy.policy import PushingPolicy

    fig, axes = plt.subplots(1, 2, figsize=(8.4, 3.8))
    explained = {}
    colors = plt.get_cmap("tab10")
    points = {}
    for ax, method in zip(axes, ("end_to_end", "proposed"), strict=True):
        if (main_preset(), method, "default") not in paths:
            ax.set_title(f"{method.replace('_', '-')}: {NOT_EVALUATED}")
            ax.axis("off")
            continue
        z = PushingPolicy.from_pretrained(paths[(main_preset(), method, "default")]).latent(unseen.images)
        centred = z - z.mean(0)
        _, s, vt = np.linalg.svd(centred, full_matrices=False)
        pcs = centred @ vt[:2].T
        explained[method] = (s[:2] ** 2 / max((s**2).sum(), 1e-30)).tolist()
        points[method] = {"pc": pcs.tolist(), "position_index": unseen.episodes["position_index"].tolist()}
        for pos in POSITIONS:
            mask = unseen.episodes["position_index"] == pos.index
            ax.scatter(pcs[mask, 0], pcs[mask, 1], color=colors(pos.index), label=pos.name, s=30)
        ax.set_title(f"{method.replace('_', '-')} (explained {sum(explained[method]):.0%})")
        ax.set_xlabel("PC 1")
        ax.set_ylabel("PC 2")
    if points:
        axes[1].legend(fontsize=7, loc="best")
    fig.suptitle(f"Fig. 5.11: latents of {len(unseen)} unseen images by block position ({main_preset()} model)"
                 + (f"\n{SMOKE_TEST}" if quick else ""))
    fig.tight_layout()
    save_figure(fig, out / "fig5_11_latent_pca.png", dpi=150, close=True)
    atomic_write_text(out / "fig5_11_latent_pca.json", json.dumps({"explained_variance": explained, **points}) + "\n")
    return explained


def render_frames(
    scene: Any, run: Any, variation: Any, times: tuple[float, ...], width: int = 320, height: int = 240
) -> list[np.ndarray]:
    """Frames ``(height, width, 3)`` of a recorded :class:`~seqmotion.lfd.rollout.AutonomousRun` at ``times`` [s].

    The recorded arm angles and block pose are written back into the scene (same variation,
    so the lighting matches) and rendered from the scene's overview camera in front of the
    robot (:meth:`seqmotion.lfd.env.pushing.PushingScene.render_states`).
    """
    scene.reset(run.position, variation)
    steps = [min(round(t / run.dt), len(run.slave_theta) - 1) for t in times]
    return scene.render_states(run.slave_theta[steps], run.block_pose[steps], width, height)


def _snapshots(out: Path, paths: dict, results: dict, scene: Any, seed: int) -> dict:
    """Fig. 5.10: one trial per method at the same placement (a failed end-to-end one if there is any)."""
    from ..lfd.env import pushing
    from ..lfd.evaluation import trial_rng
    from ..lfd.policy.policy import PushingPolicy
    from ..lfd.rollout import run_episode
    from ..sim.render import write_strip

    e2e = results.get(f"{main_preset()}/end_to_end_default") or results[f"{main_preset()}/proposed_default"]
    failed = [o for o in e2e["outcomes"] if not o["success"]]
    pick = (failed or e2e["outcomes"])[0]
    index, trial = pick["position_index"], pick["trial"]
    position = pushing.POSITIONS[index]
    variation = pushing.SceneVariation.sample(trial_rng(seed, index, trial))
    chosen = {}
    for method in ("end_to_end", "proposed"):
        if (main_preset(), method, "default") not in paths:
            continue
        policy = PushingPolicy.from_pretrained(paths[(main_preset(), method, "default")])
        run, _, _ = run_episode(scene, policy, position, variation)
        frames = render_frames(scene, run, variation, SNAPSHOT_TIMES)
        labels = [f"{method.replace('_', '-')} t={t:.1f} s" for t in SNAPSHOT_TIMES]
        write_strip(frames, out / f"fig5_10_snapshots_{method}.png", labels)
        chosen[method] = {"position": position.name, "trial": trial, "success": bool(run.success)}
    return chosen
