"""An object sliding on a frying pan: planar Coulomb stick/slip contact (ch. 3, eq. 3.9, SPEC §4).

Pan state ``x_p = [x_p, y_p, vx_p, vy_p]`` follows the double integrator under the pan's
acceleration ``u_p``. The object's state relative to the pan, ``x_d = x_o − x_p``, follows it
under ``u_d``, which friction decides (g = 9.8 m/s², static μ, dynamic μ'):

* sliding (``ṗ_d ≠ 0``):                 ``u_d = −u_p − μ' g ṗ_d / |ṗ_d|``
* sticking and ``|u_p| ≥ μ g`` (breakaway): ``u_d = −u_p + μ g u_p / |u_p|``
* sticking and ``|u_p| < μ g``:             ``u_d = 0``

**Discrete time.** A step of ``dt`` that would reverse the sliding velocity (dynamic
friction overshooting zero) ends with the object at rest, relative velocity exactly 0; from
rest it stays put until ``|u_p| ≥ μ g``. So nothing chatters, an object on a still pan stops
and stays stopped, and with the pan still friction only ever removes relative kinetic energy.
The position update uses the velocity change actually taken (``p' = p + dt (v + v') / 2``),
i.e. the double integrator driven by the effective ``u_d = (v' − v) / dt``.

**Gradients.** The step loop is a numba kernel; its backward pass is derived by hand per
branch and wrapped in a ``torch.autograd.Function``. Through a sticking (or stopping) step
the gradient with respect to ``u_p`` is exactly zero — the "gradient-vanishing zone" the
chapter-3 curriculum exists for; through sliding and breakaway it is not.
``J = ∂u_d/∂u_p`` per sample (−I while sliding, 0 while stuck, ``−I + μg (I − m mᵀ)/|u_p|``
at breakaway) is returned to propagate covariances, ``S_ud = J S_up Jᵀ`` (SPEC §2); it is
treated as a constant in the backward pass.

**Backends.** The same step loop also exists in batched PyTorch (``backend="torch"``), for tensors
on any device (a GPU above all): the loop over samples stays sequential, each step a handful of
elementwise ops over the batch, the stick/slip cases chosen by ``torch.where`` with the numba
kernel's float64 arithmetic in the same order (so the same case every sample, bit for bit, and the
same states); its backward is the same hand derivation, written in torch, with the local
Jacobians of all samples built at once and only a 2 × 2 product per sample left sequential.
``backend=None`` picks numba for CPU tensors (:data:`CPU_BACKEND`; many times faster there, see
``benchmarks/results_sliding_physics.md``) and torch for any other device (:data:`DEVICE_BACKEND`).
"""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np
import torch

from ...errors import as_trajectories, check_finite_array, check_friction, check_number
from ...physics.integrator import DT, CovarianceCarry, integrate, propagate_covariance
from ...physics.layout import StateLayout
from ...physics.parameters import Physics

GRAVITY = 9.8
MU = 1.0
MU_DYN = 0.5
MAX_FRICTION = 1e3
"""Friction coefficients above this are no physics (rubber on rubber is ~1-2): refused by name, not planned."""
STATE_DIM = 4  # [x, y, vx, vy]
ACCEL_DIM = 2
REL_LAYOUT = StateLayout(("x", "y", "v_x", "v_y"), ("m", "m", "m/s", "m/s"), "object state relative to the pan")
PLAN_LAYOUT = StateLayout(
    ("pan_x", "pan_y", "pan_v_x", "pan_v_y", "x", "y", "v_x", "v_y"), ("m", "m", "m/s", "m/s") * 2,
    "pan and object state",
)
ACCEL_LAYOUT = StateLayout(("pan_a_x", "pan_a_y"), ("m/s²", "m/s²"), "pan acceleration")


@dataclasses.dataclass(frozen=True)
class SlidingPhysics(Physics, saved_as="seqmotion.physics.sliding.SlidingPhysics"):  # its name in saved files
    """The pan–object friction the contact model runs at: static μ and dynamic μ' (``0 < μ ≤ 1e3``, ``0 ≤ μ' ≤ μ``).

    A sliding model's default is the nominal friction of its training (``options.mu``, ``options.mu_dyn``);
    ``planner.plan(command, mu=0.8)`` plans at another and the plan records it (``plan.physics``).
    """

    mu: float = MU
    mu_dyn: float = MU_DYN

    def __post_init__(self) -> None:
        mu, mu_dyn = check_pan_friction(self.mu, self.mu_dyn)
        object.__setattr__(self, "mu", mu)
        object.__setattr__(self, "mu_dyn", mu_dyn)


def check_pan_friction(mu: object, mu_dyn: object) -> tuple[float, float]:
    """Static and dynamic pan–object friction as floats (:func:`~seqmotion.errors.check_friction`: ``0 < μ ≤``
    :data:`MAX_FRICTION`, ``0 ≤ μ' ≤ μ``), or ``ValueError`` naming the rule broken."""
    static, dynamic = check_friction(mu, mu_dyn, maximum=MAX_FRICTION, between="a pan and object",
                                     note="; the shipped planners were trained at 0.8-1.2")
    return static, float(dynamic)


# Which case of eq. 3.9 a step took.
STICK, BREAKAWAY, SLIDE, STOP = 0, 1, 2, 3


@numba.njit(cache=True)
def _forward_kernel(p0, v0, u, mu, mu_dyn, dt, g, p_out, v_out, jac_out, branch_out):  # pragma: no cover - jit
    batch, steps = u.shape[0], u.shape[1]
    for b in range(batch):
        px, py, vx, vy = p0[b, 0], p0[b, 1], v0[b, 0], v0[b, 1]
        slide_decel, stick_limit = mu_dyn[b] * g, mu[b] * g
        for k in range(steps):
            ux, uy = u[b, k, 0], u[b, k, 1]
            jxx = jxy = jyy = 0.0
            speed = math.sqrt(vx * vx + vy * vy)
            if speed > 0.0:
                nx, ny = vx / speed, vy / speed
                wx = vx + dt * (-ux - slide_decel * nx)
                wy = vy + dt * (-uy - slide_decel * ny)
                if wx * vx + wy * vy <= 0.0:  # friction would reverse the motion: it stops
                    nvx = nvy = 0.0
                    code = STOP
                else:
                    nvx, nvy = wx, wy
                    code = SLIDE
                    jxx = jyy = -1.0
            else:
                un = math.sqrt(ux * ux + uy * uy)
                if un >= stick_limit and un > 0.0:
                    mx, my = ux / un, uy / un
                    nvx = dt * (-ux + stick_limit * mx)
                    nvy = dt * (-uy + stick_limit * my)
                    code = BREAKAWAY
                    f = stick_limit / un
                    jxx = -1.0 + f * (1.0 - mx * mx)
                    jyy = -1.0 + f * (1.0 - my * my)
                    jxy = -f * mx * my
                else:
                    nvx = nvy = 0.0
                    code = STICK
            px += 0.5 * dt * (vx + nvx)
            py += 0.5 * dt * (vy + nvy)
            vx, vy = nvx, nvy
            p_out[b, k, 0], p_out[b, k, 1] = px, py
            v_out[b, k, 0], v_out[b, k, 1] = vx, vy
            jac_out[b, k, 0, 0], jac_out[b, k, 0, 1] = jxx, jxy
            jac_out[b, k, 1, 0], jac_out[b, k, 1, 1] = jxy, jyy
            branch_out[b, k] = code


@numba.njit(cache=True)
def _backward_kernel(  # pragma: no cover - jit
    v0, u, v_out, branch, mu, mu_dyn, dt, g, grad_p, grad_v, grad_u, grad_p0, grad_v0
):
    batch, steps = u.shape[0], u.shape[1]
    for b in range(batch):
        slide_decel, stick_limit = mu_dyn[b] * g, mu[b] * g
        lpx = lpy = lvx = lvy = 0.0  # adjoints of the state after the current step
        for k in range(steps - 1, -1, -1):
            lpx += grad_p[b, k, 0]
            lpy += grad_p[b, k, 1]
            lvx += grad_v[b, k, 0]
            lvy += grad_v[b, k, 1]
            if k == 0:
                vx, vy = v0[b, 0], v0[b, 1]
            else:
                vx, vy = v_out[b, k - 1, 0], v_out[b, k - 1, 1]
            # dv'/dv = [[a, c], [c, d]], dv'/du = [[e, h], [h, f]] (both symmetric)
            a = c = d = e = h = f = 0.0
            code = branch[b, k]
            if code == SLIDE:
                speed = math.sqrt(vx * vx + vy * vy)
                nx, ny = vx / speed, vy / speed
                s = dt * slide_decel / speed
                a = 1.0 - s * (1.0 - nx * nx)
                d = 1.0 - s * (1.0 - ny * ny)
                c = s * nx * ny
                e = f = -dt
            elif code == BREAKAWAY:
                ux, uy = u[b, k, 0], u[b, k, 1]
                un = math.sqrt(ux * ux + uy * uy)
                mx, my = ux / un, uy / un
                r = stick_limit / un
                e = dt * (-1.0 + r * (1.0 - mx * mx))
                f = dt * (-1.0 + r * (1.0 - my * my))
                h = -dt * r * mx * my
            # p' = p + dt/2 (v + v'):  dp'/dv = dt/2 (I + dv'/dv), dp'/du = dt/2 dv'/du
            half = 0.5 * dt
            grad_u[b, k, 0] = half * (e * lpx + h * lpy) + e * lvx + h * lvy
            grad_u[b, k, 1] = half * (h * lpx + f * lpy) + h * lvx + f * lvy
            nlvx = half * ((1.0 + a) * lpx + c * lpy) + a * lvx + c * lvy
            nlvy = half * (c * lpx + (1.0 + d) * lpy) + c * lvx + d * lvy
            lvx, lvy = nlvx, nlvy
        grad_p0[b, 0], grad_p0[b, 1] = lpx, lpy
        grad_v0[b, 0], grad_v0[b, 1] = lvx, lvy


def _f64(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().numpy(), dtype=np.float64)


def _friction(value: float | torch.Tensor, batch: int) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value.detach().cpu() if torch.is_tensor(value) else value, dtype=np.float64),
                          (batch,))
    return np.ascontiguousarray(arr)


class ContactChunk(torch.autograd.Function):
    """Relative motion over C samples under pan accelerations (differentiable in ``p0, v0, u_p``)."""

    @staticmethod
    def forward(ctx, p0, v0, u, mu, mu_dyn, dt):  # noqa: ANN001, ANN205
        b, c, _ = u.shape
        mu_np, mud_np = _friction(mu, b), _friction(mu_dyn, b)
        p_out, v_out = np.empty((b, c, 2)), np.empty((b, c, 2))
        jac, branch = np.empty((b, c, 2, 2)), np.empty((b, c), dtype=np.int8)
        v0_np, u_np = _f64(v0), _f64(u)
        _forward_kernel(_f64(p0), v0_np, u_np, mu_np, mud_np, float(dt), GRAVITY, p_out, v_out, jac, branch)
        ctx.save_for_backward(p0, v0, u)
        ctx.saved_numpy = (v0_np, u_np, v_out, branch, mu_np, mud_np, float(dt))
        as_t = {"dtype": u.dtype, "device": u.device}
        jac_t, branch_t = torch.as_tensor(jac, **as_t), torch.as_tensor(branch, device=u.device)
        ctx.mark_non_differentiable(jac_t, branch_t)
        return torch.as_tensor(p_out, **as_t), torch.as_tensor(v_out, **as_t), jac_t, branch_t

    @staticmethod
    def backward(ctx, grad_p, grad_v, _grad_jac, _grad_branch):  # noqa: ANN001, ANN205
        p0, v0, u = ctx.saved_tensors
        v0_np, u_np, v_out, branch, mu_np, mud_np, dt = ctx.saved_numpy
        b, c, _ = u.shape
        zeros = np.zeros((b, c, 2))
        gp = zeros if grad_p is None else _f64(grad_p)
        gv = zeros if grad_v is None else _f64(grad_v)
        grad_u, grad_p0, grad_v0 = np.empty((b, c, 2)), np.empty((b, 2)), np.empty((b, 2))
        _backward_kernel(v0_np, u_np, v_out, branch, mu_np, mud_np, dt, GRAVITY, gp, gv, grad_u, grad_p0, grad_v0)
        as_t = {"dtype": u.dtype, "device": u.device}
        return (torch.as_tensor(grad_p0, **as_t), torch.as_tensor(grad_v0, **as_t),
                torch.as_tensor(grad_u, **as_t), None, None, None)


# --- the same contact model in batched torch (any device) -----------------------------------------

BACKENDS = ("numba", "torch", "torch_autograd")
"""``numba``: the CPU kernel above; ``torch``: batched torch with the hand-derived backward
(:class:`TorchContactChunk`); ``torch_autograd``: the same torch forward, differentiated by autograd
(slower; kept to cross-check the hand derivation)."""


CPU_BACKEND = "numba"
"""What ``backend=None`` means for CPU tensors (numba: many times faster there, see
``benchmarks/results_sliding_physics.md``); set it to ``"torch"`` to run the torch path on the CPU
everywhere (a benchmark, a check)."""

DEVICE_BACKEND = "torch"
"""What ``backend=None`` means for tensors on any other device (a GPU). ``"numba"`` works there too:
the kernel runs on the CPU with a copy each way per chunk, which may beat the launch-bound torch
loop on a GPU (see the results file)."""


def resolve_backend(backend: str | None, device: torch.device) -> str:
    """The backend to use for tensors on ``device``: ``backend`` itself, or for ``None``
    :data:`CPU_BACKEND` on the CPU and :data:`DEVICE_BACKEND` anywhere else.

    While tracing (``torch.onnx.export`` of the dynamics) any backend runs as ``"torch_autograd"``: the
    numba kernel is opaque to the tracer (its result would be baked in as a constant), and the
    ``autograd.Function`` of ``"torch"`` does not export; the forward arithmetic is the same in all three.
    """
    if backend is None:
        backend = CPU_BACKEND if device.type == "cpu" else DEVICE_BACKEND
    if backend not in BACKENDS:
        raise ValueError(f"unknown contact backend {backend!r}; choose from {BACKENDS}")
    return "torch_autograd" if torch.jit.is_tracing() else backend


def _friction_t(value: float | torch.Tensor, batch: int, device: torch.device) -> torch.Tensor:
    """Friction as float64 ``(B, 1)`` on ``device`` (the cast the numba path makes, then broadcast)."""
    t = torch.as_tensor(value.detach() if torch.is_tensor(value) else value, dtype=torch.float64, device=device)
    return t.broadcast_to((batch,)).reshape(batch, 1)


def _sqrt(x: torch.Tensor) -> torch.Tensor:
    """``sqrt`` rounded to nearest, as the numba kernel's ``math.sqrt`` (IEEE 754) is. torch's float64
    ``sqrt`` on the CPU is not (torch 2.13: about 1 % of results 1 ulp off; of speeds within a few ulps
    of the one-step stop, about 1 in 2000 would then stop or slide unlike the kernel), so there the
    value comes from NumPy (the gradient still from torch); CUDA's ``sqrt`` is IEEE round-to-nearest."""
    if x.device.type != "cpu" or torch.jit.is_tracing():  # traced: ONNX Sqrt is IEEE round-to-nearest too
        return x.sqrt()
    exact = torch.from_numpy(np.sqrt(x.detach().numpy()))
    if not (x.requires_grad and torch.is_grad_enabled()):
        return exact
    s = x.sqrt()
    return s + (exact - s.detach())  # exact - s is 0 or ±1 ulp: the sum is exact


SAFE_SPEED = 5e-324
"""What the traced graph divides ``v`` by for an object at rest (the smallest float64): a finite direction (0)
there, and the speed itself wherever it moves, since ``|v| > 0`` is at least ``√5e-324`` ≈ 1.5e-162."""


def _speed(v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Whether the object moves (``|v| > 0``, as the kernel decides it) and a divisor for ``v / |v|`` that is
    ``|v|`` wherever it moves — rounded as the kernel's ``math.sqrt(vx * vx + vy * vy)`` — and finite with a
    finite gradient at rest; both ``(..., 1)`` from ``v`` ``(..., 2)``.

    Eager: the product, sum and :func:`_sqrt` of the square, with 1 under the root at rest (so autograd
    meets no ``√0``). Traced (the exported dynamics graph, forward only): one ``ReduceL2`` node, which
    onnxruntime computes as exactly that root for two components, raised to :data:`SAFE_SPEED` at rest — the
    graph runs this once per sample, and there each node costs about as much as its arithmetic."""
    if torch.jit.is_tracing():
        speed = torch.linalg.vector_norm(v, dim=-1, keepdim=True)
        return speed > 0.0, torch.maximum(speed, torch.full((), SAFE_SPEED, dtype=v.dtype, device=v.device))
    sq = (v * v).sum(-1, keepdim=True)
    moving = sq > 0.0
    return moving, _sqrt(torch.where(moving, sq, 1.0))


def _breakaway_t(u: torch.Tensor, stick_limit: torch.Tensor, dt: float) -> tuple[torch.Tensor, ...]:
    """For every sample at once (it depends on ``u_p`` alone): whether a sticking object would break
    away ``(B, C, 1)``, the velocity it would then take ``(B, C, 2)`` (0 where it would not), and the
    breakaway Jacobian entries ``jxx, jxy, jyy`` ``(B, C)`` — the kernel's arithmetic, in its order."""
    limit = stick_limit.unsqueeze(1)  # (B, 1, 1)
    sq = (u * u).sum(-1, keepdim=True)
    pushed = sq > 0.0  # |u| > 0
    un = _sqrt(torch.where(pushed, sq, 1.0))  # a finite gradient at |u| = 0 too
    can = pushed & (un >= limit)
    safe = torch.where(can, un, 1.0)  # no 0/0, and a finite gradient, where it cannot
    m = u / safe
    vel = torch.where(can, dt * (-u + limit * m), 0.0)
    with torch.no_grad():
        f = (limit / safe).squeeze(-1)
        mx, my = m[..., 0].detach(), m[..., 1].detach()
        jac = (-1.0 + f * (1.0 - mx * mx), -f * mx * my, -1.0 + f * (1.0 - my * my))
    return (can, vel, *jac)


def contact_sample(
    v: torch.Tensor, neg_u: torch.Tensor, brk: torch.Tensor, decel: torch.Tensor, dt: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One sample of the contact loop, the only part that is sequential: from the relative velocity ``v``
    ``(..., 2)`` [m/s] under ``−u_p`` ``(..., 2)`` [m/s²], with ``brk`` ``(..., 2)`` the velocity a sticking object
    breaks away to (0 where it would not; :func:`_breakaway_t`) and ``decel = μ' g`` ``(..., 1)`` [m/s²]. Returns
    the next velocity ``(..., 2)``, whether the object moved ``(..., 1)`` bool and ``(w · v)`` ``(..., 1)`` (≤ 0:
    sliding friction would have reversed the motion, so it stopped). Shape-agnostic, so the same function is the
    eager loop's step and, traced on its own, the body of the exported graph's ``Scan``."""
    moving, speed = _speed(v)
    w = v + dt * (neg_u - decel * (v / speed))
    turn = (w * v).sum(-1, keepdim=True)  # ≤ 0: friction would reverse the motion, so it stops
    # w · [turn > 0] is w or 0 (a multiply costs a traced graph less than a second where); w is finite
    # wherever it moves (the safe divisor), for finite inputs, and a NaN stays NaN as in the kernel
    return torch.where(moving, w * (turn > 0.0), brk), moving, turn


def contact_loop(
    v0: torch.Tensor, neg_u: torch.Tensor, breaks: torch.Tensor, slide_decel: torch.Tensor, dt: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`contact_sample` over the C samples, one after another: ``v0`` ``(B, 2)``, ``neg_u`` and ``breaks``
    ``(B, C, 2)``, ``slide_decel`` ``(B, 1)`` → velocities ``(B, C, 2)``, moving ``(B, C, 1)`` and ``w · v``
    ``(B, C, 1)``."""
    c = neg_u.shape[1]
    # per sample (B, 1, 2) slices: split and cat, no squeeze or stack per sample (on a GPU each op is a launch)
    neg_us, brks, decel = neg_u.split(1, 1), breaks.split(1, 1), slide_decel.unsqueeze(1)
    v, vs, movings, turns = v0.unsqueeze(1), [], [], []
    for k in range(c):
        v, moving, turn = contact_sample(v, neg_us[k], brks[k], decel, dt)
        vs.append(v)
        movings.append(moving)
        turns.append(turn)
    return torch.cat(vs, 1), torch.cat(movings, 1), torch.cat(turns, 1)


CONTACT_LOOP_OP = "ContactLoop"
CONTACT_LOOP_DOMAIN = "seqmotion"
"""The node :class:`ContactLoop` traces into: a placeholder in domain ``seqmotion`` that the ONNX export replaces
by a ``Scan`` over :func:`contact_sample` traced on its own (:mod:`seqmotion.deploy.scan`)."""


class ContactLoop(torch.autograd.Function):
    """:func:`contact_loop` as a single node of a traced graph (forward only; used only while tracing). Unrolled,
    the loop is ~15 nodes per sample (1,500 for a chunk of 100); the export turns this node into one ``Scan`` whose
    body is the traced :func:`contact_sample`, the same ops, so the graph computes what the loop does, bit for bit.

    Its ``loop_*`` attributes tell the export so (:class:`seqmotion.deploy.scan.TracedLoop`): the placeholder's
    inputs are the relative velocity ``v0`` ``(B, 2)`` [m/s] carried from sample to sample, ``−u_p`` and the
    breakaway velocities ``(B, C, 2)`` read a sample at a time, and ``μ' g`` ``(B, 1)`` [m/s²] read whole; its
    attribute ``dt`` [s]; its outputs the velocities, moving flags and ``w · v`` of every sample.
    """

    loop_op, loop_domain, loop_name = CONTACT_LOOP_OP, CONTACT_LOOP_DOMAIN, "contact"
    loop_state = ("v", 2)
    loop_scanned = (("neg_u", 2), ("brk", 2))
    loop_constants = (("decel", 1),)
    loop_outputs = ("v_next", "moving", "turn")
    loop_attributes = ("dt",)
    loop_sample = staticmethod(contact_sample)

    @staticmethod
    def forward(ctx, v0, neg_u, breaks, slide_decel, dt):  # noqa: ANN001, ANN205
        return contact_loop(v0, neg_u, breaks, slide_decel, dt)

    @staticmethod
    def symbolic(g, v0, neg_u, breaks, slide_decel, dt):  # noqa: ANN001, ANN205
        v, moving, turn = g.op(f"{CONTACT_LOOP_DOMAIN}::{CONTACT_LOOP_OP}", v0, neg_u, breaks, slide_decel,
                               dt_t=torch.tensor(float(dt), dtype=torch.float64), outputs=3)  # dt_f would be float32
        # the exporter cannot infer a custom node's outputs: velocities like -u_p, the flags one wide
        kind = neg_u.type()
        sizes = kind.varyingSizes() or [None, None, None]
        v.setType(kind)
        moving.setType(kind.with_sizes([*sizes[:-1], 1]).with_dtype(torch.bool))
        turn.setType(kind.with_sizes([*sizes[:-1], 1]))
        return v, moving, turn


def _torch_forward(
    p0: torch.Tensor, v0: torch.Tensor, u: torch.Tensor, stick_limit: torch.Tensor, slide_decel: torch.Tensor,
    dt: float,
) -> tuple[torch.Tensor, ...]:
    """The numba forward kernel in torch, over the batch a sample at a time (float64 ``(B, 2)``,
    ``(B, 2)``, ``(B, C, 2)``, ``(B, 1)``, ``(B, 1)``). Every op is differentiable and finite (safe
    norms), so autograd may run through it; the branch choices match the kernel's bit for bit.

    Returns ``(p (B, C, 2), v (B, C, 2), jac (B, C, 2, 2), branch (B, C) int8)``."""
    b, c, _ = u.shape
    can, break_vel, jxx, jxy, jyy = _breakaway_t(u, stick_limit, dt)
    loop = ContactLoop.apply if torch.jit.is_tracing() else contact_loop
    v_out, moving_all, turn_all = loop(v0, -u, break_vel, slide_decel, dt)
    v_prev = torch.cat([v0.unsqueeze(1), v_out[:, :-1]], 1)
    step = (0.5 * dt) * (v_prev + v_out)
    p_out = torch.cumsum(torch.cat([p0.unsqueeze(1), step], 1), 1)[:, 1:]  # p' = p + dt (v + v') / 2
    with torch.no_grad():
        moving, can = moving_all[..., 0], can[..., 0]
        reverse = turn_all[..., 0] <= 0.0  # as the kernel decides it (a NaN slides)
        slide, breakaway = moving & ~reverse, ~moving & can
        code = torch.full((b, c), STICK, dtype=torch.int8, device=u.device)  # masked_fill: no host sync
        code = code.masked_fill(slide, SLIDE).masked_fill(moving & reverse, STOP).masked_fill(breakaway, BREAKAWAY)
        zero = torch.zeros_like(jxx)
        sgn = torch.where(slide, -1.0, zero)
        jac = torch.stack([
            torch.where(breakaway, jxx, sgn), torch.where(breakaway, jxy, zero),
            torch.where(breakaway, jxy, zero), torch.where(breakaway, jyy, sgn),
        ], -1).view(b, c, 2, 2)
    return p_out, v_out, jac, code


def _torch_backward(
    v_prev: torch.Tensor, jac: torch.Tensor, branch: torch.Tensor, slide_decel: torch.Tensor, dt: float,
    grad_p: torch.Tensor, grad_v: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The numba backward kernel's derivation in torch: the local Jacobians of every sample at once
    (``dv'/du_p = dt J``; ``dv'/dv = (1 − s) I + s n nᵀ``, ``s = dt μ' g / |v|``, while sliding, else 0),
    the position adjoint as a reverse cumulative sum (``dp'/dp = I``), and the velocity adjoint a
    2 × 2 product per sample, back to front. Returns ``(grad_p0, grad_v0, grad_u)``."""
    b, c, _ = v_prev.shape
    half = 0.5 * dt
    slide = (branch == SLIDE).unsqueeze(-1)
    speed = _sqrt(torch.where(slide, (v_prev * v_prev).sum(-1, keepdim=True), 1.0))
    n = v_prev / speed
    s = dt * slide_decel.unsqueeze(1) / speed  # (B, C, 1)
    nx, ny, s = n[..., 0], n[..., 1], s[..., 0]
    cross = s * nx * ny
    dvdv = torch.stack([1.0 - s * (1.0 - nx * nx), cross, cross, 1.0 - s * (1.0 - ny * ny)], -1)
    dvdv = torch.where(slide, dvdv, 0.0).view(b, c, 2, 2)
    lp = grad_p.flip(1).cumsum(1).flip(1)  # adjoint of p after sample k
    half_lp = (half * lp).unsqueeze(-1)  # (B, C, 2, 1)
    shifted = (half_lp + grad_v.unsqueeze(-1)).unbind(1)
    mats, half_lps = dvdv.unbind(1), half_lp.unbind(1)
    lv = torch.zeros_like(half_lps[0])
    qs = [lv] * c
    for k in range(c - 1, -1, -1):
        q = shifted[k] + lv  # dt/2 λ_p + λ_v after sample k
        qs[k] = q
        lv = torch.baddbmm(half_lps[k], mats[k], q)  # λ_v before it: dt/2 λ_p + (dv'/dv)ᵀ q
    grad_u = ((dt * jac) @ torch.stack(qs, 1)).squeeze(-1)
    return lp[:, 0], lv.squeeze(-1), grad_u


class TorchContactChunk(torch.autograd.Function):
    """:class:`ContactChunk` in torch on the inputs' device: same forward, same hand-derived backward."""

    @staticmethod
    def forward(ctx, p0, v0, u, mu, mu_dyn, dt):  # noqa: ANN001, ANN205
        b = u.shape[0]
        f64 = torch.float64
        slide_decel = _friction_t(mu_dyn, b, u.device) * GRAVITY
        stick_limit = _friction_t(mu, b, u.device) * GRAVITY
        v0_64 = v0.detach().to(f64)
        p, v, jac, branch = _torch_forward(p0.detach().to(f64), v0_64, u.detach().to(f64), stick_limit,
                                           slide_decel, float(dt))
        ctx.save_for_backward(torch.cat([v0_64.unsqueeze(1), v[:, :-1]], 1), jac, branch, slide_decel)
        ctx.dt, ctx.dtypes = float(dt), (p0.dtype, v0.dtype, u.dtype)
        jac_out = jac.to(u.dtype)
        ctx.mark_non_differentiable(jac_out, branch)
        return p.to(u.dtype), v.to(u.dtype), jac_out, branch

    @staticmethod
    def backward(ctx, grad_p, grad_v, _grad_jac, _grad_branch):  # noqa: ANN001, ANN205
        v_prev, jac, branch, slide_decel = ctx.saved_tensors
        zeros = torch.zeros_like(v_prev)
        gp = zeros if grad_p is None else grad_p.to(torch.float64)
        gv = zeros if grad_v is None else grad_v.to(torch.float64)
        grad_p0, grad_v0, grad_u = _torch_backward(v_prev, jac, branch, slide_decel, ctx.dt, gp, gv)
        dp, dv, du = ctx.dtypes
        return grad_p0.to(dp), grad_v0.to(dv), grad_u.to(du), None, None, None


def _torch_autograd_chunk(p0, v0, u, mu, mu_dyn, dt):  # noqa: ANN001, ANN202
    """:func:`_torch_forward` differentiated by autograd (friction treated as constant, like the others)."""
    b, f64 = u.shape[0], torch.float64
    slide_decel = _friction_t(mu_dyn, b, u.device) * GRAVITY
    stick_limit = _friction_t(mu, b, u.device) * GRAVITY
    p, v, jac, branch = _torch_forward(p0.to(f64), v0.to(f64), u.to(f64), stick_limit, slide_decel, float(dt))
    return p.to(u.dtype), v.to(u.dtype), jac.to(u.dtype), branch


def contact_chunk(
    rel_state: torch.Tensor, pan_accel: torch.Tensor, mu: float | torch.Tensor = MU,
    mu_dyn: float | torch.Tensor = MU_DYN, dt: float = DT, backend: str | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Advance the object's relative state through C pan accelerations.

    Args:
        rel_state: ``(B, 4)`` relative state before the chunk.
        pan_accel: ``(B, C, 2)`` pan accelerations ``u_p``.
        mu, mu_dyn: friction coefficients, scalars or ``(B,)`` per trajectory.
        backend: ``"numba"``, ``"torch"`` or ``"torch_autograd"`` (:data:`BACKENDS`); ``None``: numba for
            CPU tensors, torch on any other device (:func:`resolve_backend`). Results are on
            ``pan_accel``'s device either way.

    Returns:
        ``(rel_states (B, C, 4), jacobian (B, C, 2, 2) = ∂u_d/∂u_p, branch (B, C) int8)``.
    """
    backend = resolve_backend(backend, pan_accel.device)
    chunk = {"numba": ContactChunk.apply, "torch": TorchContactChunk.apply, "torch_autograd": _torch_autograd_chunk}
    p, v, jac, branch = chunk[backend](rel_state[:, :2], rel_state[:, 2:], pan_accel, mu, mu_dyn, dt)
    return torch.cat([p, v], dim=-1), jac, branch


def rollout(
    pan_accel: object, mu: float | np.ndarray = MU, mu_dyn: float | np.ndarray = MU_DYN, dt: float = DT,
    backend: str | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Roll pan accelerations out through the contact model (SPEC §7).

    Args:
        pan_accel: ``(K-1, 2)`` or ``(B, K-1, 2)`` pan accelerations [m/s²].
        mu, mu_dyn: static and dynamic friction coefficients (``0 ≤ μ' ≤ μ``), scalars or one
            per trajectory ``(B,)``.
        backend: the contact model's (:func:`contact_chunk`; default numba, the CPU's fastest).

    Returns:
        ``(pan_states, rel_states)``, each ``(K, 4)`` (or batched), starting at rest at 0:
        the pan ``[x, y, vx, vy]`` and the object relative to it.
    """
    mu_arr = check_finite_array("friction mu", mu, minimum=0.0, strict_minimum=True)
    mud_arr = check_finite_array("friction mu_dyn", mu_dyn, minimum=0.0)
    if np.any(mud_arr > mu_arr):
        raise ValueError(f"friction must satisfy mu > 0 and 0 <= mu_dyn <= mu, got mu={mu}, mu_dyn={mu_dyn}")
    check_number("dt", dt, minimum=0.0, strict_minimum=True)
    accel, single = as_trajectories(pan_accel, ACCEL_DIM, "pan_accel", min_length=1)
    u = torch.from_numpy(accel)
    zero = torch.zeros(u.shape[0], STATE_DIM, dtype=torch.float64)
    pan = integrate(zero, u, dt)
    with torch.no_grad():
        rel, _, _ = contact_chunk(zero, u, torch.as_tensor(mu_arr), torch.as_tensor(mud_arr), dt, backend)
    rel = torch.cat([zero.unsqueeze(1), rel], dim=1)
    pan_np, rel_np = pan.numpy(), rel.numpy()
    return (pan_np[0], rel_np[0]) if single else (pan_np, rel_np)


def _first_rows(value: object, rows: int) -> object:
    """A per-trajectory setting ``(B,)`` for the first ``rows`` trajectories (scalars and None as they are)."""
    return value[:rows] if isinstance(value, torch.Tensor) and value.ndim > 0 else value


class SlidingDynamics:
    """Pan integrator + contact model as a decoder's :class:`~seqmotion.models.seq2seq.ChunkDynamics`.

    States are 8-D: ``[x_p (4), x_d (4)]``; the decoder reads them as they are. Outputs per
    chunk: ``states``, ``pos_cov`` (the object's relative-position covariance, for L),
    ``pan_pos_cov`` (the pan's, for L'), ``rel_accel`` (u_d) and ``branch`` (which case of
    eq. 3.9 each sample took).

    Args:
        mu, mu_dyn: friction, scalars or ``(B,)``.
        detach_contact: ``(B,)`` bool; where true, no gradient flows back through the
            contact model (the L' stages: the pan is supervised directly).
        backend: the contact model's (:func:`contact_chunk`): ``None`` follows the device of the
            states (numba on the CPU, torch elsewhere).

    Everything it makes lives on the device of the states and accelerations it is given (friction and
    ``detach_contact`` are moved there). Traced for export, the contact model's per-sample loop is one placeholder
    node, :class:`ContactLoop`, which the export makes a ``Scan`` (``traced_loops``: :mod:`seqmotion.deploy.scan`).
    """

    traced_loops = (ContactLoop,)
    """The loop placeholders :meth:`step` traces into."""

    def __init__(
        self, mu: float | torch.Tensor = MU, mu_dyn: float | torch.Tensor = MU_DYN, dt: float = DT,
        detach_contact: torch.Tensor | None = None, backend: str | None = None,
    ) -> None:
        if backend is not None:
            resolve_backend(backend, torch.device("cpu"))  # a bad name fails here, not mid-rollout
        self.mu, self.mu_dyn, self.dt, self.detach_contact = mu, mu_dyn, dt, detach_contact
        self.backend = backend

    @classmethod
    def at(cls, physics: SlidingPhysics, dt: float = DT) -> SlidingDynamics:
        """The dynamics at the (checked) friction ``physics``."""
        return cls(physics.mu, physics.mu_dyn, dt)

    def per_trajectory(
        self, mu: torch.Tensor, mu_dyn: torch.Tensor, detach_contact: torch.Tensor | None = None
    ) -> SlidingDynamics:
        """The same dynamics with one friction per trajectory (``(B,)`` each; training's randomised friction)."""
        return SlidingDynamics(mu, mu_dyn, self.dt, detach_contact, self.backend)

    def start(self, x0: torch.Tensor) -> tuple:
        b = x0.shape[0]
        zeros = CovarianceCarry.zeros(b, 2, x0.dtype, x0.device)
        return x0[:, :4], x0[:, 4:], zeros, zeros

    def step(self, carry: tuple, mean: torch.Tensor, cov: torch.Tensor | None) -> tuple[tuple, dict]:
        pan, rel, cov_pan, cov_rel = carry
        pan_states = integrate(pan, mean, self.dt)[:, 1:]
        rows = mean.shape[0]  # a narrowed batch: the per-trajectory settings of its first rows
        detach = _first_rows(self.detach_contact, rows)
        if detach is not None:
            detach = detach.to(mean.device)
        physics = (_first_rows(self.mu, rows), _first_rows(self.mu_dyn, rows), self.dt, self.backend)
        if detach is not None and bool(detach.all()):  # nothing to backpropagate: build no graph
            with torch.no_grad():
                rel_states, jac, branch = contact_chunk(rel, mean, *physics)
        else:
            rel_states, jac, branch = contact_chunk(rel, mean, *physics)
            if detach is not None:
                rel_states = torch.where(detach.view(-1, 1, 1), rel_states.detach(), rel_states)
        out = {
            "states": torch.cat([pan_states, rel_states], dim=-1),
            "rel_accel": (torch.diff(rel_states[..., 2:], dim=1, prepend=rel[:, None, 2:]) / self.dt).detach(),
            "branch": branch,
        }
        if cov is not None:
            out["pan_pos_cov"], cov_pan = propagate_covariance(cov_pan, cov, self.dt)
            rel_cov = jac @ cov @ jac.transpose(-1, -2)
            out["pos_cov"], cov_rel = propagate_covariance(cov_rel, rel_cov, self.dt)
        return (pan_states[:, -1], rel_states[:, -1], cov_pan, cov_rel), out

    def decoder_input(self, states: torch.Tensor) -> torch.Tensor:
        return states

    def narrow(self, carry: tuple, rows: int) -> tuple:
        """The carry of the first ``rows`` trajectories (the rollout stops those that have ended)."""
        pan, rel, cov_pan, cov_rel = carry
        return pan[:rows], rel[:rows], cov_pan.narrow(rows), cov_rel.narrow(rows)

    def restart(self, carry: tuple, state: torch.Tensor, mask: torch.Tensor) -> tuple:
        pan, rel, cov_pan, cov_rel = carry
        m = mask.view(-1, 1)
        return (torch.where(m, state[:, :4], pan), torch.where(m, state[:, 4:], rel),
                cov_pan.reset_where(mask), cov_rel.reset_where(mask))
