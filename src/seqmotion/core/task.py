"""The task contract: what a task author writes (see ``docs/write-a-task.md``).

A **task** (:class:`Task`) is physics + input generators + loss + curriculum, wired to the shared
chunked seq2seq model. It declares:

* its **layouts** — the named columns and units of the motions the encoder reads
  (``input_layout``), of the states the decoder generates in closed loop (``state_layout``)
  and of the decoder's outputs (``accel_layout``);
* its **options** — a validated dataclass (:mod:`.options`) saved with the model;
* its *physics* — :meth:`Task.dynamics` (the differentiable ``ChunkDynamics`` the decoder runs
  with), :meth:`Task.start_state`, and optionally :meth:`Task.violation` (its constraint, 0 where
  satisfied) and ``end_pose`` (the fields and weights an end-pose objective reaches for);
* its **training** — presets (:meth:`Task.train_config`; as data: :attr:`Task.preset_table` of
  :class:`Preset`, with the network's scales as class attributes, :meth:`Task.model_config`), data
  (:meth:`Task.sample`) and loss (:meth:`Task.loss`; the standard one, :meth:`Task.standard_loss`, is the
  shape likelihood plus the weighted constraint violation, built from :mod:`seqmotion.training.losses`).

A task lives in ``seqmotion/tasks/`` (a module or a folder defining ``TASK``) or in the user's own
package, registered through the entry-point group ``seqmotion.tasks`` (:mod:`.registry`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import torch

from ..data.trajectories import TensorBatch, TrajectoryBatch
from ..models.seq2seq import ChunkDynamics, ChunkedSeq2Seq, Rollout, Seq2SeqConfig
from ..physics.integrator import DoubleIntegratorDynamics, integrate_covariance
from ..physics.layout import StateLayout
from ..physics.parameters import Physics
from ..training.config import TrainConfig
from ..training.curriculum import Curriculum, CurriculumParams, Stage
from ..training.losses import (
    encode_and_rollout,
    masked_mean,
    per_trajectory,
    sample_mask,
    weighted_gaussian_nll,
)
from .options import TaskOptions
from .polish import ExactForm
from .results import FEASIBLE_TOLERANCE, Motion
from .trained import TrainedModel


@dataclass(frozen=True)
class Preset:
    """A named training configuration as data (:attr:`Task.preset_table`; :meth:`Task.train_config` builds it).

    Attributes:
        layers, hidden, chunk: the model's LN-LSTM layers, their width and the samples per step C.
        batches_per_epoch, batch_size: the data volume per epoch.
        head_hidden: the width of the Gaussian head's hidden layer (0: none).
        epochs: the task's curriculum (:meth:`Task.preset_curriculum`) squeezed or stretched to this many epochs
            (:meth:`Curriculum.scaled`); None: as it is.
        options: the task's options that differ from their defaults (``{"length": (100, 200)}``).
    """

    layers: int
    hidden: int
    chunk: int
    batches_per_epoch: int
    batch_size: int
    head_hidden: int = 0
    epochs: int | None = None
    options: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class TeacherForcingParams(CurriculumParams):
    """The standard curriculum's one parameter (:meth:`Task.preset_curriculum`): the share of teacher-forced
    chunks."""

    teacher_forcing_prob: float


def teacher_forcing_curriculum() -> Curriculum:
    """The standard schedule: 40 epochs, every chunk teacher-forced until epoch 5, none from epoch 15."""
    return Curriculum(epochs=40, initial={"teacher_forcing_prob": 1.0},
                      stages=[Stage(5, 15, {"teacher_forcing_prob": [1.0, 0.0]})])


class Task(ABC):
    """A learning problem for the chunked seq2seq model (see the module docstring)."""

    name: ClassVar[str]
    presets: ClassVar[tuple[str, ...]] = ("tiny", "small", "paper")
    options_class: ClassVar[type[TaskOptions]] = TaskOptions
    input_layout: ClassVar[StateLayout]
    state_layout: ClassVar[StateLayout]
    accel_layout: ClassVar[StateLayout]
    physics_class: ClassVar[type[Physics]] = Physics
    """The task's physics parameters (:mod:`seqmotion.physics.parameters`): a frozen dataclass, resolved
    from the options by :meth:`physics` and recorded on every result (default: none)."""
    params_class: ClassVar[type[CurriculumParams]] = CurriculumParams
    """The typed curriculum parameters :meth:`sample` and :meth:`loss` receive (one field per name the
    curriculum sets)."""
    end_pose: ClassVar[tuple[tuple[str, ...], tuple[float, ...]] | None] = None
    """``(state fields, weights)`` an end-pose objective reaches for, e.g. pancake
    ``(("y", "z", "theta"), (1, 1, 0.1))``; None: the task has no end pose."""
    model_class: ClassVar[type[TrainedModel] | None] = None
    """The user-facing class of the trained model (default :class:`TrainedModel`)."""
    uncertainty_fields: ClassVar[tuple[str, ...] | None] = None
    """The state fields whose covariance the dynamics' ``pos_cov`` output holds (a result's
    ``uncertainty`` columns); None: the first p fields of ``state_layout``."""
    preset_table: ClassVar[dict[str, Preset]] = {}
    """The presets :meth:`train_config` builds, by name (a task that sets it has :attr:`presets` its names)."""
    input_scale: ClassVar[tuple[float, ...] | None] = None
    """The typical size of each ``input_layout`` column in its unit: the encoder reads ``input / input_scale``
    (:meth:`model_config`; None: 1)."""
    state_scale: ClassVar[tuple[float, ...] | None] = None
    """The same for each ``state_layout`` column, which the decoder reads (None: 1)."""
    output_scale: ClassVar[tuple[float, ...] | None] = None
    """The same for each ``accel_layout`` column: ``output = output_offset + output_scale · raw`` (None: 1)."""
    output_offset: ClassVar[tuple[float, ...] | None] = None
    """Each ``accel_layout`` column's value for a raw output of 0 (None: 0)."""
    correlated_pairs: ClassVar[tuple[tuple[int, int], ...] | None] = None
    """Pairs of ``accel_layout`` columns whose correlation the Gaussian head learns (None: the model's default)."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "preset_table" in cls.__dict__ and "presets" not in cls.__dict__:
            cls.presets = tuple(cls.preset_table)

    # --- training ------------------------------------------------------------------------------

    def train_config(self, preset: str) -> TrainConfig:
        """The named configuration (at least ``"tiny"`` for tests and ``"small"``). Default: the preset of
        :attr:`preset_table` — :meth:`model_config` of its size, :meth:`preset_curriculum` (scaled to its
        ``epochs``), its batches and its options over the options' defaults.

        Raises:
            ValueError: a preset the task does not have.
        """
        spec = self.preset_table.get(preset)
        if spec is None:
            raise ValueError(f"unknown preset {preset!r} for task {self.name}; choose from {self.presets}")
        curriculum = self.preset_curriculum()
        if spec.epochs is not None:
            curriculum = curriculum.scaled(spec.epochs)
        model = self.model_config(spec.layers, spec.hidden, spec.chunk, spec.head_hidden)
        return TrainConfig(task=self.name, preset=preset, model=model.to_dict(), curriculum=curriculum.to_dict(),
                           batches_per_epoch=spec.batches_per_epoch, batch_size=spec.batch_size,
                           options=self.options_class(**spec.options).to_dict())

    def preset_curriculum(self) -> Curriculum:
        """The schedule :meth:`train_config`'s presets train with. Default: teacher forcing fading out
        (:func:`teacher_forcing_curriculum`; its parameter is :class:`TeacherForcingParams`'s)."""
        return teacher_forcing_curriculum()

    def model_config(self, layers: int, hidden: int, chunk: int, head_hidden: int = 0) -> Seq2SeqConfig:
        """The model for this task's layouts: the encoder reads ``input_layout``, the decoder the states of
        ``state_layout`` (as they are: a task whose dynamics map them in ``decoder_input`` overrides this) and it
        writes ``accel_layout``, each scaled by the class's ``*_scale`` (network numbers near 1); ``layers`` LN-LSTM
        layers of ``hidden`` cells, ``chunk`` samples per step, a head hidden layer of ``head_hidden`` (0: none)."""

        def listed(values: tuple | None) -> list | None:
            return None if values is None else [list(v) if isinstance(v, tuple | list) else float(v) for v in values]

        return Seq2SeqConfig(
            encoder_input_dim=self.input_layout.dim, decoder_input_dim=self.state_layout.dim,
            output_dim=self.accel_layout.dim, chunk=chunk, layers=layers, hidden=hidden, head_hidden=head_hidden,
            correlated_pairs=listed(self.correlated_pairs), encoder_input_scale=listed(self.input_scale),
            decoder_input_scale=listed(self.state_scale), output_scale=listed(self.output_scale),
            output_offset=listed(self.output_offset),
        )

    def curriculum(self, config: TrainConfig) -> Curriculum:
        """The run's schedule."""
        return Curriculum.from_dict(config.curriculum)

    def params(self, values: dict[str, float]) -> CurriculumParams:
        """The typed curriculum parameters for the values :meth:`Curriculum.at` gives."""
        return self.params_class.from_values(values)

    @abstractmethod
    def sample(self, n: int, rng: np.random.Generator, params: Any, options: Any) -> TrajectoryBatch:
        """Draw ``n`` training trajectories (NumPy) for the curriculum parameters ``params`` (a
        :attr:`params_class`) and the task's ``options`` (an :attr:`options_class`)."""

    def loss(
        self, model: ChunkedSeq2Seq, batch: TensorBatch, dynamics: Any, params: Any, options: Any,
        generator: torch.Generator,
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """Scalar loss to minimise and named terms to log (include ``"feasible"`` if meaningful).

        The trainer hands over ``batch`` already on the model's device (:meth:`TrajectoryBatch.to`), the
        task's ``dynamics`` built once from its options (:meth:`dynamics` at :meth:`physics`), the typed
        curriculum ``params`` and ``options``, and the step's random ``generator`` (teacher forcing's coins).
        Default: :meth:`standard_loss` of :meth:`rollout`.
        """
        return self.standard_loss(self.rollout(model, batch, dynamics, params, generator), batch, options)

    def rollout(self, model: ChunkedSeq2Seq, batch: TensorBatch, dynamics: Any, params: Any,
                generator: torch.Generator) -> Rollout:
        """The model's closed loop over ``batch`` from :meth:`start_state`, each chunk teacher-forced by the
        batch's states with probability ``params.teacher_forcing_prob`` (0 where the curriculum has none) — for a
        task whose input layout is its state layout."""
        states, lengths = batch.states, batch.lengths
        return encode_and_rollout(model, states, lengths, self.start_state(states), dynamics, teacher=states,
                                  teacher_forcing_prob=getattr(params, "teacher_forcing_prob", 0.0),
                                  generator=generator)

    def standard_loss(self, out: Rollout, batch: TensorBatch, options: Any) -> tuple[torch.Tensor, dict[str, float]]:
        """The shape likelihood plus the weighted constraint violation, per trajectory, averaged over the batch —
        for a task whose input layout is its state layout:
        ``mean_k alpha_shape · NLL(x[k] | x̂[k], S[k] + floor) + alpha_constraint · violation[k]``, x the position
        columns the dynamics' ``pos_cov`` ``(B, K-1, p, p)`` is of (:attr:`uncertainty_fields`, else the first p),
        ``floor`` the option ``variance_floor``; ``alpha_shape``, ``alpha_constraint`` options too (default 1).

        Returns:
            ``(loss, terms)``: ``L1`` the mean NLL, and with a constraint (:meth:`violation`) ``L2`` the mean
            violation and ``feasible`` the share of trajectories within the ``max_violation`` tolerance
            (:meth:`tolerances`).
        """
        states, lengths = batch.states, batch.lengths
        k_max = states.shape[1]
        valid = sample_mask(lengths, k_max)
        cov = out.outputs["pos_cov"][:, : k_max - 1]
        p = cov.shape[-1]
        gap = (states - out.states[:, :k_max])[:, 1:]
        if self.uncertainty_fields is None:
            diff = gap[..., :p]
        else:
            diff = gap[..., [self.state_layout.index(name) for name in self.uncertainty_fields]]
        floor = getattr(options, "variance_floor", None)
        nll = weighted_gaussian_nll(diff, cov, **({} if floor is None else {"floor": floor}))
        shape = getattr(options, "alpha_shape", 1.0) * nll
        violation = self.violation(out.states[:, :k_max], out.accel[:, : k_max - 1], options)
        if violation is None:
            return per_trajectory(shape, valid, lengths).mean(), {"L1": masked_mean(nll, valid)}
        violation = violation * valid
        loss = per_trajectory(shape + getattr(options, "alpha_constraint", 1.0) * violation, valid, lengths).mean()
        tolerance = self.tolerances(options).get("max_violation", FEASIBLE_TOLERANCE)
        feasible = (violation.detach().amax(1) <= tolerance).float().mean()
        return loss, {"L1": masked_mean(nll, valid), "L2": masked_mean(violation, valid), "feasible": float(feasible)}

    def example_inputs(self, n: int, seed: int = 0) -> np.ndarray:
        """``n`` input motions ``(n, K, input_dim)`` like those the task trains on, of one length K (docs,
        tests, the viewer and ``calibrate-trust`` use them). Default: the training generator at the end of
        the ``small`` preset's curriculum (else the first preset's), each cut to the shortest of the draw."""
        config = self.train_config("small" if "small" in self.presets else self.presets[0])
        params = self.params(Curriculum.from_dict(config.curriculum).final())
        batch = self.sample(n, np.random.default_rng(seed), params, self.options(config))
        return np.asarray(batch.states[:, : int(np.min(batch.lengths))], dtype=np.float64)

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

    def physics(self, options: TaskOptions) -> Physics:
        """The physics a model with these options runs at by default: each field of :attr:`physics_class`
        from the option of the same name (sliding: ``options.mu``, ``options.mu_dyn``), else its default."""
        names = self.physics_class.names()
        return self.physics_class.from_dict({n: getattr(options, n) for n in names if hasattr(options, n)})

    @abstractmethod
    def dynamics(self, options: TaskOptions, physics: Physics) -> ChunkDynamics:
        """The differentiable physics the decoder's loop runs through, at ``physics`` (a :attr:`physics_class`)."""

    def physics_trained(self, options: TaskOptions) -> dict[str, tuple[float, float]]:
        """The (lowest, highest) value of the fields of :attr:`physics_class` that the task's own :meth:`sample` draws
        per trajectory (sliding: the friction of each command), at ``options``. Override it when ``sample`` varies
        the physics; :meth:`physics_trained_over` covers the other fields. Default: none."""
        return {}

    def physics_trained_over(self, config: TrainConfig) -> dict[str, tuple[float, float]]:
        """The (lowest, highest) value of every field of :attr:`physics_class` a training by ``config`` meets: the
        trainer records it in the model's ``config.json`` (``physics_trained``), and a generation at physics beyond
        it (by the trust margin) is out of distribution.

        Per field: the range :meth:`physics_trained` gives, else the span of the curriculum parameter of the same
        name, else the one value the training ran at (:meth:`physics` of the config's options).
        """
        options = self.options(config)
        curriculum = self.curriculum(config)
        spans = {name: curriculum.span(name) if name in curriculum.initial else (value, value)
                 for name, value in self.physics(options).to_dict().items()}
        drawn = {name: (float(low), float(high)) for name, (low, high) in self.physics_trained(options).items()}
        return {**spans, **drawn}

    def start_state(self, inputs: torch.Tensor) -> torch.Tensor:
        """Decoder start state ``(B, state_dim)`` for input motions ``(B, K, input_dim)``
        (default: their first sample)."""
        return inputs[:, 0]

    def violation(self, states: torch.Tensor, accel: torch.Tensor, options: TaskOptions) -> torch.Tensor | None:
        """The task's constraint violation per transition ``(B, K-1)`` (≥ 0, 0 where satisfied), differentiable.

        ``states`` ``(B, K, state_dim)``, ``accel`` ``(B, K-1, d)``. None: the task has no constraint.
        """
        return None

    def exact_form(self, options: TaskOptions) -> ExactForm | None:
        """What an exact polish needs (:class:`ExactForm`), or None: ``exact=True`` and ``keep_end=True``
        are then refused for this task."""
        return None

    def sketch(self, end: tuple[float, ...], length: int, timing: str = "s_curve") -> np.ndarray:
        """A rough input motion ``(K, input_dim)`` from the start to the end-pose values ``end`` (the
        CLI's default input for ``seqmotion optimize``); tasks without one refuse."""
        raise ValueError(f"task {self.name!r} has no default sketch; give the motion to adjust (--input)")

    def make_result(self, motion: Motion, model: TrainedModel) -> Any:
        """The result object ``generate`` returns (default: the :class:`Motion` itself)."""
        return motion

    # --- trust signals (:mod:`.trust`) ------------------------------------------------------------

    def input_features(self, inputs: np.ndarray, lengths: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Cheap features of ``(B, K, input_dim)`` inputs, each ``(B,)``, that the out-of-distribution flag
        compares with training (default: length, extent, peak speed and implied acceleration per unit
        group of ``input_layout``: :func:`seqmotion.tasks.trust.input_features`)."""
        from .trust import input_features

        return input_features(self.input_layout, inputs, lengths)

    def errors(
        self, inputs: np.ndarray, states: np.ndarray, accel: np.ndarray, violation: np.ndarray | None,
        options: TaskOptions,
    ) -> dict[str, np.ndarray]:
        """The errors a user judges a generated motion by, each ``(B,)`` (SI units in the name).

        ``inputs`` ``(B, K, input_dim)``, ``states`` ``(B, K, S)``, ``accel`` ``(B, K-1, d)``, ``violation``
        ``(B, K-1)`` or None. Default, for a task whose input layout is its state layout:
        ``shape_rmse_m`` (RMS over samples of the metre fields' distance from the input),
        ``end_position_error_m``, ``end_attitude_error_rad`` (largest over radian fields),
        ``end_speed_m_s`` (the generated motion's, metres per second fields) and ``max_violation``.
        """
        out: dict[str, np.ndarray] = {}
        units = self.state_layout.units
        if self.input_layout.names == self.state_layout.names:
            metres = [i for i, u in enumerate(units) if u == "m"]
            radians = [i for i, u in enumerate(units) if u == "rad"]
            if metres:
                gap = np.linalg.norm(states[..., metres] - inputs[..., metres], axis=-1)
                out["shape_rmse_m"] = np.sqrt((gap**2).mean(axis=-1))
                out["end_position_error_m"] = gap[:, -1]
            if radians:
                out["end_attitude_error_rad"] = np.abs(states[:, -1, radians] - inputs[:, -1, radians]).max(axis=-1)
        speeds = [i for i, u in enumerate(units) if u == "m/s"]
        if speeds:
            out["end_speed_m_s"] = np.linalg.norm(states[:, -1, speeds], axis=-1)
        if violation is not None:
            out["max_violation"] = violation.max(axis=-1) if violation.shape[-1] else np.zeros(len(states))
        return out

    def position_cov(
        self, accel_cov: torch.Tensor, states: torch.Tensor, accel: torch.Tensor, outputs: dict[str, torch.Tensor],
        dynamics: ChunkDynamics,
    ) -> torch.Tensor | None:
        """The covariance ``(B, K-1, p, p)`` of the positions of states ``1..K-1`` from the decoder's input
        covariances ``accel_cov`` ``(B, K-1, d, d)`` propagated through the physics from a known start —
        what the dynamics' ``pos_cov`` output holds, computed once over the whole motion.

        ``states`` ``(B, K, S)``, ``accel`` ``(B, K-1, d)`` and the dynamics' other ``outputs`` (first K-1
        samples) are the motion's. Default: the closed form of the double integrator
        (:func:`seqmotion.physics.integrator.integrate_covariance`) when the task's dynamics is one; None (the
        chunk-by-chunk propagation is used) otherwise.
        """
        if isinstance(dynamics, DoubleIntegratorDynamics):
            return integrate_covariance(accel_cov, dynamics.dt)
        return None

    def tolerances(self, options: TaskOptions) -> dict[str, float]:
        """Error name → the largest value a user accepts; a result beyond one gets a warning (default:
        ``max_violation`` ≤ :data:`FEASIBLE_TOLERANCE`)."""
        return {"max_violation": FEASIBLE_TOLERANCE}

    # --- trained models ------------------------------------------------------------------------

    def wrap(self, model: ChunkedSeq2Seq, config: dict) -> TrainedModel:
        """The user-facing object for a trained model."""
        return (self.model_class or TrainedModel)(model, config, task=self)

    def load(self, directory: Any) -> TrainedModel:
        """The trained model stored in ``directory`` (verified)."""
        return (self.model_class or TrainedModel).from_pretrained(directory)
