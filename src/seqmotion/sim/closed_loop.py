"""A trained model's online generator closing the loop around a Gymnasium arm environment.

:func:`run_episode` is what a 1 kHz robot controller does with a seq2seq decoder: every
millisecond it applies the decoder's next acceleration to the arm (``action="accel"``,
``frame_skip=1``: the environment integrates it into the PD + DOB controller's reference, as
:func:`~seqmotion.sim.run_pancake` does with a whole trajectory), measures the robot's state
(``env.model_state(obs)``, plus Gaussian measurement noise), and hands the measured states to
the generator, which replans from them:

* ``replan_every="sample"`` — after every sample (``gen.step(measured[-1:])``), where the
  stepper accepts fewer than C measured states; a stepper that refuses them (``ValueError``)
  is detected on the first call and the loop falls back to whole chunks
  (:attr:`ClosedLoopResult.replanning` says which ran);
* ``"chunk"`` — every C samples, with the C states measured since the previous call (the
  decoder's native rhythm; ``generate`` does the same in simulation);
* an integer n — every n samples, with those n states.

After the motion's K - 1 accelerations the reference decelerates to rest at constant
deceleration over ``decel_time`` (§4.4.3, as ``run_pancake``'s tail) and holds for ``hold_time``.
The noise-free ``model.generate(inputs)`` — the motion the generator means — is the yardstick:
end-pose errors are measured against its last state (and, for the pancake, against the sketch's).

:func:`turning_sketch` and :func:`draw_turning_episodes` give the documented distribution of
pancake-turning sketches the benchmark (``benchmarks/bench_envs.py``) and the example
(``examples/closed_loop_pancake.py``) run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..data.trajectories import tracking_rmse
from ..errors import check_finite_array, check_number
from .arm import workspace_problem
from .kinematics import planar_reference, stop_accelerations

PANCAKE_NOISE = (1e-3, 1e-3, 1e-2, 2e-2, 2e-2, 0.2)
"""Measurement noise σ of the pancake Deformer's state ``[y, z, θ, v_y, v_z, v_θ]``:
1 mm, 1 mm, 10 mrad, 2 cm/s, 2 cm/s, 0.2 rad/s."""

TURN_END_Y = (-0.1, 0.1)
TURN_END_Z = (-0.1, 0.1)
TURN_END_THETA = (1.5, 3.0)
TURN_LENGTH = (400, 600)


def turning_sketch(rng: np.random.Generator) -> np.ndarray:
    """One rough pancake-turning sketch ``(K, 6)``, the closed-loop benchmark's distribution.

    A straight S-curve from rest at the origin to rest at ``(y, z, θ)`` (``tasks.pancake.data.straight``,
    the inputs of Fig. 2.5 and ch. 4): ``y, z ~ U(-0.1, 0.1)`` m, ``|θ| ~ U(1.5, 3.0)`` rad with a
    random sign, ``K ~ U{400, …, 600}`` samples (0.4–0.6 s). Drawn in this order from ``rng``.
    """
    from ..tasks.pancake.data import straight

    y, z = rng.uniform(*TURN_END_Y), rng.uniform(*TURN_END_Z)
    theta = rng.choice([-1.0, 1.0]) * rng.uniform(*TURN_END_THETA)
    k = int(rng.integers(TURN_LENGTH[0], TURN_LENGTH[1] + 1))
    return straight((y, z, theta), k)


def draw_turning_episodes(model: Any, n: int, seed: int) -> tuple[list[np.ndarray], dict[str, int]]:
    """``n`` sketches (:func:`turning_sketch`, ``numpy.random.default_rng(seed)``) that ``model``
    deforms to feasible (max F_c ≤ 0.01 rad) motions inside the arm's workspace (deformed motion
    plus its 0.1 s deceleration tail, :func:`~seqmotion.sim.workspace_problem`).

    Returns:
        The sketches, and counts: ``drawn``, ``set_aside_infeasible``, ``set_aside_out_of_workspace``.
    """
    rng = np.random.default_rng(seed)
    chosen: list[np.ndarray] = []
    counts = {"drawn": 0, "set_aside_infeasible": 0, "set_aside_out_of_workspace": 0}
    while len(chosen) < n:
        sketch = turning_sketch(rng)
        counts["drawn"] += 1
        motion = model.generate(sketch)
        if not bool(motion.feasible):
            counts["set_aside_infeasible"] += 1
        elif workspace_problem(planar_reference(motion.states), "pancake") is not None:
            counts["set_aside_out_of_workspace"] += 1
        else:
            chosen.append(sketch)
    return chosen, counts


@dataclass
class ClosedLoopResult:
    """One closed-loop episode. Arrays cover the motion's samples ``1 … K-1`` (index i ↔ t = (i+1) ms);
    fewer if the episode ended early.

    Attributes:
        states: ``(N, S)`` the robot's true state after each step (the model's ``state_layout``).
        measured: ``(N, S)`` what the generator was given (``states`` + noise, or the reference).
        reference: ``(N, P)`` the environment's commanded reference (``env.reference``).
        plan: ``(K, S)`` the noise-free ``model.generate(inputs).states``.
        accel: ``(N, d)`` the accelerations applied.
        replanning: ``"sample"``, ``"chunk"``, ``"every n"``, or ``"chunk (fallback: …)"`` when
            the stepper refused fewer than C states.
        generator_calls: ``gen.step`` calls; ``generator_ms``: their median and largest time [ms].
        kept_on: the object stayed on the tool during the motion (pancake: never lost contact —
            slip ≤ 5 mm and gap ≤ 2 mm, as :attr:`PancakeResult.contact_lost`; sliding: not off the pan).
        lost_time: when contact was first lost [s from the motion's start], or ``None``.
        lost_in_tail: contact lost during the deceleration tail and hold (pancake).
        max_slip, max_gap: during the motion [m] (pancake; NaN otherwise).
        end_position_error, end_attitude_error: the true state at the motion's end (sample K-1)
            against ``plan[-1]``: position norm [m], |θ| [rad] (NaN where the task has no θ).
        end_position_error_sketch, end_attitude_error_sketch: the same against the sketch's end
            (where the inputs are states of the same layout; NaN otherwise).
        tracking_rmse: RMSE of the true positions against the reference [m] (pancake: y, z).
        plan_rmse: RMSE of the true positions against ``plan`` [m].
        ended: ``None``, or why the episode ended before the tail was done (``out_of_workspace``,
            ``unstable``, ``terminated``, ``truncated``).
        wall_s: wall-clock time of the episode [s].
    """

    states: np.ndarray
    measured: np.ndarray
    reference: np.ndarray
    plan: np.ndarray
    accel: np.ndarray
    replanning: str
    generator_calls: int
    generator_ms: tuple[float, float]
    kept_on: bool
    lost_time: float | None
    lost_in_tail: bool
    max_slip: float
    max_gap: float
    end_position_error: float
    end_attitude_error: float
    end_position_error_sketch: float
    end_attitude_error_sketch: float
    tracking_rmse: float
    plan_rmse: float
    ended: str | None
    wall_s: float
    infos: list[dict] = field(default_factory=list, repr=False)

    def summary(self) -> dict[str, Any]:
        """The scalar metrics as a JSON-friendly dict."""
        keys = ("replanning", "generator_calls", "kept_on", "lost_time", "lost_in_tail", "max_slip", "max_gap",
                "end_position_error", "end_attitude_error", "end_position_error_sketch",
                "end_attitude_error_sketch", "tracking_rmse", "plan_rmse", "ended", "wall_s")
        out = {k: getattr(self, k) for k in keys}
        out["generator_ms_p50_max"] = list(self.generator_ms)
        return out


def _planned_states(result: Any) -> np.ndarray:
    return np.asarray(result.motion().states, dtype=np.float64)


def _every(replan_every: str | int, chunk: int) -> int:
    if replan_every == "sample":
        return 1
    if replan_every == "chunk":
        return chunk
    if isinstance(replan_every, int | np.integer) and not isinstance(replan_every, bool) and 1 <= replan_every <= chunk:
        return int(replan_every)
    raise ValueError(f"replan_every must be 'sample', 'chunk' or an integer in [1, {chunk}], got {replan_every!r}")


def run_episode(
    env: Any,
    model: Any,
    inputs: object,
    *,
    noise: object | None = None,
    seed: int | None = None,
    replan_every: str | int = "sample",
    feedback: str = "measured",
    stop: str = "decel",
    decel_time: float = 0.1,
    hold_time: float = 0.0,
    stop_time: float = 0.3,
) -> ClosedLoopResult:
    """Run ``model``'s online generator for ``inputs`` in closed loop with ``env``.

    Args:
        env: a :class:`~seqmotion.sim.envs.PancakeArmEnv` or ``SlidingArmEnv`` (or a Gymnasium
            wrapper of one) with ``action="accel"`` and ``frame_skip=1``; ``normalize_actions``
            either way.
        model: a trained model whose ``state_layout`` is the environment's ``model_layout`` and
            whose ``accel_layout`` names its actions (the pancake Deformer for PancakeArm).
        inputs: what the model encodes (the pancake: a sketch ``(K, 6)``).
        noise: σ per state component, ``(S,)`` in the state's units (e.g. :data:`PANCAKE_NOISE`);
            ``None``: no noise.
        seed: of the environment's reset (object placement) and of the noise.
        replan_every: ``"sample"``, ``"chunk"`` or n (module docstring).
        feedback: ``"measured"`` (the robot's state + noise: closed loop) or ``"reference"`` (the
            environment's own reference: open loop, what ``generate`` assumes — a baseline).
        stop: what follows the motion's K - 1 accelerations: ``"decel"`` — the reference
            decelerates to rest at constant deceleration over ``decel_time`` [s], then holds for
            ``hold_time`` [s] (``run_pancake``'s tail); ``"generator"`` — the generator's own stop
            (where the stepper defines an end: it brings the robot to rest within the task's
            constraint, then holds), run for ``stop_time`` [s] with the same replanning.

    Raises:
        ValueError: an environment or model that do not fit, bad noise or options.
    """
    base = env.unwrapped
    if getattr(base, "action_mode", None) != "accel" or getattr(base, "frame_skip", None) != 1:
        raise ValueError("run_episode needs an arm environment with action='accel' and frame_skip=1 "
                         "(one decoder output per 1 ms step)")
    if tuple(base.action_layout.names) != tuple(model.accel_layout.names):
        raise ValueError(f"the environment's actions are {base.action_layout}; the model outputs {model.accel_layout}")
    s_dim = base.model_layout.dim
    base.model_state(np.zeros(base.observation_space.shape), model)  # ValueError unless the layouts match
    sigma = np.zeros(s_dim) if noise is None else check_finite_array("noise σ", noise, minimum=0.0)
    if sigma.shape != (s_dim,):
        raise ValueError(f"noise must be {s_dim} non-negative σ of {base.model_layout}, got {noise!r}")
    if feedback not in ("measured", "reference"):
        raise ValueError(f"feedback must be 'measured' or 'reference', got {feedback!r}")
    if stop not in ("decel", "generator"):
        raise ValueError(f"stop must be 'decel' or 'generator', got {stop!r}")
    for name, value in (("decel_time", decel_time), ("hold_time", hold_time), ("stop_time", stop_time)):
        check_number(f"{name} [s]", value, minimum=0.0)

    start_wall = time.perf_counter()
    plan = _planned_states(model.generate(inputs))
    sketch = np.asarray(inputs, dtype=np.float64)
    k_len = plan.shape[0]
    gen = model.generator(inputs)
    if stop == "generator" and not hasattr(gen, "done"):
        raise ValueError("this stepper defines no end of the motion; use stop='decel'")
    every = _every(replan_every, gen.chunk)
    replanning = {1: "sample", gen.chunk: "chunk"}.get(every, f"every {every}")
    rng = np.random.default_rng(seed)
    pancake = base.kind == "pancake"
    if pancake:
        options = {"start": plan[0, :3]}
    else:
        if np.abs(plan[0]).max() > 1e-9:
            raise ValueError(f"{type(base).__name__} starts at rest with the object at the pan's centre; "
                             f"the motion starts at {plan[0].tolist()}")
        options = None
    env.reset(seed=seed, options=options)
    n_pos = base.reference.shape[0] // 2

    states, measured, reference, applied, infos, call_ms = [], [], [], [], [], []
    ended = None

    def why(info: dict, terminated: bool) -> str:
        return next((key for key in ("out_of_workspace", "unstable") if key in info),
                    "object off the tool" if terminated else "truncated (time_limit)")

    def call(measured_states: np.ndarray | None) -> np.ndarray:
        t0 = time.perf_counter()
        out = gen.step() if measured_states is None else gen.step(measured_states)
        call_ms.append(1e3 * (time.perf_counter() - t0))
        return np.asarray(out, dtype=np.float64)

    n_motion = k_len - 1
    n_steps = n_motion + (round(stop_time / base.dt) if stop == "generator" else 0)
    tail_infos: list[dict] = []
    in_tail = False
    u, i, pending = call(None), 0, []
    for k in range(n_steps):
        a = u[i]
        i += 1
        obs, _, terminated, truncated, info = env.step(base.to_action(a))
        x = base.model_state(obs)
        seen = base.reference if feedback == "reference" else x + sigma * rng.standard_normal(s_dim)
        if k < n_motion:
            states.append(x)
            reference.append(base.reference)
            applied.append(a)
            infos.append(info)
            measured.append(seen)
        else:
            tail_infos.append(info)
        if terminated or truncated:
            ended, in_tail = why(info, terminated), k >= n_motion
            break
        pending.append(seen)
        if (len(pending) == every or i == len(u)) and k < n_steps - 1:
            try:
                u = call(np.array(pending))
            except ValueError as exc:
                if every == gen.chunk:
                    raise
                every, replanning = gen.chunk, f"chunk (fallback: the stepper refused {len(pending)} state(s): {exc})"
                if i < len(u):
                    continue  # keep collecting until a whole chunk
                raise
            pending, i = [], 0

    # The tail: constant deceleration of the reference to rest, then a hold (as run_pancake's).
    if ended is None and stop == "decel":
        for accel in stop_accelerations(base.reference[n_pos:], decel_time, hold_time, base.dt):
            _, _, terminated, truncated, info = env.step(base.to_action(accel))
            tail_infos.append(info)
            if terminated or truncated:
                ended, in_tail = why(info, terminated), True
                break
    if ended is not None and in_tail:  # the object falling off in the tail is lost_in_tail, not an abort
        ended = None if ended == "object off the tool" else f"{ended} (in the tail)"

    states_a, ref_a = np.array(states), np.array(reference)
    complete = len(states) == n_motion and (ended is None or in_tail)
    nan = float("nan")
    if pancake:
        lost_idx = next((j for j, inf in enumerate(infos) if not inf["in_contact"]), None)
        kept_on = complete and lost_idx is None
        lost_time = None if lost_idx is None else (lost_idx + 1) * base.dt
        lost_in_tail = any(not inf["in_contact"] for inf in tail_infos)
        max_slip = max((inf["slip"] for inf in infos), default=nan)
        max_gap = max((inf["gap"] for inf in infos), default=nan)
    else:
        kept_on, lost_time, lost_in_tail = complete, None, bool(ended)
        max_slip = max_gap = nan

    pos_dims = slice(0, 2)  # pancake y, z; sliding pan x, y
    end_pos = end_att = end_pos_sk = end_att_sk = nan
    if len(states) == k_len - 1:
        end = states_a[-1]
        end_pos = float(np.linalg.norm(end[pos_dims] - plan[-1, pos_dims]))
        if pancake:
            end_att = float(abs(end[2] - plan[-1, 2]))
            if sketch.shape == plan.shape:
                end_pos_sk = float(np.linalg.norm(end[pos_dims] - sketch[-1, pos_dims]))
                end_att_sk = float(abs(end[2] - sketch[-1, 2]))
    n = len(states)

    return ClosedLoopResult(
        states=states_a, measured=np.array(measured), reference=ref_a, plan=plan, accel=np.array(applied),
        replanning=replanning, generator_calls=len(call_ms),
        generator_ms=(float(np.median(call_ms)), float(np.max(call_ms))),
        kept_on=bool(kept_on), lost_time=lost_time, lost_in_tail=bool(lost_in_tail),
        max_slip=float(max_slip), max_gap=float(max_gap),
        end_position_error=end_pos, end_attitude_error=end_att,
        end_position_error_sketch=end_pos_sk, end_attitude_error_sketch=end_att_sk,
        tracking_rmse=tracking_rmse(states_a[:, pos_dims], ref_a[:, pos_dims]) if n else nan,
        plan_rmse=tracking_rmse(states_a[:, pos_dims], plan[1 : n + 1, pos_dims]) if n else nan,
        ended=ended, wall_s=time.perf_counter() - start_wall,
        infos=infos,
    )


__all__ = ["PANCAKE_NOISE", "ClosedLoopResult", "draw_turning_episodes", "run_episode", "turning_sketch"]
