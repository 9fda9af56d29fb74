"""A curriculum is data: stages over epoch ranges that set or ramp named training parameters.

Example — the chapter-2 schedule (SPEC §3) reads::

    Curriculum(epochs=100, initial={"teacher_forcing_prob": 1.0, "phi_max": pi/4, "accel_type_prob": 1.0},
               stages=[Stage(11, 20, {"teacher_forcing_prob": [1.0, 0.0]}),
                       Stage(31, 40, {"phi_max": [pi/4, pi]}),
                       Stage(61, 80, {"accel_type_prob": [1.0, 0.0]})])

A stage covers epochs ``start..end`` (1-based, inclusive). A plain number sets a parameter
from the stage's start on; a pair ``[a, b]`` ramps it linearly from ``a`` at the start of epoch
``start`` to ``b`` at the end of epoch ``end``, per training step, and holds ``b`` afterwards.
Parameters keep their value until a later stage changes them, so a schedule only lists what
changes. Which parameters exist, and what they mean, is up to the task (ch. 3 declares loss
switches and command mixtures the same way).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

from ..errors import check_number

Value = float | list[float]
P = TypeVar("P", bound="CurriculumParams")


@dataclass(frozen=True)
class CurriculumParams:
    """A task's curriculum parameters at one training step, typed: subclass with one float field per name
    the task's curriculum sets (``teacher_forcing_prob``, ``phi_max``, ...). The trainer builds one per
    step from :meth:`Curriculum.at` and hands it to the task's ``sample`` and ``loss``."""

    @classmethod
    def from_values(cls: type[P], values: Mapping[str, float]) -> P:
        """The parameters named in ``values``; a name the class lacks, or a field no stage sets, is refused."""
        names = [f.name for f in dataclasses.fields(cls)]
        unknown, missing = sorted(set(values) - set(names)), sorted(set(names) - set(values))
        if unknown or missing:
            detail = (f" (unknown: {unknown})" if unknown else "") + (f" (never set: {missing})" if missing else "")
            raise ValueError(f"the curriculum sets {sorted(values)}, but {cls.__name__} has fields {names}{detail}")
        return cls(**{k: float(v) for k, v in values.items()})

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass
class Stage:
    """Epochs ``start..end`` (1-based, inclusive) and the parameters they set or ramp."""

    start: int
    end: int
    set: dict[str, Value] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not 1 <= self.start <= self.end:
            raise ValueError(f"stage epochs must satisfy 1 <= start <= end, got {self.start}..{self.end}")
        for name, value in self.set.items():
            if isinstance(value, (list, tuple)) and len(value) != 2:
                raise ValueError(f"ramp of {name!r} must be [from, to], got {value}")


@dataclass
class Curriculum:
    """A schedule of training parameters over ``epochs`` epochs."""

    epochs: int
    initial: dict[str, float]
    stages: list[Stage] = field(default_factory=list)

    def __post_init__(self) -> None:
        check_number("a curriculum's epochs", self.epochs, minimum=1, integer=True)
        for stage in self.stages:
            if stage.end > self.epochs:
                raise ValueError(f"stage {stage.start}..{stage.end} ends after the last epoch {self.epochs}")
            unknown = set(stage.set) - set(self.initial)
            if unknown:
                raise ValueError(f"stage {stage.start}..{stage.end} sets parameters without initial value: {unknown}")

    def at(self, epoch: int, fraction: float = 0.0) -> dict[str, float]:
        """Parameters in force ``fraction`` ∈ [0, 1) of the way through ``epoch`` (1-based)."""
        if not 1 <= epoch <= self.epochs:
            raise ValueError(f"epoch {epoch} outside 1..{self.epochs}")
        t = epoch - 1 + fraction  # continuous time in epochs since the start
        params = dict(self.initial)
        for stage in sorted(self.stages, key=lambda s: s.start):
            begin, span = stage.start - 1, stage.end - stage.start + 1
            if t < begin:
                continue
            progress = min(1.0, (t - begin) / span)
            for name, value in stage.set.items():
                if isinstance(value, (list, tuple)):
                    params[name] = float(value[0] + (value[1] - value[0]) * progress)
                else:
                    params[name] = float(value)
        return params

    def final(self) -> dict[str, float]:
        """The parameters in force once every stage has finished (the end of the last epoch)."""
        params = dict(self.initial)
        for stage in sorted(self.stages, key=lambda s: s.start):
            for name, value in stage.set.items():
                params[name] = float(value[1] if isinstance(value, (list, tuple)) else value)
        return params

    def span(self, name: str) -> tuple[float, float]:
        """The lowest and highest value parameter ``name`` takes over the whole schedule (a ramp is linear, so its
        ends bound it); ``ValueError`` if the curriculum does not set ``name``."""
        if name not in self.initial:
            raise ValueError(f"the curriculum sets no parameter {name!r} (it sets {sorted(self.initial)})")
        values = [float(self.initial[name])]
        for stage in self.stages:
            value = stage.set.get(name)
            if value is not None:
                values += [float(v) for v in value] if isinstance(value, (list, tuple)) else [float(value)]
        return min(values), max(values)

    def at_final_stage(self, epochs: int | None = None) -> Curriculum:
        """``epochs`` epochs (default: as many as this) that hold :meth:`final`'s parameters throughout:
        for fine-tuning a model that has been through the whole schedule."""
        return Curriculum(self.epochs if epochs is None else epochs, self.final(), [])

    def scaled(self, epochs: int) -> Curriculum:
        """The same schedule squeezed or stretched to ``epochs`` epochs (for small test runs).

        Stage boundaries move proportionally; a stage keeps at least one epoch.
        """
        if epochs == self.epochs:
            return self
        factor = epochs / self.epochs

        def move(e: int) -> int:
            return min(epochs, max(1, round((e - 1) * factor) + 1))

        stages = []
        for s in self.stages:
            start = move(s.start)
            end = max(start, min(epochs, round(s.end * factor)))
            stages.append(Stage(start, end, dict(s.set)))
        return Curriculum(epochs, dict(self.initial), stages)

    def to_dict(self) -> dict:
        return {
            "epochs": self.epochs,
            "initial": dict(self.initial),
            "stages": [{"start": s.start, "end": s.end, "set": dict(s.set)} for s in self.stages],
        }

    @classmethod
    def from_dict(cls, data: dict) -> Curriculum:
        stages = [Stage(int(s["start"]), int(s["end"]), dict(s["set"])) for s in data.get("stages", [])]
        return cls(int(data["epochs"]), {k: float(v) for k, v in data["initial"].items()}, stages)
