"""``seqmotion.lfd.lerobot_import``: the LeRobot import, now :mod:`seqmotion.lfd.data.lerobot_import`
(this name stays importable).

The module object *is* :mod:`seqmotion.lfd.data.lerobot_import` (one module under two names), so reading, importing or
patching a name here reaches the real one.
"""

import sys

from .data import lerobot_import as _module

sys.modules[__name__] = _module
