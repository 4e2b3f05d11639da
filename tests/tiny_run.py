"""What the tests of training and release share: a network whose step takes milliseconds, and checks on weights.

The ``tiny`` fixture, a run of this network, is in conftest.py."""

from __future__ import annotations

import torch

from cuboidlib.checkpoint import load_checkpoint
from cuboidlib.model import ModelConfig

#: A network small enough for a step to take milliseconds; same structure as the paper's.
TINY_MODEL = ModelConfig.small(num_cuboids=4, k=8, edge_dims=(8, 8), global_dim=16, latent_dim=8, cuboid_code_dim=8,
                               cuboid_feature_dims=(16, 16), exist_hidden_dim=8, seg_dim=8)


def weights(path):
    """The model weights a checkpoint holds."""
    return load_checkpoint(path)["model"]


def assert_same_state(a: dict, b: dict):
    """Two state dicts hold the same tensors, bit for bit."""
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), f"{k} differs"
