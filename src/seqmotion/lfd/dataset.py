"""``seqmotion.lfd.dataset``: the datasets, now :mod:`seqmotion.lfd.data.dataset` (this name stays importable).

The module object *is* :mod:`seqmotion.lfd.data.dataset` (one module under two names), so reading, importing or
patching a name here reaches the real one.
"""

import sys

from .data import dataset as _module

sys.modules[__name__] = _module
