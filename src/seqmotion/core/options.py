"""Typed task options: one validated dataclass per task, saved with every model.

A task's options (friction, loss weights, lengths, ...) are the one place every consumer
reads them: the loss during training, and after training the results, objectives, CLI,
simulator and plots, through ``model.options``. A model trained at μ = 0.8 is judged at 0.8
everywhere, because nothing reads μ from anywhere else.

Options travel as JSON in ``config.json`` (``training.options``); :meth:`TaskOptions.from_dict`
turns them back into the dataclass, filling options a model was saved without with their
defaults and refusing unknown keys and bad values by name.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from typing import Any, TypeVar

from ..errors import MAX_LENGTH, check_json_number

T = TypeVar("T", bound="TaskOptions")


@dataclasses.dataclass(frozen=True)
class TaskOptions:
    """Base class of a task's options. Subclasses are frozen dataclasses that check their fields
    in ``__post_init__`` (raise ``ValueError`` naming the option)."""

    @classmethod
    def names(cls) -> list[str]:
        return [f.name for f in dataclasses.fields(cls)]

    @classmethod
    def from_dict(cls: type[T], data: Mapping[str, Any] | None) -> T:
        """The options in ``data`` (missing ones take their defaults).

        Raises:
            ValueError: an unknown option, or a value its check refuses.
        """
        if data is not None and not isinstance(data, Mapping):
            raise ValueError(f"options of {cls.__name__} must map names to values, got {type(data).__name__}")
        data = dict(data or {})
        unknown = sorted(set(data) - set(cls.names()))
        if unknown:
            raise ValueError(f"unknown option(s) {unknown} for {cls.__name__}; known options: {cls.names()}")
        try:
            return cls(**data)
        except TypeError as exc:  # e.g. a value of a type the checks cannot compare
            raise ValueError(f"bad option value for {cls.__name__}: {exc}") from None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready options (tuples become lists, as ``config.json`` stores them)."""
        return json.loads(json.dumps(dataclasses.asdict(self)))

    def replace(self: T, **changes: Any) -> T:
        """A copy with ``changes`` applied and checked (unknown names refused)."""
        return type(self).from_dict({**self.to_dict(), **changes})

    def parse(self, key: str, raw: str) -> Any:
        """The value of ``--set key=raw``: JSON, or a bare word for a text option.

        Raises:
            ValueError: an unknown option or a value that is not JSON.
        """
        if key not in self.names():
            raise ValueError(f"unknown option {key!r}; options of {type(self).__name__}: {self.names()}")
        try:
            return json.loads(raw)
        except json.JSONDecodeError:
            field = next(f for f in dataclasses.fields(self) if f.name == key)
            if "str" in str(field.type):  # text options take bare words: --set pan_shaking=velocity
                return raw
            raise ValueError(f"--set {key}=...: {raw!r} is not a JSON value") from None


# --- checks used by the tasks' __post_init__ -----------------------------------------------------


def check_positive(name: str, value: Any, allow_zero: bool = False) -> None:
    """Refuse a value that is not a finite number > 0 (≥ 0 with ``allow_zero``); options are stored as JSON, so a
    NumPy scalar is refused too (:func:`~seqmotion.errors.check_json_number`)."""
    check_json_number(f"option {name}", value, minimum=0.0, strict_minimum=not allow_zero)


def check_count(name: str, value: Any, minimum: int = 1, maximum: int = MAX_LENGTH) -> None:
    """Refuse a value that is not an integer in ``[minimum, maximum]`` (a NumPy scalar too)."""
    check_json_number(f"option {name}", value, minimum=minimum, maximum=maximum, integer=True)


def check_length_range(name: str, value: Any, minimum: int = 2) -> None:
    """A ``[K_min, K_max]`` pair of trajectory lengths (at most :data:`MAX_LENGTH`)."""
    if (
        not isinstance(value, list | tuple)
        or len(value) != 2
        or not all(isinstance(v, int) and not isinstance(v, bool) for v in value)
        or not minimum <= value[0] <= value[1] <= MAX_LENGTH
    ):
        raise ValueError(
            f"option {name} must be [K_min, K_max] with {minimum} <= K_min <= K_max <= {MAX_LENGTH}, got {value!r}"
        )


def check_choice(name: str, value: Any, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f"option {name} must be one of {list(choices)}, got {value!r}")
