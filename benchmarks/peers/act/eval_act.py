"""Closed-loop evaluation of a LeRobot ACT policy (train_act.py) on seqmotion's pushing task.

Run with the python of the LeRobot venv (seqmotion installed there, see README.md)::

    python eval_act.py MODEL_DIR --trials N --seed S --json OUT [--benchmark chapter|hard] [--image auto|live|first]
    python eval_act.py RUN/checkpoints/002000/pretrained_model --benchmark hard --trials 30 --seed 0 --json OUT

:class:`ActPolicy` is a seqmotion ``Controller`` (``reset()``, ``select_action(observation)``,
``command_interval`` 20 ms, ``camera``, ``images_every_step``), so ``seqmotion.lfd.evaluation.evaluate``
scores it exactly like seqmotion's own policies (the same ``run_episode`` / ``rollout``, trial seeds and
success test): chapter ``--trials`` per block position, hard ``--trials`` in all. ``MODEL_DIR`` is a
finished run's folder or one checkpoint of it (``checkpoints/<step>/pretrained_model``). The JSON adds the
time of every ``policy.select_action`` call (mean, p50, p99) and of every whole command (processors + ACT;
the rollout renders the image before the call).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")
os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from act_source import ActSource, load_act  # noqa: E402


class ActPolicy:
    """LeRobot's ACT as a seqmotion :class:`~seqmotion.lfd.policy.interface.Controller` (``reset``,
    ``select_action(observation)``, ``command_interval``, ``camera``, ``images_every_step``), so that
    ``seqmotion.lfd.evaluation.evaluate`` runs it through the same ``run_episode`` / ``rollout`` as
    seqmotion's own policies; ``config.kind/preset/camera`` for the evaluation's record."""

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
        # live: the rollout renders the webcam before every decision; first: only the episode's first image
        self.images_every_step = image == "live"
        self.source = ActSource(self.policy, self.preprocessor, self.postprocessor, None, self.camera, image)

    @property
    def select_ms(self) -> list[float]:
        return self.source.select_ms

    @property
    def call_ms(self) -> list[float]:
        return self.source.call_ms

    def reset(self) -> None:
        """New episode: clears ACT's temporal ensemble; the first observation's image becomes the first image."""
        self.source.reset(first_image=None)

    def select_action(self, observation):
        """The master command for one ``Observation`` (time, slave state, the image the rollout rendered)."""
        return self.source.command(observation.state, observation.image)


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
    p.add_argument("--device", default="cpu", help="cpu or cuda (where ACT runs; the simulation is on the CPU)")
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    if args.trials < 1 or args.seed < 0:
        p.error("--trials must be >= 1 and --seed >= 0")

    import torch

    torch.set_num_threads(args.threads)
    from seqmotion.lfd import evaluation

    policy = ActPolicy(args.model_dir, args.image, args.device)
    from seqmotion.lfd.env.pushing import EPISODE_SECONDS

    duration = args.duration or EPISODE_SECONDS[args.benchmark]
    result = evaluation.evaluate(policy, camera=policy.camera, trials=args.trials, seed=args.seed,
                                 duration=duration, progress=not args.quiet, benchmark=args.benchmark).as_dict()
    result["evaluator"] = "seqmotion.lfd.evaluation.evaluate"
    result.update({
        "benchmark": args.benchmark, "duration": duration, "trials_per_position": args.trials,
        "model_dir": str(args.model_dir),
        "image_mode": policy.image, "threads": args.threads,
        "select_action_ms": _ms_stats(policy.select_ms), "call_ms": _ms_stats(policy.call_ms),
        "device": args.device,
        # MODEL_DIR may be a run's folder or one of its checkpoints (checkpoints/<step>/pretrained_model):
        # train_act.py writes train_log.json in both, with the validation log up to that step
        "train": {k: policy.train_log.get(k) for k in ("steps", "batch_size", "seed", "episodes_used", "data",
                                                       "final_loss_mean_last10", "finished", "stop_reason",
                                                       "best_val_l1", "best_step")},
        "val_at_step": next((v for v in reversed(policy.train_log.get("val") or [])
                             if v.get("step") == policy.train_log.get("steps")), None),
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
