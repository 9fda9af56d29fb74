"""The chunked seq2seq model: shapes, latent, masking of padding, Gaussian head."""

import numpy as np
import pytest
import torch

from seqmotion.models.seq2seq import ChunkedSeq2Seq, Seq2SeqConfig, rollout
from seqmotion.physics.integrator import DoubleIntegratorDynamics


def make(chunk=5, layers=2, hidden=8, **kw) -> ChunkedSeq2Seq:
    torch.manual_seed(0)
    return ChunkedSeq2Seq(Seq2SeqConfig(6, 6, 3, chunk=chunk, layers=layers, hidden=hidden, **kw))


def test_latent_is_layers_times_hidden_and_initialises_decoder():
    model = make(layers=2, hidden=64)
    z = model.encode(torch.randn(3, 23, 6))
    assert z.shape == (3, 128)  # 2 × 64, as in ch. 4.3.1
    state = model.initial_state(z)
    assert len(state) == 2
    for (h, c), part in zip(state, z.split(64, dim=1), strict=True):
        assert torch.equal(c, part) and torch.count_nonzero(h) == 0


@pytest.mark.parametrize("chunk,layers,hidden", [(1, 1, 4), (7, 3, 16), (50, 2, 32)])
def test_any_chunk_layers_width(chunk, layers, hidden):
    model = make(chunk=chunk, layers=layers, hidden=hidden)
    x = torch.randn(2, 61, 6)
    z = model.encode(x)
    n = model.num_chunks(61)
    out = rollout(model, z, x[:, 0], DoubleIntegratorDynamics(3), n)
    assert out.states.shape == (2, n * chunk + 1, 6)
    assert out.accel.shape == (2, n * chunk, 3)
    assert out.accel_cov.shape == (2, n * chunk, 3, 3)
    assert out.outputs["pos_cov"].shape == (2, n * chunk, 3, 3)


def test_covariances_are_positive_definite_with_yz_correlation_only():
    model = make()
    state = model.initial_state(torch.randn(4, 16))
    _, mean, cov = model.decode_step(state, torch.randn(4, 5, 6) * 3)
    eig = torch.linalg.eigvalsh(cov)
    assert (eig > 0).all()
    assert torch.count_nonzero(cov[..., 0, 2]) == 0 and torch.count_nonzero(cov[..., 1, 2]) == 0
    assert torch.allclose(cov, cov.transpose(-1, -2))


def test_padding_does_not_change_a_trajectorys_latent():
    model = make(chunk=5)
    short = torch.randn(1, 12, 6)
    padded = torch.cat([short, short[:, -1:].expand(1, 20, 6)], dim=1)  # batch padding: repeat last
    other = torch.randn(1, 32, 6)
    z_alone = model.encode(short)
    z_batched = model.encode(torch.cat([padded, other]), torch.tensor([12, 32]))
    torch.testing.assert_close(z_batched[0:1], z_alone)


def test_teacher_forcing_feeds_true_chunks():
    model = make(chunk=4)
    x = torch.randn(2, 17, 6, dtype=torch.float64)
    z = model.encode(x.float())
    free = rollout(model, z, x[:, 0], DoubleIntegratorDynamics(3), 4)
    forced = rollout(model, z, x[:, 0], DoubleIntegratorDynamics(3), 4, teacher=x, teacher_forcing_prob=1.0)
    # the first step sees (x0, …, x0) either way; later steps differ once the true states are fed
    torch.testing.assert_close(free.accel[:, :4], forced.accel[:, :4])
    assert not torch.allclose(free.accel[:, 4:], forced.accel[:, 4:])
    # and the physics restarts from the true state at each boundary
    torch.testing.assert_close(forced.states[:, 5, :], forced.states[:, 5, :])
    step1 = forced.states[:, 5:9]
    from seqmotion.physics.integrator import integrate

    torch.testing.assert_close(step1, integrate(x[:, 4], forced.accel[:, 4:8].double())[:, 1:])


def test_config_validation():
    with pytest.raises(ValueError, match="chunk"):
        Seq2SeqConfig(6, 6, 3, chunk=0)
    with pytest.raises(ValueError, match="correlated pair"):
        Seq2SeqConfig(6, 6, 3, correlated_pairs=[[0, 3]])
    with pytest.raises(ValueError, match="output_scale"):
        Seq2SeqConfig(6, 6, 3, output_scale=[1.0])
    model = make()
    with pytest.raises(ValueError, match="latent"):
        model.initial_state(torch.zeros(2, 5))


def test_config_json_round_trip():
    cfg = Seq2SeqConfig(6, 6, 3, chunk=9, head_hidden=12, output_scale=[1.0, 2.0, 3.0])
    import json

    assert Seq2SeqConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg


def test_gradients_reach_latent_through_physics():
    model = make()
    x = torch.randn(1, 20, 6)
    z = model.encode(x).detach().requires_grad_(True)
    out = rollout(model, z, x[:, 0], DoubleIntegratorDynamics(3), 4, need_cov=False)
    out.states[:, -1, :3].sum().backward()
    assert z.grad is not None and np.isfinite(z.grad.numpy()).all() and z.grad.abs().sum() > 0


def test_int8_weights_stay_close_to_float():
    from seqmotion.models.quantize import Int8Linear, quantize_int8

    torch.manual_seed(0)
    for in_features in (512, 500):  # packed kernel (multiple of 16) and the dequantised fallback
        layer = torch.nn.Linear(in_features, 300)
        x = torch.randn(7, in_features)
        with torch.no_grad():
            y, yq = layer(x), Int8Linear(layer)(x)
        assert yq.shape == y.shape and torch.isfinite(yq).all()
        assert float((yq - y).norm() / y.norm()) < 0.02
    model = torch.nn.Sequential(torch.nn.Linear(256, 256), torch.nn.Tanh(), torch.nn.Linear(256, 8))
    q = quantize_int8(model)
    assert isinstance(q[0], Int8Linear) and isinstance(q[2], torch.nn.Linear)  # narrow layers stay float
    assert isinstance(model[0], torch.nn.Linear)  # the original is untouched
    with pytest.raises(ValueError, match="min_features"):
        quantize_int8(model, 0)
