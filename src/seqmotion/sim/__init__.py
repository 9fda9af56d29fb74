"""MuJoCo scenes, controllers and runners that execute generated motions on simulated robots."""
