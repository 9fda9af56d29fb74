"""Losses, curricula as data, checkpoints and the training loop."""

from .curriculum import Curriculum, Stage

__all__ = ["Curriculum", "Stage"]
