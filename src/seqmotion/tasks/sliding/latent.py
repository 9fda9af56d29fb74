"""Latent adjustment beside the sliding task: refining a plan so the object tracks its command.

The sliding planner (``sm.load_pretrained("sliding")``) plans in one forward pass; on commands
unlike its training commands (a 5 cm circle, a slow line) the object lags and stops short. The
plan's latent ``z`` can be refined by gradient descent on the tracking error through the
differentiable contact physics, at the friction the user gives (ch. 4's procedure with a
tracking objective)::

    import seqmotion as sm
    from seqmotion.tasks.sliding.latent import Tracking, refine_plan

    planner = sm.load_pretrained("sliding")
    command = sm.tasks.sliding.data.circle(0.05, 1200)
    plan = refine_plan(planner, command, mu=1.0, mu_dyn=0.5)      # a SlidingPlan, tracked
    # or, by hand (one round, no restarts):
    objective = Tracking(command, alpha_end=0.3, alpha_jerk=10, pan_limit=0.2)
    res = sm.optimize_latent(planner, command, objective, steps=300, optimizer="adam", lr=0.05,
                              physics=planner.physics.replace(mu=1.0, mu_dyn=0.5))

States of the sliding planner (``PLAN_LAYOUT``): columns 0..3 the pan ``x, y, vx, vy``, 4..7 the
object relative to the pan ``x, y, vx, vy`` [m, m/s].
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from ...core.execution import check_execution
from ...core.results import Motion, first_of
from ...errors import as_trajectories, check_number
from ...latent.optimize import optimize_latent
from ...latent.terms import Objective, check_weight
from ...physics.integrator import DT
from ...physics.parameters import Physics
from .physics import GRAVITY, PLAN_LAYOUT
from .task import (
    ACCEPT_CLEARANCE,
    ACCEPT_SHARE,
    PAN_LIMIT,
    ROBOT_KINDS,
    RUN_KINDS,
    PanJointLimits,
    SlidingPlan,
    check_limit_kinds,
    warn_if_not_executable,
)

MM2 = 1e6
"""m² → mm²: the objective is in mm² so its values read as a squared RMSE in millimetres."""


class Tracking(Objective):
    """Tracking error of a sliding plan against its command, with the pan kept in range.

    ``J = mean_k |p̂_d[k] − p_d[k]|² + α_v mean_k |v̂_d[k] − v_d[k]|² + α_e |p̂_d[K-1] − p_d[K-1]|²
    + α_j mean_k |û_p[k] − û_p[k−1]| + α_r mean_k max(0, |p̂_p[k]| − p_lim)²``

    per trajectory, in mm² (the velocity term in (mm/s)², the jerk term in m/s² per step): with
    α_v = α_e = α_j = α_r = 0, ``√J`` is the object's RMSE in millimetres. ``p̂_d``: the object
    relative to the pan (state columns 4, 5), ``p̂_p``: the pan (columns 0, 1), ``p_d``: the command.

    Args:
        command: ``(K, 4)`` or ``(B, K, 4)`` object states relative to the pan ``[x, y, vx, vy]``
            [m, m/s] — the command being planned for.
        alpha_range: α_r, the weight of the pan's excursion beyond ``pan_limit`` (≥ 0).
        pan_limit: p_lim [m]; default (None): the model's training option ``pan_limit``, set by
            :meth:`bind`; unbound, the task's default (0.2 m).
        alpha_velocity: α_v, the weight of the relative-velocity error (≥ 0; 0 by default).
        alpha_end: α_e, the weight of the end-position error ``|p̂_d[K-1] − p_d[K-1]|²`` (≥ 0;
            0 by default): makes the object arrive where the command ends instead of stopping short.
        alpha_jerk: α_j, the weight of ``mean_k |û_p[k] − û_p[k−1]|`` [m/s² per step] (the
            training loss's L3; ≥ 0, 0 by default): keeps refined accelerations from spiking.
    """

    layout = PLAN_LAYOUT

    def __init__(
        self, command: object, alpha_range: float = 10.0, pan_limit: float | None = None,
        alpha_velocity: float = 0.0, alpha_end: float = 0.0, alpha_jerk: float = 0.0,
    ) -> None:
        batch, _ = as_trajectories(command, 4, "command")
        self.command = torch.from_numpy(batch)  # (B or 1, K, 4) float64
        self.alpha_range = check_weight("alpha_range", alpha_range)
        self.alpha_velocity = check_weight("alpha_velocity", alpha_velocity)
        self.alpha_end = check_weight("alpha_end", alpha_end)
        self.alpha_jerk = check_weight("alpha_jerk", alpha_jerk)
        self.pan_limit = None if pan_limit is None else check_weight("pan_limit", pan_limit, positive=True)

    def bind(self, model: Any) -> Tracking:
        """This objective for a sliding model: refuses any other model; p_lim from its options."""
        task = getattr(getattr(model, "task_def", None), "name", None)
        if task != "sliding":
            raise ValueError(f"Tracking applies to a sliding planner (sm.load_pretrained('sliding')), got a "
                             f"{task!r} model")
        super().bind(model)  # the state layout
        limit = self.pan_limit if self.pan_limit is not None else float(model.options.pan_limit)
        bound = Tracking.__new__(Tracking)
        bound.command, bound.alpha_range, bound.alpha_velocity = self.command, self.alpha_range, self.alpha_velocity
        bound.alpha_end, bound.alpha_jerk = self.alpha_end, self.alpha_jerk
        bound.pan_limit = limit
        return bound

    def _command_for(self, states: torch.Tensor) -> torch.Tensor:
        b, k = states.shape[0], states.shape[1]
        if self.command.shape[1] != k or self.command.shape[0] not in (1, b):
            raise ValueError(f"Tracking's command has shape {tuple(self.command.shape)}, the plan ({b}, {k}, ...): "
                             "give the command the plan was made for")
        return self.command.to(states.dtype)

    def errors(self, states: torch.Tensor) -> torch.Tensor:
        """Object position error ``|p̂_d[k] − p_d[k]|`` per sample, ``(B, K)`` [m]."""
        return (states[..., 4:6] - self._command_for(states)[..., :2]).norm(dim=-1)

    def __call__(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor:
        if states.ndim != 3 or states.shape[-1] != PLAN_LAYOUT.dim:
            raise ValueError(f"Tracking reads sliding plans (B, K, {PLAN_LAYOUT.dim}), got {tuple(states.shape)}")
        command = self._command_for(states)
        value = MM2 * ((states[..., 4:6] - command[..., :2]) ** 2).sum(-1).mean(-1)
        if self.alpha_velocity > 0:
            value = value + self.alpha_velocity * MM2 * ((states[..., 6:8] - command[..., 2:]) ** 2).sum(-1).mean(-1)
        if self.alpha_end > 0:
            value = value + self.alpha_end * MM2 * ((states[:, -1, 4:6] - command[:, -1, :2]) ** 2).sum(-1)
        if self.alpha_jerk > 0 and accel.shape[1] > 1:
            value = value + self.alpha_jerk * (accel[:, 1:] - accel[:, :-1]).norm(dim=-1).mean(-1)
        if self.alpha_range > 0:
            limit = PAN_LIMIT if self.pan_limit is None else self.pan_limit
            over = torch.relu(states[..., :2].norm(dim=-1) - limit)
            value = value + self.alpha_range * MM2 * (over**2).mean(-1)
        return value

    def __repr__(self) -> str:
        return f"Tracking(K={self.command.shape[1]}, alpha_range={self.alpha_range:g}, pan_limit={self.pan_limit})"


DEFAULT_GAINS = (1.0, 1.2, 1.4)
"""Scaled commands whose encoder latents are tried as starts (the planner undershoots by about a third)."""


def refine_plan(
    planner: Any,
    command: object,
    mu: float | None = None,
    mu_dyn: float | None = None,
    steps: int = 300,
    lr: float = 0.05,
    objective: Tracking | None = None,
    gains: tuple[float, ...] = DEFAULT_GAINS,
    accel_steps: int = 0,
    accel_lr: float = 0.3,
    dither: float = 0.0,
    dither_hz: float = 50.0,
    robot: object = None,
    limits: tuple[str, ...] = ROBOT_KINDS,
) -> SlidingPlan:
    """Plan, then refine the plan's latent by Adam on :class:`Tracking` at the given friction.

    1. Start: of the encoder's latents of the scaled commands ``g · command`` (one per gain
       ``g``), the one whose plan scores lowest on ``objective`` (the plain plan is ``g = 1``).
    2. :func:`~seqmotion.optimize_latent` with Adam in three rounds (``steps`` updates in all,
       learning rates ``lr``, ``lr/3``, ``lr/10``), each continuing from the best latent so far;
       per trajectory the latent with the lowest objective at a round's end is kept (so the
       result never scores worse than the start).
    3. Optional (``accel_steps > 0``): Adam on the pan accelerations themselves (case 3 of
       ch. 4, through the same contact physics), from the decoded plan; the best per trajectory
       is kept. The plan is then no longer a decoding of ``latent`` (which stays the latent it
       started from). With ``dither > 0`` a second polish drives the pan with its accelerations
       plus a rotating vibration ``dither · μ g (cos 2πft, sin 2πft)``: above the breakaway
       acceleration μg it keeps the object sliding, so the gradient is alive at every sample and
       the polish can place the object's motion where the undithered plan's few slips could not
       (stiction compensation by dither). Per trajectory the better polish is kept (the objective's
       jerk term charges the base accelerations, not the vibration).

    With ``robot``: then keep that robot's limits (:meth:`SlidingPlanner.fit_robot
    <seqmotion.tasks.sliding.SlidingPlanner.fit_robot>` on the refined latent, the objective still the one above: the
    rated joint speeds, ranges, torques and accelerations mapped through the arm's Jacobian onto the pan as latent
    objective terms, checked on the simulator's IK and re-linearised until they hold); the acceleration polish, if
    asked, then carries the limits as a term too and is kept only if it keeps what the latent plan kept.
    ``plan.robot_check`` holds the verdict; ``plan.feasible`` is False, with a ``RuntimeWarning`` naming the binding
    limit, where one is broken after all.

    Gradients vanish wherever the object sticks, so refinement reshapes the plan's slips but
    cannot add new ones: it is a local fix (see benchmarks/results_planner_limits.md).

    Args:
        planner: a sliding planner (``sm.load_pretrained("sliding")``).
        command: ``(K, 4)`` or ``(B, K, 4)`` object states relative to the pan [m, m/s].
        mu, mu_dyn: the friction the plan is rolled out and refined at (default: the model's).
        steps: latent updates in all (0: no latent refinement).
        lr: the first round's learning rate (latent units).
        objective: a :class:`Tracking` for ``command`` (default
            ``Tracking(command, alpha_end=0.3, alpha_jerk=10, pan_limit=planner.options.pan_limit)``, the measured
            recipe).
        gains: the command scalings tried as starts (must include the ones wanted; ``(1.0,)``: the
            plain plan's latent).
        accel_steps: Adam updates on the pan accelerations after the latent (0: none).
        accel_lr: their learning rate [m/s²].
        dither: amplitude of the vibration added before the polish, in units of μg (0: none; needs
            ``accel_steps > 0``). It raises the pan's peak acceleration by about ``dither · μ g``.
        dither_hz: its frequency [Hz] (50 Hz: ±0.12 mm of pan motion at 1.2 μg, μ = 1).
        robot: a robot to plan for (``"panda"``, …; one command at a time), or None.
        limits: with ``robot``, the limits to keep, of :data:`~seqmotion.tasks.sliding.ROBOT_KINDS` (default all;
            :data:`~seqmotion.tasks.sliding.RUN_KINDS` keeps what a simulated run judges).

    Returns:
        the :class:`~seqmotion.tasks.sliding.SlidingPlan` (``(K, ...)`` or ``(B, K, ...)`` like
        ``command``), rolled out at ``mu``, ``mu_dyn`` (``plan.physics``).
    """
    physics = planner.physics.replace(mu=mu, mu_dyn=mu_dyn)  # checked once; the plan records it
    batch, single = as_trajectories(command, 4, "command")
    if robot is not None:
        if not single:
            raise ValueError("refine_plan(robot=...) plans one command at a time: pass a command of shape (K, 4)")
        check_limit_kinds(limits)
    for name, value in (("steps", steps), ("accel_steps", accel_steps)):
        check_number(name, value, minimum=0, integer=True)
    check_weight("dither", dither)
    if dither > 0 and accel_steps == 0:
        raise ValueError("dither is applied before the acceleration polish: give accel_steps > 0 as well")
    for name, value in (("lr", lr), ("accel_lr", accel_lr), ("dither_hz", dither_hz)):
        check_weight(name, value, positive=True)
    if isinstance(gains, str) or not gains:
        raise ValueError(f"gains must be a non-empty sequence of positive numbers, got {gains!r}")
    for gain in gains:
        check_number("each of gains", gain, minimum=0.0, strict_minimum=True)
    if objective is None:  # the measured recipe, within the pan range the planner was trained for
        objective = Tracking(batch, alpha_end=0.3, alpha_jerk=10.0, pan_limit=float(planner.options.pan_limit))
    bound = objective.bind(planner)

    best_z: np.ndarray | None = None
    best_j: np.ndarray | None = None
    for gain in gains:  # 1. the start
        with torch.no_grad():
            z = planner.encode_torch(torch.from_numpy(batch * gain)).numpy()
        result = optimize_latent(planner, batch, bound, steps=0, optimizer="adam", lr=lr, init=z, physics=physics)
        value = np.atleast_1d(result.history[-1]).astype(float)
        if best_z is None or best_j is None:
            best_z, best_j = z, value
        else:
            better = value < best_j
            best_z, best_j = np.where(better[:, None], z, best_z), np.where(better, value, best_j)
    assert best_z is not None and best_j is not None
    first, second = steps // 2, steps // 3
    for n, rate in ((first, lr), (second, lr / 3), (steps - first - second, lr / 10)):  # 2. the latent
        if n <= 0:
            continue
        result = optimize_latent(planner, batch, bound, steps=int(n), optimizer="adam", lr=rate, init=best_z,
                                 physics=physics)
        final = result.history.reshape(len(result.history), -1)[-1].astype(float)  # (B,)
        better = final < best_j
        best_z = np.where(better[:, None], np.atleast_2d(result.latent), best_z)
        best_j = np.where(better, final, best_j)
    x0 = np.concatenate([np.zeros((len(batch), 4)), batch[:, 0]], axis=1)
    plan = planner.decode(best_z, x0, batch.shape[1], physics)
    check = None
    if robot is not None:  # 2b. the robot's limits as latent objective terms
        plain = first_of(plan)
        plain.errors = planner.assess(batch[0], plain.states, plain.accel, best_z[0], physics=physics).errors
        fitted = planner.fit_robot(batch[0], plain, robot, tuple(limits), objective=bound)
        check, best_z = fitted.robot_check, np.asarray(fitted.latent, dtype=np.float32)[None]
        plan = planner.decode(best_z, x0, batch.shape[1], physics)
    if accel_steps > 0:  # 3. the accelerations
        vibration = None
        if dither > 0:
            mu_value = float(physics.mu)
            t = np.arange(batch.shape[1] - 1) * DT
            phase = 2 * math.pi * float(dither_hz) * t
            vibration = dither * mu_value * GRAVITY * np.stack([np.cos(phase), np.sin(phase)], axis=1)
        term = _limit_term(check, limits)
        goal = bound if term is None else (lambda states, accel: bound(states, accel) + term(states, accel))
        polished = _polish(planner, plan, torch.from_numpy(x0), goal, accel_steps, accel_lr, physics, vibration)
        if check is None:
            plan = polished
        else:  # kept only if it keeps what the latent plan kept
            after = check_execution(planner.task_def.name, polished.states[0], robot, dt=DT)
            if _kept_as_well(after, check, limits):
                plan, check = polished, after
    trust = planner.assess(batch, plan.motion().states, plan.motion().accel, best_z, physics=physics)
    plan.errors, plan.out_of_distribution, plan.ood_reasons, plan.uncertainty = trust
    if single:
        plan = first_of(plan)
        if robot is not None:
            plan.robot_check = check
            warn_if_not_executable(plan, plain, tuple(limits))
        return plan
    return plan


POLISH_LIMIT_WEIGHT = 1e3
"""The weight of the robot's limits (:class:`~seqmotion.tasks.sliding.PanJointLimits`) in the acceleration polish."""


def _limit_term(check: Any, limits: tuple[str, ...]) -> Any:
    """The robot's limits as a polish term (weighted :data:`POLISH_LIMIT_WEIGHT`), or None without a robot check."""
    if check is None or getattr(check, "pan_map", None) is None:
        return None
    term = PanJointLimits(check, tuple(limits))
    return lambda states, accel: POLISH_LIMIT_WEIGHT * term(states, accel)


def _kept_as_well(after: Any, before: Any, limits: tuple[str, ...]) -> bool:
    """Whether the check ``after`` keeps every limit of ``limits`` that ``before`` kept (the run's first)."""
    for kinds in (tuple(k for k in RUN_KINDS if k in limits), tuple(limits)):
        if kinds and before.kept(kinds, ACCEPT_SHARE, ACCEPT_CLEARANCE) and not after.kept(
                kinds, ACCEPT_SHARE, ACCEPT_CLEARANCE):
            return False
    return True


def _polish(
    planner: Any, plan: SlidingPlan, x0: torch.Tensor, objective: Tracking, steps: int, lr: float,
    physics: Physics, vibration: np.ndarray | None = None,
) -> SlidingPlan:
    """Adam on a batched plan's pan accelerations ``(B, K-1, 2)``; the best per trajectory is kept.

    With ``vibration`` ``(K-1, 2)`` [m/s²]: a second run optimises a base ``u_b`` with the pan driven
    by ``u_b + vibration`` from ``u_b`` = the plan, its objective charging the jerk of ``u_b`` only (the
    vibration is a fixed known signal); per trajectory the better of both runs (and of the plan) is kept.
    """
    original = torch.from_numpy(np.asarray(plan.pan_accel, dtype=np.float64))
    with torch.no_grad():
        best_j = objective(planner.integrate_torch(x0, original, physics), original)
    best_u = original.clone()  # the pan's total acceleration
    offsets = [torch.zeros(original.shape[1:], dtype=torch.float64)]
    if vibration is not None:
        offsets.append(torch.from_numpy(np.asarray(vibration, dtype=np.float64)))
    for offset in offsets:
        base = original.clone().requires_grad_(True)
        opt = torch.optim.Adam([base], lr=lr)
        for _ in range(steps + 1):
            total = base + offset
            value = objective(planner.integrate_torch(x0, total, physics), base)
            with torch.no_grad():
                better = value < best_j
                best_j = torch.where(better, value, best_j)
                best_u = torch.where(better[:, None, None], total, best_u)
            (grad,) = torch.autograd.grad(value.sum(), base)
            if not torch.isfinite(grad).all():
                break
            base.grad = grad
            opt.step()
    with torch.no_grad():
        states = planner.integrate_torch(x0, best_u, physics).numpy()
    motion = Motion(states, best_u.numpy(), plan.latent, task=planner.task_def.name, physics=physics)
    return planner.task_def.make_result(motion, planner)
