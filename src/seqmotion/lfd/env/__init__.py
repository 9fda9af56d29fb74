"""The pushing worlds and the people in them (chapter 5), apart from any policy.

* :mod:`.pushing` — the Touch-arm world: the MuJoCo scene (Touch-like arm, table, block, webcam), its
  master arm, the placements of both benchmarks and the scene variation.
* :mod:`.robot` — the same world with a standard arm holding the pen (:class:`RobotPushingScene`), built on
  the simulator's robot models and its :class:`~seqmotion.sim.arm.Arm`, and its Touch twin.
* :mod:`.teleop` — 4-channel bilateral control at 1 ms, teleoperation (the demonstrations) and the slave's
  half of the law a controller commands (:class:`TouchSlave`).
* :mod:`.operator` — the scripted human operator.
* :mod:`.gym_env` — the Gymnasium environment ``seqmotion/Pushing-v0``.
"""
