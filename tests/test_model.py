"""Tests of cuboidlib.model: the network of Sec. 3.1-3.3 (shapes, ranges, initialisation, the fast
EdgeConv / global layer against the readable ones, invariances, configuration and
input validation). A small configuration keeps the file fast."""

from __future__ import annotations

import inspect
import io
import json
import math

import pytest
import torch
from torch.func import functional_call

from cuboidlib import edgeconv_fast
from cuboidlib import kernels
from cuboidlib import model as model_module
from cuboidlib.edgeconv_fast import FastEdgeConv, FastGlobalFeature
from cuboidlib.model import (
    read_normals_from_start,
    CuboidAbstractionNet,
    CuboidSegmentation,
    EdgeConv,
    GlobalFeature,
    ModelConfig,
    allocation_saturation,
    knn_indices,
)

SMALL = ModelConfig(
    num_cuboids=4,
    k=8,
    edge_dims=(8, 8),
    global_dim=32,
    latent_dim=16,
    cuboid_code_dim=8,
    cuboid_feature_dims=(16, 12),
    exist_hidden_dim=8,
    seg_dim=8,
)


def _points(batch=3, n=64, seed=0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(batch, n, 3, generator=g, dtype=torch.float64) * 2 - 1).to(dtype)


def _net(config=SMALL, seed=0, dtype=torch.float32):
    torch.manual_seed(seed)
    return CuboidAbstractionNet(config).to(dtype)


def _randomise_batchnorms(module, seed=0):
    """Random BatchNorm scales of both signs, shifts and running statistics (tests the min branch)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for bn in module.modules():
            if isinstance(bn, torch.nn.BatchNorm1d):
                c = bn.num_features
                bn.weight.copy_(torch.rand(c, generator=g) * 2 - 1)
                bn.bias.copy_(torch.rand(c, generator=g) - 0.5)
                bn.running_mean.copy_(torch.rand(c, generator=g) - 0.5)
                bn.running_var.copy_(torch.rand(c, generator=g) + 0.5)
    assert any((bn.weight < 0).any() for bn in module.modules() if isinstance(bn, torch.nn.BatchNorm1d))


def _readable_copy(fast):
    """The readable version of a fast layer or network, holding the same parameters and buffers."""
    if isinstance(fast, CuboidAbstractionNet):
        readable = CuboidAbstractionNet(fast.config, fast=False)
    elif isinstance(fast, FastEdgeConv):
        readable = EdgeConv(fast.in_dim, fast.out_dim, fast.k, fast.negative_slope, fast.relative_dims)
    else:
        readable = GlobalFeature(fast.linear.in_features, fast.linear.out_features, fast.negative_slope)
    readable = readable.to(next(fast.parameters()).dtype)
    readable.load_state_dict(fast.state_dict())
    return readable.train(fast.training)


def _assert_same_module_state(a, b, atol):
    for (name, p), q in zip(a.named_parameters(), b.parameters()):
        torch.testing.assert_close(p.grad, q.grad, atol=atol, rtol=1e-9, msg=f"gradient of {name}")
    for (name, p), q in zip(a.named_buffers(), b.buffers()):
        torch.testing.assert_close(p, q, atol=atol, rtol=1e-9, msg=f"buffer {name}")


# ----------------------------------------------------------------------------------------------
# Outputs
# ----------------------------------------------------------------------------------------------


def test_output_shapes_and_ranges():
    net = _net()
    points = _points()
    out = net(points)
    B, N, M, L = 3, 64, SMALL.num_cuboids, SMALL.latent_dim
    assert out.centers.shape == (B, M, 3)
    assert out.quaternions.shape == (B, M, 4)
    assert out.half_sizes.shape == (B, M, 3)
    assert out.exist_logits.shape == (B, M)
    assert out.W.shape == out.affinity.shape == (B, N, M)
    assert out.mu.shape == out.logvar.shape == out.z.shape == (B, L)
    assert out.point_features.shape == (B, N, sum(SMALL.edge_dims))
    assert out.global_feature.shape == (B, SMALL.global_dim)
    assert out.cuboid_features.shape == (B, M, SMALL.cuboid_feature_dims[-1])
    torch.testing.assert_close(out.quaternions.norm(dim=-1), torch.ones(B, M))
    assert (out.half_sizes > 0).all() and (out.half_sizes < 1).all()
    assert (out.centers > -1).all() and (out.centers < 1).all()
    assert (out.W >= 0).all()
    torch.testing.assert_close(out.W.sum(-1), torch.ones(B, N))
    torch.testing.assert_close(out.exist_probs, 1 / (1 + torch.exp(-out.exist_logits)))
    assert out.segmentation.shape == (B, N) and out.segmentation.dtype == torch.long
    assert torch.equal(out.segmentation, out.W.argmax(-1))


def test_initial_biases_follow_the_paper():
    net = _net()
    head = net.abstraction.D_cp
    assert torch.equal(head.size.bias, torch.zeros(3))
    assert torch.equal(head.translation.bias, torch.zeros(3))
    assert torch.equal(head.rotation.bias, torch.tensor([1.0, 0.0, 0.0, 0.0]))
    # With the head weights zeroed, the biases alone give sigmoid(0) = 0.5 half sizes, the identity
    # rotation and tanh(0) = 0 centres: axis-aligned cuboids at the origin.
    with torch.no_grad():
        for layer in (head.size, head.translation, head.rotation):
            layer.weight.zero_()
    out = net.eval()(_points())
    torch.testing.assert_close(out.half_sizes, torch.full_like(out.half_sizes, 0.5))
    torch.testing.assert_close(out.centers, torch.zeros_like(out.centers))
    torch.testing.assert_close(out.quaternions, torch.tensor([1.0, 0, 0, 0]).expand_as(out.quaternions))


def test_paper_sized_model_has_the_layer_sizes_of_the_paper():
    cfg = ModelConfig()
    net = CuboidAbstractionNet(cfg)
    bn = lambda c: 2 * c  # noqa: E731 - scale and shift
    expected = (
        (6 * 64 + bn(64) + 64 * 64 + bn(64))  # EdgeConv 1: [x_j - x_i, x_i] (6) -> 64 -> 64
        + (128 * 64 + bn(64) + 64 * 64 + bn(64))  # EdgeConv 2: 2 x 64 -> 64 -> 64
        + (128 * 1024 + bn(1024))  # shared layer to the 1024-d global feature
        + 2 * (1024 * 512 + 512)  # mu and log-variance
        + 16 * 64  # E_cb on the one-hot code (no bias)
        + (576 * 256 + 256) + (256 * 128 + 128)  # E_cf on [z, code]
        + (128 * 3 + 3) * 2 + (128 * 4 + 4) + (128 * 32 + 32) + (32 + 1)  # D_cp heads
        + 2 * 128 * 64  # segmentation projections (no bias)
    )
    assert sum(p.numel() for p in net.parameters()) == expected
    assert 1.3e6 < expected < 1.5e6  # "about 1.4 M parameters"


def test_segmentation_is_softmax_of_dot_products_eq_2_3():
    torch.manual_seed(0)
    seg = CuboidSegmentation(point_dim=6, cuboid_dim=5, seg_dim=4)
    fp, fc = torch.randn(2, 7, 6), torch.randn(2, 3, 5)
    A, W = seg(fp, fc)
    gp = fp @ seg.point_proj.weight.T
    gc = fc @ seg.cuboid_proj.weight.T
    for b in range(2):
        for n in range(7):
            for m in range(3):
                torch.testing.assert_close(A[b, n, m], torch.dot(gc[b, m], gp[b, n]))
    expected_W = torch.exp(A) / torch.exp(A).sum(-1, keepdim=True)
    torch.testing.assert_close(W, expected_W)
    scaled = CuboidSegmentation(point_dim=6, cuboid_dim=5, seg_dim=4, attention_scale=True)
    scaled.load_state_dict(seg.state_dict())
    A_scaled, _ = scaled(fp, fc)
    torch.testing.assert_close(A_scaled, A / 2.0)  # 1 / sqrt(seg_dim = 4)


def test_cosine_affinity_is_bounded_cosine_similarity():
    torch.manual_seed(0)
    seg = CuboidSegmentation(point_dim=6, cuboid_dim=5, seg_dim=4, cosine_affinity=10.0)
    fp, fc = 1000 * torch.randn(2, 7, 6), torch.randn(2, 3, 5)  # large features: the dot product would saturate
    A, W = seg(fp, fc)
    gp = fp @ seg.point_proj.weight.T
    gc = fc @ seg.cuboid_proj.weight.T
    expected = 10.0 * torch.nn.functional.cosine_similarity(gp[:, :, None, :], gc[:, None, :, :], dim=-1)
    torch.testing.assert_close(A, expected)
    assert A.abs().max() <= 10.0 + 1e-5
    torch.testing.assert_close(W, torch.softmax(expected, dim=-1))


def test_cosine_affinity_gradients_float64():
    torch.manual_seed(1)
    seg = CuboidSegmentation(point_dim=4, cuboid_dim=3, seg_dim=3, cosine_affinity=5.0).double()
    fp = torch.randn(1, 5, 4, dtype=torch.float64, requires_grad=True)
    fc = torch.randn(1, 2, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: seg(a, b)[1], (fp, fc))


def test_allocation_saturation_by_hand():
    # point 0: gap 40 (saturated); point 1: gap 0 (two equal best); point 2: gap 2 (weight ~0.79, not saturated)
    affinity = torch.tensor([[[40.0, 0.0, 0.0], [1.0, 1.0, -5.0], [2.0, 0.0, -30.0]]])
    saturated, gap = allocation_saturation(affinity)
    assert saturated.item() == pytest.approx(1 / 3)
    assert gap.item() == pytest.approx(2.0)  # median of 40, 0, 2
    one, zero = allocation_saturation(torch.zeros(1, 4, 1))
    assert one.item() == 1.0 and zero.item() == 0.0  # one cuboid: every point is fully allocated


def test_old_configs_without_cosine_affinity_still_load():
    data = ModelConfig.small().to_dict()
    del data["cosine_affinity"]
    assert ModelConfig.from_dict(data).cosine_affinity is None


# ----------------------------------------------------------------------------------------------
# Fast layers against the readable ones (float64)
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=pytest.mark.skipif(
    not kernels.available(), reason="the compiled kernels need a C++ compiler and ninja"))])
@pytest.mark.parametrize("training", [True, False])
@pytest.mark.parametrize("in_dim", [3, 5])
def test_fast_edgeconv_matches_readable_values_gradients_and_running_stats(training, in_dim, compiled):
    # compiled: the same with the kernels of cuboidlib.kernels (tests/test_kernels.py tests them alone)
    torch.manual_seed(1)
    fast = FastEdgeConv(in_dim, 6, k=5, edges_per_chunk=17).double()  # several chunks, one partial
    _randomise_batchnorms(fast)
    fast.train(training)
    ref = _readable_copy(fast)
    x = torch.randn(2, 23, in_dim, dtype=torch.float64, requires_grad=True)
    x_ref = x.detach().clone().requires_grad_()
    if compiled:
        kernels.enable()
    try:
        y = fast(x)
        g = torch.randn_like(y)
        y.backward(g)
    finally:
        kernels.disable()
    y_ref = ref(x_ref)
    torch.testing.assert_close(y, y_ref, atol=1e-12, rtol=1e-12)
    y_ref.backward(g)
    torch.testing.assert_close(x.grad, x_ref.grad, atol=1e-12, rtol=1e-9)
    _assert_same_module_state(fast, ref, atol=1e-12)
    if training:
        assert int(fast.bn1.num_batches_tracked) == 1 and not torch.equal(fast.bn1.running_mean, torch.zeros(6))


def test_fast_edgeconv_keeps_float32_accuracy_for_clouds_far_from_the_origin():
    # On close neighbours the two halves of the per-point split W_a x_j + (W_b - W_a) x_i nearly
    # cancel; the cloud is centred first so that float32 loses no more than the reference does.
    torch.manual_seed(5)
    conv = FastEdgeConv(3, 8, k=10)
    x = 50 + 0.05 * torch.randn(2, 200, 3)
    nbr = knn_indices(x, 10)
    exact = _readable_copy(conv).double()(x.double(), nbr)
    fast = conv(x, nbr).double()
    reference32 = _readable_copy(conv)(x, nbr).double()
    assert (fast - exact).abs().max() < 1e-4 * exact.abs().max()
    assert (fast - exact).abs().max() <= 2 * (reference32 - exact).abs().max()


def test_fast_edgeconv_chunks_are_larger_on_a_gpu_unless_given():
    from cuboidlib.edgeconv_fast import _EDGES_PER_CHUNK, _EDGES_PER_CHUNK_GPU

    conv = FastEdgeConv(3, 4, k=16)
    assert conv._chunk_rows(torch.device("cpu")) == _EDGES_PER_CHUNK // 16
    assert conv._chunk_rows(torch.device("cuda")) == _EDGES_PER_CHUNK_GPU // 16 > _EDGES_PER_CHUNK // 16
    assert FastEdgeConv(3, 4, k=16, edges_per_chunk=40)._chunk_rows(torch.device("cuda")) == 2
    assert FastEdgeConv(3, 4, k=16, edges_per_chunk=5)._chunk_rows(torch.device("cpu")) == 1, "at least one point"


def test_fast_edgeconv_gradcheck():
    torch.manual_seed(2)
    conv = FastEdgeConv(3, 4, k=4, edges_per_chunk=10).double()
    _randomise_batchnorms(conv)
    x = torch.randn(2, 9, 3, dtype=torch.float64, requires_grad=True)
    nbr = knn_indices(x, 4)  # fixed graph: the output is smooth in x and the weights
    names = [n for n, _ in conv.named_parameters()]
    params = tuple(p.detach().clone().requires_grad_() for p in conv.parameters())
    for training in (True, False):
        conv.train(training)

        def f(x, *ps):
            return functional_call(conv, dict(zip(names, ps)), (x, nbr))

        assert torch.autograd.gradcheck(f, (x, *params), atol=1e-7)


@pytest.mark.parametrize("training", [True, False])
def test_fast_global_feature_matches_readable(training):
    torch.manual_seed(3)
    fast = FastGlobalFeature(5, 12).double()
    _randomise_batchnorms(fast)
    fast.train(training)
    ref = _readable_copy(fast)
    f = torch.randn(3, 20, 5, dtype=torch.float64, requires_grad=True)
    f_ref = f.detach().clone().requires_grad_()
    y, y_ref = fast(f), ref(f_ref)
    torch.testing.assert_close(y, y_ref, atol=1e-12, rtol=1e-12)
    g = torch.randn_like(y)
    y.backward(g)
    y_ref.backward(g)
    torch.testing.assert_close(f.grad, f_ref.grad, atol=1e-12, rtol=1e-9)
    _assert_same_module_state(fast, ref, atol=1e-12)


def _loss(out):
    return (
        (out.W * out.point_features[..., :1]).sum()
        + out.centers.sum()
        + (out.quaternions * torch.arange(4.0, dtype=out.quaternions.dtype)).sum()
        + out.half_sizes.square().sum()
        + out.exist_logits.sum()
        + out.mu.square().sum()
        + out.logvar.sum()
    )


def test_whole_network_fast_path_equals_readable_path():
    net = _net(dtype=torch.float64)
    _randomise_batchnorms(net)
    ref = _readable_copy(net)
    assert not any(isinstance(m, (FastEdgeConv, FastGlobalFeature)) for m in ref.modules())
    points = _points(dtype=torch.float64)
    out = net(points, sample_latent=False)
    out_ref = ref(points, sample_latent=False)
    for name in ("W", "centers", "quaternions", "half_sizes", "exist_logits", "mu", "logvar", "point_features"):
        torch.testing.assert_close(getattr(out, name), getattr(out_ref, name), atol=1e-11, rtol=1e-9)
    _loss(out).backward()
    _loss(out_ref).backward()
    _assert_same_module_state(net, ref, atol=1e-10)


def test_duplicated_points_give_the_reference_parameter_gradients():
    # Duplicates make neighbours tie in the max over k; the gradient goes to one of the tied edges,
    # which changes nothing for the weights (the tied edges carry identical features).
    net = _net(dtype=torch.float64)
    ref = _readable_copy(net)
    half = _points(n=32, dtype=torch.float64)
    points = torch.cat([half, half], dim=1)
    out, out_ref = net(points, sample_latent=False), ref(points, sample_latent=False)
    torch.testing.assert_close(out.W, out_ref.W, atol=1e-11, rtol=1e-9)
    _loss(out).backward()
    _loss(out_ref).backward()
    _assert_same_module_state(net, ref, atol=1e-10)


# ----------------------------------------------------------------------------------------------
# kNN
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("channels, k", [(3, 7), (10, 2)])  # rows shorter / longer than 64 k
def test_knn_matches_brute_force_and_includes_self(channels, k):
    g = torch.Generator().manual_seed(4)
    n = 150
    x = torch.randn(2, n, channels, generator=g)
    idx = knn_indices(x, k)
    assert idx.shape == (2, n, k) and idx.dtype == torch.long
    own = torch.arange(n).view(1, n, 1)
    assert (idx == own).any(-1).all()
    brute = torch.empty(2, n, k, dtype=torch.long)
    for b in range(2):
        for i in range(n):
            d = ((x[b] - x[b, i]) ** 2).sum(-1)
            brute[b, i] = torch.argsort(d)[:k]
    assert torch.equal(idx.sort(-1).values, brute.sort(-1).values)


def test_knn_keeps_the_point_itself_among_duplicates():
    x = torch.zeros(1, 30, 3)  # all points coincide: every distance is 0
    idx = knn_indices(x, 5)
    assert (idx == torch.arange(30).view(1, 30, 1)).any(-1).all()
    assert all(len(set(row.tolist())) == 5 for row in idx[0])


# ----------------------------------------------------------------------------------------------
# Invariances and the latent code
# ----------------------------------------------------------------------------------------------


def test_permuting_points_permutes_W_and_keeps_everything_else():
    net = _net(dtype=torch.float64).eval()
    _randomise_batchnorms(net)
    points = _points(dtype=torch.float64)
    perm = torch.randperm(points.shape[1], generator=torch.Generator().manual_seed(5))
    out, out_p = net(points), net(points[:, perm])
    for name in ("global_feature", "mu", "logvar", "centers", "quaternions", "half_sizes", "exist_logits"):
        torch.testing.assert_close(getattr(out_p, name), getattr(out, name), atol=1e-12, rtol=1e-10)
    torch.testing.assert_close(out_p.W, out.W[:, perm], atol=1e-12, rtol=1e-10)
    torch.testing.assert_close(out_p.point_features, out.point_features[:, perm], atol=1e-12, rtol=1e-10)


def test_eval_mode_uses_the_mean_unless_sampling_is_asked_for():
    net = _net().eval()
    points = _points()
    a, b = net(points), net(points)
    assert torch.equal(a.z, a.mu) and torch.equal(a.centers, b.centers)
    s1 = net(points, sample_latent=True, generator=torch.Generator().manual_seed(7))
    s2 = net(points, sample_latent=True, generator=torch.Generator().manual_seed(7))
    assert torch.equal(s1.z, s2.z)
    assert not torch.allclose(s1.z, a.mu)
    # z = mu + exp(logvar / 2) * n with n the generator's standard normal draws (Eq. (1))
    noise = torch.randn(a.mu.shape, generator=torch.Generator().manual_seed(7))
    torch.testing.assert_close(s1.z, a.mu + torch.exp(0.5 * a.logvar) * noise)


def test_training_mode_samples_by_default():
    net = _net().train()
    points = _points()
    out = net(points, generator=torch.Generator().manual_seed(8))
    assert not torch.allclose(out.z, out.mu)
    out_mean = net(points, sample_latent=False)
    assert torch.equal(out_mean.z, out_mean.mu)


def test_encode_and_decode_agree_with_forward():
    net = _net().eval()
    points = _points()
    out = net(points)
    mu, logvar = net.encode(points)
    torch.testing.assert_close(mu, out.mu)
    torch.testing.assert_close(logvar, out.logvar)
    cuboids = net.decode(out.z)
    for name in ("centers", "quaternions", "half_sizes", "exist_logits", "cuboid_features"):
        torch.testing.assert_close(getattr(cuboids, name), getattr(out, name))
    z = torch.randn(5, SMALL.latent_dim, generator=torch.Generator().manual_seed(9))
    assert net.decode(z).centers.shape == (5, SMALL.num_cuboids, 3)


def test_cuboid_branches_differ_only_by_their_one_hot_code():
    net = _net().eval()
    z = torch.randn(2, SMALL.latent_dim, generator=torch.Generator().manual_seed(10))
    out = net.decode(z)
    assert not torch.allclose(out.centers[:, 0], out.centers[:, 1])
    # Give cuboid 1 the code of cuboid 0: E_cb, E_cf and D_cp are shared, so the two become equal.
    with torch.no_grad():
        net.abstraction.E_cb[0].weight[:, 1] = net.abstraction.E_cb[0].weight[:, 0]
    out = net.decode(z)
    torch.testing.assert_close(out.centers[:, 1], out.centers[:, 0])
    torch.testing.assert_close(out.exist_logits[:, 1], out.exist_logits[:, 0])


# ----------------------------------------------------------------------------------------------
# Configuration, checkpoints, devices
# ----------------------------------------------------------------------------------------------


def test_config_round_trips_through_json_and_a_weights_only_checkpoint():
    cfg = ModelConfig.small(num_cuboids=5, attention_scale=True)
    data = json.loads(json.dumps(cfg.to_dict()))
    assert ModelConfig.from_dict(data) == cfg
    assert isinstance(data["edge_dims"], list)
    net = _net(SMALL).eval()
    buffer = io.BytesIO()
    torch.save({"config": SMALL.to_dict(), "model": net.state_dict()}, buffer)
    buffer.seek(0)
    saved = torch.load(buffer, weights_only=True)
    restored = CuboidAbstractionNet(ModelConfig.from_dict(saved["config"]))
    restored.load_state_dict(saved["model"])
    points = _points()
    torch.testing.assert_close(restored.eval()(points).W, net(points).W)


def test_small_config_is_smaller_and_runs():
    small = CuboidAbstractionNet(ModelConfig.small())
    paper = CuboidAbstractionNet(ModelConfig())
    n_small = sum(p.numel() for p in small.parameters())
    assert 15 * n_small < sum(p.numel() for p in paper.parameters()) < 20 * n_small  # "about 17x fewer"
    out = small(_points(batch=2, n=40))
    assert out.W.shape == (2, 40, 16)


@pytest.mark.parametrize(
    "overrides, match",
    [
        (dict(num_cuboids=0), "num_cuboids must be a positive integer"),
        (dict(k=2.5), "k must be a positive integer"),
        (dict(edge_dims=()), "edge_dims must be a non-empty sequence"),
        (dict(cuboid_feature_dims=(16, -1)), "cuboid_feature_dims must be a non-empty sequence"),
        (dict(attention_scale="yes"), "attention_scale must be True or False"),
        (dict(cosine_affinity=0.0), r"cosine_affinity must be None or a number in \(0, 1000\]"),
        (dict(cosine_affinity=True), r"cosine_affinity must be None or a number"),
        (dict(cosine_affinity=5.0, attention_scale=True), "cosine_affinity and attention_scale exclude each other"),
        (dict(negative_slope=1.5), r"negative_slope must be a number in \[0, 1\)"),
    ],
)
def test_config_rejects_bad_values(overrides, match):
    with pytest.raises(ValueError, match=match):
        ModelConfig(**overrides)


def test_config_from_dict_rejects_unknown_keys():
    with pytest.raises(ValueError, match=r"unknown ModelConfig key\(s\) \['widths'\]"):
        ModelConfig.from_dict({"widths": 3})


def test_float64_model_keeps_float64_and_code_is_device_agnostic():
    net = _net(dtype=torch.float64)
    out = net(_points(dtype=torch.float32))  # converted to the model's dtype
    assert out.W.dtype == out.centers.dtype == out.z.dtype == torch.float64
    for module in (model_module, edgeconv_fast):
        source = inspect.getsource(module)
        assert ".cuda(" not in source and "'cuda'" not in source and '"cuda"' not in source, module.__name__


# ----------------------------------------------------------------------------------------------
# Bad inputs
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "points, match",
    [
        (torch.zeros(2, 64, 2), r"points must have shape \(B, N, 3\)"),
        (torch.zeros(64, 3), r"points must have shape \(B, N, 3\) \(3 dimensions\)"),
        (torch.zeros(0, 64, 3), "empty batch"),
        (torch.zeros(2, 8, 3), r"N = 8 points per cloud but the EdgeConv graph needs N > k = 8"),
        ("not points", "points must be a tensor or array-like"),
    ],
)
def test_forward_rejects_bad_points(points, match):
    with pytest.raises((ValueError, TypeError), match=match):
        _net()(points)


def test_forward_rejects_nan_points():
    points = _points()
    points[1, 5, 2] = math.nan
    expected = r"points contains 1 NaN or infinite value\(s\) \(first at index \(1, 5, 2\)\)"
    with pytest.raises(ValueError, match=expected):
        _net()(points)


def test_decode_rejects_bad_latent_codes():
    net = _net()
    with pytest.raises(ValueError, match=r"z must have shape \(B, 16\)"):
        net.decode(torch.zeros(2, 15))
    with pytest.raises(ValueError, match="z contains 1 NaN"):
        net.decode(torch.full((1, 16), 0.0).index_fill_(1, torch.tensor([3]), math.inf))


def test_edgeconv_rejects_neighbour_indices_of_the_wrong_shape():
    conv = EdgeConv(3, 4, k=4)
    with pytest.raises(ValueError, match=r"neighbours must have shape \(2, 10, 4\)"):
        conv(torch.randn(2, 10, 3), torch.zeros(2, 10, 3, dtype=torch.long))


def test_numpy_points_are_accepted():
    points = _points()
    net = _net().eval()
    out = net(points.numpy())
    assert out.W.shape == (3, 64, SMALL.num_cuboids)
    torch.testing.assert_close(out.W, net(points).W)


def test_knn_indices_stay_valid_for_non_finite_features():
    x = torch.randn(2, 20, 4)
    x[0, 3] = float("nan")
    x[1] = float("nan")  # a whole diverged cloud
    idx = knn_indices(x, 5)
    assert idx.shape == (2, 20, 5) and int(idx.min()) >= 0 and int(idx.max()) < 20


# ----------------------------------------------------------------------------------------------
# The option input_normals: the encoder reads the normals (their differences, or themselves too)
# ----------------------------------------------------------------------------------------------

DIFFERENCES = ModelConfig(**{**SMALL.to_dict(), "input_normals": "differences"})
ABSOLUTE = ModelConfig(**{**SMALL.to_dict(), "input_normals": "absolute"})


def _normals(points, seed=1):
    g = torch.Generator().manual_seed(seed)
    return torch.nn.functional.normalize(torch.randn(points.shape, generator=g, dtype=points.dtype), dim=-1)


@pytest.mark.parametrize("config, in_features", [(SMALL, 2 * 3), (DIFFERENCES, 2 * 3 + 3), (ABSOLUTE, 2 * 6)])
def test_input_normals_widens_only_the_first_edgeconv(config, in_features):
    net = _net(config)
    assert net.embedding.edge_convs[0].conv1.in_features == in_features
    assert net.embedding.edge_convs[1].conv1.in_features == 2 * SMALL.edge_dims[0]
    extra = sum(p.numel() for p in net.parameters()) - sum(p.numel() for p in _net(SMALL).parameters())
    assert extra == (in_features - 6) * SMALL.edge_dims[0]
    assert config.approximate_parameters() - SMALL.approximate_parameters() == extra


@pytest.mark.parametrize("config", [DIFFERENCES, ABSOLUTE], ids=["differences", "absolute"])
def test_first_layer_reads_the_edge_feature_by_hand_on_the_graph_of_the_points(config):
    net = _net(config, dtype=torch.float64).eval()
    points = _points(dtype=torch.float64)
    normals = _normals(points)
    features = net.embedding(points, normals)[0]
    conv0 = net.embedding.edge_convs[0]
    nbr = knn_indices(points, conv0.k)  # the graph of the 3-D points
    n_j = torch.stack([normals[b][nbr[b]] for b in range(len(points))])  # (B, N, k, 3)
    x_j = torch.stack([points[b][nbr[b]] for b in range(len(points))])
    x_i, n_i = points.unsqueeze(2).expand_as(x_j), normals.unsqueeze(2).expand_as(n_j)
    parts = [x_j - x_i, n_j - n_i, x_i] + ([n_i] if config.input_normals == "absolute" else [])
    h = torch.cat(parts, dim=-1)
    for conv, bn in ((conv0.conv1, conv0.bn1), (conv0.conv2, conv0.bn2)):
        h = (conv(h) - bn.running_mean) / torch.sqrt(bn.running_var + bn.eps) * bn.weight + bn.bias  # evaluation mode
        h = torch.nn.functional.leaky_relu(h, conv0.negative_slope)
    torch.testing.assert_close(features[..., : conv0.out_dim], h.amax(dim=2), atol=1e-12, rtol=1e-10)


@pytest.mark.parametrize("config", [DIFFERENCES, ABSOLUTE], ids=["differences", "absolute"])
def test_input_normals_fast_path_equals_readable_path_values_and_gradients(config):
    net = _net(config, dtype=torch.float64)
    _randomise_batchnorms(net)
    ref = _readable_copy(net)
    points = _points(dtype=torch.float64)
    normals = _normals(points)
    out, out_ref = net(points, normals, sample_latent=False), ref(points, normals, sample_latent=False)
    for name in ("W", "centers", "exist_logits", "mu", "point_features"):
        torch.testing.assert_close(getattr(out, name), getattr(out_ref, name), atol=1e-11, rtol=1e-9)
    _loss(out).backward()
    _loss(out_ref).backward()
    _assert_same_module_state(net, ref, atol=1e-10)


@pytest.mark.parametrize("config", [DIFFERENCES, ABSOLUTE], ids=["differences", "absolute"])
def test_input_normals_gradcheck_through_the_normals(config):
    net = _net(config, dtype=torch.float64).eval()
    points = _points(batch=1, n=12, dtype=torch.float64)
    normals = _normals(points).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda n: net(points, n, sample_latent=False).W, (normals,))


def test_differences_cannot_see_which_way_a_face_points_absolute_can():
    # n_j - n_i is unchanged when every normal moves by the same vector: on a flat face (all normals
    # equal) the point features do not depend on the face's orientation, so the allocation cannot
    # sort points by the direction they face (which would let thin plates fit them, Fig. 2).
    points = _points()
    normals = _normals(points)
    shifted = normals + torch.tensor([0.3, -0.7, 0.2])
    differences, absolute = _net(DIFFERENCES).eval(), _net(ABSOLUTE).eval()
    for name in ("point_features", "W", "centers"):
        torch.testing.assert_close(getattr(differences(points, shifted), name), getattr(differences(points, normals), name),
                                   atol=1e-5, rtol=1e-4)
    assert (absolute(points, shifted).point_features - absolute(points, normals).point_features).abs().max() > 0.1


def test_normals_change_the_output_only_of_a_network_that_reads_them():
    points = _points()
    normals, other = _normals(points), _normals(points, seed=5)
    plain = _net(SMALL).eval()
    torch.testing.assert_close(plain(points, normals).W, plain(points).W, rtol=0, atol=0)
    for config in (DIFFERENCES, ABSOLUTE):
        reading = _net(config).eval()
        assert (reading(points, normals).point_features - reading(points, other).point_features).abs().max() > 0.1


def test_input_normals_config_round_trips_and_old_configs_read_none():
    data = json.loads(json.dumps(DIFFERENCES.to_dict()))
    assert data["input_normals"] == "differences" and ModelConfig.from_dict(data) == DIFFERENCES
    old = SMALL.to_dict()
    del old["input_normals"]  # a checkpoint written before the option
    assert ModelConfig.from_dict(old).input_normals == "none"
    with pytest.raises(ValueError, match=r"input_normals must be one of \('none', 'differences', 'absolute'\), got True"):
        ModelConfig(input_normals=True)
    with pytest.raises(ValueError, match=r"relative_dims must lie in \[0, in_dim\) = \[0, 3\), got 3"):
        EdgeConv(3, 8, k=4, relative_dims=3)


@pytest.mark.parametrize("config", [DIFFERENCES, ABSOLUTE], ids=["differences", "absolute"])
def test_read_normals_from_start_computes_the_coordinates_only_function_then_learns_the_normals(config):
    plain = _net(SMALL, dtype=torch.float64)
    _randomise_batchnorms(plain)
    reading = _net(config, seed=3, dtype=torch.float64)
    reading.load_state_dict(read_normals_from_start(plain.state_dict(), config.input_normals))
    points = _points(dtype=torch.float64)
    normals = _normals(points)
    for train in (False, True):  # running statistics and batch statistics
        plain.train(train), reading.train(train)
        a, b = plain(points, sample_latent=False), reading(points, normals, sample_latent=False)
        for name in ("W", "centers", "half_sizes", "exist_logits", "point_features"):
            torch.testing.assert_close(getattr(b, name), getattr(a, name), rtol=1e-12, atol=1e-12, msg=name)
    weight = reading.embedding.edge_convs[0].conv1.weight
    b.W.square().sum().backward()
    normal_columns = [3, 4, 5] + ([9, 10, 11] if config.input_normals == "absolute" else [])
    assert weight[:, normal_columns].abs().max() == 0 and weight.grad[:, normal_columns].abs().max() > 0
    before = plain.state_dict()
    assert before["embedding.edge_convs.0.conv1.weight"].shape == (SMALL.edge_dims[0], 6)  # the input is not changed


def test_read_normals_from_start_rejects_what_it_cannot_widen():
    state = _net(SMALL).state_dict()
    with pytest.raises(ValueError, match=r"input_normals must be one of \('differences', 'absolute'\), got 'none'"):
        read_normals_from_start(state, "none")
    with pytest.raises(ValueError, match=r"has shape \(8, 9\); a network that reads coordinates only has \(C, 6\)"):
        read_normals_from_start(_net(DIFFERENCES).state_dict(), "absolute")
    with pytest.raises(ValueError, match="it is not that of a CuboidAbstractionNet"):
        read_normals_from_start({"weight": torch.zeros(2, 6)}, "differences")


@pytest.mark.parametrize(
    "normals, match",
    [
        (None, r"input_normals = 'differences' and reads each point's normal: pass normals \(B, N, 3\)"),
        (torch.zeros(3, 64, 2), r"normals must have shape \(3, 64, 3\)"),
        (torch.zeros(3, 63, 3), r"normals must have shape \(3, 64, 3\)"),
        (torch.full((3, 64, 3), math.nan), "normals contains 576 NaN or infinite value"),
    ],
)
def test_network_reading_normals_rejects_missing_or_bad_normals(normals, match):
    net = _net(DIFFERENCES)
    with pytest.raises(ValueError, match=match):
        net(_points(), normals)
    with pytest.raises(ValueError, match=match):
        net.encode(_points(), normals)
