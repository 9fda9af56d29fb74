"""The task-generic model every task's training produces (:class:`TrainedModel`).

``generate`` (encode a motion and decode it through the task's physics), ``decode`` (from a latent),
``generator`` (the decoder as an online stepper fed measured states of the task's own size) and the
differentiable maps that latent optimisation uses. Tasks may subclass it for friendly verbs
(``Deformer.deform``, ``SlidingPlanner.plan``).
"""

from __future__ import annotations

import copy
import json
import math
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from ..errors import (
    MAX_LENGTH,
    CheckpointError,
    as_float_array,
    as_trajectories,
    check_finite_array,
    check_finite_result,
    check_number,
)
from ..models.seq2seq import ChunkDynamics, ChunkedSeq2Seq, Seq2SeqConfig, rollout
from ..physics.integrator import DT, reach_end
from ..physics.layout import StateLayout
from ..physics.parameters import Physics
from ..physics.transcription import Constraint, Solution, end_values, input_limits, transcription
from ..training import checkpoint as ckpt
from ..training.device import model_device, resolve_device
from ..training.pretrained import PretrainedModel
from . import registry, trust
from .execution import arm_form_for, check_execution, execution_check_for
from .polish import (
    ARM_ATTEMPTS,
    ARM_EXACT_REACH,
    ARM_ITERATIONS,
    ARM_MIN_DURATION,
    COLD_ITERATIONS,
    EXTEND_ATTEMPTS,
    EXTEND_COLD_ITERATIONS,
    EXTEND_GROWTH,
    FALLBACK_END_WEIGHT,
    POLISH_VIOLATION_TOLERANCE,
    WARM_ITERATIONS,
    ArmForm,
    ExactForm,
    polish_in_joints,
    rest_to_rest_accel,
    retimed,
    steps_to_stop,
)
from .results import Assessment, Motion, first_of, first_value
from .stepper import OnlineGenerator, stepper_contract
from .trust import position_std


class TrainedModel(PretrainedModel):
    """A trained chunked seq2seq model of any task: generate, decode, step online, optimise.

    Obtain one with ``sm.load(run_dir)`` or ``sm.load_pretrained(name)``. Everything task-specific
    (state size and names, physics, constraint, options) comes from ``self.task_def``.
    """

    config_class = Seq2SeqConfig

    def __init__(self, model: ChunkedSeq2Seq, config: dict, task: Any = None) -> None:
        self.model = model.eval()
        self.config = config
        self.task_def: Any = task if task is not None else registry.get(config["task"])
        if type(self).task is not None and self.task_def.name != type(self).task:
            raise CheckpointError(
                f"a {type(self).__name__} needs a {type(self).task!r} model, got {self.task_def.name!r}"
            )
        training = self.config.get("training", {})
        if not isinstance(training, dict):
            raise ValueError(f"the config's training record must be a JSON object, got {type(training).__name__}")
        self.options = self.task_def.options(training.get("options", {}))
        self.physics: Physics = self.task_def.physics(self.options)
        """The physics the model runs at unless told otherwise (resolved from its options once)."""
        self.physics_trained = self._physics_trained(self.config.get("physics_trained"))
        """Field → (lowest, highest) value the training met: the record the trainer wrote into ``config.json``, or
        for a model saved without one, what the task says (:meth:`Task.physics_trained`) as before."""

    def _physics_trained(self, record: object) -> dict[str, tuple[float, float]]:
        """The checked ``physics_trained`` record of ``config.json`` (None: the task's own ranges at the options)."""
        if record is None:
            return dict(self.task_def.physics_trained(self.options))
        cls = self.task_def.physics_class
        names = cls.names()
        if not isinstance(record, dict):
            raise ValueError(f"physics_trained must map physics fields to [low, high], got {type(record).__name__}")
        out = {}
        for name, span in record.items():
            if name not in names:
                raise ValueError(f"physics_trained names {name!r}, not a field of {cls.__name__} ({list(names)})")
            ok = isinstance(span, list) and len(span) == 2 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in span)
            if not ok or span[0] > span[1]:
                raise ValueError(f"physics_trained[{name!r}] must be [low, high] with finite low <= high, got {span!r}")
            out[name] = (float(span[0]), float(span[1]))
        return out

    # --- the device ---------------------------------------------------------------------------

    @property
    def device(self) -> torch.device:
        """Where the network runs (the CPU unless moved with :meth:`to` or loaded with ``device=``)."""
        return model_device(self.model)

    def to(self, device: str | torch.device) -> TrainedModel:
        """Run the network (encoder, decoder, physics of the rollout) on ``device`` — ``"auto"``, ``"cpu"``,
        ``"cuda"``, ``"cuda:N"`` — from now on; returns ``self``. Inputs and results stay NumPy arrays on the
        host: inputs are copied to the device, results back. The exact polish, the trust signals' bookkeeping
        and the online generator (:meth:`generator`, batch 1, latency-bound) run on the CPU.

        Raises:
            ValueError: an unknown device, or a CUDA device this machine does not have.
        """
        target = resolve_device(device)
        if getattr(self, "is_quantized", False) and target.type != "cpu":
            raise ValueError("a quantized copy runs on the CPU only (int8 CPU kernels)")
        self.model.to(target)
        return self

    def on_device(self, device: str | torch.device | None) -> TrainedModel:
        """This model if it already runs on ``device`` (None: wherever it is), else a copy moved there (the
        ``device=`` argument of latent optimisation: the caller's model stays where it was)."""
        if device is None:
            return self
        target = resolve_device(device)
        if target == self.device:
            return self
        moved = object.__new__(type(self))
        moved.__dict__.update(self.__dict__)
        moved.model = copy.deepcopy(self.model)
        return moved.to(target)

    # --- the save/load contract --------------------------------------------------------------

    def weights(self) -> dict[str, torch.Tensor]:
        return self.model.state_dict()

    def config_json(self) -> dict[str, Any]:
        return {k: v for k, v in self.config.items() if k not in ckpt.HASH_FIELDS}

    @classmethod
    def from_checkpoint(cls, config: dict[str, Any], tensors: dict[str, torch.Tensor], source: str) -> TrainedModel:
        """Check the config as a schema (types, ranges, the task's layouts) and every size in it against the
        weights' shapes *before* the model is allocated; then build it and load the weights."""
        task_name = config.get("task")
        if not isinstance(task_name, str):
            raise CheckpointError(f"{source}/config.json names no task (task={task_name!r})")
        try:
            task = registry.get(task_name)
        except ValueError as exc:
            raise CheckpointError(f"{source}: {exc}") from None
        if task.model_class is not None and not issubclass(task.model_class, cls):
            raise CheckpointError(f"{source} holds a {task.name!r} model, not a {cls.__name__}")
        try:
            model_config = Seq2SeqConfig.from_dict(config.get("model"))
            task.check_model_config(model_config)
        except ValueError as exc:
            raise CheckpointError(f"{source}/config.json does not describe a valid model: {exc}") from None
        ckpt.check_shapes(model_config.parameter_shapes(), {k: tuple(v.shape) for k, v in tensors.items()}, source)
        model = ChunkedSeq2Seq(model_config)
        ckpt.load_state_dict_strict(model, tensors, source)
        try:
            wrapped = task.wrap(model, config)
        except ValueError as exc:  # options the task refuses
            raise CheckpointError(f"{source}/config.json: {exc}") from None
        wrapped.source_dir = source  # where trust.json (:mod:`.trust`) lives, if anywhere
        return wrapped

    def card_summary(self, name: str) -> list[str]:
        m = self.config["model"]
        head = f" + {m['head_hidden']}-unit linear" if m.get("head_hidden") else ""
        return [
            f"Task `{self.task_def.name}` — chunked seq2seq, {m['layers']} × {m['hidden']} LN-LSTM encoder and decoder"
            f"{head}, C = {m['chunk']}, latent {m['layers'] * m['hidden']} numbers. Reads {self.input_layout}; "
            f"generates {self.state_layout} through {self.accel_layout}.",
            "",
            "```python",
            "import seqmotion as sm",
            f"model = sm.load_pretrained({name!r})   # a {type(self).__name__}",
            "result = model.generate(motion)        # (K, "
            f"{self.input_layout.dim}) {', '.join(self.input_layout.names)} at 1 ms",
            "```",
        ]

    def card_training(self) -> list[str]:
        training = self.config.get("training", {})
        provenance = self.config.get("provenance", {})
        lines = [
            f"- Command: `{provenance.get('command', 'unknown')}`",
            f"- Seed: {training.get('seed')}; preset `{training.get('preset')}`; options "
            f"{json.dumps(self.options.to_dict())}",
            f"- Data: {training.get('curriculum', {}).get('epochs')} epochs × {training.get('batches_per_epoch')} "
            f"mini-batches × {training.get('batch_size')} trajectories, drawn fresh from the task's generators",
            f"- Wall time: {self.config.get('elapsed_seconds', 0) / 60:.1f} min ({self.config.get('step')} optimiser "
            "steps)",
            f"- Machine: {provenance.get('machine', 'unknown')}",
        ]
        if "resumed_with" in provenance:
            lines.append(f"- Resumed once from a checkpoint with `{provenance['resumed_with'].get('command')}`")
        return lines

    def check_finished(self) -> None:
        """Refuse to ship a run that stopped before the end of its curriculum."""
        training = self.config.get("training", {})
        total = training.get("batches_per_epoch", 0) * training.get("curriculum", {}).get("epochs", 0)
        if self.config.get("step") != total:
            raise ValueError(f"the run has not finished training (step {self.config.get('step')} of {total})")

    # --- what the task says --------------------------------------------------------------------

    @property
    def input_layout(self) -> StateLayout:
        return self.task_def.input_layout

    @property
    def state_layout(self) -> StateLayout:
        return self.task_def.state_layout

    @property
    def accel_layout(self) -> StateLayout:
        return self.task_def.accel_layout

    @property
    def input_dim(self) -> int:
        """Features per sample of the motions the encoder reads."""
        return self.input_layout.dim

    @property
    def uncertainty_names(self) -> tuple[str, ...]:
        """The state fields a result's ``uncertainty`` columns are the predicted std of."""
        fields_ = self.task_def.uncertainty_fields
        if fields_ is None:
            p = len(self.accel_layout.names)
            fields_ = self.state_layout.names[:p]
        return tuple(fields_)

    @property
    def uncertainty_units(self) -> tuple[str, ...]:
        """The units of :attr:`uncertainty_names`."""
        return tuple(self.state_layout.units[self.state_layout.index(n)] for n in self.uncertainty_names)

    def resolve_physics(self, physics: Physics | None) -> Physics:
        """``physics`` checked to be this task's kind (:attr:`Task.physics_class`), or the model's own
        (:attr:`physics`, from its options) when None."""
        if physics is None:
            return self.physics
        cls = self.task_def.physics_class
        if type(physics) is not cls:
            raise ValueError(f"the {self.task_def.name!r} model runs at {cls.__name__} physics ({self.physics}), "
                             f"got a {type(physics).__name__}; use model.physics.replace(...)")
        return physics

    def dynamics(self, physics: Physics | None = None) -> ChunkDynamics:
        """The :class:`~seqmotion.models.seq2seq.ChunkDynamics` the decoder runs with, at ``physics``
        (default: the model's own, :attr:`physics`)."""
        return self.task_def.dynamics(self.options, self.resolve_physics(physics))

    def start_state(self, inputs: torch.Tensor) -> torch.Tensor:
        """Decoder start state ``(B, state_dim)`` for input trajectories ``(B, K, input_dim)``."""
        return self.task_def.start_state(inputs)

    def violation_torch(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor | None:
        """The task's constraint violation ``(B, K-1)`` at this model's options (None: no constraint)."""
        return self.task_def.violation(states, accel, self.options)

    # --- the exact polish --------------------------------------------------------------------------

    def exact_form(self) -> ExactForm:
        """The task's :class:`ExactForm` at this model's options; ``ValueError`` naming the task if it has none."""
        form = self.task_def.exact_form(self.options)
        if form is None:
            raise ValueError(
                f"task {self.task_def.name!r} has no exact polish (Task.exact_form returns None), so exact=True and "
                "keep_end=True are not available for it; drop them to get the learned motion as it is"
            )
        return form

    def polish(
        self, x0: np.ndarray, accel: np.ndarray, constraints: Sequence[Constraint] = (),
        params: Sequence[np.ndarray] = (), start: np.ndarray | None = None, cold_iterations: int = COLD_ITERATIONS,
        warm: bool = True, symbolic: str = "auto",
        end_cost: tuple[Sequence[int], Sequence[float], np.ndarray] | None = None, arm: ArmForm | None = None,
    ) -> Solution:
        """The motion closest to ``accel`` that meets the task's constraint and ``constraints`` exactly.

        One trajectory: ``x0`` ``(S,)`` its start state, ``accel`` ``(K-1, d)`` the inputs to start from
        and stay near; ``params`` one array per constraint (its target). IPOPT starts at ``accel`` with a
        small barrier (a few iterations from a nearly feasible motion); if that does not converge (a
        start far from feasible can even look locally infeasible), it runs once more from the same
        motion with IPOPT's default barrier. ``start``: other inputs ``(K-1, d)`` to start IPOPT from
        (default ``accel``), e.g. ``accel`` already corrected to meet linear end conditions.
        ``cold_iterations``: IPOPT's iteration cap for the cold start; ``warm=False``: only the cold start (a
        start outside the acceleration limits, as ``keep_end``'s usually is, never converges warm);
        ``symbolic``: CasADi's graph type (:func:`~seqmotion.physics.transcription.transcription`; ``"MX"`` for
        lengths that will rarely recur, where SX's slower build never pays back);
        ``end_cost``: ``(columns, weights, target)`` adds ``|weights ⊙ (x[K-1, columns] − target)|²`` to the
        cost — an end condition asked for as nearly as the constraints allow instead of exactly;
        ``arm``: a robot's limits (:class:`~seqmotion.core.polish.ArmForm`) in place of the built-in arm's workspace.
        """
        form = self.exact_form()
        if arm is not None and arm.joint_space is not None:
            return polish_in_joints(form, arm, x0, accel, constraints, params, start, cold_iterations, symbolic,
                                    end_cost)
        limits = () if form.accel_limits is None else (input_limits(form.accel_limits, "acceleration limits"),)
        own = form.constraints + (form.workspace if arm is None else arm.constraints) + limits
        every = own + tuple(constraints)
        values = [np.zeros(0)] * len(own) + [np.asarray(p, np.float64) for p in params]
        length = len(accel) + 1
        kwargs = {"dt": form.dt, "accel_weights": form.accel_weights, "smoothness": form.smoothness,
                  "symbolic": symbolic}
        target = None
        if end_cost is not None:
            columns, weights, target = end_cost
            kwargs |= {"end_columns": tuple(int(c) for c in columns), "end_weights": tuple(map(float, weights))}
        guess = accel if start is None else start
        solution = None
        if warm:
            nlp = transcription(form.dim, length, every, warm=True, max_iter=WARM_ITERATIONS, **kwargs)
            solution = nlp.solve(x0, guess, values, reference=accel, end_target=target)
            if solution.success:
                return solution
        cold = transcription(form.dim, length, every, max_iter=cold_iterations, **kwargs)
        retry = cold.solve(x0, guess, values, reference=accel, end_target=target)
        if solution is not None:
            retry.iterations += solution.iterations
            retry.seconds += solution.seconds
        return retry

    def polish_on_arm(
        self, x0: np.ndarray, accel: np.ndarray, arm: ArmForm, constraints: Sequence[Constraint] = (),
        params: Sequence[np.ndarray] = (),
    ) -> Solution:
        """:meth:`polish` within a robot's limits (``arm``), for the caller's ``constraints`` (latent optimisation's
        ``exact=True``): the motion at least :data:`ARM_MIN_DURATION` long (``accel`` ``(K-1, d)`` from ``x0``
        retimed to it), IPOPT started from that motion, then from standing still :data:`EXTEND_GROWTH` × longer.
        The first solution that holds, else the last try's."""
        def attempt(steps: int, i: int) -> Solution:
            ref = retimed(accel, steps)
            return self.polish(x0, ref, constraints, params, start=ref if i == 0 else np.zeros_like(ref), warm=False,
                               symbolic="MX", arm=arm)

        solution, _, _, _ = self._lengthen(self._arm_steps(len(accel), extend=True), ARM_ATTEMPTS, attempt)
        return solution

    def _arm_steps(self, steps: int, extend: bool) -> int:
        """The inputs a polish on a robot's joints plans: ``steps``, at least :data:`ARM_MIN_DURATION` with
        ``extend``."""
        return max(steps, math.ceil(ARM_MIN_DURATION / self._dt() - 1e-9)) if extend else steps

    def _lengthen(self, steps: int, attempts: int, attempt: Callable[[int, int], Solution]) -> tuple[
            Solution, int, int, bool]:
        """The one retiming loop of the polishes that may take longer than their input: ``attempt(steps, i)`` at
        ``steps`` inputs, then :data:`EXTEND_GROWTH` × longer, at most ``attempts`` tries, until a solution holds
        (:meth:`_holds`). Returns the last try's solution and its number of inputs, IPOPT's iterations over every
        try, and whether it holds."""
        spent = 0
        for i in range(attempts):
            solution = attempt(steps, i)
            spent += solution.iterations
            if self._holds(solution):
                return solution, steps, spent, True
            if i < attempts - 1:
                steps = math.ceil(steps * EXTEND_GROWTH)
        return solution, steps, spent, False

    # --- differentiable maps (latent optimisation works on these) -------------------------------

    def encode_torch(self, inputs: torch.Tensor) -> torch.Tensor:
        """``(B, K, input_dim)`` → latents ``(B, L·H)`` (on the model's device)."""
        return self.model.encode(inputs.float().to(self.device))

    def decode_torch(
        self, latent: torch.Tensor, x0: torch.Tensor, length: int, physics: Physics | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Decode latents from start states into ``(states (B, K, S), accel (B, K-1, d))``, differentiably.

        The physics runs in the dtype of ``x0`` (float64 gives exact bookkeeping).
        """
        out = rollout(self.model, latent, x0, self.dynamics(physics), self.model.num_chunks(length), need_cov=False)
        return out.states[:, :length], out.accel[:, : length - 1].to(x0.dtype)

    def integrate_torch(self, x0: torch.Tensor, accel: torch.Tensor, physics: Physics | None = None) -> torch.Tensor:
        """States ``(B, N+1, S)`` that accelerations ``(B, N, d)`` produce from ``x0`` through the task's physics."""
        dynamics = self.dynamics(physics)
        _, out = dynamics.step(dynamics.start(x0), accel.to(x0.dtype), None)
        return torch.cat([x0.unsqueeze(1), out["states"]], dim=1)

    # --- NumPy API -----------------------------------------------------------------------------

    def generate(
        self, inputs: object, keep_end: bool = False, extend: bool = True, physics: Physics | None = None,
        robot: object = None,
    ) -> Any:
        """Encode ``(K, input_dim)`` or ``(B, K, input_dim)`` motions (any K ≥ 2) and decode them
        through the task's physics: a :class:`Motion` (the task's own subclass of it, e.g. ``DeformResult``,
        ``SlidingPlan``; any task's code reads ``result.motion().states`` and ``.accel``).

        ``keep_end=True``: then polish each motion (:meth:`polish`) so it ends exactly at the input's
        end pose (the task's ``end_pose`` fields of the input's last sample), at rest, with the task's
        constraint held and within the arm's acceleration limits (:attr:`ExactForm.accel_limits`) — the
        learned motion changed as little as possible. An input too short for that (e.g. 0.3 m and 3 rad
        in 0.15 s) gets the time it needs: the motion is longer than the input (``result.length``), unless
        ``extend=False``, which keeps the input's length and flags such a motion instead. Needs a task with
        an exact form and an end pose; ``result.exact`` says, per motion, whether the polish succeeded.
        One that fails (an end pose the constraint, limits or reach rule out) warns and ends at rest as
        near the end pose as they allow (its end error in ``result.errors``), still within them; only if
        even that fails does it keep the learned motion.

        ``physics``: the task's physics to decode at (default :attr:`physics`); the result records it.

        ``robot``: a robot the motion is for (a name such as ``"ur5e"``, or a robot object; one motion at a time).
        With ``keep_end``, the polish also keeps that robot's rated limits where the robot layer can state them as
        constraints (``seqmotion.core.execution.arm_form_for``; the motion may take longer, and where the end pose is
        out of the robot's reach with the task's constraint held, it ends as near as it can:
        :meth:`_polish_end_on_arm`). Either way the result is judged on the robot
        (``result.robot_check``, an :class:`~seqmotion.core.execution.ExecutionCheck`): where a limit is broken
        ``result.feasible`` is False and a ``RuntimeWarning`` names the binding limit and what would fix it.

        Raises:
            ValueError: wrong shape, K < 2, NaN or inf, physics of another task's kind,
                ``keep_end`` for a task without an exact form or end pose; a batch or an unknown robot with
                ``robot``, or a task with no execution check registered.
        """
        physics = self.resolve_physics(physics)
        batch, single = as_trajectories(inputs, self.input_dim, self.input_layout.kind)
        for name, flag in (("keep_end", keep_end), ("extend", extend)):
            if not isinstance(flag, bool):
                raise ValueError(f"{name} must be True or False, got {flag!r}")
        arm = None
        if robot is not None:
            if not single:
                raise ValueError(f"{self.task_def.name}: generate(robot=...) makes one motion at a time: pass one "
                                 f"motion of shape (K, {self.input_dim})")
            execution_check_for(self.task_def.name)  # ValueError naming the task before any work
            if keep_end:
                arm = arm_form_for(self.task_def.name, robot, self._dt())
        end = self._end_constraint(batch, physics) if keep_end else None
        with torch.inference_mode():
            x = torch.from_numpy(batch)
            z = self.encode_torch(x)
            result = self._decode(z, self.start_state(x).double(), batch.shape[1], physics, inputs=batch, end=end,
                                  extend=extend, arm=arm)
        result = first_of(result) if single else result
        if robot is not None:
            self._judge_on_robot(result, robot)
        return result

    def _dt(self) -> float:
        """The motion's sample period [s]: the task's dynamics' (the double integrator's 1 ms unless it says)."""
        return float(getattr(self.dynamics(), "dt", DT))

    def _judge_on_robot(self, result: Any, robot: object) -> None:
        """Set ``result.robot_check``: whether ``robot`` can execute the motion (the simulator's check, through
        the task layer's hook), and warn naming the binding limit where it cannot."""
        length = len(result.states) if result.length is None else int(result.length)
        states = np.asarray(result.states)[:length]
        result.robot_check = check_execution(self.task_def.name, states, robot, dt=self._dt())
        problem = result.robot_check.problem()
        if problem is not None:
            warnings.warn(problem, RuntimeWarning, stacklevel=3)
        elif result.robot_check.ok is None:  # never silent: a robot whose limits are unknown is not a pass
            warnings.warn(result.robot_check.describe(), RuntimeWarning, stacklevel=3)

    def _end_constraint(self, inputs: np.ndarray, physics: Physics) -> tuple[Constraint, np.ndarray]:
        """``keep_end``'s constraint — the end-pose fields at the inputs' last values, the rate fields
        (units ending in ``/s``) at 0 — and its values ``(B, n)``; refusals by name first."""
        self.exact_form()
        task = self.task_def
        if task.end_pose is None or self.input_layout.names != self.state_layout.names:
            raise ValueError(f"keep_end=True needs a task whose inputs are its states and that declares an end pose; "
                             f"{task.name!r} does not")
        if physics != self.physics:
            raise ValueError(f"keep_end=True polishes at the model's own physics ({self.physics.describe()}); "
                             f"got {physics.describe()}")
        layout = self.state_layout
        pose = [layout.index(f) for f in task.end_pose[0]]
        rates = [i for i, unit in enumerate(layout.units) if unit.endswith("/s") and i not in pose]
        values = np.concatenate([inputs[:, -1, pose], np.zeros((len(inputs), len(rates)))], axis=1)
        return end_values(pose + rates, "end at the input's end pose, at rest"), values

    def _polish_ends(
        self, states: torch.Tensor, accel: torch.Tensor, end: tuple[Constraint, np.ndarray], extend: bool = True,
        arm: ArmForm | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, np.ndarray, np.ndarray, np.ndarray]:
        """Polish each motion onto ``end`` (see :meth:`generate`): ``(states, accel, exact (B,), length (B,),
        iterations (B,))``, padded to the longest motion by holding its end state with zero input; ``iterations``:
        IPOPT's, summed over every polish the motion took (longer tries, the fallback). With ``arm`` (a robot's
        limits): :meth:`_polish_end_on_arm`."""
        constraint, values = end
        columns = list(constraint.key[1])
        exact = np.zeros(len(states), dtype=bool)
        iterations = np.zeros(len(states), dtype=np.int64)
        x0, reference = states[:, 0].numpy(), accel.numpy()
        form = self.exact_form()
        motions = []
        for b in range(len(states)):
            motions.append((states[b].numpy(), reference[b]))
            if arm is not None:
                motions[b], exact[b], iterations[b] = self._polish_end_on_arm(b, x0[b], reference[b], end[0],
                                                                              values[b], arm, extend, motions[b])
                continue
            steps = len(reference[b])
            if not extend:
                need = rest_to_rest_accel(x0[b], columns, values[b], steps, form)
                if need is not None:  # no motion can do it within the limits in its time: say so without IPOPT
                    warnings.warn(f"keep_end: motion {b} cannot end at rest where its input ends within the "
                                  f"acceleration limits {form.accel_limits} (rest to rest in its time needs at least "
                                  f"{need}); it keeps the learned motion", RuntimeWarning, stacklevel=4)
                    continue
            steps = steps_to_stop(x0[b], columns, values[b], steps, form) if extend else steps
            attempts = EXTEND_ATTEMPTS if extend else 1

            def padded(steps: int, b: int = b) -> np.ndarray:
                # after the input's end the polish stays near rest (zero input) while it brings it to a stop
                return np.concatenate([reference[b], np.zeros((steps - len(reference[b]), reference.shape[2]))])

            def attempt(steps: int, i: int, b: int = b, attempts: int = attempts) -> Solution:
                ref = padded(steps)
                # the end conditions are linear in the inputs: meet them first in closed form, so IPOPT
                # starts from a motion that only the task's constraint still separates from exact
                start = reach_end(x0[b], ref, columns, values[b], np.array(form.accel_weights), form.dt)
                last = i == attempts - 1  # a failing try is cut short: a longer one will likely succeed
                # MX: a motion's length (its input's, or an extended one) seldom recurs soon, and "auto" would
                # build the slow-to-build SX graph on its second request
                return self.polish(x0[b], ref, [constraint], [values[b]], start=start, warm=False,
                                   cold_iterations=COLD_ITERATIONS if last else EXTEND_COLD_ITERATIONS, symbolic="MX")

            solution, steps, iterations[b], exact[b] = self._lengthen(steps, attempts, attempt)
            if exact[b]:
                motions[b] = (solution.states, solution.accel)
            else:  # at the longest time tried
                ref = padded(steps)
                # from standing still — feasible for the constraint, limits and reach from a start at rest — toward
                # the learned motion: from the learned motion itself (beyond reach, where the exact polish failed)
                # IPOPT converges less often
                near, miss = self._nearest_rest(x0[b], ref, columns, values[b])
                iterations[b] += near.iterations
                motions[b] = self._settle_near(b, near, miss, solution.status, motions[b], "the acceleration limits "
                                               "and the reach", 6)
        length = np.array([len(s) for s, _ in motions])
        longest = int(length.max())
        states = torch.from_numpy(np.stack([np.concatenate([s, np.repeat(s[-1:], longest - len(s), 0)])
                                            for s, _ in motions]))
        accel = torch.from_numpy(np.stack([np.concatenate([a, np.zeros((longest - 1 - len(a), a.shape[1]))])
                                           for _, a in motions]))
        return states, accel, exact, length, iterations

    def _polish_end_on_arm(
        self, b: int, x0: np.ndarray, reference: np.ndarray, end: Constraint, values: np.ndarray, arm: ArmForm,
        extend: bool, learned: tuple[np.ndarray, np.ndarray],
    ) -> tuple[tuple[np.ndarray, np.ndarray], bool, int]:
        """``keep_end`` within a robot's limits, for motion ``b`` (inputs ``reference`` ``(K-1, d)`` from ``x0``).

        First the motion, at least :data:`ARM_MIN_DURATION` long (with ``extend``), that ends at rest as near the end
        pose as the task's constraint and the robot's limits allow (:meth:`_nearest_rest`: from standing still,
        which the arm can always do, IPOPT finds it in a few dozen iterations); then, where that misses the pose by
        at most :data:`ARM_EXACT_REACH`, the exact polish from it. An end the arm cannot reach with the pancake on —
        a turn past the cone's half-angle has to end rising, braking at more than g, so it ends higher and further
        out than the spatula starts — is not searched for at length: the near motion is kept, flagged. Returns
        ``((states, accel), exact, iterations)``."""
        columns = list(end.key[1])
        misses: list[np.ndarray] = []

        def attempt(steps: int, i: int) -> Solution:
            near, miss = self._nearest_rest(x0, retimed(reference, steps), columns, values, arm)
            misses.append(miss)
            return near

        near, steps, spent, held = self._lengthen(self._arm_steps(len(reference), extend),
                                                  ARM_ATTEMPTS if extend else 1, attempt)
        if not held:
            warnings.warn(f"keep_end: the polish failed on motion {b} within {arm.robot}'s limits ({near.status}); "
                          "it keeps the learned motion", RuntimeWarning, stacklevel=6)
            return learned, False, spent
        ref, miss = retimed(reference, steps), misses[-1]
        form = self.exact_form()
        pose = [self.state_layout.index(f) for f in self.task_def.end_pose[0]]
        weights = np.array([form.accel_weights[c] if c < form.dim else 1.0 for c in pose])
        status = "not tried: the nearest end within the limits is too far from it"
        if math.sqrt(float(np.sum(weights * miss**2))) <= ARM_EXACT_REACH:
            solution = self.polish(x0, ref, [end], [values], start=near.accel, warm=False,
                                   cold_iterations=ARM_ITERATIONS, symbolic="MX", arm=arm)
            spent += solution.iterations
            if self._holds(solution):
                return (solution.states, solution.accel), True, spent
            status = solution.status
        return self._settle_near(b, near, miss, status, learned, f"{arm.robot}'s limits", 7), False, spent

    def _holds(self, solution: Solution) -> bool:
        """Whether a polish converged with the task's constraint held (to :data:`POLISH_VIOLATION_TOLERANCE`)."""
        states, accel = torch.from_numpy(solution.states)[None], torch.from_numpy(solution.accel)[None]
        violation = self.violation_torch(states, accel)
        return solution.success and (violation is None or violation.numel() == 0
                                     or float(violation.max()) <= POLISH_VIOLATION_TOLERANCE)

    def _nearest_rest(
        self, x0: np.ndarray, ref: np.ndarray, columns: list[int], values: np.ndarray, arm: ArmForm | None = None,
    ) -> tuple[Solution, np.ndarray]:
        """The motion as long as ``ref`` that ends at rest, keeps the task's constraint and the limits (the built-in
        arm's, or ``arm``'s) exactly, and ends as near the end pose as they allow (weighted by
        :data:`FALLBACK_END_WEIGHT`), from standing still toward the learned inputs ``ref``; and its miss of the end
        pose ``(n_pose,)`` [the pose fields' units]. ``values``: ``keep_end``'s end values on ``columns``."""
        form = self.exact_form()
        pose = [self.state_layout.index(f) for f in self.task_def.end_pose[0]]
        rates = [c for c in columns if c not in pose]
        target = np.array([values[columns.index(c)] for c in pose])
        weights = [FALLBACK_END_WEIGHT * math.sqrt(form.accel_weights[c]) if c < form.dim else FALLBACK_END_WEIGHT
                   for c in pose]
        rest = end_values(rates, "end at rest")
        solution = self.polish(x0, ref, [rest], [np.zeros(len(rates))], start=np.zeros_like(ref), warm=False,
                               symbolic="MX", end_cost=(pose, weights, target), arm=arm)
        return solution, np.abs(solution.states[-1, pose] - target)

    def _settle_near(
        self, b: int, near: Solution, miss: np.ndarray, status: str, learned: tuple[np.ndarray, np.ndarray],
        limits: str, stacklevel: int,
    ) -> tuple[np.ndarray, np.ndarray]:
        """``keep_end``'s fallback for motion ``b``, whose end pose no polish reached (``status``; e.g. a pose the
        arm can hold the pancake at only from beyond its reach): the near motion (:meth:`_nearest_rest`) if it holds —
        executable, and flagged (``exact`` stays False, the trust signals give its end error) —, else the learned
        motion as it is; either way a warning says which."""
        if self._holds(near):
            warnings.warn(f"keep_end: motion {b} cannot end at its input's end pose within the task's constraint and "
                          f"{limits} ({status}); it ends at rest as near as they allow, {np.round(miss, 4).tolist()} "
                          f"from it ({', '.join(self.task_def.end_pose[0])})", RuntimeWarning, stacklevel=stacklevel)
            return near.states, near.accel
        warnings.warn(f"keep_end: the polish failed on motion {b} ({status}; ending at rest near its end pose: "
                      f"{near.status}); it keeps the learned motion", RuntimeWarning, stacklevel=stacklevel)
        return learned

    def decode(self, latent: object, x0: object, length: int, physics: Physics | None = None) -> Any:
        """Decode latents ``(L·H,)``/``(B, L·H)`` from start states ``(S,)``/``(B, S)`` into ``length`` samples
        (at ``physics``, default :attr:`physics`)."""
        length = check_number("length", length, minimum=2, maximum=MAX_LENGTH, integer=True)
        physics = self.resolve_physics(physics)
        z, start, single = self._latent_and_start(latent, x0)
        with torch.inference_mode():
            result = self._decode(z, torch.from_numpy(start), int(length), physics)
        return first_of(result) if single else result

    def _latent_and_start(self, latent: object, x0: object) -> tuple[torch.Tensor, np.ndarray, bool]:
        with np.errstate(over="ignore"):  # a latent beyond float32 becomes inf: refused below
            z = as_float_array(latent, "latent").astype(np.float32)
        single = z.ndim == 1
        z, start = np.atleast_2d(z), np.atleast_2d(as_float_array(x0, "x0"))
        s = self.state_layout.dim
        if z.ndim != 2 or z.shape[1] != self.model.latent_dim or start.shape != (z.shape[0], s):
            raise ValueError(
                f"need latent (B, {self.model.latent_dim}) and x0 (B, {s}) [{self.state_layout}]; "
                f"got {z.shape} and {start.shape}"
            )
        if z.shape[0] == 0:
            raise ValueError("latent has an empty batch (B = 0)")
        check_finite_array("latent", z)
        check_finite_array("x0", start)
        return torch.from_numpy(z), start, single

    def rollout_with_std(
        self, z: torch.Tensor, x0: torch.Tensor, length: int, physics: Physics | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, np.ndarray | None]:
        """Decode latents ``(B, L·H)`` from ``x0`` ``(B, S)``: ``(states (B, K, S), accel (B, K-1, d), std)``
        with ``std`` ``(B, K, p)`` the predicted position std of :attr:`uncertainty_names` (None: the
        dynamics give no position covariance of that size).

        The decoder's loop runs without propagating covariances; the head's ``S_u`` are propagated once
        over the whole motion afterwards (:meth:`Task.position_cov`), which costs a fraction of doing it
        chunk by chunk. A task without that closed form gets the chunk-by-chunk propagation.
        """
        dynamics = self.dynamics(physics)
        steps = self.model.num_chunks(length)
        device = self.device  # run where the network is; hand the results back on the CPU
        z, x0 = z.to(device), x0.to(device)
        out = rollout(self.model, z, x0, trust.HeadCovarianceOnly(dynamics), steps, need_cov=True)
        states, accel = out.states[:, :length], out.accel[:, : length - 1].to(x0.dtype)
        outputs = {k: v[:, : length - 1] for k, v in out.outputs.items()}
        cov = None
        if out.accel_cov is not None:
            cov = self.task_def.position_cov(out.accel_cov[:, : length - 1].to(x0.dtype), states, accel, outputs,
                                             dynamics)
        if cov is None:  # no closed form: the dynamics' own propagation
            cov = rollout(self.model, z, x0, dynamics, steps, need_cov=True).outputs.get("pos_cov")
        ok = cov is not None and cov.shape[-1] == len(self.uncertainty_names)
        return states.cpu(), accel.cpu(), position_std(cov, length) if ok else None

    def _decode(
        self, z: torch.Tensor, x0: torch.Tensor, length: int, physics: Physics, inputs: np.ndarray | None = None,
        end: tuple[Constraint, np.ndarray] | None = None, extend: bool = True, arm: ArmForm | None = None,
    ) -> Any:
        """Decode (with the predicted std, :meth:`rollout_with_std`), polish onto ``end`` when given
        (``keep_end``; ``extend``: see :meth:`generate`; within ``arm``'s limits when given), and judge the motion
        against ``inputs`` ``(B, K, input_dim)`` when given (errors, out-of-distribution flag)."""
        x0 = x0.double()
        states, accel, std = self.rollout_with_std(z, x0, length, physics)
        exact = own_length = iterations = None
        if end is not None:
            states, accel, exact, own_length, iterations = self._polish_ends(states, accel, end, extend, arm)
        violation = self.violation_torch(states, accel)
        if own_length is not None and violation is not None:  # a batch's padding past a motion's end is not part of it
            past = torch.arange(violation.shape[1]) >= torch.from_numpy(own_length - 1)[:, None]
            violation = violation.masked_fill(past, 0.0)
        if std is not None and std.shape[1] < states.shape[1]:  # the model predicted the input's time only
            std = np.concatenate([std, np.repeat(std[:, -1:], states.shape[1] - std.shape[1], axis=1)], axis=1)
        states_np = check_finite_result(states.numpy(), f"{self.task_def.name} generation")
        latent_np = z.float().cpu().numpy()
        motion = Motion(states_np, accel.numpy(), latent_np, None if violation is None else violation.numpy(),
                        uncertainty=std, exact=exact, length=own_length, polish_iterations=iterations,
                        task=self.task_def.name, physics=physics)
        if inputs is not None:
            motion.errors, motion.out_of_distribution, motion.ood_reasons = self._judge(
                inputs, states_np, motion.accel, motion.violation, std, physics)
        return self.task_def.make_result(motion, self)

    def _judge(
        self, inputs: np.ndarray, states: np.ndarray, accel: np.ndarray, violation: np.ndarray | None,
        std: np.ndarray | None, physics: Physics,
    ) -> tuple[dict[str, np.ndarray], np.ndarray | None, list[list[str]]]:
        """Errors ``(B,)`` each, out-of-distribution flags ``(B,)`` and reasons for a batch (``keep_end`` may have
        made the motions longer than the inputs: the input then holds its end, where the motion comes to rest);
        ``physics`` beyond what the training met is a reason too."""
        inputs = np.asarray(inputs, dtype=np.float64)
        held = np.concatenate([inputs, np.repeat(inputs[:, -1:], states.shape[1] - inputs.shape[1], axis=1)], axis=1)
        errors = self.task_def.errors(held, states, accel, violation, self.options)
        try:
            calibration = trust.calibration_for(self)
        except Exception as exc:  # noqa: BLE001 - a task whose generator cannot calibrate: say so, never fail
            self.trust_calibration = trust.TrustCalibration(upper={}, source=f"not calibrated ({exc})")
            calibration = self.trust_calibration
        physics_out = self._physics_beyond_training(physics)
        if not calibration.upper:
            if physics_out:
                return errors, np.ones(len(states), dtype=bool), [[*physics_out, calibration.source] for _ in states]
            return errors, None, [[calibration.source] for _ in range(len(states))]
        flags, reasons = calibration.check(trust.features_of(self, inputs, None, std))
        if physics_out:
            flags, reasons = np.ones_like(flags), [[*physics_out, *r] for r in reasons]
        return errors, flags, reasons

    def _physics_beyond_training(self, physics: Physics) -> list[str]:
        """Reasons (``"mu 1e+300 outside 0.72-1.32 (trained 0.8-1.2)"``) for each physics parameter beyond what the
        training met, widened by the trust margin: the model was never shown that physics."""
        reasons = []
        for name, (low, high) in self.physics_trained.items():
            value = getattr(physics, name, None)
            if value is None:
                continue
            # widened away from zero on both sides: a negative bound scaled by (1 - margin) would move inwards
            lo, hi = low - trust.MARGIN * abs(low), high + trust.MARGIN * abs(high)
            if not lo <= float(value) <= hi:
                reasons.append(f"{name} {float(value):.4g} outside {lo:.4g}-{hi:.4g} (trained {low:.4g}-{high:.4g})")
        return reasons

    def trust_lines(self, result: Any, tolerances: dict[str, float] | None = None) -> list[str]:
        """The lines the command lines print under a result (a task's result, a :class:`Motion` or an
        :class:`Assessment`): errors, predicted std at the end, ``warning:`` lines for missed tolerances
        (:meth:`Task.tolerances`, updated by ``tolerances``) and an input out of distribution
        (:func:`.trust.summary_lines`)."""
        return trust.summary_lines(
            getattr(result, "errors", None), getattr(result, "uncertainty", None),
            getattr(result, "out_of_distribution", None), getattr(result, "ood_reasons", None),
            {**self.task_def.tolerances(self.options), **(tolerances or {})}, self.uncertainty_names,
            self.uncertainty_units,
        )

    def assess(
        self, inputs: object, states: object, accel: object, latent: object | None = None,
        physics: Physics | None = None,
    ) -> Assessment:
        """Trust signals for a motion produced some other way (e.g. latent optimisation): its errors
        against ``inputs``, whether ``inputs`` lie outside the training distribution, and — given the
        ``latent`` it was decoded from — the predicted std (its end value joins the flag's features).

        Args:
            inputs: ``(K, input_dim)`` or ``(B, K, input_dim)`` the motion(s) the user gave.
            states: ``(K, S)``/``(B, K, S)`` the result's states; ``accel``: ``(K-1, d)``/``(B, K-1, d)``.
            latent: ``(L·H,)``/``(B, L·H)``, decoded from ``states[..., 0, :]`` for the uncertainty.
            physics: the physics the motion was generated at (default: the model's, :attr:`physics`).

        Returns:
            :class:`Assessment` (errors, out_of_distribution, ood_reasons, uncertainty); floats, a
            bool and a list of strings for one motion, ``(B,)`` arrays and a list per motion for a batch.
        """
        batch, single = as_trajectories(inputs, self.input_dim, self.input_layout.kind)
        states_b, accel_b = as_float_array(states, "states"), as_float_array(accel, "accel")
        if single:
            states_b, accel_b = states_b[None], accel_b[None]
        k = batch.shape[1]
        if states_b.shape != (len(batch), k, self.state_layout.dim) or accel_b.shape != (
            len(batch), k - 1, self.accel_layout.dim
        ):
            raise ValueError(
                f"need states (B, {k}, {self.state_layout.dim}) and accel (B, {k - 1}, {self.accel_layout.dim}) "
                f"for inputs {batch.shape}; got {states_b.shape} and {accel_b.shape}"
            )
        physics = self.resolve_physics(physics)
        std = None
        if latent is not None:
            z, start, _ = self._latent_and_start(latent, states_b[:, 0])
            with torch.inference_mode():
                _, _, std = self.rollout_with_std(z, torch.from_numpy(start), k, physics)
        with torch.inference_mode():
            violation = self.violation_torch(torch.from_numpy(states_b), torch.from_numpy(accel_b))
        errors, flags, reasons = self._judge(batch, states_b, accel_b, None if violation is None else violation.numpy(),
                                             std, physics)
        result = Assessment(errors, flags, reasons, std)
        if single:
            return Assessment(*(first_value(v) for v in result))
        return result

    def generator(
        self, inputs: object | None = None, *, latent: object | None = None, x0: object | None = None,
        length: int | None = None, replan: bool = True, physics: Physics | None = None,
    ) -> OnlineGenerator:
        """The decoder as an online motion generator for a control loop (contract: :mod:`.stepper`).

        Give either the ``inputs`` motion to encode (x0 = the task's start state for it, K = its
        length) or a ``latent`` and a start state ``x0`` of the task's ``state_layout`` (K = ``length``,
        default: the longest motion the model trained on). Past K the generator brings the robot to
        rest within the task's constraint, then holds. ``replan``: between chunk boundaries, correct
        the remaining outputs from the latest measured states.
        """
        if inputs is not None:
            if latent is not None or x0 is not None:
                raise ValueError("give either the input motion, or latent and x0 — not both")
            batch, single = as_trajectories(inputs, self.input_dim, self.input_layout.kind)
            with torch.inference_mode():
                x = torch.from_numpy(batch)
                z = self.encode_torch(x).cpu().numpy()
                start = self.start_state(x).double().numpy()
            length = batch.shape[1] if length is None else length
        elif latent is not None and x0 is not None:
            z_t, start, single = self._latent_and_start(latent, x0)
            z = z_t.numpy()
        else:
            raise ValueError("give either the input motion, or both latent and x0")
        dynamics = self.dynamics(physics)
        # batch 1, one chunk at a time: latency-bound, so the online generator steps on the CPU
        network = self.model if self.device.type == "cpu" else copy.deepcopy(self.model).cpu()
        return OnlineGenerator(network, dynamics, stepper_contract(self, dynamics), z, start, single,
                               length=length, violation=self.violation_torch, replan=replan)

    def quantized(self, min_features: int = 256) -> TrainedModel:
        """A copy for fast CPU inference with the big linear layers in int8 (weight-only).

        Worth it for wide models (the paper-size sliding planner: ~2.5× faster generation);
        narrow layers stay float32. See :mod:`seqmotion.models.quantize` for the error it adds.
        """
        from ..models.quantize import quantize_int8

        copy = object.__new__(type(self))
        copy.__dict__.update(self.__dict__)
        copy.model = quantize_int8(self.model, min_features)
        copy.is_quantized = True
        return copy

    def __repr__(self) -> str:
        m = self.model.cfg
        return f"{type(self).__name__}(task={self.task_def.name!r}, {m.layers}x{m.hidden}, C={m.chunk})"


__all__ = ["TrainedModel"]
