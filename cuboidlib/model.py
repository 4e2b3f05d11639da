"""The network of the paper (Sec. 3.1-3.3, Fig. 3), readable: feature embedding, shape abstraction, segmentation.

One file, because the network's blocks are read together: each block's inputs are the last one's outputs.

Shapes (batch-first): points (B, N, 3); cuboid centers (B, M, 3), unit quaternions (B, M, 4) in
(w, x, y, z) order, half sizes (B, M, 3); allocation W (B, N, M), a softmax over the cuboids, i.e. the
transpose of the paper's W_{m,n}. Blocks are named after the paper: :class:`EdgeConv`, :class:`GlobalFeature`
and :class:`FeatureEmbedding` (E_pp, f^g and the VAE head, Sec. 3.1), :class:`ShapeAbstraction` and
:class:`CuboidDecoder` (E_cb, E_cf, D_cp, Sec. 3.2), :class:`CuboidSegmentation` (Eq. (2)-(3), Sec. 3.3), and
:class:`CuboidAbstractionNet`, configured by :class:`ModelConfig`. EdgeConv and the global layer are written
as the paper describes them; the network runs their fast twins of :mod:`cuboidlib.edgeconv_fast` (same
parameters, same results) unless built with ``fast=False``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from ._checks import (MAX_NETWORK_LAYERS, MAX_NETWORK_PARAMETERS, MAX_NETWORK_WIDTH, MAX_NEIGHBOURS, as_float_tensor,
                      check_finite, check_shape)
from .config import ConfigDict
from .edgeconv_fast import FastEdgeConv, FastGlobalFeature
from .neighbors import knn_indices

__all__ = [
    "ModelConfig",
    "EdgeConv",
    "GlobalFeature",
    "FeatureEmbedding",
    "CuboidDecoder",
    "ShapeAbstraction",
    "CuboidSegmentation",
    "allocation_saturation",
    "read_normals_from_start",
    "CuboidPrediction",
    "ModelOutput",
    "CuboidAbstractionNet",
    "reparameterize",
    # Re-exported, for the notebooks that import them from here: defined in neighbors and edgeconv_fast.
    "knn_indices",
    "FastEdgeConv",
]

#: The values of ModelConfig.input_normals: what the encoder reads of the normals.
INPUT_NORMALS = ("none", "differences", "absolute")

# ----------------------------------------------------------------------------------------------
# Configuration
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ModelConfig(ConfigDict):
    """Sizes and options of :class:`CuboidAbstractionNet`; the defaults are the paper's (Sec. 3.1-3.3).

    Args:
        num_cuboids: M, the cuboids predicted per shape.
        k: neighbours of each point in the EdgeConv graph, the point itself included.
        edge_dims: output width of each EdgeConv layer of E_pp; f^p has sum(edge_dims) channels (paper: 64 + 64).
        global_dim: width of the global feature f^g (paper: 1024).
        latent_dim: size of the latent code z (paper: 512).
        cuboid_code_dim: width of the one-hot cuboid code embedding E_cb (paper: 64).
        cuboid_feature_dims: widths of E_cf's layers, the last one f^c's (paper: 128; the public code adds a
            hidden layer of 256).
        exist_hidden_dim: hidden width of D_cp's existence head (public code: 32).
        seg_dim: width of g^p and g^c in the segmentation branch (paper: 64).
        attention_scale: divide the affinity of Eq. (2) by sqrt(seg_dim), as the public code does (the paper
            does not).
        negative_slope: slope of every LeakyReLU (public code: 0.2).
        cosine_affinity: None (the paper's dot product) or s > 0: A_mn = s cos(g^c_m, g^p_n), so |A_mn| <= s and
            the softmax of Eq. (3) never saturates beyond a gap of 2 s (the course's change, not the paper's).
        affinity_temperature: T >= 1, W = softmax(A / T): a softer allocation, the same argmax (1: Eq. (3)).
        input_normals: what the first EdgeConv reads of each point's unit normal: "none" (the paper's; the
            normals enter only the loss), "differences" (edge feature [x_j - x_i, n_j - n_i, x_i]) or
            "absolute" ([x_j - x_i, n_j - n_i, x_i, n_i]); the kNN graph stays that of the 3-D points, and
            the last two need the normals at inference (``forward(points, normals)``).

    ``to_dict`` / ``from_dict`` convert to and from a dict of plain JSON types (for checkpoints).
    """

    num_cuboids: int = 16
    k: int = 20
    edge_dims: tuple[int, ...] = (64, 64)
    global_dim: int = 1024
    latent_dim: int = 512
    cuboid_code_dim: int = 64
    cuboid_feature_dims: tuple[int, ...] = (256, 128)
    exist_hidden_dim: int = 32
    seg_dim: int = 64
    attention_scale: bool = False
    negative_slope: float = 0.2
    cosine_affinity: float | None = None
    affinity_temperature: float = 1.0
    input_normals: str = "none"

    def __post_init__(self) -> None:
        for name in ("edge_dims", "cuboid_feature_dims"):
            value = getattr(self, name)
            if isinstance(value, (list, tuple)):
                object.__setattr__(self, name, tuple(value))
        counts = ("num_cuboids", "k", "global_dim", "latent_dim", "cuboid_code_dim", "exist_hidden_dim", "seg_dim")
        for name in counts:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"ModelConfig.{name} must be a positive integer, got {value!r}")
        for name in ("edge_dims", "cuboid_feature_dims"):
            value = getattr(self, name)
            if (
                not isinstance(value, tuple)
                or not value
                or any(isinstance(v, bool) or not isinstance(v, int) or v < 1 for v in value)
            ):
                raise ValueError(
                    f"ModelConfig.{name} must be a non-empty sequence of positive integers, got {value!r}"
                )
        if not isinstance(self.attention_scale, bool):
            raise ValueError(f"ModelConfig.attention_scale must be True or False, got {self.attention_scale!r}")
        if self.input_normals not in INPUT_NORMALS:
            raise ValueError(f"ModelConfig.input_normals must be one of {INPUT_NORMALS}, got {self.input_normals!r}")
        cos = self.cosine_affinity
        if cos is not None:
            if isinstance(cos, bool) or not isinstance(cos, (int, float)) or not 0.0 < cos <= 1000.0:
                raise ValueError(f"ModelConfig.cosine_affinity must be None or a number in (0, 1000], got {cos!r}")
            if self.attention_scale:
                raise ValueError("ModelConfig.cosine_affinity and attention_scale exclude each other; set one of them")
            object.__setattr__(self, "cosine_affinity", float(cos))
        temp = self.affinity_temperature
        if isinstance(temp, bool) or not isinstance(temp, (int, float)) or not 1.0 <= temp <= 100.0:
            raise ValueError(f"ModelConfig.affinity_temperature must be a number in [1, 100], got {temp!r}")
        object.__setattr__(self, "affinity_temperature", float(temp))
        slope = self.negative_slope
        if isinstance(slope, bool) or not isinstance(slope, (int, float)) or not 0.0 <= slope < 1.0:
            raise ValueError(f"ModelConfig.negative_slope must be a number in [0, 1), got {slope!r}")
        object.__setattr__(self, "negative_slope", float(slope))
        # Bounds (cuboidlib._checks), so that a config read from a file cannot ask for an absurd allocation
        for name in counts:
            if getattr(self, name) > MAX_NETWORK_WIDTH:
                raise ValueError(f"ModelConfig.{name} = {getattr(self, name)} is above the limit of "
                                 f"{MAX_NETWORK_WIDTH} (cuboidlib._checks.MAX_NETWORK_WIDTH)")
        for name in ("edge_dims", "cuboid_feature_dims"):
            value = getattr(self, name)
            if len(value) > MAX_NETWORK_LAYERS or max(value) > MAX_NETWORK_WIDTH:
                raise ValueError(f"ModelConfig.{name} = {list(value)} has more than {MAX_NETWORK_LAYERS} layers or a "
                                 f"width above {MAX_NETWORK_WIDTH} (cuboidlib._checks.MAX_NETWORK_LAYERS and "
                                 "MAX_NETWORK_WIDTH)")
        if self.k > MAX_NEIGHBOURS:
            raise ValueError(f"ModelConfig.k = {self.k} is above the limit of {MAX_NEIGHBOURS} neighbours "
                             "(cuboidlib._checks.MAX_NEIGHBOURS)")
        if self.approximate_parameters() > MAX_NETWORK_PARAMETERS:
            raise ValueError(
                f"ModelConfig describes a network of about {self.approximate_parameters() / 1e6:.0f} million "
                f"parameters; at most {MAX_NETWORK_PARAMETERS / 1e6:.0f} million are accepted "
                f"(cuboidlib._checks.MAX_NETWORK_PARAMETERS; the paper's: "
                f"{ModelConfig().approximate_parameters() / 1e6:.1f} million)"
            )

    def approximate_parameters(self) -> int:
        """Number of weights of the network's matrices (biases and normalisation left out)."""
        widths, total, prev = self.edge_dims, 0, self.input_dim
        relative = self.relative_dims
        for w in widths:  # EdgeConv blocks: two 1x1 layers on (x_i, x_j - x_i)
            total += (2 * prev - relative) * w + w * w
            prev, relative = w, 0
        total += self.point_feature_dim * self.global_dim + 2 * self.global_dim * self.latent_dim
        chain = (self.latent_dim + self.cuboid_code_dim,) + self.cuboid_feature_dims
        total += sum(a * b for a, b in zip(chain, chain[1:])) + self.num_cuboids * self.cuboid_code_dim
        f_c = self.cuboid_feature_dims[-1]
        total += f_c * (self.exist_hidden_dim + 10) + (self.point_feature_dim + f_c) * self.seg_dim
        return total

    @classmethod
    def small(cls, **overrides) -> "ModelConfig":
        """A narrow model for quick CPU experiments (same structure, about 17x fewer parameters)."""
        sizes = dict(
            k=16,
            edge_dims=(32, 32),
            global_dim=256,
            latent_dim=64,
            cuboid_code_dim=32,
            cuboid_feature_dims=(128, 64),
            exist_hidden_dim=16,
            seg_dim=32,
        )
        sizes.update(overrides)
        return cls(**sizes)

    @property
    def input_dim(self) -> int:
        """Channels per point that enter the first EdgeConv: 3 coordinates, plus the normal's 3 unless
        ``input_normals`` is "none"."""
        return 3 if self.input_normals == "none" else 6

    @property
    def relative_dims(self) -> int:
        """Trailing input channels of the first EdgeConv that enter only as differences n_j - n_i."""
        return 3 if self.input_normals == "differences" else 0

    @property
    def point_feature_dim(self) -> int:
        """Channels of the point feature f^p (concatenation of the EdgeConv outputs)."""
        return sum(self.edge_dims)


# ----------------------------------------------------------------------------------------------
# Helpers
# ----------------------------------------------------------------------------------------------


def _next_momentum(bn: nn.BatchNorm1d) -> float:
    """Count one more training batch in ``bn`` and return its running-average factor (as nn.BatchNorm)."""
    bn.num_batches_tracked.add_(1)
    return bn.momentum if bn.momentum is not None else 1.0 / float(bn.num_batches_tracked)


def reparameterize(
    mu: torch.Tensor, logvar: torch.Tensor, generator: torch.Generator | None = None
) -> torch.Tensor:
    """The re-parameterisation of Eq. (1): z = mu + sigma * n, sigma = exp(logvar / 2), n ~ N(0, I).

    The paper's sigma is the standard deviation in Eq. (1) and the log-variance in the KL loss (Eq. (8));
    the network predicts the log-variance.

    Args:
        mu, logvar: (B, D) the mean and log-variance of q(z | points).
        generator: the source of n (default: torch's global one).

    Returns:
        (B, D) the latent codes z.
    """
    noise = torch.randn(mu.shape, generator=generator, dtype=mu.dtype, device=mu.device)
    return mu + noise * torch.exp(0.5 * logvar)


# ----------------------------------------------------------------------------------------------
# EdgeConv and the global feature (Sec. 3.1), readable (the fast ones: cuboidlib.edgeconv_fast)
# ----------------------------------------------------------------------------------------------


class EdgeConv(nn.Module):
    """One EdgeConv layer [DGCNN] of the point-feature encoder E_pp (Sec. 3.1), as the paper describes it.

    For each point i and each of its k nearest neighbours j (itself included), the edge feature
    [x_j - x_i, x_i] goes through two shared bias-free 1x1 layers (``conv1``, ``conv2``), each followed by
    BatchNorm over all B*N*k edges and LeakyReLU; the output is the max over the k edges. It builds the
    explicit (B, 2 C_in, N, k) edge tensor; :class:`cuboidlib.edgeconv_fast.FastEdgeConv` computes the
    same function of the same parameters faster.

    Args:
        in_dim, out_dim: C_in and C_out, the channels per point read and written.
        k: neighbours per point.
        negative_slope: LeakyReLU slope.
        relative_dims: r, the last input channels that enter the edge feature only as differences,
            [x_j - x_i, x_i without them] (2 C_in - r channels; ``input_normals="differences"``).

    Example::

        >>> conv = EdgeConv(3, 64, k=20)
        >>> conv(torch.rand(2, 1024, 3)).shape
        torch.Size([2, 1024, 64])
    """

    def __init__(self, in_dim: int, out_dim: int, k: int, negative_slope: float = 0.2, relative_dims: int = 0):
        super().__init__()
        if not 0 <= relative_dims < in_dim:
            raise ValueError(f"relative_dims must lie in [0, in_dim) = [0, {in_dim}), got {relative_dims}")
        self.in_dim, self.out_dim, self.k = in_dim, out_dim, k
        self.relative_dims = relative_dims
        self.negative_slope = negative_slope
        self.conv1 = nn.Linear(2 * in_dim - relative_dims, out_dim, bias=False)
        self.bn1 = nn.BatchNorm1d(out_dim)
        self.conv2 = nn.Linear(out_dim, out_dim, bias=False)
        self.bn2 = nn.BatchNorm1d(out_dim)

    def _neighbours(self, x: torch.Tensor, neighbours: torch.Tensor | None) -> torch.Tensor:
        if neighbours is None:
            return knn_indices(x, self.k)
        check_shape(neighbours, (x.shape[0], x.shape[1], self.k), "neighbours")
        return neighbours

    def forward(self, x: torch.Tensor, neighbours: torch.Tensor | None = None) -> torch.Tensor:
        """One EdgeConv layer.

        Args:
            x: (B, N, C_in) point features.
            neighbours: (B, N, k) indices of each point's neighbours; None: the kNN graph of x.

        Returns:
            (B, N, C_out) new point features.
        """
        nbr = self._neighbours(x, neighbours)
        batch, n, c = x.shape
        offsets = torch.arange(batch, device=x.device).view(batch, 1, 1) * n
        x_j = x.reshape(batch * n, c)[(nbr + offsets).reshape(-1)].view(batch, n, self.k, c)
        x_i = x.unsqueeze(2).expand(batch, n, self.k, c)
        x_i_kept = x_i[..., : c - self.relative_dims]  # the last relative_dims channels enter as differences only
        edges = torch.cat([x_j - x_i, x_i_kept], dim=-1).permute(0, 3, 1, 2)  # (B, 2C - r, N, k)
        h = edges
        for conv, bn in ((self.conv1, self.bn1), (self.conv2, self.bn2)):
            h = F.conv2d(h, conv.weight[:, :, None, None])
            momentum = _next_momentum(bn) if bn.training and bn.running_mean is not None else 0.0
            h = F.batch_norm(h, bn.running_mean, bn.running_var, bn.weight, bn.bias, bn.training, momentum, bn.eps)
            h = F.leaky_relu(h, self.negative_slope)
        return h.max(dim=-1).values.transpose(1, 2)  # (B, N, C_out)


class GlobalFeature(nn.Module):
    """The global feature f^g (Sec. 3.1, as in PointNet): a shared fully connected layer, BatchNorm and
    LeakyReLU on every point, then the max over the points. :class:`cuboidlib.edgeconv_fast.FastGlobalFeature`
    is the same function, faster.

    Args:
        in_dim, out_dim: C_in, the channels of the point features, and C_out, those of f^g.
        negative_slope: LeakyReLU slope.
    """

    def __init__(self, in_dim: int, out_dim: int, negative_slope: float = 0.2):
        super().__init__()
        self.linear = nn.Linear(in_dim, out_dim, bias=False)
        self.bn = nn.BatchNorm1d(out_dim)
        self.negative_slope = negative_slope

    def forward(self, f: torch.Tensor) -> torch.Tensor:
        """Args: f: (B, N, C_in) point features. Returns: (B, C_out) the global feature f^g."""
        h = self.linear(f).transpose(1, 2)  # (B, C_out, N)
        h = self.bn(h)
        return F.leaky_relu(h, self.negative_slope).max(dim=-1).values


# ----------------------------------------------------------------------------------------------
# Feature embedding (Sec. 3.1)
# ----------------------------------------------------------------------------------------------


class FeatureEmbedding(nn.Module):
    """E_pp (the EdgeConv layers), the global feature f^g and the VAE head predicting mu and log-variance (Sec. 3.1).

    The first EdgeConv uses the kNN graph of the 3-D points, each later one that of the previous layer's
    features.

    Args:
        config: the network's sizes.
        fast: the fast layers of :mod:`cuboidlib.edgeconv_fast` (default) or, if False, the readable
            :class:`EdgeConv` and :class:`GlobalFeature` (same parameters and results, slower).
    """

    def __init__(self, config: ModelConfig, fast: bool = True):
        super().__init__()
        dims = (config.input_dim,) + config.edge_dims
        self.input_normals = config.input_normals != "none"
        edge_conv, global_layer = (FastEdgeConv, FastGlobalFeature) if fast else (EdgeConv, GlobalFeature)
        self.edge_convs = nn.ModuleList(
            edge_conv(dims[i], dims[i + 1], config.k, config.negative_slope,
                      relative_dims=config.relative_dims if i == 0 else 0)
            for i in range(len(config.edge_dims))
        )
        self.global_feature = global_layer(config.point_feature_dim, config.global_dim, config.negative_slope)
        self.fc_mu = nn.Linear(config.global_dim, config.latent_dim)
        self.fc_logvar = nn.Linear(config.global_dim, config.latent_dim)

    def forward(
        self, points: torch.Tensor, normals: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Embed a batch of point clouds.

        Args:
            points: (B, N, 3).
            normals: (B, N, 3) unit normals, read unless the config's ``input_normals`` is "none".

        Returns:
            point_features (B, N, sum(edge_dims)) f^p, global_feature (B, global_dim) f^g, mu and logvar
            (B, latent_dim).
        """
        h, features, neighbours = points, [], None
        if self.input_normals:  # [x, n] per point; the first graph is that of the 3-D points
            h, neighbours = torch.cat([points, normals], dim=-1), knn_indices(points, self.edge_convs[0].k)
        for conv in self.edge_convs:
            h = conv(h, neighbours)
            features.append(h)
            neighbours = None  # every later layer builds its graph in feature space
        point_features = torch.cat(features, dim=-1)
        global_feature = self.global_feature(point_features)
        return point_features, global_feature, self.fc_mu(global_feature), self.fc_logvar(global_feature)


# ----------------------------------------------------------------------------------------------
# Shape abstraction (Sec. 3.2)
# ----------------------------------------------------------------------------------------------


@dataclass(eq=False)
class CuboidPrediction:
    """Cuboid parameters predicted by D_cp (Sec. 3.2) for B shapes and M cuboids.

    Attributes:
        centers: (B, M, 3) in (-1, 1) (tanh).
        quaternions: (B, M, 4) unit, (w, x, y, z).
        half_sizes: (B, M, 3) in (0, 1) (sigmoid).
        exist_logits: (B, M); the existence delta_m = sigmoid(logit).
        cuboid_features: (B, M, C) the cuboid features f^c.
    """

    centers: torch.Tensor
    quaternions: torch.Tensor
    half_sizes: torch.Tensor
    exist_logits: torch.Tensor
    cuboid_features: torch.Tensor

    @property
    def exist_probs(self) -> torch.Tensor:
        """Existence probabilities delta_m = sigmoid(exist_logits), (B, M)."""
        return torch.sigmoid(self.exist_logits)


class CuboidDecoder(nn.Module):
    """D_cp (Sec. 3.2): linear heads for the half sizes (sigmoid), the quaternion (normalised) and the centre
    (tanh), and a small MLP (C -> hidden -> 1) for the existence logit. As in the paper (Sec. 3.4.5), training
    starts from axis-aligned cuboids of half size 0.5 at the origin (size and translation biases 0, the
    quaternion's [1, 0, 0, 0]).

    Args:
        in_dim: C, the width of the cuboid feature f^c.
        exist_hidden_dim: hidden width of the existence head.
        negative_slope: LeakyReLU slope.
    """

    def __init__(self, in_dim: int, exist_hidden_dim: int = 32, negative_slope: float = 0.2):
        super().__init__()
        self.size = nn.Linear(in_dim, 3)
        self.rotation = nn.Linear(in_dim, 4)
        self.translation = nn.Linear(in_dim, 3)
        self.existence = nn.Sequential(
            nn.Linear(in_dim, exist_hidden_dim), nn.LeakyReLU(negative_slope), nn.Linear(exist_hidden_dim, 1)
        )
        with torch.no_grad():
            self.size.bias.zero_()
            self.translation.bias.zero_()
            self.rotation.bias.copy_(torch.tensor([1.0, 0.0, 0.0, 0.0]))

    def forward(self, cuboid_features: torch.Tensor) -> CuboidPrediction:
        """Args: cuboid_features: (B, M, C) f^c. Returns: the :class:`CuboidPrediction` of the B x M cuboids."""
        return CuboidPrediction(
            centers=torch.tanh(self.translation(cuboid_features)),
            quaternions=F.normalize(self.rotation(cuboid_features), dim=-1),
            half_sizes=torch.sigmoid(self.size(cuboid_features)),
            exist_logits=self.existence(cuboid_features).squeeze(-1),
            cuboid_features=cuboid_features,
        )


class ShapeAbstraction(nn.Module):
    """Latent code z -> M cuboids (Sec. 3.2): E_cb embeds cuboid m's one-hot code (a bias-free linear layer and
    LeakyReLU), E_cf maps [z, code] to f^c_m, D_cp decodes it; all three are shared by the cuboids. (E_cf's
    layers have a bias here, not in the public code.)

    Args:
        config: the network's sizes.
    """

    def __init__(self, config: ModelConfig):
        super().__init__()
        self.num_cuboids = config.num_cuboids
        slope = config.negative_slope
        self.E_cb = nn.Sequential(
            nn.Linear(config.num_cuboids, config.cuboid_code_dim, bias=False), nn.LeakyReLU(slope)
        )
        layers: list[nn.Module] = []
        width = config.latent_dim + config.cuboid_code_dim
        for out in config.cuboid_feature_dims:
            layers += [nn.Linear(width, out), nn.LeakyReLU(slope)]
            width = out
        self.E_cf = nn.Sequential(*layers)
        self.D_cp = CuboidDecoder(width, config.exist_hidden_dim, slope)

    def forward(self, z: torch.Tensor) -> CuboidPrediction:
        """Args: z: (B, latent_dim) latent codes. Returns: the :class:`CuboidPrediction` of B x M cuboids."""
        batch, m = z.shape[0], self.num_cuboids
        codes = self.E_cb(torch.eye(m, dtype=z.dtype, device=z.device))  # (M, code)
        joint = torch.cat([z.unsqueeze(1).expand(batch, m, -1), codes.expand(batch, m, -1)], dim=-1)
        return self.D_cp(self.E_cf(joint))


# ----------------------------------------------------------------------------------------------
# Cuboid-associated segmentation (Sec. 3.3)
# ----------------------------------------------------------------------------------------------


class CuboidSegmentation(nn.Module):
    """Point-to-cuboid allocation (Sec. 3.3): the affinity A_nm = g^c_m . g^p_n of Eq. (2), with g^p and g^c the
    point and cuboid features reduced to seg_dim by bias-free linear layers, and W = softmax of A over the
    cuboids, Eq. (3); the argmax over the cuboids is the segmentation.

    Args:
        point_dim, cuboid_dim: C_p and C_c, the widths of f^p and f^c.
        seg_dim: the width of g^p and g^c.
        attention_scale: divide A by sqrt(seg_dim), as the public code does (the paper does not).
        cosine_affinity: None, or s: A = s cos(g^c_m, g^p_n) instead, bounded by s.
        temperature: T, divide A by T (the returned logits include every factor).
    """

    def __init__(self, point_dim: int, cuboid_dim: int, seg_dim: int = 64, attention_scale: bool = False,
                 cosine_affinity: float | None = None, temperature: float = 1.0):
        super().__init__()
        self.point_proj = nn.Linear(point_dim, seg_dim, bias=False)
        self.cuboid_proj = nn.Linear(cuboid_dim, seg_dim, bias=False)
        self.scale = 1.0 / math.sqrt(seg_dim) if attention_scale else 1.0
        self.cosine_affinity = cosine_affinity
        self.temperature = float(temperature)

    def forward(
        self, point_features: torch.Tensor, cuboid_features: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Allocate the points to the cuboids.

        Args:
            point_features: (B, N, C_p) f^p.
            cuboid_features: (B, M, C_c) f^c.

        Returns:
            The affinity logits (B, N, M) and the allocation W (B, N, M), rows summing to 1.
        """
        g_p, g_c = self.point_proj(point_features), self.cuboid_proj(cuboid_features)
        if self.cosine_affinity is not None:
            g_p, g_c = F.normalize(g_p, dim=-1), F.normalize(g_c, dim=-1)
        affinity = g_p @ g_c.transpose(1, 2)
        if self.cosine_affinity is not None:
            affinity = affinity * self.cosine_affinity
        elif self.scale != 1.0:
            affinity = affinity * self.scale
        if self.temperature != 1.0:
            affinity = affinity / self.temperature
        return affinity, torch.softmax(affinity, dim=-1)


@torch.no_grad()
def allocation_saturation(affinity: torch.Tensor, threshold: float = 0.999) -> tuple[torch.Tensor, torch.Tensor]:
    """How hard the allocation softmax of Eq. (3) is. A logit gap g leaves the other cuboids a weight of at
    most e^-g, and the gradient that could move the point to them shrinks with it (a gap of 30 is final).

    Args:
        affinity: (B, N, M) affinity logits.
        threshold: the largest weight above which a point counts as saturated.

    Returns:
        Two scalars: the fraction of points whose largest weight max_m W_nm exceeds ``threshold``, and the
        median gap between the largest and the second-largest logit.
    """
    if affinity.shape[-1] < 2:
        zero = affinity.new_zeros(())
        return affinity.new_ones(()), zero
    top = affinity.topk(2, dim=-1).values
    gap = top[..., 0] - top[..., 1]
    largest = torch.softmax(affinity, dim=-1).amax(dim=-1)
    return (largest > threshold).to(affinity.dtype).mean(), gap.flatten().median()


# ----------------------------------------------------------------------------------------------
# The whole network
# ----------------------------------------------------------------------------------------------


@dataclass(eq=False)
class ModelOutput(CuboidPrediction):
    """Everything :class:`CuboidAbstractionNet` predicts for B point clouds of N points: the cuboids of
    :class:`CuboidPrediction` (M per shape) and

    Attributes:
        W: (B, N, M) the allocation, rows summing to 1.
        affinity: (B, N, M) its logits.
        mu, logvar: (B, latent_dim) the mean and LOG-variance of q(z | points) (the paper's sigma in Eq. (8)).
        z: (B, latent_dim) the code that was decoded.
        point_features: (B, N, C_p) f^p.
        global_feature: (B, global_dim) f^g.
    """

    W: torch.Tensor
    affinity: torch.Tensor
    mu: torch.Tensor
    logvar: torch.Tensor
    z: torch.Tensor
    point_features: torch.Tensor
    global_feature: torch.Tensor

    @property
    def segmentation(self) -> torch.Tensor:
        """Cuboid label of every point, argmax over M of W, (B, N) int64 (Sec. 3.3)."""
        return self.W.argmax(dim=-1)


def read_normals_from_start(state: dict[str, torch.Tensor], input_normals: str) -> dict[str, torch.Tensor]:
    """The weights of a network that reads coordinates only, as those of one that also reads the normals.

    The normal channels' columns are zero, so the new network computes exactly the old one's function until
    training moves them (a second training stage starts reading normals this way).

    Args:
        state: the state dict of a network with ``input_normals="none"``, whose first EdgeConv reads
            [p_j - p_i, p_i] (``conv1.weight`` (C, 6)).
        input_normals: "differences" (edge feature [p_j - p_i, n_j - n_i, p_i]) or "absolute"
            ([p_j - p_i, n_j - n_i, p_i, n_i]).

    Returns:
        A copy of ``state`` whose first ``conv1.weight`` is (C, 9) or (C, 12).

    Example::

        >>> old = CuboidAbstractionNet(ModelConfig.small())
        >>> new = CuboidAbstractionNet(ModelConfig.small(input_normals="differences"))
        >>> new.load_state_dict(read_normals_from_start(old.state_dict(), "differences"))
        <All keys matched successfully>
    """
    if input_normals not in INPUT_NORMALS[1:]:
        raise ValueError(f"input_normals must be one of {INPUT_NORMALS[1:]}, got {input_normals!r}")
    key = "embedding.edge_convs.0.conv1.weight"
    if key not in state:
        raise ValueError(f"the state dict has no {key!r}: it is not that of a CuboidAbstractionNet")
    weight = state[key]
    if weight.dim() != 2 or weight.shape[1] != 6:
        raise ValueError(f"{key} has shape {tuple(weight.shape)}; a network that reads coordinates only has "
                         f"(C, 6) there")
    zeros = weight.new_zeros(weight.shape[0], 3)
    columns = [weight[:, :3], zeros, weight[:, 3:]] + ([zeros] if input_normals == "absolute" else [])
    widened = dict(state)
    widened[key] = torch.cat(columns, dim=1)
    return widened


class CuboidAbstractionNet(nn.Module):
    """The paper's network (Fig. 3): point cloud -> M cuboids and the point-to-cuboid allocation.

    ``forward`` runs the feature embedding (Sec. 3.1), the shape abstraction (Sec. 3.2) and the segmentation
    (Sec. 3.3); ``encode`` gives (mu, logvar), ``decode`` the cuboids of latent codes (generation,
    interpolation).

    Args:
        config: the sizes (default: the paper's).
        fast: the fast EdgeConv and global layer (default) or, if False, the readable :class:`EdgeConv` and
            :class:`GlobalFeature`: the same parameters (a state dict loads into either) and results, slower.
    """

    def __init__(self, config: ModelConfig | None = None, fast: bool = True):
        super().__init__()
        self.config = config if config is not None else ModelConfig()
        cfg = self.config
        self.embedding = FeatureEmbedding(cfg, fast)
        self.abstraction = ShapeAbstraction(cfg)
        self.segmentation = CuboidSegmentation(
            cfg.point_feature_dim, cfg.cuboid_feature_dims[-1], cfg.seg_dim, cfg.attention_scale,
            cfg.cosine_affinity, cfg.affinity_temperature,
        )

    def _check_points(self, points) -> torch.Tensor:
        param = next(self.parameters())
        points = as_float_tensor(points, "points", dtype=param.dtype, device=param.device)
        sizes = check_shape(points, ("B", "N", 3), "points")
        if sizes["B"] == 0:
            raise ValueError("points is an empty batch (B = 0); at least one point cloud is needed")
        if sizes["N"] <= self.config.k:
            raise ValueError(
                f"points has N = {sizes['N']} points per cloud but the EdgeConv graph needs N > k = "
                f"{self.config.k}; use more points or a smaller ModelConfig.k"
            )
        check_finite(points, "points")
        return points

    def _check_normals(self, normals, points: torch.Tensor) -> torch.Tensor | None:
        """The normals the encoder reads, (B, N, 3) and finite; None when ``input_normals`` is "none"."""
        if self.config.input_normals == "none":
            return None
        if normals is None:
            raise ValueError(
                f"this network was trained with ModelConfig.input_normals = {self.config.input_normals!r} and reads "
                "each point's normal: "
                "pass normals (B, N, 3) beside the points (cuboidlib.normals.estimate_normals makes them)"
            )
        normals = as_float_tensor(normals, "normals", dtype=points.dtype, device=points.device)
        check_shape(normals, tuple(points.shape), "normals")
        check_finite(normals, "normals")
        return normals

    def encode(self, points: torch.Tensor, normals: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Encode point clouds (Sec. 3.1).

        Args:
            points: (B, N, 3) with N > k.
            normals: (B, N, 3), for a network that reads them (``ModelConfig.input_normals``).

        Returns:
            mu, logvar: (B, latent_dim) the mean and log-variance of q(z | points).
        """
        points = self._check_points(points)
        _, _, mu, logvar = self.embedding(points, self._check_normals(normals, points))
        return mu, logvar

    def decode(self, z: torch.Tensor) -> CuboidPrediction:
        """Decode latent codes (Sec. 3.2).

        Args:
            z: (B, latent_dim) latent codes.

        Returns:
            The :class:`CuboidPrediction` (cuboids and existence logits) of B x M cuboids.
        """
        param = next(self.parameters())
        z = as_float_tensor(z, "z", dtype=param.dtype, device=param.device)
        check_shape(z, ("B", self.config.latent_dim), "z")
        check_finite(z, "z")
        return self.abstraction(z)

    def forward(
        self,
        points: torch.Tensor,
        normals: torch.Tensor | None = None,
        sample_latent: bool | None = None,
        generator: torch.Generator | None = None,
    ) -> ModelOutput:
        """Run the whole network.

        Args:
            points: (B, N, 3) with N > k.
            normals: (B, N, 3) unit normals, required when ``ModelConfig.input_normals`` is "differences" or
                "absolute", ignored when it is "none".
            sample_latent: draw z = mu + sigma * n (Eq. (1)) if True, use z = mu if False; None: sample in
                training mode only (the public code samples in both).
            generator: the source of n (default: torch's global one).

        Returns:
            The :class:`ModelOutput`.
        """
        points = self._check_points(points)
        point_features, global_feature, mu, logvar = self.embedding(points, self._check_normals(normals, points))
        if sample_latent is None:
            sample_latent = self.training
        z = reparameterize(mu, logvar, generator) if sample_latent else mu
        cuboids = self.abstraction(z)
        affinity, W = self.segmentation(point_features, cuboids.cuboid_features)
        return ModelOutput(
            **{f.name: getattr(cuboids, f.name) for f in dataclasses.fields(CuboidPrediction)},
            W=W,
            affinity=affinity,
            mu=mu,
            logvar=logvar,
            z=z,
            point_features=point_features,
            global_feature=global_feature,
        )
