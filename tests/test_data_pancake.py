"""Pancake input generators (eqs. 2.26–2.33): bounds, feasibility, determinism."""

import math

import numpy as np
import pytest

from seqmotion.data.trajectories import s_curve
from seqmotion.physics import integrator
from seqmotion.tasks.pancake import data as gen
from seqmotion.tasks.pancake import physics as phys


def valid_violation(batch):
    out = []
    for b in range(len(batch)):
        k = batch.lengths[b]
        out.append(phys.violation(batch.states[b, :k], batch.accel[b, : k - 1]).max())
    return np.array(out)


def test_acceleration_type_at_atan_mu_is_always_feasible():
    batch = gen.acceleration_type(3000, np.random.default_rng(0), phi_max=math.pi / 4)
    assert valid_violation(batch).max() == 0.0


def test_acceleration_type_at_pi_often_violates():
    batch = gen.acceleration_type(500, np.random.default_rng(1), phi_max=math.pi)
    assert (valid_violation(batch) > 0.2).mean() > 0.3


def test_acceleration_type_states_are_the_integrated_inputs():
    batch = gen.acceleration_type(5, np.random.default_rng(2), length=(100, 500))
    for b in range(5):
        k = batch.lengths[b]
        states = integrator.integrate_numpy(np.zeros(6), batch.accel[b, : k - 1])
        np.testing.assert_allclose(batch.states[b, :k], states, atol=1e-12)
        # padding repeats the last sample
        assert np.all(batch.states[b, k:] == batch.states[b, k - 1])


def test_lengths_in_range_and_seeded():
    a = gen.position_type(400, np.random.default_rng(3))
    b = gen.position_type(400, np.random.default_rng(3))
    assert a.lengths.min() >= 100 and a.lengths.max() <= 500
    np.testing.assert_array_equal(a.states, b.states)
    c = gen.position_type(400, np.random.default_rng(4))
    assert not np.array_equal(a.states, c.states)


def test_position_type_starts_and_ends_at_rest_inside_bounds():
    batch = gen.position_type(300, np.random.default_rng(5))
    assert np.all(batch.states[:, 0] == 0.0)
    for b in range(len(batch)):
        end = batch.states[b, batch.lengths[b] - 1]
        assert np.allclose(end[3:], 0.0, atol=1e-6)
    assert np.all(np.abs(batch.states[:, -1, :3]) <= [0.3, 0.3, 3.14])


def test_position_type_velocity_is_the_derivative_of_position():
    batch = gen.position_type(3, np.random.default_rng(6), length=400)
    pos, vel = batch.states[:, :, :3], batch.states[:, :, 3:]
    fd = np.gradient(pos, 1e-3, axis=1)
    np.testing.assert_allclose(vel[:, 5:-5], fd[:, 5:-5], atol=2e-3 * np.abs(vel).max())


def test_s_curve_is_rest_to_rest_and_monotone():
    tau = np.linspace(0, 1, 1001)
    s, ds, dds = s_curve(tau)
    assert s[0] == 0 and s[-1] == pytest.approx(1.0)
    assert ds[0] == 0 and ds[-1] == pytest.approx(0.0, abs=1e-9)
    assert dds[0] == 0 and dds[-1] == pytest.approx(0.0, abs=1e-9)
    assert np.all(np.diff(s) >= 0)


def test_mixture_respects_probability_extremes():
    rng = np.random.default_rng(7)
    only_pos = gen.mixture(50, rng, accel_type_prob=0.0, phi_max=math.pi)
    # position-type trajectories end at rest
    ends = only_pos.states[np.arange(50), only_pos.lengths - 1, 3:]
    assert np.allclose(ends, 0, atol=1e-6)
    with pytest.raises(ValueError, match="accel_type_prob"):
        gen.mixture(5, rng, accel_type_prob=1.5, phi_max=1.0)


def test_straight_reaches_the_target():
    s = gen.straight((0.1, -0.1, math.pi), 500)
    assert s.shape == (500, 6)
    np.testing.assert_allclose(s[-1, :3], [0.1, -0.1, math.pi], atol=1e-12)
    lin = gen.straight((0, 0, -3 * math.pi / 4), 500, timing="linear")
    assert np.allclose(np.diff(lin[:, 2]), lin[1, 2] - lin[0, 2])
