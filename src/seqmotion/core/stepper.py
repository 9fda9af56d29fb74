"""The decoder as a real-time motion generator for any task: the stepper and its contract.

``model.generator(inputs)`` (or ``model.generator(latent=z, x0=x0, length=K)``) returns an
:class:`OnlineGenerator`; ``sm.deploy.OnnxStepper`` runs the same :class:`StepperCore` on
onnxruntime. The contract below is written once, here; :func:`stepper_contract` puts it in a
dict (``gen.contract()``) and ``seqmotion export-onnx`` writes that dict as ``contract.json``.

**Layouts and units.** Measured states are rows of the task's ``state_layout`` (SI units: the
pancake's ``y, z, θ, v_y, v_z, v_θ`` in m, m, rad, m/s, m/s, rad/s; the sliding planner's pan and
object-relative ``[x, y, v_x, v_y]``); outputs are rows of its ``accel_layout`` (m/s², rad/s²; a
torque-driven arm's N·m), one per sample of ``dt`` (1 ms). Input and output scales are inside the
model (and the graphs).

**What initialises the decoder.** A latent ``z`` of L·H numbers and a start state ``x0``:
decoder layer l starts with ``c_l = z[l·H:(l+1)·H]`` and ``h_l = 0``; its first step reads ``x0``
repeated C times (eq. 2.12). From an input motion, ``z`` is the encoder's final cell states and
``x0`` the task's start state for it.

**Time.** Sample t = 0 is ``x0``; output ``u[t]`` takes the robot from ``x[t]`` to ``x[t+1]``.
Outputs come in chunks of C samples: chunk k is ``u[kC .. kC+C-1]``. A motion has K samples
(``x[0..K-1]``): ``u[0..K-2]`` are the decoder's, and from ``u[K-1]`` on the generator stops the robot.

**step(measured) → outputs.** Each call returns the outputs from the sample after the latest
measured state to the end of that sample's chunk (1..C rows). The first call takes no states and
returns ``u[0..C-1]``. Every later call takes the ``n ≥ 1`` states measured since the previous call,
``x[t+1..t+n]``, one per output applied, so at most as many as that call returned (calls never
cross a chunk boundary: a chunk's last output is always the last row returned).

* **At a chunk boundary** (t a multiple of C) the decoder advances one step from its saved
  recurrent state, reading the C states measured in the chunk that just ended, and the whole next
  chunk is returned: exactly what ``generate`` computes. Fed its own states (whole chunks or any
  split of them) it reproduces ``generate`` (bit for bit for whole chunks).
* **Between boundaries** (j = t − kC, 1 ≤ j < C) the recurrent state does not move. With
  ``replan=True`` the remaining outputs are the chunk's plan corrected by the decoder's own
  response to what was measured: ``u[t+i] = plan[j+i] + π(W_meas)[i] − π(W_pred)[i]``, where π re-runs
  the chunk's decoder step from the state saved at its boundary on the last C measured states
  ``W_meas = x[t-C+1..t]`` (before the motion: ``x0``), and on the same window with this chunk's
  samples replaced by what the plan predicts through the task's dynamics from ``x[kC]``. Without a
  disturbance ``W_meas = W_pred`` and the plan is returned unchanged (so sample-by-sample replay equals
  ``generate`` to float rounding); a disturbance changes all remaining outputs at once, as the
  decoder would react had the chunk started at t. ``replan=False`` returns the plan unchanged.
* **The end.** From sample K−1 on the generator plans accelerations of the velocity columns ``v``
  (columns d..2d−1 of the state, d = accel size: the accelerated coordinates' velocities)
  ``a = clip(−s·v/τ, ±a_max)`` per axis (τ = ``stop.tau``, ``a_max`` = ``stop.accel_limit`` in the
  velocity columns' units per second), for the largest s in ``stop.shrink`` (1, ½, ¼, ⅛, 1/16) whose
  predicted stop keeps the task's worst violation over the returned samples within
  ``stop.violation_tolerance`` of what coasting (zero acceleration) would give — so ≤ the tolerance
  wherever coasting keeps the constraint; if none does, the least violating s, or s = 1 where coasting
  breaks the constraint too (it cannot be kept: stop promptly); once every ``|v| ≤ stop.rest_velocity``
  the acceleration is exactly 0 (hold). ``stop.outputs`` says how a planned acceleration becomes an
  output: ``"accelerations"`` — the outputs are those accelerations (a double integrator; ``a_max`` is
  the model's output scale), so the hold outputs exactly 0; ``"outputs_for"`` — the task's dynamics
  turn them into its outputs, ``outputs_for(x, a)``, the outputs that give the accelerations ``a``
  along the path they take from ``x`` (a torque-driven arm: its inverse dynamics, so the hold is
  gravity compensation; ``a_max`` is the dynamics' ``stop_accel_limit``); the bundle holds that map as
  a graph. ``gen.stopping`` is True while it decelerates, ``gen.done`` once the latest measured state
  is at rest (the accelerations then 0). The stop is recomputed at every call from the latest measured
  state (or, in the chunk where the motion ends, from the state the plan predicts at K−1). The decoder
  is not run past the end. A task whose outputs are neither accelerations of its velocity columns (by
  their units) nor mapped by ``outputs_for`` has ``stop.outputs`` null: its stepper is refused (it
  could not stop the robot).

**prepare().** Optional, between calls: the work of the next call that no measurement changes,
done now — a control loop calls it after its command went out, while it waits for the next period,
so the next call (one measured state between boundaries) holds one decoder run instead of two. The
outputs are the same, bit for bit, whether it is called or not. ``OnnxStepper`` prepares the
predicted window's decoder run; the PyTorch generator has nothing to prepare.

**set_latent(z, restart=False, length=None).** Replay (default): takes effect at the next chunk
boundary; the decoder state there becomes the one it would have had with ``z`` from the start, fed
the same measured chunks (c = z, h = 0, x0 repeated C times, then the measured chunks); the clock
and K stay (``length`` sets a new K, counted from the motion's start). Only while the motion runs.
``restart=True``: at the next chunk boundary a new motion of ``length`` samples (default: the
current K) starts from the latest measured state (c = z, h = 0, that state repeated C times);
the clock restarts there.

**reset(x0=None).** Back to t = 0 with the latest latent and length, from ``x0`` (default: the
generator's start state); the next call is again a first call.

**Errors.** ``ValueError`` naming the problem: measured states of the wrong shape (the message
names the task's layout), NaN or inf in measured states, a latent or x0; more states than outputs
handed out; a first call with states, a later call without.

This module imports only NumPy at load time (``export-onnx`` copies it beside the graphs, where
only NumPy and onnxruntime are needed); the PyTorch backend imports torch when it is used.
"""

from __future__ import annotations

from typing import Any

import numpy as np

CONTRACT_FORMAT = "seqmotion-stepper/2"
"""The contract's format; a runner reads only its own (a bundle of another format is refused: re-export it)."""
DYNAMICS_GRAPH = "dynamics.onnx"
"""The file of the exported dynamics graph (one chunk of the task's ``ChunkDynamics.step``) in a bundle."""
OUTPUTS_FOR_GRAPH = "outputs_for.onnx"
"""The file of the exported ``outputs_for`` graph (the stop's accelerations → the task's outputs), for tasks
whose outputs are not accelerations."""
STOP_OUTPUTS = ("accelerations", "outputs_for")
"""What ``stop.outputs`` may name (module docstring, "The end"); null: the stop cannot be planned."""
STOP_TAU = 0.05
"""Time constant of the end-of-motion deceleration [s] (at shrink factor 1)."""
STOP_SHRINK = (1.0, 0.5, 0.25, 0.125, 0.0625)
"""Factors tried on the deceleration, largest first, until the task's constraint holds."""
REST_VELOCITY = 1e-6
"""Below this |v| on every velocity column the stop outputs exactly 0 (hold)."""
VIOLATION_TOLERANCE = 1e-6
"""A predicted stop sample with violation ≤ this counts as feasible."""

SEMANTICS = {
    "step": "returns u from the sample after the latest measured state to the end of its chunk; first call: no "
            "states, returns u[0..C-1]; later calls: the n >= 1 states measured since the previous call (at most as "
            "many as it returned)",
    "boundary": "when t reaches a multiple of C the decoder advances one step from its saved state on the C states "
                "measured in that chunk and the whole next chunk is returned (what generate computes)",
    "between_boundaries": "replan: u[t+i] = plan[j+i] + pi(W_meas)[i] - pi(W_pred)[i]; pi = the chunk's decoder step "
                          "re-run from the state saved at its boundary on the last C measured states (W_meas) and on "
                          "the same window with the chunk's samples replaced by the plan's prediction (W_pred); no "
                          "replan: the plan",
    "end": "samples >= K-1: a = clip(-s v / tau, +-a_max) on the velocity columns, largest s in shrink whose worst "
           "violation is within tolerance of coasting's (a = 0; so <= tolerance where coasting is feasible); if "
           "none, the least violating s, or s = 1 where coasting violates too; a exactly 0 once all |v| <= "
           "rest_velocity; outputs: a itself (stop.outputs 'accelerations'), or outputs_for(x, a), the task "
           "outputs that give a along the path from x ('outputs_for', graph files.outputs_for)",
    "set_latent": "replay (default): from the next chunk boundary the decoder state is the one z gives from the start "
                  "fed the same measured chunks, same clock and K; restart: at the next boundary a new motion of "
                  "length samples starts from the latest measured state",
    "reset": "t = 0 from x0 (or a new x0) with the latest latent and length",
}


def layout_dict(layout: Any) -> dict[str, Any]:
    return {"kind": layout.kind, "names": list(layout.names), "units": list(layout.units)}


def physics_inputs(dynamics: Any, physics: Any) -> list[str]:
    """The fields of ``physics`` (a :class:`~seqmotion.physics.parameters.Physics`) that ``dynamics`` reads as
    attributes of the same name (sliding: ``mu``, ``mu_dyn``; a double integrator: none), in field order:
    what an exported dynamics graph takes as its ``physics`` input, so a deployed model runs at other values."""
    return [name for name in physics.names() if hasattr(dynamics, name)]


CLOSED_FORMS = ("double_integrator",)
"""The closed forms a contract may name for the task's dynamics (a runner computes them without the graph)."""
CLOSED_FORM_TOLERANCE = 1e-12
"""How close (relative to the states' magnitude) a task's dynamics must come to a closed form for the contract to
name it: the same arithmetic in another order, ~1e-16 in float64."""


def closed_form(dynamics: Any, state_dim: int, accel_dim: int, chunk: int, reads_physics: bool) -> str | None:
    """``"double_integrator"`` when ``dynamics`` compute the double integrator (states ``[p (d), v (d)]`` driven by
    the outputs as accelerations, :func:`seqmotion.physics.integrator.integrate`) on random states and a random
    chunk of outputs, else None; a runner may then predict in closed form. Judged by what the dynamics compute,
    not by their class; never for dynamics that read physics (another value could make them another system)."""
    if reads_physics or state_dim != 2 * accel_dim:
        return None
    import torch

    from ..physics.integrator import DT, integrate

    rng = np.random.default_rng(0)
    x = torch.from_numpy(rng.standard_normal((4, state_dim)))
    accel = torch.from_numpy(10.0 * rng.standard_normal((4, chunk, accel_dim)))
    with torch.no_grad():
        _, out = dynamics.step(dynamics.start(x), accel, None)
        ref = integrate(x, accel, float(getattr(dynamics, "dt", DT)))[:, 1:]
    states = out["states"].detach().cpu().double()
    if states.shape != ref.shape:
        return None
    gap = float((states - ref).abs().max()) / float(ref.abs().max())
    return CLOSED_FORMS[0] if gap <= CLOSED_FORM_TOLERANCE else None


def dynamics_spec(dynamics: Any, physics: Any, chunk: int, state_dim: int, accel_dim: int) -> dict[str, Any]:
    """How the task's dynamics closes the loop, as data: the graph that runs one chunk of it, the time step,
    the chunk, the physics (its class, every field, the fields the graph reads and the values it runs at) and
    the closed form the dynamics compute, if any (:func:`closed_form`).

    The values are ``physics`` with each field the dynamics reads taken from the dynamics object itself, so
    the contract states what the stepper runs with.

    Raises:
        ValueError: a field the dynamics hold one value per trajectory of (the stepper runs one value).
    """
    from ..physics.integrator import DT

    inputs = physics_inputs(dynamics, physics)
    held = {}
    for name in inputs:
        value = getattr(dynamics, name)
        value = np.asarray(value.detach().cpu() if hasattr(value, "detach") else value, dtype=np.float64)
        if value.size != 1:
            raise ValueError(f"the stepper runs one value of {name}, not one per trajectory (got shape {value.shape})")
        held[name] = float(value.reshape(()))
    return {
        "graph": DYNAMICS_GRAPH,
        "dt": float(getattr(dynamics, "dt", DT)),
        "chunk": int(chunk),
        "physics": {"class": physics.key(), "names": list(physics.names()), "inputs": inputs,
                    "values": physics.replace(**held).to_dict()},
        "closed_form": closed_form(dynamics, state_dim, accel_dim, chunk, bool(inputs)),
    }


def is_acceleration_unit(output_unit: str, velocity_unit: str) -> bool:
    """Whether an output in ``output_unit`` is the rate of change of a velocity in ``velocity_unit``
    (``m/s²`` of ``m/s``, ``rad/s²`` of ``rad/s``; ``N·m`` of ``rad/s`` is not)."""
    return output_unit in (velocity_unit + "²", velocity_unit + "^2")


def outputs_are_accelerations(state_units: list[str], accel_units: list[str], velocity: list[int] | None) -> bool:
    """Whether each output's unit is its velocity column's per second (module docstring, "The end")."""
    return velocity is not None and len(velocity) == len(accel_units) and all(
        is_acceleration_unit(unit, state_units[i]) for unit, i in zip(accel_units, velocity, strict=True))


def stop_spec(dynamics: Any, state: Any, accel: Any, output_scale: list[float] | None,
              velocity: list[int] | None) -> tuple[str | None, list[float]]:
    """How the stop makes its outputs (``stop.outputs``) and the largest acceleration it plans per velocity
    column (``stop.accel_limit``, in the velocity columns' units per second).

    Dynamics with an ``outputs_for(x (B, S), accel (B, n, d)) -> (B, n, d)`` method map the planned
    accelerations to the task's outputs, and name the limit themselves (``stop_accel_limit``: d numbers):
    the model's output scale is in the outputs' units (N·m for torques), not an acceleration. Otherwise
    outputs in the velocity columns' units per second are the accelerations, limited by the output scale.

    Raises:
        ValueError: dynamics with ``outputs_for`` but no valid ``stop_accel_limit``.
    """
    d = accel.dim
    if callable(getattr(dynamics, "outputs_for", None)):
        limit = getattr(dynamics, "stop_accel_limit", None)
        try:
            values = [float(v) for v in limit]
        except (TypeError, ValueError):
            values = []
        if len(values) != d or not all(np.isfinite(v) and v > 0 for v in values):
            raise ValueError(f"the {type(dynamics).__name__} dynamics map the stop's accelerations to outputs "
                             f"(outputs_for) but give no stop_accel_limit of {d} finite numbers > 0 (the largest "
                             f"deceleration of each velocity column, in its unit per second), got {limit!r}")
        return "outputs_for", values
    scale = [float(v) for v in (output_scale or [1.0] * d)]
    if outputs_are_accelerations(list(state.units), list(accel.units), velocity):
        return "accelerations", scale
    return None, scale


def stepper_contract(model: Any, dynamics: Any, physics: Any = None) -> dict[str, Any]:
    """The stepper's contract for a trained model (a ``TrainedModel``), the dynamics it runs with and their
    physics (default: the model's own, ``model.physics``)."""
    cfg = model.model.cfg
    state, accel = model.state_layout, model.accel_layout
    d = accel.dim
    velocity = list(range(d, 2 * d))
    if 2 * d > state.dim or not all(state.units[i].endswith("/s") for i in velocity):
        velocity = None  # not the [positions, velocities] convention: the stop holds (outputs 0)
    spec = dynamics_spec(dynamics, model.physics if physics is None else physics, cfg.chunk, state.dim, d)
    outputs, limit = stop_spec(dynamics, state, accel, cfg.output_scale, velocity)
    lengths = getattr(model.options, "length", None)
    return {
        "format": CONTRACT_FORMAT,
        "task": model.task_def.name,
        "state_layout": layout_dict(state),
        "accel_layout": layout_dict(accel),
        "input_layout": layout_dict(model.input_layout),
        "chunk": int(cfg.chunk),
        "dt": spec["dt"],
        "layers": int(cfg.layers),
        "hidden": int(cfg.hidden),
        "latent_dim": int(cfg.latent_dim),
        "decoder_init": "c_l = z[l*H:(l+1)*H], h_l = 0 for each layer l; the first decoder step reads x0 repeated "
                        "C times",
        "decoder_input": "C consecutive states of state_layout in its units (physical; scales are inside the model)",
        "velocity_columns": velocity,
        "dynamics": spec,
        "constraint": _has_constraint(model),
        "options": model.options.to_dict(),
        "default_length": int(lengths[1]) if isinstance(lengths, (tuple, list)) and len(lengths) == 2 else None,
        "stop": {
            "tau": STOP_TAU,
            "shrink": list(STOP_SHRINK),
            "accel_limit": limit,
            "outputs": outputs,
            "rest_velocity": REST_VELOCITY,
            "violation_tolerance": VIOLATION_TOLERANCE,
        },
        "semantics": dict(SEMANTICS),
    }


def _has_constraint(model: Any) -> bool:
    """Whether the task declares a constraint (its ``violation`` returns a tensor)."""
    import torch

    s, d = model.state_layout.dim, model.accel_layout.dim
    out = model.task_def.violation(torch.zeros(1, 2, s, dtype=torch.float64), torch.zeros(1, 1, d, dtype=torch.float64),
                                   model.options)
    return out is not None


def stop_accel(v0: np.ndarray, n: int, scale: np.ndarray, tau: float, limit: np.ndarray, dt: float,
               rest: float) -> np.ndarray:
    """The end-of-motion deceleration ``(B, n, d)`` from velocities ``v0`` ``(B, d)``.

    Per axis ``a[i] = clip(−scale·v[i]/τ, ±limit)``, ``v[i+1] = v[i] + dt·a[i]`` (closed form: a
    constant-deceleration phase while clipped, then geometric decay); exactly 0 from the first
    sample at which every ``|v| ≤ rest``.
    """
    v0 = np.asarray(v0, dtype=np.float64)
    rate = (np.asarray(scale, dtype=np.float64) / tau)[:, None]  # (B, 1)
    lim = np.asarray(limit, dtype=np.float64)[None, :]  # (1, d)
    speed, sign = np.abs(v0), np.sign(v0)
    clipped_steps = np.maximum(np.ceil((speed - lim / rate) / (lim * dt)), 0.0)  # (B, d)
    i = np.arange(n, dtype=np.float64)[None, :, None]
    m = clipped_steps[:, None, :]
    clipped = i < m
    v_lin = sign[:, None, :] * (speed[:, None, :] - lim[:, None, :] * dt * i)
    v_m = sign * np.maximum(speed - lim * dt * clipped_steps, 0.0)
    v_geo = v_m[:, None, :] * (1.0 - rate[:, None, :] * dt) ** np.maximum(i - m, 0.0)
    v = np.where(clipped, v_lin, v_geo)
    a = np.where(clipped, -sign[:, None, :] * lim[:, None, :], -rate[:, None, :] * v)
    still = np.logical_or.accumulate(np.abs(v).max(axis=2) <= rest, axis=1)
    return np.where(still[..., None], 0.0, a)


MAX_ABS_STATE = 1e6
"""The largest magnitude a measured or start state may have (SI units: a million metres or metres
per second is a sensor fault, not a state; past float32's range the decoder would return NaN)."""


def _refuse_complex(value: object, name: str) -> None:
    if np.iscomplexobj(value):
        raise ValueError(f"{name} must be real numbers, got a complex array")


def _refuse_absurd(arr: np.ndarray, name: str) -> None:
    if np.any(np.abs(arr) > MAX_ABS_STATE):
        bad = np.argwhere(np.abs(arr) > MAX_ABS_STATE)[0].tolist()
        raise ValueError(f"{name} has a magnitude above {MAX_ABS_STATE:g} (first at index {bad}): not a physical state")


def check_states(value: object, batch: int, single: bool, layout: dict[str, Any], name: str) -> np.ndarray:
    """``value`` as float64 ``(B, n, S)`` of the layout (``ValueError`` naming the problem)."""
    names, units = layout["names"], layout["units"]
    _refuse_complex(value, name)
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric array, got {type(value).__name__}: {exc}") from None
    s = len(names)
    if arr.ndim != (2 if single else 3) or arr.shape[-1] != s:
        columns = ", ".join(f"{n} [{u}]" for n, u in zip(names, units, strict=True))
        if arr.ndim != (2 if single else 3):
            want = f"(n, {s})" if single else f"({batch}, n, {s})"
            raise ValueError(f"{name} must have shape {want} of {layout['kind']} ({columns}), got shape {arr.shape}")
        raise ValueError(f"{name} must have {s} columns per sample ({layout['kind']}: {columns}), "
                         f"got shape {arr.shape}")
    if not single and arr.shape[0] != batch:
        raise ValueError(f"{name} must hold {batch} trajectories like the generator, got shape {arr.shape}")
    if arr.shape[-2] < 1:
        raise ValueError(f"{name} holds no states (shape {arr.shape})")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0].tolist()
        raise ValueError(f"{name} contains NaN or inf (first at index {bad})")
    _refuse_absurd(arr, name)
    return arr[None] if single else arr


def check_vectors(value: object, dim: int, name: str, what: str, batch: int | None = None) -> tuple[np.ndarray, bool]:
    """``(B, dim)`` float64 from ``(dim,)`` or ``(B, dim)``, finite; and whether it was a single vector."""
    _refuse_complex(value, name)
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric array, got {type(value).__name__}: {exc}") from None
    single = arr.ndim == 1
    arr2 = np.atleast_2d(arr)
    if arr2.ndim != 2 or arr2.shape[1] != dim or (batch is not None and arr2.shape[0] not in (batch,)):
        shape = f"({dim},)" if batch in (None, 1) else f"({batch}, {dim})"
        raise ValueError(f"{name} must have shape {shape} ({what}), got shape {arr.shape}")
    if not np.all(np.isfinite(arr2)):
        raise ValueError(f"{name} must be finite (NaN or inf given)")
    return arr2, single


class StepperCore:
    """The stepper's bookkeeping (chunks, corrections, the stop, latent swaps), in NumPy.

    A backend supplies the decoder, the dynamics' prediction and the constraint
    (:meth:`_initial_state`, :meth:`_decode`, :meth:`_predict`, :meth:`_violation`). The semantics
    are the module docstring's.
    """

    def __init__(self, contract: dict[str, Any], latent: np.ndarray, x0: np.ndarray, single: bool,
                 length: int | None, replan: bool = True) -> None:
        self._contract = contract
        self.chunk = int(contract["chunk"])
        self.dt = float(contract["dt"])
        self.state_dim = len(contract["state_layout"]["names"])
        self.accel_dim = len(contract["accel_layout"]["names"])
        self._latent_dim = int(contract["latent_dim"])
        stop = contract["stop"]
        self._tau, self._shrink = float(stop["tau"]), tuple(float(s) for s in stop["shrink"])
        self._limit = np.asarray(stop["accel_limit"], dtype=np.float64)
        self._rest, self._tol = float(stop["rest_velocity"]), float(stop["violation_tolerance"])
        self._velocity = contract["velocity_columns"]
        # a contract without the field predates it: the schema let it through only where the outputs are the
        # accelerations by their units (deploy/bundle.py)
        self._outputs = stop.get("outputs", "accelerations")
        if self._velocity is not None and self._outputs not in STOP_OUTPUTS:
            units = ", ".join(contract["accel_layout"]["units"])
            raise ValueError(f"the {contract['task']!r} task's outputs ({units}) are not accelerations of its velocity "
                             "columns and its dynamics define no outputs_for(x, accel): the generator could not "
                             "bring the robot to rest after the motion. Give the dynamics an outputs_for method "
                             "(the outputs that produce given accelerations, e.g. inverse dynamics) and a "
                             "stop_accel_limit")
        self._single = bool(single)
        self._z = self._check_latent(latent)
        self._batch = self._z.shape[0]
        self._x0, _ = check_vectors(x0, self.state_dim, "x0", contract["state_layout"]["kind"], self._batch)
        self._length = self._check_length(length)
        self.replan = bool(replan)
        self._pending: tuple[np.ndarray, int | None] | None = None
        self._rows: tuple[np.ndarray, np.ndarray] | None = None
        self.reset()

    # --- checks ----------------------------------------------------------------------------------

    def _check_latent(self, latent: object) -> np.ndarray:
        batch = getattr(self, "_batch", None)
        z, _ = check_vectors(latent, self._latent_dim, "latent", f"L·H = {self._latent_dim} numbers", batch)
        return z.astype(np.float32)

    def _check_length(self, length: object) -> int:
        if length is None:
            length = self._contract.get("default_length")
            if length is None:
                raise ValueError("give the motion's length (length=K samples): the task has no default")
        try:
            k = int(length)
        except (TypeError, ValueError):
            raise ValueError(f"length must be an integer number of samples, got {length!r}") from None
        if k != length or k < 2:
            raise ValueError(f"length must be an integer K >= 2 samples, got {length!r}")
        return k

    # --- public interface ------------------------------------------------------------------------

    @property
    def length(self) -> int:
        """K, the samples of the current motion (x[0..K-1])."""
        return self._length

    @property
    def time(self) -> int:
        """t, the index of the latest measured state since the last reset (0 before any measurement)."""
        return self._t

    @property
    def stopping(self) -> bool:
        """Whether the motion is past its end (t ≥ K−1) and the robot not yet at rest: the outputs decelerate it."""
        return self._past_end and not self._at_rest()

    @property
    def done(self) -> bool:
        """Whether the motion is over and the robot at rest: t ≥ K−1 and every velocity column of the latest
        measured state within ``stop.rest_velocity``, so every planned acceleration from here on is exactly 0
        (outputs 0, or for ``stop.outputs == "outputs_for"`` the outputs that hold the robot, e.g. against
        gravity; a batch: all of its motions). ``while not gen.done`` loops until the robot stands still."""
        return self._past_end and self._at_rest()

    @property
    def _past_end(self) -> bool:
        return self._t - self._origin >= self._length - 1

    def _at_rest(self) -> bool:
        return self._velocity is None or bool(np.all(np.abs(self._latest[:, self._velocity]) <= self._rest))

    @property
    def latent(self) -> np.ndarray:
        """The latent the decoder runs on now ((L·H,) or (B, L·H))."""
        return self._z[0].copy() if self._single else self._z.copy()

    def contract(self) -> dict[str, Any]:
        """The stepper's contract (module docstring) with this generator's length and mode."""
        return {**self._contract, "length": self._length, "batch": None if self._single else self._batch,
                "replan": self.replan}

    def reset(self, x0: object | None = None) -> None:
        """Back to t = 0 (the next call is a first call) with the latest latent and length; optionally a new x0."""
        if x0 is not None:
            self._x0, _ = check_vectors(x0, self.state_dim, "x0", self._contract["state_layout"]["kind"], self._batch)
        if self._pending is not None:
            self._z, length = self._pending
            self._length = length if length is not None else self._length
            self._pending = None
        self._t = self._origin = 0
        self._started = False
        self._available = 0
        self._latest = self._x0.copy()
        self._next_state = self._initial_state(self._z)
        self._state = None
        self._history: list[np.ndarray] = []
        self._plan = self._pred = self._window = None
        self._measured = np.zeros((self._batch, self.chunk, self.state_dim))

    def set_latent(self, latent: object, *, restart: bool = False, length: int | None = None) -> None:
        """Replace the latent from the next chunk boundary (see the module docstring for ``restart``)."""
        z = self._check_latent(latent)
        if length is not None:
            length = self._check_length(length)
        if restart:
            self._pending = (z, length)
            return
        if self._started and self._past_end:
            raise ValueError("the motion has ended; set_latent(z, restart=True) starts a new one from here")
        self._pending = None
        state = self._initial_state(z)
        for window in self._history:  # as if z had been there from the start, fed the same chunks
            state, _ = self._decode(state, window)
        self._next_state, self._z = state, z
        if length is not None:
            self._length = length

    def prepare(self) -> None:
        """The next call's work that no measurement changes, done now (module docstring, "prepare()"): nothing
        here; a backend with such work (``OnnxStepper``) overrides it."""

    def step(self, measured: object | None = None) -> np.ndarray:
        """The next outputs (see the module docstring): ``(m, d)``, or ``(B, m, d)`` for a batch, 1 ≤ m ≤ C."""
        layout = self._contract["state_layout"]
        if not self._started:
            if measured is not None:
                raise ValueError("the first step starts from x0; call it without measured states")
            self._started = True
            return self._boundary()
        if measured is None:
            raise ValueError(f"after the first step, pass the states measured since the last call (1 to "
                             f"{self._available} rows of {layout['kind']})")
        states = check_states(measured, self._batch, self._single, layout, "measured")
        n = states.shape[1]
        if n > self._available:
            raise ValueError(f"measured holds {n} states, but the last call handed out only {self._available} "
                             f"outputs: pass one measured state per output applied (at most {self._available})")
        j = (self._t - self._origin) % self.chunk
        self._measured[:, j:j + n] = states
        self._t += n
        self._latest = states[:, -1].copy()
        if (self._t - self._origin) % self.chunk == 0:
            return self._boundary()
        return self._emit()

    # --- the algorithm -----------------------------------------------------------------------------

    def _boundary(self) -> np.ndarray:
        if self._pending is not None:  # a restart: a new motion from the latest measured state
            self._z, length = self._pending
            self._length = length if length is not None else self._length
            self._pending = None
            self._origin = self._t
            self._next_state = self._initial_state(self._z)
            self._history = []
        tau = self._t - self._origin
        if tau < self._length - 1:  # the chunk has decoder outputs
            if tau == 0:
                window = np.repeat(self._latest[:, None], self.chunk, axis=1)
            else:
                window = self._measured.copy()
            self._state = self._next_state
            self._next_state, self._plan = self._decode(self._state, window)
            self._window = window
            self._pred = self._predict(self._latest, self._plan)  # the plan's states: W_pred, the stop's start
            self._history.append(window)
        else:
            self._plan = self._pred = self._window = None
        return self._emit()

    def _emit(self) -> np.ndarray:
        c, b = self.chunk, self._batch
        tau = self._t - self._origin
        k, j = divmod(tau, c)
        n_total = c - j
        n_motion = max(0, min(c, self._length - 1 - k * c) - j)
        parts = []
        if n_motion > 0:
            u = self._plan[:, j:j + n_motion]
            if j > 0 and self.replan:
                w_meas = np.concatenate([self._window[:, j:], self._measured[:, :j]], axis=1)
                w_pred = np.concatenate([self._window[:, j:], self._pred[:, :j]], axis=1)
                _, mean = self._decode(self._state, np.concatenate([w_meas, w_pred]), repeat=2)
                u = u + (mean[:b, :n_motion] - mean[b:, :n_motion])
            parts.append(u)
        n_stop = n_total - n_motion
        if n_stop > 0:
            if n_motion == 0:
                start = self._latest
            elif j == 0:
                start = self._pred[:, n_motion - 1]
            else:
                start = self._predict(self._latest, parts[0])[:, -1]
            parts.append(self._stop(start, n_stop))
        out = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1)
        if not np.all(np.isfinite(out)):  # never hand NaN to a robot: refuse (the generator needs a reset)
            raise ValueError("the measured states drove the decoder out of its numeric range (NaN outputs); "
                             "check the measurements, then reset() the generator")
        self._available = n_total
        return out[0] if self._single else out

    def _stop(self, x: np.ndarray, n: int) -> np.ndarray:
        """The end-of-motion outputs ``(B, n, d)`` from states ``x`` ``(B, S)``."""
        b, d = x.shape[0], self.accel_dim
        if self._velocity is None:
            return np.zeros((b, n, d))
        v = x[:, self._velocity]
        mapped = self._outputs == "outputs_for"
        if not self._contract["constraint"]:
            accel = stop_accel(v, n, np.ones(b), self._tau, self._limit, self.dt, self._rest)
            return self._outputs_for(x, accel) if mapped else accel
        ns = len(self._shrink)
        rows, scale = self._candidate_rows(b)
        accel = stop_accel(v[rows[: ns * b]], n, scale, self._tau, self._limit, self.dt, self._rest)
        candidates = np.concatenate([accel, np.zeros((b, n, d))])  # + coasting, the reference
        start = x[rows]
        if mapped:  # the outputs that give those accelerations, coasting's included
            candidates = self._outputs_for(start, candidates)
        states = np.concatenate([start[:, None], self._predict(start, candidates)], axis=1)
        worst = self._violation(states, candidates).max(axis=1).reshape(ns + 1, b)
        ok = worst[:ns] <= np.maximum(worst[ns], 0.0) + self._tol  # no worse than not decelerating
        lost = worst[ns] > self._tol  # even coasting breaks the constraint: stop promptly instead
        pick = np.where(ok.any(axis=0), ok.argmax(axis=0), np.where(lost, 0, worst[:ns].argmin(axis=0)))
        return candidates[: ns * b].reshape(ns, b, n, d)[pick, np.arange(b)]

    def _candidate_rows(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        """For B states: the rows that repeat them once per stop candidate and once for coasting
        (candidate-major, ``((ns+1)·B,)``), and each candidate row's shrink factor ``(ns·B,)`` — made once:
        the stop is planned at every call near the end of a motion, where a call must stay short."""
        if self._rows is None or self._rows[0].size != (len(self._shrink) + 1) * b:
            self._rows = (np.tile(np.arange(b), len(self._shrink) + 1), np.repeat(np.asarray(self._shrink), b))
        return self._rows

    # --- the backend -------------------------------------------------------------------------------

    def _initial_state(self, z: np.ndarray) -> Any:
        """Decoder state from latents ``(B, L·H)`` float32: c = z, h = 0."""
        raise NotImplementedError

    def _decode(self, state: Any, windows: np.ndarray, repeat: int = 1) -> tuple[Any, np.ndarray]:
        """One decoder step on ``windows`` ``(repeat·B, C, S)`` float64 from ``state`` (for B, repeated):
        the new state and the means ``(repeat·B, C, d)`` float64."""
        raise NotImplementedError

    def _predict(self, x: np.ndarray, accel: np.ndarray) -> np.ndarray:
        """States ``(B, n, S)`` that ``accel`` ``(B, n, d)`` produce from ``x`` ``(B, S)`` (the task's dynamics)."""
        raise NotImplementedError

    def _violation(self, states: np.ndarray, accel: np.ndarray) -> np.ndarray:
        """The task's violation ``(B, n)`` of states ``(B, n+1, S)`` and accelerations ``(B, n, d)``."""
        raise NotImplementedError

    def _outputs_for(self, x: np.ndarray, accel: np.ndarray) -> np.ndarray:
        """The outputs ``(B, n, d)`` that give the velocity columns the accelerations ``accel`` ``(B, n, d)`` along
        the path they take from states ``x`` ``(B, S)`` (the dynamics' ``outputs_for``; ``stop.outputs`` is
        ``"outputs_for"``)."""
        raise NotImplementedError


class OnlineGenerator(StepperCore):
    """The stepper on the PyTorch model (``model.generator(...)``); semantics in the module docstring.

    Attributes:
        chunk: C, outputs per decoder step.
        replan: whether calls between chunk boundaries correct the plan (module docstring).
    """

    def __init__(self, model: Any, dynamics: Any, contract: dict[str, Any], latent: np.ndarray, x0: np.ndarray,
                 single: bool, *, length: int | None = None, violation: Any = None, replan: bool = True) -> None:
        import torch

        self._torch = torch
        self.model, self.dynamics, self._violation_fn = model, dynamics, violation
        super().__init__(contract, latent, x0, single, length, replan)

    def _initial_state(self, z: np.ndarray) -> Any:
        return self.model.initial_state(self._torch.from_numpy(z))

    def _decode(self, state: Any, windows: np.ndarray, repeat: int = 1) -> tuple[Any, np.ndarray]:
        torch = self._torch
        if repeat > 1:
            state = tuple((h.repeat(repeat, 1), c.repeat(repeat, 1)) for h, c in state)
        with torch.inference_mode():
            inputs = self.dynamics.decoder_input(torch.from_numpy(windows))
            state, mean, _ = self.model.decode_step(state, inputs, need_cov=False)
        return state, mean.double().numpy()

    def _predict(self, x: np.ndarray, accel: np.ndarray) -> np.ndarray:
        torch = self._torch
        with torch.inference_mode():
            start = torch.from_numpy(np.ascontiguousarray(x))
            _, out = self.dynamics.step(self.dynamics.start(start), torch.from_numpy(np.ascontiguousarray(accel)), None)
        return out["states"].numpy()

    def _violation(self, states: np.ndarray, accel: np.ndarray) -> np.ndarray:
        torch = self._torch
        with torch.inference_mode():
            out = self._violation_fn(torch.from_numpy(states), torch.from_numpy(accel))
        return out.double().numpy()

    def _outputs_for(self, x: np.ndarray, accel: np.ndarray) -> np.ndarray:
        torch = self._torch
        with torch.inference_mode():
            out = self.dynamics.outputs_for(torch.from_numpy(np.ascontiguousarray(x)),
                                            torch.from_numpy(np.ascontiguousarray(accel)))
        return out.double().numpy()


__all__ = [
    "CLOSED_FORMS", "CLOSED_FORM_TOLERANCE", "CONTRACT_FORMAT", "DYNAMICS_GRAPH", "OUTPUTS_FOR_GRAPH",
    "OnlineGenerator", "REST_VELOCITY", "SEMANTICS", "STOP_OUTPUTS", "STOP_SHRINK", "STOP_TAU", "StepperCore",
    "VIOLATION_TOLERANCE", "check_states", "check_vectors", "closed_form", "dynamics_spec", "is_acceleration_unit",
    "layout_dict", "outputs_are_accelerations", "physics_inputs", "stepper_contract", "stop_accel", "stop_spec",
]
