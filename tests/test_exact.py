"""Exact latent adjustment (``exact=True``), the defaults that work, and the force-form cone they rest on."""

import math
import warnings

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion.data import pancake as gen
from seqmotion.data import sliding as commands
from seqmotion.latent.objectives import AtRest, EndPose, Ranges
from seqmotion.latent.transcription import true_j1
from seqmotion.physics import integrator
from seqmotion.physics import pancake as physics
from seqmotion.physics.transcription import casadi

HARD_TARGETS = np.array([[0.1, -0.1, math.pi], [-0.1, 0.1, -math.pi], [0.0, 0.1, 0.0]])  # ch. 4's, incl. θ = ±π


def test_force_form_cone_is_the_angle_cone():
    """μ n − t ≥ 0 and μ n + t ≥ 0 hold exactly where F_c = 0, at any attitude and input (away from the edge)."""
    ca = casadi()
    rng = np.random.default_rng(0)
    for mu in (0.5, 1.0, 2.0):
        x, u, p = ca.SX.sym("x", 6, 2), ca.SX.sym("u", 3, 1), ca.SX.sym("p", 0)
        g = ca.Function("g", [x, u], [physics.cone_constraint(mu).build(x, u, p)])
        theta = rng.uniform(-math.pi, math.pi, 400)
        accel = rng.normal(0, 15, (400, 3))
        states = np.zeros((400, 2, 6))
        states[:, :, 2] = theta[:, None]
        fc = physics.violation(states[:, :1], accel[:, None], mu)[:, 0]
        psi = np.abs(physics.psi(states[:, :1], accel[:, None])[:, 0])
        for i in range(400):
            if abs(psi[i] - math.atan(mu)) < 1e-6:
                continue
            inside = bool(np.all(np.array(g(states[i].T, accel[i][:, None])) >= 0))
            assert inside == (fc[i] == 0), (mu, theta[i], accel[i])


def test_exact_reaches_hard_targets_with_the_cone_kept(deformer):
    x = np.stack([gen.straight(t, 500) for t in HARD_TARGETS])
    res = sm.optimize_latent(deformer, x, EndPose(HARD_TARGETS), exact=True)
    assert np.all(res.exact)
    for b, target in enumerate(HARD_TARGETS):
        j1, max_fc = true_j1(res.accel[b], target, mu=deformer.options.mu)
        assert j1 <= 1e-9 and max_fc <= 1e-6
    np.testing.assert_allclose(integrator.step_reference(res.states[:, :-1], res.accel), res.states[:, 1:], atol=1e-12)
    assert [s.name for s in res.stages] == ["latent", "polish"]
    assert res.stages[0].steps <= 10 and np.all(np.atleast_1d(res.stages[1].steps) < 50)
    assert res.met and "end error" in res.describe() and "polish" in res.describe()


def test_defaults_are_levenberg_marquardt_with_continuation(deformer):
    """With only (model, states, EndPose) the call reaches J1 < 1e-3 within 5 updates; eq. 4.2 stays available."""
    x = np.stack([gen.straight(t, 500) for t in HARD_TARGETS])
    default = sm.optimize_latent(deformer, x, EndPose(HARD_TARGETS), steps=5)
    assert default.history[5].mean() < 1e-3
    assert default.exact is None and [s.name for s in default.stages] == ["latent"]
    plain = sm.optimize_latent(deformer, x, EndPose(HARD_TARGETS), steps=5, optimizer="sgd")
    assert plain.history[5].mean() > 10 * default.history[5].mean()


def test_exact_end_at_rest_and_ranges(deformer):
    target = (0.05, 0.05, 1.5)
    x = gen.straight(target, 300)
    res = sm.optimize_latent(deformer, x, EndPose(target) + AtRest(), exact=True)
    assert res.exact and res.met
    np.testing.assert_allclose(res.states[-1, :3], target, atol=1e-7)
    np.testing.assert_allclose(res.states[-1, 3:], 0.0, atol=1e-7)
    j2 = sm.optimize_latent(deformer, gen.straight((0.0, 0.0, -3 * math.pi / 4), 500, timing="linear"), Ranges(),
                            steps=5, exact=True)
    assert j2.exact and set(j2.terms) == {"end position band", "end attitude band", "velocity limits", "friction cone"}
    assert all(term.met for term in j2.terms.values())
    assert abs(j2.states[-1, 2] + 3 * math.pi / 4) <= 0.5 + 1e-6


def test_exact_flags_an_unreachable_target(deformer):
    """Sinking 5 m in 0.1 s needs the spatula to fall faster than gravity: the pancake would leave it."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = sm.optimize_latent(deformer, gen.straight((0.0, -5.0, 0.0), 100), EndPose((0.0, -5.0, 0.0)),
                                 exact=True)
    assert res.exact is False and not res.met
    assert any("exact polish failed" in str(w.message) for w in caught)
    assert res.stages[-1].name == "polish"


def test_exact_is_refused_by_name(deformer, planner):
    x = gen.straight((0.1, 0.0, 1.0), 100)
    with pytest.raises(ValueError, match="has no exact form"):
        sm.optimize_latent(deformer, x, lambda states, accel: (accel**2).mean((1, 2)), exact=True)
    with pytest.raises(ValueError, match="'sliding' has no exact polish"):
        sm.optimize_latent(planner, commands.circle(0.02, 200), lambda s, a: (s[:, -1, 4:6] ** 2).sum(-1), exact=True)
    with pytest.raises(ValueError, match="exact must be True or False"):
        sm.optimize_latent(deformer, x, EndPose((0.1, 0.0, 1.0)), exact="yes")
    report = EndPose((0.1, 0.0, 1.0)).report(torch.zeros(1, 5, 6, dtype=torch.float64),
                                             torch.zeros(1, 4, 3, dtype=torch.float64))
    assert not report["end error"].met and report["constraint"].met
