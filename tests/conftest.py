"""Fixtures shared across the test files: the shipped models (read-only) and a one-thread torch."""

from __future__ import annotations

import pytest
import torch

import seqmotion as sm


@pytest.fixture(scope="session")
def deformer():
    """The shipped Deformer (``sm.load_pretrained("pancake")``); tests must not modify it. Test files
    that train their own tiny model define their own ``deformer``, which takes precedence."""
    return sm.load_pretrained("pancake")


@pytest.fixture(scope="session")
def planner():
    """The shipped SlidingPlanner (``sm.load_pretrained("sliding")``); tests must not modify it."""
    return sm.load_pretrained("sliding")


@pytest.fixture(scope="module")
def one_thread():
    """torch on one thread for the module, restored afterwards: a control loop steps a batch of one,
    where one thread is fastest and least disturbed by a busy machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
