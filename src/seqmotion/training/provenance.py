"""Provenance of a run: the machine it ran on and the command that started it (recorded with every model)."""

from __future__ import annotations

import os
import platform
import shlex
import sys

import torch


def machine_record() -> dict:
    """Where a run happened: CPU model, cores, torch threads, GPU, versions and the load it ran under."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {
        "platform": platform.platform(),
        "processor": cpu,
        "cpus": os.cpu_count(),
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }


def machine_description() -> str:
    """:func:`machine_record` in one line: what a timing needs to be read against."""
    return describe_machine(machine_record())


def describe_machine(record: dict) -> str:
    """A :func:`machine_record` (possibly an older one, missing some fields) in one line.

    A complete record gives ``"<cpu>, <n> cores, <t> torch threads[, GPU <name>]; Python <v>, torch <v>"``;
    fields the record lacks are left out.
    """
    gpu = f", GPU {record['gpu']}" if record.get("gpu") else ""
    versions = ", ".join(f"{name} {record[key]}" for name, key in (("Python", "python"), ("torch", "torch"))
                         if record.get(key))
    return (f"{record.get('processor', 'unknown CPU')}, {record.get('cpus', '?')} cores, "
            f"{record.get('torch_threads', '?')} torch threads{gpu}" + (f"; {versions}" if versions else ""))


def command_line(program: str = "seqmotion") -> str:
    """This process's command as ``program`` plus its shell-quoted arguments, pasteable back into a shell."""
    return " ".join([program, *map(shlex.quote, sys.argv[1:])])
