"""Closed-loop evaluation of a LeRobot ACT policy (train_act.py) on seqmotion's pushing task.

Run with the python of the LeRobot venv (seqmotion installed there, see README.md)::

    python eval_act.py MODEL_DIR --trials N --seed S --json OUT [--benchmark chapter|hard] [--image auto|live|first]

:class:`ActPolicy` has the ``run(scene, position, variation, camera, duration, latent) -> (AutonomousRun,
image, z)`` of :class:`seqmotion.lfd.policy.policy.PushingPolicy`, so that ``seqmotion.lfd.evaluation.evaluate``
can score it like seqmotion's own policies. Where ``evaluate`` does not take such a policy yet (it
checks ``isinstance(policy, PushingPolicy)`` and has no ``benchmark`` argument), the same trials are run
here the same way: chapter ``--trials`` per block position (``trial_rng(seed, position, trial)``,
``SceneVariation.sample``), hard ``--trials`` in all (``trial_rng(seed, HARD_KEY, trial)``,
``sample_hard_placement``), 4 s, success = ``scene.success()``. The JSON adds the time of every
``policy.select_action`` call (mean, p50, p99) and of every whole command (render + processors + ACT).
"""

from __future__ import annotations

import argparse
import inspect
import json
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")
os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from act_source import ActSource, load_act  # noqa: E402


class ActPolicy:
    """LeRobot's ACT behind seqmotion's policy interface (``run``, ``config.kind/preset/camera``)."""

    kind = "act"
    camera = "default"

    def __init__(self, model_dir: str | Path, image: str = "auto", device: str = "cpu") -> None:
        self.model_dir = Path(model_dir)
        self.policy, self.preprocessor, self.postprocessor = load_act(self.model_dir, device)
        log_path = self.model_dir / "train_log.json"
        self.train_log = json.loads(log_path.read_text()) if log_path.is_file() else {}
        if image == "auto":  # what the training frames showed
            image = "first" if self.train_log.get("webcam_static_in_episode") else "live"
        self.image = image
        c = self.policy.config
        self.preset = f"lerobot-act chunk{c.chunk_size} te{c.temporal_ensemble_coeff} n{c.n_action_steps}"
        self.config = self  # evaluate() reads policy.config.kind / .preset / .camera
        self.command_interval = 0.02  # the dataset's 50 fps
        self.select_ms: list[float] = []
        self.call_ms: list[float] = []

    def run(self, scene, position, variation=None, camera: str | None = None, duration: float = 4.0,
            latent=None):
        """One episode: reset the scene, take the first image, ACT drives the slave every 20 ms."""
        from seqmotion.lfd.env.pushing import SceneVariation
        from seqmotion.lfd.rollout import run_autonomous

        variation = variation or SceneVariation()
        camera = camera or self.camera
        scene.reset(position, variation)
        image = scene.render(camera)
        source = ActSource(self.policy, self.preprocessor, self.postprocessor, scene, camera, self.image)
        source.reset(first_image=image)
        run = run_autonomous(scene, source, position, duration, variation, self.command_interval, reset=False)
        self.select_ms.extend(source.select_ms)
        self.call_ms.extend(source.call_ms)
        return run, image, np.zeros(0)


def _evaluate_here(policy: ActPolicy, trials: int, seed: int, benchmark: str, duration: float,
                   progress: bool) -> dict:
    """``evaluate``'s trials, run here (for an ``evaluate`` that does not take this policy yet)."""
    from seqmotion.lfd import evaluation
    from seqmotion.lfd.env import pushing
    from seqmotion.lfd.evaluation import EVAL_STREAM, trial_rng

    HARD_KEY = getattr(evaluation, "HARD_KEY", 100)  # noqa: N806 (the hard benchmark's seed key)

    scene = pushing.PushingScene(benchmark=benchmark)
    # as evaluate(): chapter = trials per position, interleaved; hard = trials in all, seed key HARD_KEY
    episodes = ([(HARD_KEY, t) for t in range(trials)] if benchmark == "hard"
                else [(pos.index, t) for t in range(trials) for pos in pushing.POSITIONS])
    outcomes, start = [], time.perf_counter()
    try:
        for key, trial in episodes:
            rng = trial_rng(seed, key, trial)
            if benchmark == "hard":
                placed, variation = pushing.sample_hard_placement(rng)
            else:
                placed, variation = pushing.POSITIONS[key], pushing.SceneVariation.sample(rng)
            run, _, _ = policy.run(scene, placed, variation, policy.camera, duration)
            outcomes.append({
                "position_index": placed.index, "position": placed.name, "trial": trial,
                "seed_key": [seed, EVAL_STREAM, key, trial], "success": bool(run.success),
                "crossed_time": None if math.isnan(run.crossed_time) else float(run.crossed_time),
                "final_block_y": float(run.block_pose[-1, 1]),
            })
            if progress:
                ok = sum(o["success"] for o in outcomes)
                print(f"\r[eval_act] {len(outcomes)}/{len(episodes)} trials, {ok} successful, "
                      f"{time.perf_counter() - start:.0f} s", end="", file=sys.stderr, flush=True)
    finally:
        scene.close()
    if progress:
        print(file=sys.stderr)
    outcomes.sort(key=lambda o: (o["position_index"], o["trial"]))
    successes = sum(o["success"] for o in outcomes)
    per_position = {}
    for o in outcomes:
        s, n = per_position.get(o["position"], (0, 0))
        per_position[o["position"]] = (s + o["success"], n + 1)
    return {"policy_kind": "act", "policy_preset": policy.preset, "success_rate": successes / len(outcomes),
            "successes": successes, "n_trials": len(outcomes), "per_position": per_position,
            "camera": policy.camera, "seed": seed, "seconds": time.perf_counter() - start, "outcomes": outcomes,
            "evaluator": "eval_act._evaluate_here"}


def _ms_stats(xs: list[float]) -> dict:
    if not xs:
        return {"n": 0}
    a = np.asarray(xs)
    return {"n": int(a.size), "mean": float(a.mean()), "p50": float(np.percentile(a, 50)),
            "p99": float(np.percentile(a, 99)), "max": float(a.max())}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("model_dir", type=Path)
    p.add_argument("--trials", type=int, default=5,
                   help="chapter: trials per block position (6 positions; default 5); hard: trials in all")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, required=True)
    p.add_argument("--benchmark", choices=["chapter", "hard"], default="chapter")
    p.add_argument("--image", choices=["auto", "live", "first"], default="auto",
                   help="auto: 'first' if the training episodes had one image each (train_log.json), else 'live'")
    p.add_argument("--duration", type=float, help="episode length [s] (default: the benchmark's, 4 chapter, 6 hard)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    if args.trials < 1 or args.seed < 0:
        p.error("--trials must be >= 1 and --seed >= 0")

    import torch

    torch.set_num_threads(args.threads)
    from seqmotion.lfd import evaluation

    policy = ActPolicy(args.model_dir, args.image)
    params = inspect.signature(evaluation.evaluate).parameters
    from seqmotion.lfd.env.pushing import EPISODE_SECONDS

    duration = args.duration or EPISODE_SECONDS[args.benchmark]
    if "benchmark" in params:  # the generalised evaluate: any object with run()
        result = evaluation.evaluate(policy, camera=policy.camera, trials=args.trials, seed=args.seed,
                                     duration=duration, progress=not args.quiet,
                                     benchmark=args.benchmark).as_dict()
        result["evaluator"] = "seqmotion.lfd.evaluation.evaluate"
    else:
        result = _evaluate_here(policy, args.trials, args.seed, args.benchmark, duration, not args.quiet)
    result.update({
        "benchmark": args.benchmark, "duration": duration, "trials_per_position": args.trials,
        "model_dir": str(args.model_dir),
        "image_mode": policy.image, "threads": args.threads,
        "select_action_ms": _ms_stats(policy.select_ms), "call_ms": _ms_stats(policy.call_ms),
        "train": {k: policy.train_log.get(k) for k in ("steps", "batch_size", "seed", "episodes_used", "data",
                                                       "final_loss_mean_last10")},
    })
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1))
    s = result["select_action_ms"]
    print(f"success {result['successes']}/{result['n_trials']} = {result['success_rate']:.2f}; select_action "
          f"mean {s.get('mean', float('nan')):.1f} ms p50 {s.get('p50', float('nan')):.1f} p99 "
          f"{s.get('p99', float('nan')):.1f} ms over {s['n']} calls; image {policy.image}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
