"""seqmotion: motion generators from chunked seq2seq models trained through differentiable physics.

>>> import seqmotion as sm
>>> d = sm.load_pretrained("pancake")        # a Deformer
>>> states = sm.tasks.pancake.data.straight((0.2, 0.0, 2.5), 500)   # a sketch: each task's own in tasks/<name>/
>>> r = d.deform(states)                     # (K, 6) → feasible (K, 6), accelerations, F_c, latent
>>> res = sm.optimize_latent(d, states, sm.objectives.EndPose((0.1, 0.0, 3.14)))
>>> res.save("res.npz"); sm.load_result("res.npz")   # any result: named arrays, no pickle; res.plot() draws it

``sm.sim`` (MuJoCo) and ``sm.lfd`` (learning from demonstration) are imported on first use.
"""

import importlib
from typing import Any

from . import data, physics, tasks
from .api import load, load_pretrained, pretrained_models
from .core.results import load_result
from .errors import CheckpointError
from .latent import objectives, optimize_latent, optimize_trajectory
from .sim.registration import register_envs, register_execution_checks
from .tasks import pancake as _pancake  # noqa: F401 - a built-in task's folder: sm.tasks.pancake.data.straight, ...
from .tasks import sliding as _sliding  # noqa: F401 - sm.tasks.sliding.data.circle, ...
from .tasks.sliding.latent import refine_plan

register_envs()  # gymnasium.make("seqmotion/PancakeArm-v0") (string entry points: MuJoCo is not imported)
register_execution_checks()  # deform(robot=...) reaches the simulator's check (a string entry point too)

__version__ = "0.1.0"
__all__ = [
    "CheckpointError", "data", "lfd", "load", "load_pretrained", "load_result", "objectives", "optimize_latent",
    "optimize_trajectory", "physics", "pretrained_models", "refine_plan", "sim", "tasks",
]


def __getattr__(name: str) -> Any:
    if name in ("sim", "lfd", "deploy"):  # heavy (MuJoCo, ONNX export): imported only when used
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'seqmotion' has no attribute {name!r}")
