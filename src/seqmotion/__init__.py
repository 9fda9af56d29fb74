"""seqmotion: motion generators from chunked seq2seq models trained through differentiable physics.

>>> import seqmotion as sm
>>> d = sm.load_pretrained("pancake")        # a Deformer
>>> r = d.deform(states)                     # (K, 6) → feasible (K, 6), accelerations, F_c, latent
"""

from . import data, physics
from .api import load, load_pretrained
from .errors import CheckpointError

__version__ = "0.1.0"
__all__ = ["CheckpointError", "data", "load", "load_pretrained", "physics"]
