"""The pancake task (ch. 2): turning a rough spatula motion into one that keeps the pancake on.

One folder for what is the pancake task's alone, each file in the layer of its role (``tests/test_layers.py``):

* :mod:`.physics` — the friction cone on the planar spatula: ``PancakePhysics``, ψ, the violation F_c, its
  constraint for the exact polish (rank of ``physics``);
* :mod:`.data` — the acceleration- and position-type training motions and the S-curve sketch
  ``straight`` (``sm.tasks.pancake.data.straight``; rank of ``data``);
* :mod:`.task` — the task (:class:`PancakeTask`: options, curriculum, loss, exact form), its result
  (:class:`DeformResult`) and trained model (:class:`Deformer`, ``sm.load_pretrained("pancake")``), exported here;
* :mod:`.latent` — J2's bands (:class:`~.latent.PancakeRanges`, what ``sm.objectives.Ranges()`` without field
  names builds: registered when this folder is imported), the true J1 and the IPOPT peer of ch. 4, built on the
  latent optimiser below the tasks (the task's rank).

Its MuJoCo run stays in :mod:`seqmotion.sim.pancake` (``sm.sim.run_pancake``), beside the simulator's other scenes.
"""

from ...core.execution import BindingLimit, ExecutionCheck
from . import data, latent, physics
from .task import (
    END_POSITION_TOLERANCE,
    END_SPEED_TOLERANCE,
    FEASIBLE_TOLERANCE,
    JOINT_POLISH_NORMAL_FLOOR,
    POLISH_ACCEL_LIMITS,
    POLISH_NORMAL_FLOOR,
    POLISH_REACH,
    POLISH_SMOOTHNESS,
    POLISH_TRAVEL_ACCEL,
    RESULT_PARTS,
    TASK,
    THETA_WEIGHT,
    Deformer,
    DeformResult,
    PancakeOptions,
    PancakeParams,
    PancakeTask,
    chapter2_curriculum,
)

__all__ = [
    "END_POSITION_TOLERANCE", "END_SPEED_TOLERANCE", "FEASIBLE_TOLERANCE", "JOINT_POLISH_NORMAL_FLOOR",
    "POLISH_ACCEL_LIMITS", "POLISH_NORMAL_FLOOR", "POLISH_REACH", "POLISH_SMOOTHNESS", "POLISH_TRAVEL_ACCEL",
    "RESULT_PARTS", "TASK", "THETA_WEIGHT", "BindingLimit", "DeformResult", "Deformer", "ExecutionCheck",
    "PancakeOptions", "PancakeParams", "PancakeTask", "chapter2_curriculum", "data", "latent", "physics",
]
