"""The user-facing Deformer and online generator (SPEC §7), on a tiny trained model."""

import numpy as np
import pytest

import seqmotion as sm
from seqmotion import tasks
from seqmotion.physics import integrator
from seqmotion.tasks import train
from seqmotion.tasks.pancake import Deformer
from seqmotion.tasks.pancake import data as gen
from seqmotion.tasks.pancake import physics as pancake


@pytest.fixture(scope="module")
def deformer(tmp_path_factory) -> Deformer:
    run = tmp_path_factory.mktemp("tiny")
    train(tasks.get("pancake").train_config("tiny"), run, progress=False)
    return sm.load(run)


@pytest.mark.parametrize("k", [2, 3, 10, 11, 57, 500])
def test_any_length_round_trips_the_physics(deformer, k):
    states = gen.straight((0.1, -0.05, 2.0), k)
    r = deformer.deform(states)
    assert r.states.shape == (k, 6) and r.accel.shape == (k - 1, 3)
    assert r.violation.shape == (k - 1,) and r.psi.shape == (k - 1,)
    assert r.latent.shape == (deformer.model.latent_dim,)
    np.testing.assert_array_equal(r.states[0], states[0])
    np.testing.assert_allclose(integrator.step_reference(r.states[:-1], r.accel), r.states[1:], atol=1e-12)
    np.testing.assert_allclose(r.violation, pancake.violation(r.states[:-1], r.accel), atol=1e-9)


def test_batch_equals_one_by_one(deformer):
    batch = gen.position_type(4, np.random.default_rng(0), length=120).states
    rb = deformer.deform(batch)
    assert rb.states.shape == (4, 120, 6) and rb.latent.shape[0] == 4
    for i in range(4):
        ri = deformer.deform(batch[i])
        np.testing.assert_allclose(rb.accel[i], ri.accel, rtol=1e-5, atol=1e-5)
    assert rb.feasible.shape == (4,)


def test_online_generator_fed_its_own_states_reproduces_deform(deformer):
    states = gen.position_type(1, np.random.default_rng(1), length=95).states[0]
    r = deformer.deform(states)
    g = deformer.generator(states)
    c = g.chunk
    accel = [g.step()]
    for k in range(1, deformer.model.num_chunks(95)):
        accel.append(g.step(r.states[(k - 1) * c + 1 : k * c + 1]))  # the C states its last outputs produced
    accel = np.concatenate(accel)[:94]
    np.testing.assert_array_equal(accel, r.accel)  # bit for bit
    # and closing the loop with the library's own integrator gives the same motion
    g.reset()
    x, outs, measured = states[0], [], None
    for _ in range(deformer.model.num_chunks(95)):
        u = g.step(measured)
        measured = integrator.integrate_numpy(x, u)[1:]
        x = measured[-1]
        outs.append(u)
    np.testing.assert_allclose(np.concatenate(outs)[:94], r.accel, rtol=1e-6, atol=1e-6)


def test_decode_from_latent_matches_deform(deformer):
    states = gen.straight((0.0, 0.1, -1.0), 80)
    r = deformer.deform(states)
    again = deformer.decode(r.latent, states[0], 80)
    np.testing.assert_allclose(again.accel, r.accel, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize(
    "bad,match",
    [
        (np.zeros((10, 5)), "columns"),
        (np.zeros((1, 6)), "K = 2"),
        (np.zeros(6), "shape"),
        (np.full((10, 6), np.nan), "NaN"),
        (np.zeros((0, 10, 6)), "empty"),
        ("abc", "numeric"),
    ],
)
def test_bad_input_raises_clear_errors(deformer, bad, match):
    with pytest.raises(ValueError, match=match):
        deformer.deform(bad)


def test_generator_misuse(deformer):
    g = deformer.generator(gen.straight((0.1, 0, 1), 50))
    with pytest.raises(ValueError, match="first step"):
        g.step(np.zeros((g.chunk, 6)))
    g.step()
    with pytest.raises(ValueError, match="measured"):
        g.step()
    with pytest.raises(ValueError, match="last"):
        g.step(np.zeros((g.chunk + 1, 6)))


def test_save_and_load_round_trip(deformer, tmp_path):
    deformer.save_pretrained(tmp_path / "m")
    again = Deformer.from_pretrained(tmp_path / "m")
    s = gen.straight((0.1, 0.1, 1.0), 64)
    np.testing.assert_array_equal(again.deform(s).accel, deformer.deform(s).accel)
