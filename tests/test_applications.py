"""Tests of cuboidlib.applications: generation, interpolation, structural clustering, checkpoints by name.

A tiny randomly initialised network is enough: validity, determinism and the exact endpoints of an
interpolation do not depend on training. Clustering scores are checked against values computed by
hand from contingency tables.
"""

from __future__ import annotations

import math

import pytest
import torch

from cuboidlib.applications import (
    CHECKPOINT_DIR_ENV,
    abstract_shapes,
    adjusted_rand_index,
    cluster_by_existence,
    committed_checkpoints,
    cuboid_step_changes,
    decode_latents,
    encode_shapes,
    existence_groups,
    existence_mask,
    generate_shapes,
    interpolate_codes,
    interpolate_latents,
    load_trained_model,
    purity,
    resolve_checkpoint,
)
from cuboidlib.checkpoint import save_checkpoint
from cuboidlib.geometry import Cuboids
from cuboidlib.losses import allocation_weighted_centers
from cuboidlib.model import CuboidAbstractionNet, ModelConfig

TINY = ModelConfig.small(num_cuboids=5, k=4, edge_dims=(4,), global_dim=8, latent_dim=4, cuboid_code_dim=4,
                         cuboid_feature_dims=(8,), exist_hidden_dim=4, seg_dim=4)


@pytest.fixture(scope="module")
def model() -> CuboidAbstractionNet:
    torch.manual_seed(0)
    net = CuboidAbstractionNet(TINY)
    net.train()  # the applications must switch to evaluation mode themselves (and back)
    return net


@pytest.fixture(scope="module")
def clouds() -> torch.Tensor:
    g = torch.Generator().manual_seed(1)
    return torch.rand(2, 40, 3, generator=g) - 0.5


def _set_existence_bias(net: CuboidAbstractionNet, value: float) -> None:
    with torch.no_grad():
        net.abstraction.D_cp.existence[-1].bias.fill_(value)


# ----------------------------------------------------------------------------------------------
# Existence and decoding
# ----------------------------------------------------------------------------------------------


def test_existence_mask_thresholds_and_keeps_the_most_probable_cuboid_of_an_empty_shape():
    probs = torch.tensor([[0.9, 0.2, 0.6], [0.1, 0.4, 0.3]])
    expected = torch.tensor([[True, False, True], [False, True, False]])
    assert torch.equal(existence_mask(probs), expected)
    assert torch.equal(existence_mask(probs, threshold=0.0), torch.ones(2, 3, dtype=torch.bool))
    with pytest.raises(ValueError, match="threshold must lie in"):
        existence_mask(probs, threshold=1.0)
    with pytest.raises(ValueError, match="exist_probs must have shape"):
        existence_mask(torch.rand(3))


def test_generated_shapes_are_valid_and_repeatable(model):
    shapes = generate_shapes(model, 6, torch.Generator().manual_seed(3))
    c = shapes.cuboids
    assert c.centers.shape == (6, 5, 3) and shapes.z.shape == (6, TINY.latent_dim) and len(shapes) == 6
    assert (c.centers.abs() < 1).all()  # tanh head
    assert ((c.half_sizes > 0) & (c.half_sizes < 1)).all()  # sigmoid head
    torch.testing.assert_close(c.quaternions.norm(dim=-1), torch.ones(6, 5))
    assert torch.equal(c.exists, existence_mask(shapes.exist_probs))
    assert (shapes.num_existing() >= 1).all()
    assert shapes.labels is None and shapes.W is None
    again = generate_shapes(model, 6, torch.Generator().manual_seed(3))
    assert torch.equal(again.cuboids.centers, c.centers) and torch.equal(again.z, shapes.z)
    other = generate_shapes(model, 6, torch.Generator().manual_seed(4))
    assert not torch.equal(other.z, shapes.z)
    assert model.training  # the model's mode is restored


def test_generated_codes_are_standard_normal_and_decoded_by_the_network(model):
    g = torch.Generator().manual_seed(7)
    shapes = generate_shapes(model, 3, g)
    z = torch.randn(3, TINY.latent_dim, generator=torch.Generator().manual_seed(7))
    assert torch.equal(shapes.z, z)
    model.eval()
    try:
        with torch.no_grad():
            pred = model.decode(z)
    finally:
        model.train()
    assert torch.equal(shapes.cuboids.centers, pred.centers)
    assert torch.equal(shapes.exist_probs, torch.sigmoid(pred.exist_logits))


def test_existence_follows_the_probabilities_with_at_least_one_cuboid(model):
    z = torch.randn(4, TINY.latent_dim, generator=torch.Generator().manual_seed(0))
    original = model.abstraction.D_cp.existence[-1].bias.clone()
    try:
        _set_existence_bias(model, -50.0)  # every probability ~0: only the most probable cuboid is kept
        none = decode_latents(model, z)
        assert torch.equal(none.num_existing(), torch.ones(4, dtype=torch.long))
        assert torch.equal(none.cuboids.exists.float().argmax(dim=1), none.exist_probs.argmax(dim=1))
        _set_existence_bias(model, 50.0)  # every probability ~1
        assert decode_latents(model, z).cuboids.exists.all()
    finally:
        with torch.no_grad():
            model.abstraction.D_cp.existence[-1].bias.copy_(original)


def test_generate_rejects_bad_arguments(model):
    with pytest.raises(ValueError, match="n_shapes must be a positive integer"):
        generate_shapes(model, 0)
    with pytest.raises(TypeError, match="model must be a CuboidAbstractionNet"):
        decode_latents(torch.nn.Linear(2, 2), torch.zeros(1, 4))
    with pytest.raises(ValueError, match="z must have shape"):
        decode_latents(model, torch.zeros(2, TINY.latent_dim + 1))


def test_abstraction_segments_points_into_existing_cuboids_only(model, clouds):
    original = model.abstraction.D_cp.existence[-1].bias.clone()
    try:
        _set_existence_bias(model, -50.0)  # one existing cuboid per shape: every point goes to it
        out = abstract_shapes(model, clouds)
        kept = out.cuboids.exists.float().argmax(dim=1)
        assert torch.equal(out.labels, kept[:, None].expand(2, 40))
        _set_existence_bias(model, 50.0)  # all exist: the labels are the argmax of W
        out = abstract_shapes(model, clouds)
        assert torch.equal(out.labels, out.W.argmax(dim=-1))
    finally:
        with torch.no_grad():
            model.abstraction.D_cp.existence[-1].bias.copy_(original)
    assert out.z.shape == (2, TINY.latent_dim) and out.W.shape == (2, 40, 5)
    one = abstract_shapes(model, clouds[0])  # (N, 3) is one shape
    assert one.labels.shape == (1, 40)
    full, chunked = abstract_shapes(model, clouds), abstract_shapes(model, clouds, batch_size=1)
    torch.testing.assert_close(chunked.cuboids.centers, full.cuboids.centers)  # batching changes nothing
    torch.testing.assert_close(chunked.W, full.W)
    assert torch.equal(chunked.cuboids.exists, full.cuboids.exists) and torch.equal(chunked.labels, full.labels)
    centroids = abstract_shapes(model, clouds, centers_from_allocation=True)
    torch.testing.assert_close(centroids.cuboids.centers, allocation_weighted_centers(centroids.W, clouds))


# ----------------------------------------------------------------------------------------------
# Interpolation
# ----------------------------------------------------------------------------------------------


def test_cuboid_step_changes_measure_the_largest_corner_move():
    half = [0.1, 0.2, 0.3]
    identity = [1.0, 0.0, 0.0, 0.0]
    quarter_turn_z = [math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]
    centers = torch.tensor([[[0.0, 0, 0], [1, 0, 0]], [[0.1, 0, 0], [1, 0, 0]], [[10.0, 0, 0], [1, 0, 0]]])
    quaternions = torch.tensor([[identity, identity], [identity, identity], [identity, quarter_turn_z]])
    half_sizes = torch.tensor([[half, half]] * 3)
    exists = torch.tensor([[True, True], [True, True], [False, True]])
    change, flips = cuboid_step_changes(Cuboids(centers, quaternions, half_sizes, exists))
    # step 1: cuboid 0 moves by 0.1; step 2: cuboid 0 disappears (its move is ignored) and cuboid 1 turns
    # by 90 degrees about z: corner (x, y, z) -> (-y, x, z) moves by sqrt((x + y)^2 + (x - y)^2).
    torch.testing.assert_close(change, torch.tensor([0.1, math.sqrt(2 * (0.1**2 + 0.2**2))]))
    assert flips.tolist() == [0, 1]
    with pytest.raises(ValueError, match="at least 2 shapes"):
        cuboid_step_changes(Cuboids(centers[:1], quaternions[:1], half_sizes[:1]))


def test_interpolation_endpoints_are_exactly_the_decoded_encodings(model, clouds):
    path = interpolate_latents(model, clouds[0], clouds[1], steps=6)
    mu_a = encode_shapes(model, clouds[0])
    mu_b = encode_shapes(model, clouds[1])
    first, last = decode_latents(model, mu_a), decode_latents(model, mu_b)
    s = path.shapes.cuboids
    for name in ("centers", "quaternions", "half_sizes", "exists"):
        assert torch.equal(getattr(s, name)[:1], getattr(first.cuboids, name))
        assert torch.equal(getattr(s, name)[-1:], getattr(last.cuboids, name))
    assert torch.equal(path.shapes.z[0], mu_a[0]) and torch.equal(path.shapes.z[-1], mu_b[0])
    assert path.t[0] == 0 and path.t[-1] == 1 and len(path.t) == 6
    expected = (1 - path.t[:, None]) * mu_a + path.t[:, None] * mu_b
    torch.testing.assert_close(path.shapes.z, expected)  # a straight line in latent space
    assert path.step_change.shape == (5,) and path.existence_changes.shape == (5,)
    assert path.evenness >= 1
    assert model.training


def test_finer_interpolation_moves_the_cuboids_less_per_step(model, clouds):
    coarse = interpolate_latents(model, clouds[0], clouds[1], steps=3)
    fine = interpolate_latents(model, clouds[0], clouds[1], steps=17)
    assert fine.max_step_change < coarse.max_step_change / 2  # 8x smaller steps in z: a continuous path


def test_interpolating_a_shape_with_itself_changes_nothing(model, clouds):
    path = interpolate_latents(model, clouds[0], clouds[0], steps=4)
    assert path.max_step_change == 0 and path.existence_changes.sum() == 0
    assert path.evenness == float("inf")


def test_interpolation_rejects_bad_arguments(model, clouds):
    with pytest.raises(ValueError, match="steps must be an integer >= 2"):
        interpolate_latents(model, clouds[0], clouds[1], steps=1)
    with pytest.raises(ValueError, match="points_a must be ONE point cloud"):
        interpolate_latents(model, clouds, clouds[1])
    with pytest.raises(ValueError, match="z_b must have shape"):
        interpolate_codes(model, torch.zeros(TINY.latent_dim), torch.zeros(TINY.latent_dim + 2))
    with pytest.raises(ValueError, match="NaN"):
        interpolate_codes(model, torch.zeros(TINY.latent_dim), torch.full((TINY.latent_dim,), float("nan")))


# ----------------------------------------------------------------------------------------------
# Structural clustering
# ----------------------------------------------------------------------------------------------


def test_shapes_with_identical_existence_vectors_share_a_group():
    exists = torch.tensor([[1, 0, 1], [0, 1, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1], [1, 0, 1]], dtype=torch.bool)
    ids = cluster_by_existence(exists)
    # groups by size: {0, 2, 5} (3 shapes), {1, 4} (2), {3} (1)
    assert ids.tolist() == [0, 1, 0, 2, 1, 0]
    groups = existence_groups(exists)
    assert [(g.cluster, g.size, g.cuboids, g.members) for g in groups] == [
        (0, 3, [0, 2], [0, 2, 5]), (1, 2, [1, 2], [1, 4]), (2, 1, [0, 1, 2], [3])
    ]
    assert cluster_by_existence(exists.long()).tolist() == ids.tolist()  # 0/1 integers are accepted


def test_groups_of_equal_size_are_numbered_by_first_appearance():
    exists = torch.tensor([[0, 1], [1, 0], [0, 1], [1, 0]], dtype=torch.bool)
    assert cluster_by_existence(exists).tolist() == [0, 1, 0, 1]


def test_clustering_rejects_probabilities_and_bad_shapes():
    with pytest.raises(ValueError, match="threshold probabilities first"):
        cluster_by_existence(torch.rand(3, 4))
    with pytest.raises(ValueError, match=r"exists must have shape \(S, M\)"):
        cluster_by_existence(torch.ones(4, dtype=torch.bool))
    with pytest.raises(ValueError, match="booleans or 0/1"):
        cluster_by_existence(torch.tensor([[0, 2]]))


def test_purity_and_ari_match_hand_computed_tables():
    clusters, truth = [0, 0, 0, 1, 1, 1], [0, 0, 1, 1, 2, 2]
    # contingency [[2, 1, 0], [0, 1, 2]]: majority counts 2 + 2 of 6 shapes
    assert purity(clusters, truth) == pytest.approx(4 / 6)
    # index = C(2,2) + C(2,2) = 2; rows C(3,2) * 2 = 6; columns C(2,2) * 3 = 3; C(6,2) = 15
    # expected = 6 * 3 / 15 = 1.2; maximum = (6 + 3) / 2 = 4.5; ARI = 0.8 / 3.3
    assert adjusted_rand_index(clusters, truth) == pytest.approx(0.8 / 3.3)
    # [0,0,1,2] vs [0,0,1,1]: index 1, rows 1, columns 2, C(4,2) = 6: (1 - 1/3) / (1.5 - 1/3) = 4/7
    assert adjusted_rand_index([0, 0, 1, 2], [0, 0, 1, 1]) == pytest.approx(4 / 7)
    # worse than chance: [0,1,0,1] vs [0,0,1,1]: index 0, expected 2 * 2 / 6, maximum 2
    assert adjusted_rand_index([0, 1, 0, 1], [0, 0, 1, 1]) == pytest.approx(-0.5)


def test_ari_is_one_for_renamed_partitions_and_symmetric():
    a = torch.tensor([3, 3, 7, 7, 7, 1])
    b = torch.tensor([0, 0, 5, 5, 5, 9])
    assert adjusted_rand_index(a, b) == pytest.approx(1.0) and purity(a, b) == 1.0
    x, y = [0, 0, 1, 1, 2, 2, 2], [1, 0, 1, 2, 2, 2, 0]
    assert adjusted_rand_index(x, y) == pytest.approx(adjusted_rand_index(y, x))
    assert adjusted_rand_index([0, 0, 0], [5, 5, 5]) == 1.0  # both trivial: identical partitions
    assert adjusted_rand_index([0, 1, 2], [2, 0, 1]) == 1.0
    assert adjusted_rand_index([4], [2]) == 1.0


def test_purity_rewards_splitting_while_ari_does_not():
    truth = [0, 0, 0, 0, 1, 1, 1, 1]
    singletons = list(range(8))
    assert purity(singletons, truth) == 1.0
    assert adjusted_rand_index(singletons, truth) == pytest.approx(0.0)  # index 0 = expected 0


def test_existence_clustering_recovers_structure_types():
    # Existence vectors that depend only on a shape's structure type (as a well-trained network's would),
    # except that type 2 comes in two variants: groups stay pure, but the ARI sees the split.
    vectors = {0: [1, 1, 0, 0, 1], 1: [1, 0, 1, 0, 1], 2: [0, 1, 1, 1, 0]}
    truth = [0, 1, 2, 0, 1, 2, 0, 2]
    exists = torch.tensor([vectors[t] for t in truth], dtype=torch.bool)
    ids = cluster_by_existence(exists)
    assert purity(ids, truth) == 1.0 and adjusted_rand_index(ids, truth) == pytest.approx(1.0)
    exists[-1] = torch.tensor([0, 1, 1, 0, 0], dtype=torch.bool)  # one type-2 shape drops cuboid 3
    ids = cluster_by_existence(exists)
    assert purity(ids, truth) == 1.0
    assert 0 < adjusted_rand_index(ids, truth) < 1


def test_cluster_scores_reject_bad_labels():
    with pytest.raises(ValueError, match="same length"):
        purity([0, 1], [0, 1, 1])
    with pytest.raises(ValueError, match="must hold integer labels"):
        adjusted_rand_index([0.0, 1.0], [0, 1])
    with pytest.raises(ValueError, match="non-empty 1-D"):
        purity([], [])


# ----------------------------------------------------------------------------------------------
# Checkpoints by name
# ----------------------------------------------------------------------------------------------


def _save_tiny(path, seed: int = 0):
    torch.manual_seed(seed)
    net = CuboidAbstractionNet(TINY)
    return save_checkpoint(path, {"model": TINY.to_dict(), "n_points": 64}, net.state_dict(), step=5), net


def test_resolve_checkpoint_by_file_run_folder_and_committed_name(tmp_path, monkeypatch):
    file, _ = _save_tiny(tmp_path / "run" / "best.pt")
    assert resolve_checkpoint(file) == file
    assert resolve_checkpoint(tmp_path / "run") == file  # a training run folder means its best.pt
    committed = tmp_path / "committed"
    named, net = _save_tiny(committed / "chair.pt", seed=2)
    monkeypatch.setenv(CHECKPOINT_DIR_ENV, str(committed))
    assert committed_checkpoints() == {"chair": named}
    assert resolve_checkpoint("chair") == named
    model, state, path = load_trained_model("chair")
    assert path == named and state["step"] == 5 and not model.training
    for k, v in net.state_dict().items():
        assert torch.equal(model.state_dict()[k], v)
    with pytest.raises(FileNotFoundError, match=r"table: no such checkpoint.*committed: chair"):
        resolve_checkpoint("table")


def test_missing_and_unreadable_checkpoints_raise_clear_errors(tmp_path, monkeypatch):
    monkeypatch.setenv(CHECKPOINT_DIR_ENV, str(tmp_path / "nothing"))
    assert committed_checkpoints() == {}
    with pytest.raises(FileNotFoundError, match="committed: none yet"):
        resolve_checkpoint("chair")
    (tmp_path / "empty_run").mkdir()
    with pytest.raises(FileNotFoundError, match="without best.pt or last.pt"):
        resolve_checkpoint(tmp_path / "empty_run")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"ply\nthis is not a checkpoint")
    with pytest.raises(ValueError, match="junk.pt: not a readable cuboidlib checkpoint"):
        load_trained_model(junk)


# ----------------------------------------------------------------------------------------------
# A network that reads the normals (ModelConfig.input_normals)
# ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def normals_model() -> CuboidAbstractionNet:
    torch.manual_seed(0)
    return CuboidAbstractionNet(ModelConfig(**{**TINY.to_dict(), "input_normals": "differences"}))


def _unit(points: torch.Tensor, seed: int = 2) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.nn.functional.normalize(torch.randn(points.shape, generator=g), dim=-1)


def test_applications_pass_the_normals_to_a_network_that_reads_them(normals_model, clouds):
    normals = _unit(clouds)
    out = abstract_shapes(normals_model, clouds, normals=normals)
    with torch.no_grad():
        expected = normals_model.eval()(clouds, normals, sample_latent=False)
    torch.testing.assert_close(out.W, expected.W)
    batched = abstract_shapes(normals_model, clouds, normals=normals, batch_size=1)  # chunks keep their normals
    torch.testing.assert_close(batched.W, out.W)
    one = abstract_shapes(normals_model, clouds[1], normals=normals[1])  # one cloud (N, 3) with its (N, 3) normals
    torch.testing.assert_close(one.W[0], out.W[1])
    torch.testing.assert_close(encode_shapes(normals_model, clouds, normals), expected.mu)
    path = interpolate_latents(normals_model, clouds[0], clouds[1], steps=3, normals_a=normals[0], normals_b=normals[1])
    torch.testing.assert_close(path.shapes.z[0], expected.mu[0])
    with pytest.raises(ValueError, match="reads each point's normal: pass normals"):
        abstract_shapes(normals_model, clouds)
    with pytest.raises(ValueError, match="reads each point's normal: pass normals"):
        interpolate_latents(normals_model, clouds[0], clouds[1])


def test_latent_statistics_whiten_the_codes_and_the_distance_is_mahalanobis():
    from cuboidlib.applications import latent_distance, latent_statistics

    torch.manual_seed(0)
    config = ModelConfig.small(num_cuboids=4, k=8, edge_dims=(8, 8), global_dim=16, latent_dim=3, cuboid_code_dim=8,
                               cuboid_feature_dims=(16, 16), exist_hidden_dim=8, seg_dim=8)
    model = CuboidAbstractionNet(config).eval()
    points = torch.rand(40, 64, 3) - 0.5
    stats = latent_statistics(model, points, batch_size=7)
    mu = encode_shapes(model, points).double()
    covariance = torch.cov(mu.T)
    covariance += 1e-3 * covariance.diagonal().mean() * torch.eye(3, dtype=torch.float64)
    torch.testing.assert_close(stats["mean"], mu.mean(dim=0))
    torch.testing.assert_close(stats["whitening"] @ covariance @ stats["whitening"].T, torch.eye(3, dtype=torch.float64))
    by_hand = ((mu - mu.mean(0)) @ torch.linalg.inv(covariance) * (mu - mu.mean(0))).sum(-1).sqrt()
    torch.testing.assert_close(latent_distance(mu, stats), by_hand)
    assert latent_distance(stats["mean"], stats).item() == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match="more shapes than the 3 latent dimensions"):
        latent_statistics(model, points[:3])
    with pytest.raises(ValueError, match="mu"):
        latent_distance(torch.zeros(2, 5), stats)


def test_every_committed_network_holds_its_training_shapes_latent_statistics():
    for name, path in committed_checkpoints().items():
        model, state, _ = load_trained_model(path)
        stats = state["latent_statistics"]
        assert stats["mean"].shape == (model.config.latent_dim,) and int(stats["shapes"]) == 700, name
