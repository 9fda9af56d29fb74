"""``seqmotion.lfd.lerobot``: the LeRobot export, now :mod:`seqmotion.lfd.data.lerobot` (this name stays importable).

The module object *is* :mod:`seqmotion.lfd.data.lerobot` (one module under two names), so reading, importing or
patching a name here reaches the real one.
"""

import sys

from .data import lerobot as _module

sys.modules[__name__] = _module
