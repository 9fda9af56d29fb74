"""Named state layouts: what each column of a task's trajectories is, and in which unit.

Everything task-generic (results, the online stepper, objectives, CSV columns, plots, the CLI)
reads column names and units from a task's layouts instead of assuming the pancake's six.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class StateLayout:
    """Column names and units of a trajectory array ``(..., K, dim)``.

    Attributes:
        names: one name per column, e.g. ``("y", "z", "theta", "v_y", "v_z", "v_theta")``.
        units: one SI unit per column, e.g. ``("m", "m", "rad", "m/s", "m/s", "rad/s")``.
        kind: a short name for messages (``"pancake state"``).
    """

    names: tuple[str, ...]
    units: tuple[str, ...]
    kind: str = "state"

    def __post_init__(self) -> None:
        if len(self.names) != len(self.units) or not self.names:
            raise ValueError(f"a layout needs one unit per name, got {self.names} and {self.units}")
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"layout names must be unique, got {self.names}")

    @property
    def dim(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Column of ``name``; ``ValueError`` naming the known columns if there is none."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"{self.kind} has no column {name!r}; its columns: {list(self.names)}") from None

    def labels(self) -> list[str]:
        """``"name [unit]"`` per column, for plots and CSV headers."""
        return [f"{n} [{u}]" for n, u in zip(self.names, self.units, strict=True)]

    def __str__(self) -> str:
        return f"{self.kind} ({', '.join(self.labels())})"
