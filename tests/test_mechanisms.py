"""One of each small mechanism: each is computed in one place, and the places that used to copy it agree."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from seqmotion.data.trajectories import tracking_rmse
from seqmotion.models.seq2seq import chunks_needed
from seqmotion.physics import integrator
from seqmotion.tasks.pancake.physics import PancakePhysics, check_mu, cone_half_angle, violation_torch
from seqmotion.training.config import Optimization, TrainConfig


def test_integrate_numpy_is_integrate_bit_for_bit():
    rng = np.random.default_rng(3)
    for batch, k, d in [((), 1, 1), ((), 700, 3), ((2,), 45, 2), ((3, 2), 9, 4)]:
        x0 = rng.normal(size=batch + (2 * d,))
        accel = rng.normal(scale=30.0, size=batch + (k, d))
        closed = integrator.integrate(torch.from_numpy(x0), torch.from_numpy(accel)).numpy()
        np.testing.assert_array_equal(integrator.integrate_numpy(x0, accel), closed)
    x, u = rng.normal(size=4), rng.normal(size=(50, 2))
    steps = [x]
    for k in range(50):
        steps.append(integrator.step_reference(steps[-1], u[k]))
    np.testing.assert_allclose(integrator.integrate_numpy(x, u), np.array(steps), atol=1e-12)


def test_integrate_covariance_agrees_with_the_definition_and_the_chunk_form():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(30, 2, 2))
    s_u = a @ a.transpose(0, 2, 1)
    reference = integrator.propagate_covariance_reference(s_u)[1:, :2, :2]
    whole = integrator.integrate_covariance(torch.from_numpy(s_u)[None]).numpy()[0]
    chunk, _ = integrator.propagate_covariance(integrator.CovarianceCarry.zeros(1, 2, torch.float64, "cpu"),
                                              torch.from_numpy(s_u)[None])
    np.testing.assert_allclose(whole, reference, rtol=1e-9, atol=1e-22)
    np.testing.assert_allclose(chunk.numpy()[0], reference, rtol=1e-9, atol=1e-22)


@pytest.mark.parametrize("chunk", [1, 3, 10, 64])
def test_chunks_needed_for_ints_and_tensors(chunk):
    lengths = list(range(0, 200))
    expected = [max(1, math.ceil((k - 1) / chunk)) for k in lengths]
    assert [chunks_needed(k, chunk) for k in lengths] == expected
    assert chunks_needed(torch.tensor(lengths), chunk).tolist() == expected


def test_tracking_rmse():
    achieved = np.array([[0.0, 0.0], [3.0, 4.0], [0.0, 0.0], [0.0, 0.0]])
    assert tracking_rmse(achieved, np.zeros_like(achieved)) == pytest.approx(math.sqrt(25 / 4))
    assert tracking_rmse(achieved) == tracking_rmse(achieved + 1.0, np.ones_like(achieved))
    batch = tracking_rmse(np.stack([achieved, 2 * achieved]), np.zeros((2, 4, 2)))
    np.testing.assert_allclose(batch, [2.5, 5.0])
    assert math.isnan(tracking_rmse(np.zeros((0, 3))))
    with pytest.raises(ValueError, match="positions"):
        tracking_rmse(np.zeros(5))


def test_the_stop_brings_the_reference_to_rest_and_the_tail_follows_it():
    from seqmotion.sim.kinematics import _with_tail, stop_accelerations

    vel = np.array([0.4, -1.2, 3.0])
    accel = stop_accelerations(vel, decel_time=0.1, hold_time=0.05, dt=1e-3)
    assert accel.shape == (150, 3)
    np.testing.assert_array_equal(accel[:100], np.tile(-vel / 0.1, (100, 1)))
    np.testing.assert_array_equal(accel[100:], 0.0)
    states = integrator.integrate_numpy(np.concatenate([np.zeros(3), vel]), accel)
    np.testing.assert_allclose(states[100:, 3:], 0.0, atol=1e-12)  # at rest after 0.1 s, held
    pos, v, a = _with_tail(np.zeros((1, 3)), vel[None], 0.1, 0.05, 1e-3)
    np.testing.assert_allclose(pos, states[:, :3], atol=1e-12)  # the arm's reference is that integration
    np.testing.assert_allclose(v, states[:, 3:], atol=1e-12)
    np.testing.assert_array_equal(a[:-1], accel)
    assert stop_accelerations(vel, 0.0, 0.0, 1e-3).shape == (0, 3)


def test_one_mu_check_and_one_cone_angle():
    assert cone_half_angle(1.0) == pytest.approx(math.pi / 4)
    assert PancakePhysics(mu=0.8).cone_half_angle == cone_half_angle(0.8)
    theta = torch.zeros(1, dtype=torch.float64)  # a level spatula pushed sideways: |ψ| = atan(a / g)
    assert float(violation_torch(theta, torch.tensor([[20.0, 0.0, 0.0]], dtype=torch.float64), 1.0)) == \
        pytest.approx(math.atan2(20.0, 9.8) - math.pi / 4)
    assert float(violation_torch(theta, torch.tensor([[5.0, 0.0, 0.0]], dtype=torch.float64), 1.0)) == 0.0
    for bad in (0.0, -1.0, float("nan"), float("inf"), True, "1", None):
        with pytest.raises(ValueError, match="mu"):
            check_mu(bad)
        with pytest.raises(ValueError, match="mu"):
            PancakePhysics(mu=bad)
    assert check_mu(np.float32(0.5)) == 0.5 and isinstance(check_mu(2), float)


def test_every_training_shares_one_optimisation_config():
    from seqmotion.lfd.train import CNNTraining, SeqAETraining

    config = TrainConfig("pancake", "tiny", {}, {"epochs": 1}, 1, 2, lr=3e-3)
    for settings in (config, SeqAETraining(lr=3e-3), CNNTraining(lr=3e-3)):
        assert isinstance(settings, Optimization)
        assert settings.loop_settings()["lr"] == 3e-3
    assert SeqAETraining().loop_settings() == {"lr": 1e-3, "lr_final_fraction": 0.1, "grad_clip": 1.0}
    assert CNNTraining().loop_settings() == {"lr": 1e-3, "lr_final_fraction": 1.0, "grad_clip": None}
    for cls, args in ((TrainConfig, ("pancake", "tiny", {}, {"epochs": 1}, 1, 2)), (SeqAETraining, ()),
                      (CNNTraining, ())):
        for name, value in (("lr", 0.0), ("lr", float("nan")), ("lr_final_fraction", 1.5), ("grad_clip", -1.0)):
            with pytest.raises(ValueError, match=name):
                cls(*args, **{name: value})
