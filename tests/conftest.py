"""Fixtures shared by several test modules."""

from __future__ import annotations

import os

import pytest
import torch

from cuboidlib import kernels
from cuboidlib.dataset import load_splits
from cuboidlib.shapes import make_shape
from cuboidlib.train_config import TrainConfig
from tiny_run import TINY_MODEL


@pytest.fixture(autouse=True)
def reference_code_by_default(monkeypatch):
    """The library's tests run the PyTorch code, the reference, in this process and in the commands they start;
    the tests of the compiled kernels ask for them (tests/test_kernels.py). The lessons run as a learner's do."""
    monkeypatch.setenv(kernels.ENV, "0")
    kernels.disable()
    yield
    kernels.disable()


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    """A private collection cache for the module (``CUBOIDLIB_CACHE``, also handed to subprocesses)."""
    path = tmp_path_factory.mktemp("cache")
    old = os.environ.get("CUBOIDLIB_CACHE")
    os.environ["CUBOIDLIB_CACHE"] = str(path)
    yield path
    if old is None:
        del os.environ["CUBOIDLIB_CACHE"]
    else:
        os.environ["CUBOIDLIB_CACHE"] = old


@pytest.fixture
def restore_threads():
    """Put torch's thread count back after a test that sets it (the trainer does)."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


# Property-based tests (Hypothesis) draw the same cases on every run, so a CI run is repeatable;
# `pytest --hypothesis-profile explore` draws new, more numerous cases to look for failures.
from hypothesis import settings  # noqa: E402

settings.register_profile("repeatable", derandomize=True, database=None)
settings.register_profile("explore", max_examples=500, database=None)
settings.load_profile("repeatable")


@pytest.fixture(scope="module")
def chair():
    """A procedural chair of 512 points (tests/test_hostile_inputs.py and test_hostile_files.py)."""
    return make_shape("chair", 2, n_points=512)


@pytest.fixture(scope="module")
def tiny(cache_dir):
    """(config, splits) of a tiny run: 20 chairs of 96 points, batch 4 (3 steps per epoch)."""
    config = TrainConfig(category="chair", n_shapes=20, n_points=96, batch_size=4, max_steps=9, checkpoint_every=3,
                         validate_every=4, num_threads=1, model=TINY_MODEL, seed=3)
    return config, load_splits(config)
