"""Physical truths of the Coulomb stick/slip contact model (eq. 3.9, SPEC §4)."""

import numpy as np
import pytest
import torch

from seqmotion.physics.integrator import implied_accel
from seqmotion.tasks.sliding import physics as sliding

G, MU, MU_DYN = sliding.GRAVITY, sliding.MU, sliding.MU_DYN


def constant(accel, steps):
    return np.tile(np.asarray(accel, dtype=np.float64), (steps, 1))


def test_object_stays_exactly_put_below_mu_g():
    rng = np.random.default_rng(0)
    u = rng.normal(size=(5000, 2))
    u *= (0.99 * MU * G) * rng.uniform(0, 1, size=(5000, 1)) / np.linalg.norm(u, axis=1, keepdims=True)
    pan, rel = sliding.rollout(u)
    assert np.all(rel == 0.0)  # exactly, not approximately
    assert np.abs(pan).max() > 0.1  # while the pan moved a lot


def test_breakaway_slide_then_stop_and_stay_stopped():
    direction = np.array([0.6, 0.8])
    push = 15.0
    u = np.concatenate([constant(push * direction, 300), constant([0.0, 0.0], 2000)])
    _, rel = sliding.rollout(u)
    u_d = implied_accel(rel)
    # breakaway step: |u_d| = |u_p| - μ g, along -u_p
    np.testing.assert_allclose(u_d[0], -(push - MU * G) * direction, rtol=1e-9)
    # sliding: |u_d| = |u_p| - μ' g, along -u_p
    np.testing.assert_allclose(u_d[10:300], np.tile(-(push - MU_DYN * G) * direction, (290, 1)), rtol=1e-9)
    # pan stops: the object decelerates at μ' g ...
    speed = np.linalg.norm(rel[:, 2:], axis=1)
    decel = -np.diff(speed)[305:400]
    np.testing.assert_allclose(decel, MU_DYN * G * 1e-3, rtol=1e-9)
    # ... comes to rest and stays at rest, exactly
    stopped = int(np.argmax(speed[300:] == 0.0)) + 300
    assert stopped > 300 and np.all(speed[stopped:] == 0.0)
    assert np.all(rel[stopped:, :2] == rel[stopped, :2])
    # the stopping time matches v / (μ' g)
    assert abs((stopped - 300) * 1e-3 - speed[300] / (MU_DYN * G)) < 2e-3


def test_friction_never_adds_energy_while_the_pan_is_still():
    rng = np.random.default_rng(1)
    for _ in range(20):
        pushes = rng.normal(scale=20, size=(rng.integers(5, 60), 2))
        u = np.concatenate([pushes, np.zeros((800, 2))])
        _, rel = sliding.rollout(u)
        energy = 0.5 * (rel[:, 2:] ** 2).sum(1)
        assert np.all(np.diff(energy[len(pushes):]) <= 1e-15)
        assert energy[-1] == 0.0


def test_no_chattering_at_low_speed():
    # a slow slide under a pan acceleration between μ'g and μg never re-starts once stuck
    u = np.concatenate([constant([12.0, 0.0], 5), constant([-0.8 * MU * G, 0.0], 1000)])
    _, rel = sliding.rollout(u)
    moving = np.linalg.norm(rel[:, 2:], axis=1) > 0
    changes = np.count_nonzero(np.diff(moving.astype(int)))
    assert changes <= 2  # starts once, stops once


def sticking_and_sliding(steps=40):
    rel0 = torch.zeros(2, 4, dtype=torch.float64)
    rel0[1, 2] = 0.5  # the second trajectory is already sliding
    u = torch.full((2, steps, 2), 2.0, dtype=torch.float64)  # far below μ g
    return rel0, u.requires_grad_(True)


def test_gradient_vanishes_through_sticking_and_not_through_sliding():
    rel0, u = sticking_and_sliding()
    rel, _, branch = sliding.contact_chunk(rel0, u)
    rel[:, -1, :2].sum().backward()
    assert torch.count_nonzero(u.grad[0]) == 0  # stuck: the gradient-vanishing zone
    assert (branch[0] == sliding.STICK).all()
    assert (branch[1, :5] == sliding.SLIDE).all() and u.grad[1, 0].abs().sum() > 0


def test_hand_derived_backward_matches_finite_differences():
    rng = np.random.default_rng(2)
    rel0 = torch.tensor(np.concatenate([rng.normal(scale=0.01, size=(3, 2)), rng.normal(size=(3, 2))], 1))
    u = torch.tensor(rng.normal(scale=30, size=(3, 25, 2)))  # slides, sticks and breaks away
    rel0.requires_grad_(True)
    u.requires_grad_(True)

    def f(r, a):
        return sliding.contact_chunk(r, a, 1.0, 0.5)[0]

    # finite differences only where no sample sits on a branch boundary (true almost surely)
    assert torch.autograd.gradcheck(f, (rel0, u), eps=1e-7, atol=1e-5, rtol=1e-4)


def test_breakaway_jacobian_and_covariance_through_contact():
    dyn = sliding.SlidingDynamics()
    x0 = torch.zeros(2, 8, dtype=torch.float64)
    mean = torch.zeros(2, 10, 2, dtype=torch.float64)
    mean[1] = 20.0  # the second one breaks away and slides
    cov = torch.eye(2, dtype=torch.float64).expand(2, 10, 2, 2) * 0.5
    _, out = dyn.step(dyn.start(x0), mean, cov)
    assert torch.count_nonzero(out["pos_cov"][0]) == 0  # stuck: the object's position is certain
    assert (torch.linalg.eigvalsh(out["pos_cov"][1, 1:]) > 0).all()
    torch.testing.assert_close(out["pan_pos_cov"][0], out["pan_pos_cov"][1])
    assert out["states"].shape == (2, 10, 8)


def test_rollout_shapes_start_and_validation():
    pan, rel = sliding.rollout(np.ones((3, 99, 2)) * 12.0)
    assert pan.shape == rel.shape == (3, 100, 4)
    assert np.all(pan[:, 0] == 0) and np.all(rel[:, 0] == 0)
    with pytest.raises(ValueError, match="friction"):
        sliding.rollout(np.ones((9, 2)), mu=0.5, mu_dyn=0.7)
    with pytest.raises(ValueError, match="columns"):
        sliding.rollout(np.ones((9, 3)))
    with pytest.raises(ValueError, match="NaN"):
        sliding.rollout(np.full((9, 2), np.nan))


def test_lower_friction_slides_farther():
    u = np.concatenate([constant([25.0, 0.0], 100), np.zeros((1500, 2))])
    far = np.abs(sliding.rollout(u, mu=0.7, mu_dyn=0.3)[1][-1, 0])
    near = np.abs(sliding.rollout(u, mu=1.3, mu_dyn=0.7)[1][-1, 0])
    assert far > near > 0
