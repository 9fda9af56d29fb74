"""The chapter-3 task: curriculum variants, losses, the planner API, on tiny configs."""

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion import tasks
from seqmotion.tasks import train
from seqmotion.tasks.sliding import SlidingPlanner, chapter3_curriculum
from seqmotion.tasks.sliding import data as commands
from seqmotion.tasks.sliding import physics as contact
from seqmotion.training.trainer import step_loss

TASK = tasks.get("sliding")
L_ONLY = TASK.params({"loss_prime_prob": 0.0, "bspline_prob": 0.0})
PRIME_ONLY = TASK.params({"loss_prime_prob": 1.0, "bspline_prob": 0.0})


def test_table_3_1_schedule_with_fading_reading():
    c = chapter3_curriculum()
    assert c.at(5) == {"loss_prime_prob": 1.0, "bspline_prob": 0.0}
    assert c.at(16)["loss_prime_prob"] == pytest.approx(0.5)  # L' fades out over 11–20
    assert c.at(25) == {"loss_prime_prob": 0.0, "bspline_prob": 0.0}
    assert c.at(36)["bspline_prob"] == pytest.approx(0.5)  # B-spline commands fade in over 31–40
    assert c.at(45) == {"loss_prime_prob": 0.0, "bspline_prob": 1.0}


def test_variants_keep_the_budget_and_fix_their_stage():
    configs = {v: TASK.apply_variant(TASK.train_config("small"), v) for v in "ABC"}
    assert len({(c.batch_size, c.batches_per_epoch, c.epochs) for c in configs.values()}) == 1
    b, c = (TASK.curriculum(configs[v]) for v in "BC")
    for epoch in (1, 20, 50):
        assert b.at(epoch) == {"loss_prime_prob": 0.0, "bspline_prob": 0.0}
        assert c.at(epoch) == {"loss_prime_prob": 1.0, "bspline_prob": 0.0}
    with pytest.raises(ValueError, match="variant"):
        TASK.apply_variant(TASK.train_config("tiny"), "D")


def test_loss_prime_does_not_backpropagate_through_the_contact_model():
    cfg = TASK.train_config("tiny")
    torch.manual_seed(0)
    model = TASK.build_model(cfg)
    rng = np.random.default_rng(0)
    batch = TASK.sample(4, rng, PRIME_ONLY, TASK.options(cfg))
    assert batch.extras["loss_prime"].all()
    calls = []
    original = contact.ContactChunk.backward

    def spy(ctx, *grads):
        calls.append(1)
        return original(ctx, *grads)

    contact.ContactChunk.backward = staticmethod(spy)
    try:
        loss, _ = step_loss(TASK, model, batch, {"loss_prime_prob": 1.0, "bspline_prob": 0.0}, cfg, torch.Generator())
        loss.backward()
        assert not calls  # L' only: no gradient through the contact model (and no graph built)
        grads = [p.grad.clone() for p in model.parameters()]
        batch.extras["loss_prime"][:] = False
        model.zero_grad()
        loss, _ = step_loss(TASK, model, batch, {"loss_prime_prob": 0.0, "bspline_prob": 0.0}, cfg, torch.Generator())
        loss.backward()
        assert calls  # L: it does
        assert any(not torch.equal(g, p.grad) for g, p in zip(grads, model.parameters(), strict=True))
    finally:
        contact.ContactChunk.backward = staticmethod(original)


@pytest.fixture(scope="module")
def planner(tmp_path_factory) -> SlidingPlanner:
    run = tmp_path_factory.mktemp("sliding-tiny")
    train(TASK.train_config("tiny"), run, progress=False)
    return sm.load(run)


def test_plan_shapes_and_physics(planner):
    command = commands.circle(0.03, 150)
    plan = planner.plan(command)
    assert plan.pan_accel.shape == (149, 2) and plan.pan_states.shape == plan.rel_states.shape == (150, 4)
    pan, rel = contact.rollout(plan.pan_accel)  # the plan is the 2-D physics of its own accelerations
    np.testing.assert_allclose(pan, plan.pan_states, atol=1e-9)
    np.testing.assert_allclose(rel, plan.rel_states, atol=1e-9)
    batch = planner.plan(np.stack([command, command]))
    assert batch.pan_accel.shape == (2, 149, 2)
    np.testing.assert_allclose(batch.pan_accel[1], plan.pan_accel, rtol=1e-5, atol=1e-5)


def test_int8_planner_plans_close_to_float(planner, tmp_path):
    command = commands.circle(0.03, 150)
    fast = planner.quantized(min_features=16)  # every layer of the tiny model
    assert fast.plan(command).pan_accel == pytest.approx(planner.plan(command).pan_accel, abs=0.05)
    with pytest.raises(ValueError, match="inference only"):
        fast.save_pretrained(tmp_path)


def test_plan_rejects_bad_input(planner):
    with pytest.raises(ValueError, match="columns"):
        planner.plan(np.zeros((100, 6)))
    with pytest.raises(ValueError, match="K = 2"):
        planner.plan(np.zeros((1, 4)))
    with pytest.raises(ValueError, match="friction"):
        planner.plan(np.zeros((10, 4)), mu=0.3, mu_dyn=0.5)
    with pytest.raises(sm.CheckpointError, match="not 'pancake'"):
        from seqmotion.tasks.pancake import Deformer

        Deformer.from_pretrained(planner_dir(planner))


def planner_dir(planner, _cache={}):  # noqa: B006 - cache one saved copy per test session
    if "dir" not in _cache:
        import tempfile
        from pathlib import Path

        _cache["dir"] = Path(tempfile.mkdtemp()) / "planner"
        planner.save_pretrained(_cache["dir"])
    return _cache["dir"]


def test_generators_are_seeded_and_start_at_rest():
    a = commands.physics_type(6, np.random.default_rng(3), length=(500, 700))
    b = commands.physics_type(6, np.random.default_rng(3), length=(500, 700))
    np.testing.assert_array_equal(a.states, b.states)
    assert np.all(a.states[:, 0] == 0) and np.all(a.extras["pan_states"][:, 0] == 0)
    s = commands.bspline_type(6, np.random.default_rng(4), length=600)
    reach = np.linalg.norm(s.states[..., :2], axis=-1).max(1)
    assert np.all((reach >= 0.01 - 1e-12) & (reach <= 0.08 + 1e-12))
    # physics-type commands are what the pan shaking does to the object
    pan, rel = contact.rollout(a.extras["pan_accel"][0, : a.lengths[0] - 1])
    np.testing.assert_allclose(rel, a.states[0, : a.lengths[0]], atol=1e-12)


def test_friction_randomisation_draws_valid_pairs_and_reaches_the_physics():
    cfg = TASK.train_config("tiny")
    cfg.options["friction_range"] = [[0.7, 1.3], [0.3, 0.7]]
    batch = TASK.sample(64, np.random.default_rng(0), L_ONLY, TASK.options(cfg))
    mu, mud = batch.extras["mu"], batch.extras["mu_dyn"]
    assert np.all((mu >= 0.7) & (mu <= 1.3) & (mud >= 0.3) & (mud < mu)) and mu.std() > 0.1
    # physics-type commands were rolled out with each trajectory's own friction
    b = int(np.argmin(mu))
    k = batch.lengths[b]
    pan_accel = np.diff(batch.extras["pan_states"][b, :k, 2:], axis=0) / 1e-3
    _, rel = contact.rollout(pan_accel, mu=mu[b], mu_dyn=mud[b])
    np.testing.assert_allclose(rel, batch.states[b, :k], atol=1e-9)
    default = TASK.sample(8, np.random.default_rng(0), L_ONLY, TASK.options(TASK.train_config("tiny")))
    assert np.all(default.extras["mu"] == 1.0) and np.all(default.extras["mu_dyn"] == 0.5)


def test_friction_pairs_draw_only_the_listed_pairs_and_bad_pairs_are_refused():
    cfg = TASK.train_config("tiny")
    cfg.options["friction_pairs"] = [[0.8, 0.35], [1.2, 0.65]]
    params = {"loss_prime_prob": 0.0, "bspline_prob": 0.0}
    batch = TASK.sample(64, np.random.default_rng(0), TASK.params(params), TASK.options(cfg))
    drawn = set(zip(batch.extras["mu"].tolist(), batch.extras["mu_dyn"].tolist(), strict=True))
    assert drawn == {(0.8, 0.35), (1.2, 0.65)}
    cfg.options["friction_pairs"] = [[0.5, 0.7]]  # μ' > μ
    with pytest.raises(ValueError, match="friction_pairs"):
        TASK.sample(4, np.random.default_rng(0), TASK.params(params), TASK.options(cfg))


def test_velocity_shaking_slides_as_often_but_lets_the_pan_drift():
    rng = np.random.default_rng(5)
    bounded = commands.physics_type(200, rng, length=1200)
    drifting = commands.physics_type(200, rng, length=1200, shaking="velocity")

    def farthest(states):
        return np.linalg.norm(states[..., :2], axis=-1).max(1)

    def share_above_mu_g(batch):
        return float((np.linalg.norm(batch.extras["pan_accel"], axis=-1) > contact.MU * 9.81).mean())

    assert np.all(drifting.extras["pan_states"][:, 0] == 0)  # from rest at home
    # both shake hard enough for the object to break away, in a comparable share of samples
    assert 0.5 < share_above_mu_g(drifting) / share_above_mu_g(bounded) < 2.0
    # a bounded shake stays near home; a velocity shake random-walks away from it
    assert farthest(bounded.extras["pan_states"]).max() < 0.1
    assert np.median(farthest(drifting.extras["pan_states"])) > 0.1
    # and the object's path is still what the pan's shaking does to it
    k = drifting.lengths[0]
    _, rel = contact.rollout(drifting.extras["pan_accel"][0, : k - 1])
    np.testing.assert_allclose(rel, drifting.states[0, :k], atol=1e-12)
    cfg = TASK.train_config("tiny")
    cfg.options["pan_shaking"] = "sideways"
    with pytest.raises(ValueError, match="pan_shaking"):
        TASK.sample(4, np.random.default_rng(0), PRIME_ONLY, TASK.options(cfg))
