"""MuJoCo's friction in the scenes matches the Coulomb friction of the 2-D models."""

import math

import numpy as np
import pytest

from seqmotion.sim import run_pancake, run_sliding
from seqmotion.sim.arm import workspace_problem
from seqmotion.sim.kinematics import planar_reference
from seqmotion.sim.motions import pan_circle, still
from seqmotion.tasks.pancake.data import acceleration_type
from seqmotion.tasks.pancake.physics import violation

MU_G = 0.5 * 9.8  # breakaway acceleration of the pan's object (μ = 0.5)


def test_still_spatula_holds_the_pancake_at_40_degrees():
    result = run_pancake(still(math.radians(40), duration=1.0), hold_time=0.0)
    assert not result.contact_lost
    assert result.max_slip < 1e-3  # placed 0.1 mm above the blade; no creep after landing
    assert result.slip[-1] - result.slip[200] < 1e-4  # held still for 0.8 s: no creep
    assert result.on_spatula


def test_still_spatula_drops_the_pancake_at_50_degrees_with_coulombs_acceleration():
    result = run_pancake(still(math.radians(50), duration=0.4), hold_time=0.0, settle_time=0.0)
    assert result.contact_lost
    # Sliding down a 50° incline with μ = 1: a = g (sin 50° - cos 50°) = 1.21 m/s².
    t, slip = result.time[: result.n_motion], result.slip[: result.n_motion]
    sliding = (slip > 1e-3) & (slip < 0.06)
    accel = np.polyfit(t[sliding], np.gradient(slip, 1e-3)[sliding], 1)[0]
    assert accel == pytest.approx(9.8 * (math.sin(math.radians(50)) - math.cos(math.radians(50))), rel=0.05)


def test_the_tilt_limit_is_atan_mu_on_both_sides():
    for sign in (1, -1):
        assert not run_pancake(still(sign * math.radians(42), 0.4), hold_time=0).contact_lost
        assert run_pancake(still(sign * math.radians(48), 0.4), hold_time=0).contact_lost


def test_object_on_a_still_pan_stays_put():
    result = run_sliding(np.zeros((1000, 4)), hold_time=0.0)
    assert not result.fell_off and not result.tipped
    assert np.abs(result.object_path - result.object_path[0]).max() < 2e-4
    assert np.abs(result.object_height).max() < 1e-3


@pytest.mark.parametrize(("fraction", "slides"), [(0.85, False), (1.15, True)])
def test_object_breaks_away_near_mu_g(fraction, slides):
    """On a circle at constant |u_p|, the object sticks below μg and slides above it."""
    result = run_sliding(pan_circle(fraction * MU_G, freq=3.0, duration=1.6, ramp=1.0), hold_time=0.0)
    steady = slice(1100, result.n_motion)
    accel = np.linalg.norm(result.pan_accel[steady], axis=1)
    assert accel.mean() == pytest.approx(fraction * MU_G, rel=0.05)  # the arm really shook it so hard
    moved = np.linalg.norm(result.object_path[steady] - result.object_path[steady][0], axis=1).max()
    assert (moved > 3e-3) == slides, f"object moved {moved * 1e3:.2f} mm at {fraction} μg"


def _acceleration_type(phi_max: float, seed: int, want_violation: bool) -> np.ndarray:
    """A short acceleration-type trajectory inside the arm's workspace."""
    rng = np.random.default_rng(seed)
    batch = acceleration_type(64, rng, phi_max=phi_max, length=(100, 160))
    for i in range(len(batch)):
        k = batch.lengths[i]
        states, accel = batch.states[i, :k], batch.accel[i, : k - 1]
        if want_violation and violation(states, accel).max() <= 0.2:
            continue
        if workspace_problem(planar_reference(states), "pancake") is None:
            return states
    raise AssertionError("no suitable trajectory drawn")


def test_feasible_acceleration_type_motion_keeps_the_pancake():
    result = run_pancake(_acceleration_type(math.pi / 4, seed=3, want_violation=False), hold_time=0.0)
    assert result.diverged is None
    assert not result.contact_lost
    assert result.executed_violation.max() < 0.05  # the arm really did a feasible motion


def test_violating_acceleration_type_motion_loses_the_pancake():
    result = run_pancake(_acceleration_type(math.pi, seed=4, want_violation=True), hold_time=0.0)
    assert result.diverged is None
    assert result.contact_lost
