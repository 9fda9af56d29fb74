"""The training loop: curriculum → data → loss → Adam, with checkpoints, resume and data parallelism.

It reads top to bottom like the dissertation's procedure: for every mini-batch, look up the
curriculum's parameters, draw fresh trajectories from the task's generators, score the
model's free-running (or teacher-forced) rollout through the task's physics, step Adam.

The optimisation itself — Adam, the learning-rate schedule, clipping, checkpoints, resume and
``metrics.csv`` — is :class:`~seqmotion.training.loop.TrainingLoop`, shared with the
chapter-5 trainings; this module adds the curriculum, the data and data parallelism.

**Determinism and exact resume.** Weights are initialised from ``seed``; the data and the
scheduled-sampling coin flips of step ``s`` are drawn from generators seeded by
``(seed, s)``, not from a running random state. A checkpoint therefore only needs the weights,
Adam's state and the step counter, and a resumed run continues bit for bit. A checkpoint of
another configuration (anything but the checkpoint cadence differing) is refused.

**Data parallelism.** Launched by ``torchrun --nproc_per_node=N``, every process draws the
same global batch and trains on its 1/N share (trajectories ``rank, rank + N, …``); the
gradients are averaged with one all-reduce per step (``gloo`` on CPU, ``nccl`` on GPUs).
The scheduled-sampling coins do not depend on the rank either: the coins generator is the
single-process one, and every ``torch.rand``/``torch.randn(n, …, generator=coins)`` a task's
loss makes on a rank draws the global batch's ``N·n`` numbers and keeps the rank's rows
(:class:`_RankSlice`), so trajectory ``b`` gets the coin it gets in one process whichever
rank holds it. An N-process run therefore trains on exactly the data, coins and per-trajectory
losses of the single-process run of the same command. What differs is floating-point
rounding only: the gradient is the mean of N per-rank means summed by the all-reduce
instead of one mean over the batch, and the kernels run on N-times smaller batches, which
may round differently; weights agree to float32 rounding after a step and drift apart
slowly over many steps. The logged terms are means of the per-rank means. Other draws from the
coins generator (``bernoulli``, ``Tensor.uniform_``) are per rank.
Rank 0 writes checkpoints and logs.

**Run directories.** A training locks its run directory while it writes there (a second
training into it is refused by name), and removes what a killed run left half-written.
Every write is atomic (:mod:`seqmotion.io`, :mod:`.checkpoint`): a kill at any instant leaves the previous
checkpoint, ``latest`` and ``metrics.csv`` intact, ``sm.load(run)`` always loads a complete
model (the run's latest checkpoint when the top-level model was being replaced), and
rerunning the command resumes bit for bit and rewrites a top-level model the kill left stale.
"""

from __future__ import annotations

import numbers
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch.overrides import TorchFunctionMode
from tqdm import tqdm

from ..errors import check_number
from ..io import check_writable_dir
from . import checkpoint as ckpt
from .config import TrainConfig
from .device import backend_for, process_device, resolve_device
from .loop import TrainingLoop
from .provenance import command_line, machine_description


def _distributed(device: torch.device) -> tuple[int, int]:
    """Join the process group torchrun set up, if any; return ``(rank, world_size)``. The backend follows
    the chosen device (``nccl`` on GPUs, ``gloo`` on CPUs), not whether a GPU happens to be visible."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1
    if not dist.is_initialized():
        if device.type == "cuda":
            torch.cuda.set_device(device)
        dist.init_process_group(backend_for(device))
    return dist.get_rank(), dist.get_world_size()


def _average_gradients(params: list[torch.nn.Parameter], world: int) -> None:
    """All-reduce every gradient in one flat buffer and divide by the number of processes."""
    grads = [p.grad for p in params if p.grad is not None]
    flat = torch.cat([g.reshape(-1) for g in grads])
    dist.all_reduce(flat)
    flat /= world
    offset = 0
    for g in grads:
        g.copy_(flat[offset : offset + g.numel()].view_as(g))
        offset += g.numel()


class _RankSlice(TorchFunctionMode):
    """While active on data-parallel rank ``rank`` of ``world``: ``torch.rand``/``torch.randn`` calls that
    draw from ``generator`` with a leading batch axis of ``n`` draw ``world · n`` rows (the global
    batch's, as one process draws them) and return rows ``rank, rank + world, …`` (this rank's
    trajectories). Every other call passes through unchanged."""

    def __init__(self, generator: torch.Generator, rank: int, world: int) -> None:
        super().__init__()
        self.generator, self.rank, self.world = generator, rank, world

    def __torch_function__(self, func, types, args=(), kwargs=None):  # noqa: ANN001, ANN204 - torch's protocol
        kwargs = kwargs or {}
        if func in (torch.rand, torch.randn) and kwargs.get("generator") is self.generator and args:
            size = tuple(args[0]) if len(args) == 1 and isinstance(args[0], (tuple, list, torch.Size)) else args
            if size and all(isinstance(n, int) for n in size):
                full = func(size[0] * self.world, *size[1:], **kwargs)
                return full[self.rank :: self.world]
        return func(*args, **kwargs)


CADENCE = ("training.checkpoint_every", "training.keep_checkpoints")
"""Settings a resumed run may change (how often and how many checkpoints are written)."""


def model_config(config: TrainConfig, extra: dict | None = None) -> dict:
    """The ``config.json`` of a trained model: task, architecture and how it was trained."""
    return {"task": config.task, "model": config.model, "training": config.to_dict(), **(extra or {})}


def train(
    task: Any,
    config: TrainConfig,
    run_dir: str | Path,
    *,
    resume: bool = True,
    progress: bool = True,
    stop_at_step: int | None = None,
    init_from: str | Path | None = None,
    device: str | torch.device | None = "auto",
) -> Path:
    """Train (or continue training) a model; return the run directory.

    Args:
        task: the :class:`~seqmotion.tasks.Task` that ``config`` names (``seqmotion.tasks.train``
            looks it up; this layer does not know the registry): ``build_model``, ``curriculum``,
            ``sample``, ``loss`` and ``options``.
        config: the run's configuration.
        run_dir: where checkpoints (``checkpoints/``, ``latest``), the exported model
            (``model.safetensors`` + ``config.json``) and ``metrics.csv`` go.
        resume: continue from the run's latest checkpoint if there is one.
        progress: show a progress bar with the loss terms and the share of feasible outputs.
        stop_at_step: stop after this many optimiser steps in total (for timing and tests; ≥ 1).
        init_from: fine-tune: start from the weights of this model or run directory (loaded strictly, verified;
            its task and architecture must be ``config``'s) instead of fresh ones seeded by ``seed``. The
            source and its weights' hash go into the run's identity (a checkpoint of another start is refused
            on resume) and provenance. Adam's state and the step counter start fresh.
        device: where the model, the batches, the physics and the scheduled-sampling coins live:
            ``"auto"`` (default: the GPU if PyTorch sees one, else the CPU), ``"cpu"``, ``"cuda"``, ``"cuda:N"``
            (:func:`.device.resolve_device`). Under torchrun on GPUs every process takes ``cuda:LOCAL_RANK``
            and the gradients are all-reduced with ``nccl``; on CPUs with ``gloo``. Not part of the run's
            identity: checkpoints hold CPU tensors, and a run resumes on any device (a GPU's random
            coins and kernels differ from the CPU's, so a run is bit-for-bit repeatable per device).

    Raises:
        ValueError: a bad setting (named; an unknown device or ``cuda`` without a GPU too), or ``run_dir``
            cannot be written.
        seqmotion.CheckpointError: the run directory holds another training's checkpoints.
        seqmotion.errors.RunInUseError: another training is writing into ``run_dir``.
    """
    if getattr(task, "name", None) != config.task:
        raise ValueError(f"the config is for task {config.task!r}, not {getattr(task, 'name', task)!r}")
    config.validate()  # attributes may have been changed since it was made
    if stop_at_step is not None:
        check_number("stop_at_step (--max-steps)", stop_at_step, minimum=1, integer=True)
    task.options(config)  # refuse unknown or bad options before anything is written
    device = resolve_device(device)
    world_env = int(os.environ.get("WORLD_SIZE", "1"))
    device = process_device(device, world_env)
    rank, world = _distributed(device)
    if config.batch_size % world:
        raise ValueError(f"batch_size {config.batch_size} is not divisible by {world} processes")
    run_dir = Path(run_dir)
    if rank == 0:
        check_writable_dir(run_dir, "run directory")

    torch.manual_seed(config.seed)
    model = task.build_model(config)
    start = _load_initial_weights(model, config, init_from) if init_from is not None else None
    model.to(device)  # after building (and loading) on the CPU: the initial weights do not depend on the device
    curriculum = task.curriculum(config)
    total = curriculum.epochs * config.batches_per_epoch
    loop = TrainingLoop(
        model, list(model.parameters()), **config.loop_settings(), total_steps=total, run_dir=run_dir,
        identity={"training": config.to_dict(), **({"init_from": start} if start else {})},
        ignore=CADENCE + ("init_from.path",), keep_checkpoints=config.keep_checkpoints,
        writer=rank == 0, reduce_gradients=(lambda params: _average_gradients(params, world)) if world > 1 else None,
    )
    try:
        _run(task, config, model, curriculum, loop, run_dir, rank, world, resume, progress, stop_at_step, start,
             device)
    finally:
        loop.close()
    return run_dir


def _load_initial_weights(model: torch.nn.Module, config: TrainConfig, source: str | Path) -> dict:
    """Load ``source``'s weights into ``model`` for fine-tuning (``init_from``); return what identifies them.

    ``source`` is a model directory or a training run (its model, or its latest checkpoint). Raises
    ValueError (another task or architecture) or CheckpointError (missing, corrupt, misfit weights).
    """
    path = Path(source)
    if not path.exists():  # a shipped model's name is resolved to its folder by the caller (seqmotion train)
        raise ValueError(f"--init-from {source}: no such model or run directory")
    directory = ckpt.resolve_model_dir(path)
    saved, tensors = ckpt.read_model(directory, expected_task=config.task)
    if saved.get("model") != config.model:
        differ = sorted(k for k in set(config.model) | set(saved.get("model") or {})
                        if (saved.get("model") or {}).get(k) != config.model.get(k))
        raise ValueError(f"--init-from {source}: its model config differs from this run's in {differ} "
                         "(choose the preset it was trained with)")
    ckpt.load_state_dict_strict(model, tensors, str(directory))
    return {"path": str(source), "weights_sha256": saved.get("weights_sha256")}


def step_loss(
    task: Any, model: torch.nn.Module, batch: Any, params: Any, options: Any, generator: torch.Generator,
    dynamics: Any = None,
) -> tuple[torch.Tensor, dict[str, float]]:
    """One training step's loss, as the loop computes it: ``task.loss`` with the NumPy ``batch`` moved to the
    model's device, typed curriculum ``params`` (a dict of the curriculum's values is typed here), typed
    ``options`` (a ``TrainConfig``'s are read here) and the task's ``dynamics`` at its physics (built here
    unless given; the loop builds them once).

    Raises:
        ValueError: the batch is not what ``task.sample`` promises (:func:`check_batch`), or ``task.loss``
            returned something other than a scalar loss and a dict of floats (:func:`check_loss`); the message
            names the task, the method and the shapes.
    """
    if isinstance(options, TrainConfig):
        options = task.options(options)
    if isinstance(params, dict):
        params = task.params(params)
    if dynamics is None:
        dynamics = task.dynamics(options, task.physics(options))
    check_batch(task, batch)
    device = next(model.parameters()).device
    return check_loss(task, task.loss(model, batch.to(device), dynamics, params, options, generator))


def _shape(shape: tuple[int, ...]) -> str:
    return f"({', '.join(map(str, shape))}{',' if len(shape) == 1 else ''})"


def _described(value: Any) -> str:
    """``"of shape (8, 200, 3)"`` for an array, ``"of type list"`` for anything else (for messages)."""
    return f"of shape {_shape(value.shape)}" if isinstance(value, np.ndarray) else f"of type {type(value).__name__}"


def check_batch(task: Any, batch: Any) -> None:
    """``ValueError`` naming the task unless ``batch`` is what :meth:`Task.sample` promises: ``states``
    ``(B, K, input_dim)`` of numbers, ``lengths`` ``(B,)`` integers in ``[2, K]``, ``accel`` ``(B, K-1, ·)`` or
    None, every extra with B rows.

    A plug-in's slip otherwise surfaces deep in the model as a broadcasting ``RuntimeError`` — or trains on
    nonsense without a word (lengths past the padding, accelerations of another length). Shapes and dtypes
    only, plus the ``(B,)`` lengths' range: the per-step cost is nil and nothing waits for a device."""
    def refuse(what: str) -> ValueError:
        return ValueError(f"task {getattr(task, 'name', task)!r}: sample() returned {what}")

    if not all(hasattr(batch, name) for name in ("states", "lengths", "to")):
        raise refuse(f"a {type(batch).__name__}, expected a TrajectoryBatch (states, lengths, accel, extras)")
    layout = getattr(task, "input_layout", None)  # the encoder reads the sampled motions in this layout
    width = "input_dim" if layout is None else layout.dim
    states, lengths, accel = batch.states, batch.lengths, getattr(batch, "accel", None)
    if not isinstance(states, np.ndarray) or states.ndim != 3 or (layout is not None and states.shape[2] != width):
        rows = states.shape[0] if isinstance(states, np.ndarray) and states.ndim == 3 else "B"
        names = "" if layout is None else f" (the columns of {layout})"
        raise refuse(f"states {_described(states)}, expected ({rows}, K, {width}){names}")
    if states.dtype.kind not in "fiu":  # bool or text would be cast silently by the move to the device
        raise refuse(f"states of dtype {states.dtype}, expected numbers (floats)")
    n, k = states.shape[:2]
    if not isinstance(lengths, np.ndarray) or lengths.shape != (n,):
        raise refuse(f"lengths {_described(lengths)}, expected ({n},): one per trajectory of the states")
    if lengths.dtype.kind not in "iu":
        raise refuse(f"lengths of dtype {lengths.dtype}, expected integers")
    if n and not 2 <= int(lengths.min()) <= int(lengths.max()) <= k:
        raise refuse(f"lengths from {int(lengths.min())} to {int(lengths.max())}, expected between 2 and K = {k} "
                     "(the states' padded length)")
    if accel is not None and (not isinstance(accel, np.ndarray) or accel.ndim != 3 or accel.shape[:2] != (n, k - 1)):
        raise refuse(f"accel {_described(accel)}, expected ({n}, {k - 1}, accel_dim) or None")
    for name, value in (getattr(batch, "extras", None) or {}).items():
        if np.ndim(value) == 0 or np.shape(value)[0] != n:  # rows are selected per data-parallel rank
            raise refuse(f"extras[{name!r}] {_described(value)}, expected ({n}, ...)")


def check_loss(task: Any, out: Any) -> tuple[torch.Tensor, dict[str, float]]:
    """``out`` — what :meth:`Task.loss` returned — when it is ``(loss, terms)`` with a scalar tensor loss that
    depends on the weights and a dict of terms; else ``ValueError`` naming the task and what it got.

    Otherwise a vector loss fails in ``backward`` ("grad can be implicitly created only for scalar outputs")
    and a detached one with "does not require grad". Shape and flags only: no value is read here (whether
    it is finite is the loop's check, which reads it once anyway)."""
    def refuse(what: str) -> ValueError:
        return ValueError(f"task {getattr(task, 'name', task)!r}: loss() returned {what}")

    if not isinstance(out, tuple) or len(out) != 2:
        raise refuse(f"a {type(out).__name__}, expected (loss, terms): a scalar tensor and a dict of named floats")
    loss, terms = out
    if not isinstance(loss, torch.Tensor):
        raise refuse(f"a loss of type {type(loss).__name__}, expected a scalar torch.Tensor")
    if loss.numel() != 1:  # (1,) is accepted: backward takes it as a scalar
        raise refuse(f"a loss of shape {_shape(tuple(loss.shape))}, expected a scalar (shape ()), e.g. its .mean()")
    if not loss.is_floating_point():
        raise refuse(f"a loss of dtype {loss.dtype}, expected floats")
    if torch.is_grad_enabled() and not loss.requires_grad:
        raise refuse("a loss that does not depend on the model's weights (requires_grad is False: detached, or "
                     "computed without the model's outputs)")
    if not isinstance(terms, dict):
        raise refuse(f"terms of type {type(terms).__name__}, expected a dict of named floats")
    for name, value in terms.items():  # logged to metrics.csv and written into the checkpoints' JSON
        if not isinstance(name, str) or isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise refuse(f"terms[{name!r}] of type {type(value).__name__}, expected a float (e.g. float(t.detach()))")
    return loss, terms


def _run(
    task: Any, config: TrainConfig, model: torch.nn.Module, curriculum: Any, loop: TrainingLoop, run_dir: Path,
    rank: int, world: int, resume: bool, progress: bool, stop_at_step: int | None, start: dict | None = None,
    device: torch.device | None = None,
) -> None:
    """The body of :func:`train` (its loop is closed, and the run directory unlocked, by the caller)."""
    bpe = config.batches_per_epoch
    total = curriculum.epochs * bpe
    every = config.checkpoint_every or bpe
    program = sys.argv[0]
    if program.endswith("seqmotion"):
        program = "seqmotion"
    elif program.endswith(os.path.join("seqmotion", "cli.py")):
        program = "python -m seqmotion.cli" if world == 1 else f"torchrun --nproc_per_node={world} -m seqmotion.cli"
    device = torch.device("cpu") if device is None else device
    provenance = {"command": command_line(program), "machine": machine_description(), "world_size": world}
    if device.type != "cpu":  # (CPU runs' records stay what they were)
        provenance["device"] = str(device)
    if start:
        provenance["init_from"] = start
    saved = loop.start(resume)
    if saved:
        provenance = {**saved.get("provenance", {}), "resumed_with": provenance}
    step = loop.steps

    bar = tqdm(total=total, initial=step, disable=not progress or rank != 0, desc=f"train {config.task}", unit="batch")
    end = total if stop_at_step is None else min(total, stop_at_step)

    # the task's plumbing, once: typed options, its dynamics at its physics
    options = task.options(config)
    dynamics = task.dynamics(options, task.physics(options))
    # what the model is trained over, recorded with it: a generation at other physics is then flagged for any task
    physics_over = getattr(task, "physics_trained_over", None)
    spans = physics_over(config) if physics_over is not None else {}
    physics_trained = {name: [low, high] for name, (low, high) in spans.items()}

    def draw(s: int) -> tuple[dict, Any, Any]:
        """The curriculum's values, the task's typed parameters and this process's share of the data of step ``s``."""
        stage = curriculum.at(s // bpe + 1, (s % bpe) / bpe)
        params = task.params(stage)
        batch = task.sample(config.batch_size, np.random.default_rng([config.seed, s]), params, options)
        return stage, params, (batch.select(slice(rank, None, world)) if world > 1 else batch)

    # Data are drawn in the loop, not on a prefetch thread: on a 2-core CPU a second thread
    # fights PyTorch's own threads and made steps ~60 % slower (measured).
    wrote_at = None
    while step < end:
        epoch = step // bpe + 1
        stage, params, batch = draw(step)
        # the single-process coins of step `step`; on a data-parallel rank, _RankSlice hands out this rank's share
        coins = torch.Generator(device).manual_seed(int(np.random.default_rng([config.seed, step, 1]).integers(2**62)))

        if world > 1:
            with _RankSlice(coins, rank, world):
                loss, terms = step_loss(task, model, batch, params, options, coins, dynamics)
        else:
            loss, terms = step_loss(task, model, batch, params, options, coins, dynamics)
        loop.step(loss, about=f" (epoch {epoch}): {terms}")
        step = loop.steps

        terms = {"loss": float(loss.detach()), **terms}
        if world > 1:
            values = torch.tensor(list(terms.values()), dtype=torch.float64, device=device)  # nccl: on the GPU
            dist.all_reduce(values)
            terms = dict(zip(terms, (values / world).tolist(), strict=True))
        loop.log({**terms, **{f"param_{k}": v for k, v in stage.items()}}, epoch=epoch)
        if rank == 0:
            bar.set_postfix({k: f"{v:.3g}" for k, v in terms.items()}, refresh=False)
        bar.update(1)

        if step % every == 0 or step == end:
            if rank == 0:
                elapsed = loop.elapsed
                cfg = model_config(
                    config, {"step": step, "elapsed_seconds": elapsed, "last_terms": terms, "provenance": provenance,
                             "physics_trained": physics_trained}
                )
                loop.checkpoint(cfg, {"epoch": epoch, "elapsed_seconds": elapsed, "provenance": provenance})
                ckpt.write_model(run_dir, model.state_dict(), cfg)
                wrote_at = step
            if world > 1:
                dist.barrier()
    bar.close()
    if rank == 0 and wrote_at != loop.steps and loop.steps > 0:
        _repair_exported_model(run_dir, model, loop.steps)


def _repair_exported_model(run_dir: Path, model: torch.nn.Module, step: int) -> None:
    """Rewrite the run's top-level model from its latest checkpoint (the state this run resumed) when a
    kill left it stale (an earlier step) or incomplete (weights and config of different writes)."""
    latest = ckpt.latest_checkpoint(run_dir)
    if latest is None:
        return
    try:
        current = ckpt.model_is_complete(run_dir) and ckpt.read_config(run_dir).get("step") == step
    except ckpt.CheckpointError:
        current = False
    if not current:
        saved = ckpt.read_config(latest)
        ckpt.write_model(run_dir, model.state_dict(), {k: v for k, v in saved.items() if k not in ckpt.HASH_FIELDS})
