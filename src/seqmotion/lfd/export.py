"""Ship a trained pushing policy inside the package: ``seqmotion lfd export POLICY_DIR``.

Copies the policy's ``model.safetensors`` + ``config.json`` (written by ``seqmotion lfd train``)
to ``seqmotion/pretrained/pushing/`` (or ``--name``) and writes ``MODEL_CARD.md`` from what the
training recorded in the config (command, seed, settings, wall times, machine) and from the
evaluations given (JSON files written by ``seqmotion lfd evaluate --json``).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from ..training import checkpoint as ckpt

PRETRAINED_ROOT = Path(__file__).resolve().parents[1] / "pretrained"
MACHINE = "2-core CPU container, no GPU"
_TARGETS = {
    "pair": "each image's target the encoder's z of its own demonstration (eq. 5.2)",
    "position_mean": "each image's target the mean encoder z of the demonstrations without images at its block "
    "position (see `CNNTraining.targets`)",
    "position_medoid": "each image's target the encoder z of the most typical demonstration without images at its "
    "block position, the one nearest their mean (see `CNNTraining.targets`)",
}


def _evaluation_line(path: Path) -> tuple[str, dict]:
    result = json.loads(Path(path).read_text())
    cells = ", ".join(f"{k} {v[0]}/{v[1]}" for k, v in result["per_position"].items())
    who = (
        f"{result['policy_kind'].replace('_', '-')} ({result['policy_preset']})"
        if result.get("policy_kind")
        else f"`{Path(path).stem}`"
    )
    line = (
        f"- {who}, {result['camera']} camera: **{result['success_rate']:.1%}** ({result['successes']}/"
        f"{result['n_trials']} trials, evaluation seed {result['seed']}) — {cells}"
    )
    brief = {k: result[k] for k in ("camera", "seed", "success_rate", "successes", "n_trials", "per_position")}
    return line, brief


def export_policy(
    policy_dir: str | Path,
    name: str = "pushing",
    evaluations: list[str | Path] | None = None,
    notes: str = "",
    root: str | Path = PRETRAINED_ROOT,
) -> Path:
    """Copy a policy directory to ``root/name`` and write its model card.

    Args:
        policy_dir: a ``<method>_<camera>/`` directory written by :func:`seqmotion.lfd.train.train`.
        name: pretrained name (``sm.load_pretrained(name)``).
        evaluations: JSON files of ``seqmotion lfd evaluate --json`` runs of this policy (or of
            its moved-camera siblings) to quote as measured success rates.
        notes: free text appended to the card.
        root: where pretrained models live (default: the package's ``pretrained/``).

    Returns:
        The target directory.
    """
    from .models import load_policy

    policy_dir = Path(policy_dir)
    policy = load_policy(policy_dir)  # verifies weights against the config
    cfg = policy.config
    training: dict[str, Any] = cfg.training
    target = Path(root) / name
    target.mkdir(parents=True, exist_ok=True)
    for file in (ckpt.WEIGHTS, ckpt.CONFIG):
        shutil.copyfile(policy_dir / file, target / f".{file}.tmp")
        (target / f".{file}.tmp").replace(target / file)
    size_mb = (target / ckpt.WEIGHTS).stat().st_size / 1e6
    seq, cnn = cfg.seqae, cfg.cnn
    seqae_rec = training.get("seqae", {})
    cnn_rec = training.get("cnn", {})
    machine = training.get("machine", {})
    seconds = [seqae_rec.get("seconds"), cnn_rec.get("seconds")]
    lines = [
        f"# Model card: `{name}`",
        "",
        f"Task `pushing` (dissertation ch. 5) — the combined policy of Fig. 5.2, kind `{cfg.kind}`: a CNN "
        f"(5 conv + ReLU + BatchNorm, channels {list(cnn['channels'])}, linear → z ∈ R^{seq['latent']}) in front "
        f"of the SeqAE's decoder ({seq['layers']} × {seq['hidden']} LSTM, preset `{cfg.preset}`), which reads z "
        f"and the slave state and emits the next master command every {cfg.command_interval * 1000:g} ms; the "
        f"SeqAE's motion encoder is kept. Webcam pose: `{cfg.camera}`. {size_mb:.2f} MB of weights.",
        "",
        "```python",
        "import seqmotion as sm",
        f'policy = sm.load_pretrained("{name}")',
        "result = sm.lfd.evaluate(policy, trials=5)      # 30 closed-loop trials, 5 at each block position",
        "```",
        "",
        "## How it was trained",
        "",
        f"- Command: `{training.get('command') or 'unknown'}`",
        f"- Seed: {training.get('seed')}; data `{training.get('data_dir')}` "
        f"(`seqmotion lfd collect`, seed {training.get('seed')})",
        f"- SeqAE: {seqae_rec.get('motions')} of {seqae_rec.get('of')} demonstrations without images (failed ones "
        f"left out); settings {json.dumps(seqae_rec.get('settings', {}), sort_keys=True)}; final eq.-5.1 loss "
        f"{seqae_rec.get('final_loss', float('nan')):.4f}",
        f"- CNN: {cnn_rec.get('pairs')} of {cnn_rec.get('of')} image–motion pairs (`{cnn_rec.get('dataset')}`), "
        f"{_TARGETS.get(cnn_rec.get('settings', {}).get('targets', 'pair'), '')}; "
        f"settings {json.dumps(cnn_rec.get('settings', {}), sort_keys=True)}",
        "- Wall time: "
        + ", ".join(f"{part} {s:.0f} s" for part, s in zip(("SeqAE", "CNN"), seconds, strict=True) if s is not None)
        + (f" (total {sum(s for s in seconds if s is not None) / 60:.1f} min)" if any(seconds) else ""),
        f"- Machine: {MACHINE} ({machine.get('platform', 'unknown')}, {machine.get('cpus')} CPUs, torch "
        f"{machine.get('torch')} with {machine.get('torch_threads')} thread(s); other jobs shared the CPU, load "
        f"average {machine.get('load_average')})",
        "",
        "## Measured",
        "",
    ]
    briefs = []
    for path in evaluations or []:
        line, brief = _evaluation_line(Path(path))
        lines.append(line)
        briefs.append(brief)
    if not briefs:
        lines.append("(no evaluations given)")
    if notes:
        lines += ["", "## Notes", "", notes]
    (target / "MODEL_CARD.md").write_text("\n".join(lines) + "\n")
    if briefs:
        (target / "evaluations.json").write_text(json.dumps(briefs, indent=1) + "\n")
    return target
