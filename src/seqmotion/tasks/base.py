"""What a task is, and the task-generic model every task's training produces.

A **task** (:class:`Task`) is physics + input generators + loss + curriculum, wired to the shared
chunked seq2seq model. It declares:

* its **layouts** — the named columns and units of the motions the encoder reads
  (``input_layout``), of the states the decoder generates in closed loop (``state_layout``)
  and of the decoder's outputs (``accel_layout``);
* its **options** — a validated dataclass (:mod:`.options`) saved with the model;
* its **physics** — :meth:`Task.dynamics` (the differentiable ``ChunkDynamics`` the decoder runs
  with), :meth:`Task.start_state`, and optionally :meth:`Task.violation` (its constraint, 0 where
  satisfied) and ``end_pose`` (the fields and weights an end-pose objective reaches for);
* its **training** — presets (:meth:`Task.train_config`), data (:meth:`Task.sample`) and loss
  (:meth:`Task.loss`, built from :mod:`seqmotion.training.losses`).

A task lives in ``seqmotion/tasks/`` (one module defining ``TASK``) or in the user's own
package, registered through the entry-point group ``seqmotion.tasks`` (:mod:`.registry`).

A **trained model** (:class:`TrainedModel`) is task-generic: ``generate`` (encode a motion and
decode it through the task's physics), ``decode`` (from a latent), ``generator`` (the decoder as
an online stepper fed measured states of the task's own size) and the differentiable maps that
latent optimisation uses. Tasks may subclass it for friendly verbs (``Deformer.deform``,
``SlidingPlanner.plan``).
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np
import torch

from ..data.trajectories import TrajectoryBatch
from ..errors import CheckpointError, as_float_array, as_trajectories, check_finite_result, check_number
from ..models.seq2seq import ChunkDynamics, ChunkedSeq2Seq, Seq2SeqConfig, rollout
from ..physics.layout import StateLayout
from ..training import checkpoint as ckpt
from ..training.config import TrainConfig
from ..training.curriculum import Curriculum
from ..training.pretrained import PretrainedModel
from . import registry
from .options import TaskOptions
from .stepper import OnlineGenerator, stepper_contract

MAX_LENGTH = 1_000_000
"""The longest motion ``decode`` generates (1000 s at 1 ms)."""
FEASIBLE_TOLERANCE = 0.01
"""A motion counts as feasible when its largest constraint violation is at most this."""


class Task(ABC):
    """A learning problem for the chunked seq2seq model (see the module docstring)."""

    name: ClassVar[str]
    presets: ClassVar[tuple[str, ...]] = ("tiny", "small", "paper")
    options_class: ClassVar[type[TaskOptions]] = TaskOptions
    input_layout: ClassVar[StateLayout]
    state_layout: ClassVar[StateLayout]
    accel_layout: ClassVar[StateLayout]
    physics_parameters: ClassVar[tuple[str, ...]] = ()
    """Keyword arguments :meth:`dynamics` accepts at inference (e.g. ``("mu", "mu_dyn")``); their
    defaults are the model's options."""
    end_pose: ClassVar[tuple[tuple[str, ...], tuple[float, ...]] | None] = None
    """``(state fields, weights)`` an end-pose objective reaches for, e.g. pancake
    ``(("y", "z", "theta"), (1, 1, 0.1))``; None: the task has no end pose."""
    model_class: ClassVar[type[TrainedModel] | None] = None
    """The user-facing class of the trained model (default :class:`TrainedModel`)."""

    # --- training ------------------------------------------------------------------------------

    @abstractmethod
    def train_config(self, preset: str) -> TrainConfig:
        """The named configuration (at least ``"tiny"`` for tests and ``"small"``)."""

    def curriculum(self, config: TrainConfig) -> Curriculum:
        """The run's schedule."""
        return Curriculum.from_dict(config.curriculum)

    @abstractmethod
    def sample(
        self, n: int, rng: np.random.Generator, params: dict[str, float], config: TrainConfig
    ) -> TrajectoryBatch:
        """Draw ``n`` training trajectories for the curriculum parameters ``params``."""

    @abstractmethod
    def loss(
        self,
        model: ChunkedSeq2Seq,
        batch: TrajectoryBatch,
        params: dict[str, float],
        config: TrainConfig,
        generator: torch.Generator,
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """Scalar loss to minimise and named terms to log (include ``"feasible"`` if meaningful)."""

    def build_model(self, config: TrainConfig) -> ChunkedSeq2Seq:
        model_config = Seq2SeqConfig.from_dict(config.model)
        self.check_model_config(model_config)
        return ChunkedSeq2Seq(model_config)

    def check_model_config(self, model_config: Seq2SeqConfig) -> None:
        """``ValueError`` unless the model reads the task's input layout and writes its accel layout."""
        reads, writes = model_config.encoder_input_dim, model_config.output_dim
        if reads != self.input_layout.dim or writes != self.accel_layout.dim:
            raise ValueError(
                f"task {self.name}: the model reads {model_config.encoder_input_dim} and writes "
                f"{model_config.output_dim} features, but the task's {self.input_layout} and {self.accel_layout} "
                "need " + f"{self.input_layout.dim} and {self.accel_layout.dim}"
            )

    # --- options ---------------------------------------------------------------------------------

    def options(self, config: TrainConfig | dict[str, Any] | None) -> TaskOptions:
        """The typed, checked options of a training config (or of an options dict)."""
        data = config.options if isinstance(config, TrainConfig) else config
        return self.options_class.from_dict(data)

    # --- physics ---------------------------------------------------------------------------------

    @abstractmethod
    def dynamics(self, options: TaskOptions, **physics: Any) -> ChunkDynamics:
        """The differentiable physics the decoder's loop runs through at inference."""

    def start_state(self, inputs: torch.Tensor) -> torch.Tensor:
        """Decoder start state ``(B, state_dim)`` for input motions ``(B, K, input_dim)``
        (default: their first sample)."""
        return inputs[:, 0]

    def violation(self, states: torch.Tensor, accel: torch.Tensor, options: TaskOptions) -> torch.Tensor | None:
        """The task's constraint violation per transition ``(B, K-1)`` (≥ 0, 0 where satisfied), differentiable.

        ``states`` ``(B, K, state_dim)``, ``accel`` ``(B, K-1, d)``. None: the task has no constraint.
        """
        return None

    def sketch(self, end: tuple[float, ...], length: int, timing: str = "s_curve") -> np.ndarray:
        """A rough input motion ``(K, input_dim)`` from the start to the end-pose values ``end`` (the
        CLI's default input for ``seqmotion optimize``); tasks without one refuse."""
        raise ValueError(f"task {self.name!r} has no default sketch; give the motion to adjust (--input)")

    def make_result(self, motion: Motion, model: TrainedModel) -> Any:
        """The result object ``generate`` returns (default: the :class:`Motion` itself)."""
        return motion

    # --- trained models ------------------------------------------------------------------------

    def wrap(self, model: ChunkedSeq2Seq, config: dict) -> TrainedModel:
        """The user-facing object for a trained model."""
        return (self.model_class or TrainedModel)(model, config, task=self)

    def load(self, directory: Any) -> TrainedModel:
        """The trained model stored in ``directory`` (verified)."""
        return (self.model_class or TrainedModel).from_pretrained(directory)


def first_of(result: Any) -> Any:
    """The same result dataclass with every array field indexed by ``[0]`` (drop a batch axis of 1)."""
    values = {f.name: getattr(result, f.name) for f in fields(result)}
    return type(result)(**{k: v if v is None or np.ndim(v) == 0 else v[0] for k, v in values.items()})


@dataclass
class Motion:
    """A generated motion (a leading B axis on every array for a batch).

    Attributes:
        states: ``(K, S)`` states in the task's ``state_layout``; ``states[0]`` is the start state.
        accel: ``(K-1, d)`` the decoder's outputs ``u[0..K-2]`` in the task's ``accel_layout``.
        latent: ``(L·H,)`` the latent z the motion was decoded from.
        violation: ``(K-1,)`` the task's constraint violation per transition (0 where it holds),
            or None for a task without a constraint.
    """

    states: np.ndarray
    accel: np.ndarray
    latent: np.ndarray
    violation: np.ndarray | None = None

    @property
    def feasible(self) -> np.ndarray | bool | None:
        """Whether the largest violation is ≤ 0.01 (per trajectory for a batch); None without a constraint."""
        if self.violation is None:
            return None
        ok = self.violation.max(axis=-1) <= FEASIBLE_TOLERANCE
        return bool(ok) if np.ndim(ok) == 0 else ok


class TrainedModel(PretrainedModel):
    """A trained chunked seq2seq model of any task: generate, decode, step online, optimise.

    Obtain one with ``sm.load(run_dir)`` or ``sm.load_pretrained(name)``. Everything task-specific
    (state size and names, physics, constraint, options) comes from ``self.task_def``.
    """

    config_class = Seq2SeqConfig

    def __init__(self, model: ChunkedSeq2Seq, config: dict, task: Task | None = None) -> None:
        self.model = model.eval()
        self.config = config
        self.task_def: Task = task if task is not None else registry.get(config["task"])
        if type(self).task is not None and self.task_def.name != type(self).task:
            raise CheckpointError(
                f"a {type(self).__name__} needs a {type(self).task!r} model, got {self.task_def.name!r}"
            )
        training = self.config.get("training", {})
        if not isinstance(training, dict):
            raise ValueError(f"the config's training record must be a JSON object, got {type(training).__name__}")
        self.options = self.task_def.options(training.get("options", {}))

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
            return task.wrap(model, config)
        except ValueError as exc:  # options the task refuses
            raise CheckpointError(f"{source}/config.json: {exc}") from None

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

    def check_physics(self, physics: dict[str, Any]) -> None:
        """Refuse inference-time physics parameters the task's dynamics do not take, by name."""
        unknown = sorted(set(physics) - set(self.task_def.physics_parameters))
        if unknown:
            allowed = list(self.task_def.physics_parameters) or "none"
            raise ValueError(
                f"the {self.task_def.name!r} model's dynamics take no parameter(s) {unknown} (they take: {allowed}); "
                f"its options are {self.options.to_dict()} — options such as mu are fixed when the model is trained"
                + (" (objectives take their own mu=...)" if "mu" in unknown else "")
            )

    def dynamics(self, **physics: Any) -> ChunkDynamics:
        """The :class:`~seqmotion.models.seq2seq.ChunkDynamics` the decoder runs with (options' physics
        unless ``physics`` overrides what the task allows)."""
        self.check_physics(physics)
        return self.task_def.dynamics(self.options, **physics)

    def start_state(self, inputs: torch.Tensor) -> torch.Tensor:
        """Decoder start state ``(B, state_dim)`` for input trajectories ``(B, K, input_dim)``."""
        return self.task_def.start_state(inputs)

    def violation_torch(self, states: torch.Tensor, accel: torch.Tensor) -> torch.Tensor | None:
        """The task's constraint violation ``(B, K-1)`` at this model's options (None: no constraint)."""
        return self.task_def.violation(states, accel, self.options)

    # --- differentiable maps (latent optimisation works on these) -------------------------------

    def encode_torch(self, inputs: torch.Tensor) -> torch.Tensor:
        """``(B, K, input_dim)`` → latents ``(B, L·H)``."""
        return self.model.encode(inputs.float())

    def decode_torch(
        self, latent: torch.Tensor, x0: torch.Tensor, length: int, **physics: Any
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Decode latents from start states into ``(states (B, K, S), accel (B, K-1, d))``, differentiably.

        The physics runs in the dtype of ``x0`` (float64 gives exact bookkeeping).
        """
        out = rollout(self.model, latent, x0, self.dynamics(**physics), self.model.num_chunks(length), need_cov=False)
        return out.states[:, :length], out.accel[:, : length - 1].to(x0.dtype)

    def integrate_torch(self, x0: torch.Tensor, accel: torch.Tensor, **physics: Any) -> torch.Tensor:
        """States ``(B, N+1, S)`` that accelerations ``(B, N, d)`` produce from ``x0`` through the task's physics."""
        dynamics = self.dynamics(**physics)
        _, out = dynamics.step(dynamics.start(x0), accel.to(x0.dtype), None)
        return torch.cat([x0.unsqueeze(1), out["states"]], dim=1)

    # --- NumPy API -----------------------------------------------------------------------------

    def generate(self, inputs: object, **physics: Any) -> Any:
        """Encode ``(K, input_dim)`` or ``(B, K, input_dim)`` motions (any K ≥ 2) and decode them
        through the task's physics: the task's result (a :class:`Motion` unless the task says otherwise).

        Raises:
            ValueError: wrong shape, K < 2, NaN or inf, a physics parameter the task does not take.
        """
        self.check_physics(physics)
        batch, single = as_trajectories(inputs, self.input_dim, self.input_layout.kind)
        with torch.inference_mode():
            x = torch.from_numpy(batch)
            z = self.encode_torch(x)
            result = self._decode(z, self.start_state(x).double(), batch.shape[1], physics)
        return first_of(result) if single else result

    def decode(self, latent: object, x0: object, length: int, **physics: Any) -> Any:
        """Decode latents ``(L·H,)``/``(B, L·H)`` from start states ``(S,)``/``(B, S)`` into ``length`` samples."""
        length = check_number("length", length, minimum=2, maximum=MAX_LENGTH, integer=True)
        self.check_physics(physics)
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
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(start))):
            raise ValueError("latent and x0 must be finite (NaN or inf given)")
        return torch.from_numpy(z), start, single

    def _decode(self, z: torch.Tensor, x0: torch.Tensor, length: int, physics: dict[str, Any]) -> Any:
        states, accel = self.decode_torch(z, x0.double(), length, **physics)
        violation = self.violation_torch(states, accel)
        states_np = check_finite_result(states.numpy(), f"{self.task_def.name} generation")
        motion = Motion(states_np, accel.numpy(), z.float().numpy(), None if violation is None else violation.numpy())
        return self.task_def.make_result(motion, self)

    def generator(
        self, inputs: object | None = None, *, latent: object | None = None, x0: object | None = None,
        length: int | None = None, replan: bool = True, **physics: Any
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
                z = self.encode_torch(x).numpy()
                start = self.start_state(x).double().numpy()
            length = batch.shape[1] if length is None else length
        elif latent is not None and x0 is not None:
            z_t, start, single = self._latent_and_start(latent, x0)
            z = z_t.numpy()
        else:
            raise ValueError("give either the input motion, or both latent and x0")
        dynamics = self.dynamics(**physics)
        return OnlineGenerator(self.model, dynamics, stepper_contract(self, dynamics), z, start, single,
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


__all__ = ["FEASIBLE_TOLERANCE", "Motion", "OnlineGenerator", "Task", "TrainConfig", "TrainedModel", "first_of"]
