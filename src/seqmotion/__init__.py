"""seqmotion: motion generators from chunked seq2seq models trained through differentiable physics."""

from . import data, physics
from .errors import CheckpointError

__version__ = "0.1.0"
__all__ = ["CheckpointError", "data", "physics"]
