"""Train LeRobot's own ACT (lerobot 0.4.4) on a seqmotion LeRobot v3.0 export, as ``lerobot-train`` would.

Run with the python of the LeRobot venv (see README.md beside this file), never with seqmotion's venv::

    python train_act.py --data LEROBOT_FOLDER --out DIR --steps N --batch-size B --seed S [--episodes 10]

Every piece is LeRobot's own code, called the way ``lerobot/scripts/lerobot_train.py::train`` calls it:

* ``TrainPipelineConfig(...).validate()`` (``lerobot/configs/train.py``): takes the policy's optimizer
  preset (``ACTConfig.get_optimizer_preset``: AdamW lr 1e-5, weight decay 1e-4, grad clip 10) and its
  scheduler preset (none);
* ``make_dataset(cfg)`` (``lerobot/datasets/factory.py``): ``LeRobotDataset(repo_id, root=...,
  episodes=[0..E-1], delta_timestamps={"action": [i/fps for i in range(chunk_size)]})`` and, as
  ``DatasetConfig.use_imagenet_stats`` defaults to True, ImageNet mean/std for the camera;
* ``make_policy(cfg.policy, ds_meta=dataset.meta)`` (``lerobot/policies/factory.py``): ``ACTPolicy``
  with the output features from ``dataset_to_policy_features`` (``lerobot/datasets/utils.py``);
* ``make_pre_post_processors(cfg.policy, dataset_stats=dataset.meta.stats)``: the ACT processors of
  ``lerobot/policies/act/processor_act.py`` (MEAN_STD normaliser / unnormaliser from meta/stats.json);
* ``make_optimizer_and_scheduler(cfg, policy)`` (``lerobot/optim/factory.py``) with
  ``policy.get_optim_params()`` (backbone lr 1e-5);
* the loop of ``train``: a shuffled ``DataLoader``, ``batch = preprocessor(batch)`` and
  ``lerobot_train.update_policy(...)`` (forward -> L1 + 10 KL, ``accelerator.backward``,
  ``clip_grad_norm_(10)``, ``optimizer.step``, ``zero_grad``) with an ``Accelerator(cpu=True)``.

Writes into ``--out``: ``config.json`` + ``model.safetensors`` (``policy.save_pretrained``), the
processors (``policy_preprocessor.json``, ``policy_postprocessor.json`` and their state files) and
``train_log.json``. The hub is never contacted (``HF_HUB_OFFLINE=1``; ``pretrained_backbone_weights=None``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

# Offline before huggingface_hub / datasets / lerobot read their environment at import.
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")

INPUT_KEYS = ("observation.state", "observation.effort", "observation.images.webcam")
"""What the policy is given. ``make_policy`` would take every non-action feature; we leave out
``observation.environment_state`` (the block's true pose, which ACT would read as an ENV token and
which a real webcam policy does not have). ``observation.effort`` is typed STATE by
``dataset_to_policy_features``; ACT reads only ``observation.state``, so it is normalised and ignored."""


def build_config(args: argparse.Namespace):
    """``TrainPipelineConfig`` with ``ACTConfig``: LeRobot defaults except where noted."""
    from lerobot.configs.default import DatasetConfig, WandBConfig
    from lerobot.configs.train import TrainPipelineConfig
    from lerobot.policies.act.configuration_act import ACTConfig

    policy = ACTConfig(
        device="cpu",
        pretrained_backbone_weights=None,  # offline: no ImageNet download (default "ResNet18_Weights.IMAGENET1K_V1")
        temporal_ensemble_coeff=args.temporal_ensemble_coeff,  # 0.01: "the value used in ACT" (configuration_act.py)
        n_action_steps=args.n_action_steps,  # 1: required with temporal ensembling (ACTConfig.__post_init__)
        chunk_size=args.chunk_size,  # default 100
        push_to_hub=False,
    )
    cfg = TrainPipelineConfig(
        dataset=DatasetConfig(repo_id=args.repo_id, root=str(args.data), episodes=args.episode_list),
        policy=policy,
        seed=args.seed,
        num_workers=args.num_workers,  # LeRobot default 4; 0 here (2 shared cores, deterministic order)
        batch_size=args.batch_size,
        steps=args.steps,
        eval_freq=0,  # no LeRobot sim env: the closed loop is eval_act.py
        log_freq=args.log_every,
        save_checkpoint=False,  # one save_pretrained at the end (resume is not needed)
        wandb=WandBConfig(enable=False),
    )
    cfg.validate()  # policy presets -> cfg.optimizer (AdamW), cfg.scheduler (None)
    cfg.output_dir = Path(args.out)
    return cfg


def choose_episodes(root: Path, count: int | None, successful_only: bool) -> list[int]:
    """Episode indices to train on: the first ``count`` (all if None), or the first ``count`` successful ones
    (``seqmotion/success`` in ``meta/episodes``, written by seqmotion's export)."""
    import pyarrow.parquet as pq

    info = json.loads((root / "meta" / "info.json").read_text())
    total = int(info["total_episodes"])
    if not successful_only:
        count = total if count is None else count
        if not 1 <= count <= total:
            raise ValueError(f"--episodes must be in 1..{total} (the folder has {total} episodes)")
        return list(range(count))
    import pandas as pd

    files = sorted((root / "meta" / "episodes").rglob("*.parquet"))
    table = pd.concat([pq.read_table(f).to_pandas() for f in files])
    if "seqmotion/success" not in table.columns:
        raise ValueError(f"{root}/meta/episodes has no seqmotion/success column: not a seqmotion export")
    table = table.sort_values("episode_index")
    ok = [int(e) for e, s in zip(table["episode_index"], table["seqmotion/success"], strict=True) if bool(s)]
    count = len(ok) if count is None else count
    if not 1 <= count <= len(ok):
        raise ValueError(f"--episodes must be in 1..{len(ok)} ({len(ok)} of {total} episodes are successful)")
    return ok[:count]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True, help="a LeRobot v3.0 folder (OUT/<set> of export-lerobot)")
    p.add_argument("--out", type=Path, required=True, help="output folder (must not exist or be empty)")
    p.add_argument("--steps", type=int, required=True)
    p.add_argument("--batch-size", type=int, default=8, help="LeRobot's default 8")
    p.add_argument("--seed", type=int, default=1000, help="LeRobot's default 1000")
    p.add_argument("--episodes", type=int, default=None,
                   help="train on the first E episodes (default all), by episode index")
    p.add_argument("--successful-only", action="store_true",
                   help="the first E episodes whose seqmotion/success is true (the hard benchmark's rule)")
    p.add_argument("--repo-id", default="seqmotion/pushing", help="a label only (offline)")
    p.add_argument("--chunk-size", type=int, default=100)
    p.add_argument("--n-action-steps", type=int, default=1)
    p.add_argument("--temporal-ensemble-coeff", type=float, default=0.01,
                   help="0.01 as LeRobot's ACTConfig recommends; a negative value means None (no ensembling)")
    p.add_argument("--num-workers", type=int, default=0)
    p.add_argument("--threads", type=int, default=1, help="torch.set_num_threads (default 1)")
    p.add_argument("--log-every", type=int, default=50)
    args = p.parse_args(argv)
    if args.temporal_ensemble_coeff is not None and args.temporal_ensemble_coeff < 0:
        args.temporal_ensemble_coeff = None

    if not (args.data / "meta" / "info.json").is_file():
        p.error(f"{args.data} has no meta/info.json: not a LeRobot dataset folder (LeRobot would ask the hub)")
    try:
        args.episode_list = choose_episodes(args.data, args.episodes, args.successful_only)
    except ValueError as exc:
        p.error(str(exc))
    if args.out.exists() and any(args.out.iterdir()):
        p.error(f"{args.out} exists and is not empty")
    args.data = args.data.resolve()

    import torch

    torch.set_num_threads(args.threads)
    # A fresh `datasets` cache, so an Arrow cache of an older export of the same path cannot answer.
    cache = tempfile.TemporaryDirectory(prefix="act_train_")
    os.environ.setdefault("HF_DATASETS_CACHE", cache.name)

    from accelerate import Accelerator
    from lerobot.configs.types import FeatureType
    from lerobot.datasets.factory import make_dataset
    from lerobot.datasets.utils import cycle, dataset_to_policy_features
    from lerobot.optim.factory import make_optimizer_and_scheduler
    from lerobot.policies.factory import make_policy, make_pre_post_processors
    from lerobot.scripts.lerobot_train import update_policy
    from lerobot.utils.logging_utils import AverageMeter, MetricsTracker
    from lerobot.utils.random_utils import set_seed

    cfg = build_config(args)
    accelerator = Accelerator(step_scheduler_with_optimizer=False, cpu=True)
    set_seed(cfg.seed, accelerator=accelerator)  # as train(): random, numpy, torch (+ accelerate)

    t0 = time.perf_counter()
    dataset = make_dataset(cfg)
    features = dataset_to_policy_features(dataset.meta.features)
    missing = [k for k in INPUT_KEYS if k not in features]
    if "observation.images.webcam" in missing or "observation.state" in missing:
        raise SystemExit(f"{args.data} lacks {missing}: export a set with the webcam (e.g. pairs_default)")
    cfg.policy.input_features = {k: features[k] for k in INPUT_KEYS if k in features}
    policy = make_policy(cfg=cfg.policy, ds_meta=dataset.meta)
    preprocessor, postprocessor = make_pre_post_processors(policy_cfg=cfg.policy, dataset_stats=dataset.meta.stats)
    optimizer, lr_scheduler = make_optimizer_and_scheduler(cfg, policy)
    setup_s = time.perf_counter() - t0

    dataloader = torch.utils.data.DataLoader(
        dataset, num_workers=cfg.num_workers, batch_size=cfg.batch_size, shuffle=True, sampler=None,
        pin_memory=False, drop_last=False, prefetch_factor=2 if cfg.num_workers > 0 else None,
    )
    policy, optimizer, dataloader, lr_scheduler = accelerator.prepare(policy, optimizer, dataloader, lr_scheduler)
    dl_iter = cycle(dataloader)
    policy.train()
    meters = {
        "loss": AverageMeter("loss", ":.3f"), "grad_norm": AverageMeter("grdn", ":.3f"),
        "lr": AverageMeter("lr", ":0.1e"), "update_s": AverageMeter("updt_s", ":.3f"),
        "dataloading_s": AverageMeter("data_s", ":.3f"),
    }
    tracker = MetricsTracker(cfg.batch_size, dataset.num_frames, dataset.num_episodes, meters,
                             initial_step=0, accelerator=accelerator)

    history, update_s, data_s = [], [], []
    train_start = time.perf_counter()
    for step in range(1, cfg.steps + 1):
        start = time.perf_counter()
        batch = preprocessor(next(dl_iter))
        tracker.dataloading_s = time.perf_counter() - start
        tracker, output = update_policy(tracker, policy, batch, optimizer, cfg.optimizer.grad_clip_norm,
                                        accelerator=accelerator, lr_scheduler=lr_scheduler)
        update_s.append(tracker.update_s.val)
        data_s.append(tracker.dataloading_s.val)
        history.append({"step": step, "loss": tracker.loss.val, "grad_norm": tracker.grad_norm.val, **output})
        tracker.step()
        if cfg.log_freq > 0 and step % cfg.log_freq == 0:
            print(f"step {step}/{cfg.steps} {tracker}", file=sys.stderr, flush=True)
            tracker.reset_averages()
    train_s = time.perf_counter() - train_start

    args.out.mkdir(parents=True, exist_ok=True)
    unwrapped = accelerator.unwrap_model(policy)
    unwrapped.save_pretrained(args.out)
    preprocessor.save_pretrained(args.out)
    postprocessor.save_pretrained(args.out)

    def _mean(xs: list[float]) -> float | None:
        return sum(xs) / len(xs) if xs else None

    skip = min(5, len(update_s) // 2)  # the first steps include one-off allocation
    tail = history[-10:]
    log = {
        "lerobot_version": __import__("importlib.metadata").metadata.version("lerobot"),
        "torch_version": torch.__version__,
        "data": str(args.data),
        "episodes_used": args.episode_list,
        "successful_only": args.successful_only,
        "frames_used": dataset.num_frames,
        "fps": dataset.meta.fps,
        "steps": cfg.steps,
        "batch_size": cfg.batch_size,
        "seed": cfg.seed,
        "threads": args.threads,
        "num_workers": cfg.num_workers,
        "seconds": {"setup": setup_s, "train": train_s},
        "s_per_step": train_s / cfg.steps,
        "s_per_step_update": _mean(update_s[skip:]),
        "s_per_step_dataloading": _mean(data_s[skip:]),
        "final_loss": history[-1]["loss"],
        "final_loss_mean_last10": _mean([h["loss"] for h in tail]),
        "final_l1_mean_last10": _mean([h["l1_loss"] for h in tail]),
        "final_kld_mean_last10": _mean([h["kld_loss"] for h in tail if "kld_loss" in h]),
        "history": history,
        "input_features": {k: [v.type.name, list(v.shape)] for k, v in cfg.policy.input_features.items()},
        "output_features": {k: [v.type.name, list(v.shape)] for k, v in cfg.policy.output_features.items()},
        "ignored_by_act": [k for k, v in cfg.policy.input_features.items()
                           if v.type is FeatureType.STATE and k != "observation.state"],
        "webcam_static_in_episode": _static_images(dataset),
        "optimizer": {"type": "adamw", **{k: v for k, v in vars(cfg.optimizer).items()}},
        "backbone_lr": cfg.policy.optimizer_lr_backbone,
        "scheduler": None if cfg.scheduler is None else type(cfg.scheduler).__name__,
        "use_imagenet_stats": cfg.dataset.use_imagenet_stats,
        "policy_config": json.loads((args.out / "config.json").read_text()),
    }
    (args.out / "train_log.json").write_text(json.dumps(log, indent=1, default=str))
    print(json.dumps({k: log[k] for k in ("steps", "batch_size", "episodes_used", "frames_used", "s_per_step",
                                          "s_per_step_update", "s_per_step_dataloading", "final_loss",
                                          "final_loss_mean_last10", "webcam_static_in_episode")}))
    cache.cleanup()
    return 0


def _static_images(dataset) -> bool:
    """Whether the first episode's webcam frames are all one image (seqmotion's export without per-frame
    video: one image per episode on every frame). eval_act.py then feeds the first image on every call."""
    import torch

    key = "observation.images.webcam"
    ep = dataset.meta.episodes[0]
    first, last = int(ep["dataset_from_index"]), int(ep["dataset_to_index"]) - 1
    # hf_dataset rows, not dataset[i]: no action chunk needed; images come back as CHW float tensors
    rows = dataset.hf_dataset.select([first, (first + last) // 2, last])
    if key not in rows.column_names:  # a video feature: decode through the dataset
        imgs = [dataset[i][key] for i in (first, (first + last) // 2, last)]
    else:
        imgs = [rows[i][key] for i in range(3)]
    return bool(all(torch.equal(imgs[0], im) for im in imgs[1:]))


if __name__ == "__main__":
    raise SystemExit(main())
