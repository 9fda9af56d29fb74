"""Ship a trained pushing policy inside the package: ``seqmotion lfd export POLICY_DIR``.

The copying and the model card are the library's one exporter,
:func:`seqmotion.training.pretrained.export_pretrained`: the policy's ``model.safetensors`` +
``config.json`` (written by ``seqmotion lfd train``) go to ``seqmotion/pretrained/pushing/``
(or ``--name``) and ``MODEL_CARD.md`` is written from what the training recorded in the
config (command, seed, settings, wall times, the machine as
:func:`seqmotion.training.provenance.machine_record` saw it; see
:meth:`~seqmotion.lfd.policy.policy.PushingPolicy.card_training`). What is chapter-5's own is here:
the evaluations given (JSON files written by ``seqmotion lfd evaluate --json``) become the
card's measured success rates and ``evaluations.json`` beside the model.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..core.registry import home_package
from ..io import atomic_write_bytes, read_json
from ..training.pretrained import check_pretrained_name, export_pretrained
from .policy.policy import PushingPolicy
from .task import TASK

PRETRAINED_ROOT = home_package(TASK) / "pretrained"
"""Where the pushing task's shipped models live (``seqmotion/pretrained/``)."""
EVALUATIONS = "evaluations.json"


def evaluation_summary(path: str | Path) -> tuple[str, str, dict[str, Any]]:
    """``(label, Markdown line, brief)`` of one ``seqmotion lfd evaluate --json`` result file.

    The label names the policy and camera (``"proposed (smaller), default camera"``), the line
    gives the success rate with its trials and per-position cells, the brief the numbers.
    """
    result = read_json(path, "evaluation result")
    cells = ", ".join(f"{k} {v[0]}/{v[1]}" for k, v in result["per_position"].items())
    who = (
        f"{result['policy_kind'].replace('_', '-')} ({result['policy_preset']})"
        if result.get("policy_kind")
        else f"`{Path(path).stem}`"
    )
    benchmark = result.get("benchmark", "chapter")
    label = f"{who}, {result['camera']} camera" + (", hard benchmark" if benchmark == "hard" else "")
    low, high = result.get("wilson_95", (None, None))
    interval = f", 95 % Wilson {low:.0%}–{high:.0%}" if low is not None else ""
    line = (
        f"- {label}: **{result['success_rate']:.1%}** ({result['successes']}/{result['n_trials']} trials{interval}, "
        f"evaluation seed {result['seed']}) — {cells}"
    )
    brief = {k: result[k] for k in ("camera", "seed", "success_rate", "successes", "n_trials", "per_position")}
    brief["benchmark"] = benchmark
    return label, line, brief


def export_policy(
    policy_dir: str | Path,
    name: str = "pushing",
    evaluations: list[str | Path] | None = None,
    notes: str = "",
    root: str | Path = PRETRAINED_ROOT,
) -> Path:
    """Copy a policy directory to ``root/name`` and write its model card (and ``evaluations.json``).

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
    check_pretrained_name(name)  # before anything is read
    policy_dir = Path(policy_dir)
    policy = PushingPolicy.from_pretrained(policy_dir)  # verifies weights against the config
    metrics: dict[str, Any] = {}
    lines: list[str] = []
    for path in evaluations or []:
        label, line, brief = evaluation_summary(path)
        key = f"{label}, evaluation seed {brief['seed']}"
        metrics[key if key not in metrics else f"{key} ({len(metrics) + 1})"] = brief
        lines.append(line)
    target = export_pretrained(policy, policy_dir, name, root, metrics or None, notes, measured=lines)
    if metrics:
        briefs = list(metrics.values())
        atomic_write_bytes(target / EVALUATIONS, (json.dumps(briefs, indent=1) + "\n").encode())
    return target
