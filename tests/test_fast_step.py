"""The faster training step (issue 21, part 3) computes what the chunk-by-chunk path computes."""

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion.models.lstm import StackedLSTM
from seqmotion.models.seq2seq import rollout
from seqmotion.physics.integrator import (
    CovarianceCarry,
    DoubleIntegratorDynamics,
    propagate_covariance,
    propagate_entrywise,
)
from seqmotion.training.losses import pad_to


class ChunkByChunk:
    """The double integrator without ``propagate_entrywise``: :func:`rollout` takes its chunk-by-chunk loop."""

    def __init__(self) -> None:
        self.inner = DoubleIntegratorDynamics(3)

    def start(self, x0):  # noqa: ANN001, ANN201
        return self.inner.start(x0)

    def step(self, carry, mean, cov):  # noqa: ANN001, ANN201
        return self.inner.step(carry, mean, cov)

    def decoder_input(self, states):  # noqa: ANN001, ANN201
        return self.inner.decoder_input(states)

    def restart(self, carry, state, mask):  # noqa: ANN001, ANN201
        return self.inner.restart(carry, state, mask)


@pytest.fixture(scope="module")
def small_model_and_batch():
    task = sm.tasks.get("pancake")
    cfg = task.train_config("small")
    torch.manual_seed(0)
    model = task.build_model(cfg)
    batch = task.sample(16, np.random.default_rng(3), task.params(task.curriculum(cfg).at(15, 0.5)), task.options(cfg))
    return model, torch.from_numpy(batch.states).float(), torch.from_numpy(batch.lengths)


@pytest.mark.parametrize("teacher_forcing_prob", [0.0, 0.5, 1.0])
def test_entrywise_rollout_equals_the_chunk_by_chunk_loop(small_model_and_batch, teacher_forcing_prob):
    model, states, lengths = small_model_and_batch
    with torch.no_grad():
        z = model.encode(states, lengths)
        n = model.num_chunks(states.shape[1])
        teacher = pad_to(states, n * model.chunk + 1).double()
        runs = [rollout(model, z, states[:, 0].double(), dyn, n, teacher=teacher,
                        teacher_forcing_prob=teacher_forcing_prob, generator=torch.Generator().manual_seed(7))
                for dyn in (DoubleIntegratorDynamics(3), ChunkByChunk())]
    fast, loop = runs
    assert torch.equal(fast.states, loop.states) and torch.equal(fast.accel, loop.accel)
    torch.testing.assert_close(fast.accel_cov, loop.accel_cov.to(fast.accel_cov.dtype), rtol=1e-6, atol=0)
    torch.testing.assert_close(fast.outputs["pos_cov"], loop.outputs["pos_cov"], rtol=1e-9, atol=1e-30)
    compact = rollout(model, z, states[:, 0].double(), DoubleIntegratorDynamics(3), n, teacher=teacher,
                      teacher_forcing_prob=teacher_forcing_prob, generator=torch.Generator().manual_seed(7),
                      expand_cov=False)
    assert compact.accel_cov is None and "pos_cov" not in compact.outputs
    for i, j in [(0, 0), (0, 1), (1, 0), (1, 1), (2, 2), (0, 2)]:
        torch.testing.assert_close(compact.cov_entry("pos_cov", i, j), loop.outputs["pos_cov"][..., i, j],
                                   rtol=1e-9, atol=1e-30)


def test_propagate_entrywise_matches_the_chunk_recursion_with_restarts():
    torch.manual_seed(1)
    b, n, c = 5, 4, 7
    cov = torch.randn(b, n * c, 3, 3, dtype=torch.float64)
    cov = cov @ cov.transpose(-1, -2)
    known = torch.rand(b, n) < 0.4
    known[:, 0] = True
    carry, expected = CovarianceCarry.zeros(b, 3, torch.float64, torch.device("cpu")), []
    for k in range(n):
        if k:
            carry = carry.reset_where(known[:, k])
        pos, carry = propagate_covariance(carry, cov[:, k * c : (k + 1) * c])
        expected.append(pos)
    expected = torch.cat(expected, dim=1)
    entries = torch.stack([cov[..., i, j] for i, j in [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2)]], dim=1)
    got = propagate_entrywise(entries, known, c)
    for e, (i, j) in enumerate([(0, 0), (1, 1), (2, 2), (0, 1), (0, 2)]):
        torch.testing.assert_close(got[:, e], expected[..., i, j], rtol=1e-10, atol=1e-25)
    with pytest.raises(ValueError, match="chunks"):
        propagate_entrywise(entries[..., :-1], known, c)


def _encode_step_by_step_masked(model, x, lengths):  # noqa: ANN001, ANN202
    """The reference encoder: every trajectory step by step, its state frozen past its last chunk (masking)."""
    b, k, f = x.shape
    c = model.chunk
    n = -(-k // c)
    x = torch.cat([x, x[:, -1:].expand(b, n * c - k, f)], dim=1)
    inputs = model.encoder_in((x / model.encoder_scale).reshape(b, n, -1))
    active = torch.arange(n).unsqueeze(0) < torch.ceil(lengths.double() / c).unsqueeze(1)
    cells = []
    for cell in model.encoder.cells:
        h = cc = inputs.new_zeros(b, model.cfg.hidden)
        outputs = []
        for step in range(n):
            h_new, c_new = cell(inputs[:, step], (h, cc))
            keep = active[:, step].unsqueeze(1)
            h, cc = torch.where(keep, h_new, h), torch.where(keep, c_new, cc)
            outputs.append(h)
        inputs = torch.stack(outputs, dim=1)
        cells.append(cc)
    return torch.cat(cells, dim=1)


@pytest.mark.parametrize("training", [False, True])
def test_packed_encoder_equals_step_by_step_masking(small_model_and_batch, training):
    """The encoder skips trajectories that have ended (packed, longest first) and puts the latents back in the
    batch's order: the same z as running every trajectory to the end with its state frozen, in any order."""
    model, states, lengths = small_model_and_batch
    model = model.double().train(training)
    states = states.double()
    lengths = lengths.clone()
    lengths[3] = 1  # one chunk only
    shuffled = torch.randperm(len(lengths), generator=torch.Generator().manual_seed(0))
    try:
        with torch.no_grad():
            expected = _encode_step_by_step_masked(model, states, lengths)
            torch.testing.assert_close(model.encode(states, lengths), expected, rtol=1e-12, atol=1e-12)
            torch.testing.assert_close(model.encode(states[shuffled], lengths[shuffled]), expected[shuffled],
                                       rtol=1e-12, atol=1e-12)
            full = torch.full_like(lengths, states.shape[1])
            torch.testing.assert_close(model.encode(states), _encode_step_by_step_masked(model, states, full),
                                       rtol=1e-12, atol=1e-12)
            assert not model.encode(states, torch.zeros_like(lengths)).any()  # no samples: the zero state
    finally:
        model.float().train()


def test_packed_lstm_refuses_sizes_that_are_not_longest_first():
    lstm = StackedLSTM(8, 6, 2)
    with pytest.raises(ValueError, match="non-increasing"):
        lstm.run_packed(torch.randn(7, 8), [3, 4])


def test_gaussian_head_covariance_is_the_entry_by_entry_one():
    task = sm.tasks.get("pancake")
    torch.manual_seed(3)
    model = task.build_model(task.train_config("tiny"))
    h = torch.randn(6, model.cfg.hidden)
    mean, cov = model.head(h)
    raw = model.head.net(h).view(6, model.chunk, -1)
    sigma = model.head.scale * (torch.nn.functional.softplus(raw[..., 3:6]) + model.head.sigma_min)
    rho = 0.99 * torch.tanh(raw[..., 6])
    ref = torch.zeros(6, model.chunk, 3, 3)
    for i in range(3):
        ref[..., i, i] = sigma[..., i] ** 2
    ref[..., 0, 1] = ref[..., 1, 0] = rho * sigma[..., 0] * sigma[..., 1]
    torch.testing.assert_close(cov, ref, rtol=1e-6, atol=0)
    torch.testing.assert_close(mean, model.head.offset + model.head.scale * raw[..., :3], rtol=0, atol=0)


def test_lstm_tanh_through_sigmoid_is_tanh():
    from seqmotion.models import lstm

    x = torch.linspace(-30, 30, 100_001)
    assert float((lstm._tanh(x) - torch.tanh(x)).abs().max()) < 3e-7


def test_cached_maps_made_in_inference_mode_serve_autograd():
    from seqmotion.physics import integrator

    integrator._integration_maps.cache_clear()
    integrator._chunk_covariance_map.cache_clear()
    integrator._carry_basis.cache_clear()
    x0, u = torch.zeros(2, 6), torch.ones(2, 5, 3)
    entries, known = torch.ones(2, 4, 10), torch.ones(2, 2, dtype=torch.bool)
    with torch.inference_mode():
        integrator.integrate_chunk(x0, u)
        integrator.propagate_entrywise(entries, known, 5)
    u.requires_grad_(True)
    entries.requires_grad_(True)
    (integrator.integrate_chunk(x0, u).sum() + integrator.propagate_entrywise(entries, known, 5).sum()).backward()
    assert u.grad is not None and entries.grad is not None


def _within_lengths(x: torch.Tensor, limit: torch.Tensor) -> torch.Tensor:
    """``x`` ``(B, T, …)`` with the samples at or past ``limit`` ``(B,)`` set to zero."""
    keep = torch.arange(x.shape[1]).unsqueeze(0) < limit.unsqueeze(1)
    return x * keep.view(*keep.shape, *([1] * (x.ndim - 2))).to(x.dtype)


@pytest.mark.parametrize("task_name", ["pancake", "sliding"])
def test_rollout_skips_ended_trajectories_with_the_same_numbers_within_their_lengths(task_name):
    """``rollout(..., lengths=)`` runs each trajectory only up to its last chunk (pancake: the entrywise
    covariance path with teacher forcing; sliding: the chunk-by-chunk path with per-trajectory friction), in any
    batch order: within every trajectory's chunks it gives the numbers and gradients of running all chunks, the
    same coin per trajectory, and zero past them."""
    task = sm.tasks.get(task_name)
    cfg = task.train_config("tiny")
    torch.manual_seed(4)
    model = task.build_model(cfg).double()
    stage = task.curriculum(cfg).at(cfg.epochs - 1, 0.5)
    batch = task.sample(12, np.random.default_rng(5), task.params(stage), task.options(cfg))
    shuffled = np.random.default_rng(6).permutation(len(batch))  # the rollout sorts and puts back
    batch = batch.select(shuffled)
    states = torch.from_numpy(batch.states).double()
    lengths = torch.from_numpy(batch.lengths)
    if task_name == "pancake":
        x0, dynamics, prob = states[:, 0], DoubleIntegratorDynamics(3), 0.5
    else:
        from seqmotion.tasks.sliding.physics import SlidingDynamics

        x0 = torch.zeros(len(batch), 8, dtype=torch.float64)
        x0[:, 4:] = states[:, 0]
        dynamics = SlidingDynamics(torch.from_numpy(batch.extras["mu"]), torch.from_numpy(batch.extras["mu_dyn"]))
        prob = 0.0
    n = model.num_chunks(states.shape[1])
    chunks = ((lengths - 2).clamp_min(0) // model.chunk + 1) * model.chunk  # samples each trajectory's chunks hold
    z = model.encode(states, lengths)
    runs = []
    for given in (None, lengths):
        model.zero_grad()
        out = rollout(model, z, x0, dynamics, n, teacher=pad_to(states, n * model.chunk + 1) if prob else None,
                      teacher_forcing_prob=prob, generator=torch.Generator().manual_seed(8), lengths=given)
        masked = (_within_lengths(out.states[:, 1:], chunks), _within_lengths(out.accel, chunks),
                  _within_lengths(out.outputs["pos_cov"], chunks))
        sum(m.square().sum() for m in masked).backward(retain_graph=True)
        runs.append((out, masked, [p.grad.clone() for p in model.parameters()]))
    (_, full, full_grad), (packed_out, packed, packed_grad) = runs
    for a, b in zip(full, packed, strict=True):
        torch.testing.assert_close(b, a, rtol=1e-10, atol=1e-12)
    for a, b in zip(full_grad, packed_grad, strict=True):
        torch.testing.assert_close(b, a, rtol=1e-8, atol=1e-10)
    past = _within_lengths(packed_out.states[:, 1:], chunks) - packed_out.states[:, 1:]
    assert lengths.min() < n * model.chunk - model.chunk  # some trajectory did skip chunks
    assert not past.any()  # past a trajectory's chunks: zero
