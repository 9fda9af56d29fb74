"""The one optimisation loop core every seqmotion training runs on.

:class:`TrainingLoop` owns what a training run needs besides its data and its loss:

* **Adam** over the given parameters (PyTorch's default settings otherwise);
* the **learning-rate schedule** :func:`cosine_learning_rate` — a cosine from ``lr`` down to
  ``lr_final_fraction · lr`` at the last step, exactly ``lr`` throughout when the fraction is 1;
* **gradient clipping** of the global norm (off when ``grad_clip`` is None or 0) and an optional
  hook between backward and clipping (the data-parallel gradient all-reduce);
* **training checkpoints** through :func:`.checkpoint.write_training_checkpoint` (atomic, a
  ``latest`` pointer, old ones pruned): weights, Adam's state, the step counter, the states of
  the run's random generators and whatever extra state the caller adds (epoch, loss history,
  provenance);
* **exact resume** from the latest checkpoint, refused with a :class:`~seqmotion.CheckpointError`
  naming the differing settings when the saved run's identity is not this run's;
* the **metrics log** ``metrics.csv`` (one row per :meth:`TrainingLoop.log` call), which a
  resumed run continues without losing a row it had written up to the checkpoint.

The callers — the seq2seq trainer (:mod:`.trainer`: curriculum, fresh data per step, data
parallelism) and the chapter-5 trainings (:mod:`seqmotion.lfd.train`: epochs over a fixed set
of demonstrations) — keep only what is their own: how a mini-batch and its loss are made, and
when to checkpoint.

A typical use::

    loop = TrainingLoop(model, list(model.parameters()), lr=1e-3, total_steps=n, run_dir=run,
                        identity={"training": config_dict}, generators={"rng": gen})
    state = loop.start()                      # {} for a fresh run, the saved extra state on resume
    while loop.steps < n:
        loop.step(loss_of_next_batch())
        loop.log({"loss": value}, epoch=epoch)
        if loop.steps % every == 0:
            loop.checkpoint(config_dict, {"epoch": epoch})
"""

from __future__ import annotations

import csv
import io
import json
import math
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import torch

from ..errors import CheckpointError, check_number
from ..io import atomic_write_bytes
from . import checkpoint as ckpt

METRICS = "metrics.csv"
"""File name of the metrics log in a run directory."""


def cosine_learning_rate(lr: float, final_fraction: float, step: int, total: int) -> float:
    """Adam's learning rate at optimiser step ``step`` of ``total`` (steps counted from 0).

    A cosine from ``lr`` at step 0 to ``final_fraction · lr`` at step ``total`` (and after);
    with ``final_fraction = 1`` it is exactly ``lr`` at every step (``lr · 1.0``), so a
    constant-rate run is bit for bit plain Adam.
    """
    progress = min(step, total) / max(total, 1)
    return lr * (final_fraction + (1.0 - final_fraction) * 0.5 * (1.0 + math.cos(math.pi * progress)))


class MetricsLog:
    """``metrics.csv``: one row per call of :meth:`write`, its columns fixed by the first row.

    Resume-safe: on opening, the rows of steps ``<= keep_before`` (those up to the checkpoint
    the run resumes from) are written back to the file atomically (readers and a kill see the
    old file or the new one, never a truncated one) and new rows are appended; every row is
    flushed as it is written, so a kill loses nothing already logged. Rows a kill cut short
    (fewer fields than the header) and repeated steps are dropped on reopening, so the log
    holds every step exactly once.
    """

    def __init__(self, path: Path, keep_before: int) -> None:
        self.path = Path(path)
        rows: list[dict[str, str]] = []
        fields: list[str] | None = None
        if self.path.exists() and keep_before > 0:
            with open(self.path, newline="", errors="replace") as f:
                reader = csv.DictReader(f)
                fields = list(reader.fieldnames or []) or None
                seen: set[int] = set()
                for row in reader:
                    step = _step_of(row)
                    if step is None or step > keep_before or step in seen or None in row.values():
                        continue  # a row cut short by a kill, a duplicate, or one after the checkpoint
                    seen.add(step)
                    rows.append(row)
        buffer = io.StringIO(newline="")
        self._fields = fields if rows else None
        if self._fields:
            writer = csv.DictWriter(buffer, fieldnames=self._fields)
            writer.writeheader()
            writer.writerows(rows)
        # a fresh run replaces what an earlier run left there, like opening with "w" did
        atomic_write_bytes(self.path, buffer.getvalue().encode())
        self._file = open(self.path, "a", newline="")
        self._writer: csv.DictWriter | None = None
        if self._fields:
            self._writer = csv.DictWriter(self._file, fieldnames=self._fields, extrasaction="ignore", restval="")

    def write(self, row: dict[str, Any]) -> None:
        """Append one row (its keys name the columns; the first row's keys become the header)."""
        if self._writer is None:
            self._fields = list(row)
            self._writer = csv.DictWriter(self._file, fieldnames=self._fields, extrasaction="ignore", restval="")
            self._writer.writeheader()
        self._writer.writerow(row)
        self._file.flush()

    def close(self) -> None:
        self._file.close()


def _step_of(row: dict[str, Any]) -> int | None:
    try:
        return int(row.get("step") or "")
    except (TypeError, ValueError):
        return None


def _flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    """Nested dicts → ``{"a.b": leaf}`` (lists and scalars are leaves)."""
    if not isinstance(value, dict):
        return {prefix: value}
    out: dict[str, Any] = {}
    for key, item in value.items():
        out.update(_flatten(item, f"{prefix}.{key}" if prefix else str(key)))
    return out


class TrainingLoop:
    """Adam, the learning-rate schedule, clipping, checkpoints, exact resume and the metrics log.

    Args:
        module: the model being trained (its ``state_dict`` is checkpointed and restored).
        params: the parameters Adam updates (usually ``list(module.parameters())``).
        lr: Adam's (initial) learning rate.
        total_steps: optimiser steps of the whole run (the schedule's length).
        lr_final_fraction: the rate at ``total_steps``, relative to ``lr`` (1: constant).
        grad_clip: clip the global gradient norm to this (None or 0: no clipping).
        run_dir: where ``checkpoints/``, ``latest`` and ``metrics.csv`` go (None: no
            checkpoints, no resume, no log).
        identity: what makes a run this run (JSON-serialisable: settings, data hash, layer
            shapes...). It is written into every checkpoint's ``config.json``; resuming from a
            checkpoint whose identity differs is refused.
        ignore: dotted keys of ``identity`` that may differ on resume (checkpoint cadence).
        generators: the run's random generators by name; their states are checkpointed (beside
            the weights, under these names) and restored, so the random stream continues exactly.
        keep_checkpoints: how many training checkpoints to keep.
        metrics: write ``run_dir/metrics.csv``.
        writer: this process writes checkpoints and the log (False on data-parallel ranks > 0,
            which still resume from the checkpoint rank 0 wrote).
        reduce_gradients: called with ``params`` after backward, before clipping (the
            data-parallel all-reduce).
    """

    def __init__(
        self,
        module: torch.nn.Module,
        params: Iterable[torch.nn.Parameter],
        *,
        lr: float,
        total_steps: int,
        lr_final_fraction: float = 1.0,
        grad_clip: float | None = None,
        run_dir: str | Path | None = None,
        identity: dict[str, Any] | None = None,
        ignore: Iterable[str] = (),
        generators: dict[str, torch.Generator] | None = None,
        keep_checkpoints: int = 2,
        metrics: bool = True,
        writer: bool = True,
        reduce_gradients: Callable[[list[torch.nn.Parameter]], None] | None = None,
    ) -> None:
        check_number("lr", lr, minimum=0.0, strict_minimum=True)
        check_number("lr_final_fraction", lr_final_fraction, minimum=0.0, strict_minimum=True, maximum=1.0)
        check_number("total_steps", total_steps, minimum=0, integer=True)
        self.module = module
        self.params = list(params)
        self.optimizer = torch.optim.Adam(self.params, lr=lr)
        self.lr, self.lr_final_fraction, self.total_steps = lr, lr_final_fraction, int(total_steps)
        self.grad_clip = grad_clip
        self.run_dir = None if run_dir is None else Path(run_dir)
        self.identity = json.loads(json.dumps(identity or {}))  # as a checkpoint reads it back
        self.ignore = frozenset(ignore)
        self.generators = dict(generators or {})
        self.keep_checkpoints = keep_checkpoints
        self.writer = writer
        self.reduce_gradients = reduce_gradients
        self._metrics = metrics
        self._log: MetricsLog | None = None
        self._lock = ckpt.RunLock(self.run_dir) if self.run_dir is not None and writer else None
        self.steps = 0
        """Optimiser steps taken (restored on resume); sets the learning rate."""
        self._clock = time.perf_counter()

    # --- starting and resuming -------------------------------------------------------------------

    def start(self, resume: bool = True) -> dict[str, Any]:
        """Resume from ``run_dir``'s latest checkpoint if there is one (and ``resume``); open the log.

        Returns:
            The extra state the checkpoint was written with (``{}`` for a fresh run).

        A writing loop locks ``run_dir`` (:class:`~.checkpoint.RunLock`) until :meth:`close`, and
        removes the temporaries a killed run left there; ``resume=False`` removes the run's old
        checkpoints (a fresh run must not be pruned in favour of an older run's later steps).

        Raises:
            seqmotion.CheckpointError: the checkpoint belongs to another run (its identity
                differs) or is unreadable or does not fit the model.
            seqmotion.errors.RunInUseError: another training is writing into ``run_dir``.
        """
        state: dict[str, Any] = {}
        elapsed = 0.0
        if self._lock is not None:
            self._lock.acquire()
            if not resume:
                ckpt.forget_checkpoints(self.run_dir)
        exists = self.run_dir is not None and self.run_dir.exists()
        latest = ckpt.latest_checkpoint(self.run_dir) if resume and exists else None
        if latest is not None:
            config, tensors, optimizer_state, state = ckpt.read_training_checkpoint(latest)
            self._check_identity(config, latest)
            for name, generator in self.generators.items():
                if name not in tensors:
                    raise CheckpointError(f"{latest} holds no state of the random generator {name!r}")
                generator.set_state(tensors.pop(name))
            ckpt.load_state_dict_strict(self.module, tensors, str(latest))
            self.optimizer.load_state_dict(optimizer_state)
            self.steps = int(state["step"])
            # "seconds": the key chapter-5 checkpoints used before this loop existed
            elapsed = float(state.get("elapsed_seconds", state.get("seconds", 0.0)))
        if self.run_dir is not None and self.writer and self._metrics:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            self._log = MetricsLog(self.run_dir / METRICS, keep_before=self.steps)
        self._clock = time.perf_counter() - elapsed
        return state

    def _check_identity(self, saved: dict[str, Any], where: Path) -> None:
        mine, theirs = _flatten(self.identity), _flatten({k: saved.get(k) for k in self.identity})
        differ = sorted(
            k for k in set(mine) | set(theirs)
            if k not in self.ignore and mine.get(k) != theirs.get(k)
        )
        if differ:
            raise CheckpointError(
                f"cannot resume from {where}: it is a checkpoint of another training (different configuration: "
                f"{differ}); use another output directory, or start over (--no-resume)"
            )

    # --- the step --------------------------------------------------------------------------------

    def learning_rate(self, step: int | None = None) -> float:
        """The rate of optimiser step ``step`` (default: the next one)."""
        return cosine_learning_rate(
            self.lr, self.lr_final_fraction, self.steps if step is None else step, self.total_steps
        )

    def step(self, loss: torch.Tensor, about: str = "") -> None:
        """Backpropagate ``loss``, reduce and clip the gradients, take one Adam step at the scheduled rate.

        Raises:
            FloatingPointError: ``loss`` is not finite (``about`` is added to the message, e.g. the loss terms).
                No step is taken, so the weights stay as they were: a non-finite loss (from non-finite or
                overflowing data, or a diverged run) must never reach the weights and then be saved.
        """
        if not bool(torch.isfinite(loss.detach()).all()):
            raise FloatingPointError(f"non-finite loss at step {self.steps}{about}: {loss.detach().tolist()}")
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if self.reduce_gradients is not None:
            self.reduce_gradients(self.params)
        if self.grad_clip:
            torch.nn.utils.clip_grad_norm_(self.params, self.grad_clip)
        rate = self.learning_rate()
        for group in self.optimizer.param_groups:
            group["lr"] = rate
        self.optimizer.step()
        self.steps += 1

    @property
    def elapsed(self) -> float:
        """Wall time of the run so far [s], counting the time before a resume."""
        return time.perf_counter() - self._clock

    # --- records ---------------------------------------------------------------------------------

    def log(self, values: dict[str, float], **columns: Any) -> None:
        """One row of ``metrics.csv``: ``step``, ``columns`` (e.g. ``epoch``), ``seconds``, then ``values``
        (6 significant digits). A no-op without a run directory or on a non-writing rank."""
        if self._log is None:
            return
        row = {"step": self.steps, **columns, "seconds": f"{self.elapsed:.3f}"}
        row.update({k: f"{v:.6g}" for k, v in values.items()})
        self._log.write(row)

    def checkpoint(self, config: dict[str, Any] | None = None, extra: dict[str, Any] | None = None) -> Path | None:
        """Write ``run_dir/checkpoints/step-<steps>/`` atomically and point ``latest`` at it.

        Args:
            config: what the checkpoint's ``config.json`` holds besides the run's identity
                (e.g. the model's config, so that the checkpoint loads as a model).
            extra: JSON-serialisable state the caller needs back on resume (returned by :meth:`start`).

        Returns:
            The checkpoint directory (None on a non-writing rank).
        """
        if not self.writer:
            return None
        if self.run_dir is None:
            raise ValueError("this training loop has no run directory to write checkpoints to")
        weights = dict(self.module.state_dict())
        for name, generator in self.generators.items():
            if name in weights:
                raise ValueError(f"a random generator is called {name!r}, like one of the model's tensors")
            weights[name] = generator.get_state()
        state = {"step": self.steps, "elapsed_seconds": self.elapsed, **(extra or {})}
        return ckpt.write_training_checkpoint(
            self.run_dir, f"step-{self.steps:08d}", weights, self.optimizer.state_dict(),
            {**(config or {}), **self.identity}, state, keep=self.keep_checkpoints,
        )

    def close(self) -> None:
        """Close the metrics log and release the run directory's lock."""
        if self._log is not None:
            self._log.close()
            self._log = None
        if self._lock is not None:
            self._lock.release()

    def __enter__(self) -> TrainingLoop:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
