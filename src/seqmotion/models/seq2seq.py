"""The chunked sequence-to-sequence model (Figs. 2.2, 2.4, 3.2–3.4; SPEC §§1–2).

**Encoder.** Step κ reads the chunk ``x[Cκ : C(κ+1)-1]`` flattened (C × state features),
through a linear layer into L stacked LN-LSTM layers. The latent ``z`` is the encoder's final
memory: the cell states ``c`` of its L layers, concatenated (L·H numbers — 128 for 2 × 64,
as in ch. 4.3.1). It is *exactly* what initialises the decoder: decoder layer l starts
with ``c_l = z_l`` and ``h_l = 0``.

**Decoder.** Step k reads the last C generated states (the first step reads
``(x[0], …, x[0])``, eq. 2.12) and emits the next C inputs as Gaussians: means and
covariances ``S_u`` (σ per dimension, correlation ρ for declared pairs, eq. 2.11).

**Rollout.** :func:`rollout` closes the loop through a task's differentiable
:class:`ChunkDynamics`: the C means are integrated (with their covariances) into the next
C states, which feed the next decoder step — or, with probability ``teacher_forcing_prob``
per trajectory and step, the true states do (scheduled sampling, ref. [24]). With dynamics that
propagate covariances entrywise (the double integrator), the loop carries the means only and all
chunks' covariances are made and propagated at once afterwards (same numbers, far fewer operations).

Sequences of any length K ≥ 2 are handled: the encoder freezes a trajectory's state after
its last (partly padded) chunk, so a trajectory's ``z`` does not depend on what it was
batched with; the decoder runs ``ceil(K / C)`` steps and callers keep the first K samples.

Physical units are converted to network scale inside the model (``*_scale`` in the config),
so everything outside speaks metres, radians and seconds.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Protocol, TypeVar

import torch
from torch import nn

from ..errors import check_json_number
from .lstm import LSTMState, StackedLSTM

DEFAULT_CHUNK = 50
"""C, the samples one decoder step emits, unless a task's model config says otherwise (SPEC §1)."""
SIZE_BOUNDS = {
    "encoder_input_dim": 4096,
    "decoder_input_dim": 4096,
    "output_dim": 1024,
    "chunk": 100_000,
    "layers": 64,
    "hidden": 65_536,
    "head_hidden": 65_536,
}
"""Upper bounds of a config's sizes: far beyond any model, low enough that a corrupt config cannot ask for
absurd allocations (loading also compares every size with the weights before anything is allocated)."""
MAX_LAYER_WEIGHTS = 2**31
"""The largest input layer (chunk × features × hidden weights) a config may describe."""
SCALE_BUFFERS = {
    "encoder_input_scale": "encoder_scale",
    "decoder_input_scale": "decoder_scale",
    "output_scale": "head.scale",
    "output_offset": "head.offset",
}
"""Config field → the buffer of :class:`ChunkedSeq2Seq` that holds it in the weights. The network computes with
the buffer, everything built from the config (the online stop's acceleration limits, a deployment contract)
reads the field: loading weights refuses a buffer that differs from its field."""


@dataclass
class Seq2SeqConfig:
    """Architecture of a chunked seq2seq model (JSON-serialisable).

    Attributes:
        encoder_input_dim: features per sample read by the encoder.
        decoder_input_dim: features per sample read by the decoder.
        output_dim: d, the dimension of the generated input (acceleration) per sample.
        chunk: C, samples per encoder/decoder step.
        layers, hidden: L stacked LN-LSTM layers of H cells, in the encoder and in the decoder.
        head_hidden: width of an extra tanh linear layer before the Gaussian head (0: none;
            500 in ch. 3).
        correlated_pairs: index pairs of output dimensions with a learned correlation ρ
            (``[[0, 1]]``: ρ_yz in ch. 2, ρ_xy in ch. 3). Default (None): ``[[0, 1]]`` when
            ``output_dim`` ≥ 2, none for a single output.
        encoder_input_scale, decoder_input_scale: divide the inputs by these per feature.
        output_scale, output_offset: ``mean = offset + scale * raw`` per output dimension;
            σ is in the same scale.
        sigma_min: lower bound of σ as a fraction of ``output_scale`` (keeps S_u positive definite).
    """

    encoder_input_dim: int
    decoder_input_dim: int
    output_dim: int
    chunk: int = DEFAULT_CHUNK
    layers: int = 2
    hidden: int = 64
    head_hidden: int = 0
    correlated_pairs: list[list[int]] | None = None
    encoder_input_scale: list[float] | None = None
    decoder_input_scale: list[float] | None = None
    output_scale: list[float] | None = None
    output_offset: list[float] | None = None
    sigma_min: float = 1e-3

    def __post_init__(self) -> None:
        """Check the config as a schema before anything is built: types, ranges and sizes.

        Raises:
            ValueError: naming the first bad field.
        """
        for name, bound in SIZE_BOUNDS.items():
            value, low = getattr(self, name), 0 if name == "head_hidden" else 1
            try:
                check_json_number(name, value, minimum=low, maximum=bound, integer=True)
            except ValueError:  # one message for every way a size is wrong: it states the range
                raise ValueError(f"{name} must be an integer in [{low}, {bound}], got {value!r}") from None
        if self.chunk * max(self.encoder_input_dim, self.decoder_input_dim) * self.hidden > MAX_LAYER_WEIGHTS:
            raise ValueError(
                f"chunk × input features × hidden = {self.chunk} × "
                f"{max(self.encoder_input_dim, self.decoder_input_dim)} × {self.hidden} is beyond any model "
                f"({MAX_LAYER_WEIGHTS} weights per layer)"
            )
        if self.correlated_pairs is None:
            # The default follows the output size: a single output has no pair to correlate, and a saved
            # config always holds the resolved list, so shipped models load as they were written.
            self.correlated_pairs = [[0, 1]] if self.output_dim >= 2 else []
        if not isinstance(self.correlated_pairs, list | tuple):
            raise ValueError(f"correlated_pairs must be a list of [i, j] pairs, got {self.correlated_pairs!r}")
        for pair in self.correlated_pairs:
            if (
                not isinstance(pair, list | tuple)
                or len(pair) != 2
                or not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < self.output_dim for i in pair)
                or pair[0] == pair[1]
            ):
                raise ValueError(f"correlated pair {pair} is not two distinct output dimensions")
        dims = {
            "encoder_input_scale": self.encoder_input_dim,
            "decoder_input_scale": self.decoder_input_dim,
            "output_scale": self.output_dim,
            "output_offset": self.output_dim,
        }
        for name, dim in dims.items():
            value = getattr(self, name)
            if value is None:
                continue
            if not isinstance(value, list | tuple) or len(value) != dim:
                raise ValueError(f"{name} needs {dim} entries, got {value!r}")
            scales = name != "output_offset"  # they divide or scale: > 0
            for v in value:
                check_json_number(f"{name} entries", v, minimum=0.0 if scales else None, strict_minimum=scales)
        check_json_number("sigma_min (it keeps S_u positive definite)", self.sigma_min, minimum=0.0,
                          strict_minimum=True)

    @property
    def latent_dim(self) -> int:
        return self.layers * self.hidden

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> Seq2SeqConfig:
        """The config ``to_dict`` wrote, checked (``ValueError`` for anything else: unknown or missing keys,
        bad values)."""
        if not isinstance(data, dict):
            raise ValueError(f"a model config must be a JSON object, got {type(data).__name__}")
        try:
            return cls(**data)
        except TypeError as exc:
            raise ValueError(f"not a model config: {exc}") from None

    def parameter_shapes(self) -> dict[str, tuple[int, ...]]:
        """Name → shape of every tensor of the model this config describes, without allocating it
        (built on PyTorch's ``meta`` device)."""
        with torch.device("meta"):
            module = ChunkedSeq2Seq(self)
        return {k: tuple(v.shape) for k, v in module.state_dict().items()}


class GaussianHead(nn.Module):
    """Maps a decoder output to C Gaussian inputs: means ``(B, C, d)`` and covariances ``(B, C, d, d)``."""

    def __init__(self, cfg: Seq2SeqConfig) -> None:
        super().__init__()
        self.chunk, self.dim = cfg.chunk, cfg.output_dim
        self.pairs = [tuple(p) for p in cfg.correlated_pairs]
        self.per_sample = 2 * self.dim + len(self.pairs)
        width = cfg.hidden
        layers: list[nn.Module] = []
        if cfg.head_hidden:
            layers += [nn.Linear(width, cfg.head_hidden), nn.Tanh()]
            width = cfg.head_hidden
        layers.append(nn.Linear(width, self.chunk * self.per_sample))
        self.net = nn.Sequential(*layers)
        with torch.no_grad():  # start from small accelerations and moderate σ
            self.net[-1].weight.mul_(0.1)
            self.net[-1].bias.zero_()
        self.sigma_min = cfg.sigma_min
        self.register_buffer("scale", torch.tensor(cfg.output_scale or [1.0] * self.dim))
        self.register_buffer("offset", torch.tensor(cfg.output_offset or [0.0] * self.dim))

    def forward(self, h: torch.Tensor, need_cov: bool = True) -> tuple[torch.Tensor, torch.Tensor | None]:
        raw = self.raw(h)
        mean = self.mean(raw)
        if not need_cov:
            return mean, None
        return mean, self.expand(self.entries(raw))

    # The pieces of forward, for a rollout that decodes the means chunk by chunk and the covariances once.

    def raw(self, h: torch.Tensor) -> torch.Tensor:
        """The head's raw output ``(B, C, 2d + pairs)`` for decoder outputs ``h`` (B, hidden)."""
        out = self.net(h)
        # -1, not h.shape[0]: a traced graph then reads no shape at run time (torch cannot infer -1 for 0 rows)
        return out.reshape(-1, self.chunk, self.per_sample) if len(out) else out.view(0, self.chunk, self.per_sample)

    def mean(self, raw: torch.Tensor) -> torch.Tensor:
        """Means ``(..., d)`` of raw outputs ``(..., 2d + pairs)``."""
        return self.offset + self.scale * raw[..., : self.dim]

    @property
    def entry_index(self) -> list[tuple[int, int]]:
        """The entries of ``S_u`` that can be non-zero, in the order :meth:`entries` gives them: the variances
        ``(i, i)``, then the declared pairs ``(i, j)`` (i.e. ``(j, i)`` too: ``S_u`` is symmetric)."""
        return [(i, i) for i in range(self.dim)] + list(self.pairs)

    def split(self, raw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Raw outputs ``(..., 2d + pairs)`` → ``(the means' part (..., d), the covariances' part (..., d + pairs))``
        (one split: its gradient is one concatenation, where slices would each fill a zero tensor)."""
        first, rest = raw.split([self.dim, self.per_sample - self.dim], dim=-1)
        return first, rest

    def mean_of(self, first: torch.Tensor) -> torch.Tensor:
        """Means ``(..., d)`` from the means' part of raw outputs."""
        return self.offset + self.scale * first

    def entries(self, raw: torch.Tensor, dim: int = -1) -> torch.Tensor:
        """The non-zero entries of ``S_u`` ``(..., d + pairs)`` (:attr:`entry_index`) of raw outputs: ``σ_i²``
        and ``ρ σ_i σ_j`` (eq. 2.11); ``dim``: where the entries' axis goes (1: ``(B, E, K)``)."""
        return self.entries_of(self.split(raw)[1], dim)

    def entries_of(self, rest: torch.Tensor, dim: int = -1) -> torch.Tensor:
        """:meth:`entries` from the covariances' part of raw outputs (:meth:`split`)."""
        sigma_raw, rho_raw = rest.split([self.dim, len(self.pairs)], dim=-1)
        # softplus of a contiguous copy: PyTorch's strided softplus runs ~6x slower than copy + vectorised
        sigma = self.scale * (nn.functional.softplus(sigma_raw.contiguous()) + self.sigma_min)
        s = sigma.unbind(-1)  # unbind: one stack in the backward pass instead of a zero fill per slice
        values = [s[i] ** 2 for i in range(self.dim)]
        if self.pairs:
            r = (0.99 * torch.tanh(rho_raw)).unbind(-1)
            values += [r[p] * s[i] * s[j] for p, (i, j) in enumerate(self.pairs)]
        return torch.stack(values, dim=dim)

    def expand(self, entries: torch.Tensor) -> torch.Tensor:
        """Full symmetric ``(..., d, d)`` matrices from their :attr:`entry_index` entries ``(..., d + pairs)``
        (an exact 0/1 map: every entry is copied, the others are zero)."""
        zero = torch.zeros_like(entries[..., 0])
        full = [[zero] * self.dim for _ in range(self.dim)]
        for e, (i, j) in enumerate(self.entry_index):
            full[i][j] = full[j][i] = entries[..., e]
        return torch.stack([v for row in full for v in row], dim=-1).view(*entries.shape[:-1], self.dim, self.dim)


T = TypeVar("T", int, torch.Tensor)


def chunks_needed(length: T, chunk: int) -> T:
    """Decoder steps that generate the inputs ``u[0..K-2]`` of a length-K motion: ``max(1, ⌈(K-1)/C⌉)``, for an
    ``int`` K or a tensor of lengths (elementwise; the same integer arithmetic, so both agree)."""
    if torch.is_tensor(length):
        return (length - 2).clamp_min(0) // chunk + 1
    return max(length - 2, 0) // chunk + 1


class ChunkedSeq2Seq(nn.Module):
    """Encoder–decoder over chunks of C samples with a Gaussian output head."""

    def __init__(self, cfg: Seq2SeqConfig) -> None:
        super().__init__()
        self.cfg = cfg
        c = cfg.chunk
        self.encoder_in = nn.Linear(c * cfg.encoder_input_dim, cfg.hidden)
        self.encoder = StackedLSTM(cfg.hidden, cfg.hidden, cfg.layers)
        self.decoder_in = nn.Linear(c * cfg.decoder_input_dim, cfg.hidden)
        self.decoder = StackedLSTM(cfg.hidden, cfg.hidden, cfg.layers)
        self.head = GaussianHead(cfg)
        self.register_buffer("encoder_scale", torch.tensor(cfg.encoder_input_scale or [1.0] * cfg.encoder_input_dim))
        self.register_buffer("decoder_scale", torch.tensor(cfg.decoder_input_scale or [1.0] * cfg.decoder_input_dim))

    def _load_from_state_dict(self, state_dict: dict, prefix: str, *args: object, **kwargs: object) -> None:
        """``load_state_dict`` (this module's part; ``nn.Module`` calls it on every load, however the model is
        wrapped): refuse, before anything is copied, weights whose scale buffers differ from the config
        (:data:`SCALE_BUFFERS`)."""
        self.check_scales({k: state_dict[prefix + k] for k in SCALE_BUFFERS.values() if prefix + k in state_dict})
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def check_scales(self, buffers: dict[str, torch.Tensor]) -> None:
        """``ValueError`` naming the first of ``buffers`` (name → tensor, e.g. from a weights file) that differs
        from the config field it stands for; agreement is up to float32 rounding (a float64 model holds the
        float32-rounded scales). Tensors without values (the ``meta`` device) or of another shape (the shape
        check reports them) are skipped."""
        for field_name, buffer in SCALE_BUFFERS.items():
            tensor = buffers.get(buffer)
            if tensor is None or tensor.is_meta:
                continue
            configured = getattr(self.cfg, field_name)
            if configured is None:  # what __init__ fills the buffer with then
                configured = [0.0 if field_name == "output_offset" else 1.0] * tensor.numel()
            expected = torch.tensor(configured, dtype=torch.float64)
            values = tensor.detach().to("cpu", torch.float64)
            if values.shape != expected.shape:
                continue
            if not torch.allclose(values, expected, rtol=1e-6, atol=0.0):
                raise ValueError(
                    f"the config's {field_name} {expected.tolist()} differs from the weights' {buffer} "
                    f"{values.tolist()} (the network computes with the weights'): edited or mixed-up files"
                )

    @property
    def chunk(self) -> int:
        return self.cfg.chunk

    @property
    def latent_dim(self) -> int:
        return self.cfg.latent_dim

    def num_chunks(self, length: int) -> int:
        """Decoder steps needed to generate inputs ``u[0..K-2]`` of a length-K trajectory (:func:`num_chunks`)."""
        return chunks_needed(length, self.chunk)

    def encode(self, x: torch.Tensor, lengths: torch.Tensor | None = None) -> torch.Tensor:
        """Encode trajectories into latents.

        Args:
            x: ``(B, K, encoder_input_dim)``, padded by repeating each trajectory's last sample.
            lengths: ``(B,)`` true lengths (default: all K).

        Returns:
            ``z`` of shape ``(B, L·H)``.
        """
        b, k, features = x.shape
        c = self.chunk
        n = math.ceil(k / c)
        if n * c != k:  # pad to whole chunks by repeating the last sample
            x = torch.cat([x, x[:, -1:].expand(b, n * c - k, features)], dim=1)
        # Chunks per trajectory (a trajectory's z is the state after its last, partly padded, chunk, so it
        # does not depend on what it was batched with), then the batch packed longest first, step by step.
        if lengths is None:
            count = torch.full((b,), n, device=x.device)
        else:
            count = ((lengths.to(x.device).long() + c - 1) // c).clamp(0, n)  # ceil(K / C)
        order = torch.argsort(count, descending=True, stable=True)
        sizes = [s for s in (count[order].unsqueeze(0) > torch.arange(n, device=x.device).unsqueeze(1)).sum(1).tolist()
                 if s > 0]
        z = x.new_zeros(b, self.latent_dim)
        if not sizes:  # no trajectory has a sample: the zero state, as for an unused encoder
            return z
        rows = torch.cat([order[:size] * n + t for t, size in enumerate(sizes)])  # into the (B·n) chunks
        chunks = x.reshape(b * n, c, features)[rows] / self.encoder_scale
        state = self.encoder.run_packed(self.encoder_in(chunks.reshape(len(rows), c * features)), sizes)
        packed_z = torch.cat([cell for _, cell in state], dim=1)  # (sizes[0], L·H), longest first
        if sizes[0] == b and bool((order == torch.arange(b, device=x.device)).all()):
            return packed_z  # already in order (the training losses sort their batches longest first)
        return z.index_put((order[: sizes[0]],), packed_z)

    def initial_state(self, z: torch.Tensor) -> LSTMState:
        """Decoder state from a latent: ``c_l = z_l``, ``h_l = 0``."""
        if z.ndim != 2 or z.shape[1] != self.latent_dim:
            raise ValueError(f"latent must have shape (B, {self.latent_dim}), got {tuple(z.shape)}")
        cells = z.split(self.cfg.hidden, dim=1)
        return tuple((torch.zeros_like(cell), cell) for cell in cells)

    def decode_step(
        self, state: LSTMState, inputs: torch.Tensor, need_cov: bool = True
    ) -> tuple[LSTMState, torch.Tensor, torch.Tensor | None]:
        """One decoder step.

        Args:
            state: decoder state.
            inputs: ``(B, C, decoder_input_dim)`` the last C states (physical units).

        Returns:
            ``(state, mean (B, C, d), cov (B, C, d, d) or None)``.
        """
        state, out = self.decoder_output(state, inputs)
        mean, cov = self.head(out, need_cov)
        return state, mean, cov

    def decoder_output(self, state: LSTMState, inputs: torch.Tensor) -> tuple[LSTMState, torch.Tensor]:
        """The decoder's new state and top-layer output ``(B, H)`` for the last C states ``(B, C, dim)``."""
        flat = (inputs.to(self.decoder_scale.dtype) / self.decoder_scale).flatten(1)  # a graph reads no shape
        out, state = self.decoder(self.decoder_in(flat), state)
        return state, out


class ChunkDynamics(Protocol):
    """The differentiable physics a task closes the decoder's loop with.

    A ``carry`` is whatever the dynamics needs at a chunk boundary (state, covariances…).
    """

    def start(self, x0: torch.Tensor) -> object:
        """Carry for trajectories starting at states ``x0`` (B, state_dim), covariance zero."""
        ...

    def step(self, carry: object, mean: torch.Tensor, cov: torch.Tensor | None) -> tuple[object, dict]:
        """Apply C inputs; return the new carry and this chunk's outputs.

        The dict holds at least ``"states"`` (B, C, state_dim): the C states that follow;
        with ``cov`` given also ``"pos_cov"`` (B, C, p, p) for the likelihood loss; tasks
        may add more (e.g. the object's inputs in ch. 3).
        """
        ...

    def decoder_input(self, states: torch.Tensor) -> torch.Tensor:
        """Map ``(B, C, state_dim)`` states to the decoder's ``(B, C, decoder_input_dim)``."""
        ...

    def restart(self, carry: object, state: torch.Tensor, mask: torch.Tensor) -> object:
        """Teacher forcing: where ``mask`` (B,), continue from the true ``state`` (B, state_dim)."""
        ...

    def narrow(self, carry: object, rows: int) -> object:
        """Optional: the carry of the first ``rows`` trajectories, so that the rollout can stop those that
        have ended (``rollout(..., lengths=...)``, the batch sorted longest first); per-trajectory
        parameters of the dynamics then apply to those rows."""
        ...

    # Optional, for a task whose outputs are not the accelerations of its velocity columns (e.g. joint
    # torques): ``outputs_for(x (B, S), accel (B, n, d)) -> (B, n, d)``, the outputs that give those
    # accelerations along the path from ``x``, and ``stop_accel_limit`` ``(d,)``, the accelerations the
    # online generator may plan to stop the robot with. The generator stops such a task through them (and
    # exports ``outputs_for`` beside the dynamics graph); without them its stepper is refused by name
    # (``seqmotion.core.stepper``; examples/cup_arm has both).


class EntrywiseCovariance(Protocol):
    """Optionally, dynamics whose covariance propagation acts on every entry of ``S_u`` alike (the double
    integrator: a fixed linear map along time). :func:`rollout` then decodes the means chunk by chunk and
    propagates all chunks' covariances at once afterwards — the same numbers with far fewer operations."""

    def propagate_entrywise(self, entries: torch.Tensor, known: torch.Tensor, chunk: int) -> dict[str, torch.Tensor]:
        """``entries`` ``(B, E, N·C)``: E entries of ``S_u`` per sample for N chunks of C; ``known`` ``(B, N)``:
        chunk k starts from a known state (zero covariance: the start, or teacher forcing). Returns what
        :meth:`ChunkDynamics.step` would have returned besides the states, per entry (``"pos_cov"``
        ``(B, E, N·C)``), which the rollout expands to full matrices."""
        ...


@dataclass
class Rollout:
    """Everything one decoding pass produced (length N·C + 1 states for N decoder steps).

    Attributes:
        states: ``(B, N·C + 1, state_dim)``, ``states[:, 0] = x0``.
        accel: ``(B, N·C, d)`` means of the generated inputs.
        accel_cov: ``(B, N·C, d, d)`` or None.
        outputs: further per-sample outputs of the dynamics (e.g. ``pos_cov`` ``(B, N·C, p, p)``
            of ``states[:, 1:]``), concatenated over chunks.
        cov_entries: with ``rollout(..., expand_cov=False)`` on dynamics with entrywise covariances: the
            covariances as their non-zero entries ``(B, E, N·C)`` only (``"accel_cov"`` and the dynamics'
            covariance outputs, e.g. ``"pos_cov"``), in the order of ``entry_index`` (``(i, j)`` per entry);
            ``accel_cov`` and those outputs are then not built. None otherwise.
    """

    states: torch.Tensor
    accel: torch.Tensor
    accel_cov: torch.Tensor | None
    outputs: dict[str, torch.Tensor]
    cov_entries: dict[str, torch.Tensor] | None = None
    entry_index: list[tuple[int, int]] | None = None

    def cov_entry(self, key: str, i: int, j: int) -> torch.Tensor:
        """Entry ``(i, j)`` ``(B, N·C)`` of the covariance ``key`` (``"accel_cov"``, ``"pos_cov"``…), from
        ``cov_entries`` when the rollout kept only those, else from the full matrices."""
        if self.cov_entries is not None and self.entry_index is not None:
            # one unbind per key (its gradient is one stack; a select per entry would each fill a zero tensor)
            cache = self.__dict__.setdefault("_unbound", {})
            if key not in cache:
                cache[key] = self.cov_entries[key].unbind(1)
            for e, pair in enumerate(self.entry_index):
                if pair in ((i, j), (j, i)):
                    return cache[key][e]
            return torch.zeros_like(cache[key][0])
        full = self.accel_cov if key == "accel_cov" else self.outputs[key]
        return full[..., i, j]


def rollout(
    model: ChunkedSeq2Seq,
    z: torch.Tensor,
    x0: torch.Tensor,
    dynamics: ChunkDynamics,
    num_chunks: int,
    *,
    need_cov: bool = True,
    teacher: torch.Tensor | None = None,
    teacher_forcing_prob: float = 0.0,
    generator: torch.Generator | None = None,
    expand_cov: bool = True,
    lengths: torch.Tensor | None = None,
) -> Rollout:
    """Run the decoder in closed loop with the dynamics (free running / scheduled sampling).

    Args:
        z: ``(B, L·H)`` latents.
        x0: ``(B, state_dim)`` initial states.
        num_chunks: decoder steps N.
        teacher: ``(B, ≥ N·C + 1, state_dim)`` true states for teacher forcing.
        teacher_forcing_prob: probability, per trajectory and decoder step, of feeding the true
            chunk (and continuing the physics from the true state) instead of the generated one.
        generator: random source for the teacher-forcing coin flips.
        expand_cov: with dynamics that propagate covariances entrywise (:class:`EntrywiseCovariance`):
            False keeps them as their non-zero entries (``Rollout.cov_entries``) instead of building
            ``(d, d)`` matrices (a loss that reads a few entries saves the matrices' memory traffic).
        lengths: ``(B,)`` the trajectories' lengths K, for a loss that reads each one's first K samples only.
            With dynamics that can :meth:`~ChunkDynamics.narrow` their carry, the decoder stops at each
            trajectory's last chunk (:meth:`ChunkedSeq2Seq.num_chunks`) and everything past it is zero: the
            same numbers within the lengths, about a third less work for lengths spread evenly. Fastest with
            the batch sorted longest first (else it is sorted here and put back). Otherwise (or None) every
            trajectory runs all ``num_chunks``.
    """
    c = model.chunk
    use_teacher = teacher is not None and teacher_forcing_prob > 0.0
    if use_teacher and teacher.shape[1] < num_chunks * c + 1:
        raise ValueError(f"teacher needs {num_chunks * c + 1} samples, got {teacher.shape[1]}")
    if need_cov and hasattr(dynamics, "propagate_entrywise"):
        return _rollout_entrywise(model, z, x0, dynamics, num_chunks, teacher if use_teacher else None,
                                  teacher_forcing_prob, generator, expand_cov, lengths)
    b = x0.shape[0]
    rows, order, z, x0, teacher = _longest_first(dynamics, lengths, num_chunks, c, z, x0, teacher)
    state = model.initial_state(z)
    carry = dynamics.start(x0)
    inputs = dynamics.decoder_input(x0.unsqueeze(1).expand(-1, c, -1))
    states, accels, covs, outputs = [x0.unsqueeze(1)], [], [], {}
    for k in range(num_chunks):
        active = rows[k]
        state, inputs, carry = _first_rows(active, state, inputs, carry, dynamics)
        state, mean, cov = model.decode_step(state, inputs, need_cov)
        carry, out = dynamics.step(carry, mean.to(x0.dtype), None if cov is None else cov.to(x0.dtype))
        generated = out["states"]
        states.append(generated)
        accels.append(mean)
        if cov is not None:
            covs.append(cov)
        for key, value in out.items():
            if key != "states":
                outputs.setdefault(key, []).append(value)
        inputs = dynamics.decoder_input(generated)
        if use_teacher and k + 1 < num_chunks:
            coin = _coins(b, teacher_forcing_prob, generator, x0.device, order)[:active]
            true_chunk = teacher[:active, k * c + 1 : (k + 1) * c + 1]
            inputs = torch.where(coin.view(-1, 1, 1), dynamics.decoder_input(true_chunk), inputs)
            carry = dynamics.restart(carry, true_chunk[:, -1], coin)
    inverse = None if order is None else torch.argsort(order)
    return Rollout(
        states=_cat_rows(states, b, inverse),
        accel=_cat_rows(accels, b, inverse),
        accel_cov=_cat_rows(covs, b, inverse) if covs else None,
        outputs={key: _cat_rows(value, b, inverse) for key, value in outputs.items()},
    )


def _longest_first(
    dynamics: ChunkDynamics, lengths: torch.Tensor | None, num_chunks: int, chunk: int, z: torch.Tensor,
    x0: torch.Tensor, teacher: torch.Tensor | None,
) -> tuple[list[int], torch.Tensor | None, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """How a rollout skips trajectories that have ended: ``rows[k]``, the trajectories chunk k computes (the
    first ones of the batch sorted longest first); ``order``, the sorting permutation (None when the batch is
    sorted already, or when there are no ``lengths`` or the dynamics cannot ``narrow`` a carry); and ``z``,
    ``x0``, ``teacher`` in that order."""
    batch, device = x0.shape[0], x0.device
    if lengths is None or not hasattr(dynamics, "narrow"):
        return [batch] * num_chunks, None, z, x0, teacher
    needed = chunks_needed(lengths.to(device), chunk).clamp_max(num_chunks)
    order = torch.argsort(needed, descending=True, stable=True)
    if bool((order == torch.arange(batch, device=device)).all()):
        order = None  # already longest first (the training losses' batches are drawn so)
    else:
        needed, z, x0 = needed[order], z[order], x0[order]
        teacher = None if teacher is None else teacher[order]
    rows = (needed.unsqueeze(0) > torch.arange(num_chunks, device=device).unsqueeze(1)).sum(1).tolist()
    return rows, order, z, x0, teacher


def _first_rows(
    active: int, state: LSTMState, inputs: torch.Tensor, carry: object, dynamics: ChunkDynamics
) -> tuple[LSTMState, torch.Tensor, object]:
    """The decoder state, inputs and carry of the first ``active`` trajectories (the others have ended)."""
    if active == inputs.shape[0]:
        return state, inputs, carry
    return tuple((h[:active], cell[:active]) for h, cell in state), inputs[:active], dynamics.narrow(carry, active)


def _coins(
    batch: int, prob: float, generator: torch.Generator | None, device: torch.device, order: torch.Tensor | None
) -> torch.Tensor:
    """One chunk's teacher-forcing coins, one per trajectory in the caller's order (so the random stream and
    each trajectory's coin are the same whichever trajectories run), then in the rollout's order."""
    coin = torch.rand(batch, generator=generator, device=device) < prob
    return coin if order is None else coin[order]


def _rollout_entrywise(
    model: ChunkedSeq2Seq,
    z: torch.Tensor,
    x0: torch.Tensor,
    dynamics: ChunkDynamics,
    num_chunks: int,
    teacher: torch.Tensor | None,
    teacher_forcing_prob: float,
    generator: torch.Generator | None,
    expand: bool = True,
    lengths: torch.Tensor | None = None,
) -> Rollout:
    """:func:`rollout` with ``need_cov`` for dynamics with :meth:`EntrywiseCovariance.propagate_entrywise`.

    The closed loop needs only the means: the decoder and the physics run chunk by chunk on them, the
    head's raw outputs are kept, and after the loop the covariances of all N·C samples are made and
    propagated in a few whole-sequence operations (the head's ``S_u`` entries, their propagation with
    the restarts teacher forcing made, the expansion to matrices) instead of N rounds of small ones.
    Same coin flips, same states, same covariances as the chunk-by-chunk loop.

    With ``lengths`` (and dynamics that can ``narrow`` a carry), the batch runs longest first and chunk k
    computes only the ``rows[k]`` trajectories that still need it; what follows a trajectory's last chunk
    is zero-padded.
    """
    c = model.chunk
    head = model.head
    b = x0.shape[0]
    rows, order, z, x0, teacher = _longest_first(dynamics, lengths, num_chunks, c, z, x0, teacher)
    state = model.initial_state(z)
    carry = dynamics.start(x0)
    inputs = dynamics.decoder_input(x0.unsqueeze(1).expand(-1, c, -1))
    states, means, rests = [x0.unsqueeze(1)], [], []
    known = [torch.ones(b, dtype=torch.bool, device=x0.device)]  # chunk 0 starts from x0, covariance zero
    for k in range(num_chunks):
        active = rows[k]
        state, inputs, carry = _first_rows(active, state, inputs, carry, dynamics)
        state, out = model.decoder_output(state, inputs)
        first, rest = head.split(head.raw(out))
        mean = head.mean_of(first)
        means.append(mean)
        rests.append(rest)
        carry, step_out = dynamics.step(carry, mean.to(x0.dtype), None)
        generated = step_out["states"]
        states.append(generated)
        inputs = dynamics.decoder_input(generated)
        if k + 1 < num_chunks:
            if teacher is not None:  # a coin for every trajectory, so the stream is the same whatever ran
                coin = _coins(b, teacher_forcing_prob, generator, x0.device, order)
                true_chunk = teacher[:active, k * c + 1 : (k + 1) * c + 1]
                inputs = torch.where(coin[:active].view(-1, 1, 1), dynamics.decoder_input(true_chunk), inputs)
                carry = dynamics.restart(carry, true_chunk[:, -1], coin[:active])
                known.append(coin)
            else:
                known.append(torch.zeros_like(known[0]))
    entries = head.entries_of(_cat_rows(rests, b), dim=1)  # (B, E, N·C): each entry's series contiguous
    propagated = dynamics.propagate_entrywise(entries.to(x0.dtype), torch.stack(known, dim=1), c)
    inverse = None if order is None else torch.argsort(order)
    states_all, means_all = _cat_rows(states, b, inverse), _cat_rows(means, b, inverse)
    if rows[-1] < b:  # past a trajectory's last chunk: zero, like its unused samples elsewhere
        ran = torch.repeat_interleave(torch.tensor(rows, device=x0.device).unsqueeze(0) >
                                      torch.arange(b, device=x0.device).unsqueeze(1), c, dim=1)
        ran = ran.to(entries.dtype).unsqueeze(1)  # (B, 1, N·C): a float mask (a bool one converts per element)
        entries = entries * ran
        propagated = {key: value * ran.to(value.dtype) for key, value in propagated.items()}
    if inverse is not None:  # back to the caller's order
        entries, propagated = entries[inverse], {key: value[inverse] for key, value in propagated.items()}
    if not expand:
        return Rollout(states=states_all, accel=means_all, accel_cov=None, outputs={},
                       cov_entries={"accel_cov": entries, **propagated}, entry_index=head.entry_index)
    return Rollout(
        states=states_all,
        accel=means_all,
        accel_cov=head.expand(entries.movedim(1, -1)),
        outputs={key: head.expand(value.movedim(1, -1)) for key, value in propagated.items()},
    )


def _cat_rows(pieces: list[torch.Tensor], rows: int, inverse: torch.Tensor | None = None) -> torch.Tensor:
    """Chunks ``(b_k, C, …)`` with ``b_k ≤ rows`` → one ``(rows, ΣC, …)`` tensor, zero where a chunk had no row
    (padding's gradient is a view, so this costs one copy more than a plain concatenation); ``inverse``: put
    the rows back in the caller's order."""
    whole = torch.cat([piece if piece.shape[0] == rows else
                       nn.functional.pad(piece, [0, 0] * (piece.ndim - 1) + [0, rows - piece.shape[0]])
                       for piece in pieces], dim=1)
    return whole if inverse is None else whole[inverse]
