"""Tests of cuboidlib.losses, in sections that follow the module's sections (one per loss term of Sec. 3.4)."""

from __future__ import annotations

import math

import pytest
import torch

from cuboidlib.losses import allocation_portions, compactness_loss, l1_penalty, l2_penalty


def _random_simplex(rows: int, M: int, seed: int, dtype=torch.float64) -> torch.Tensor:
    """(rows, M) points drawn uniformly from the simplex (normalised exponentials = Dirichlet(1, ..., 1))."""
    g = torch.Generator().manual_seed(seed)
    e = -torch.log(torch.rand(rows, M, generator=g, dtype=dtype))
    return e / e.sum(dim=-1, keepdim=True)


# =========================================================================================================
# Allocation portions w_m = (1/N) sum_n W_{m,n} (Sec. 3.4.2)
# =========================================================================================================


def test_allocation_portions_hand_example():
    # shape 0: point 0 fully in cuboid 0, point 1 split between cuboids 1 and 2
    # shape 1: both points fully in cuboid 2
    W = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 0.5, 0.5]], [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]])
    w = allocation_portions(W)
    torch.testing.assert_close(w, torch.tensor([[0.5, 0.25, 0.25], [0.0, 0.0, 1.0]]))


def test_allocation_portions_of_a_softmax_sum_to_one_with_shape_b_m():
    g = torch.Generator().manual_seed(0)
    W = torch.softmax(torch.randn(4, 50, 7, generator=g, dtype=torch.float64), dim=-1)
    w = allocation_portions(W)
    assert w.shape == (4, 7)
    assert w.dtype == torch.float64
    torch.testing.assert_close(w.sum(dim=-1), torch.ones(4, dtype=torch.float64))


def test_allocation_portions_accepts_nested_lists():
    torch.testing.assert_close(allocation_portions([[[0.0, 1.0], [1.0, 0.0]]]), torch.tensor([[0.5, 0.5]]))


@pytest.mark.parametrize(
    "W, match",
    [
        (torch.ones(5, 3), r"W must have shape \(B, N, M\)"),
        (torch.ones(2, 0, 3), r"W has no points \(N = 0\)"),
        ("not a tensor", "W must be a tensor"),
    ],
)
def test_allocation_portions_rejects_bad_input(W, match):
    with pytest.raises((ValueError, TypeError), match=match):
        allocation_portions(W)


# =========================================================================================================
# Cuboid compactness loss (Sec. 3.4.2, Eq. 6) and the comparison penalties of Fig. 5 (L1, L2)
# =========================================================================================================

EPS = 0.01  # the paper's eps_sps
PENALTIES = {"l05": compactness_loss, "l1": l1_penalty, "l2": l2_penalty}


@pytest.mark.parametrize("M", [1, 2, 5, 16])
def test_compactness_at_uniform_portions(M):
    # Eq. (6) with w_m = 1/M: (M sqrt(1/M + eps))^2
    w = torch.full((M,), 1.0 / M, dtype=torch.float64)
    expected = (M * math.sqrt(1.0 / M + EPS)) ** 2
    assert compactness_loss(w).item() == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("M", [1, 2, 5, 16])
def test_compactness_at_a_vertex(M):
    # one cuboid holds all points: (sqrt(1 + eps) + (M - 1) sqrt(eps))^2
    w = torch.zeros(M, dtype=torch.float64)
    w[M // 2] = 1.0
    expected = (math.sqrt(1 + EPS) + (M - 1) * math.sqrt(EPS)) ** 2
    assert compactness_loss(w).item() == pytest.approx(expected, rel=1e-12)


def test_penalties_hand_example():
    w = torch.tensor([0.2, 0.3, 0.5], dtype=torch.float64)
    assert l1_penalty(w).item() == pytest.approx(1.0, rel=1e-12)
    assert l2_penalty(w).item() == pytest.approx(0.04 + 0.09 + 0.25, rel=1e-12)
    # (sqrt(1/4) + sqrt(3/4))^2 = 1/4 + 3/4 + 2 * sqrt(3/16) = 1 + sqrt(3) / 2
    w2 = torch.tensor([0.25, 0.75], dtype=torch.float64)
    assert compactness_loss(w2, eps_sps=0.0).item() == pytest.approx(1 + math.sqrt(3) / 2, rel=1e-12)


def test_average_over_cuboids_is_the_paper_value_over_m_squared_with_gradient_m_squared_smaller():
    for M in (2, 7, 16):
        w = _random_simplex(3, M, seed=M).requires_grad_(True)
        paper = compactness_loss(w)
        code = compactness_loss(w, average_over_cuboids=True)
        torch.testing.assert_close(code, paper / M**2)
        (g_paper,) = torch.autograd.grad(paper.sum(), w)
        (g_code,) = torch.autograd.grad(code.sum(), w)
        torch.testing.assert_close(g_code * M**2, g_paper)


@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-14), (torch.float32, 1e-6)])
def test_l1_gradient_with_respect_to_logits_is_zero(dtype, tol):
    # analytically J^T 1 = w * (1 - sum w) = 0; numerically sum w = 1 only up to rounding
    g = torch.Generator().manual_seed(1)
    logits = (3 * torch.randn(64, 16, generator=g, dtype=dtype)).requires_grad_(True)
    l1_penalty(torch.softmax(logits, dim=-1)).sum().backward()
    assert logits.grad.abs().max().item() < tol
    # the same through the network's path: per-point softmax -> portions -> L1
    logits_pts = torch.randn(2, 100, 8, generator=g, dtype=dtype).requires_grad_(True)
    l1_penalty(allocation_portions(torch.softmax(logits_pts, dim=-1))).sum().backward()
    assert logits_pts.grad.abs().max().item() < tol
    # whereas the L0.5 and L2 gradients are clearly not zero at these logits
    logits.grad = None
    compactness_loss(torch.softmax(logits, dim=-1)).sum().backward()
    assert logits.grad.abs().max().item() > 1e-2


def test_l1_is_one_everywhere_on_the_simplex():
    w = _random_simplex(100, 9, seed=2)
    torch.testing.assert_close(l1_penalty(w), torch.ones(100, dtype=torch.float64))


@pytest.mark.parametrize("M", [2, 5, 16])
def test_l2_minimum_on_the_simplex_is_uniform(M):
    w = _random_simplex(500, M, seed=M)
    assert (l2_penalty(w) >= 1.0 / M - 1e-12).all()
    uniform = torch.full((M,), 1.0 / M, dtype=torch.float64)
    assert l2_penalty(uniform).item() == pytest.approx(1.0 / M, rel=1e-12)
    # and gradient descent on the logits walks there from a random start (the step M is below the
    # stability limit M^2 set by the curvature 2 / M^2 at uniform; much larger steps can overshoot
    # into a saturated softmax, where every gradient vanishes)
    logits = torch.randn(M, generator=torch.Generator().manual_seed(M), dtype=torch.float64) * 2
    logits.requires_grad_(True)
    for _ in range(1000):
        (grad,) = torch.autograd.grad(l2_penalty(torch.softmax(logits, dim=-1)), logits)
        logits = (logits - M * grad).detach().requires_grad_(True)
    torch.testing.assert_close(torch.softmax(logits, -1).detach(), uniform, atol=1e-6, rtol=0)


@pytest.mark.parametrize("M", [2, 5, 16])
def test_l05_decreases_from_uniform_towards_a_vertex_and_vertices_are_minima(M):
    uniform = torch.full((M,), 1.0 / M, dtype=torch.float64)
    vertex = torch.zeros(M, dtype=torch.float64)
    vertex[0] = 1.0
    t = torch.linspace(0, 1, 51, dtype=torch.float64)[:, None]
    values = compactness_loss((1 - t) * uniform + t * vertex)
    assert (values.diff() < 0).all(), "L0.5 must decrease strictly along the segment uniform -> vertex"
    # concave on the simplex, so no point of the simplex is below the (all equal) vertex values
    w = _random_simplex(500, M, seed=10 + M)
    assert (compactness_loss(w) >= compactness_loss(vertex) - 1e-12).all()


def test_l05_gradient_descent_on_logits_reaches_a_vertex():
    logits = torch.tensor([0.3, 0.0, -0.2, 0.1], dtype=torch.float64, requires_grad=True)
    for _ in range(300):
        (grad,) = torch.autograd.grad(compactness_loss(torch.softmax(logits, dim=-1)), logits)
        logits = (logits - 1.0 * grad).detach().requires_grad_(True)
    w = torch.softmax(logits, -1)
    assert w.argmax().item() == 0  # the largest start portion wins
    assert w.max().item() > 0.999


@pytest.mark.parametrize("M", [2, 5, 16])
def test_compactness_gradient_is_bounded_at_zero_with_eps(M):
    # d/dw_m L = S / sqrt(w_m + eps), S = sum_k sqrt(w_k + eps); at a vertex the zero entries get S / sqrt(eps)
    w = torch.zeros(M, dtype=torch.float64)
    w[0] = 1.0
    w.requires_grad_(True)
    compactness_loss(w).backward()
    S = math.sqrt(1 + EPS) + (M - 1) * math.sqrt(EPS)
    assert w.grad[1:].tolist() == pytest.approx([S / math.sqrt(EPS)] * (M - 1), rel=1e-12)
    assert w.grad[0].item() == pytest.approx(S / math.sqrt(1 + EPS), rel=1e-12)
    # Cauchy-Schwarz: S^2 <= M sum(w + eps), so |dL/dw_m| <= sqrt(M (1 + M eps) / eps) anywhere on the simplex
    ws = _random_simplex(200, M, seed=M).requires_grad_(True)
    compactness_loss(ws).sum().backward()
    assert ws.grad.abs().max().item() <= math.sqrt(M * (1 + M * EPS) / EPS)


def test_compactness_gradient_without_eps_is_infinite_at_zero_and_huge_near_it():
    w = torch.tensor([0.0, 1.0], dtype=torch.float64, requires_grad=True)
    compactness_loss(w, eps_sps=0.0).backward()
    assert math.isinf(w.grad[0].item())
    # near zero it grows like 1 / sqrt(w): dL/dw_0 = (sqrt(d) + sqrt(1 - d)) / sqrt(d)
    d = 1e-10
    w = torch.tensor([d, 1 - d], dtype=torch.float64, requires_grad=True)
    compactness_loss(w, eps_sps=0.0).backward()
    assert w.grad[0].item() == pytest.approx((math.sqrt(d) + math.sqrt(1 - d)) / math.sqrt(d), rel=1e-9)
    assert w.grad[0].item() > 1e4


def test_eps_keeps_logit_gradients_finite_when_a_softmax_entry_underflows_to_zero():
    logits = torch.tensor([0.0, -200.0, 1.0])  # float32 softmax gives exactly 0 for the middle entry
    assert torch.softmax(logits, -1)[1].item() == 0.0
    grads = {}
    for eps in (EPS, 0.0):
        z = logits.clone().requires_grad_(True)
        compactness_loss(torch.softmax(z, -1), eps_sps=eps).backward()
        grads[eps] = z.grad
    assert torch.isfinite(grads[EPS]).all()
    assert torch.isnan(grads[0.0]).all()  # 0 * inf = NaN in the softmax backward spreads to every logit


@pytest.mark.parametrize(
    "name, kwargs",
    [("l05", {}), ("l05", {"average_over_cuboids": True}), ("l05", {"eps_sps": 0.0}), ("l1", {}), ("l2", {})],
)
def test_penalties_gradcheck(name, kwargs):
    w = (_random_simplex(3, 6, seed=4) + 0.05).requires_grad_(True)  # away from 0 for the eps_sps = 0 case
    assert torch.autograd.gradcheck(lambda x: PENALTIES[name](x, **kwargs), (w,))


def test_penalties_gradcheck_through_softmax_logits():
    z = torch.randn(2, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(5)).requires_grad_(True)
    for fn in PENALTIES.values():
        assert torch.autograd.gradcheck(lambda x: fn(torch.softmax(x, dim=-1)), (z,))


@pytest.mark.parametrize("name", list(PENALTIES))
@pytest.mark.parametrize("shape", [(4,), (3, 4), (2, 3, 4)])
def test_penalties_reduce_the_last_axis(name, shape):
    w = torch.softmax(torch.randn(shape, generator=torch.Generator().manual_seed(6)), dim=-1)
    out = PENALTIES[name](w)
    assert out.shape == shape[:-1]
    assert out.dtype == torch.float32
    # each row is computed independently of the others
    torch.testing.assert_close(out.reshape(-1), torch.stack([PENALTIES[name](r) for r in w.reshape(-1, 4)]))


@pytest.mark.parametrize("name", list(PENALTIES))
def test_penalties_keep_float64_and_accept_lists(name):
    assert PENALTIES[name](torch.tensor([0.5, 0.5], dtype=torch.float64)).dtype == torch.float64
    torch.testing.assert_close(PENALTIES[name]([0.5, 0.5]), PENALTIES[name](torch.tensor([0.5, 0.5])))


@pytest.mark.parametrize("name", list(PENALTIES))
@pytest.mark.parametrize(
    "w, error, match",
    [
        (torch.tensor([0.5, float("nan")]), ValueError, r"w contains 1 NaN or infinite value\(s\) \(first at index \(1,\)\)"),
        (torch.tensor([[0.5, float("inf")]]), ValueError, r"w contains 1 NaN or infinite"),
        (torch.tensor(1.0), ValueError, r"w must have shape \(\.\.\., M\) with M >= 1 cuboids, got shape \(\)"),
        (torch.ones(3, 0), ValueError, r"w must have shape \(\.\.\., M\) with M >= 1 cuboids, got shape \(3, 0\)"),
        (torch.tensor([1.2, -0.2]), ValueError, r"w must be non-negative; the entry at index \(1,\) is -0.2"),
        ("abc", TypeError, r"w must be a tensor or array-like of numbers"),
    ],
)
def test_penalties_reject_bad_input(name, w, error, match):
    with pytest.raises(error, match=match):
        PENALTIES[name](w)


def test_compactness_rejects_negative_eps():
    with pytest.raises(ValueError, match=r"eps_sps must be non-negative, got -0.01"):
        compactness_loss(torch.tensor([0.5, 0.5]), eps_sps=-0.01)


# =========================================================================================================
# Reconstruction (Eq. 4), existence (Eq. 7), KL (Eq. 8) and the total loss (Eq. 9)
# =========================================================================================================

from types import SimpleNamespace  # noqa: E402

from cuboidlib.distance import nearest_surface_distance, point_to_cuboid_distance  # noqa: E402
from cuboidlib.losses import (  # noqa: E402
    LOSS_TERMS,
    LossConfig,
    allocation_weighted_centers,
    existence_loss,
    existence_targets,
    kl_divergence,
    nearest_cuboid_allocation,
    reconstruction_loss,
    total_loss,
)


def test_reconstruction_loss_by_hand():
    W = torch.tensor([[[1.0, 0.0], [0.25, 0.75]]])
    d = torch.tensor([[[2.0, 10.0], [4.0, 8.0]]])
    # point 0: 1 * 2 = 2; point 1: 0.25 * 4 + 0.75 * 8 = 7; mean over the two points = 4.5
    assert reconstruction_loss(W, d).tolist() == [4.5]
    with pytest.raises(ValueError, match=r"\(B, N, M\)"):
        reconstruction_loss(W, d[..., :1])


def test_nearest_cuboid_allocation_is_one_hot_argmin():
    d = torch.tensor([[[3.0, 1.0, 2.0], [0.5, 4.0, 0.7]]], requires_grad=True)
    W = nearest_cuboid_allocation(d)
    assert W.tolist() == [[[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]]
    assert not W.requires_grad


def test_allocation_weighted_centers_by_hand():
    points = torch.tensor([[[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 4.0, 0.0]]])
    W = torch.tensor([[[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]])
    # cuboid 0: (0 + 2) / (2 + 1) on x; cuboid 1: 4 / (1 + 1) on y
    expected = torch.tensor([[[2 / 3, 0.0, 0.0], [0.0, 2.0, 0.0]]])
    torch.testing.assert_close(allocation_weighted_centers(W, points), expected)


def test_existence_targets_paper_threshold_and_code_threshold():
    w = torch.tensor([[0.04, 0.06, 0.9]])
    assert existence_targets(w).tolist() == [[0.0, 1.0, 1.0]]
    # the code's rule with N = 500 points: 0.04 * 500 = 20 <= 24, 0.06 * 500 = 30 > 24
    assert existence_targets(w, min_points=24, num_points=500).tolist() == [[0.0, 1.0, 1.0]]
    # with N = 100 the counts are 4, 6 and 90: only the last passes 24 points
    assert existence_targets(w, min_points=24, num_points=100).tolist() == [[0.0, 0.0, 1.0]]
    with pytest.raises(ValueError, match="num_points"):
        existence_targets(w, min_points=24)


def test_existence_loss_matches_eq7_on_probabilities():
    logits = torch.tensor([[0.3, -1.2, 2.0]], dtype=torch.float64)
    t = torch.tensor([[1.0, 0.0, 1.0]], dtype=torch.float64)
    p = torch.sigmoid(logits)
    by_hand = -(t * p.log() + (1 - t) * (1 - p).log()).mean(dim=-1)
    torch.testing.assert_close(existence_loss(logits, t), by_hand)
    with pytest.raises(ValueError, match=r"\(B, M\)"):
        existence_loss(logits, t[:, :2])


def test_kl_divergence_by_hand():
    zero = torch.zeros(2, 4)
    assert kl_divergence(zero, zero).tolist() == [0.0, 0.0]
    mu = torch.tensor([[1.0, 0.0]])
    logvar = torch.tensor([[0.0, math.log(2.0)]])
    # dim 0: 0.5 * (1 - 1 + 1) = 0.5; dim 1: 0.5 * (2 - (1 + log 2)) = 0.5 - 0.5 log 2
    assert kl_divergence(mu, logvar).item() == pytest.approx(1.0 - 0.5 * math.log(2.0))


def _toy_prediction(requires_grad=False):
    """Two cuboids and four points with normals, as a network output would hold them."""
    g = torch.Generator().manual_seed(0)
    points = torch.tensor([[[0.5, 0.0, 0.0], [0.0, 0.5, 0.1], [1.5, 0.2, 0.0], [1.0, 0.0, 0.3]]])
    # tilted normals, so that the sampling along the normal changes the distance (Eq. 5)
    normals = torch.nn.functional.normalize(torch.tensor([[[1.0, 0.3, 0.0], [0.0, 1.0, 0.2], [1.0, 0.0, -0.4], [0.1, 0.0, 1.0]]]), dim=-1)
    out = SimpleNamespace(
        centers=torch.tensor([[[0.0, 0.0, 0.0], [1.2, 0.0, 0.0]]]),
        quaternions=torch.tensor([[[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]]]),
        half_sizes=torch.tensor([[[0.5, 0.5, 0.5], [0.3, 0.3, 0.3]]]),
        exist_logits=torch.tensor([[1.0, -1.0]]),
        W=torch.softmax(torch.randn(1, 4, 2, generator=g), dim=-1),
        mu=torch.tensor([[0.5, -0.5]]),
        logvar=torch.tensor([[0.1, -0.2]]),
    )
    if requires_grad:
        for name in ("centers", "half_sizes", "W"):
            setattr(out, name, getattr(out, name).clone().requires_grad_())
    return out, points, normals


def test_total_loss_combines_the_terms_with_the_paper_weights():
    out, points, normals = _toy_prediction()
    config = LossConfig(sigma_s=0.0)
    terms = total_loss(out, points, normals, config)
    d = point_to_cuboid_distance(points, normals, out.centers, out.quaternions, out.half_sizes, sigma_s=0.0)
    w = out.W.mean(dim=1)
    recons = (out.W * d).sum(-1).mean()
    compact = (torch.sqrt(w + 0.01).sum(-1) ** 2).mean()
    exist = existence_loss(out.exist_logits, (w > 0.05).float()).mean()
    kl = kl_divergence(out.mu, out.logvar).mean()
    torch.testing.assert_close(terms.reconstruction, recons)
    torch.testing.assert_close(terms.compactness, compact)
    torch.testing.assert_close(terms.existence, exist)
    torch.testing.assert_close(terms.kl, kl)
    torch.testing.assert_close(terms.total, recons + 0.1 * compact + 0.01 * exist + 6e-6 * kl)
    assert set(terms.as_floats()) == {"total", "reconstruction", "compactness", "existence", "kl", "consistency"}


def test_total_loss_sampling_is_reproducible_with_a_generator():
    out, points, normals = _toy_prediction()
    a = total_loss(out, points, normals, generator=torch.Generator().manual_seed(5)).total
    b = total_loss(out, points, normals, generator=torch.Generator().manual_seed(5)).total
    c = total_loss(out, points, normals, generator=torch.Generator().manual_seed(6)).total
    assert a == b and a != c


def test_total_loss_gradients_reach_cuboids_and_allocation():
    out, points, normals = _toy_prediction(requires_grad=True)
    total_loss(out, points, normals, LossConfig(sigma_s=0.0)).total.backward()
    for name in ("centers", "half_sizes", "W"):
        grad = getattr(out, name).grad
        assert grad is not None and grad.abs().sum() > 0, name


def test_authors_code_options_change_the_terms_as_documented():
    out, points, normals = _toy_prediction()
    paper = total_loss(out, points, normals, LossConfig(sigma_s=0.0))
    code = total_loss(out, points, normals, LossConfig.authors_code(sigma_s=0.0))
    M = out.W.shape[-1]
    torch.testing.assert_close(code.compactness, paper.compactness / M**2)
    centroids = allocation_weighted_centers(out.W, points)
    d = point_to_cuboid_distance(points, normals, centroids, out.quaternions, out.half_sizes, sigma_s=0.0)
    torch.testing.assert_close(code.reconstruction, reconstruction_loss(out.W, d).mean())
    # 4 points can never pass the 24-point existence rule: every target is 0
    torch.testing.assert_close(code.existence, existence_loss(out.exist_logits, torch.zeros(1, M)).mean())


def test_ablation_variants():
    out, points, normals = _toy_prediction()
    nearest = total_loss(out, points, normals, LossConfig(distance="nearest_surface"))
    d = nearest_surface_distance(points, out.centers, out.quaternions, out.half_sizes)
    torch.testing.assert_close(nearest.reconstruction, reconstruction_loss(out.W, d).mean())

    hard = total_loss(out, points, normals, LossConfig(allocation="nearest_cuboid", sigma_s=0.0))
    d = point_to_cuboid_distance(points, normals, out.centers, out.quaternions, out.half_sizes, sigma_s=0.0)
    torch.testing.assert_close(hard.W, nearest_cuboid_allocation(d))
    torch.testing.assert_close(hard.reconstruction, d.amin(dim=-1).mean())

    chamfer = total_loss(out, points, normals, LossConfig(distance="chamfer"), generator=torch.Generator().manual_seed(0))
    assert torch.all(chamfer.W.sum(-1) == 1) and set(chamfer.W.unique().tolist()) <= {0.0, 1.0}
    assert chamfer.reconstruction > 0


@pytest.mark.parametrize(
    "kwargs, match",
    [({"distance": "l2"}, "distance"), ({"allocation": "random"}, "allocation"), ({"lambda_compact": -1}, "lambda_compact"),
     ({"sigma_s": float("nan")}, "sigma_s")],
)
def test_loss_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        LossConfig(**kwargs)


def test_loss_config_dict_round_trip():
    config = LossConfig.authors_code(lambda_compact=0.2)
    assert LossConfig.from_dict(config.to_dict()) == config
    with pytest.raises(ValueError, match="unknown"):
        LossConfig.from_dict({"lambda_4": 1.0})


# =========================================================================================================
# Slot consistency across shapes (a course option, lambda_consistency)
# =========================================================================================================

from cuboidlib.losses import slot_consistency_loss  # noqa: E402


def test_slot_consistency_by_hand():
    # slot 0: centres x = 0 and 0.3 with portions 0.5 and 0.25: mean 0.1, spread (0.5 * 0.01 + 0.25 * 0.04) / 0.75
    # slot 1: the same centre in both shapes, spread 0
    centers = torch.tensor([[[0.0, 0, 0], [0.1, 0.2, 0]], [[0.3, 0, 0], [0.1, 0.2, 0]]])
    w = torch.tensor([[0.5, 0.5], [0.25, 0.75]])
    expected = ((0.5 * 0.01 + 0.25 * 0.04) / 0.75 + 0.0) / 2
    assert slot_consistency_loss(centers, w).item() == pytest.approx(expected, rel=1e-5)


def test_slot_consistency_ignores_empty_slots_and_is_translation_invariant():
    g = torch.Generator().manual_seed(1)
    centers = torch.rand(4, 3, 3, generator=g)
    w = torch.softmax(torch.randn(4, 3, generator=g), dim=-1)
    value = slot_consistency_loss(centers, w)
    torch.testing.assert_close(slot_consistency_loss(centers + torch.tensor([5.0, -2.0, 1.0]), w), value)
    # a shape whose slot 0 holds no points does not count, wherever that slot's centre is
    w0 = w.clone()
    w0[0, 0] = 0.0
    moved = centers.clone()
    moved[0, 0] += 10.0
    torch.testing.assert_close(slot_consistency_loss(moved, w0), slot_consistency_loss(centers, w0))


def test_slot_consistency_gradient_moves_points_out_of_a_stray_slot():
    # slot 0 sits at x = 0 in three shapes and at x = 1 in the fourth: the gradient lowers that shape's portion
    centers = torch.zeros(4, 2, 3, dtype=torch.float64)
    centers[3, 0, 0] = 1.0
    w = torch.full((4, 2), 0.5, dtype=torch.float64, requires_grad=True)
    slot_consistency_loss(centers, w).backward()
    assert w.grad[3, 0] > 0 > w.grad[0, 0]
    cw = torch.rand(3, 2, 3, dtype=torch.float64, requires_grad=True)
    ww = torch.rand(3, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(slot_consistency_loss, (cw, ww))


def test_total_loss_adds_the_weighted_consistency_term():
    one, points, normals = _toy_prediction()
    # two shapes: the toy and a copy whose second cuboid sits elsewhere, with a different allocation
    out = SimpleNamespace(**{k: torch.cat([v, v]) for k, v in vars(one).items()})
    out.centers[1, 1] += torch.tensor([0.0, 0.4, 0.0])
    out.W[1] = out.W[1].flip(-1)
    points, normals = torch.cat([points, points]), torch.cat([normals, normals])
    plain = total_loss(out, points, normals, LossConfig(sigma_s=0.0))
    with_term = total_loss(out, points, normals, LossConfig(sigma_s=0.0, lambda_consistency=0.5))
    expected = 0.5 * slot_consistency_loss(out.centers, plain.portions)
    assert expected > 0
    torch.testing.assert_close(with_term.total, plain.total + expected)
    # with centroid centres the term uses them, not the predicted translations
    code = LossConfig.authors_code(sigma_s=0.0)
    code_with_term = LossConfig.authors_code(sigma_s=0.0, lambda_consistency=0.5)
    centroids = allocation_weighted_centers(out.W, points)
    torch.testing.assert_close(total_loss(out, points, normals, code_with_term).total,
                               total_loss(out, points, normals, code).total
                               + 0.5 * slot_consistency_loss(centroids, plain.portions))
    with pytest.raises(ValueError, match="lambda_consistency"):
        LossConfig(lambda_consistency=-1.0)


def test_slot_consistency_rejects_bad_shapes():
    with pytest.raises(ValueError, match=r"\(B, M, 3\)"):
        slot_consistency_loss(torch.zeros(2, 3, 2), torch.full((2, 3), 1 / 3))


def test_the_slot_consistency_term_is_reported_and_weighted_into_the_total():
    torch.manual_seed(0)
    B, N, M = 3, 64, 4
    points = torch.rand(B, N, 3)
    normals = torch.nn.functional.normalize(torch.randn(B, N, 3), dim=-1)

    class Output:
        centers = torch.rand(B, M, 3)
        quaternions = torch.nn.functional.normalize(torch.randn(B, M, 4), dim=-1)
        half_sizes = torch.rand(B, M, 3) * 0.3 + 0.05
        exist_logits = torch.randn(B, M)
        W = torch.softmax(torch.randn(B, N, M), dim=-1)
        mu = torch.randn(B, 8)
        logvar = torch.randn(B, 8)

    plain = total_loss(Output, points, normals, LossConfig(), torch.Generator().manual_seed(1))
    weighted = total_loss(Output, points, normals, LossConfig(lambda_consistency=0.5), torch.Generator().manual_seed(1))
    assert float(plain.consistency) > 0, "the spread of random centres is positive, and it is reported"
    torch.testing.assert_close(weighted.consistency, plain.consistency)
    torch.testing.assert_close(weighted.total - plain.total, 0.5 * plain.consistency)
    assert set(plain.as_floats()) == set(LOSS_TERMS)
