"""Load a LeRobotDataset v3.0 folder with LeRobot's own loader and check what it yields.

Run with the python of the separate LeRobot venv (see README.md beside this file), never with
seqmotion's venv: this script imports only LeRobot, torch and their dependencies.

    python check_load.py ROOT [--repo-id ID] [--horizon 10] [--batch-size 16]
    python check_load.py --make-tiny DIR [--videos]      # write a tiny dataset with LeRobot's writer

It opens ``LeRobotDataset(repo_id, root=ROOT, delta_timestamps=...)`` with an ACT-style chunk of
future actions (``action``: ``[i / fps for i in range(horizon)]``) and the previous + current
state (``observation.state``: ``[-1 / fps, 0]``), iterates every item through a ``DataLoader``
and checks, against the raw parquet columns and ``meta/``:

* frame and episode counts against ``meta/info.json`` (and the parquet rows, not ``len(ds)``,
  which LeRobot takes from info.json itself);
* ``index`` = 0..N-1, each episode a contiguous block ``[dataset_from_index, dataset_to_index)``
  with ``frame_index`` = 0..len-1 and ``timestamp`` = ``frame_index / fps`` (LeRobot maps
  ``delta_timestamps`` and video frames through these);
* each item: shapes and dtypes (``(horizon, action_dim)``, ``(2, state_dim)``, images
  ``(C, H, W)`` float32 in [0, 1]), no NaN, the ``*_is_pad`` masks, the chunk values equal the
  raw rows they should come from, and ``task`` equal to the episode's task;
* ``meta/stats.json`` shapes (what a policy normalises with).

Prints one JSON object on stdout (versions, counts, features and shapes, seconds, problems) and
exits 1 when any problem was found, 2 on a usage error (no such folder). The hub is never
contacted: ``HF_HUB_OFFLINE=1`` is set before LeRobot is imported, and the folder must exist.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any

# Offline before huggingface_hub / datasets / lerobot read their environment at import.
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")

META_KEYS = ("timestamp", "frame_index", "episode_index", "index", "task_index")
TS_TOL_S = 1e-4  # LeRobot's default tolerance_s
MAX_PROBLEMS = 50  # keep the JSON readable when something is wrong on every row


def _versions() -> dict[str, str | None]:
    """Versions of the packages the load depends on (None where not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    out: dict[str, str | None] = {"python": sys.version.split()[0]}
    for name in ("lerobot", "torch", "torchvision", "torchcodec", "datasets", "pyarrow", "pandas",
                 "numpy", "av", "huggingface-hub"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


def _tail(exc: BaseException, lines: int = 6) -> str:
    """Last lines of a traceback: where LeRobot failed and what it said."""
    text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__)).rstrip()
    return "\n".join(text.splitlines()[-lines:])


def _chw(ft: dict[str, Any]) -> tuple[int, int, int]:
    """(C, H, W) that LeRobot returns for an image/video feature declared in info.json.

    info.json declares images as (H, W, C) with names [height, width, channels] (LeRobot's own
    writer) or (C, H, W) with names [channels, height, width]; the loader always yields (C, H, W).
    """
    shape = tuple(ft["shape"])
    names = ft.get("names") or []
    if list(names)[:3] == ["channels", "height", "width"]:
        return shape  # type: ignore[return-value]
    if list(names)[:3] == ["height", "width", "channels"] or shape[-1] in (1, 3, 4):
        return (shape[2], shape[0], shape[1])
    return shape  # type: ignore[return-value]


def _policy_types(feats: dict[str, dict], problems: Problems) -> dict[str, str]:
    """Feature key -> LeRobot policy FeatureType name (STATE, ENV, VISUAL, ACTION) via LeRobot's own mapping."""
    from lerobot.datasets.utils import dataset_to_policy_features

    try:
        return {k: f"{v.type.name} {list(v.shape)}" for k, v in dataset_to_policy_features(feats).items()}
    except Exception as exc:  # noqa: BLE001
        problems.add(f"dataset_to_policy_features raised {type(exc).__name__}: {exc}")
        return {}


class Problems(list):
    """Problems found, capped at MAX_PROBLEMS entries (the count is kept)."""

    count = 0

    def add(self, msg: str) -> None:
        self.count += 1
        if len(self) < MAX_PROBLEMS:
            self.append(msg)


def check(root: Path, repo_id: str, horizon: int, batch_size: int, video_backend: str | None,
          limit: int, compare: Path | None = None) -> dict[str, Any]:
    """Open ``root`` with LeRobot, iterate it and return the summary (``problems`` empty = ok)."""
    t_start = time.perf_counter()
    problems = Problems()
    warnings: list[str] = []
    summary: dict[str, Any] = {"root": str(root), "repo_id": repo_id, "versions": _versions()}

    info = json.loads((root / "meta" / "info.json").read_text())
    fps = info["fps"]
    feats = info["features"]
    summary.update(codebase_version=info.get("codebase_version"), fps=fps)
    delta: dict[str, list[float]] = {}
    for key, d in (("action", [i / fps for i in range(horizon)]), ("observation.state", [-1 / fps, 0.0])):
        if key in feats:
            delta[key] = d
        else:
            problems.add(f"info.json: no feature '{key}' (ACT-style training needs it)")
    summary["delta_timestamps"] = {k: [round(x, 6) for x in v] for k, v in delta.items()}

    import numpy as np
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    t0 = time.perf_counter()
    try:
        ds = LeRobotDataset(repo_id, root=root, delta_timestamps=delta or None, video_backend=video_backend)
    except Exception as exc:  # noqa: BLE001 - report whatever LeRobot raised, verbatim
        problems.add(f"LeRobotDataset(...) raised {type(exc).__name__}:\n{_tail(exc)}")
        summary.update(problems=list(problems), problem_count=problems.count, ok=False,
                       seconds={"total": round(time.perf_counter() - t_start, 2)})
        return summary
    t_open = time.perf_counter() - t0
    summary["video_backend"] = ds.video_backend if ds.meta.video_keys else None

    # --- counts: info.json vs the parquet rows and meta/episodes ---
    n_rows = len(ds.hf_dataset)
    eps = ds.meta.episodes
    n_info, e_info = info["total_frames"], info["total_episodes"]
    if n_rows != n_info:
        problems.add(f"data/*.parquet has {n_rows} rows, info.json total_frames = {n_info}")
    if len(eps) != e_info:
        problems.add(f"meta/episodes has {len(eps)} rows, info.json total_episodes = {e_info}")
    tasks = ds.meta.tasks  # DataFrame indexed by the task string, column task_index
    if len(tasks) != info.get("total_tasks", len(tasks)):
        problems.add(f"meta/tasks.parquet has {len(tasks)} tasks, info.json total_tasks = {info.get('total_tasks')}")
    # LeRobot maps task_index -> string by *row position* (tasks.iloc[i].name), so the rows must be in order.
    if list(tasks["task_index"]) != list(range(len(tasks))):
        problems.add(f"meta/tasks.parquet task_index column is {list(tasks['task_index'])[:10]}..., "
                     "not 0..n-1 in row order (LeRobot would return the wrong task string)")

    # --- raw columns: index / episodes / frame_index / timestamp ---
    raw_keys = [k for k in (*META_KEYS, *delta) if k in ds.hf_dataset.column_names]
    raw = ds.hf_dataset.select_columns(raw_keys).with_format("numpy")[:]
    raw = {k: np.asarray(v) for k, v in raw.items()}
    for k in META_KEYS:
        if k not in raw:
            problems.add(f"data parquet: no column '{k}'")
    if all(k in raw for k in META_KEYS):
        if not np.array_equal(raw["index"], np.arange(n_rows)):
            problems.add("data parquet: 'index' is not 0..N-1 in row order")
        ep_len: dict[int, int] = {}
        for row in eps:
            e, a, b = int(row["episode_index"]), int(row["dataset_from_index"]), int(row["dataset_to_index"])
            ep_len[e] = b - a
            if row.get("length") is not None and int(row["length"]) != b - a:
                problems.add(f"meta/episodes ep {e}: length {row['length']} != to-from {b - a}")
            if not (0 <= a < b <= n_rows):
                problems.add(f"meta/episodes ep {e}: rows [{a}, {b}) outside 0..{n_rows}")
                continue
            if not np.all(raw["episode_index"][a:b] == e):
                problems.add(f"ep {e}: rows [{a}, {b}) do not all carry episode_index {e}")
            if not np.array_equal(raw["frame_index"][a:b], np.arange(b - a)):
                problems.add(f"ep {e}: frame_index is not 0..{b - a - 1}")
            ts = raw["timestamp"][a:b].astype(np.float64)
            err = np.abs(ts - np.arange(b - a) / fps).max()
            if err > TS_TOL_S:
                problems.add(f"ep {e}: timestamp deviates from frame_index/fps by up to {err:.3g} s (> {TS_TOL_S})")
            ep_tasks = list(row.get("tasks") or [])
            names = {tasks.index[i] for i in np.unique(raw["task_index"][a:b]) if 0 <= i < len(tasks)}
            if ep_tasks and not names <= set(ep_tasks):
                problems.add(f"ep {e}: task_index gives {sorted(names)}, meta/episodes tasks = {ep_tasks}")
        if sorted(ep_len) != list(range(len(eps))):
            problems.add(f"meta/episodes episode_index is not 0..{len(eps) - 1}")
        if sum(ep_len.values()) != n_rows:
            problems.add(f"episode lengths sum to {sum(ep_len.values())}, data has {n_rows} rows")
        if not np.array_equal(np.unique(raw["episode_index"]), np.arange(len(eps))):
            problems.add("data parquet: episode_index values are not 0..E-1")
        bad_t = (raw["task_index"] < 0) | (raw["task_index"] >= len(tasks))
        if bad_t.any():
            problems.add(f"data parquet: {int(bad_t.sum())} rows with task_index outside 0..{len(tasks) - 1}")

    # --- stats.json: what normalisation uses ---
    stats = ds.meta.stats
    if stats is None:
        warnings.append("meta/stats.json missing: LeRobot loads, but policies cannot normalise")
    else:
        for key, ft in feats.items():
            if key in META_KEYS:
                continue
            if key not in stats:
                warnings.append(f"stats.json: no entry for '{key}'")
                continue
            want = (_chw(ft)[0], 1, 1) if ft["dtype"] in ("image", "video") else tuple(ft["shape"])
            for s in ("mean", "std", "min", "max"):
                got = np.asarray(stats[key].get(s)) if s in stats[key] else None
                if got is None:
                    problems.add(f"stats.json['{key}']: no '{s}'")
                elif got.shape != want:
                    problems.add(f"stats.json['{key}']['{s}'] has shape {got.shape}, expected {want}")
                elif not np.all(np.isfinite(got)):
                    problems.add(f"stats.json['{key}']['{s}'] is not finite")

    # --- iterate every item the way a training loop does ---
    expect: dict[str, tuple[tuple[int, ...], torch.dtype]] = {}
    for key, ft in feats.items():
        if ft["dtype"] in ("image", "video"):
            shape, dt = _chw(ft), torch.float32
        elif ft["dtype"] == "string":
            continue
        else:
            shape = () if tuple(ft["shape"]) == (1,) else tuple(ft["shape"])
            dt = getattr(torch, ft["dtype"])
        if key in delta:
            shape = (len(delta[key]), *shape)
        expect[key] = (shape, dt)
    loaded_shapes: dict[str, list[int]] = {}
    frame_idx = raw.get("frame_index")
    ep_of = raw.get("episode_index")
    bounds = {int(r["episode_index"]): (int(r["dataset_from_index"]), int(r["dataset_to_index"])) for r in eps}

    t0 = time.perf_counter()
    seen = 0
    seen_eps: set[int] = set()
    # len(ds) is info.json's total_frames: iterate what a training loop would ask for.
    n_total = len(ds) if limit <= 0 else min(limit, len(ds))
    subset = ds if n_total == len(ds) else torch.utils.data.Subset(ds, range(n_total))
    loader = torch.utils.data.DataLoader(subset, batch_size=batch_size, shuffle=False, num_workers=0)
    try:
        for batch in loader:
            bsz = len(batch["index"])
            rows = np.arange(seen, seen + bsz)
            for key, (shape, dt) in expect.items():
                if key not in batch:
                    problems.add(f"item has no '{key}' (declared in info.json)")
                    continue
                v = batch[key]
                loaded_shapes[key] = list(v.shape[1:])
                if tuple(v.shape[1:]) != shape or v.dtype != dt:
                    problems.add(f"'{key}': got {tuple(v.shape[1:])} {v.dtype}, expected {shape} {dt}")
                    continue
                if v.is_floating_point() and torch.isnan(v).any():
                    problems.add(f"'{key}': NaN in rows {rows[0]}..{rows[-1]}")
                if feats[key]["dtype"] in ("image", "video") and (v.min() < 0 or v.max() > 1):
                    problems.add(f"'{key}': values outside [0, 1] in rows {rows[0]}..{rows[-1]}")
            if frame_idx is not None:
                for k in ("index", "episode_index", "frame_index", "task_index"):
                    if k in batch and not np.array_equal(batch[k].numpy(), raw[k][rows]):
                        problems.add(f"'{k}' of items {rows[0]}..{rows[-1]} differs from the parquet rows")
                if "timestamp" in batch and np.abs(batch["timestamp"].numpy() - raw["timestamp"][rows]).max() > 0:
                    problems.add(f"'timestamp' of items {rows[0]}..{rows[-1]} differs from the parquet rows")
                want_task = [tasks.index[i] for i in raw["task_index"][rows]]
                if list(batch.get("task", [])) != want_task:
                    problems.add(f"'task' of items {rows[0]}..{rows[-1]} is {list(batch.get('task', []))[:2]}..., "
                                 f"expected {want_task[:2]}...")
                # delta chunks: the value at offset d must be the raw row i+d clamped into the episode,
                # and *_is_pad must flag exactly the offsets that leave the episode.
                for key, d_ts in delta.items():
                    if key not in batch or f"{key}_is_pad" not in batch or key not in raw:
                        problems.add(f"item has no '{key}' chunk or '{key}_is_pad'")
                        continue
                    offs = np.rint(np.asarray(d_ts) * fps).astype(int)
                    a = np.array([bounds[int(e)][0] for e in ep_of[rows]])
                    b = np.array([bounds[int(e)][1] for e in ep_of[rows]])
                    tgt = rows[:, None] + offs[None, :]
                    pad = (tgt < a[:, None]) | (tgt >= b[:, None])
                    src = np.clip(tgt, a[:, None], b[:, None] - 1)
                    if not np.array_equal(batch[f"{key}_is_pad"].numpy(), pad):
                        problems.add(f"'{key}_is_pad' wrong in items {rows[0]}..{rows[-1]}")
                    want = raw[key][src]
                    got = batch[key].numpy().reshape(want.shape) if batch[key].numel() == want.size else None
                    if got is None or not np.array_equal(got, want, equal_nan=want.dtype.kind == "f"):
                        problems.add(f"'{key}' chunk of items {rows[0]}..{rows[-1]} is not the rows at "
                                     f"offsets {offs.tolist()}")
                seen_eps.update(int(e) for e in ep_of[rows])
            seen += bsz
    except Exception as exc:  # noqa: BLE001 - report where LeRobot failed while reading
        problems.add(f"iterating failed after {seen} items with {type(exc).__name__}:\n{_tail(exc)}")
    t_iter = time.perf_counter() - t0
    if compare is not None:
        try:
            summary["compare"] = compare_cameras(ds, compare, problems)
        except Exception as exc:  # noqa: BLE001
            problems.add(f"compare failed with {type(exc).__name__}:\n{_tail(exc)}")

    if seen != n_total:
        problems.add(f"iterated {seen} items, expected {n_total}")
    elif limit <= 0 and len(seen_eps) != len(eps):
        problems.add(f"items cover {len(seen_eps)} episodes, meta/episodes has {len(eps)}")

    summary.update(
        frames={"info_json": n_info, "parquet_rows": n_rows, "len_dataset": len(ds), "iterated": seen},
        episodes={"info_json": e_info, "meta_episodes": len(eps), "iterated": len(seen_eps)},
        tasks=list(tasks.index)[:10],
        features={k: {"dtype": ft["dtype"], "info_shape": list(ft["shape"]),
                      "item_shape": loaded_shapes.get(k)} for k, ft in feats.items()},
        # how a LeRobot policy config would see each feature (ACT reads only observation.state as robot
        # state, plus ENV and VISUAL features; other STATE features are ignored by it)
        policy_features=_policy_types(feats, problems),
        image_keys=list(ds.meta.image_keys), video_keys=list(ds.meta.video_keys),
        batch_size=batch_size,
        seconds={"open": round(t_open, 2), "iterate": round(t_iter, 2),
                 "total": round(time.perf_counter() - t_start, 2)},
        items_per_s=round(seen / t_iter, 1) if t_iter > 0 else None,
        warnings=warnings, problems=list(problems), problem_count=problems.count, ok=problems.count == 0,
    )
    return summary


def compare_cameras(ds: Any, other_root: Path, problems: Problems) -> dict[str, Any]:
    """Compare each camera frame of ``ds`` with the same item of another export of the same data.

    Meant for the mp4 export against the PNG export: the mean |difference| is the codec's loss, and
    a decoded frame that matches a neighbouring PNG better than its own means frames are shifted.
    """
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    other = LeRobotDataset(f"local/{other_root.name}", root=other_root)
    out: dict[str, Any] = {"other_root": str(other_root)}
    if len(other) != len(ds):
        problems.add(f"compare: {other_root} has {len(other)} items, this one {len(ds)}")
        return out
    for key in ds.meta.camera_keys:
        if key not in other.meta.camera_keys:
            problems.add(f"compare: '{key}' not in {other_root}")
            continue
        mine = torch.stack([ds[i][key] for i in range(len(ds))])
        ref = torch.stack([other[i][key] for i in range(len(other))])
        d0 = (mine - ref).abs().mean(dim=(1, 2, 3))
        d_prev = (mine[1:] - ref[:-1]).abs().mean(dim=(1, 2, 3))  # my frame i vs their frame i-1
        d_next = (mine[:-1] - ref[1:]).abs().mean(dim=(1, 2, 3))  # my frame i vs their frame i+1
        # Strictly closer only: a static scene (equal neighbours) is not a shift, a shift at a
        # change of scene (e.g. an episode boundary) is.
        shifted = int((d_prev < d0[1:]).sum() + (d_next < d0[:-1]).sum())
        step = (ref[1:] - ref[:-1]).abs().mean(dim=(1, 2, 3))
        out[key] = {"mean_abs_diff": round(float(d0.mean()), 4), "max_item_mean_abs_diff": round(float(d0.max()), 4),
                    "max_pixel_abs_diff": round(float((mine - ref).abs().max()), 4),
                    "items_closer_to_a_neighbour": shifted,
                    "consecutive_frames_that_differ": int((step > 0).sum()),
                    "max_mean_abs_diff_between_consecutive_frames": round(float(step.max()), 4)}
        if shifted:
            problems.add(f"compare '{key}': {shifted} frames match a neighbouring frame of {other_root} better")
        if float(d0.max()) > 0.1:
            problems.add(f"compare '{key}': a frame differs by {float(d0.max()):.3f} on average from {other_root}")
    return out


def make_tiny(root: Path, videos: bool, fps: int = 10) -> None:
    """Write a tiny dataset (3 episodes of 7, 12 and 5 frames, 2 tasks) with LeRobot's own writer."""
    import numpy as np
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    features = {
        "observation.state": {"dtype": "float32", "shape": (4,), "names": ["x", "y", "vx", "vy"]},
        "action": {"dtype": "float32", "shape": (2,), "names": ["fx", "fy"]},
        "observation.images.webcam": {"dtype": "video" if videos else "image", "shape": (24, 32, 3),
                                      "names": ["height", "width", "channels"]},
    }
    ds = LeRobotDataset.create("local/tiny", fps, root=root, features=features, use_videos=videos,
                               robot_type="tiny", vcodec="h264" if videos else "libsvtav1")
    rng = np.random.default_rng(0)
    for e, (n, task) in enumerate([(7, "push left"), (12, "push right"), (5, "push left")]):
        for i in range(n):
            img = np.full((24, 32, 3), (10 * e + 8 * i) % 256, dtype=np.uint8)
            ds.add_frame({"observation.state": rng.standard_normal(4).astype(np.float32),
                          "action": np.array([e, i], dtype=np.float32),
                          "observation.images.webcam": img, "task": task})
        ds.save_episode()
    ds.finalize()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("root", nargs="?", type=Path, help="dataset folder (holds meta/info.json)")
    p.add_argument("--repo-id", help="repo id to pass (default: local/<folder name>); only a label offline")
    p.add_argument("--horizon", type=int, default=10, help="action chunk length (steps), as ACT uses it")
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--video-backend", default=None, help="torchcodec or pyav (default: LeRobot's choice)")
    p.add_argument("--limit", type=int, default=0, help="iterate only the first N items (0 = all)")
    p.add_argument("--compare", type=Path, metavar="ROOT2",
                   help="also compare camera frames item by item with another export of the same data")
    p.add_argument("--make-tiny", type=Path, metavar="DIR", help="write a tiny dataset to DIR and exit")
    p.add_argument("--videos", action="store_true", help="with --make-tiny: mp4 instead of png images")
    a = p.parse_args(argv)
    if a.make_tiny:
        if a.make_tiny.exists():
            p.error(f"{a.make_tiny} exists; LeRobot's writer wants a new folder")
        make_tiny(a.make_tiny, a.videos)
        print(json.dumps({"written": str(a.make_tiny)}))
        return 0
    if a.root is None:
        p.error("give a dataset folder or --make-tiny DIR")
    # LeRobot would mkdir a missing root and then try the hub: refuse before that.
    if not (a.root / "meta" / "info.json").is_file():
        p.error(f"{a.root} has no meta/info.json")
    # A fresh datasets cache per run, so that an old Arrow cache of a re-exported folder cannot answer.
    with tempfile.TemporaryDirectory(prefix="lerobot_check_") as cache:
        os.environ.setdefault("HF_DATASETS_CACHE", cache)
        summary = check(a.root.resolve(), a.repo_id or f"local/{a.root.resolve().name}", a.horizon,
                        a.batch_size, a.video_backend, a.limit,
                        a.compare.resolve() if a.compare else None)
    print(json.dumps(summary, indent=1))
    return 0 if summary["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
