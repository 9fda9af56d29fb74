"""Refining a sliding plan's latent for tracking (seqmotion.tasks.sliding.latent)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion.reproduce.ch3 import rmse_mm
from seqmotion.tasks.sliding.latent import Tracking, refine_plan


@pytest.fixture(scope="module")
def command() -> np.ndarray:
    """A 2 cm circle in 0.6 s: the plain plan leaves ~13 mm RMSE on it."""
    return sm.tasks.sliding.data.circle(0.02, 600)


def test_refinement_lowers_tracking_error(planner, command, one_thread) -> None:
    plain = planner.plan(command, mu=0.9, mu_dyn=0.4)
    refined = refine_plan(planner, command, mu=0.9, mu_dyn=0.4, steps=60, accel_steps=30)
    assert refined.rel_states.shape == command.shape and refined.pan_accel.shape == (len(command) - 1, 2)
    assert rmse_mm(refined.rel_states, command) < 0.6 * rmse_mm(plain.rel_states, command)
    # the plan is consistent: its accelerations rolled out at the same friction give its states
    pan, rel = sm.tasks.sliding.physics.rollout(refined.pan_accel, mu=0.9, mu_dyn=0.4)
    np.testing.assert_allclose(rel[:, :2], refined.rel_states[:, :2], atol=1e-6)
    np.testing.assert_allclose(pan[:, :2], refined.pan_states[:, :2], atol=1e-6)


def test_objective_is_the_rmse_and_optimize_latent_lowers_it(planner, command, one_thread) -> None:
    objective = Tracking(command, alpha_range=0.0)
    res = sm.optimize_latent(planner, command, objective, steps=15, optimizer="adam", lr=0.05)
    plan = planner.plan(command)
    assert np.sqrt(res.history[0]) == pytest.approx(rmse_mm(plan.rel_states, command), rel=1e-3)
    assert res.history.min() < res.history[0]


def test_batch_and_refusals(planner, deformer, command) -> None:
    batch = np.stack([command, 0.5 * command])
    plan = refine_plan(planner, batch, steps=0, gains=(1.0,))
    assert plan.rel_states.shape == batch.shape
    np.testing.assert_allclose(plan.rel_states, planner.plan(batch).rel_states, atol=1e-9)
    with pytest.raises(ValueError, match="sliding"):
        Tracking(command).bind(deformer)
    bound = Tracking(command).bind(planner)
    assert bound.pan_limit == planner.options.pan_limit
    with pytest.raises(ValueError, match="command"):
        bound(torch.zeros(1, 10, 8, dtype=torch.float64), torch.zeros(1, 9, 2, dtype=torch.float64))
    for bad in ({"steps": -1}, {"gains": ()}, {"lr": 0.0}, {"accel_steps": 1.5}, {"dither": 1.0}, {"dither": -1.0}):
        with pytest.raises(ValueError):
            refine_plan(planner, command, **bad)
    with pytest.raises(ValueError):
        Tracking(command, alpha_end=-1.0)


def test_dithered_polish_never_scores_worse_than_its_start(planner, command, one_thread) -> None:
    objective = Tracking(command, alpha_end=0.3, pan_limit=0.2)  # no jerk term: it charges the base, not the dither
    plain = refine_plan(planner, command, mu=1.3, mu_dyn=0.3, steps=0, gains=(1.0,), objective=objective)
    dithered = refine_plan(planner, command, mu=1.3, mu_dyn=0.3, steps=0, gains=(1.0,), objective=objective,
                           accel_steps=20, dither=1.2)
    bound = objective.bind(planner)

    def score(plan: object) -> float:
        states = np.concatenate([plan.pan_states, plan.rel_states], axis=-1)[None]
        return float(bound(torch.from_numpy(states), torch.from_numpy(plan.pan_accel[None])))

    assert score(dithered) <= score(plain) + 1e-9
