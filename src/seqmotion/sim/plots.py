"""Figures of the robot experiments: tracking (Fig. 2.8), ψ on the robot (Fig. 2.9), sliding (Fig. 3.8)."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import Any

import numpy as np

from ..io import pyplot, save_figure
from ..physics.integrator import implied_accel
from ..tasks.pancake.physics import check_mu, cone_half_angle, psi
from .pancake import PancakeResult
from .sliding import SlidingResult


def _save(fig: Any, path: str | Path) -> Path:
    """Lay out ``fig``, write it to ``path`` (130 dpi, the format of the suffix; parent folders made) and close it."""
    fig.tight_layout()
    return save_figure(fig, path, close=True, dpi=130)


def plot_pancake_tracking(
    states: np.ndarray, result: PancakeResult, path: str | Path, original: np.ndarray | None = None
) -> Path:
    """Fig. 2.8: y, z, θ of the original input (dotted), the command (dashed) and the robot (solid).

    Args:
        states: ``(K, 6)`` the executed command (e.g. the deformed trajectory).
        result: what :func:`~seqmotion.sim.run_pancake` returned for ``states``.
        original: ``(K', 6)`` the undeformed input, if any.
    """
    plt = pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(6.5, 6), sharex=True)
    t = result.time * 1e3
    for i, (ax, name, unit) in enumerate(zip(axes, ("y", "z", "θ"), ("m", "m", "rad"), strict=True)):
        if original is not None:
            ax.plot(np.arange(len(original)), original[:, i], ":", color="tab:blue", label="original")
        ax.plot(np.arange(len(states)), states[:, i], "--", color="tab:blue", label="command")
        ax.plot(t, result.response[:, i], "-", color="tab:red", lw=1.2, label="robot")
        ax.axvline(result.n_motion - 1, color="0.7", lw=0.8)
        ax.set_ylabel(f"{name} [{unit}]")
    axes[0].legend(fontsize=8, loc="best")
    axes[-1].set_xlabel("time [ms] (grey: end of the input; then 0.1 s deceleration)")
    fig.suptitle(f"Tracking: {result.position_rmse * 1e3:.1f} mm, {math.degrees(result.attitude_rmse):.2f}° RMSE")
    return _save(fig, path)


def plot_pancake_psi(deformed: Any, result: PancakeResult, path: str | Path, mu: float | None = None) -> Path:
    """Fig. 2.9: ψ of the commanded motion and of the robot's, with the friction cone shaded.

    Args:
        deformed: an object with ``states (K, 6)`` and ``accel (K-1, 3)`` (a deformer's result), or
            a ``(K, 6)`` states array (its accelerations are taken from its velocities).
        result: the robot run of those states.
        path: the PNG to write.
        mu: friction coefficient of the shaded cone ``|ψ| ≤ atan μ``; default the μ the run
            was judged with (``result.mu``, the ``mu`` given to :func:`~seqmotion.sim.run_pancake`).
    """
    plt = pyplot()
    if hasattr(deformed, "states"):
        states, accel = np.asarray(deformed.states), np.asarray(deformed.accel)
    else:
        states = np.asarray(deformed)
        accel = implied_accel(states)
    k = result.n_motion
    resp = result.response[:k]
    if k >= 2:
        # The robot's accelerations are differences of measured velocities; contact impacts (a
        # pancake sliding off) make 1 ms spikes, so the plot shows a 5 ms moving mean.
        acc = np.diff(resp[:, 3:], axis=0) / 1e-3
        kernel = np.ones(5) / 5
        acc = np.stack([np.convolve(np.pad(a, 2, mode="edge"), kernel, mode="valid") for a in acc.T], axis=1)
        resp_psi = psi(resp, acc)
    else:
        resp_psi = np.zeros(0)
    mu = result.mu if mu is None else mu
    cone = cone_half_angle(check_mu(mu))
    fig, ax = plt.subplots(figsize=(6.5, 3.2))
    ax.axhspan(-cone, cone, color="tab:blue", alpha=0.15, label="friction cone")
    ax.plot(np.arange(len(accel)), psi(states, accel), "--", color="tab:blue", label="command")
    ax.plot(np.arange(len(resp_psi)), resp_psi, "-", color="tab:red", lw=1.0, label="robot (5 ms mean)")
    ax.set(xlabel="time [ms]", ylabel="arg(g − u) − θ [rad]", ylim=(-math.pi, math.pi))
    ax.legend(fontsize=8, loc="best")
    return _save(fig, path)


def plot_sliding(result: SlidingResult, path: str | Path, label: str = "") -> Path:
    """Fig. 3.8: the object's path in the pan frame against the command, and the pan's path."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(9, 4))
    k = result.n_motion
    if result.command is not None:
        axes[0].plot(result.command[:, 0], result.command[:, 1], "--", color="0.3", label="command")
    axes[0].plot(result.object_path[:k, 0], result.object_path[:k, 1], "-", color="tab:red", label="object (robot)")
    axes[0].set(xlabel="x_d [m]", ylabel="y_d [m]", title="(a) object, pan frame", aspect="equal")
    axes[1].plot(result.pan_command[:k, 0], result.pan_command[:k, 1], "--", color="0.3", label="command")
    axes[1].plot(result.pan_response[:k, 0], result.pan_response[:k, 1], "-", color="tab:blue", label="pan (robot)")
    axes[1].set(xlabel="x_p [m]", ylabel="y_p [m]", title="(b) frying pan", aspect="equal")
    for ax in axes:
        ax.legend(fontsize=8)
    rmse = "" if result.rmse is None else f"object RMSE {result.rmse * 1e3:.1f} mm"
    fig.suptitle(f"{label} {rmse}".strip())
    return _save(fig, path)


def snapshot_steps(result: PancakeResult, n_snapshots: int = 6) -> list[int]:
    """The control periods :func:`~seqmotion.sim.run_pancake` (``snapshots=``) renders for ``result``: ``n``
    evenly over the input motion (the rule of :meth:`seqmotion.sim.arm.Media.plan`)."""
    last = min(len(result.time), result.n_motion) - 1
    return sorted(set(np.linspace(0, last, n_snapshots).round().astype(int).tolist()))


def snapshot_labels(name: str, result: PancakeResult, steps: list[int]) -> tuple[str, list[str]]:
    """A snapshot row's title (the run's name and :meth:`PancakeResult.describe`, the line the demo prints: the
    task, how the motion carried the pancake, and what happened after it) and one label per frame: its time and
    ``"off"`` once the pancake has lost contact (slip > ``SLIP_LIMIT`` or gap > ``GAP_LIMIT``, the test behind
    ``contact_lost``) at or before that frame, else ``"on"`` (``"t = 0.25 s: on"``); a frame after the input motion
    says so (``"(stopping)"``: the deceleration tail; :func:`snapshot_steps` renders none there)."""
    from .pancake import GAP_LIMIT, SLIP_LIMIT

    lost = (result.slip > SLIP_LIMIT) | (result.gap > GAP_LIMIT)
    labels = []
    for k in steps:
        k = min(k, len(lost) - 1)
        state = "off" if lost[: k + 1].any() else "on"
        tail = " (stopping)" if k >= result.n_motion else ""
        labels.append(f"t = {result.time[k]:.2f} s: {state}{tail}")
    return f"{name}: {result.describe()}", labels


def plot_snapshot_rows(rows: list[tuple[str, list[str], np.ndarray]], path: str | Path) -> Path:
    """Snapshot strips of several runs, one row each, titled and labelled per frame.

    Args:
        rows: ``(title, labels, strip)`` per run; ``strip`` ``(H, W, 3|4)`` the PNG
            :func:`~seqmotion.sim.render.write_strip` wrote (frames side by side, 6 px apart, one per label).
        path: the PNG to write.
    """
    plt = pyplot()
    width = max(strip.shape[1] for _, _, strip in rows) / 100
    # describe() is one long line: wrapped to the row's width (about 10 px per character at 14 pt), 0.3 in a line.
    titles = [textwrap.fill(title, max(40, strip.shape[1] // 10)) for title, _, strip in rows]
    height = sum(s.shape[0] for _, _, s in rows) / 100 + sum(0.4 + 0.3 * (t.count("\n") + 1) for t in titles)
    fig, axes = plt.subplots(len(rows), 1, figsize=(width, height), squeeze=False)
    for ax, title, (_, labels, strip) in zip(axes[:, 0], titles, rows, strict=True):
        ax.imshow(strip)
        ax.axis("off")
        ax.set_title(title, fontsize=14, loc="left")
        n, w = len(labels), strip.shape[1]
        frame = (w - 6 * (n - 1)) / n
        for i, label in enumerate(labels):
            colour = "tab:red" if ": off" in label else "tab:green"
            ax.text((i * (frame + 6) + frame / 2) / w, 0.97, label, transform=ax.transAxes, ha="center",
                    va="top", fontsize=13, color=colour, bbox={"facecolor": "white", "alpha": 0.8, "lw": 0})
    return _save(fig, path)
