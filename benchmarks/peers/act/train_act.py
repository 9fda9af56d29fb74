"""Train LeRobot's own ACT (lerobot 0.4.4) on a seqmotion LeRobot v3.0 export, as ``lerobot-train`` would.

Run with the python of the LeRobot venv (see README.md beside this file), never with seqmotion's venv::

    python train_act.py --data LEROBOT_FOLDER --out DIR --steps N --batch-size B --seed S [--episodes 10]
    # to convergence, resumable: validation on held-out episodes, checkpoints, a stop rule
    python train_act.py --data F --out DIR --episodes 100 --successful-only --val-episodes successful:110-139 \
        --steps 40000 --min-steps 10000 --patience 2000 --val-every 500 --resume

Every piece is LeRobot's own code, called the way ``lerobot/scripts/lerobot_train.py::train`` calls it:

* ``TrainPipelineConfig(...).validate()`` (``lerobot/configs/train.py``): takes the policy's optimizer
  preset (``ACTConfig.get_optimizer_preset``: AdamW lr 1e-5, weight decay 1e-4, grad clip 10) and its
  scheduler preset (none);
* ``make_dataset(cfg)`` (``lerobot/datasets/factory.py``): ``LeRobotDataset(repo_id, root=...,
  episodes=[...], delta_timestamps={"action": [i/fps for i in range(chunk_size)]})`` and, as
  ``DatasetConfig.use_imagenet_stats`` defaults to True, ImageNet mean/std for the camera;
* ``make_policy(cfg.policy, ds_meta=dataset.meta)`` (``lerobot/policies/factory.py``): ``ACTPolicy``
  with the output features from ``dataset_to_policy_features`` (``lerobot/datasets/utils.py``);
* ``make_pre_post_processors(cfg.policy, dataset_stats=dataset.meta.stats)``: the ACT processors of
  ``lerobot/policies/act/processor_act.py`` (MEAN_STD normaliser / unnormaliser from meta/stats.json);
* ``make_optimizer_and_scheduler(cfg, policy)`` (``lerobot/optim/factory.py``) with
  ``policy.get_optim_params()`` (backbone lr ``optimizer_lr_backbone``);
* the loop of ``train``: ``batch = preprocessor(batch)`` and ``lerobot_train.update_policy(...)``
  (forward -> L1 + 10 KL, ``accelerator.backward``, ``clip_grad_norm_(10)``, ``optimizer.step``,
  ``zero_grad``) with an ``Accelerator``;
* checkpoints: ``lerobot/utils/train_utils.py::save_checkpoint`` / ``load_training_state`` (LeRobot's
  layout ``checkpoints/<step>/{pretrained_model,training_state}`` and its ``last`` link).

Departures, each for exact resumption: the data order is a fresh permutation of the training frames per
epoch from a generator seeded by (seed, epoch), not the ``DataLoader``'s ``shuffle=True`` (whose order
depends on the global RNG at each epoch's start and is lost on LeRobot's resume), and the position in it
is saved with each checkpoint; the ``DataLoader`` is not passed through ``accelerator.prepare`` (which
would rewrap its sampler); each checkpoint is written into a temporary folder and renamed into place.

Writes into ``--out``: ``checkpoints/<step>/...`` during training; when the run is finished (``--steps``
reached or the stop rule met) also ``config.json`` + ``model.safetensors`` (``policy.save_pretrained``),
the processors (``policy_preprocessor.json``, ``policy_postprocessor.json`` and their state files) and
``train_log.json`` (also written at every checkpoint, ``"finished": false`` until then). The hub is never
contacted (``HF_HUB_OFFLINE=1``; ``pretrained_backbone_weights=None``).

Validation loss (``--val-episodes``; logged every ``--val-every`` steps with step and wall time):

* ``val_l1`` (used by the stop rule and to choose configurations): the L1 of ``ACTPolicy.forward``
  (unpadded action chunk, normalised units, mean over batch x chunk x 9) with the policy in eval mode:
  no dropout and, as in ``ACT.forward`` outside training, the latent is zero (the prior's mean). That is
  the action chunk the deployed policy predicts (``select_action`` runs the same forward), so it measures
  what the evaluation uses, and it is deterministic.
* ``val_loss_vae`` = ``val_l1_vae`` + kl_weight x ``val_kld`` (``--val-vae``, on by default): ACT's
  training objective on the held-out frames: the VAE encoder sees the true chunk, the latent is sampled
  from its posterior (with a fixed noise seed, inside ``torch.random.fork_rng``), dropout off. Reported
  beside, not used to stop: its L1 is conditioned on the future actions the deployed policy never sees,
  so a run can lower it by leaning on the latent, and its KL depends on the VAE encoder's size, one of
  the choices compared.

Neither consumes the training RNG, so a run's weights are the same with or without validation.
"""

from __future__ import annotations

import argparse
import copy
import datetime as dt
import json
import math
import os
import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

# Offline before huggingface_hub / datasets / lerobot read their environment at import.
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")

INPUT_KEYS = ("observation.state", "observation.effort", "observation.images.webcam")
"""What the policy is given. ``make_policy`` would take every non-action feature; we leave out
``observation.environment_state`` (the block's true pose, which ACT would read as an ENV token and
which a real webcam policy does not have). ``observation.effort`` is typed STATE by
``dataset_to_policy_features``; ACT reads only ``observation.state``, so it is normalised and ignored."""

STATE_FILE = "seqmotion_state.json"
"""Beside LeRobot's files in ``training_state/``: data-order position, validation log, stop-rule state."""
HISTORY_FILE = "history.json"
"""Beside LeRobot's files in ``training_state/``: every step's loss, so a resumed log is continuous."""
VAL_NOISE_SEED = 12345
"""The VAE posterior's noise in ``val_loss_vae``: fixed, so that the number is a function of the weights."""

IDENTITY_KEYS = ("data", "episodes_used", "val_episodes_used", "val_stride", "val_every", "val_vae", "batch_size",
                 "seed", "policy")
"""What a resumed run must share with its checkpoint (``--steps``, ``--min-steps``, ``--patience``,
``--stop-at``, threads, workers and device may change)."""


# --------------------------------------------------------------------------------------------- episodes


def _episode_table(root: Path) -> tuple[int, dict[int, bool]]:
    """(total episodes, {episode index: seqmotion/success}) from ``meta/`` (written by seqmotion's export)."""
    import pandas as pd
    import pyarrow.parquet as pq

    info = json.loads((root / "meta" / "info.json").read_text())
    total = int(info["total_episodes"])
    files = sorted((root / "meta" / "episodes").rglob("*.parquet"))
    table = pd.concat([pq.read_table(f).to_pandas() for f in files])
    if "seqmotion/success" not in table.columns:
        return total, {}
    return total, {int(e): bool(s) for e, s in zip(table["episode_index"], table["seqmotion/success"], strict=True)}


def choose_episodes(root: Path, count: int | None, successful_only: bool) -> list[int]:
    """Episode indices to train on: the first ``count`` (all if None), or the first ``count`` successful ones
    (``seqmotion/success`` in ``meta/episodes``, written by seqmotion's export)."""
    total, success = _episode_table(root)
    if not successful_only:
        count = total if count is None else count
        if not 1 <= count <= total:
            raise ValueError(f"--episodes must be in 1..{total} (the folder has {total} episodes)")
        return list(range(count))
    if not success:
        raise ValueError(f"{root}/meta/episodes has no seqmotion/success column: not a seqmotion export")
    ok = sorted(e for e, s in success.items() if s)
    count = len(ok) if count is None else count
    if not 1 <= count <= len(ok):
        raise ValueError(f"--episodes must be in 1..{len(ok)} ({len(ok)} of {total} episodes are successful)")
    return ok[:count]


def parse_episode_spec(root: Path, spec: str) -> list[int]:
    """``--val-episodes``: ``[successful:]A-B,C,...`` (inclusive ranges and single indices); with the
    ``successful:`` prefix only those whose ``seqmotion/success`` is true."""
    total, success = _episode_table(root)
    only_ok = spec.startswith("successful:")
    body = spec.removeprefix("successful:")
    chosen: set[int] = set()
    for part in filter(None, (s.strip() for s in body.split(","))):
        if "-" in part:
            a, b = (int(x) for x in part.split("-", 1))
            chosen.update(range(a, b + 1))
        else:
            chosen.add(int(part))
    if not chosen or min(chosen) < 0 or max(chosen) >= total:
        raise ValueError(f"--val-episodes {spec!r}: indices must be in 0..{total - 1}")
    if only_ok:
        if not success:
            raise ValueError(f"{root}/meta/episodes has no seqmotion/success column: 'successful:' needs one")
        chosen = {e for e in chosen if success.get(e)}
    if not chosen:
        raise ValueError(f"--val-episodes {spec!r} selects no episode")
    return sorted(chosen)


# --------------------------------------------------------------------------------------------- config


def build_config(args: argparse.Namespace):
    """``TrainPipelineConfig`` with ``ACTConfig``: LeRobot defaults except where noted."""
    from lerobot.configs.default import DatasetConfig, WandBConfig
    from lerobot.configs.train import TrainPipelineConfig
    from lerobot.policies.act.configuration_act import ACTConfig

    sizes = {k: getattr(args, k) for k in ("dim_model", "dim_feedforward", "n_heads", "n_encoder_layers",
                                           "n_decoder_layers", "n_vae_encoder_layers") if getattr(args, k) is not None}
    lrs = {}
    if args.lr is not None:
        lrs["optimizer_lr"] = args.lr
    # The ResNet-18 starts from random weights here (offline), so it gets the main lr unless told otherwise.
    # (LeRobot 0.4.4's defaults are 1e-5 for both; modeling_act.py: "As of now, lr_backbone == lr".)
    backbone_lr = args.lr_backbone if args.lr_backbone is not None else args.lr
    if backbone_lr is not None:
        lrs["optimizer_lr_backbone"] = backbone_lr
    policy = ACTConfig(
        device=args.device,
        pretrained_backbone_weights=None,  # offline: no ImageNet download (default "ResNet18_Weights.IMAGENET1K_V1")
        temporal_ensemble_coeff=args.temporal_ensemble_coeff,  # 0.01: "the value used in ACT" (configuration_act.py)
        n_action_steps=args.n_action_steps,  # 1: required with temporal ensembling (ACTConfig.__post_init__)
        chunk_size=args.chunk_size,  # default 100
        push_to_hub=False,
        **sizes,  # only those given: LeRobot's defaults otherwise (512 / 3200 / 8 / 4 / 1 / 4)
        **lrs,
    )
    cfg = TrainPipelineConfig(
        dataset=DatasetConfig(repo_id=args.repo_id, root=str(args.data), episodes=args.episode_list),
        policy=policy,
        seed=args.seed,
        num_workers=args.num_workers,  # LeRobot default 4; 0 here (2 shared cores)
        batch_size=args.batch_size,
        steps=args.steps,
        eval_freq=0,  # no LeRobot sim env: the closed loop is eval_act.py
        log_freq=args.log_every,
        save_checkpoint=args.val_every > 0 or args.checkpoint_every > 0,
        save_freq=max(args.checkpoint_every, 1),
        wandb=WandBConfig(enable=False),
    )
    cfg.validate()  # policy presets -> cfg.optimizer (AdamW), cfg.scheduler (None)
    cfg.output_dir = Path(args.out)
    return cfg


def _identity(args: argparse.Namespace, cfg) -> dict[str, Any]:
    """What defines the run (compared on resume): data, episodes, validation set, seed, the policy's config."""
    from dataclasses import asdict

    policy = {k: v for k, v in asdict(cfg.policy).items()
              if k not in ("device", "input_features", "output_features", "pretrained_path", "push_to_hub",
                           "repo_id", "private", "tags", "license", "use_amp", "use_peft")}
    return {"data": str(args.data), "episodes_used": args.episode_list, "val_episodes_used": args.val_list,
            "val_stride": args.val_stride, "val_every": args.val_every, "val_vae": args.val_vae,
            "batch_size": args.batch_size, "seed": args.seed, "policy": json.loads(json.dumps(policy, default=str))}


# --------------------------------------------------------------------------------------------- data order


class EpochBatches:
    """Batches of frame indices, epoch after epoch, from a given (epoch, batch) position; endless.

    Epoch ``e`` is ``torch.randperm(n)`` from a generator seeded with ``seed * 1_000_003 + e`` cut into
    batches of ``batch_size`` (the last one short, as LeRobot's ``drop_last=False``). The order depends on
    nothing else, so a checkpoint needs only the position to continue it exactly.
    """

    def __init__(self, n: int, batch_size: int, seed: int, epoch: int = 0, batch: int = 0) -> None:
        self.n, self.batch_size, self.seed = n, batch_size, seed
        self.start = (epoch, batch)
        self.per_epoch = math.ceil(n / batch_size)

    def epoch_order(self, epoch: int) -> list[int]:
        import torch

        gen = torch.Generator().manual_seed(self.seed * 1_000_003 + epoch)
        return torch.randperm(self.n, generator=gen).tolist()

    def advance(self, epoch: int, batch: int) -> tuple[int, int]:
        """The position after one more batch."""
        return (epoch + 1, 0) if batch + 1 >= self.per_epoch else (epoch, batch + 1)

    def __iter__(self):
        epoch, batch = self.start
        while True:
            order = self.epoch_order(epoch)
            for b in range(batch, self.per_epoch):
                yield order[b * self.batch_size:(b + 1) * self.batch_size]
            epoch, batch = epoch + 1, 0


# --------------------------------------------------------------------------------------------- validation


def make_validation(cfg, val_episodes: list[int], stride: int, batch_size: int, preprocessor) -> list[dict]:
    """The held-out frames (every ``stride``-th of the validation episodes' frames), batched and
    preprocessed once: they never change, and decoding their PNGs at each validation would cost more
    than the forward passes."""
    import torch
    from lerobot.datasets.factory import make_dataset

    vcfg = copy.deepcopy(cfg)
    vcfg.dataset.episodes = val_episodes
    vds = make_dataset(vcfg)
    idx = list(range(0, len(vds), stride))
    loader = torch.utils.data.DataLoader(torch.utils.data.Subset(vds, idx), batch_size=batch_size, shuffle=False,
                                         num_workers=0, generator=torch.Generator())  # own generator: see below
    return [preprocessor(b) for b in loader]


def validation_loss(policy, batches: list[dict], with_vae: bool, device: str) -> dict[str, float]:
    """Held-out losses (see the module docstring): ``val_l1`` (eval mode, zero latent) and, with
    ``with_vae``, ``val_l1_vae``, ``val_kld``, ``val_loss_vae`` (posterior latent, fixed noise, no dropout).
    Frame-weighted means over all batches; the global RNG is left as it was."""
    import torch

    sums: dict[str, float] = {}
    frames = 0
    was_training = policy.training
    policy.eval()
    try:
        with torch.no_grad():
            for batch in batches:
                b = len(batch["action"])
                frames += b
                # Eval mode: ACTPolicy.forward would compute the KL from the absent posterior, so the L1
                # is computed here with the same expression as ACTPolicy.forward's.
                obs = dict(batch)
                if policy.config.image_features:
                    obs["observation.images"] = [batch[k] for k in policy.config.image_features]
                actions_hat, _ = policy.model(obs)
                l1 = (torch.nn.functional.l1_loss(batch["action"], actions_hat, reduction="none")
                      * ~batch["action_is_pad"].unsqueeze(-1)).mean()
                sums["val_l1"] = sums.get("val_l1", 0.0) + l1.item() * b
                if with_vae:
                    devices = [torch.device(device).index or 0] if str(device).startswith("cuda") else []
                    with torch.random.fork_rng(devices=devices):
                        torch.manual_seed(VAL_NOISE_SEED)
                        # Only the ACT module's own flag: its VAE branch runs, its dropout layers stay in eval.
                        policy.model.training = True
                        try:
                            loss, out = policy.forward(batch)
                        finally:
                            policy.model.training = False
                    sums["val_loss_vae"] = sums.get("val_loss_vae", 0.0) + loss.item() * b
                    sums["val_l1_vae"] = sums.get("val_l1_vae", 0.0) + out["l1_loss"] * b
                    sums["val_kld"] = sums.get("val_kld", 0.0) + out["kld_loss"] * b
    finally:
        policy.train(was_training)
    return {k: v / frames for k, v in sums.items()}


# --------------------------------------------------------------------------------------------- checkpoints


def write_json(path: Path, payload: Any) -> None:
    """Atomically: a temporary file in the same folder, then ``os.replace``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(fd, "w") as f:
        f.write(json.dumps(payload, indent=1, default=str))
    os.replace(tmp, path)


def _differences(old: dict, new: dict) -> dict[str, tuple]:
    """``{key: (old, new)}`` over IDENTITY_KEYS (the policy config key by key)."""
    diff: dict[str, tuple] = {}
    for k in IDENTITY_KEYS:
        a, b = old.get(k), new.get(k)
        if isinstance(a, dict) and isinstance(b, dict):
            diff.update({f"{k}.{j}": (a.get(j), b.get(j)) for j in sorted(set(a) | set(b)) if a.get(j) != b.get(j)})
        elif a != b:
            diff[k] = (a, b)
    return diff


def _step_name(step: int) -> str:
    return f"{step:06d}"  # LeRobot's get_step_identifier for runs under a million steps


def save_run_checkpoint(out: Path, step: int, cfg, policy, optimizer, lr_scheduler, preprocessor, postprocessor,
                        state: dict, history: list[dict], summary: dict, keep_every: int) -> Path:
    """LeRobot's ``save_checkpoint`` into ``checkpoints/.tmp-<step>``, our state beside it, then renamed to
    ``checkpoints/<step>`` and ``checkpoints/last`` pointed at it (both ``os.replace``: an interrupted save
    leaves the previous checkpoint whole). Older checkpoints lose their ``training_state`` (optimizer: 2x
    the weights) and, unless their step is a multiple of ``keep_every`` or the best validation, their
    weights too."""
    from lerobot.utils.train_utils import save_checkpoint

    root = out / "checkpoints"
    root.mkdir(parents=True, exist_ok=True)
    final = root / _step_name(step)
    tmp = root / f".tmp-{_step_name(step)}"
    shutil.rmtree(tmp, ignore_errors=True)
    save_checkpoint(tmp, step, cfg, policy, optimizer, lr_scheduler, preprocessor, postprocessor)
    write_json(tmp / "training_state" / STATE_FILE, state)
    write_json(tmp / "training_state" / HISTORY_FILE, history)
    # eval_act.py reads train_log.json beside the weights (image mode, steps, episodes)
    write_json(tmp / "pretrained_model" / "train_log.json", summary)
    if final.exists():  # the same step saved again (a resumed run that had nothing left to do)
        shutil.rmtree(final)
    os.replace(tmp, final)
    link_tmp = root / ".last.tmp"
    if link_tmp.is_symlink() or link_tmp.exists():
        link_tmp.unlink()
    link_tmp.symlink_to(final.name)
    os.replace(link_tmp, root / "last")  # LeRobot's LAST_CHECKPOINT_LINK, replaced atomically
    best = state.get("best_step")
    for old in sorted(p for p in root.iterdir() if p.is_dir() and not p.is_symlink() and p.name.isdigit()):
        s = int(old.name)
        if s == step:
            continue
        shutil.rmtree(old / "training_state", ignore_errors=True)
        if not ((keep_every > 0 and s % keep_every == 0) or s == best):
            shutil.rmtree(old, ignore_errors=True)
    return final


def _clean_partial(out: Path) -> None:
    """Remove what an interrupted save left (``.tmp-*`` folders, a dangling link file)."""
    root = out / "checkpoints"
    if not root.is_dir():
        return
    for p in root.iterdir():
        if p.name.startswith(".tmp-"):
            shutil.rmtree(p, ignore_errors=True)
        elif p.name == ".last.tmp":
            p.unlink()


# --------------------------------------------------------------------------------------------- main


def _parse(argv: list[str] | None) -> tuple[argparse.ArgumentParser, argparse.Namespace]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True, help="a LeRobot v3.0 folder (OUT/<set> of export-lerobot)")
    p.add_argument("--out", type=Path, required=True, help="output folder (must not exist or be empty, or --resume)")
    p.add_argument("--steps", type=int, required=True, help="the most optimiser steps (the cap)")
    p.add_argument("--batch-size", type=int, default=8, help="LeRobot's default 8")
    p.add_argument("--seed", type=int, default=1000, help="LeRobot's default 1000")
    p.add_argument("--episodes", type=int, default=None,
                   help="train on the first E episodes (default all), by episode index")
    p.add_argument("--successful-only", action="store_true",
                   help="the first E episodes whose seqmotion/success is true (the hard benchmark's rule)")
    p.add_argument("--repo-id", default="seqmotion/pushing", help="a label only (offline)")
    g = p.add_argument_group("policy (LeRobot's ACTConfig defaults unless given)")
    g.add_argument("--chunk-size", type=int, default=100)
    g.add_argument("--n-action-steps", type=int, default=1)
    g.add_argument("--temporal-ensemble-coeff", type=float, default=0.01,
                   help="0.01 as LeRobot's ACTConfig recommends; a negative value means None (no ensembling)")
    g.add_argument("--dim-model", type=int, help="default 512")
    g.add_argument("--dim-feedforward", type=int, help="default 3200")
    g.add_argument("--n-heads", type=int, help="default 8")
    g.add_argument("--n-encoder-layers", type=int, help="default 4")
    g.add_argument("--n-decoder-layers", type=int, help="default 1")
    g.add_argument("--n-vae-encoder-layers", type=int, help="default 4")
    g.add_argument("--lr", type=float, help="optimizer_lr (default 1e-5)")
    g.add_argument("--lr-backbone", type=float,
                   help="optimizer_lr_backbone (default: --lr if given, else LeRobot's 1e-5)")
    g = p.add_argument_group("validation, checkpoints, stop rule")
    g.add_argument("--val-episodes", help="held-out episodes: '[successful:]A-B,C,...', e.g. successful:110-139")
    g.add_argument("--val-every", type=int, default=500, help="steps between validations (with --val-episodes)")
    g.add_argument("--val-stride", type=int, default=10, help="every k-th frame of the validation episodes")
    g.add_argument("--val-batch-size", type=int, default=32)
    g.add_argument("--no-val-vae", dest="val_vae", action="store_false",
                   help="skip the VAE-posterior validation loss (val_l1 only)")
    g.add_argument("--checkpoint-every", type=int, default=None, help="default: --val-every (0: none in between)")
    g.add_argument("--keep-every", type=int, default=2000,
                   help="keep the weights of checkpoints at multiples of this (for evaluation); 0: last and best only")
    g.add_argument("--min-steps", type=int, default=0, help="stop rule: at least this many steps")
    g.add_argument("--patience", type=int, default=None,
                   help="stop rule: stop once val_l1 has not improved for this many steps (needs --val-episodes)")
    g.add_argument("--min-delta", type=float, default=0.0,
                   help="stop rule: an improvement must lower val_l1 by this fraction (default 0: any)")
    g.add_argument("--resume", action="store_true",
                   help="continue from --out/checkpoints/last if it exists (else start); a finished run exits")
    g.add_argument("--stop-at", type=int, default=None,
                   help="pause this process after this step (checkpointed, not finished; --resume continues)")
    g.add_argument("--past-stop", action="store_true",
                   help="with --resume: continue a run the stop rule finished, to --steps (a diagnostic of what "
                        "more steps give; run it on a copy, since the run is then no longer the rule's)")
    g = p.add_argument_group("machine")
    g.add_argument("--device", default="cpu", help="cpu or cuda")
    g.add_argument("--num-workers", type=int, default=0)
    g.add_argument("--threads", type=int, default=1, help="torch.set_num_threads (default 1)")
    g.add_argument("--log-every", type=int, default=50)
    args = p.parse_args(argv)
    if args.temporal_ensemble_coeff is not None and args.temporal_ensemble_coeff < 0:
        args.temporal_ensemble_coeff = None
    if args.checkpoint_every is None:
        args.checkpoint_every = args.val_every if args.val_episodes else 0
    if args.patience is not None and not args.val_episodes:
        p.error("--patience needs --val-episodes")
    if args.val_episodes and args.val_every < 1:
        p.error("--val-every must be >= 1 with --val-episodes")
    if not args.val_episodes:
        args.val_every = 0
    return p, args


def main(argv: list[str] | None = None) -> int:
    p, args = _parse(argv)
    if not (args.data / "meta" / "info.json").is_file():
        p.error(f"{args.data} has no meta/info.json: not a LeRobot dataset folder (LeRobot would ask the hub)")
    try:
        args.episode_list = choose_episodes(args.data, args.episodes, args.successful_only)
        args.val_list = parse_episode_spec(args.data, args.val_episodes) if args.val_episodes else []
    except ValueError as exc:
        p.error(str(exc))
    if overlap := sorted(set(args.episode_list) & set(args.val_list)):
        p.error(f"validation episodes {overlap} are also training episodes")
    args.data = args.data.resolve()
    last = args.out / "checkpoints" / "last"
    if args.resume:
        _clean_partial(args.out)
    resuming = args.resume and last.is_dir()
    if args.resume and not resuming:  # nothing whole to resume from (killed during the first save): start over
        shutil.rmtree(args.out / "checkpoints", ignore_errors=True)
    elif not resuming and args.out.exists() and any(args.out.iterdir()):
        p.error(f"{args.out} exists and is not empty (--resume continues a run from its checkpoints/last)")

    import torch

    torch.set_num_threads(args.threads)
    # A fresh `datasets` cache, so an Arrow cache of an older export of the same path cannot answer.
    cache = tempfile.TemporaryDirectory(prefix="act_train_")
    os.environ.setdefault("HF_DATASETS_CACHE", cache.name)

    from accelerate import Accelerator
    from lerobot.datasets.factory import make_dataset
    from lerobot.datasets.utils import dataset_to_policy_features
    from lerobot.optim.factory import make_optimizer_and_scheduler
    from lerobot.policies.factory import make_policy, make_pre_post_processors
    from lerobot.scripts.lerobot_train import update_policy
    from lerobot.utils.logging_utils import AverageMeter, MetricsTracker
    from lerobot.utils.random_utils import set_seed
    from lerobot.utils.train_utils import load_training_state
    from safetensors.torch import load_model

    cfg = build_config(args)
    identity = _identity(args, cfg)
    state: dict[str, Any] = {}
    history: list[dict] = []
    if resuming:
        last = last.resolve()
        state = json.loads((last / "training_state" / STATE_FILE).read_text())
        history = json.loads((last / "training_state" / HISTORY_FILE).read_text())
        diff = _differences(state["identity"], identity)
        if diff:
            raise SystemExit(f"--resume: {args.out}'s checkpoint was trained otherwise (checkpoint, now): {diff}")
        past_stop = args.past_stop and state.get("finished") == "patience" and args.steps > state["step"]
        if state.get("finished") and not (state["finished"] == "steps" and args.steps > state["step"]) \
                and not past_stop:
            print(json.dumps({"already_finished": state["finished"], "step": state["step"], "out": str(args.out)}))
            return 0

    accelerator = Accelerator(step_scheduler_with_optimizer=False, cpu=args.device == "cpu")
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
    val_batches = (make_validation(cfg, args.val_list, args.val_stride, args.val_batch_size, preprocessor)
                   if args.val_list else [])
    args.val_frames = sum(len(b["action"]) for b in val_batches)
    setup_s = time.perf_counter() - t0

    policy, optimizer, lr_scheduler = accelerator.prepare(policy, optimizer, lr_scheduler)
    unwrapped = accelerator.unwrap_model(policy)
    if resuming:
        load_model(unwrapped, str(last / "pretrained_model" / "model.safetensors"), device=args.device)
        # LeRobot's own: optimizer state, step, RNG (python, numpy, torch[, cuda]) -- last, so that
        # nothing built above draws from the restored generators.
        step, optimizer, lr_scheduler = load_training_state(last, optimizer, lr_scheduler)
        if step != state["step"]:
            raise SystemExit(f"{last}: training_step.json says {step}, {STATE_FILE} {state['step']}")
        state["finished"] = None
    else:
        step = 0
        state = {"identity": identity, "step": 0, "epoch": 0, "batch_in_epoch": 0, "val": [], "best_val_l1": None,
                 "best_step": None, "seconds": {"train_loop": 0.0, "validation": 0.0, "checkpoint": 0.0},
                 "sessions": [], "finished": None}
    state["sessions"].append({"start_step": step, "started": dt.datetime.now().isoformat(timespec="seconds"),
                              "device": args.device, "threads": args.threads, "setup_s": setup_s,
                              "past_stop": bool(resuming and args.past_stop)})

    sampler = EpochBatches(dataset.num_frames, cfg.batch_size, cfg.seed, state["epoch"], state["batch_in_epoch"])
    # batch_sampler: our order; generator: the DataLoader draws its base seed from it, not from the global RNG
    dataloader = torch.utils.data.DataLoader(
        dataset, batch_sampler=sampler, num_workers=cfg.num_workers, pin_memory=args.device != "cpu",
        prefetch_factor=2 if cfg.num_workers > 0 else None, generator=torch.Generator(),
    )
    dl_iter = iter(dataloader)
    policy.train()
    meters = {
        "loss": AverageMeter("loss", ":.3f"), "grad_norm": AverageMeter("grdn", ":.3f"),
        "lr": AverageMeter("lr", ":0.1e"), "update_s": AverageMeter("updt_s", ":.3f"),
        "dataloading_s": AverageMeter("data_s", ":.3f"),
    }
    tracker = MetricsTracker(cfg.batch_size, dataset.num_frames, dataset.num_episodes, meters,
                             initial_step=step, accelerator=accelerator)
    static = _static_images(dataset)

    def summary() -> dict:
        return _summary(args, cfg, state, history, dataset, static, setup_s, torch.__version__)

    def validate() -> None:
        v0 = time.perf_counter()
        losses = validation_loss(unwrapped, val_batches, args.val_vae, args.device)
        state["seconds"]["validation"] += time.perf_counter() - v0
        entry = {"step": step, **losses, "seconds": round(time.perf_counter() - v0, 2),
                 "train_loop_s": round(state["seconds"]["train_loop"], 1),
                 "wall_s": round(sum(state["seconds"].values()), 1),
                 "time": dt.datetime.now().isoformat(timespec="seconds")}
        state["val"].append(entry)
        best = state["best_val_l1"]
        if best is None or losses["val_l1"] < best * (1 - args.min_delta):
            state["best_val_l1"], state["best_step"] = losses["val_l1"], step
        print(f"val step {step}: " + " ".join(f"{k} {v:.4f}" for k, v in losses.items()), file=sys.stderr, flush=True)

    def checkpoint() -> None:
        c0 = time.perf_counter()
        state["sessions"][-1]["end_step"] = step
        # beside the weights: the log without the per-step history (eval_act.py reads a few fields)
        light = {k: v for k, v in summary().items() if k != "history"}
        save_run_checkpoint(args.out, step, cfg, unwrapped, optimizer, lr_scheduler, preprocessor, postprocessor,
                            state, history, light, args.keep_every)
        state["seconds"]["checkpoint"] += time.perf_counter() - c0
        write_json(args.out / "train_log.json", summary())

    # SIGTERM/SIGINT (campaign.py stopping, `kill -TERM`): finish the step, checkpoint, exit; resumable
    interrupted: list[int] = []
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda signum, frame: interrupted.append(signum))

    def stop_reason() -> str | None:
        if (args.patience is not None and state["best_step"] is not None and step >= args.min_steps
                and step - state["best_step"] >= args.patience):
            return "patience"
        if step >= args.steps:
            return "steps"
        if args.stop_at is not None and step >= args.stop_at:
            return "stop_at"
        if interrupted:
            return "signal"
        return None

    if val_batches and not state["val"]:
        validate()  # step 0: the untrained policy, the curve's origin
    reason = stop_reason()
    while reason is None:
        start, cpu_start = time.perf_counter(), time.process_time()
        batch = preprocessor(next(dl_iter))
        tracker.dataloading_s = time.perf_counter() - start
        tracker, output = update_policy(tracker, policy, batch, optimizer, cfg.optimizer.grad_clip_norm,
                                        accelerator=accelerator, lr_scheduler=lr_scheduler)
        step += 1
        state["step"] = step
        state["epoch"], state["batch_in_epoch"] = sampler.advance(state["epoch"], state["batch_in_epoch"])
        history.append({"step": step, "loss": tracker.loss.val, "grad_norm": tracker.grad_norm.val, **output,
                        "update_s": round(tracker.update_s.val, 4), "data_s": round(tracker.dataloading_s.val, 4),
                        # this process's CPU time: unaffected by a pause (kill -STOP) or by sharing the core
                        "cpu_s": round(time.process_time() - cpu_start, 4)})
        state["seconds"]["train_loop"] += time.perf_counter() - start
        tracker.step()
        if cfg.log_freq > 0 and step % cfg.log_freq == 0:
            print(f"step {step}/{cfg.steps} {tracker}", file=sys.stderr, flush=True)
            tracker.reset_averages()
        if args.val_every and step % args.val_every == 0:
            validate()
        reason = stop_reason()
        if reason is not None or (args.checkpoint_every and step % args.checkpoint_every == 0):
            if reason in ("patience", "steps"):
                state["finished"] = reason
            checkpoint()
    if reason in ("patience", "steps") and not state["finished"]:  # met on (re)start: nothing trained
        state["finished"] = reason
        checkpoint()
    state["sessions"][-1]["end_step"] = step

    if state["finished"]:
        unwrapped.save_pretrained(args.out)
        preprocessor.save_pretrained(args.out)
        postprocessor.save_pretrained(args.out)
    log = summary()
    write_json(args.out / "train_log.json", log)
    if reason == "signal":
        print(f"stopped by signal {interrupted[0]} at step {step} (checkpointed; --resume continues)", file=sys.stderr)
    print(json.dumps({k: log.get(k) for k in ("steps", "finished", "stop_reason", "batch_size", "frames_used",
                                              "s_per_step", "s_per_step_median", "cpu_s_per_step",
                                              "s_per_step_update", "s_per_step_dataloading",
                                              "final_loss_mean_last10", "best_val_l1", "best_step")}))
    cache.cleanup()
    return 0


def _summary(args: argparse.Namespace, cfg, state: dict, history: list[dict], dataset, static: bool,
             setup_s: float, torch_version: str) -> dict:
    """``train_log.json``: settings, the validation log, timings and every step's loss."""
    from lerobot.configs.types import FeatureType

    def _mean(xs: list[float]) -> float | None:
        return sum(xs) / len(xs) if xs else None

    def _median(xs: list[float]) -> float | None:
        return sorted(xs)[len(xs) // 2] if xs else None

    steps = state["step"]
    skip = min(5, len(history) // 2)  # the first steps include one-off allocation
    tail = history[-10:]
    loop = state["seconds"]["train_loop"]
    return {
        "lerobot_version": __import__("importlib.metadata").metadata.version("lerobot"),
        "torch_version": torch_version,
        "data": str(args.data),
        "episodes_used": args.episode_list,
        "successful_only": args.successful_only,
        "val_episodes_used": args.val_list,
        "val_stride": args.val_stride,
        "val_frames": getattr(args, "val_frames", None),
        "frames_used": dataset.num_frames,
        "fps": dataset.meta.fps,
        "steps": steps,
        "epochs": steps * cfg.batch_size / dataset.num_frames,
        "steps_cap": args.steps,
        "stop_rule": {"min_steps": args.min_steps, "patience": args.patience, "min_delta": args.min_delta,
                      "val_every": args.val_every, "metric": "val_l1"},
        "finished": bool(state["finished"]),
        "stop_reason": state["finished"],
        "best_val_l1": state["best_val_l1"],
        "best_step": state["best_step"],
        "val": state["val"],
        "batch_size": cfg.batch_size,
        "seed": cfg.seed,
        "threads": args.threads,
        "num_workers": cfg.num_workers,
        "device": args.device,
        "seconds": {"setup": setup_s, "train": loop, **state["seconds"]},
        "sessions": state["sessions"],
        "s_per_step": loop / steps if steps else None,
        "s_per_step_update": _mean([h["update_s"] for h in history[skip:] if "update_s" in h]),
        "s_per_step_dataloading": _mean([h["data_s"] for h in history[skip:] if "data_s" in h]),
        # robust to a pause (kill -STOP) inside one step, which the means above include
        "s_per_step_median": _median([h["update_s"] + h["data_s"] for h in history[skip:] if "update_s" in h]),
        "cpu_s_per_step": _mean([h["cpu_s"] for h in history[skip:] if "cpu_s" in h]),
        "final_loss": history[-1]["loss"] if history else None,
        "final_loss_mean_last10": _mean([h["loss"] for h in tail]),
        "final_l1_mean_last10": _mean([h["l1_loss"] for h in tail]),
        "final_kld_mean_last10": _mean([h["kld_loss"] for h in tail if "kld_loss" in h]),
        "history": history,
        "input_features": {k: [v.type.name, list(v.shape)] for k, v in cfg.policy.input_features.items()},
        "output_features": {k: [v.type.name, list(v.shape)] for k, v in cfg.policy.output_features.items()},
        "ignored_by_act": [k for k, v in cfg.policy.input_features.items()
                           if v.type is FeatureType.STATE and k != "observation.state"],
        "webcam_static_in_episode": static,
        "optimizer": {"type": "adamw", **{k: v for k, v in vars(cfg.optimizer).items()}},
        "backbone_lr": cfg.policy.optimizer_lr_backbone,
        "scheduler": None if cfg.scheduler is None else type(cfg.scheduler).__name__,
        "use_imagenet_stats": cfg.dataset.use_imagenet_stats,
        "data_order": "per-epoch torch.randperm, generator seeded seed*1000003+epoch (train_act.EpochBatches)",
        "policy_config": json.loads(json.dumps(__import__("dataclasses").asdict(cfg.policy), default=str)),
    }


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
