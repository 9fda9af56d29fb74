"""Exact latent adjustment (``exact=True``), the defaults that work, and the force-form cone they rest on."""

import math
import warnings

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion.latent.objectives import AtRest, EndPose, Ranges
from seqmotion.physics import integrator
from seqmotion.physics.transcription import casadi
from seqmotion.tasks.pancake import POLISH_REACH, physics
from seqmotion.tasks.pancake import data as gen
from seqmotion.tasks.pancake.latent import true_j1
from seqmotion.tasks.sliding import data as commands

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
    report = EndPose((0.1, 0.0, 1.0)).bind(deformer).report(torch.zeros(1, 5, 6, dtype=torch.float64),
                                             torch.zeros(1, 4, 3, dtype=torch.float64))
    assert not report["end error"].met and report["constraint"].met


def test_reach_end_is_the_nearest_motion_that_ends_there():
    """The closed-form end correction meets the end conditions, and nothing nearer does (any other change
    that keeps them differs from it by a component orthogonal to the correction)."""
    rng = np.random.default_rng(3)
    x0, accel = rng.normal(0, 0.1, 6), rng.normal(0, 5, (120, 3))
    values = np.array([0.1, -0.05, 1.0, 0.0, 0.0, 0.0])
    weights = np.array([1.0, 1.0, 0.01])
    out = integrator.reach_end(x0, accel, [0, 1, 2, 3, 4, 5], values, weights)
    np.testing.assert_allclose(integrator.integrate_numpy(x0, out)[-1], values, atol=1e-10)
    delta = out - accel
    for _ in range(5):  # any other sequence with the same end differs by a change W-orthogonal to delta
        extra = integrator.reach_end(np.zeros(6), rng.normal(0, 1, (120, 3)), [0, 1, 2, 3, 4, 5], np.zeros(6),
                                     weights)  # a change that keeps the end where it is
        np.testing.assert_allclose(integrator.integrate_numpy(np.zeros(6), extra)[-1], 0.0, atol=1e-10)
        assert abs(float((weights * delta * extra).sum())) < 1e-6 * np.abs(delta).sum() * np.abs(extra).sum()


def test_keep_end_ends_exactly_at_rest_in_the_cone(deformer):
    batch = gen.position_type(3, np.random.default_rng(11), length=300).states  # (3, 300, 6), rest to rest
    plain = deformer.deform(batch)
    kept = deformer.deform(batch, keep_end=True)
    assert plain.exact is None and kept.exact.shape == (3,) and np.all(kept.exact)
    np.testing.assert_allclose(kept.states[:, -1, :3], batch[:, -1, :3], atol=1e-7)
    np.testing.assert_allclose(kept.states[:, -1, 3:], 0.0, atol=1e-7)
    assert kept.violation.max() <= 1e-6 and np.all(kept.feasible)
    np.testing.assert_allclose(integrator.step_reference(kept.states[:, :-1], kept.accel), kept.states[:, 1:],
                               atol=1e-12)
    assert np.all(kept.errors["end_position_error_m"] < 1e-7)  # the trust signals judge the polished motion
    one = deformer.deform(batch[0], keep_end=True)
    assert one.exact is True and one.states.shape == (one.length, 6)
    assert one.length == 300 and kept.states.shape[1] == kept.length.max() >= 300  # never shorter than the sketch
    # 0.3 m and 3 rad, rest to rest in 59 ms, needs ≥ 4 · 0.3 / 0.059² = 345 m/s², beyond the arm's 30:
    # the motion gets the time it needs, within the limits, and ends exactly there at rest
    cut = gen.straight((0.3, 0.0, 3.0), 60)
    longer = deformer.deform(cut, keep_end=True)
    limits = np.array(deformer.exact_form().accel_limits)
    assert longer.exact is True and longer.length > 60 and longer.states.shape == (longer.length, 6)
    np.testing.assert_allclose(longer.states[-1], np.r_[cut[-1, :3], np.zeros(3)], atol=1e-7)
    assert longer.violation.max() <= 1e-6 and np.all(np.abs(longer.accel) <= limits * (1 + 1e-6))
    assert longer.errors["end_position_error_m"] < 1e-7
    # extend=False keeps the sketch's time: flagged, and the learned motion comes back, not a motion no arm executes
    with pytest.warns(RuntimeWarning, match=r"acceleration limits .* needs at least \(344\.7, 0\.0, 3447\.3\)"):
        flagged = deformer.deform(cut, keep_end=True, extend=False)
    assert flagged.exact is False and flagged.length == 60
    np.testing.assert_array_equal(flagged.states, deformer.deform(cut).states)
    # in a batch, the shorter motion holds its end (at rest, zero input, no violation counted) up to the longer
    mixed = deformer.deform(np.stack([batch[0, :60], cut]), keep_end=True)
    assert np.all(mixed.exact) and mixed.states.shape[1] == mixed.length.max()
    short = int(mixed.length.argmin())
    np.testing.assert_array_equal(mixed.accel[short, mixed.length[short] - 1:], 0.0)
    assert mixed.violation.max() <= 1e-6


def test_keep_end_out_of_reach_ends_at_rest_as_near_as_it_can(deformer):
    """An end pose no motion reaches (0.42 m down, beyond the 0.40 m reach) is flagged, and the motion returned
    is still one the arm executes: at rest, in the cone, within the limits and the reach, as near as they allow."""
    sketch = gen.straight((0.0, -0.42, 0.0), 300)
    with pytest.warns(RuntimeWarning, match="ends at rest as near as they allow"):
        r = deformer.deform(sketch, keep_end=True)
    form = deformer.exact_form()
    assert r.exact is False and r.violation.max() <= 1e-6
    np.testing.assert_allclose(r.states[-1, 3:], 0.0, atol=1e-7)
    assert np.hypot(r.states[:, 0], r.states[:, 1]).max() <= POLISH_REACH + 1e-6
    assert np.all(np.abs(r.accel) <= np.array(form.accel_limits) * (1 + 1e-6))
    assert 0.019 < r.errors["end_position_error_m"] < 0.021  # the nearest reachable end: 0.40 m down


def test_keep_end_is_refused_by_name(deformer, planner):
    with pytest.raises(ValueError, match="keep_end must be True or False"):
        deformer.deform(gen.straight((0.1, 0.0, 1.0), 100), keep_end="yes")
    with pytest.raises(ValueError, match="'sliding' has no exact polish"):
        planner.generate(commands.circle(0.02, 200), keep_end=True)
