"""``seqmotion.lfd.operator``: the scripted operator, now :mod:`seqmotion.lfd.env.operator` (still importable).

The module object *is* :mod:`seqmotion.lfd.env.operator` (one module under two names), so reading, importing or
patching a name here reaches the real one.
"""

import sys

from .env import operator as _module

sys.modules[__name__] = _module
