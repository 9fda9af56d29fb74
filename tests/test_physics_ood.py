"""Hardening, second round (issue 31, item 13): physics the model never met is out of distribution.

Before, ``plan(line, mu=1e300)`` came back in distribution with a predicted end std of 0.0 mm while
the object missed its end by 50 mm.
"""

from __future__ import annotations

import pytest

import seqmotion as sm
from seqmotion.tasks.pancake.physics import PancakePhysics
from seqmotion.tasks.sliding import data as commands


@pytest.fixture(scope="module")
def planner():
    return sm.load_pretrained("sliding")


@pytest.fixture(scope="module")
def line():
    return commands.line(0.05, 500)


def test_the_shipped_planner_knows_the_friction_it_was_trained_on(planner):
    from seqmotion.tasks.sliding import friction_trained

    assert friction_trained(planner.options) == {"mu": (0.8, 1.2), "mu_dyn": (0.35, 0.65)}


def test_absurd_friction_is_refused_by_name(planner, line):
    for mu in (1e300, 1e4):
        with pytest.raises(ValueError, match=r"mu = .* no friction coefficient"):
            planner.plan(line, mu=mu)


@pytest.mark.parametrize("mu, mu_dyn", [(5.0, None), (0.3, 0.1), (1.0, 0.05)])
def test_friction_beyond_training_is_out_of_distribution(planner, line, mu, mu_dyn):
    plan = planner.plan(line, mu=mu, mu_dyn=mu_dyn)
    assert plan.out_of_distribution
    named = "mu_dyn" if mu == 1.0 else "mu"
    assert any(r.startswith(f"{named} ") and "trained" in r for r in plan.ood_reasons), plan.ood_reasons


def test_friction_within_training_adds_no_reason(planner, line):
    for mu, mu_dyn in ((None, None), (0.9, 0.4), (1.2, 0.65)):
        plan = planner.plan(line, mu=mu, mu_dyn=mu_dyn)
        assert not any("trained" in r for r in plan.ood_reasons), plan.ood_reasons


def test_a_batch_is_flagged_whole_and_assess_checks_physics_too(planner, line):
    import numpy as np

    plans = planner.plan(np.stack([line, line]), mu=3.0)
    assert plans.out_of_distribution.tolist() == [True, True]
    one = planner.plan(line)
    judged = planner.assess(line, _states(one), one.pan_accel, physics=planner.physics.replace(mu=3.0))
    assert judged.out_of_distribution and any(r.startswith("mu ") for r in judged.ood_reasons)
    with pytest.raises(ValueError, match="runs at SlidingPhysics"):
        planner.assess(line, _states(one), one.pan_accel, physics=PancakePhysics(mu=1.0))


def _states(plan):
    """A plan's states in the planner's state layout (pan x, y, vx, vy + object relative x, y, vx, vy)."""
    import numpy as np

    return np.concatenate([plan.pan_states, plan.rel_states], axis=-1)
