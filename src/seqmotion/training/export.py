"""Ship a trained run inside the package: weights, config and a model card.

``seqmotion export RUN_DIR --name pancake --metrics reproduce/ch2/results.json`` copies the
run's final ``model.safetensors`` + ``config.json`` to ``src/seqmotion/pretrained/<name>/`` and
writes ``MODEL_CARD.md`` from what the run recorded (the exact training command, seed, wall
time, machine) and the metrics measured on it (any JSON the reproduction wrote).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from . import checkpoint as ckpt

PRETRAINED_ROOT = Path(__file__).resolve().parents[1] / "pretrained"


def export_pretrained(run_dir: Path, name: str, metrics: dict | None = None, notes: str = "") -> Path:
    """Copy the run's model to ``seqmotion/pretrained/<name>`` and write its model card."""
    config, _ = ckpt.read_model(run_dir)  # verifies weights against config
    training = config.get("training", {})
    provenance = config.get("provenance", {})
    steps_total = training.get("batches_per_epoch", 0) * training.get("curriculum", {}).get("epochs", 0)
    if config.get("step") != steps_total:
        raise ValueError(f"{run_dir} has not finished training (step {config.get('step')} of {steps_total})")
    target = PRETRAINED_ROOT / name
    target.mkdir(parents=True, exist_ok=True)
    for file in (ckpt.WEIGHTS, ckpt.CONFIG):
        shutil.copyfile(Path(run_dir) / file, target / f".{file}.tmp")
        (target / f".{file}.tmp").replace(target / file)
    size_mb = (target / ckpt.WEIGHTS).stat().st_size / 1e6
    model = config["model"]
    lines = [
        f"# Model card: `{name}`",
        "",
        f"Task `{config['task']}` — chunked seq2seq, {model['layers']} × {model['hidden']} LN-LSTM encoder and decoder"
        + (f" + {model['head_hidden']}-unit linear" if model.get("head_hidden") else "")
        + f", C = {model['chunk']}, latent {model['layers'] * model['hidden']} numbers; {size_mb:.1f} MB of weights.",
        "",
        "## How it was trained",
        "",
        f"- Command: `{provenance.get('command', 'unknown')}`",
        f"- Seed: {training.get('seed')}; preset `{training.get('preset')}`; "
        f"options {json.dumps(training.get('options', {}))}",
        f"- Data: {training.get('curriculum', {}).get('epochs')} epochs × {training.get('batches_per_epoch')} "
        f"mini-batches × {training.get('batch_size')} trajectories, drawn fresh from the task's generators",
        f"- Wall time: {config.get('elapsed_seconds', 0) / 60:.1f} min ({config.get('step')} optimiser steps)",
        f"- Machine: {provenance.get('machine', 'unknown')}",
    ]
    if "resumed_with" in provenance:
        lines.append(f"- Resumed once from a checkpoint with `{provenance['resumed_with'].get('command')}`")
    lines += ["", "## Measured", ""]
    if metrics:
        lines += ["```json", json.dumps(metrics, indent=2), "```"]
    else:
        lines.append("(no metrics given)")
    if notes:
        lines += ["", "## Notes", "", notes]
    (target / "MODEL_CARD.md").write_text("\n".join(lines) + "\n")
    return target
