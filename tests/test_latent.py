"""Latent-space adjustment (ch. 4): objectives, cases 1–3, batching, other tasks, errors."""

import math

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion import tasks
from seqmotion.latent.objectives import EndPose, Ranges
from seqmotion.physics import integrator
from seqmotion.tasks import train
from seqmotion.tasks.pancake import data as gen
from seqmotion.tasks.sliding import data as commands


@pytest.fixture(scope="module")
def deformer(tmp_path_factory):
    run = tmp_path_factory.mktemp("pancake-tiny")
    train(tasks.get("pancake").train_config("tiny"), run, progress=False)
    return sm.load(run)


def test_end_pose_matches_eq_4_3(deformer):
    states = torch.zeros(1, 5, 6, dtype=torch.float64)
    states[0, -1, :3] = torch.tensor([0.1, -0.2, 1.0])
    accel = torch.zeros(1, 4, 3, dtype=torch.float64)
    j = EndPose((0.0, 0.0, 0.0)).bind(deformer)(states, accel)  # the pancake's fields, its cone at μ = 1
    assert float(j) == pytest.approx(0.1**2 + 0.2**2 + (0.1 * 1.0) ** 2)
    # the cone term: a still spatula at 50° everywhere violates by 5° per sample
    states[0, :, 2] = math.radians(50)
    states[0, -1, :3] = 0.0
    states[0, -1, 2] = math.radians(50)
    j = EndPose((0.0, 0.0, math.radians(50)), alpha=1.0).bind(deformer)(states, accel)
    assert float(j) == pytest.approx(4 * math.radians(5))


def test_objectives_refuse_to_be_evaluated_before_they_are_bound():
    """The columns, the end pose and the constraint's physics come from the model: an unbound objective never
    falls back to the pancake's columns and μ = 1."""
    from seqmotion.latent.objectives import AtRest, TaskConstraint

    s, a = torch.zeros(1, 5, 6, dtype=torch.float64), torch.zeros(1, 4, 3, dtype=torch.float64)
    for objective in (EndPose((0.0, 0.0, 0.0)), AtRest(), TaskConstraint(), Ranges(), Ranges(end={"y": (0, 1)})):
        with pytest.raises(ValueError, match="not bound to a model"):
            objective(s, a)
    with pytest.raises(ValueError, match="not bound to a model"):
        EndPose((0.0, 0.0, 0.0)).report(s, a)
    with pytest.raises(ValueError, match="not bound to a model"):
        AtRest().exact_constraints()


def test_ranges_terms_are_zero_inside_every_band(deformer):
    s = torch.zeros(1, 50, 6, dtype=torch.float64)
    s[0, -1, :3] = torch.tensor([0.1, 0.1, -3 * math.pi / 4 + 0.3])
    s[0, :, 3:] = torch.tensor([1.0, -1.0, 4.0])
    j2 = Ranges().bind(deformer)
    assert float(j2(s, torch.zeros(1, 49, 3, dtype=torch.float64))) == 0.0
    s[0, 10, 3] = 2.5  # 1 m/s over the y limit in one sample: β/K · 1²
    assert float(j2(s, torch.zeros(1, 49, 3, dtype=torch.float64))) == pytest.approx(0.01 / 50)


def test_objectives_compose(deformer):
    s = torch.zeros(2, 5, 6, dtype=torch.float64)
    a = torch.zeros(2, 4, 3, dtype=torch.float64)
    e = EndPose((0.1, 0.0, 0.0)).bind(deformer)

    def f(states, accel):
        return states[:, -1, 0] + 1.0

    combo = 2 * e + f
    torch.testing.assert_close(combo(s, a), 2 * e(s, a) + 1.0)
    from seqmotion.latent.objectives import as_objective

    with pytest.raises(ValueError, match="callable"):
        as_objective("nope")


@pytest.mark.parametrize("case", ["encoder", "random", "trajectory"])
def test_each_case_reduces_the_end_pose_objective(deformer, case):
    start = gen.straight((0.05, 0.05, 1.0), 120)
    objective = EndPose((0.05, 0.05, 1.0))
    if case == "trajectory":
        res = sm.optimize_trajectory(deformer, start, objective, steps=15, lr=1000.0)
        assert res.latent is None
    else:
        res = sm.optimize_latent(deformer, start, objective, steps=15, lr=0.5, init=case, optimizer="adam")
        assert res.latent.shape == (deformer.model.latent_dim,)
    assert res.history.shape == (16,)
    assert res.history[-1] < res.history[0]
    assert res.states.shape == (120, 6) and res.accel.shape == (119, 3)
    np.testing.assert_allclose(integrator.step_reference(res.states[:-1], res.accel), res.states[1:], atol=1e-12)
    # the reported final objective is the objective of the returned motion
    final = objective.bind(deformer)(torch.from_numpy(res.states)[None], torch.from_numpy(res.accel)[None])
    assert float(final) == pytest.approx(res.history[-1], rel=1e-9)


def test_auto_step_size_decreases_monotonically(deformer):
    starts = np.stack([gen.straight(t, 100) for t in ([0.1, 0.0, 2.0], [-0.05, 0.05, -1.0])])
    res = sm.optimize_latent(deformer, starts, EndPose([[0.1, 0.0, 2.0], [-0.05, 0.05, -1.0]]), steps=8,
                             optimizer="sgd")
    totals = res.history.sum(1)
    assert np.all(np.diff(totals) <= 1e-12) and totals[-1] < totals[0]
    res3 = sm.optimize_trajectory(deformer, starts[0], EndPose([0.1, 0.0, 2.0]), steps=5, optimizer="sgd")
    assert np.all(np.diff(res3.history) <= 1e-12)
    with pytest.raises(ValueError, match="needs a numeric lr"):
        sm.optimize_latent(deformer, starts[0], EndPose([0.1, 0.0, 2.0]), optimizer="adam")


def test_least_squares_residuals_compose(deformer):
    s = torch.zeros(2, 5, 6, dtype=torch.float64)
    s[:, -1, 0] = 0.3
    a = torch.zeros(2, 4, 3, dtype=torch.float64)
    e1, e2 = EndPose((0.1, 0.0, 0.0)).bind(deformer), EndPose((0.0, 0.2, 1.0), alpha=3.0).bind(deformer)
    combo = 4 * e1 + e2
    r, p = combo.residuals(s, a), combo.penalty(s, a)
    assert r.shape == (2, 6)
    torch.testing.assert_close((r**2).sum(-1) + p, combo(s, a))  # J = |r|² + p
    with pytest.raises(ValueError, match="least-squares"):
        (e1 + (lambda states, accel: states[:, -1, 0])).residuals(s, a)
    with pytest.raises(ValueError, match="least-squares"):
        (-1 * e1).residuals(s, a)


def test_levenberg_marquardt_never_increases_and_beats_gradient_descent(deformer):
    targets = np.array([[0.1, 0.0, 2.0], [-0.05, 0.05, -1.0]])
    starts = np.stack([gen.straight(t, 100) for t in targets])
    lm = sm.optimize_latent(deformer, starts, EndPose(targets), steps=8, optimizer="lm", continuation=None)
    gd = sm.optimize_latent(deformer, starts, EndPose(targets), steps=8, optimizer="sgd")
    assert np.all(np.diff(lm.history, axis=0) <= 1e-9)  # per trajectory: a rejected step is retried
    assert lm.history[-1].sum() < gd.history[-1].sum()
    with pytest.raises(ValueError, match="least-squares"):
        sm.optimize_latent(deformer, starts[0], lambda states, accel: states[:, -1, 0] ** 2, steps=1, optimizer="lm")
    with pytest.raises(ValueError, match="continuation"):
        sm.optimize_latent(deformer, starts[0], EndPose(targets[0]), steps=1, optimizer="sgd", continuation=(1e-3, 4))
    with pytest.raises(ValueError, match="continuation"):
        sm.optimize_latent(deformer, starts[0], EndPose(targets[0]), steps=1, optimizer="lm", continuation=(0.0, 4))
    relaxed = sm.optimize_latent(deformer, starts, EndPose(targets), steps=4, optimizer="lm", continuation=(1e-3, 2))
    # the history is the true objective: recompute it for the returned motion
    final = EndPose(targets).bind(deformer)(torch.from_numpy(relaxed.states), torch.from_numpy(relaxed.accel))
    np.testing.assert_allclose(relaxed.history[-1], final.numpy(), rtol=1e-5)


def test_plain_gradient_descent_is_eq_4_2(deformer):
    start = gen.straight((0.0, 0.1, -1.0), 80)
    objective = EndPose((0.0, 0.1, -1.0)).bind(deformer)
    one = sm.optimize_latent(deformer, start, objective, steps=1, lr=3.0)
    x = torch.from_numpy(start)[None]
    z = deformer.encode_torch(x).detach().requires_grad_(True)
    states, accel = deformer.decode_torch(z, x[:, 0], 80)
    objective(states, accel).sum().backward()
    np.testing.assert_allclose(one.latent, (z - 3.0 * z.grad).detach().numpy()[0], rtol=1e-5, atol=1e-6)


def test_batched_targets_match_one_by_one(deformer):
    targets = np.array([[0.1, 0.0, math.pi], [-0.1, 0.1, 0.0], [0.0, -0.1, -math.pi]])
    starts = np.stack([gen.straight(t, 100) for t in targets])
    batch = sm.optimize_latent(deformer, starts, EndPose(targets), steps=5, lr=1.0)
    assert batch.history.shape == (6, 3) and batch.states.shape == (3, 100, 6)
    single = sm.optimize_latent(deformer, starts[1], EndPose(targets[1]), steps=5, lr=1.0)
    np.testing.assert_allclose(batch.history[:, 1], single.history, rtol=1e-4, atol=1e-7)


def test_model_weights_are_untouched(deformer):
    before = {k: v.clone() for k, v in deformer.model.state_dict().items()}
    sm.optimize_latent(deformer, gen.straight((0.1, 0, 1), 60), EndPose((0.1, 0, 1)), steps=3, lr=1.0)
    assert all(torch.equal(before[k], v) for k, v in deformer.model.state_dict().items())
    assert all(p.requires_grad for p in deformer.model.parameters())


def test_works_for_the_sliding_planner(tmp_path):
    train(tasks.get("sliding").train_config("tiny"), tmp_path, progress=False)
    planner = sm.load(tmp_path)
    command = commands.circle(0.03, 100)

    def pan_stays_home(states, accel):  # a new objective for a chapter-3 model
        return (states[:, :, :2] ** 2).sum((1, 2)) + 1e-4 * (accel**2).sum((1, 2))

    res = sm.optimize_latent(planner, command, pan_stays_home, steps=5, lr=0.3, optimizer="adam")
    assert res.states.shape == (100, 8) and res.history[-1] < res.history[0]
    res3 = sm.optimize_trajectory(planner, command, pan_stays_home, steps=3, lr=10.0)
    assert res3.history[-1] < res3.history[0]


def test_bad_arguments(deformer):
    s = gen.straight((0.1, 0, 1), 60)
    with pytest.raises(ValueError, match="init"):
        sm.optimize_latent(deformer, s, EndPose((0, 0, 0)), init="zeros")
    with pytest.raises(ValueError, match="optimizer"):
        sm.optimize_latent(deformer, s, EndPose((0, 0, 0)), optimizer="lbfgs")
    with pytest.raises(ValueError, match="lr"):
        sm.optimize_latent(deformer, s, EndPose((0, 0, 0)), lr=-1)
    with pytest.raises(ValueError, match="trained seqmotion model"):
        sm.optimize_latent("model", s, EndPose((0, 0, 0)))
    with pytest.raises(ValueError, match="target"):
        EndPose((np.nan, 0, 0))
    with pytest.raises(ValueError, match="end pose is"):  # two values for the pancake's (y, z, theta)
        sm.optimize_latent(deformer, s, EndPose((0, 0)), steps=1)
    with pytest.raises(ValueError, match="alpha"):
        EndPose((0, 0, 0), alpha=float("nan"))
    with pytest.raises(ValueError, match="v_lim"):
        Ranges(v_lim=(float("nan"), 1, 1))
    with pytest.raises(ValueError, match="columns"):
        sm.optimize_latent(deformer, np.zeros((60, 4)), EndPose((0, 0, 0)))


def test_generate_is_every_models_verb_and_deform_the_pancakes_name_for_it(deformer):
    """Issue 32 item 7: ``generate`` works on the pancake's model too, with the same result as ``deform``."""
    sketch = gen.straight((0.1, 0.0, 1.0), 120)
    named, generic = deformer.deform(sketch), deformer.generate(sketch)
    assert type(named) is type(generic)
    np.testing.assert_array_equal(named.states, generic.states)
    np.testing.assert_array_equal(named.violation, generic.violation)
