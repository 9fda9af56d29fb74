"""Trust signals on every result: predicted uncertainty, the errors that matter, and an out-of-distribution flag.

A trained model only knows the inputs its task's generators drew during training. A sketch far
outside them (five times longer, three times faster) still comes back as a motion — perhaps one
that strays centimetres from the sketch — so every result carries three signals:

* **uncertainty** ``(K, p)`` — the standard deviation of the generated positions per sample, from
  the Gaussian head's covariance propagated through the task's physics (eq. 2.14; the ``pos_cov``
  its dynamics output). Row 0 (the known start) is 0.
* **errors** — the numbers a user judges a result by (:meth:`Task.errors
  <seqmotion.core.task.Task.errors>`): pancake shape RMSE, end-pose error, end speed, largest
  friction-cone violation; sliding tracking RMSE, end error, travel share, pan excursion.
* **out_of_distribution** + **ood_reasons** — whether a cheap feature of the input (length K,
  extent, peak speed, peak implied acceleration per unit group; :func:`input_features`) or the
  predicted end-position uncertainty lies beyond what the model met in training, and which.

The bounds come from a :class:`TrustCalibration`: :func:`calibrate` draws ``n`` inputs from the task's own
training generator (:meth:`Task.sample <seqmotion.core.task.Task.sample>`, at curriculum points spread
over the whole schedule, at the model's options), runs the model on them and keeps, per feature, the
``lower_percentile``/``upper_percentile`` quantiles (length: the smallest and largest K seen). A shipped
model carries it as ``trust.json`` beside its weights (tied to them by the weights' hash);
:func:`calibration_for` loads it, or computes it on the fly (and caches it on the model) for a
run directory without one. ``seqmotion calibrate-trust MODEL`` (re)writes the file.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..io import atomic_write_json, read_json
from ..physics.integrator import DT
from ..physics.layout import StateLayout
from ..training.config import TrainConfig

TRUST_FILE = "trust.json"
"""The calibration's file name, beside ``config.json`` and ``model.safetensors``."""
FORMAT = 1
LOWER_PERCENTILE = 0.5
UPPER_PERCENTILE = 99.5
UNCERTAINTY_FEATURE = "end_std_m"
"""The predicted-uncertainty feature: the predicted std of the end position [m] (metre fields)."""
MARGIN = 0.1
"""Headroom on every upper bound: a feature is out beyond ``(1 + MARGIN) ×`` its upper percentile (the
features have heavy tails: the percentile alone flags too many fresh in-distribution inputs,
``benchmarks/results_trust.md``)."""
DEFAULT_N = 2048
"""Calibration inputs drawn by :func:`calibrate` (a shipped model's ``trust.json``)."""
ON_THE_FLY_N = 512
"""Calibration inputs drawn when a model has no ``trust.json`` (computed once per loaded model)."""


# --- features ------------------------------------------------------------------------------------


def _unit_key(unit: str) -> str:
    return unit.replace("/", "_").replace("²", "2").replace("³", "3").replace(" ", "")


def _mask(lengths: np.ndarray, k: int) -> np.ndarray:
    return np.arange(k)[None, :] < lengths[:, None]


def input_features(
    layout: StateLayout, inputs: np.ndarray, lengths: np.ndarray | None = None, dt: float = DT
) -> dict[str, np.ndarray]:
    """Cheap per-motion features of ``(B, K, dim)`` inputs in ``layout`` (padding past ``lengths`` ignored).

    Columns are grouped by unit: a velocity unit (``…/s``) gives ``peak_speed_<unit>`` (the largest
    norm over the group's columns) and ``peak_accel_<unit>2`` (the largest norm of the implied
    acceleration ``Δv/dt``); any other unit gives ``extent_<unit>`` (the farthest the group gets from
    its first sample). Plus ``length`` (K). E.g. pancake: ``length, extent_m, extent_rad,
    peak_speed_m_s, peak_speed_rad_s, peak_accel_m_s2, peak_accel_rad_s2``.

    Returns:
        feature name → ``(B,)`` float64.
    """
    x = np.asarray(inputs, dtype=np.float64)
    if x.ndim == 2:
        x = x[None]
    b, k, _ = x.shape
    lengths = np.full(b, k) if lengths is None else np.asarray(lengths)
    valid = _mask(lengths, k)
    out: dict[str, np.ndarray] = {"length": lengths.astype(np.float64)}
    groups: dict[str, list[int]] = {}
    for i, unit in enumerate(layout.units):
        groups.setdefault(unit, []).append(i)
    for unit, cols in groups.items():
        block = x[..., cols]
        if unit.endswith("/s"):
            speed = np.where(valid, np.linalg.norm(block, axis=-1), 0.0)
            out[f"peak_speed_{_unit_key(unit)}"] = speed.max(axis=1)
            if k > 1:
                accel = np.linalg.norm(np.diff(block, axis=1), axis=-1) / dt
                accel = np.where(valid[:, 1:], accel, 0.0)
                out[f"peak_accel_{_unit_key(unit)}2"] = accel.max(axis=1)
            else:
                out[f"peak_accel_{_unit_key(unit)}2"] = np.zeros(b)
        elif "/" not in unit:
            reach = np.where(valid, np.linalg.norm(block - block[:, :1], axis=-1), 0.0)
            out[f"extent_{_unit_key(unit)}"] = reach.max(axis=1)
    return out


def position_std(pos_cov: torch.Tensor | np.ndarray, length: int) -> np.ndarray:
    """Per-sample position std ``(B, K, p)`` from the rollout's ``pos_cov`` ``(B, ≥ K-1, p, p)`` (covariance
    of states ``1..``); row 0, the known start, is 0."""
    cov = pos_cov.detach().cpu().numpy() if torch.is_tensor(pos_cov) else np.asarray(pos_cov)
    diag = np.sqrt(np.clip(np.diagonal(cov[:, : length - 1], axis1=-2, axis2=-1), 0.0, None))
    return np.concatenate([np.zeros_like(diag[:, :1]), diag], axis=1)


class HeadCovarianceOnly:
    """A task's dynamics for :func:`~seqmotion.models.seq2seq.rollout` with ``need_cov=True`` that keeps the
    head's input covariances (``Rollout.accel_cov``) but does not propagate them chunk by chunk."""

    def __init__(self, dynamics: Any) -> None:
        self.dynamics = dynamics

    def start(self, x0: torch.Tensor) -> object:
        return self.dynamics.start(x0)

    def step(self, carry: object, mean: torch.Tensor, cov: torch.Tensor | None) -> tuple[object, dict]:
        return self.dynamics.step(carry, mean, None)

    def decoder_input(self, states: torch.Tensor) -> torch.Tensor:
        return self.dynamics.decoder_input(states)

    def restart(self, carry: object, state: torch.Tensor, mask: torch.Tensor) -> object:
        return self.dynamics.restart(carry, state, mask)


def uncertainty_features(
    std: np.ndarray, units: tuple[str, ...], lengths: np.ndarray | None = None
) -> dict[str, np.ndarray]:
    """``end_std_m`` ``(B,)``: the norm of the predicted std of the metre fields at each motion's last sample
    (all fields when none is in metres); ``std`` ``(B, K, p)``, ``units`` the p fields' units."""
    b, k, _ = std.shape
    lengths = np.full(b, k) if lengths is None else np.asarray(lengths)
    cols = [i for i, u in enumerate(units) if u == "m"] or list(range(len(units)))
    end = std[np.arange(b), lengths - 1][:, cols]
    return {UNCERTAINTY_FEATURE: np.linalg.norm(end, axis=-1)}


# --- calibration ---------------------------------------------------------------------------------


@dataclass
class TrustCalibration:
    """Per-feature bounds of what a model met in training (see the module docstring).

    Attributes:
        upper: feature → the largest value still in distribution.
        lower: feature → the smallest value still in distribution (only ``length`` by default).
        n: calibration inputs drawn; seed: their seed.
        weights_sha256: the hash of the weights the calibration belongs to (None: unknown).
        percentiles: the ``(lower, upper)`` percentiles the bounds are.
        source: how the record was made (``"trust.json"``, ``"on the fly"``).
    """

    upper: dict[str, float]
    lower: dict[str, float] = field(default_factory=dict)
    n: int = 0
    seed: int = 0
    weights_sha256: str | None = None
    percentiles: tuple[float, float] = (LOWER_PERCENTILE, UPPER_PERCENTILE)
    margin: float = MARGIN
    source: str = "on the fly"

    def check(self, features: dict[str, np.ndarray]) -> tuple[np.ndarray, list[list[str]]]:
        """Which motions lie outside the bounds, and why.

        Args:
            features: feature → ``(B,)`` values (features without a bound are ignored).

        Returns:
            ``(flags (B,) bool, reasons)``: per motion a list like ``["length 2000 > 500"]``.
        """
        b = len(next(iter(features.values())))
        flags = np.zeros(b, dtype=bool)
        reasons: list[list[str]] = [[] for _ in range(b)]
        for name, values in features.items():
            values = np.asarray(values, dtype=np.float64)
            for bound, out, sign in ((self.upper.get(name), values > (self.upper.get(name) or 0.0), ">"),
                                     (self.lower.get(name), values < (self.lower.get(name) or 0.0), "<")):
                if bound is None:
                    continue
                for i in np.flatnonzero(out):
                    flags[i] = True
                    reasons[i].append(f"{name} {values[i]:.4g} {sign} {bound:.4g}")
        return flags, reasons

    def to_dict(self) -> dict[str, Any]:
        return {"format": FORMAT, **asdict(self), "percentiles": list(self.percentiles)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrustCalibration:
        """The record :meth:`to_dict` wrote (``ValueError`` for anything else)."""
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise ValueError(f"not a trust calibration of format {FORMAT}")
        try:
            return cls(
                upper={str(k): float(v) for k, v in data["upper"].items()},
                lower={str(k): float(v) for k, v in data.get("lower", {}).items()},
                n=int(data.get("n", 0)), seed=int(data.get("seed", 0)),
                weights_sha256=data.get("weights_sha256"),
                percentiles=tuple(float(p) for p in data.get("percentiles", (LOWER_PERCENTILE, UPPER_PERCENTILE))),
                margin=float(data.get("margin", MARGIN)),
                source=TRUST_FILE,
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ValueError(f"not a trust calibration: {exc}") from None


def training_inputs(model: Any, n: int, seed: int = 0, per_draw: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """``n`` fresh inputs from the task's training generator at the model's options: ``(inputs (n, K_max, dim),
    lengths (n,))``, drawn in groups of ``per_draw`` at curriculum points uniform over the whole schedule."""
    record = model.config.get("training")
    if not isinstance(record, dict) or not record:
        raise ValueError("the model's config holds no training record to draw calibration inputs from")
    config = TrainConfig.from_dict(record)
    curriculum = model.task_def.curriculum(config)
    rng = np.random.default_rng(seed)
    parts, lengths = [], []
    done = 0
    while done < n:
        m = min(per_draw, n - done)
        params = model.task_def.params(curriculum.at(int(rng.integers(1, curriculum.epochs + 1)), float(rng.random())))
        batch = model.task_def.sample(m, rng, params, model.task_def.options(config))
        parts.append(batch.states)
        lengths.append(batch.lengths)
        done += m
    k_max = max(p.shape[1] for p in parts)
    padded = [np.concatenate([p, np.repeat(p[:, -1:], k_max - p.shape[1], axis=1)], axis=1) for p in parts]
    return np.concatenate(padded), np.concatenate(lengths)


def predicted_std(model: Any, inputs: np.ndarray, lengths: np.ndarray | None = None, batch: int = 128) -> np.ndarray:
    """The model's per-sample position std ``(B, K_max, p)`` for padded ``(B, K_max, dim)`` inputs."""
    x_all = torch.from_numpy(np.asarray(inputs, dtype=np.float32))
    k_max = x_all.shape[1]
    lengths = np.full(len(x_all), k_max) if lengths is None else np.asarray(lengths)
    out = []
    with torch.inference_mode():
        for i in range(0, len(x_all), batch):
            x = x_all[i : i + batch]
            device = getattr(model, "device", x.device)  # where the network runs (TrainedModel.device)
            z = model.model.encode(x.to(device), torch.from_numpy(lengths[i : i + batch]).to(device))
            _, _, std = model.rollout_with_std(z, model.start_state(x).double(), k_max)
            if std is None:
                raise KeyError("the model's dynamics give no position covariance")
            out.append(std)
    return np.concatenate(out)


def features_of(model: Any, inputs: np.ndarray, lengths: np.ndarray | None = None,
                std: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The input features (:meth:`Task.input_features`) and, with ``std`` ``(B, K, p)``, the uncertainty feature."""
    feats = model.task_def.input_features(inputs, lengths)
    if std is not None:
        feats.update(uncertainty_features(std, model.uncertainty_units, lengths))
    return feats


def calibrate(model: Any, n: int = DEFAULT_N, seed: int = 0,
              percentiles: tuple[float, float] = (LOWER_PERCENTILE, UPPER_PERCENTILE),
              margin: float = MARGIN) -> TrustCalibration:
    """Bounds of the features of ``n`` fresh training inputs (see the module docstring).

    Upper bounds for every feature at ``(1 + margin) ×`` its ``percentiles[1]`` percentile; the length's
    bounds are the smallest and largest K drawn (the training range). A model whose dynamics give no
    ``pos_cov`` gets no uncertainty bound.
    """
    inputs, lengths = training_inputs(model, n, seed)
    try:
        std = predicted_std(model, inputs, lengths)
    except KeyError:  # dynamics without pos_cov
        std = None
    feats = features_of(model, inputs, lengths, std)
    upper = {k: (1 + margin) * float(np.percentile(v, percentiles[1])) for k, v in feats.items() if k != "length"}
    upper["length"] = float(lengths.max())
    if upper.get(UNCERTAINTY_FEATURE, 1.0) <= 0:  # a model that never predicts spread (sliding-B: it never slides)
        del upper[UNCERTAINTY_FEATURE]
    return TrustCalibration(
        upper=upper, lower={"length": float(lengths.min())}, n=int(n), seed=int(seed),
        weights_sha256=model.config.get("weights_sha256"), percentiles=tuple(percentiles), margin=margin,
        source="calibrate",
    )


def read_calibration(directory: str | Path, weights_sha256: str | None = None) -> TrustCalibration | None:
    """``directory/trust.json``; ``None`` when there is none, or (given ``weights_sha256``) when it is for other
    weights (a stale calibration: the caller computes one).

    Raises:
        ValueError: naming the file, when it is there but unreadable, not strict JSON (:func:`seqmotion.io.read_json`)
            or not a trust calibration.
    """
    path = Path(directory) / TRUST_FILE
    data = read_json(path, "trust calibration", missing=None)
    if data is None:
        return None
    try:
        record = TrustCalibration.from_dict(data)
    except ValueError as exc:
        raise ValueError(f"trust calibration {path}: {exc}") from None
    if weights_sha256 is not None and record.weights_sha256 not in (None, weights_sha256):
        return None
    return record


def write_calibration(model: Any, directory: str | Path, n: int = DEFAULT_N, seed: int = 0) -> Path:
    """Calibrate ``model`` and write ``directory/trust.json`` atomically; returns the path."""
    record = calibrate(model, n, seed)
    path = Path(directory) / TRUST_FILE
    atomic_write_json(path, record.to_dict())
    record.source = TRUST_FILE
    model.trust_calibration = record
    return path


def calibration_for(model: Any) -> TrustCalibration:
    """The model's calibration: cached on it, else its directory's ``trust.json``, else computed on the fly
    (:data:`ON_THE_FLY_N` inputs) and cached."""
    record = getattr(model, "trust_calibration", None)
    if record is None:
        source = getattr(model, "source_dir", None)
        if source is not None:
            record = read_calibration(source, model.config.get("weights_sha256"))
        if record is None:
            record = calibrate(model, ON_THE_FLY_N)
        model.trust_calibration = record
    return record


def missed(errors: dict[str, Any], tolerances: dict[str, float]) -> list[str]:
    """Messages for every error beyond its tolerance (for a batch: the worst motion), e.g.
    ``"tracking_rmse 42.0 mm > tolerance 5.0 mm"``."""
    out = []
    for name, limit in tolerances.items():
        if name in errors:
            worst = float(np.max(errors[name]))
            if worst > limit:
                out.append(f"{format_error(name, worst)} > tolerance {format_error(name, limit).split(' ', 1)[1]}")
    return out


def format_error(name: str, value: float) -> str:
    """``"shape_rmse 9.2 mm"``, ``"max_violation_rad 0.0000 rad"``… (metres shown in millimetres)."""
    if name.endswith("_m_s"):
        return f"{name[:-4]} {value:.3f} m/s"
    if name.endswith("_m"):
        return f"{name[:-2]} {1000 * value:.1f} mm"
    if name.endswith("_rad"):
        return f"{name[:-4]} {value:.4f} rad"
    return f"{name} {value:.3g}"


def summary_lines(
    errors: dict[str, Any] | None, uncertainty: np.ndarray | None, out_of_distribution: Any,
    ood_reasons: list | None, tolerances: dict[str, float], names: tuple[str, ...] = (),
    units: tuple[str, ...] = (),
) -> list[str]:
    """What the command lines print under a result: its errors, the predicted std at its end, and a
    ``warning:`` line per missed tolerance and for an input out of distribution (one motion; for a
    batch, the worst motion and the share flagged).

    Args:
        uncertainty: ``(K, p)`` or ``(B, K, p)`` predicted std; ``names``/``units``: its columns.
    """
    lines = []
    if errors:
        worst = {k: float(np.max(v)) for k, v in errors.items()}
        label = "errors" if np.ndim(next(iter(errors.values()))) == 0 else "errors (worst of the batch)"
        lines.append(f"{label}: " + ", ".join(format_error(k, v) for k, v in worst.items()))
    if uncertainty is not None:
        end = np.asarray(uncertainty)[..., -1, :].reshape(-1, np.shape(uncertainty)[-1]).max(axis=0)
        parts = []
        for i, v in enumerate(end):
            name = names[i] if i < len(names) else f"p{i}"
            unit = units[i] if i < len(units) else ""
            parts.append(f"{name} {1000 * v:.1f} mm" if unit == "m" else f"{name} {v:.4g} {unit}".rstrip())
        lines.append("predicted std at the end (the model's own uncertainty): " + ", ".join(parts))
    if errors:
        lines += [f"warning: {m}" for m in missed(errors, tolerances)]
    flags = np.atleast_1d(np.asarray(out_of_distribution if out_of_distribution is not None else False, dtype=bool))
    if flags.any():
        reasons = ood_reasons or []
        if reasons and isinstance(reasons[0], list):  # a batch: the first flagged motion's reasons
            reasons = reasons[int(np.flatnonzero(flags)[0])]
        share = f" ({flags.sum()} of {flags.size} motions)" if flags.size > 1 else ""
        lines.append(f"warning: the input lies outside what the model was trained on{share}: "
                     f"{'; '.join(reasons)} — expect it to stray; check the errors")
    return lines


__all__ = [
    "HeadCovarianceOnly", "TRUST_FILE", "TrustCalibration", "calibrate", "calibration_for", "features_of",
    "format_error", "input_features", "missed", "position_std", "predicted_std",
    "read_calibration", "summary_lines", "training_inputs", "uncertainty_features", "write_calibration",
]
