"""The batched torch contact model (``backend="torch"``) against the numba kernel, case for case.

On the CPU both compute in float64 with the same operations in the same order (torch's CPU ``sqrt``
corrected to round to nearest), so states, Jacobians and stick/slip decisions must agree bit for bit,
also on inputs built to sit at the decision boundaries; gradients (a different summation order) to
float tolerance. The CUDA test repeats the comparison on a GPU and skips where there is none.
"""

import numpy as np
import pytest
import torch

from seqmotion import tasks
from seqmotion.tasks.sliding import physics as sliding
from seqmotion.training.trainer import step_loss

G, MU, MU_DYN = sliding.GRAVITY, sliding.MU, sliding.MU_DYN
TORCH_BACKENDS = ("torch", "torch_autograd")


def run(backend, rel0, u, mu=MU, mu_dyn=MU_DYN, upstream=None):
    """States, Jacobian, branch and (with ``upstream``, a weight on the states) the gradients."""
    rel0 = rel0.detach().clone().requires_grad_(upstream is not None)
    u = u.detach().clone().requires_grad_(upstream is not None)
    states, jac, branch = sliding.contact_chunk(rel0, u, mu, mu_dyn, backend=backend)
    grads = None
    if upstream is not None:
        (states * upstream).sum().backward()
        grads = (rel0.grad, u.grad)
    return states.detach(), jac, branch, grads


def random_case(seed, batch=48, steps=60, dtype=torch.float64):
    """Starts at rest and sliding, pushes below and above μ g, per-trajectory friction."""
    rng = np.random.default_rng(seed)
    pos = rng.normal(scale=0.01, size=(batch, 2))
    vel = rng.normal(scale=0.3, size=(batch, 2)) * (rng.random((batch, 1)) < 0.5)
    rel0 = torch.tensor(np.concatenate([pos, vel], 1), dtype=dtype)
    u = torch.tensor(rng.normal(scale=12, size=(batch, steps, 2)) * rng.uniform(0.2, 2, (batch, 1, 1)), dtype=dtype)
    mu = torch.tensor(rng.uniform(0.4, 1.5, batch))
    return rel0, u, mu, mu * torch.tensor(rng.uniform(0, 1, batch))


def assert_same_forward(a, b):
    assert torch.equal(a[2], b[2]), "stick/slip decisions differ"
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])  # states and Jacobians, bit for bit


@pytest.mark.parametrize("backend", TORCH_BACKENDS)
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_same_states_jacobians_and_branches_as_numba(backend, dtype):
    for seed in range(3):
        rel0, u, mu, mu_dyn = random_case(seed, dtype=dtype)
        ref = run("numba", rel0, u, mu, mu_dyn)
        assert_same_forward(run(backend, rel0, u, mu, mu_dyn), ref)
        assert ref[0].dtype == dtype
        assert set(ref[2].unique().tolist()) == {sliding.STICK, sliding.BREAKAWAY, sliding.SLIDE, sliding.STOP}


def ulps_around(x, n):
    """``x`` and its ``n`` float64 neighbours on either side."""
    out = [x]
    lo = hi = x
    for _ in range(n):
        lo, hi = np.nextafter(lo, -np.inf), np.nextafter(hi, np.inf)
        out += [lo, hi]
    return np.array(out)


def test_same_decisions_at_the_stick_limit():
    """From rest, pushes within a few ulps (and 1e-15 relative) of μ g, along axes and diagonals."""
    mu = np.array([1.0, 0.7, 0.3])
    rows, mus = [], []
    rng = np.random.default_rng(3)
    for m in mu:
        limit = m * G
        mags = np.concatenate([ulps_around(limit, 6), limit * (1 + rng.uniform(-1e-15, 1e-15, 24))])
        angles = np.concatenate([[0.0, np.pi / 2, np.pi / 4, 3 * np.pi / 4], rng.uniform(0, 2 * np.pi, 8)])
        for mag in mags:
            for a in angles:
                rows.append([mag * np.cos(a), mag * np.sin(a)])
                mus.append(m)
    u = torch.tensor(rows).unsqueeze(1)  # one step each
    mu_t = torch.tensor(mus)
    rel0 = torch.zeros(len(rows), 4, dtype=torch.float64)
    ref = run("numba", rel0, u, mu_t, 0.5 * mu_t)
    codes = ref[2][:, 0]
    assert (codes == sliding.STICK).any() and (codes == sliding.BREAKAWAY).any()  # both sides are hit
    for backend in TORCH_BACKENDS:
        assert_same_forward(run(backend, rel0, u, mu_t, 0.5 * mu_t), ref)


def test_same_decisions_at_the_stop():
    """Sliding at a speed within a few ulps of what one step of dynamic friction removes (so the
    velocity lands at ±0), with no push and with pushes along and across the motion."""
    rng = np.random.default_rng(4)
    dt = sliding.DT
    rels, pushes, mud = [], [], []
    for m_dyn in (0.5, 0.25, 0.8):
        one_step = dt * m_dyn * G
        for speed in np.concatenate([ulps_around(one_step, 6), one_step * (1 + rng.uniform(-1e-14, 1e-14, 12))]):
            for a in np.concatenate([[0.0, np.pi / 3], rng.uniform(0, 2 * np.pi, 4)]):
                n = np.array([np.cos(a), np.sin(a)])
                for push in (np.zeros(2), 1e-9 * n, -1e-9 * n, rng.normal(scale=1e-9, size=2)):
                    rels.append([0.0, 0.0, *(speed * n)])
                    pushes.append([push, push])  # two steps: the stop, then what follows it
                    mud.append(m_dyn)
    rel0, u, mu_dyn = torch.tensor(rels), torch.tensor(np.array(pushes)), torch.tensor(mud)
    ref = run("numba", rel0, u, 1.0, mu_dyn)
    codes = ref[2][:, 0]
    assert (codes == sliding.STOP).any() and (codes == sliding.SLIDE).any()
    for backend in TORCH_BACKENDS:
        assert_same_forward(run(backend, rel0, u, 1.0, mu_dyn), ref)
    # and 20000 random ones (any friction, any direction, ±8 ulps): about 1 in 2000 of these decides
    # differently with torch's own CPU sqrt, which is why the torch path rounds its square roots to nearest
    n = 20000
    m_dyn = rng.uniform(0.1, 1.0, n)
    speed = dt * m_dyn * G * (1 + rng.integers(-8, 9, n) * 2.0**-52)
    a = rng.uniform(0, 2 * np.pi, n)
    rel0 = torch.tensor(np.stack([0 * a, 0 * a, speed * np.cos(a), speed * np.sin(a)], 1))
    u = torch.zeros(n, 1, 2, dtype=torch.float64)
    ref = run("numba", rel0, u, 1.0, torch.tensor(m_dyn))
    assert_same_forward(run("torch", rel0, u, 1.0, torch.tensor(m_dyn)), ref)


def test_degenerate_inputs_decide_alike():
    """Zero push from rest (|u| = 0: stick, no 0/0), a speed whose square underflows (treated as rest by
    both), a push of exactly μ g (breakaway: ``|u| ≥ μ g``), and NaN (a slide, as the kernel says)."""
    rel0 = torch.tensor([[0, 0, 0, 0], [0, 0, 1e-170, 0], [0, 0, 0, 0], [0, 0, 0.3, 0], [0, 0, 0, 0.0]])
    u = torch.tensor([[0, 0], [0, 0], [G, 0], [np.nan, 0], [0, -G]]).unsqueeze(1).double()
    ref = run("numba", rel0, u)
    assert ref[2][:, 0].tolist() == [sliding.STICK, sliding.STICK, sliding.BREAKAWAY, sliding.SLIDE, sliding.BREAKAWAY]
    for backend in TORCH_BACKENDS:
        out = run(backend, rel0, u)
        assert torch.equal(out[2], ref[2])
        torch.testing.assert_close(out[0], ref[0], equal_nan=True, rtol=0, atol=0)


@pytest.mark.parametrize("backend", TORCH_BACKENDS)
def test_gradients_match_the_numba_backward(backend):
    for seed in range(2):
        rel0, u, mu, mu_dyn = random_case(seed + 10, batch=16, steps=80)
        upstream = torch.tensor(np.random.default_rng(seed).normal(size=(16, 80, 4)))
        ref = run("numba", rel0, u, mu, mu_dyn, upstream)
        out = run(backend, rel0, u, mu, mu_dyn, upstream)
        assert torch.equal(out[2], ref[2])
        for got, want in zip(out[3], ref[3], strict=True):
            torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)
        assert out[3][1].abs().sum() > 0


@pytest.mark.parametrize("backend", sliding.BACKENDS)
def test_gradients_match_finite_differences(backend):
    """Through all four cases (numba too: tests/test_physics_sliding.py's inputs only slide). Rest
    (v = 0) is itself a case boundary (any speed slides), so the two trajectories that start at rest
    are differentiated in their start position and pushes only."""
    rng = np.random.default_rng(2)
    pos0 = torch.tensor(rng.normal(scale=0.01, size=(3, 2)), requires_grad=True)
    # the second slides, stops, then sticks
    vel0 = torch.tensor([[0.012, -0.01]], dtype=torch.float64, requires_grad=True)
    u = torch.tensor(rng.normal(scale=30, size=(3, 16, 2)))
    u[0, :5] = 3.0  # the first sticks, then breaks away, slides and stops; so does the third
    u[1] = torch.tensor(rng.normal(scale=1.0, size=(16, 2)))
    u.requires_grad_(True)
    mu, mu_dyn = torch.tensor([1.0, 0.6, 1.2]), torch.tensor([0.5, 0.3, 1.0])

    def start(p, v):
        rest = torch.zeros(1, 2, dtype=torch.float64)
        return torch.cat([p, torch.cat([rest, v, rest])], 1)

    def f(p, v, a):
        return sliding.contact_chunk(start(p, v), a, mu, mu_dyn, backend=backend)[0]

    branch = sliding.contact_chunk(start(pos0, vel0).detach(), u.detach(), mu, mu_dyn)[2]
    assert set(branch.unique().tolist()) == {sliding.STICK, sliding.BREAKAWAY, sliding.SLIDE, sliding.STOP}
    # finite differences only where no sample sits on a case boundary (true for these inputs)
    assert torch.autograd.gradcheck(f, (pos0, vel0, u), eps=1e-7, atol=1e-5, rtol=1e-4)


@pytest.mark.parametrize("backend", TORCH_BACKENDS)
def test_exactly_zero_and_finite_gradient_through_stick_and_stop(backend):
    """At rest with no push (|v| = |u| = 0: the norms' square roots must not make NaN), sticking under
    a push, and a slide that stops: exactly zero gradient with respect to the pushes before it."""
    rel0 = torch.zeros(3, 4, dtype=torch.float64)
    rel0[2, 2] = 0.002  # stops within the first step (one step of μ' g dt removes 0.0049 m/s)
    u = torch.zeros(3, 30, 2, dtype=torch.float64)
    u[1] = 3.0  # far below μ g: sticks
    upstream = torch.ones(3, 30, 4, dtype=torch.float64)
    _, _, branch, (g_rel, g_u) = run(backend, rel0, u, upstream=upstream)
    assert (branch[:2] == sliding.STICK).all() and branch[2, 0] == sliding.STOP
    assert (branch[2, 1:] == sliding.STICK).all()
    assert torch.isfinite(g_u).all() and torch.isfinite(g_rel).all()
    assert torch.count_nonzero(g_u) == 0  # the gradient-vanishing zone, exactly
    # the start velocity only reaches the first position update (p1 = p0 + dt (v0 + v1) / 2), as in numba
    torch.testing.assert_close(g_rel, run("numba", rel0, u, upstream=upstream)[3][0], rtol=1e-12, atol=0)
    torch.testing.assert_close(g_rel[:, 2:], torch.full((3, 2), 30 * sliding.DT / 2, dtype=torch.float64))


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_physical_truths_hold_on_every_backend(backend):
    rng = np.random.default_rng(0)
    # an object on a pan pushed below μ g stays exactly put
    u = rng.normal(size=(3, 1500, 2))
    u *= (0.99 * MU * G) * rng.uniform(0, 1, size=(3, 1500, 1)) / np.linalg.norm(u, axis=-1, keepdims=True)
    pan, rel = sliding.rollout(u, backend=backend)
    assert np.all(rel == 0.0) and np.abs(pan).max() > 0.01
    # with the pan still after a few pushes, friction only ever removes kinetic energy, down to rest
    n_push = rng.integers(5, 60, size=12)
    u = np.zeros((12, 900, 2))
    for i, n in enumerate(n_push):
        u[i, :n] = rng.normal(scale=20, size=(n, 2))
    _, rel = sliding.rollout(u, mu=rng.uniform(0.5, 1.2, 12), mu_dyn=rng.uniform(0.2, 0.5, 12), backend=backend)
    energy = 0.5 * (rel[..., 2:] ** 2).sum(-1)
    for i, n in enumerate(n_push):
        assert np.all(np.diff(energy[i, n:]) <= 1e-15)
        assert energy[i, -1] == 0.0


def test_rollout_is_the_same_on_both_backends():
    u = np.random.default_rng(5).normal(scale=15, size=(6, 400, 2))
    for a, b in zip(sliding.rollout(u, 0.8, 0.4), sliding.rollout(u, 0.8, 0.4, backend="torch"), strict=True):
        assert np.array_equal(a, b)


def test_dispatch_by_device_and_name():
    assert sliding.resolve_backend(None, torch.device("cpu")) == sliding.CPU_BACKEND == "numba"
    assert sliding.resolve_backend(None, torch.device("cuda")) == sliding.DEVICE_BACKEND == "torch"
    assert sliding.resolve_backend("torch", torch.device("cpu")) == "torch"
    with pytest.raises(ValueError, match="backend"):
        sliding.resolve_backend("cupy", torch.device("cpu"))
    with pytest.raises(ValueError, match="backend"):
        sliding.SlidingDynamics(backend="jax")


def test_dynamics_step_and_detach_contact_alike_on_both_backends():
    rng = np.random.default_rng(6)
    x0 = torch.tensor(np.concatenate([np.zeros((4, 4)), rng.normal(scale=0.1, size=(4, 4))], 1))
    mean = torch.tensor(rng.normal(scale=12, size=(4, 50, 2)))
    cov = torch.eye(2, dtype=torch.float64).expand(4, 50, 2, 2) * 0.3
    detach = torch.tensor([True, False, True, False])
    results = []
    for backend in ("numba", "torch"):
        dyn = sliding.SlidingDynamics(torch.full((4,), 0.9), torch.full((4,), 0.4), detach_contact=detach,
                                      backend=backend)
        m = mean.clone().requires_grad_(True)
        carry, out = dyn.step(dyn.start(x0), m, cov)
        out["states"][..., 4:6].sum().backward()
        results.append((out, carry, m.grad))
    (a, ca, ga), (b, cb, gb) = results
    for key in a:
        assert torch.equal(a[key], b[key]), key
    assert all(torch.equal(x, y) for x, y in zip(ca[:2], cb[:2], strict=True))
    assert torch.count_nonzero(ga[detach]) == 0 and torch.count_nonzero(gb[detach]) == 0
    torch.testing.assert_close(ga, gb, rtol=1e-10, atol=1e-12)


def test_training_loss_and_gradients_alike_on_both_backends(monkeypatch):
    """The chapter-3 loss of a tiny model (float32, through the contact model) on a batch: the torch
    backend gives the numba one's loss exactly and its parameter gradients to float tolerance."""
    task = tasks.get("sliding")
    cfg = task.train_config("tiny")
    params = {"loss_prime_prob": 0.0, "bspline_prob": 0.5}
    batch = task.sample(6, np.random.default_rng(0), task.params(params), task.options(cfg))
    results = []
    for backend in ("numba", "torch"):
        torch.manual_seed(0)
        model = task.build_model(cfg)
        monkeypatch.setattr(sliding, "CPU_BACKEND", backend)
        loss, terms = step_loss(task, model, batch, params, cfg, torch.Generator().manual_seed(0))
        loss.backward()
        results.append((loss.detach(), terms, [p.grad for p in model.parameters()]))
    (la, ta, ga), (lb, tb, gb) = results
    assert torch.equal(la, lb) and ta == tb
    for x, y in zip(ga, gb, strict=True):
        torch.testing.assert_close(x, y, rtol=1e-4, atol=1e-6)


needs_cuda = pytest.mark.skipif(
    not torch.cuda.is_available(), reason="no CUDA device here: the torch contact path is checked on the CPU only"
)


@needs_cuda
def test_on_cuda_the_torch_path_runs_there_and_matches_numba():
    rel0, u, mu, mu_dyn = random_case(7, batch=64, steps=100)
    upstream = torch.tensor(np.random.default_rng(7).normal(size=(64, 100, 4)))
    ref = run("numba", rel0, u, mu, mu_dyn, upstream)
    cuda = [t.cuda() for t in (rel0, u, mu, mu_dyn, upstream)]
    assert sliding.resolve_backend(None, cuda[1].device) == "torch"
    out = run(None, *cuda)
    assert out[0].is_cuda and out[2].is_cuda and out[3][1].is_cuda
    assert torch.equal(out[2].cpu(), ref[2])  # CUDA's float64 sqrt and division round to nearest too
    torch.testing.assert_close(out[0].cpu(), ref[0], rtol=1e-12, atol=1e-14)  # positions: a parallel cumsum
    assert torch.equal(out[1].cpu(), ref[1])
    for got, want in zip(out[3], ref[3], strict=True):
        torch.testing.assert_close(got.cpu(), want, rtol=1e-10, atol=1e-12)


@needs_cuda
def test_on_cuda_a_training_loss_runs_on_the_gpu():
    task = tasks.get("sliding")
    cfg = task.train_config("tiny")
    params = {"loss_prime_prob": 0.5, "bspline_prob": 0.5}
    batch = task.sample(6, np.random.default_rng(1), task.params(params), task.options(cfg))
    losses = []
    for device in ("cpu", "cuda"):
        torch.manual_seed(0)
        model = task.build_model(cfg).to(device)
        loss, _ = step_loss(task, model, batch, params, cfg, torch.Generator().manual_seed(0))
        loss.backward()
        assert loss.device.type == device
        assert all(torch.isfinite(p.grad).all() for p in model.parameters())
        losses.append(float(loss))
    assert losses[1] == pytest.approx(losses[0], rel=1e-2)  # cuDNN's LSTM (TF32 allowed) is not the CPU's


def test_float32_gradients_come_back_in_float32():
    rel0, u, mu, mu_dyn = random_case(8, batch=4, steps=20, dtype=torch.float32)
    _, _, _, grads = run("torch", rel0, u, mu, mu_dyn, upstream=torch.ones(4, 20, 4))
    assert all(g.dtype == torch.float32 for g in grads)


def test_shipped_planner_plans_alike_on_both_backends(planner, monkeypatch):
    """The shipped model's plan (physics in the loop at inference) is the same on the torch backend."""
    from seqmotion.tasks.sliding.data import circle

    command = circle(0.05, 600)
    plans = []
    for backend in ("numba", "torch"):
        monkeypatch.setattr(sliding, "CPU_BACKEND", backend)
        plans.append(planner.plan(command, mu=0.7, mu_dyn=0.35))
    for field in ("pan_accel", "pan_states", "rel_states", "uncertainty"):
        assert np.array_equal(getattr(plans[0], field), getattr(plans[1], field)), field
