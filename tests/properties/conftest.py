"""Hypothesis settings for the property tests: profile "ci" (the default here) is derandomized (the
same examples on every run and machine), has no deadline (the first JAX example compiles) and
few examples per test, to fit the suite's time budget. HYPOTHESIS_PROFILE=thorough runs 200."""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

from tests.backends import INSTALLED

settings.register_profile(
    "ci",
    max_examples=8,
    derandomize=True,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.differing_executors],
)
settings.register_profile("thorough", parent=settings.get_profile("ci"), max_examples=200)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


@pytest.fixture(autouse=True)
def one_torch_thread():
    """The tiny property inputs run ~20x faster on one intra-op thread than on two when the 2 CPU
    cores are already busy (pytest -n 2); the previous setting is restored after each test."""
    if not INSTALLED["torch"]:
        yield
        return
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)
