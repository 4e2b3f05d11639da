import pytest
import torch

from cuboidlib.baseline import fit_cluster_boxes, kmeans, oriented_bounding_box
from cuboidlib.geometry import sample_cuboid_surfaces
from cuboidlib.rotations import quaternion_to_rotation_matrix, random_quaternions


def test_kmeans_separates_well_separated_blobs_and_is_deterministic():
    g = torch.Generator().manual_seed(0)
    centres = torch.tensor([[0.0, 0.0], [5.0, 0.0], [0.0, 5.0]])
    x = torch.cat([c + 0.1 * torch.randn(50, 2, generator=g) for c in centres])
    labels, c = kmeans(x, 3, generator=torch.Generator().manual_seed(1))
    for block in labels.view(3, 50):  # every blob is one cluster, and the three clusters differ
        assert torch.all(block == block[0])
    assert len(set(labels.view(3, 50)[:, 0].tolist())) == 3
    again, _ = kmeans(x, 3, generator=torch.Generator().manual_seed(1))
    assert torch.equal(labels, again)
    torch.testing.assert_close(c[labels.view(3, 50)[:, 0]], centres, atol=0.05, rtol=0)


def test_kmeans_runs_a_batch_of_point_sets_like_each_one_alone():
    g = torch.Generator().manual_seed(0)
    true_centers = torch.tensor([[-3.0, 0, 0], [0, 3.0, 0], [0, 0, 3.0]])
    points = torch.stack([true_centers.repeat_interleave(50, 0) + 0.1 * torch.randn(150, 3, generator=g)
                          for _ in range(2)])
    labels, centers = kmeans(points, 3, generator=torch.Generator().manual_seed(1))
    assert labels.shape == (2, 150) and centers.shape == (2, 3, 3)
    for b in range(2):  # every true blob gets its own centre, every blob is one cluster
        distance = torch.cdist(true_centers, centers[b])
        assert distance.amin(dim=1).max() < 0.1
        assert len(set(distance.argmin(dim=1).tolist())) == 3
        assert all(len(set(labels[b, 50 * k:50 * (k + 1)].tolist())) == 1 for k in range(3))
    one, _ = kmeans(points[:1], 3, generator=torch.Generator().manual_seed(1))
    alone, _ = kmeans(points[0], 3, generator=torch.Generator().manual_seed(1))
    assert torch.equal(one[0], alone)


def test_kmeans_rejects_bad_k():
    with pytest.raises(ValueError, match="k must be"):
        kmeans(torch.zeros(4, 2), 5)


def test_oriented_bounding_box_recovers_a_rotated_box():
    g = torch.Generator().manual_seed(0)
    q = random_quaternions(1, generator=g)
    center, half = torch.tensor([[[0.3, -0.2, 0.1]]]), torch.tensor([[[0.5, 0.2, 0.05]]])
    corners_local = torch.cartesian_prod(*[torch.tensor([-1.0, 1.0])] * 3) * half[0, 0]
    inside = (torch.rand(500, 3, generator=g) * 2 - 1) * half[0, 0]
    local = torch.cat([corners_local, inside])
    R = quaternion_to_rotation_matrix(q)[0]
    points = local @ R.T + center[0, 0]
    c, qq, h = oriented_bounding_box(points)
    torch.testing.assert_close(c, center[0, 0], atol=1e-4, rtol=0)
    torch.testing.assert_close(h, half[0, 0], atol=0.01, rtol=0)  # PCA axes of a sample are slightly off
    R2 = quaternion_to_rotation_matrix(qq)
    assert torch.allclose((R2.T @ R).abs(), torch.eye(3), atol=0.03)  # same axes up to sign, within ~2 degrees


def test_oriented_bounding_box_of_one_point_is_a_tiny_box():
    c, q, h = oriented_bounding_box(torch.tensor([[1.0, 2.0, 3.0]]))
    torch.testing.assert_close(c, torch.tensor([1.0, 2.0, 3.0]))
    assert torch.all(h == 1e-3)
    with pytest.raises(ValueError, match="empty"):
        oriented_bounding_box(torch.zeros(0, 3))


def test_fit_cluster_boxes_on_two_separate_boxes():
    centers = torch.tensor([[[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    quats = torch.tensor([[[1.0, 0.0, 0.0, 0.0]] * 2])
    half = torch.tensor([[[0.3, 0.2, 0.1], [0.15, 0.3, 0.06]]])  # distinct sizes: PCA axes are well defined
    s = sample_cuboid_surfaces(centers, quats, half, 2000, generator=torch.Generator().manual_seed(0))
    result = fit_cluster_boxes(s.points[0], s.normals[0], num_boxes=2, normal_weight=0.0)
    assert result.cuboids.num_cuboids == 2 and result.labels.shape == (1, 2000) and bool(result.cuboids.exists.all())
    # each fitted box matches one true box
    order = result.cuboids.centers[0, :, 0].argsort()
    torch.testing.assert_close(result.cuboids.centers[0, order], centers[0], atol=0.02, rtol=0)
    torch.testing.assert_close(result.cuboids.half_sizes[0, order].sort(dim=-1).values, half[0].sort(dim=-1).values,
                               atol=0.02, rtol=0)


def test_fit_cluster_boxes_rejects_mismatched_normals():
    with pytest.raises(ValueError, match="normals"):
        fit_cluster_boxes(torch.zeros(10, 3), torch.zeros(9, 3), 2)
