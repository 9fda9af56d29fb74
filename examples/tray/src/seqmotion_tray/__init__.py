"""A seqmotion task defined outside seqmotion: carry a cup on a tray (see ``task.py``)."""

from .task import TASK, TrayOptions, TrayTask

__all__ = ["TASK", "TrayOptions", "TrayTask"]
