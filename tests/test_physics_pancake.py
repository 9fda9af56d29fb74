"""Physical truths of the double integrator and the pancake friction cone (SPEC §§2–3)."""

import math

import numpy as np
import pytest
import torch

from seqmotion.physics import integrator
from seqmotion.tasks.pancake import physics as pancake


def still(theta: float) -> tuple[np.ndarray, np.ndarray]:
    states = np.zeros((1, 6))
    states[0, 2] = theta
    return states, np.zeros((1, 3))


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_still_spatula_holds_at_40_degrees_not_50(sign):
    assert pancake.violation(*still(sign * math.radians(40))).max() == 0.0
    fc = pancake.violation(*still(sign * math.radians(50))).max()
    assert fc == pytest.approx(math.radians(5), abs=1e-12)


def test_cone_edge_is_atan_mu():
    for mu in (0.3, 1.0, 2.0):
        edge = math.atan(mu)
        assert pancake.violation(*still(edge - 1e-6), mu=mu).max() == 0.0
        assert pancake.violation(*still(edge + 1e-6), mu=mu).max() > 0.0


def test_matching_tilt_while_accelerating_gives_zero_psi():
    rng = np.random.default_rng(0)
    accel = np.zeros((200, 3))
    accel[:, :2] = rng.uniform(-15, 15, size=(200, 2))
    states = np.zeros((200, 6))
    states[:, 2] = pancake.tilt_for(accel[:, :2])
    assert np.abs(pancake.psi(states, accel)).max() < 1e-12
    # accelerating in +y: the spatula must lean so the specific force g - u stays normal
    a = np.array([[3.0, 0.0, 0.0]])
    theta = pancake.tilt_for(a[:, :2])[0]
    assert theta == pytest.approx(math.atan2(-3.0, 9.8))
    s = np.zeros((1, 6))
    s[0, 2] = theta
    assert pancake.psi(s, a)[0] == pytest.approx(0.0, abs=1e-15)


def test_psi_wraps_around_pi():
    for theta in (math.pi - 0.1, -math.pi + 0.1, 3 * math.pi - 0.1, 7.0):
        p = pancake.psi(*still(theta))[0]
        assert -math.pi < p <= math.pi
        assert math.isclose(math.cos(p), math.cos(-theta), abs_tol=1e-12)
        assert math.isclose(math.sin(p), math.sin(-theta), abs_tol=1e-12)
    # a full turn is the same attitude
    assert pancake.violation(*still(2 * math.pi + 0.2))[0] == pytest.approx(0.0)
    # upside down is the worst violation: π - atan μ
    assert pancake.violation(*still(math.pi))[0] == pytest.approx(math.pi - math.pi / 4)


def test_free_fall_has_finite_gradient():
    theta = torch.zeros(1, requires_grad=True)
    accel = torch.tensor([[0.0, -pancake.GRAVITY, 0.0]], requires_grad=True)
    pancake.violation_torch(theta, accel).sum().backward()
    assert torch.isfinite(theta.grad).all() and torch.isfinite(accel.grad).all()


def test_violation_rejects_bad_input():
    with pytest.raises(ValueError, match="columns"):
        pancake.violation(np.zeros((5, 4)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="NaN"):
        pancake.violation(np.full((5, 6), np.nan), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="more samples"):
        pancake.violation(np.zeros((3, 6)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="mu"):
        pancake.violation(np.zeros((3, 6)), np.zeros((2, 3)), mu=0.0)


def test_closed_form_integration_matches_sample_by_sample():
    rng = np.random.default_rng(1)
    x0 = rng.normal(size=6)
    u = rng.normal(scale=10, size=(437, 3))
    closed = integrator.integrate_numpy(x0, u)
    ref = [x0]
    for k in range(len(u)):
        ref.append(integrator.step_reference(ref[-1], u[k]))
    np.testing.assert_allclose(closed, np.array(ref), rtol=1e-12, atol=1e-12)


def test_chunk_covariance_matches_sample_by_sample():
    rng = np.random.default_rng(2)
    n_chunks, c, d = 3, 7, 3
    l = rng.normal(size=(n_chunks * c, d, d))
    cov_u = l @ l.transpose(0, 2, 1)
    ref = integrator.propagate_covariance_reference(cov_u)
    carry = integrator.CovarianceCarry.zeros(1, d, torch.float64, torch.device("cpu"))
    pos = []
    for i in range(n_chunks):
        chunk = torch.from_numpy(cov_u[i * c : (i + 1) * c])[None]
        p, carry = integrator.propagate_covariance(carry, chunk)
        pos.append(p[0].numpy())
    pos = np.concatenate(pos)
    np.testing.assert_allclose(pos, ref[1:, :d, :d], rtol=1e-10, atol=1e-20)
    np.testing.assert_allclose(carry.vel[0].numpy(), ref[-1, d:, d:], rtol=1e-10, atol=1e-20)
    np.testing.assert_allclose(carry.cross[0].numpy(), ref[-1, :d, d:], rtol=1e-10, atol=1e-20)
