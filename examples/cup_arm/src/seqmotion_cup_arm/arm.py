"""Physics of a planar two-link arm carrying an open cup: kinematics, the manipulator equation, the spill angle.

**The arm.** Two uniform links in a vertical plane (gravity −y): the shoulder angle ``q1`` is link 1's
angle from the horizontal, the elbow angle ``q2`` link 2's angle from link 1 (so link 2 points at
``q1 + q2``). Link 1 is 0.30 m long and weighs 1.0 kg, link 2 0.25 m and 0.6 kg (uniform rods:
inertia ``m l² / 12`` about their middle). The cup and its liquid are a point mass, ``payload_mass``,
at the tip of link 2. Joint torques ``τ`` [N·m] drive the joints through the manipulator equation::

    M(q) q̈ + C(q, q̇) q̇ + g(q) + b q̇ = τ

with ``b`` the joints' viscous damping (``joint_damping``). ``M`` is 2 × 2, symmetric positive definite;
it is inverted in closed form (no solver: the step traces to an ONNX graph).

**Time.** Semi-implicit Euler at ``dt`` = 1 ms: ``q̇[k+1] = q̇[k] + dt q̈[k]``, ``q[k+1] = q[k] + dt q̇[k+1]``,
with ``q̈[k]`` from the state ``k``. Its energy error stays bounded (a symplectic step): an undamped arm
left to fall swings for ever instead of gaining or losing energy. A state's accelerations are therefore
exactly ``(q̇[k+1] − q̇[k]) / dt``: :func:`spill_violation` reads them from consecutive states, so it
needs no physics parameters.

**The cup.** Its axis (pointing out of its opening) is fixed to link 2, perpendicular to it: the cup is
upright when ``q1 + q2 = 0`` (link 2 horizontal). The liquid feels the specific force ``f = a_cup − g``
(what an accelerometer on the cup reads: ``(0, 9.81)`` m/s² at rest); it stays in while the angle
between ``f`` and the cup's axis stays under a limit (a half-full cup of this shape spills near 20°).

**Covariances.** For the decoder's likelihood loss the torques' covariance ``Σ_τ`` is propagated through
the step linearised with ``M(q)`` known per sample: ``Σ_q̈ = M⁻¹ Σ_τ M⁻ᵀ``, then the semi-implicit
integration (:func:`propagate_covariance`). The state's feedback through gravity and Coriolis terms
(``∂q̈/∂q``, ``∂q̈/∂q̇``) is left out: the covariance is the open-loop spread of the joint angles
that the torque noise alone makes, which is what the likelihood scores a sketch against.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import torch

from seqmotion.errors import check_number
from seqmotion.physics.integrator import DT, CovarianceCarry
from seqmotion.physics.parameters import Physics

GRAVITY = 9.81  # [m/s²]
LINK_LENGTHS = (0.30, 0.25)  # [m]
LINK_MASSES = (1.0, 0.6)  # [kg]
HOME = (0.6, -0.6)
"""The home pose ``(q1, q2)`` [rad]: link 1 raised 34°, link 2 horizontal, the cup upright."""
STOP_ACCEL = (5.0, 5.0)
"""The hardest the online generator's end-of-motion stop decelerates each joint [rad/s²]: within what the
model's torque scale (2 and 1 N·m about the hold torque) gives at :data:`HOME` (about 9 and 32 rad/s²),
and gentle on the cup: 5 rad/s² at the arm's full 0.55 m reach is 2.75 m/s², a 16° lean of the specific
force, under the default 20° spill limit (the stop slows further where the constraint asks)."""
Number = float | torch.Tensor


@dataclasses.dataclass(frozen=True)
class CupArmPhysics(Physics):
    """What the arm carries and how its joints drag.

    Attributes:
        payload_mass: the cup and liquid at the tip of link 2 [kg] (0 to 20).
        joint_damping: viscous friction ``b`` at both joints [N·m·s/rad] (0 to 100).
    """

    payload_mass: float = 0.3
    joint_damping: float = 0.02

    def __post_init__(self) -> None:
        check_number("payload_mass", self.payload_mass, minimum=0.0, maximum=20.0)
        check_number("joint_damping", self.joint_damping, minimum=0.0, maximum=100.0)


def _inertias(payload_mass: Number) -> tuple[Number, Number, Number, Number]:
    """``(j1, j2, s2, w1)``: link 1's inertia about the shoulder with link 2 and the payload at the elbow
    [kg·m²], link 2's with the payload about the elbow [kg·m²], link 2's first moment about the elbow
    [kg·m] and the first moment of everything along link 1 about the shoulder [kg·m]."""
    (l1, l2), (m1, m2) = LINK_LENGTHS, LINK_MASSES
    carried = m2 + payload_mass
    s2 = m2 * l2 / 2 + payload_mass * l2
    j2 = m2 * l2**2 / 3 + payload_mass * l2**2
    return m1 * l1**2 / 3 + carried * l1**2, j2, s2, m1 * l1 / 2 + carried * l1


def mass_matrix(q: torch.Tensor, payload_mass: Number) -> torch.Tensor:
    """``M(q)`` ``(..., 2, 2)`` [kg·m²] for joint angles ``q`` ``(..., 2)`` [rad]."""
    j1, j2, s2, _ = _inertias(payload_mass)
    c = LINK_LENGTHS[0] * s2 * torch.cos(q[..., 1])
    m11, m12, m22 = j1 + j2 + 2 * c, j2 + c, j2 + torch.zeros_like(c)
    return torch.stack([torch.stack([m11, m12], -1), torch.stack([m12, m22], -1)], -2)


def bias_torques(q: torch.Tensor, dq: torch.Tensor, physics: CupArmPhysics) -> torch.Tensor:
    """``C(q, q̇) q̇ + g(q) + b q̇`` ``(..., 2)`` [N·m]: what the torques must overcome before accelerating."""
    _, _, s2, w1 = _inertias(physics.payload_mass)
    h = LINK_LENGTHS[0] * s2 * torch.sin(q[..., 1])
    tip = GRAVITY * s2 * torch.cos(q[..., 0] + q[..., 1])
    dq1, dq2, b = dq[..., 0], dq[..., 1], physics.joint_damping
    return torch.stack([-h * dq2 * (2 * dq1 + dq2) + GRAVITY * w1 * torch.cos(q[..., 0]) + tip + b * dq1,
                        h * dq1 * dq1 + tip + b * dq2], -1)


def inverse_dynamics(q: torch.Tensor, dq: torch.Tensor, ddq: torch.Tensor, physics: CupArmPhysics) -> torch.Tensor:
    """The torques ``τ = M q̈ + C q̇ + g + b q̇`` ``(..., 2)`` [N·m] that give accelerations ``q̈`` at ``(q, q̇)``
    (a computed-torque controller's feed-forward; ``τ = g(q)`` holds the arm still)."""
    accel = (mass_matrix(q, physics.payload_mass) @ ddq.unsqueeze(-1))[..., 0]
    return accel + bias_torques(q, dq, physics)


def energy(q: torch.Tensor, dq: torch.Tensor, payload_mass: Number) -> torch.Tensor:
    """Kinetic plus potential energy ``½ q̇ᵀ M q̇ + V(q)`` ``(...)`` [J] (V = 0 with both links horizontal)."""
    _, _, s2, w1 = _inertias(payload_mass)
    kinetic = 0.5 * (dq.unsqueeze(-2) @ mass_matrix(q, payload_mass) @ dq.unsqueeze(-1))[..., 0, 0]
    return kinetic + GRAVITY * (w1 * torch.sin(q[..., 0]) + s2 * torch.sin(q[..., 0] + q[..., 1]))


def cup_position(q: torch.Tensor) -> torch.Tensor:
    """The cup's position ``(..., 2)`` [m] from the shoulder, for ``q`` ``(..., 2)``."""
    (l1, l2), phi = LINK_LENGTHS, q[..., 0] + q[..., 1]
    return torch.stack([l1 * torch.cos(q[..., 0]) + l2 * torch.cos(phi),
                        l1 * torch.sin(q[..., 0]) + l2 * torch.sin(phi)], -1)


def cup_tilt(q: torch.Tensor, dq: torch.Tensor, ddq: torch.Tensor) -> torch.Tensor:
    """The signed angle ``(...)`` [rad] from the cup's axis to the specific force ``a_cup − g`` it feels.

    ``a_cup = J(q) q̈ + J̇(q, q̇) q̇`` from the arm's kinematics; the axis is ``(−sin φ, cos φ)``, φ = q1 + q2.
    """
    (l1, l2), q1, phi = LINK_LENGTHS, q[..., 0], q[..., 0] + q[..., 1]
    w1, wphi, a1, aphi = dq[..., 0], dq[..., 0] + dq[..., 1], ddq[..., 0], ddq[..., 0] + ddq[..., 1]
    ax = -l1 * (torch.sin(q1) * a1 + torch.cos(q1) * w1**2) - l2 * (torch.sin(phi) * aphi + torch.cos(phi) * wphi**2)
    ay = l1 * (torch.cos(q1) * a1 - torch.sin(q1) * w1**2) + l2 * (torch.cos(phi) * aphi - torch.sin(phi) * wphi**2)
    fy = ay + GRAVITY
    ux, uy = -torch.sin(phi), torch.cos(phi)
    return torch.atan2(ux * fy - uy * ax, ux * ax + uy * fy)


def spill_violation(states: torch.Tensor, limit: float, dt: float = DT) -> torch.Tensor:
    """``max(0, |tilt| − limit)`` ``(B, K-1)`` [rad] per transition of states ``(B, K, 4)`` (``[q, q̇]``), with
    ``q̈[k] = (q̇[k+1] − q̇[k]) / dt`` (exact for this module's integrator)."""
    ddq = (states[:, 1:, 2:] - states[:, :-1, 2:]) / dt
    return torch.relu(cup_tilt(states[:, :-1, :2], states[:, :-1, 2:], ddq).abs() - limit)


@lru_cache(maxsize=32)
def _weights(steps: int, dt: float, dtype: torch.dtype, device: str) -> torch.Tensor:
    """``(steps + 2, steps)``: rows n−1 = ``dt⁴ (n − j)²`` for j < n (how input j's variance reaches the angle
    at n), then ``dt² · 1`` and ``dt³ (steps − j)`` (how it reaches the velocity and the angle–velocity
    covariance at the last step)."""
    with torch.inference_mode(False):  # cached: usable by autograd even if first made in inference mode
        n = torch.arange(1, steps + 1, dtype=torch.float64).unsqueeze(1)
        j = torch.arange(steps, dtype=torch.float64).unsqueeze(0)
        pos = dt**4 * torch.where(j < n, (n - j) ** 2, torch.zeros(()))
        extra = torch.stack([dt**2 * torch.ones(steps, dtype=torch.float64), dt**3 * (steps - j[0])])
        return torch.cat([pos, extra]).to(dtype=dtype, device=device)


def propagate_covariance(carry: CovarianceCarry, accel_cov: torch.Tensor, dt: float = DT,
                         cache: bool = True) -> tuple[torch.Tensor, CovarianceCarry]:
    """The semi-implicit Euler step's covariances over n = 1..C steps driven by independent joint accelerations
    of covariance ``accel_cov`` ``(B, C, 2, 2)`` [rad²/s⁴] from ``carry`` (angle, cross and velocity blocks).

    ``q[n] = q0 + n dt q̇0 + dt² Σ_{j<n} (n − j) q̈[j]``, so ``P[n] = P0 + n dt (X0 + X0ᵀ) + (n dt)² V0 +
    dt⁴ Σ_{j<n} (n − j)² S[j]``. Returns the angles' covariance ``(B, C, 2, 2)`` and the carry at step C.
    ``cache=False`` for a whole motion's C (its ``(C + 2) × C`` weights are not worth keeping).
    """
    b, c = accel_cov.shape[:2]
    w = (_weights if cache else _weights.__wrapped__)(c, dt, accel_cov.dtype, str(accel_cov.device))
    driven = (w @ accel_cov.reshape(b, c, 4)).view(b, c + 2, 2, 2)
    t = dt * torch.arange(1, c + 1, dtype=accel_cov.dtype, device=accel_cov.device).view(1, c, 1, 1)
    cross = carry.cross + carry.cross.transpose(-1, -2)
    pos = carry.pos.unsqueeze(1) + t * cross.unsqueeze(1) + t**2 * carry.vel.unsqueeze(1) + driven[:, :c]
    new_cross = carry.cross + c * dt * carry.vel + driven[:, c + 1]
    return pos, CovarianceCarry(pos[:, -1], new_cross, carry.vel + driven[:, c])


def accel_covariance(q: torch.Tensor, tau_cov: torch.Tensor, payload_mass: Number) -> torch.Tensor:
    """``M⁻¹ Σ_τ M⁻ᵀ`` ``(..., 2, 2)`` for angles ``(..., 2)`` and torque covariances ``(..., 2, 2)`` (the 2 × 2
    inverse in closed form)."""
    m = mass_matrix(q, payload_mass).to(tau_cov.dtype)
    det = (m[..., 0, 0] * m[..., 1, 1] - m[..., 0, 1] ** 2)[..., None, None]
    adj = torch.stack([m[..., 1, 1], -m[..., 0, 1], -m[..., 1, 0], m[..., 0, 0]], -1).view(m.shape)
    inverse = adj / det
    return inverse @ tau_cov @ inverse.transpose(-1, -2)


class CupArmDynamics:
    """The arm as a decoder's ``ChunkDynamics``: torques in, states ``[q1, q2, q̇1, q̇2]`` out.

    The carry is ``(x, cov)``: the state ``(B, 4)`` at the chunk boundary and the joint angles'
    :class:`CovarianceCarry`. ``payload_mass`` and ``joint_damping`` are read at every step (an exported
    graph sets them from its ``physics`` input); floats or 0-d tensors. :meth:`outputs_for` (the torques for
    given joint accelerations) and ``stop_accel_limit`` let the online generator stop the arm through its
    torques.
    """

    stop_accel_limit = STOP_ACCEL
    """The stop's deceleration limit per joint [rad/s²] (:data:`STOP_ACCEL`)."""

    def __init__(self, payload_mass: Number = 0.3, joint_damping: Number = 0.02, dt: float = DT) -> None:
        self.payload_mass, self.joint_damping, self.dt = payload_mass, joint_damping, dt

    @classmethod
    def at(cls, physics: CupArmPhysics, dt: float = DT) -> CupArmDynamics:
        return cls(physics.payload_mass, physics.joint_damping, dt)

    def start(self, x0: torch.Tensor) -> tuple[torch.Tensor, CovarianceCarry]:
        return x0, CovarianceCarry.zeros(x0.shape[0], 2, x0.dtype, x0.device)

    def step(self, carry: tuple[torch.Tensor, CovarianceCarry], tau: torch.Tensor,
             cov: torch.Tensor | None) -> tuple[tuple[torch.Tensor, CovarianceCarry], dict[str, torch.Tensor]]:
        """Apply C torques ``(B, C, 2)`` [N·m] (with covariances ``(B, C, 2, 2)``, or None): the C states that
        follow, and with ``cov`` the angles' covariance ``pos_cov`` ``(B, C, 2, 2)`` [rad²]."""
        x, cov_carry = carry
        q1, q2, dq1, dq2 = x.unbind(-1)
        j1, j2, s2, w1 = _inertias(self.payload_mass)
        l1s2, g_w1, g_s2, b, dt = LINK_LENGTHS[0] * s2, GRAVITY * w1, GRAVITY * s2, self.joint_damping, self.dt
        j12, j1j2 = j1 + j2, j1 * j2
        rows: list[list[torch.Tensor]] = [[], [], [], []]
        for tau1, tau2 in zip(*(t.unbind(1) for t in tau.unbind(-1)), strict=True):
            # M = [[j1 + j2 + 2c, j2 + c], [j2 + c, j2]] with c = l1 s2 cos q2, so det M = j1 j2 − c²
            c, h = l1s2 * torch.cos(q2), l1s2 * torch.sin(q2)
            tip = g_s2 * torch.cos(q1 + q2)
            r1 = tau1 + h * dq2 * (2 * dq1 + dq2) - g_w1 * torch.cos(q1) - tip - b * dq1
            r2 = tau2 - h * dq1 * dq1 - tip - b * dq2
            m12, step = j2 + c, dt / (j1j2 - c * c)
            dq1, dq2 = dq1 + step * (j2 * r1 - m12 * r2), dq2 + step * ((j12 + 2 * c) * r2 - m12 * r1)
            q1, q2 = q1 + dt * dq1, q2 + dt * dq2
            for row, value in zip(rows, (q1, q2, dq1, dq2), strict=True):
                row.append(value)
        out = {"states": torch.stack([torch.stack(row, 1) for row in rows], -1)}
        if cov is not None:  # M at the state each torque acts from: the chunk's start, then its first C−1 states
            before = torch.cat([x[:, None, :2], out["states"][:, :-1, :2]], 1)
            out["pos_cov"], cov_carry = propagate_covariance(
                cov_carry, accel_covariance(before, cov, self.payload_mass), self.dt)
        return (out["states"][:, -1], cov_carry), out

    def outputs_for(self, x: torch.Tensor, ddq: torch.Tensor) -> torch.Tensor:
        """The torques ``(B, n, 2)`` [N·m] that give the joints the accelerations ``ddq`` ``(B, n, 2)`` [rad/s²]
        sample by sample from states ``x`` ``(B, 4)``: ``τ[k] = M(q[k]) q̈[k] + C(q[k], q̇[k]) q̇[k] + g(q[k]) +
        b q̇[k]`` at the states the semi-implicit step passes through with those accelerations, so :meth:`step`
        applied to them accelerates the arm by ``ddq`` (to rounding). Zero accelerations hold a resting arm
        against gravity. The online generator's stop plans accelerations and outputs these torques."""
        q1, q2, dq1, dq2 = x.unbind(-1)
        j1, j2, s2, w1 = _inertias(self.payload_mass)
        l1s2, g_w1, g_s2, b, dt = LINK_LENGTHS[0] * s2, GRAVITY * w1, GRAVITY * s2, self.joint_damping, self.dt
        rows: list[list[torch.Tensor]] = [[], []]
        for a1, a2 in zip(*(a.unbind(1) for a in ddq.unbind(-1)), strict=True):
            c, h = l1s2 * torch.cos(q2), l1s2 * torch.sin(q2)  # M = [[j1 + j2 + 2c, j2 + c], [j2 + c, j2]]
            tip = g_s2 * torch.cos(q1 + q2)
            rows[0].append((j1 + j2 + 2 * c) * a1 + (j2 + c) * a2 - h * dq2 * (2 * dq1 + dq2) + g_w1 * torch.cos(q1)
                           + tip + b * dq1)
            rows[1].append((j2 + c) * a1 + j2 * a2 + h * dq1 * dq1 + tip + b * dq2)
            dq1, dq2 = dq1 + dt * a1, dq2 + dt * a2
            q1, q2 = q1 + dt * dq1, q2 + dt * dq2
        return torch.stack([torch.stack(row, 1) for row in rows], -1)

    def decoder_input(self, states: torch.Tensor) -> torch.Tensor:
        return states

    def narrow(self, carry: tuple[torch.Tensor, CovarianceCarry], rows: int) -> tuple[torch.Tensor, CovarianceCarry]:
        x, cov = carry
        return x[:rows], cov.narrow(rows)

    def restart(self, carry: tuple[torch.Tensor, CovarianceCarry], state: torch.Tensor,
                mask: torch.Tensor) -> tuple[torch.Tensor, CovarianceCarry]:
        x, cov = carry
        return torch.where(mask.view(-1, 1), state.to(x.dtype), x), cov.reset_where(mask)
