"""The disturbance observer turns a disturbed plant back into its nominal model."""

import numpy as np
import pytest

from seqmotion.sim.observers import DisturbanceObserver, LowPass, PseudoDerivative


def simulate(use_dob: bool, disturbance: float = 2.0, steps: int = 3000, dt: float = 1e-3) -> float:
    """1-DOF inertia J θ̈ = τ + d under PD to θ = 0; returns the final |θ| [rad]."""
    inertia, kp, kd = 0.05, 100.0, 20.0
    dob = DisturbanceObserver(inertia, cutoff=100.0, dt=dt)
    theta = vel = 0.0
    tau_dis = 0.0
    for _ in range(steps):
        accel_ref = -kp * theta - kd * vel
        tau = inertia * accel_ref + (tau_dis if use_dob else 0.0)  # plant: J θ̈ = τ - τ_dis
        vel += dt * (tau + disturbance) / inertia
        theta += dt * vel
        tau_dis = float(dob.update(tau, vel))
    return abs(theta)


def test_dob_rejects_constant_disturbance_by_an_order_of_magnitude():
    without, with_dob = simulate(False), simulate(True)
    assert without == pytest.approx(2.0 / (0.05 * 100.0), rel=0.05)  # d / (J kp)
    assert with_dob < 0.1 * without


def test_lowpass_step_response_matches_first_order():
    f = LowPass(cutoff=10.0, dt=1e-3)
    out = [float(f.update(1.0)) for _ in range(100)]
    assert out[-1] == pytest.approx(1 - np.exp(-10.0 * 0.1), rel=1e-9)


def test_pseudo_derivative_of_a_ramp_converges_to_its_slope():
    d = PseudoDerivative(cutoff=200.0, dt=1e-3)
    v = [float(d.update(3.0 * k * 1e-3)) for k in range(200)]
    assert v[-1] == pytest.approx(3.0, rel=1e-3)


def test_observer_rejects_nonpositive_parameters():
    with pytest.raises(ValueError):
        DisturbanceObserver(0.0, 10.0, 1e-3)
    with pytest.raises(ValueError):
        LowPass(-1.0, 1e-3)
