"""One contract for every trained model: save, load, describe, ship.

:class:`PretrainedModel` is the base of the seq2seq models' user-facing objects (``Deformer``,
``SlidingPlanner``, a plug-in task's model) and of the learning-from-demonstration policy. A
model directory is ``model.safetensors`` + ``config.json`` (:mod:`.checkpoint`: atomic writes,
a hash tying config to weights, no pickle). A subclass says what its weights and config are
(:meth:`weights`, :meth:`config_json`) and how to rebuild itself from them
(:meth:`from_checkpoint`); ``save_pretrained``/``from_pretrained`` round-trip through that, and
:meth:`model_card` writes the card every shipped model carries, reading the machine and
command that :mod:`.provenance` recorded at training time.

:func:`export_pretrained` is the one exporter: it copies a model directory to where a package
ships its models and writes the card beside it.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import torch

from ..io import atomic_path, atomic_write_bytes, check_writable_dir
from . import checkpoint as ckpt

M = TypeVar("M", bound="PretrainedModel")
CARD = "MODEL_CARD.md"


class PretrainedModel:
    """Base of every trained model (see the module docstring).

    Class attributes:
        task: the registered task the model belongs to (``None`` for a generic class whose
            instances take the task from their config).
        config_class: the dataclass describing the architecture (``Seq2SeqConfig``, ``PolicyConfig``).
    """

    task: ClassVar[str | None] = None
    config_class: ClassVar[type]

    # --- what a subclass provides ------------------------------------------------------------

    def weights(self) -> dict[str, torch.Tensor]:
        """The tensors written to ``model.safetensors``."""
        raise NotImplementedError

    def config_json(self) -> dict[str, Any]:
        """What ``config.json`` holds (at least ``"task"``); format and hash are added on writing."""
        raise NotImplementedError

    @classmethod
    def from_checkpoint(cls: type[M], config: dict[str, Any], tensors: dict[str, torch.Tensor], source: str) -> M:
        """Rebuild the model from a verified config and its weights.

        Raises:
            seqmotion.CheckpointError: the config does not describe such a model or the weights do not fit it.
        """
        raise NotImplementedError

    def card_summary(self, name: str) -> list[str]:
        """Markdown lines saying what the model is and how to use it (``name``: what it ships as)."""
        return [f"Task `{self.config_json().get('task')}`.", "", f"Load it with `sm.load_pretrained({name!r})`."]

    def card_training(self) -> list[str]:
        """Markdown lines saying how it was trained (command, seed, data, wall time, machine)."""
        return ["(no training record)"]

    # --- the shared contract -------------------------------------------------------------------

    @property
    def name(self) -> str:
        """The model's kind (its class name), as ``config.json`` records it."""
        return type(self).__name__

    def save_pretrained(self, directory: str | Path) -> Path:
        """Write ``model.safetensors`` + ``config.json`` atomically; ``from_pretrained`` reads them back."""
        if getattr(self, "is_quantized", False):
            raise ValueError("a quantized copy is for inference only; save the float model it came from")
        directory = Path(directory)
        ckpt.write_model(directory, self.weights(), self.config_json())
        return directory

    @classmethod
    def from_pretrained(cls: type[M], directory: str | Path) -> M:
        """Load a model directory (or a training run's latest checkpoint) written for this class's task.

        Raises:
            seqmotion.CheckpointError: missing, corrupt or mismatched files, or another task's model.
        """
        directory = ckpt.resolve_model_dir(Path(directory))
        config, tensors = ckpt.read_model(directory, expected_task=cls.task)
        cls._dry_run(config, tensors, str(directory))
        return cls.from_checkpoint(config, tensors, str(directory))

    @classmethod
    def _dry_run(cls, config: dict[str, Any], tensors: dict[str, torch.Tensor], source: str) -> None:
        """Build the model ``config`` describes on PyTorch's ``meta`` device (no memory) and fit the weights'
        shapes into it: a config that does not fit its weights is refused (CheckpointError) before anything
        is allocated, however large a model it describes. Anything else the meta device cannot do is left
        to the real load, which checks everything again."""
        shapes = {k: torch.empty(v.shape, dtype=v.dtype, device="meta") for k, v in tensors.items()}
        try:
            with torch.device("meta"):
                cls.from_checkpoint(config, shapes, source)
        except ValueError:  # CheckpointError included: a bad config, or weights that do not fit it
            raise
        except Exception:  # noqa: BLE001 - an operation the meta device does not support: inconclusive
            pass

    def model_card(
        self, name: str, metrics: dict | None = None, notes: str = "", size_mb: float | None = None,
        measured: list[str] | None = None,
    ) -> str:
        """The Markdown model card shipped beside the weights.

        Args:
            name: the name the model ships as (the card's title).
            metrics: measured numbers, shown as JSON.
            notes: free text for a Notes section.
            size_mb: size of the weights file [MB].
            measured: Markdown lines that state the measurements for people (before the JSON).
        """
        lines = [f"# Model card: `{name}`", ""] + self.card_summary(name)
        if size_mb is not None:
            lines += ["", f"Weights: {size_mb:.2f} MB (`model.safetensors`, no pickle)."]
        lines += ["", "## How it was trained", ""] + self.card_training()
        lines += ["", "## Measured", ""]
        if measured:
            lines += [*measured, ""]
        if metrics:
            lines += ["```json", json.dumps(metrics, indent=2), "```"]
        elif not measured:
            lines.append("(no metrics given)")
        if notes:
            lines += ["", "## Notes", "", notes]
        return "\n".join(lines) + "\n"


def export_pretrained(
    model: PretrainedModel,
    source: str | Path,
    name: str,
    root: str | Path,
    metrics: dict | None = None,
    notes: str = "",
    measured: list[str] | None = None,
) -> Path:
    """Ship ``model`` (loaded from the model directory ``source``) as ``root/name`` with its card.

    The weights and config are copied byte for byte (so the hashes in the config still hold).
    A new ``root/name`` is written whole under a temporary name and renamed into place (complete
    or absent); an existing one gets the weights, then the config, then the card, each through
    a temporary name.

    Returns:
        The target directory.

    Raises:
        ValueError: ``name`` is not one plain folder name (``"../x"``, ``".hidden"``, ``"a/b"``),
            ``source`` is not a model directory, or ``root`` cannot be written.
    """
    check_pretrained_name(name)
    source, target = Path(source), Path(root) / name
    for file in (ckpt.WEIGHTS, ckpt.CONFIG):
        if not (source / file).is_file():
            raise ValueError(f"{source} has no {file}: not a model directory")
    check_writable_dir(Path(root), "pretrained folder")
    card = model.model_card(name, metrics, notes, (source / ckpt.WEIGHTS).stat().st_size / 1e6, measured)
    if not target.exists():  # a new model appears whole (weights, config and card) or not at all
        with atomic_path(target, directory=True) as tmp:
            for file in (ckpt.WEIGHTS, ckpt.CONFIG):
                shutil.copyfile(source / file, tmp / file)
            (tmp / CARD).write_bytes(card.encode())
        return target
    for file in (ckpt.WEIGHTS, ckpt.CONFIG):  # replacing one: the config, which names its weights, last
        with atomic_path(target / file) as tmp:
            shutil.copyfile(source / file, tmp)
    atomic_write_bytes(target / CARD, card.encode())
    return target


PRETRAINED_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")
"""What a shipped model may be called: one plain folder name (no path, no leading dot)."""


def check_pretrained_name(name: object) -> str:
    """``ValueError`` unless ``name`` is a plain folder name (letters, digits, ``.``, ``_``, ``-``)."""
    if not isinstance(name, str) or not PRETRAINED_NAME.fullmatch(name) or ".." in name:
        raise ValueError(
            f"a pretrained name is one plain folder name (letters, digits, '.', '_', '-'; at most 100), got {name!r}"
        )
    return name
