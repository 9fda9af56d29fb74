"""The MuJoCo layer every simulated scene shares: the import, gravity, and one control period.

* :func:`import_mujoco` — the one place that imports MuJoCo (and picks the headless GL backend).
* :data:`CONTROL_DT` — the control period of every scene [s].
* :data:`GRAVITY`, :data:`PUSHING_GRAVITY` — the gravity of the scenes [m/s²].
* :func:`control_period` — advance a model by one control period with a torque computed from
  the state at the start of the period (``mj_step1`` → torque → ``mj_step2`` → substeps).

The MH3F arm scenes (:mod:`seqmotion.sim.arm`, pancake and sliding) and the chapter-5 pushing
scene (:mod:`seqmotion.lfd.env.pushing`) and the viewer's replay all step through :func:`control_period`,
the one control step (its ``record`` hook is how a logger or a renderer reads each period).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from typing import Any

import numpy as np

from ..physics.integrator import DT as CONTROL_DT
from ..tasks.pancake.physics import GRAVITY

__all__ = ["CONTROL_DT", "GRAVITY", "PUSHING_GRAVITY", "control_period", "import_mujoco"]

# CONTROL_DT (1 ms, imported above) is the sample period of the planned states (SPEC §2): the
# arm's controller tracks one state per period. The pushing scene's bilateral control runs at
# the same 1 ms (Table 5.1).

# GRAVITY (9.8 m/s², imported above) is the 2-D models' value: the pancake and sliding scenes use
# it so that the simulated arm and the planner agree on the physics they were planned with.

PUSHING_GRAVITY = 9.81
"""Gravity of the chapter-5 pushing scene [m/s²] (MuJoCo's default), not :data:`GRAVITY`.

Why it differs: the pushing demonstrations, the shipped ``pushing`` policy trained on them and
its evaluations (``pretrained/pushing/evaluations.json``) were all made at 9.81. Evaluated at
9.8 (seed 1, 30 trials from each of the three webcams) the policy keeps its success counts, but
the block crosses the centre line up to 23 ms earlier or later and ends up to 3 mm elsewhere:
the shipped numbers would no longer be reproduced exactly. The seeded demonstrations change too: the same
0.6 s episode collected at 9.8 differs from the one at 9.81 by up to 1.6e-5 in its recorded motion (float32
columns), so every dataset's bytes would change. The pushing task has no 2-D model to agree with.
"""


def import_mujoco() -> Any:
    """Import MuJoCo on first use (``import seqmotion.sim`` stays cheap) and return the module.

    On a Linux machine without a display, offscreen rendering needs ``MUJOCO_GL=egl``, which
    MuJoCo reads when it is first imported; set it unless the user chose a backend.
    """
    if "mujoco" not in sys.modules and sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
        os.environ.setdefault("MUJOCO_GL", "egl")
    import mujoco

    return mujoco


def control_period(
    model: Any,
    data: Any,
    torque: Callable[[], np.ndarray | None],
    substeps: int = 1,
    record: Callable[[np.ndarray], bool | None] | None = None,
) -> np.ndarray | None:
    """Advance ``data`` by one control period under a torque held constant over the period.

    The one control step of every simulated arm: the MH3F arm and the standard arms
    (:meth:`seqmotion.sim.arm.Arm.step`, under :func:`~seqmotion.sim.arm.execute` and the viewer's
    replay), the chapter-5 Touch arms and the standard arm holding the pen in the pushing world.

    ``mj_step1`` computes the kinematics, mass matrix and velocities of the current state;
    ``torque()`` is then called to read them (a controller, an observer) and returns the actuator
    command ``(nu,)`` [N m]; ``record(tau)`` (the recording hook) sees the same state with that
    torque (a logger, a renderer); ``mj_step2`` integrates one physics step with it and
    ``substeps - 1`` more ``mj_step`` calls hold it for the rest of the period. (``mj_step1`` +
    ``mj_step2`` is bit-for-bit one ``mj_step``; the split only lets the torque see the state.)

    Args:
        model, data: the ``mujoco.MjModel`` and its ``mujoco.MjData``.
        torque: called once per period after ``mj_step1``; returning ``None`` stops before the
            state is advanced (a caller that detects divergence keeps the state it judged).
        substeps: physics steps per control period (control period / ``model.opt.timestep``).
        record: called with the torque ``(nu,)`` [N m] while ``data`` holds the state it was computed
            from; returning ``False`` stops before the state is advanced (as ``torque`` returning ``None``).

    Returns:
        The torque applied, or ``None`` if ``torque()`` or ``record`` stopped the period.
    """
    mujoco = import_mujoco()
    mujoco.mj_step1(model, data)
    tau = torque()
    if tau is None or (record is not None and record(tau) is False):
        return None
    data.ctrl[:] = tau
    mujoco.mj_step2(model, data)
    for _ in range(substeps - 1):
        mujoco.mj_step(model, data)
    return tau
