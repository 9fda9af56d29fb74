"""A task's physics parameters as a frozen dataclass: resolved once, checked once, recorded on every result.

A task declares the numbers its dynamics read at inference — the sliding contact's friction
``SlidingPhysics(mu, mu_dyn)``, the pancake cone's ``PancakePhysics(mu)``, none for the tray — as a
subclass of :class:`Physics` whose ``__post_init__`` checks them (``ValueError`` naming the field).
A trained model resolves its physics from its options (``model.physics``); a user asks for other
physics by name (``planner.plan(line, mu=0.8)`` builds ``model.physics.replace(mu=0.8)``), and the
result records what it was computed at (``plan.physics.mu == 0.8``).

The field order is the order of the ``physics`` vector an exported dynamics graph reads
(:meth:`Physics.vector`), so a deployed model can run at other physics without re-export.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar, TypeVar

import numpy as np

T = TypeVar("T", bound="Physics")
_CLASSES: dict[str, type] = {}
"""Every Physics class defined so far, by :meth:`Physics.key`: what a saved result's physics may be rebuilt as."""


@dataclasses.dataclass(frozen=True)
class Physics:
    """Base class: no parameters. Subclasses are frozen dataclasses of floats checked in ``__post_init__``."""

    _saved_as: ClassVar[str | None] = None

    def __init_subclass__(cls, saved_as: str | None = None, **kwargs: Any) -> None:
        """``saved_as``: the name files know the class by when it is not its ``module.QualName`` — where the
        class stood when results and bundles first recorded it, kept when its module moves (a label, never
        imported)."""
        super().__init_subclass__(**kwargs)
        cls._saved_as = saved_as
        _CLASSES[cls.key()] = cls

    @classmethod
    def key(cls) -> str:
        """How a saved result, a stepper contract and a bundle name the physics class: its ``saved_as`` if it
        declares one, else ``module.QualName``."""
        return cls.__dict__.get("_saved_as") or f"{cls.__module__}.{cls.__qualname__}"

    @staticmethod
    def class_named(key: str) -> type[Physics]:
        """The Physics class saved as ``key`` (:meth:`key`), among those defined (never imported by name)."""
        if key == Physics.key():
            return Physics
        if key not in _CLASSES:
            raise ValueError(f"{key!r} is no physics class of this installation (known: {sorted(_CLASSES)})")
        return _CLASSES[key]

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def from_dict(cls: type[T], values: dict[str, Any]) -> T:
        """The physics named in ``values`` (missing fields take their defaults; unknown names are refused)."""
        unknown = sorted(set(values) - set(cls.names()))
        if unknown:
            raise ValueError(f"unknown physics parameter(s) {unknown} for {cls.__name__}; it has: "
                             f"{list(cls.names()) or 'none'}")
        return cls(**values)

    def replace(self: T, **changes: Any) -> T:
        """A copy with ``changes`` (None values are left as they are), checked like a new one."""
        changes = {k: v for k, v in changes.items() if v is not None}
        return type(self).from_dict({**self.to_dict(), **changes}) if changes else self

    def to_dict(self) -> dict[str, float]:
        return {name: float(getattr(self, name)) for name in self.names()}

    def vector(self) -> np.ndarray:
        """The parameters as float64 ``(P,)`` in field order (the exported dynamics graph's ``physics`` input)."""
        return np.array([getattr(self, name) for name in self.names()], dtype=np.float64)

    def describe(self) -> str:
        """``"mu = 0.8, mu_dyn = 0.4"`` (or ``"none"``)."""
        return ", ".join(f"{k} = {v:g}" for k, v in self.to_dict().items()) or "none"


__all__ = ["Physics"]
