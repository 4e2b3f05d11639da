import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from cuboidlib.distance import chamfer_distance, nearest_neighbors
from cuboidlib.neighbors import knn_indices, nearest_index, nearest_indices
from cuboidlib.normals import estimate_normals, normal_errors


def _brute_sq(a, b):
    return (a.double()[:, :, None] - b.double()[:, None]).square().sum(-1)


def test_knn_sorted_lists_the_point_first_then_by_distance():
    x = torch.rand(2, 300, 5, generator=torch.Generator().manual_seed(0))
    idx = knn_indices(x, 7, sorted=True)
    d = _brute_sq(x, x)
    assert torch.equal(idx[..., 0], torch.arange(300).expand(2, 300))
    torch.testing.assert_close(torch.gather(d, 2, idx), d.sort(-1).values[..., :7])


def test_knn_unsorted_gives_the_same_sets():
    x = torch.randn(1, 200, 3, generator=torch.Generator().manual_seed(1))
    assert torch.equal(knn_indices(x, 9).sort(-1).values, knn_indices(x, 9, sorted=True).sort(-1).values)


def test_nearest_indices_match_brute_force_in_both_directions():
    g = torch.Generator().manual_seed(2)
    a, b = torch.rand(3, 150, 3, generator=g), torch.rand(3, 90, 3, generator=g)
    a_to_b, b_to_a = nearest_indices(a, b, chunk=16)
    d = _brute_sq(a, b)
    assert torch.equal(a_to_b, d.argmin(2))
    assert torch.equal(b_to_a, d.argmin(1))
    assert torch.equal(nearest_index(a, b, chunk=16), a_to_b)  # the one-way search is the first half


def test_reverse_direction_returns_a_row_that_holds_the_column_minimum_under_ties():
    a = torch.tensor([[[0.0, 0, 0], [0.0, 0, 0], [5.0, 0, 0]]])  # rows 0 and 1 tie for b's first point
    b = torch.tensor([[[0.5, 0, 0], [4.0, 0, 0]]])
    _, b_to_a = nearest_indices(a, b, chunk=2)
    assert b_to_a[0, 0].item() in (0, 1) and b_to_a[0, 1].item() == 2


@pytest.mark.parametrize("offset", [100.0, 1e4])
def test_float32_search_far_from_the_origin_is_as_exact_as_near_it(offset):
    # |a|^2 + |b|^2 - 2ab cancels badly at large offsets; the search centres the points first
    p = torch.rand(1, 2048, 3, generator=torch.Generator().manual_seed(0))
    near = chamfer_distance(p, p + 1e-3)
    far = chamfer_distance(p + offset, p + offset + 1e-3)
    assert near.item() == pytest.approx(6e-6, rel=1e-3)
    assert far.item() == pytest.approx(6e-6, rel=0.05)  # float32 rounding of the shifted input only
    assert torch.equal(nearest_neighbors(p + offset, p + offset)[1], torch.arange(2048)[None])


def test_huge_coordinates_do_not_overflow():
    p = torch.rand(1, 500, 3, generator=torch.Generator().manual_seed(3))
    assert chamfer_distance(p + 1e20, p + 1e20).item() == 0.0
    spread = p * 1e25  # squared distances overflow float32: the search runs in float64
    idx = nearest_neighbors(spread, spread)[1]
    assert torch.equal(idx, torch.arange(500)[None])
    assert torch.equal(knn_indices(spread, 3, sorted=True), knn_indices(p.double(), 3, sorted=True))


def test_normals_far_from_the_origin_are_as_good_as_near_it():
    from cuboidlib.shapes import make_shape

    s = make_shape("chair", 0, n_points=2048)
    pts = torch.as_tensor(s.points, dtype=torch.float64)
    errors = {}
    for offset in (0.0, 1e4):
        angle, flipped = normal_errors(estimate_normals((pts + offset).float()), torch.as_tensor(s.normals))
        errors[offset] = (float(angle.median()), float(flipped.float().mean()))
    assert abs(errors[1e4][0] - errors[0.0][0]) < 1.0, errors  # median angle, degrees
    assert abs(errors[1e4][1] - errors[0.0][1]) < 0.01, errors  # share of flipped normals


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(1, 40),
    m=st.integers(1, 40),
    dim=st.integers(1, 6),
    scale=st.sampled_from([1e-6, 1.0, 1e3, 1e8]),
    offset=st.sampled_from([0.0, -50.0, 1e3]),
    seed=st.integers(0, 2**16),
)
def test_nearest_indices_property(n, m, dim, scale, offset, seed):
    g = torch.Generator().manual_seed(seed)
    a = (torch.rand(1, n, dim, generator=g, dtype=torch.float64) * scale + offset)
    b = (torch.rand(1, m, dim, generator=g, dtype=torch.float64) * scale + offset)
    a_to_b, b_to_a = nearest_indices(a, b)
    d = _brute_sq(a, b)
    # the chosen neighbour is as near as the best one (ties may pick either)
    torch.testing.assert_close(torch.gather(d, 2, a_to_b[..., None])[..., 0], d.amin(2), rtol=1e-9, atol=0)
    torch.testing.assert_close(torch.gather(d, 1, b_to_a[:, None])[:, 0], d.amin(1), rtol=1e-9, atol=0)
    one_way = nearest_index(a, b)
    torch.testing.assert_close(torch.gather(d, 2, one_way[..., None])[..., 0], d.amin(2), rtol=1e-9, atol=0)


def test_bad_k():
    with pytest.raises(ValueError, match="k must be an integer"):
        knn_indices(torch.zeros(1, 4, 3), 5)
    with pytest.raises(ValueError, match="k must be an integer"):
        knn_indices(torch.zeros(1, 4, 3), 0)
