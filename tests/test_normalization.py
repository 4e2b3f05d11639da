import numpy as np
import pytest
import torch

from cuboidlib.normalization import bounding_box, denormalize, normalize


def test_hand_computed_box():
    # Bounding box [1, 3] x [2, 6] x [-1, 3]: centre (2, 4, 1), sides (2, 4, 4), diagonal 6.
    pts = np.array([[1.0, 2.0, -1.0], [3.0, 6.0, 3.0], [2.0, 3.0, 0.0]])
    out, center, scale = normalize(pts)
    np.testing.assert_allclose(center, [2.0, 4.0, 1.0])
    assert scale == pytest.approx(6.0)
    np.testing.assert_allclose(out[0], [-1 / 6, -2 / 6, -2 / 6])
    assert isinstance(out, np.ndarray)


def test_result_has_unit_diagonal_and_centred_box_and_round_trips():
    g = torch.Generator().manual_seed(0)
    pts = torch.rand(2, 100, 3, generator=g) * torch.tensor([3.0, 1.0, 0.5]) + 7.0
    out, center, scale = normalize(pts)
    lo, hi = bounding_box(out)
    torch.testing.assert_close((lo + hi) / 2, torch.zeros(2, 3), atol=1e-6, rtol=0)
    torch.testing.assert_close(torch.linalg.vector_norm(hi - lo, dim=-1), torch.ones(2))
    assert center.shape == (2, 3) and scale.shape == (2,)
    torch.testing.assert_close(denormalize(out, center, scale), pts)


def test_normalising_twice_is_the_identity_and_scaling_the_input_does_not_matter():
    pts = np.random.default_rng(1).normal(size=(50, 3))
    once, _, _ = normalize(pts)
    twice, c2, s2 = normalize(once)
    np.testing.assert_allclose(twice, once, atol=1e-12)
    np.testing.assert_allclose(c2, 0, atol=1e-12)
    assert s2 == pytest.approx(1.0)
    scaled, _, _ = normalize(pts * 5 + 3)
    np.testing.assert_allclose(scaled, once, atol=1e-12)


def test_bad_inputs():
    with pytest.raises(ValueError, match="identical"):
        normalize(np.ones((10, 3)))
    with pytest.raises(ValueError, match="NaN"):
        normalize(np.array([[0.0, 0, 0], [np.nan, 1, 1]]))
    with pytest.raises(ValueError, match="empty"):
        normalize(np.zeros((0, 3)))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        normalize(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="scale must be positive"):
        denormalize(np.zeros((4, 3)), np.zeros(3), np.array(0.0))
    with pytest.raises(ValueError, match="center must have shape"):
        denormalize(np.zeros((4, 3)), np.zeros(2), np.array(1.0))
