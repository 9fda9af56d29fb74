"""Choosing the device a training or an inference runs on: ``auto``, ``cpu``, ``cuda`` or ``cuda:N``.

``auto`` is the first GPU when PyTorch sees one (``torch.cuda.is_available()``), else the CPU. A
device that cannot be used here is refused by name with a ``ValueError`` before anything is built:
an unknown string, ``cuda`` on a machine (or a PyTorch build) without CUDA, ``cuda:N`` beyond the
GPUs there are.

Checkpoints do not depend on the device: weights, Adam's state and generator states are written
as CPU tensors (:mod:`.checkpoint`) and read back as CPU tensors, and loading copies them onto
whatever device the model lives on. A run trained on a GPU resumes on a CPU and the other way round.
"""

from __future__ import annotations

import os
import re

import torch

DEVICE_CHOICES = ("auto", "cpu", "cuda", "cuda:N")
"""What ``--device`` / ``device=`` accept (``N`` a GPU index)."""
_CUDA = re.compile(r"cuda(?::(\d+))?")


def resolve_device(device: object = "auto") -> torch.device:
    """The :class:`torch.device` that ``device`` names (``"auto"``, ``"cpu"``, ``"cuda"``, ``"cuda:N"``, a
    ``torch.device`` of those kinds, or None for ``"auto"``).

    Raises:
        ValueError: an unknown device, or a CUDA device this machine does not have.
    """
    if device is None:
        device = "auto"
    if isinstance(device, torch.device):
        text = str(device)
    elif isinstance(device, str):
        text = device.strip().lower()
    else:
        raise ValueError(f"device must be one of {', '.join(DEVICE_CHOICES)}, got {type(device).__name__} {device!r}")
    if text == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if text == "cpu":
        return torch.device("cpu")
    match = _CUDA.fullmatch(text)
    if match is None:
        raise ValueError(f"unknown device {device!r}; choose one of {', '.join(DEVICE_CHOICES)}")
    if not torch.cuda.is_available():
        why = "this PyTorch build has no CUDA support" if torch.version.cuda is None else "no CUDA GPU is visible"
        raise ValueError(f"device {device!r} needs a CUDA GPU, but {why} (torch.cuda.is_available() is False); "
                         "use --device cpu or auto")
    index = int(match.group(1)) if match.group(1) is not None else None
    count = torch.cuda.device_count()
    if index is not None and index >= count:
        raise ValueError(f"device {device!r} does not exist: this machine has {count} CUDA GPU(s) "
                         f"(cuda:0 to cuda:{count - 1})")
    return torch.device("cuda", index if index is not None else torch.cuda.current_device())


def process_device(device: torch.device, world: int) -> torch.device:
    """This process's device in a run of ``world`` processes: on GPUs, one process per GPU
    (``cuda:LOCAL_RANK``, as torchrun numbers them); on the CPU, the CPU."""
    if device.type != "cuda" or world <= 1:
        return device
    local = int(os.environ.get("LOCAL_RANK", "0"))
    count = torch.cuda.device_count()
    if local >= count:
        raise ValueError(f"process {local} of this node needs its own GPU, but there are {count} "
                         "(start at most one process per GPU: torchrun --nproc_per_node <= GPUs)")
    return torch.device("cuda", local)


def backend_for(device: torch.device) -> str:
    """The process group's backend for data parallelism on ``device``: ``nccl`` on GPUs, ``gloo`` on CPUs."""
    return "nccl" if device.type == "cuda" else "gloo"


def model_device(module: torch.nn.Module) -> torch.device:
    """The device a module's parameters (or, without any, its buffers) live on (CPU for neither)."""
    for tensor in module.parameters():
        return tensor.device
    for tensor in module.buffers():
        return tensor.device
    return torch.device("cpu")
