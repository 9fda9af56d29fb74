"""A robot's rated limits as a latent objective for pancake motions (ch. 4: velocity limits are the dissertation's
example of an external order): :class:`ArmLimits`.

On an arm placed so that three parallel joints turn the spatula (:mod:`.planar_chain`: the UR5e's shoulder lift,
elbow and wrist 1; the Panda's joints 2, 4 and 6), the spatula's planar state *is* the arm's joint state, exactly: the
joint speeds follow from the chain's Jacobian, the joint angles from its closed-form inverse kinematics, the torques
from its Newton–Euler equations. Written here in PyTorch, they make the limits a differentiable penalty on the
generator's output, so ``optimize_latent(model, sketch, sm.sim.ArmLimits("ur5e") + ...)`` moves the learned
motion itself toward one the arm can run before any exact polish; :meth:`ArmLimits.report` says how far each limit is
from held.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from ..errors import check_number
from ..latent.terms import Objective, Term
from ..physics.integrator import DT
from ..tasks.pancake import physics as pancake_physics
from .executable import ACCEL_WINDOW
from .planar_chain import SPEED_MARGIN, TORQUE_MARGIN, PlanarChain, chain_torques, link_angles, planar_chain
from .robot_models import resolve_robot

ARM_KINDS = ("speed", "acceleration", "torque", "reach")
"""The limits :class:`ArmLimits` can hold: rated joint speeds and accelerations, torque limits, and the chain's reach
(its elbow within :data:`~seqmotion.sim.planar_chain.ELBOW_MARGIN` of stretched and folded)."""

_TERM_NAMES = {"speed": "rated joint speeds", "acceleration": "rated joint accelerations", "torque": "torque limits",
               "reach": "reach"}


def chain_motion(chain: PlanarChain, states: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The chain's joint angles ``(B, K, 3)`` [rad] (within π of home), joint speeds ``(B, K, 3)`` [rad/s] and
    shoulder–wrist distances ``(B, K)`` [m] along pancake states ``(B, K, 6)``, differentiably: the closed form of
    :func:`~seqmotion.sim.planar_chain.chain_joints` on the home's elbow branch. Out of reach the elbow is put
    stretched or folded (the distance says by how much)."""
    y, z, theta, vy, vz, vtheta = states.unbind(-1)
    w0y, w0z = (float(v) for v in chain.wrist)
    sy, sz = (float(v) for v in chain.shoulder)
    l1, l2 = chain.upper, chain.fore
    c, s = torch.cos(theta), torch.sin(theta)
    rwy, rwz = c * w0y - s * w0z, s * w0y + c * w0z  # R(θ) w0
    dy, dz = y + rwy - sy, z + rwz - sz
    cy, cz = vy - vtheta * rwz, vz + vtheta * rwy  # Ẇ = v + θ̇ J R(θ) w0
    dist = torch.sqrt(dy**2 + dz**2 + 1e-12)
    inner, outer = chain.reach
    held = dist.clamp(inner, outer)  # the links' geometry at the nearest reachable distance
    along = (held**2 + l1**2 - l2**2) / (2 * held)
    across = chain.elbow * torch.sqrt((l1**2 - along**2).clamp_min(1e-12))
    ay, az = (along * dy - across * dz) / dist, (along * dz + across * dy) / dist  # E − S
    by, bz = dy - ay, dz - az  # W − E
    det = ay * bz - az * by
    w1 = (cy * by + cz * bz) / det
    w2 = -(ay * cy + az * cz) / det
    a1, a2 = link_angles(chain)
    phi1, phi2 = torch.atan2(az, ay), torch.atan2(bz, by)
    delta = torch.stack([phi1 - a1, (phi2 - a2) - (phi1 - a1), theta - (phi2 - a2)], dim=-1)
    delta = torch.atan2(torch.sin(delta), torch.cos(delta))  # within π of home: the chain never turns further
    sign = torch.as_tensor(chain.axis_sign, dtype=states.dtype, device=states.device)
    home = torch.as_tensor(chain.home[list(chain.index)], dtype=states.dtype, device=states.device)
    speeds = torch.stack([w1, w2 - w1, vtheta - w2], dim=-1) * sign
    return home + sign * delta, speeds, dist


class ArmLimits(Objective):
    """A robot's rated limits on the joints that turn the spatula, as a penalty on pancake motions::

        Σ_kind 1/K Σ_k Σ_j max(0, |x_kj| / (margin · limit_j) − 1)²

    over the chain's joint speeds (``"speed"``), accelerations (``"acceleration"``, the speeds averaged over
    :data:`~seqmotion.sim.executable.ACCEL_WINDOW` and differenced, as the robot check does, where the maker publishes
    them), torques (``"torque"``, the chain's inverse dynamics against :data:`~seqmotion.sim.planar_chain.TORQUE_MARGIN`
    of the model's limits) and its reach (``"reach"``: the shoulder–wrist distance within the elbow's bounds, in
    metres). Use it with ``optimize_latent`` beside the task's constraint and an end pose (a sum with it is optimised
    by gradient descent with a line search: no residuals); the exact polish (``exact=True, robot=...``) then holds the
    limits as hard constraints.

    Args:
        robot: a standard arm whose placement has a planar chain and whose rated speeds are known (``"ur5e"``,
            ``"panda"``); any other is refused by name.
        kinds: the limits to hold, of :data:`ARM_KINDS` (an unpublished one, e.g. the UR5e's accelerations, is
            skipped).
        margin: aim at this share of each rated speed and acceleration (0 < margin ≤ 1; default the polish's).
        dt: the motion's sample period [s].
    """

    def __init__(self, robot: Any, kinds: tuple[str, ...] = ARM_KINDS, margin: float = SPEED_MARGIN,
                 dt: float = DT) -> None:
        standard = resolve_robot(robot)
        chain = None if standard is None else planar_chain(standard)
        if standard is None or chain is None or standard.limits.velocity is None:
            name = "the built-in arm" if standard is None else standard.label
            raise ValueError(f"ArmLimits needs an arm whose placement turns the spatula with three parallel joints "
                             f"and whose rated speeds are known (the UR5e, the Panda); {name} has "
                             f"{'no such placement' if chain is None else 'no published rated speeds'}")
        unknown = sorted(set(kinds) - set(ARM_KINDS))
        if unknown or not kinds:
            raise ValueError(f"kinds must be among {ARM_KINDS}, got {tuple(kinds)!r}")
        margin = check_number("margin", margin, minimum=0.0, maximum=1.0, strict_minimum=True)
        dt = check_number("dt", dt, minimum=0.0, strict_minimum=True)
        self.robot, self.chain, self.dt, self.margin = standard, chain, float(dt), float(margin)
        self.layout = pancake_physics.STATE_LAYOUT
        limits, index = standard.limits, list(chain.index)
        self.limit: dict[str, np.ndarray] = {}
        if "speed" in kinds:
            self.limit["speed"] = margin * np.asarray(limits.velocity)[index]
        if "acceleration" in kinds and limits.acceleration is not None:
            self.limit["acceleration"] = margin * np.asarray(limits.acceleration)[index]
        if "torque" in kinds and limits.torque is not None:
            self.limit["torque"] = TORQUE_MARGIN * np.asarray(limits.torque)[index]
        self.reach = "reach" in kinds
        self.window = max(1, round(ACCEL_WINDOW / self.dt))

    def excess(self, states: torch.Tensor) -> dict[str, torch.Tensor]:
        """Each held limit's share along the motion (``(B, M, 3)``, 1 = at the limit aimed at) and, for the reach, how
        far the shoulder–wrist distance is outside the elbow's bounds ``(B, K)`` [m] (0 inside)."""
        q, qd, dist = chain_motion(self.chain, states)
        out: dict[str, torch.Tensor] = {}
        if "speed" in self.limit:
            out["speed"] = qd[:, 1:].abs() / self._tensor("speed", states)  # the start state is given, not made
        if "acceleration" in self.limit or "torque" in self.limit:
            kernel = torch.full((3, 1, self.window), 1.0 / self.window, dtype=states.dtype, device=states.device)
            smooth = torch.nn.functional.conv1d(qd.transpose(1, 2), kernel, groups=3).transpose(1, 2)
            qdd = torch.diff(smooth, dim=1) / self.dt
            if "acceleration" in self.limit:
                out["acceleration"] = qdd.abs() / self._tensor("acceleration", states)
            if "torque" in self.limit:
                at = slice(self.window // 2, self.window // 2 + qdd.shape[1])  # q and q̇ where q̈ is taken
                tau = chain_torques(self.chain, q[:, at].unbind(-1), qd[:, at].unbind(-1), qdd.unbind(-1),
                                    torch.cos, torch.sin)
                out["torque"] = torch.stack(tau, dim=-1).abs() / self._tensor("torque", states)
        if self.reach:
            inner, outer = self.chain.reach
            out["reach"] = torch.relu(inner - dist) + torch.relu(dist - outer)
        return out

    def _tensor(self, kind: str, like: torch.Tensor) -> torch.Tensor:
        return torch.as_tensor(self.limit[kind], dtype=like.dtype, device=like.device)

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        total = torch.zeros(states.shape[0], dtype=states.dtype, device=states.device)
        for kind, value in self.excess(states).items():
            over = value / 0.01 if kind == "reach" else torch.relu(value - 1.0)  # reach: a centimetre counts as 1
            total = total + (over**2).reshape(len(over), -1).sum(1) / states.shape[1]
        return total

    def report(self, states: torch.Tensor, accel: torch.Tensor) -> dict[str, Term]:
        """Each limit's worst share of the rated value (met at ≤ 1/margin, i.e. within the rated value) and the
        reach's worst overshoot [m] (met at 0)."""
        terms = {}
        with torch.no_grad():
            for kind, value in self.excess(states).items():
                worst = value.reshape(len(value), -1).amax(1).cpu().numpy()
                if kind == "reach":
                    terms[_TERM_NAMES[kind]] = Term(worst, 1e-6, "m")
                else:
                    aimed = TORQUE_MARGIN if kind == "torque" else self.margin
                    terms[_TERM_NAMES[kind]] = Term(worst * aimed, 1.0, "× rated")
        return terms

    def __repr__(self) -> str:
        kinds = tuple(self.limit) + (("reach",) if self.reach else ())
        return f"ArmLimits({self.robot.name!r}, kinds={kinds}, margin={self.margin:g})"


def arm_limit_shares(robot: Any, states: np.ndarray, dt: float = DT) -> dict[str, float]:
    """The worst share of each rated limit (and the reach's overshoot [m]) along one pancake motion ``(K, 6)`` on
    ``robot``'s chain: :meth:`ArmLimits.report` without an optimisation (how near a learned motion lands)."""
    objective = ArmLimits(robot, dt=dt)
    arr = torch.as_tensor(np.asarray(states, dtype=np.float64))[None]
    terms = objective.report(arr, arr[:, :-1, :3])
    return {name: float(np.asarray(term.value)[0]) for name, term in terms.items()}


__all__ = ["ARM_KINDS", "ArmLimits", "arm_limit_shares", "chain_motion"]
